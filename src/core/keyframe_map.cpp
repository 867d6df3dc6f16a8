// The local map's keyframe merge (fmcwlog/frontend/keyframe_map.py, KeyframeMap.add): the new
// keyframe's points and the kept old ones, one point per voxel, the newest keyframe's where two
// fall in one voxel, sorted by voxel key. The same keys, points and owners as the numpy code's
// np.unique(..., return_index=True) over [new keys, kept old keys], bit for bit.
#include <algorithm>
#include <utility>

#include <nanobind/stl/tuple.h>

#include "common.hpp"
#include "kernels.hpp"
#include "voxel.hpp"

namespace fmcwlog {
namespace {

using Keys = nb::ndarray<const int64_t, nb::shape<-1>, nb::c_contig, nb::device::cpu>;
using NumpyKeys = nb::ndarray<nb::numpy, int64_t, nb::shape<-1>>;
using NumpyPoints = nb::ndarray<nb::numpy, double, nb::shape<-1, 2>>;

template <class T>
nb::ndarray<nb::numpy, T> owned(T* data, std::initializer_list<size_t> shape) {
    nb::capsule owner(data, [](void* d) noexcept { delete[] static_cast<T*>(d); });
    return nb::ndarray<nb::numpy, T>(data, shape, owner);
}

// KeyframeMap.add's merge. xy (N, 2): the new keyframe's points (map, m); size: the voxel (m);
// old_keys (M,) strictly increasing, old_points (M, 2), old_owner (M,): the map as it stands;
// the old entries of owner < oldest leave; the new points are owned by ident. Returns
// (keys (K,), points (K, 2), owner (K,)), or None where old_keys is not strictly increasing
// (not a map this code made: the numpy code answers).
nb::object keyframe_map_merge(Points xy, double size, Keys old_keys, Points old_points, Keys old_owner,
                              int64_t oldest, int64_t ident) {
    const size_t n = xy.shape(0), m = old_keys.shape(0);
    if (old_points.shape(0) != m || old_owner.shape(0) != m) throw std::invalid_argument("old map arrays differ in length");
    const double* p = xy.data();
    const int64_t* ok = old_keys.data();
    const double* op = old_points.data();
    const int64_t* oo = old_owner.data();
    for (size_t j = 1; j < m; ++j)
        if (!(ok[j - 1] < ok[j])) return nb::none();
    std::vector<std::pair<int64_t, size_t>> fresh(n);  // (key, index), mirrors voxel_keys(xy, size)
    // written straight into the outputs, sized for the most the merge can keep
    int64_t* out_keys = new int64_t[n + m + 1];
    double* out_points = new double[2 * (n + m) + 1];
    int64_t* out_owner = new int64_t[n + m + 1];
    size_t k = 0;
    {
        nb::gil_scoped_release release;
        for (size_t i = 0; i < n; ++i) fresh[i] = {int64_t(voxel_key(p[2 * i], p[2 * i + 1], size)), i};
        // np.unique's stable sort: equal keys keep their order, the first is the one kept
        std::stable_sort(fresh.begin(), fresh.end(),
                         [](const auto& a, const auto& b) { return a.first < b.first; });
        auto take = [&](int64_t key, double x, double y, int64_t who) {
            out_keys[k] = key;
            out_points[2 * k] = x;
            out_points[2 * k + 1] = y;
            out_owner[k] = who;
            ++k;
        };
        size_t a = 0, b = 0;
        while (a < n || b < m) {
            if (b < m && oo[b] < oldest) {  // an old keyframe's point that leaves the map
                ++b;
                continue;
            }
            const bool old_first = a == n || (b < m && ok[b] < fresh[a].first);
            if (old_first) {
                take(ok[b], op[2 * b], op[2 * b + 1], oo[b]);
                ++b;
                continue;
            }
            const int64_t key = fresh[a].first;
            const size_t i = fresh[a].second;
            take(key, p[2 * i], p[2 * i + 1], ident);  // the new point wins its voxel: it comes first
            while (a < n && fresh[a].first == key) ++a;
            if (b < m && ok[b] == key) ++b;
        }
    }
    return nb::make_tuple(owned(out_keys, {k}), owned(out_points, {k, 2}), owned(out_owner, {k}));
}

}  // namespace

void bind_keyframe_map(nb::module_& m) {
    m.def("keyframe_map_merge", &keyframe_map_merge, nb::arg("xy"), nb::arg("size"), nb::arg("old_keys"),
          nb::arg("old_points"), nb::arg("old_owner"), nb::arg("oldest"), nb::arg("ident"));
}

}  // namespace fmcwlog
