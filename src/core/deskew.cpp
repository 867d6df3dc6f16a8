// De-skewing of one sweep under a constant base_link twist (fmcwlog/frontend/deskew.py deskew, its
// column path _lidar_motion_columns + geometry.rotate_translate).
//
// Each point i, seen in the lidar frame at t_i, goes to the lidar frame at t_ref through the lidar's
// pose P_i = L^-1 (+) exp(dt_i xi) (+) L (L the mount in base_link, xi = (v, v_y, omega)). The
// arithmetic is the same formulas, arranged with one sincos a point instead of numpy's three sin/cos
// pairs: with th = omega dt and (sh, ch) = (sin th/2, cos th/2),
//   sin th / th = 2 sh ch / th,  (1 - cos th) / th = 2 sh^2 / th  (se2_exp's sinc forms; their
//   Taylor series for |th| < 1e-4),
//   P_i's yaw is th (L's rotations cancel; numpy wraps it twice, which moves neither sin nor cos),
//   cos(ith + th), sin(ith + th) by the angle-sum formulas.
// The results agree with numpy's to rounding (~1e-15 m on metre-scale points), not bit for bit.
// deskew_placed also places the de-skewed points by one rigid transform (deskew.deskew_placed);
// deskew_source is the front end's source cloud in one call (deskew.deskewed_source): the mask of
// the points used, those de-skewed and placed, their voxel thinning and their Doppler velocities.
// The de-skewing (Deskewer) is in deskew.hpp, the thinning in voxel.hpp.
#include "common.hpp"
#include "deskew.hpp"
#include "kernels.hpp"
#include "voxel.hpp"

#include <nanobind/stl/optional.h>
#include <nanobind/stl/tuple.h>

#include <optional>
#include <string>

