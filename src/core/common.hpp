// Shared by the compiled kernels: array types, constants, wrap_angle and the target grid.
//
// Frames and units as in fmcwlog/kernels/nearest.py: a pose (x, y, theta) maps source points into
// the target frame (q = R(theta) p + t), metres and radians. Every distance is the KD-tree's own
// arithmetic, sqrt((dx)^2 + (dy)^2), so that the pairs are those of the numpy reference.
#pragma once

#include <nanobind/nanobind.h>
#include <nanobind/ndarray.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <limits>
#include <stdexcept>
#include <vector>

namespace nb = nanobind;

namespace fmcwlog {

using Points = nb::ndarray<const double, nb::shape<-1, 2>, nb::c_contig, nb::device::cpu>;
using OutPoints = nb::ndarray<double, nb::shape<-1, 2>, nb::c_contig, nb::device::cpu>;
using OutVector = nb::ndarray<double, nb::shape<-1>, nb::c_contig, nb::device::cpu>;
using OutIndex = nb::ndarray<int64_t, nb::shape<-1>, nb::c_contig, nb::device::cpu>;

constexpr double kInf = std::numeric_limits<double>::infinity();
constexpr double kPi = 3.14159265358979311600;  // numpy's pi
constexpr int64_t kMaxCells = 1 << 22;

// geometry.wrap_angle on a scalar: (a + pi) mod 2 pi - pi, the modulo with the divisor's sign
inline double wrap_angle(double a) {
    const double two_pi = 2.0 * kPi;
    double r = std::fmod(a + kPi, two_pi);
    if (r != 0.0 && (r < 0.0) != (two_pi < 0.0)) r += two_pi;
    return r - kPi;
}

// The target points bucketed by a uniform grid of cells half the search radius wide, each cell's
// points stored together (interleaved x, y) in index order. A query scans its own cell, then rings
// of cells about it: each side of a ring, and each cell, only where its box may hold a point as
// near as the best so far, until no farther ring can; the first best is the radius itself. The
// answer is that of cKDTree.query(q, distance_upper_bound=radius) on the points, with ties (equal
// squared distances) to the lowest index: the boxes are widened by more than any rounding, so
// every point as near as the answer is scanned, whatever cell rounding gave it or the query.
class TargetGrid {
  public:
    TargetGrid(const double* xy, size_t m, double radius) : radius_(radius) {
        if (m >= size_t(std::numeric_limits<int32_t>::max())) throw std::length_error("TargetGrid: too many points");
        xy_.assign(xy, xy + 2 * m);
        double x0 = kInf, y0 = kInf, x1 = -kInf, y1 = -kInf;  // the finite points' box
        for (size_t i = 0; i < m; ++i) {  // NaN left out
            x0 = std::min(x0, xy[2 * i]);
            y0 = std::min(y0, xy[2 * i + 1]);
            x1 = std::max(x1, xy[2 * i]);
            y1 = std::max(y1, xy[2 * i + 1]);
        }
        if (!std::isfinite(x0) || !std::isfinite(y0) || !std::isfinite(x1) || !std::isfinite(y1)) {
            x0 = y0 = kInf;  // an infinite coordinate: again without such points (never an answer)
            x1 = y1 = -kInf;
            for (size_t i = 0; i < m; ++i) {
                if (!std::isfinite(xy[2 * i]) || !std::isfinite(xy[2 * i + 1])) continue;
                x0 = std::min(x0, xy[2 * i]);
                y0 = std::min(y0, xy[2 * i + 1]);
                x1 = std::max(x1, xy[2 * i]);
                y1 = std::max(y1, xy[2 * i + 1]);
            }
            if (!(x0 <= x1)) x0 = y0 = x1 = y1 = 0.0;  // no finite point (or none at all)
        }
        cell_ = radius / 2.0;
        while ((std::floor((x1 - x0) / cell_) + 1.0) * (std::floor((y1 - y0) / cell_) + 1.0) > double(kMaxCells))
            cell_ *= 2.0;  // a wide map: fewer, wider cells (the rings still cover the radius)
        rings_ = int64_t(std::ceil(radius / cell_)) + 1;
        inv_cell_ = 1.0 / cell_;
        // a cell's box, widened by more than the rounding of a point's cell and of the box's edges
        const double scale = std::max({std::fabs(x0), std::fabs(y0), std::fabs(x1), std::fabs(y1)});
        margin_ = 1e-9 * cell_ + 1e-14 * scale;
        x0_ = x0;
        y0_ = y0;
        nx_ = int64_t(std::floor((x1 - x0) / cell_)) + 1;
        ny_ = int64_t(std::floor((y1 - y0) / cell_)) + 1;
        // a counting sort by cell, stable: each cell's points in index order
        const size_t cells = size_t(nx_ * ny_);
        start_.assign(cells + 1, 0);
        std::vector<int32_t> where(m);
        for (size_t i = 0; i < m; ++i) {
            const double px = xy[2 * i], py = xy[2 * i + 1];
            int64_t cx = 0, cy = 0;  // a point not finite: any cell (it is never an answer)
            if (std::isfinite(px) && std::isfinite(py)) {
                cx = std::clamp(int64_t(std::floor((px - x0_) * inv_cell_)), int64_t(0), nx_ - 1);
                cy = std::clamp(int64_t(std::floor((py - y0_) * inv_cell_)), int64_t(0), ny_ - 1);
            }
            where[i] = int32_t(cy * nx_ + cx);
            ++start_[size_t(where[i])];
        }
        for (size_t c = 1; c < cells; ++c) start_[c] += start_[c - 1];  // each cell's end
        start_[cells] = int32_t(m);
        order_.resize(m);
        oxy_.resize(2 * m);
        for (size_t i = m; i-- > 0;) {  // from the last point back: each cell's start at the end
            const size_t k = size_t(--start_[size_t(where[i])]);
            order_[k] = int32_t(i);
            oxy_[2 * k] = xy[2 * i];
            oxy_[2 * k + 1] = xy[2 * i + 1];
        }
    }

