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
// Shared by deskew.cpp's kernels and the fused ones that de-skew on the way (deskew_source).
#pragma once

#include "common.hpp"

namespace fmcwlog {

// Lidar-to-reference motion of a sweep (the loop-invariant part of deskew.deskew's column path):
// L^-1 = (ix, iy, ith) and its rotation's (ci, si), for the mount (mx, my, myaw).
struct Deskewer {
    double t_ref, v, v_y, omega, mx, my, ix, iy, ci, si;

    Deskewer(double t_ref_, double v_, double v_y_, double omega_, double mx_, double my_, double myaw)
        : t_ref(t_ref_), v(v_), v_y(v_y_), omega(omega_), mx(mx_), my(my_) {
        // geometry.inverse(mount)
        const double cm = std::cos(myaw), sm = std::sin(myaw);
        ix = -cm * mx - sm * my;
        iy = sm * mx - cm * my;
        const double ith = wrap_angle(-myaw);
        ci = std::cos(ith);
        si = std::sin(ith);
    }

    // The point (x, y) seen at time ti, in the lidar frame at t_ref: (ox, oy).
    void operator()(double x, double y, double ti, double& ox, double& oy) const {
        const double dt = ti - t_ref;
        const double th = omega * dt;
        const double sh = std::sin(0.5 * th), ch = std::cos(0.5 * th);
        double a, b;  // sin th / th and (1 - cos th) / th
        if (std::fabs(th) < 1e-4) {  // their series (next terms < 1e-24 relative): exact at 0, no subnormal halving
            const double t2 = th * th;
            a = 1.0 - t2 / 6.0 * (1.0 - t2 / 20.0);
            b = 0.5 * th * (1.0 - t2 / 12.0 * (1.0 - t2 / 30.0));
        } else {
            a = 2.0 * sh * ch / th;
            b = 2.0 * sh * sh / th;
        }
        const double sth = 2.0 * sh * ch, cth = 1.0 - 2.0 * sh * sh;
        // se2_exp: the base's displacement over dt
        const double bx = (a * v - b * v_y) * dt, by = (b * v + a * v_y) * dt;
        // compose(L^-1, base): translation ix + R(ith) b, yaw ith + th
        const double px = ix + ci * bx - si * by, py = iy + si * bx + ci * by;
        const double c2 = ci * cth - si * sth, s2 = si * cth + ci * sth;
        // compose(that, L): translation p + R(ith + th) m
        const double qx = c2 * mx + px - s2 * my, qy = s2 * mx + py + c2 * my;
        // rotate_translate: R(th) p_i + q
        ox = cth * x - sth * y + qx;
        oy = sth * x + cth * y + qy;
    }
};

}  // namespace fmcwlog
