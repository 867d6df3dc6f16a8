// The back end's submap normals (fmcwlog/backend/registration.py: build_submap): each point's
// ``k`` nearest points (itself among them), their mean and covariance summed one neighbour at a
// time in order of distance, as the reference sums them, and the covariance's smaller eigenvector
// as the normal (LAPACK's dlaev2, the 2 x 2 step of the eigh numpy calls; the normals agree with
// numpy's to rounding, up to their sign, which no use of a normal sees).
//
// The neighbours are those of the KD-tree query (squared distances dx^2 + dy^2, nearest first;
// equal distances by index here, where the tree may order them otherwise: the same set but for a
// tie at the k-th place, which only duplicated points make).
#include <nanobind/stl/optional.h>
#include <nanobind/stl/tuple.h>

#include <cmath>

#include "common.hpp"
#include "kernels.hpp"
#include "line_icp.hpp"

namespace fmcwlog {
namespace {

using Normals = nb::ndarray<double, nb::shape<-1, 2>, nb::c_contig, nb::device::cpu>;
using Flags = nb::ndarray<bool, nb::ndim<1>, nb::c_contig, nb::device::cpu>;
using Near = nb::ndarray<int32_t, nb::ndim<2>, nb::c_contig, nb::device::cpu>;
using Reach = nb::ndarray<double, nb::ndim<2>, nb::c_contig, nb::device::cpu>;

// The points bucketed by a uniform grid of square cells (index order within a cell).
class Buckets {
  public:
    Buckets(const double* xy, int64_t m) : xy_(xy) {
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
Eigen2 eigen_2x2(double a, double b, double c) {
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

}  // namespace

void submap_normals_into(const double* xy, int64_t m, int64_t neighbours, double min_planarity, double* out,
                         bool* flag, int32_t* near_out, double* reach_out) {
    if (m == 0) return;
    const int64_t k = std::min(neighbours, m);
    const Buckets buckets(xy, m);
    std::vector<double> d2;
    std::vector<int64_t> idx;
    const double kd = double(k);
    for (int64_t q = 0; q < m; ++q) {
        buckets.nearest(q, k, d2, idx);
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
        out[2 * q] = e.nx;
        out[2 * q + 1] = e.ny;
        flag[q] = e.small <= min_planarity * std::max(e.large, 1e-12) && k >= 3;
        if (near_out) {
            const double last = k == m ? kInf : std::sqrt(d2[size_t(k - 1)]);  // beyond the k
            for (int64_t i = 0; i < neighbours; ++i) {
                near_out[q * neighbours + i] = i < k ? int32_t(idx[size_t(i)]) : -1;
                reach_out[q * (neighbours + 1) + i] = i < k ? std::sqrt(d2[size_t(i)]) : last;
            }
            reach_out[q * (neighbours + 1) + neighbours] = last;
        }
    }
}

namespace {

// build_submap's normals: ``points`` (M, 2); ``normals`` (M, 2) and ``has_normal`` (M,) are filled.
// Where given, ``near`` (M, neighbours) gets each point's neighbours (the k nearest, itself among
// them, nearest first; -1 past k = min(neighbours, M)) and ``reach`` (M, neighbours + 1) distances
// (m): every point but the first j of its row lies at or beyond reach[j] (the j-th neighbour's
// distance; past k, the k-th's, or inf where the k are all M points). The line ICP's pairing
// (line_icp.cpp) answers from them where it can.
void submap_normals(Points points, int64_t neighbours, double min_planarity, Normals normals, Flags has_normal,
                    std::optional<Near> near, std::optional<Reach> reach) {
    const int64_t m = int64_t(points.shape(0));
    if (int64_t(normals.shape(0)) != m || int64_t(has_normal.shape(0)) != m) throw nb::value_error("outputs of M rows");
    if (near.has_value() != reach.has_value()) throw nb::value_error("near and reach together");
    if (near && (int64_t(near->shape(0)) != m || int64_t(near->shape(1)) != neighbours || int64_t(reach->shape(0)) != m ||
                 int64_t(reach->shape(1)) != neighbours + 1))
        throw nb::value_error("near (M, neighbours) and reach (M, neighbours + 1)");
    if (m == 0) return;
    if (neighbours < 1) throw nb::value_error("neighbours >= 1");
    int32_t* near_out = near ? near->data() : nullptr;
    double* reach_out = reach ? reach->data() : nullptr;
    nb::gil_scoped_release release;
    submap_normals_into(points.data(), m, neighbours, min_planarity, normals.data(), has_normal.data(), near_out,
                        reach_out);
}

}  // namespace

void bind_submap(nb::module_& m) {
    m.def("submap_normals", &submap_normals, nb::arg("points"), nb::arg("neighbours"), nb::arg("min_planarity"),
          nb::arg("normals"), nb::arg("has_normal"), nb::arg("near").none() = nb::none(),
          nb::arg("reach").none() = nb::none());
}

}  // namespace fmcwlog