    double radius() const { return radius_; }
    size_t size() const { return xy_.size() / 2; }  // the points M
    double x(int64_t i) const { return xy_[2 * size_t(i)]; }
    double y(int64_t i) const { return xy_[2 * size_t(i) + 1]; }

    // What the search of one query leaves for the next query of the same source point (an ICP moves
    // its source a little each iteration): the query (qx, qy), the answer (index -1: none searched
    // yet) and clear, a distance (m) that every other target point is at least as far as from it.
    struct Memo {
        double qx = 0.0, qy = 0.0, clear = 0.0;
        int64_t index = -1, slot = -1;
    };

    // The nearest target point to (qx, qy) closer than the radius: its index and distance, or -1 and inf.
    // at (optional): the point's (x, y) where one is found, read from the cell just scanned (the same
    // numbers as x(index), y(index), without a look-up in index order).
    int64_t nearest(double qx, double qy, double& dist, double* at = nullptr) const {
        return search<false>(qx, qy, dist, at, nullptr);
    }

    // nearest(), the same answer bit for bit, from memo where it decides it: a query moved by delta
    // from the memo's keeps its answer j while |q - p_j| + delta is less than the memo's clear
    // distance (every other point is at least clear - delta away, by the triangle inequality; the
    // margin exceeds any rounding, so a tie or a near tie searches again). Otherwise a search, which
    // fills the memo. The distance is the search's arithmetic on the same stored coordinates.
    int64_t nearest(double qx, double qy, double& dist, double* at, Memo& memo) const {
        if (memo.index >= 0 && std::isfinite(qx) && std::isfinite(qy)) {
            const double mx = qx - memo.qx, my = qy - memo.qy;
            const double moved = std::sqrt(mx * mx + my * my);
            const double dx = oxy_[2 * size_t(memo.slot)] - qx;
            const double dy = oxy_[2 * size_t(memo.slot) + 1] - qy;
            const double d = std::sqrt(dx * dx + dy * dy);
            if (d < radius_ && d + moved < memo.clear * (1.0 - 1e-9) - 1e-12) {
                dist = d;
                if (at != nullptr) {
                    at[0] = oxy_[2 * size_t(memo.slot)];
                    at[1] = oxy_[2 * size_t(memo.slot) + 1];
                }
                return memo.index;
            }
        }
        return search<true>(qx, qy, dist, at, &memo);
    }

