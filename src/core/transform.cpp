// Rigid 2-D transform of a point set (fmcwlog/geometry.py, rotate_translate with one pose):
// out = R p + t as (c x - s y) + tx, (s x + c y) + ty, the numpy expression's operations in its
// order, each rounded (no FMA contraction: CMakeLists.txt), so the same bits.
#include "common.hpp"
#include "kernels.hpp"

namespace fmcwlog {
namespace {

nb::ndarray<nb::numpy, double, nb::shape<-1, 2>> rotate_translate(Points points, double c, double s, double tx,
                                                                 double ty) {
    const size_t n = points.shape(0);
    const double* p = points.data();
    double* out = new double[2 * n + 1];
    for (size_t i = 0; i < n; ++i) {
        const double x = p[2 * i], y = p[2 * i + 1];
        out[2 * i] = c * x - s * y + tx;
        out[2 * i + 1] = s * x + c * y + ty;
    }
    nb::capsule owner(out, [](void* d) noexcept { delete[] static_cast<double*>(d); });
    return nb::ndarray<nb::numpy, double, nb::shape<-1, 2>>(out, {n, 2}, owner);
}

}  // namespace

void bind_transform(nb::module_& m) {
    m.def("rotate_translate", &rotate_translate, nb::arg("points"), nb::arg("c"), nb::arg("s"), nb::arg("tx"),
          nb::arg("ty"));
}

}  // namespace fmcwlog
