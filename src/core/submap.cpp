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
#include "normals.hpp"

namespace fmcwlog {
namespace {

using Normals = nb::ndarray<double, nb::shape<-1, 2>, nb::c_contig, nb::device::cpu>;
using Flags = nb::ndarray<bool, nb::ndim<1>, nb::c_contig, nb::device::cpu>;
using Near = nb::ndarray<int32_t, nb::ndim<2>, nb::c_contig, nb::device::cpu>;
using Reach = nb::ndarray<double, nb::ndim<2>, nb::c_contig, nb::device::cpu>;

}  // namespace

void submap_normals_into(const double* xy, int64_t m, int64_t neighbours, double min_planarity, double* out,
                         bool* flag, int32_t* near_out, double* reach_out) {
    if (m == 0) return;
    const int64_t k = std::min(neighbours, m);
    const NeighbourBuckets buckets(xy, m);
    std::vector<double> d2;
    std::vector<int64_t> idx;
    for (int64_t q = 0; q < m; ++q) {
        flag[q] = point_normal(xy, buckets, m, q, neighbours, min_planarity, out + 2 * q, d2, idx);
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
