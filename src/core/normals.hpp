// Each point's line normal from its nearest neighbours (fmcwlog/kernels/normals.py,
// fmcwlog/backend/registration.py build_submap): the neighbour search, the 2 x 2 eigenproblem and one
// point's normal, shared by the back end's submaps (submap.cpp) and the front end's robust ICP
// (robust_icp.cpp, which computes them lazily, for the map points it pairs with).
#pragma once

#include <algorithm>
#include <cmath>
#include <memory>
#include <vector>

#include "common.hpp"

namespace fmcwlog {

// The points bucketed by a uniform grid of square cells (index order within a cell).
class NeighbourBuckets {
  public:
    NeighbourBuckets(const double* xy, int64_t m) : xy_(xy) {
        double x1 = -kInf, y1 = -kInf;
        x0_ = y0_ = kInf;
        for (int64_t i = 0; i < m; ++i) {
            x0_ = std::min(x0_, xy[2 * i]);
            y0_ = std::min(y0_, xy[2 * i + 1]);
            x1 = std::max(x1, xy[2 * i]);
            y1 = std::max(y1, xy[2 * i + 1]);
        }
        const double wx = x1 - x0_, wy = y1 - y0_;
        // about four cells a point over the box (on lines: some ten points an occupied cell)
        cell_ = std::max({std::sqrt(wx * wy / double(m)) / 2.0, std::max(wx, wy) / double(4 * m), 1e-9});
        bucket(m);
    }

    // The k nearest points of point ``q`` into idx (nearest first, equal squared distances by index).
    void nearest(int64_t q, int64_t k, std::vector<double>& d2, std::vector<int64_t>& idx) const {
        const double x = xy_[2 * q], y = xy_[2 * q + 1];
        const int64_t qx = cx(x), qy = cy(y);
        d2.clear();
        idx.clear();
        for (int64_t r = 0;; ++r) {
            for (int64_t j = qy - r; j <= qy + r; ++j) {
                if (j < 0 || j >= ny_) continue;
                const bool edge = j == qy - r || j == qy + r;
                for (int64_t i = qx - r; i <= qx + r; i += (edge || r == 0) ? 1 : 2 * r) {
                    if (i < 0 || i >= nx_) continue;
                    const int64_t c = j * nx_ + i;
                    for (int64_t s = start_[size_t(c)]; s < start_[size_t(c + 1)]; ++s)
                        offer(order_[size_t(s)], x, y, k, d2, idx);
                }
            }
            if (r >= nx_ && r >= ny_) return;  // the ring holds the whole grid
            // every point outside the rings so far is at least this far (a margin for the rounding
            // of a point's cell)
            const double bound = std::min({x - (x0_ + double(qx - r) * cell_), x0_ + double(qx + r + 1) * cell_ - x,
                                           y - (y0_ + double(qy - r) * cell_), y0_ + double(qy + r + 1) * cell_ - y}) -
                                 1e-9 * cell_;
            if (int64_t(idx.size()) == k && bound > 0.0 && d2.back() < bound * bound) return;
        }
    }

  private:
    void bucket(int64_t m) {
        const double* xy = xy_;
        double x1 = -kInf, y1 = -kInf;
        for (int64_t i = 0; i < m; ++i) {
            x1 = std::max(x1, xy[2 * i]);
            y1 = std::max(y1, xy[2 * i + 1]);
        }
        nx_ = int64_t(std::floor((x1 - x0_) / cell_)) + 1;
        ny_ = int64_t(std::floor((y1 - y0_) / cell_)) + 1;
        start_.assign(size_t(nx_ * ny_ + 1), 0);
        std::vector<int64_t> where(static_cast<size_t>(m));
        for (int64_t i = 0; i < m; ++i) {
            where[size_t(i)] = cy(xy[2 * i + 1]) * nx_ + cx(xy[2 * i]);
            ++start_[size_t(where[size_t(i)] + 1)];
        }
        for (size_t c = 1; c < start_.size(); ++c) start_[c] += start_[c - 1];
        order_.resize(size_t(m));
        std::vector<int64_t> fill(start_.begin(), start_.end() - 1);
        for (int64_t i = 0; i < m; ++i) order_[size_t(fill[size_t(where[size_t(i)])]++)] = i;
    }