  private:
    struct Best {
        double d2;
        int64_t index, slot;  // the point's index and its place in cell order
        // with Track: the least squared distance of any other point scanned, and the least squared
        // gap of a cell or ring left unscanned (a bound on the distance of every point in it)
        double other2 = kInf;
    };

    // The search behind nearest(); with Track, it fills memo (clear: the least of the other points'
    // distances scanned, the gaps of what was left unscanned and the radius).
    template <bool Track>
    int64_t search(double qx, double qy, double& dist, double* at, Memo* memo) const {
        dist = kInf;
        if constexpr (Track) memo->index = -1;
        if (!std::isfinite(qx) || !std::isfinite(qy)) return -1;
        const double fx = std::floor((qx - x0_) * inv_cell_), fy = std::floor((qy - y0_) * inv_cell_);  // any cell near q
        const double reach = double(rings_) + 1.0;
        if (fx < -reach || fy < -reach || fx > double(nx_) + reach || fy > double(ny_) + reach) return -1;
        const int64_t cx = int64_t(fx), cy = int64_t(fy);
        Best b{radius_ * radius_ * (1.0 + 1e-9), -1, -1};  // a bound: the root decides below
        if (cx >= 0 && cx < nx_ && cy >= 0 && cy < ny_) scan<Track>(cy * nx_ + cx, qx, qy, b);
        for (int64_t r = 1; r <= rings_; ++r) {
            const int64_t xl = cx - r, xh = cx + r, yl = cy - r, yh = cy + r;
            if (xl < 0 && xh >= nx_ && yl < 0 && yh >= ny_) break;
            const double bl = sq(gap_x(xl, qx)), bh = sq(gap_x(xh, qx));
            const double cl = sq(gap_y(yl, qy)), ch = sq(gap_y(yh, qy));
            const double ring = std::min(std::min(bl, bh), std::min(cl, ch));
            if (ring > b.d2) {  // this ring and all beyond
                if constexpr (Track) b.other2 = std::min(b.other2, ring);
                break;
            }
            const int64_t xa = std::max(xl, int64_t(0)), xb = std::min(xh, nx_ - 1);
            const int64_t ya = std::max(yl + 1, int64_t(0)), yb = std::min(yh - 1, ny_ - 1);
            if (yl >= 0 && yl < ny_) side<Track>(yl, cl, xa, xb, cx, qx, qy, b, true);
            if (yh >= 0 && yh < ny_) side<Track>(yh, ch, xa, xb, cx, qx, qy, b, true);
            if (xl >= 0 && xl < nx_) side<Track>(xl, bl, ya, yb, cy, qx, qy, b, false);
            if (xh >= 0 && xh < nx_) side<Track>(xh, bh, ya, yb, cy, qx, qy, b, false);
        }
        if (b.index < 0) return -1;
        dist = std::sqrt(b.d2);
        if (!(dist < radius_)) {
            dist = kInf;
            return -1;
        }
        if (at != nullptr) {
            at[0] = oxy_[2 * size_t(b.slot)];
            at[1] = oxy_[2 * size_t(b.slot) + 1];
        }
        if constexpr (Track) *memo = Memo{qx, qy, std::min(std::sqrt(b.other2), radius_), b.index, b.slot};
        return b.index;
    }

