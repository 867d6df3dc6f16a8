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

// The target points bucketed by a uniform grid of cells half the search radius wide.
// A query scans its own cell, then rings of cells about it, each cell only where the cell's box
// may hold a point nearer than the best so far, until no farther ring can; the first best is
// the radius itself. Within a cell the points keep their order (ties go to the lowest index).
class TargetGrid {
  public:
    TargetGrid(const double* xy, size_t m, double radius) : radius_(radius) {
        x_.resize(m);
        y_.resize(m);
        double x0 = kInf, y0 = kInf, x1 = -kInf, y1 = -kInf;
        for (size_t i = 0; i < m; ++i) {
            x_[i] = xy[2 * i];
            y_[i] = xy[2 * i + 1];
            x0 = std::min(x0, x_[i]);
            y0 = std::min(y0, y_[i]);
            x1 = std::max(x1, x_[i]);
            y1 = std::max(y1, y_[i]);
        }
        if (m == 0) x0 = y0 = x1 = y1 = 0.0;
        cell_ = radius / 2.0;
        while ((std::floor((x1 - x0) / cell_) + 1.0) * (std::floor((y1 - y0) / cell_) + 1.0) > double(kMaxCells))
            cell_ *= 2.0;  // a wide map: fewer, wider cells (the rings still cover the radius)
        rings_ = int64_t(std::ceil(radius / cell_)) + 1;
        margin_ = 1e-9 * cell_;  // a cell's box, widened by more than the rounding of a point's cell
        x0_ = x0;
        y0_ = y0;
        nx_ = int64_t(std::floor((x1 - x0) / cell_)) + 1;
        ny_ = int64_t(std::floor((y1 - y0) / cell_)) + 1;
        start_.assign(size_t(nx_ * ny_ + 1), 0);
        std::vector<int64_t> where(m);
        for (size_t i = 0; i < m; ++i) {
            int64_t cx = std::clamp(int64_t(std::floor((x_[i] - x0_) / cell_)), int64_t(0), nx_ - 1);
            int64_t cy = std::clamp(int64_t(std::floor((y_[i] - y0_) / cell_)), int64_t(0), ny_ - 1);
            where[i] = cy * nx_ + cx;
            ++start_[size_t(where[i] + 1)];
        }
        for (size_t c = 1; c < start_.size(); ++c) start_[c] += start_[c - 1];
        order_.resize(m);
        std::vector<int64_t> fill(start_.begin(), start_.end() - 1);
        for (size_t i = 0; i < m; ++i) order_[size_t(fill[size_t(where[i])]++)] = int64_t(i);
        ox_.resize(m);
        oy_.resize(m);
        for (size_t k = 0; k < m; ++k) {
            ox_[k] = x_[size_t(order_[k])];
            oy_[k] = y_[size_t(order_[k])];
        }
    }

    double radius() const { return radius_; }
    double x(int64_t i) const { return x_[size_t(i)]; }
    double y(int64_t i) const { return y_[size_t(i)]; }

    // The nearest target point to (qx, qy) closer than the radius: its index and distance, or -1 and inf.
    int64_t nearest(double qx, double qy, double& dist) const {
        dist = kInf;
        if (!std::isfinite(qx) || !std::isfinite(qy)) return -1;
        const double fx = std::floor((qx - x0_) / cell_), fy = std::floor((qy - y0_) / cell_);
        const double reach = double(rings_) + 1.0;
        if (fx < -reach || fy < -reach || fx > double(nx_) + reach || fy > double(ny_) + reach) return -1;
        const int64_t cx = int64_t(fx), cy = int64_t(fy);
        double best = radius_ * radius_ * (1.0 + 1e-9);  // a bound: the root decides below
        int64_t found = -1;
        for (int64_t r = 0; r <= rings_; ++r) {
            const double gap = double(r - 1) * cell_ - margin_;  // every cell of ring r is at least this far
            if (r > 1 && gap * gap > best) break;
            for (int64_t y = cy - r; y <= cy + r; ++y) {
                if (y < 0 || y >= ny_) continue;
                const bool edge = (y == cy - r || y == cy + r);
                for (int64_t x = cx - r; x <= cx + r; x += (edge || r == 0) ? 1 : 2 * r) {
                    if (x < 0 || x >= nx_) continue;
                    const double lx = x0_ + double(x) * cell_ - margin_, hx = x0_ + double(x + 1) * cell_ + margin_;
                    const double ly = y0_ + double(y) * cell_ - margin_, hy = y0_ + double(y + 1) * cell_ + margin_;
                    const double bx = std::max({0.0, lx - qx, qx - hx}), by = std::max({0.0, ly - qy, qy - hy});
                    if (bx * bx + by * by > best) continue;
                    const int64_t c = y * nx_ + x;
                    for (int64_t k = start_[size_t(c)]; k < start_[size_t(c + 1)]; ++k) {
                        const double dx = ox_[size_t(k)] - qx;
                        const double dy = oy_[size_t(k)] - qy;
                        const double d2 = dx * dx + dy * dy;
                        if (d2 < best || (d2 == best && order_[size_t(k)] < found)) {
                            best = d2;
                            found = order_[size_t(k)];
                        }
                    }
                }
            }
        }
        if (found < 0) return -1;
        dist = std::sqrt(best);
        if (!(dist < radius_)) {
            dist = kInf;
            return -1;
        }
        return found;
    }

  private:
    double radius_, cell_ = 1.0, margin_ = 0.0, x0_ = 0.0, y0_ = 0.0;
    int64_t nx_ = 1, ny_ = 1, rings_ = 5;
    std::vector<double> x_, y_, ox_, oy_;
    std::vector<int64_t> start_, order_;
};

}  // namespace fmcwlog