    int64_t cx(double x) const { return std::clamp(int64_t(std::floor((x - x0_) / cell_)), int64_t(0), nx_ - 1); }
    int64_t cy(double y) const { return std::clamp(int64_t(std::floor((y - y0_) / cell_)), int64_t(0), ny_ - 1); }

    void offer(int64_t p, double x, double y, int64_t k, std::vector<double>& d2, std::vector<int64_t>& idx) const {
        const double dx = xy_[2 * p] - x, dy = xy_[2 * p + 1] - y;
        const double d = dx * dx + dy * dy;
        if (int64_t(idx.size()) == k && !(d < d2.back() || (d == d2.back() && p < idx.back()))) return;
        if (int64_t(idx.size()) < k) {
            d2.push_back(d);
            idx.push_back(p);
        } else {
            d2.back() = d;
            idx.back() = p;
        }
        for (size_t s = idx.size() - 1; s > 0; --s) {  // insertion: (d2, index) ascending
            if (d2[s - 1] < d2[s] || (d2[s - 1] == d2[s] && idx[s - 1] < idx[s])) break;
            std::swap(d2[s - 1], d2[s]);
            std::swap(idx[s - 1], idx[s]);
        }
    }

    const double* xy_;
    double x0_, y0_, cell_;
    int64_t nx_, ny_;
    std::vector<int64_t> start_, order_;
};

struct Eigen2 {
    double small, large, nx, ny;  // eigenvalues ascending; (nx, ny): the unit eigenvector of ``small``
};

// LAPACK's dlaev2 on [[a, b], [b, c]]: rt1 (the eigenvalue of larger magnitude), rt2, and the unit
// eigenvector (cs1, sn1) of rt1; for a covariance rt1 >= rt2, so the normal is (-sn1, cs1).
inline Eigen2 eigen_2x2(double a, double b, double c) {
    const double sm = a + c, df = a - c, adf = std::fabs(df), tb = b + b, ab = std::fabs(tb);
    double acmx = a, acmn = c;
    if (std::fabs(a) <= std::fabs(c)) {
        acmx = c;
        acmn = a;
    }
    double rt;
    if (adf > ab) {
        const double q = ab / adf;
        rt = adf * std::sqrt(1.0 + q * q);
    } else if (adf < ab) {
        const double q = adf / ab;
        rt = ab * std::sqrt(1.0 + q * q);
    } else {
        rt = ab * std::sqrt(2.0);
    }
    double rt1, rt2;
    int sgn1;
    if (sm < 0.0) {
        rt1 = 0.5 * (sm - rt);
        sgn1 = -1;
        rt2 = (acmx / rt1) * acmn - (b / rt1) * b;
    } else if (sm > 0.0) {
        rt1 = 0.5 * (sm + rt);
        sgn1 = 1;
        rt2 = (acmx / rt1) * acmn - (b / rt1) * b;
    } else {
        rt1 = 0.5 * rt;
        rt2 = -0.5 * rt;
        sgn1 = 1;
    }
    int sgn2;
    double cs;
    if (df >= 0.0) {
        cs = df + rt;
        sgn2 = 1;
    } else {
        cs = df - rt;
        sgn2 = -1;
    }
    double cs1, sn1;
    if (std::fabs(cs) > ab) {
        const double ct = -tb / cs;
        sn1 = 1.0 / std::sqrt(1.0 + ct * ct);
        cs1 = ct * sn1;
    } else if (ab == 0.0) {
        cs1 = 1.0;
        sn1 = 0.0;
    } else {
        const double tn = -cs / tb;
        cs1 = 1.0 / std::sqrt(1.0 + tn * tn);
        sn1 = tn * cs1;
    }
    if (sgn1 == sgn2) {
        const double tn = cs1;
        cs1 = -sn1;
        sn1 = tn;
    }
    if (rt2 <= rt1) return {rt2, rt1, -sn1, cs1};
    return {rt1, rt2, cs1, sn1};
}

// Point q's normal (unit, into out[0..1]) from its k = min(neighbours, m) nearest points (itself among
// them; into d2 and idx, nearest first), their mean and covariance summed one neighbour at a time in
// that order and divided by k; returns whether they lie on a line: the covariance's smaller eigenvalue
// at most min_planarity times the larger (floored at 1e-12) and k >= 3.
inline bool point_normal(const double* xy, const NeighbourBuckets& buckets, int64_t m, int64_t q, int64_t neighbours,
                         double min_planarity, double* out, std::vector<double>& d2, std::vector<int64_t>& idx) {
    const int64_t k = std::min(neighbours, m);
    buckets.nearest(q, k, d2, idx);
    const double kd = double(k);
    // centre = nb[:, 0] + nb[:, 1] + ..., then the deviations from centre / k
    double sx = xy[2 * idx[0]], sy = xy[2 * idx[0] + 1];
    for (int64_t i = 1; i < k; ++i) {
        sx += xy[2 * idx[size_t(i)]];
        sy += xy[2 * idx[size_t(i)] + 1];
    }
    const double mx = sx / kd, my = sy / kd;
    // products xx, xy, yy summed from +0 one neighbour at a time, then / k
    double cxx = 0.0, cxy = 0.0, cyy = 0.0;
    for (int64_t i = 0; i < k; ++i) {
        const double dx = xy[2 * idx[size_t(i)]] - mx, dy = xy[2 * idx[size_t(i)] + 1] - my;
        cxx += dx * dx;
        cxy += dx * dy;
        cyy += dy * dy;
    }
    cxx /= kd;
    cxy /= kd;
    cyy /= kd;
    const Eigen2 e = eigen_2x2(cxx, cxy, cyy);
    out[0] = e.nx;
    out[1] = e.ny;
    return e.small <= min_planarity * std::max(e.large, 1e-12) && k >= 3;
}

// The line normals of a point set, each computed at its first use (point_normal) and kept: the robust
// ICP asks for those of the map points it pairs with, a few hundred of the map's thousands. The same
// numbers as submap_normals_into for every point asked about.
class LineNormals {
  public:
    LineNormals(const double* xy, int64_t m, int64_t neighbours, double min_planarity)
        : xy_(xy, xy + 2 * m), m_(m), neighbours_(neighbours), min_planarity_(min_planarity), state_(size_t(m), -1),
          normals_(size_t(2 * m)) {}
    LineNormals(const LineNormals&) = delete;  // the buckets point into xy_
    LineNormals& operator=(const LineNormals&) = delete;

    // Whether point j is on a line; its unit normal into n (the normal is set either way).
    bool on_line(int64_t j, const double*& n) {
        int8_t& s = state_[size_t(j)];
        if (s < 0) {
            if (!buckets_) buckets_ = std::make_unique<NeighbourBuckets>(xy_.data(), m_);
            s = point_normal(xy_.data(), *buckets_, m_, j, neighbours_, min_planarity_, &normals_[size_t(2 * j)], d2_,
                             idx_) ? 1 : 0;
        }
        n = &normals_[size_t(2 * j)];
        return s == 1;
    }
    int64_t size() const { return m_; }
    int64_t computed() const { return int64_t(std::count_if(state_.begin(), state_.end(), [](int8_t s) { return s >= 0; })); }

  private:
    std::vector<double> xy_;
    int64_t m_, neighbours_;
    double min_planarity_;
    std::vector<int8_t> state_;  // -1: not yet computed, 0: no line, 1: a line
    std::vector<double> normals_;
    std::unique_ptr<NeighbourBuckets> buckets_;
    std::vector<double> d2_;
    std::vector<int64_t> idx_;
};

}  // namespace fmcwlog