    static double sq(double v) { return v * v; }
    // How far (qx) is left of column x's box, or right of it; 0 for its own column (m).
    double gap_x(int64_t x, double qx) const {
        const double lx = x0_ + double(x) * cell_ - margin_, hx = x0_ + double(x + 1) * cell_ + margin_;
        return std::max({0.0, lx - qx, qx - hx});
    }
    double gap_y(int64_t y, double qy) const {
        const double ly = y0_ + double(y) * cell_ - margin_, hy = y0_ + double(y + 1) * cell_ + margin_;
        return std::max({0.0, ly - qy, qy - hy});
    }
    // A ring's row y (across: cells xa..xb) or column x (else: cells ya..yb), whose squared gap g2
    // across it is known: each cell whose box may hold a point as near as the best so far, and the
    // ring's own cell in line with q (c0) always. With Track, what is left unscanned gives its gap.
    template <bool Track>
    void side(int64_t line, double g2, int64_t a, int64_t z, int64_t c0, double qx, double qy, Best& b,
              bool across) const {
        if (g2 > b.d2) {
            if constexpr (Track) b.other2 = std::min(b.other2, g2);
            return;
        }
        for (int64_t k = a; k <= z; ++k) {
            const double cell2 = k == c0 ? 0.0 : (across ? sq(gap_x(k, qx)) : sq(gap_y(k, qy)));
            if (k == c0 || g2 + cell2 <= b.d2) {
                scan<Track>(across ? line * nx_ + k : k * nx_ + line, qx, qy, b);
            } else if constexpr (Track) {
                b.other2 = std::min(b.other2, g2 + cell2);
            }
        }
    }
    // The points of cell c against the best so far: nearer, or as near with a lower index. A cell
    // keeps its points in index order, so its first nearest is its lowest index at that distance.
    // With Track, the cell's other points (and a displaced best) bound the other points' distance.
    template <bool Track>
    void scan(int64_t c, double qx, double qy, Best& b) const {
        const int64_t k0 = start_[size_t(c)], k1 = start_[size_t(c + 1)];
        double m = kInf, m2 = kInf;
        int64_t km = -1;
        for (int64_t k = k0; k < k1; ++k) {
            const double dx = oxy_[2 * size_t(k)] - qx;
            const double dy = oxy_[2 * size_t(k) + 1] - qy;
            const double d2 = dx * dx + dy * dy;
            const bool nearer = d2 < m;
            if constexpr (Track) m2 = nearer ? m : std::min(m2, d2);
            m = nearer ? d2 : m;
            km = nearer ? k : km;
        }
        if constexpr (Track) b.other2 = std::min(b.other2, m2);
        if (km < 0) return;
        if (m > b.d2) {
            if constexpr (Track) b.other2 = std::min(b.other2, m);
            return;
        }
        const int64_t i = order_[size_t(km)];
        if (m < b.d2 || i < b.index) {
            if constexpr (Track) {
                if (b.index >= 0) b.other2 = std::min(b.other2, b.d2);
            }
            b = Best{m, i, km, b.other2};
        } else if constexpr (Track) {
            b.other2 = std::min(b.other2, m);
        }
    }

    double radius_, cell_ = 1.0, inv_cell_ = 1.0, margin_ = 0.0, x0_ = 0.0, y0_ = 0.0;
    int64_t nx_ = 1, ny_ = 1, rings_ = 5;
    std::vector<double> xy_, oxy_;
    std::vector<int32_t> start_, order_;  // per cell + 1: its first point; per point: its index
};

// A source point (px, py) moved by a pose (c, sn its rotation's cosine and sine; x, y m) as
// NearestPairs moves it, (mx, my), and the grid's nearest target to it (index and distance dist, or
// -1 and inf): point_to_point_icp.cpp's nearest, a point at a time.
inline int64_t nearest_moved(const TargetGrid& grid, double c, double sn, double x, double y, double px, double py,
                             double& mx, double& my, double& dist) {
    mx = c * px + (-sn) * py + x;
    my = c * py + sn * px + y;
    return grid.nearest(mx, my, dist);
}

// recovery.inlier_fraction's count: the n source points s (interleaved x, y) whose nearest target
// under the pose (x, y, theta) is closer than distance (m; at most the grid's radius to be exact).
// memo (optional, n entries): each point's TargetGrid::Memo, as an ICP's iterations left them.
inline int64_t count_within(const TargetGrid& grid, const double* s, size_t n, double x, double y, double theta,
                            double distance, std::vector<TargetGrid::Memo>* memo = nullptr) {
    const double c = std::cos(theta), sn = std::sin(theta);
    int64_t k = 0;
    for (size_t i = 0; i < n; ++i) {
        double mx, my, d;
        if (memo == nullptr) {
            nearest_moved(grid, c, sn, x, y, s[2 * i], s[2 * i + 1], mx, my, d);
        } else {
            mx = c * s[2 * i] + (-sn) * s[2 * i + 1] + x;
            my = c * s[2 * i + 1] + sn * s[2 * i] + y;
            grid.nearest(mx, my, d, nullptr, (*memo)[i]);
        }
        k += d < distance;
    }
    return k;
}

}  // namespace fmcwlog
