// Voxel thinning (fmcwlog/kernels/voxel.py): the first point, in the order given, of each square
// voxel floor(xy / size) (voxel_downsample: exactly its points and order), or each voxel's centroid
// (voxel_centroids: the same sums in the same order, hence the same floats).
#include "common.hpp"
#include "kernels.hpp"
#include "voxel.hpp"

namespace fmcwlog {
namespace {

// voxel.voxel_downsample for size > 0 and N > 0: the kept points (M, 2), in the order given.
nb::ndarray<nb::numpy, double, nb::shape<-1, 2>> voxel_downsample(Points xy, double size) {
    std::vector<double> kept;
    {
        nb::gil_scoped_release release;
        kept = first_of_voxels(xy.data(), xy.shape(0), size);
    }
    return numpy_points(kept.data(), kept.size() / 2);
}

// voxel.voxel_centroids_numpy for size > 0 and N > 0: each voxel's mean (M, 2), in the order of
// its first point.
nb::ndarray<nb::numpy, double, nb::shape<-1, 2>> voxel_centroids(Points xy, double size) {
    std::vector<double> means;
    {
        nb::gil_scoped_release release;
        means = voxel_means(xy.data(), xy.shape(0), size);
    }
    return numpy_points(means.data(), means.size() / 2);
}

}  // namespace

void bind_voxel(nb::module_& m) {
    m.def("voxel_downsample", &voxel_downsample, nb::arg("xy"), nb::arg("size"));
    m.def("voxel_centroids", &voxel_centroids, nb::arg("xy"), nb::arg("size"));
}

}  // namespace fmcwlog