namespace fmcwlog {
namespace {

using Times = nb::ndarray<const double, nb::shape<-1>, nb::c_contig, nb::device::cpu>;
using Mask = nb::ndarray<const bool, nb::shape<-1>, nb::c_contig, nb::device::cpu>;


// deskew.deskew on its column path: xy (N, 2) seen at t (N,) s, to the lidar frame at t_ref; twist
// (v, v_y) m/s and omega rad/s of base_link; mount (mx, my, myaw) the lidar in base_link (m, rad).
void deskew(Points xy, Times t, double t_ref, double v, double v_y, double omega, double mx, double my,
            double myaw, OutPoints out) {
    const size_t n = xy.shape(0);
    if (t.shape(0) != n || out.shape(0) != n) throw nb::value_error("deskew: xy, t and out differ in length");
    const double* p = xy.data();
    const double* tt = t.data();
    double* o = out.data();
    nb::gil_scoped_release release;
    const Deskewer at(t_ref, v, v_y, omega, mx, my, myaw);
    for (size_t i = 0; i < n; ++i) at(p[2 * i], p[2 * i + 1], tt[i], o[2 * i], o[2 * i + 1]);
}

// deskew.deskew_placed: the points where keep (N,; None: all) is set, de-skewed as deskew does and then
// placed by one rigid transform (c, s the cosine and sine of its yaw; tx, ty m) as
// geometry.rotate_translate places them: (c x - s y) + tx, (s x + c y) + ty, each operation rounded in
// that order (the same bits as the two calls one after the other). Returns a new (K, 2) array.
nb::ndarray<nb::numpy, double, nb::shape<-1, 2>> deskew_placed(Points xy, Times t, std::optional<Mask> keep,
                                                              double t_ref, double v, double v_y, double omega,
                                                              double mx, double my, double myaw, double c,
                                                              double s, double tx, double ty) {
    const size_t n = xy.shape(0);
    if (t.shape(0) != n || (keep && keep->shape(0) != n))
        throw nb::value_error("deskew_placed: xy, t and keep differ in length");
    const double* p = xy.data();
    const double* tt = t.data();
    const bool* k = keep ? keep->data() : nullptr;
    size_t m = n;
    if (k) m = static_cast<size_t>(std::count(k, k + n, true));
    double* out = new double[2 * m + 1];
    {
        nb::gil_scoped_release release;
        const Deskewer at(t_ref, v, v_y, omega, mx, my, myaw);
        size_t j = 0;
        for (size_t i = 0; i < n; ++i) {
            if (k && !k[i]) continue;
            double dx, dy;
            at(p[2 * i], p[2 * i + 1], tt[i], dx, dy);
            out[2 * j] = c * dx - s * dy + tx;
            out[2 * j + 1] = s * dx + c * dy + ty;
            ++j;
        }
    }
    nb::capsule owner(out, [](void* d) noexcept { delete[] static_cast<double*>(d); });
    return nb::ndarray<nb::numpy, double, nb::shape<-1, 2>>(out, {m, 2}, owner);
}

// The front end's source cloud of a sweep (deskew.deskewed_source_numpy, deskew_wheels's twin):
// use = ~(near | moving) (moving None: ~near), written into use (N,); the used points moved by
// place(x, y, t, ox, oy) (pts (K, 2)); pts thinned by voxel_size as voxel.voxel_downsample (centroid
// false) or voxel.voxel_centroids (centroid true) thin them (pts itself where voxel_size <= 0 or
// K == 0); the used points' velocities (K,) where velocity is given. Returns (pts, source,
// velocities or None).
template <class Place>
nb::tuple source_cloud(const char* name, Points xy, Times t, Mask near, std::optional<Mask> moving,
                       std::optional<Times> velocity, double voxel_size, bool centroid,
                       nb::ndarray<bool, nb::shape<-1>, nb::c_contig, nb::device::cpu> use, const Place& place) {
    const size_t n = xy.shape(0);
    if (t.shape(0) != n || near.shape(0) != n || use.shape(0) != n || (moving && moving->shape(0) != n) ||
        (velocity && velocity->shape(0) != n))
        throw nb::value_error((std::string(name) + ": xy, t, near, moving, velocity and use differ in length").c_str());
    const double* p = xy.data();
    const double* tt = t.data();
    const bool* nr = near.data();
    const bool* mv = moving ? moving->data() : nullptr;
    const double* vel = velocity ? velocity->data() : nullptr;
    bool* u = use.data();
    std::vector<double> pts, thinned, speeds;
    {
        nb::gil_scoped_release release;
        pts.reserve(2 * n);
        if (vel) speeds.reserve(n);
        for (size_t i = 0; i < n; ++i) {
            u[i] = !(nr[i] || (mv && mv[i]));
            if (!u[i]) continue;
            double ox, oy;
            place(p[2 * i], p[2 * i + 1], tt[i], ox, oy);
            pts.push_back(ox);
            pts.push_back(oy);
            if (vel) speeds.push_back(vel[i]);
        }
        const size_t k = pts.size() / 2;
        if (voxel_size > 0.0 && k > 0)
            thinned = centroid ? voxel_means(pts.data(), k, voxel_size) : first_of_voxels(pts.data(), k, voxel_size);
    }
    const size_t k = pts.size() / 2;
    nb::object placed = nb::cast(numpy_points(pts.data(), k));
    nb::object source = voxel_size > 0.0 && k > 0 ? nb::cast(numpy_points(thinned.data(), thinned.size() / 2)) : placed;
    nb::object kept_velocity = nb::none();
    if (vel) {
        double* out = new double[k + 1];
        std::copy(speeds.begin(), speeds.end(), out);
        nb::capsule owner(out, [](void* q) noexcept { delete[] static_cast<double*>(q); });
        kept_velocity = nb::cast(nb::ndarray<nb::numpy, double, nb::shape<-1>>(out, {k}, owner));
    }
    return nb::make_tuple(placed, source, kept_velocity);
}

// deskew.deskewed_source_numpy: source_cloud with each point de-skewed under the constant twist (v, omega)
// and placed by (c, s, tx, ty) as deskew_placed places them.
nb::tuple deskew_source(Points xy, Times t, Mask near, std::optional<Mask> moving, std::optional<Times> velocity,
                        double v, double omega, double mx, double my, double myaw, double c, double s, double tx,
                        double ty, double voxel_size, bool centroid,
                        nb::ndarray<bool, nb::shape<-1>, nb::c_contig, nb::device::cpu> use) {
    const Deskewer at(0.0, v, 0.0, omega, mx, my, myaw);
    return source_cloud("deskew_source", xy, t, near, moving, velocity, voxel_size, centroid, use,
                        [&](double x, double y, double ti, double& ox, double& oy) {
                            double dx, dy;
                            at(x, y, ti, dx, dy);
                            ox = c * dx - s * dy + tx;
                            oy = s * dx + c * dy + ty;
                        });
}

using Rows = nb::ndarray<const double, nb::ndim<2>, nb::c_contig, nb::device::cpu>;

// deskew_wheels.deskewed_source_wheels_numpy: source_cloud with each point placed in base_link at the
// stamp by B(t) (+) L (WheelDeskewer; starts (K,), poses (K, 3), twists (K, 2) the profile).
nb::tuple deskew_source_wheels(Points xy, Times t, Mask near, std::optional<Mask> moving,
                               std::optional<Times> velocity, Times starts, Rows poses, Rows twists, double mx,
                               double my, double myaw, double voxel_size, bool centroid,
                               nb::ndarray<bool, nb::shape<-1>, nb::c_contig, nb::device::cpu> use) {
    const size_t k = starts.shape(0);
    if (k == 0 || poses.shape(0) != k || poses.shape(1) != 3 || twists.shape(0) != k || twists.shape(1) != 2)
        throw nb::value_error("deskew_source_wheels: starts (K,), poses (K, 3) and twists (K, 2) with K >= 1");
    const WheelDeskewer at(starts.data(), poses.data(), twists.data(), k, mx, my, myaw);
    return source_cloud("deskew_source_wheels", xy, t, near, moving, velocity, voxel_size, centroid, use, at);
}

}  // namespace

void bind_deskew(nb::module_& m) {
    m.def("deskew", &deskew, nb::arg("xy"), nb::arg("t"), nb::arg("t_ref"), nb::arg("v"), nb::arg("v_y"),
          nb::arg("omega"), nb::arg("mx"), nb::arg("my"), nb::arg("myaw"), nb::arg("out"));
    m.def("deskew_placed", &deskew_placed, nb::arg("xy"), nb::arg("t"), nb::arg("keep").none(), nb::arg("t_ref"),
          nb::arg("v"), nb::arg("v_y"), nb::arg("omega"), nb::arg("mx"), nb::arg("my"), nb::arg("myaw"), nb::arg("c"),
          nb::arg("s"), nb::arg("tx"), nb::arg("ty"));
    m.def("deskew_source", &deskew_source, nb::arg("xy"), nb::arg("t"), nb::arg("near"), nb::arg("moving").none(),
          nb::arg("velocity").none(), nb::arg("v"), nb::arg("omega"), nb::arg("mx"), nb::arg("my"), nb::arg("myaw"),
          nb::arg("c"), nb::arg("s"), nb::arg("tx"), nb::arg("ty"), nb::arg("voxel_size"), nb::arg("centroid"),
          nb::arg("use"));
    m.def("deskew_source_wheels", &deskew_source_wheels, nb::arg("xy"), nb::arg("t"), nb::arg("near"),
          nb::arg("moving").none(), nb::arg("velocity").none(), nb::arg("starts"), nb::arg("poses"),
          nb::arg("twists"), nb::arg("mx"), nb::arg("my"), nb::arg("myaw"), nb::arg("voxel_size"),
          nb::arg("centroid"), nb::arg("use"));
}

}  // namespace fmcwlog
