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

// The terms of an arc turning by th (rad): a = sin th / th, b = (1 - cos th) / th (their series
// below 1e-4 rad: next terms < 1e-24 relative, exact at 0, no subnormal halving), and sin th, cos th,
// from one sincos of th / 2.
inline void arc_terms(double th, double& a, double& b, double& sth, double& cth) {
    const double sh = std::sin(0.5 * th), ch = std::cos(0.5 * th);
    if (std::fabs(th) < 1e-4) {
        const double t2 = th * th;
        a = 1.0 - t2 / 6.0 * (1.0 - t2 / 20.0);
        b = 0.5 * th * (1.0 - t2 / 12.0 * (1.0 - t2 / 30.0));
    } else {
        a = 2.0 * sh * ch / th;
        b = 2.0 * sh * sh / th;
    }
    sth = 2.0 * sh * ch;
    cth = 1.0 - 2.0 * sh * sh;
}

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
        double a, b, sth, cth;
        arc_terms(th, a, b, sth, cth);
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

// De-skewing by a piecewise-constant base_link twist (deskew_wheels.deskew_wheels_numpy): segment j
// starts at starts[j] (s after the stamp) from base_link's pose poses[j] (in base_link at the stamp)
// with the twist twists[j] = (v, omega). A point (x, y) seen in the lidar frame at ti goes to
// base_link at the stamp by B(ti) (+) L, B(ti) = poses[j] (+) exp((ti - starts[j]) (v, 0, omega)) for the
// last segment j with starts[j] <= ti (the first where ti is before it); L the mount. The same
// sinc forms as Deskewer; the compositions by the angle-sum formulas (one sincos a point).
struct WheelDeskewer {
    const double* starts;
    const double* twists;
    size_t k;
    double mx, my;
    std::vector<double> seg;  // per segment: x, y, cos, sin of poses[j]'s yaw, cos, sin of (its yaw + myaw)

    WheelDeskewer(const double* starts_, const double* poses, const double* twists_, size_t k_, double mx_,
                  double my_, double myaw)
        : starts(starts_), twists(twists_), k(k_), mx(mx_), my(my_), seg(6 * k_) {
        for (size_t j = 0; j < k; ++j) {
            const double yaw = poses[3 * j + 2];
            seg[6 * j] = poses[3 * j];
            seg[6 * j + 1] = poses[3 * j + 1];
            seg[6 * j + 2] = std::cos(yaw);
            seg[6 * j + 3] = std::sin(yaw);
            seg[6 * j + 4] = std::cos(yaw + myaw);
            seg[6 * j + 5] = std::sin(yaw + myaw);
        }
    }

    void operator()(double x, double y, double ti, double& ox, double& oy) const {
        size_t j = static_cast<size_t>(std::upper_bound(starts, starts + k, ti) - starts);  // searchsorted right
        j = j == 0 ? 0 : j - 1;
        const double v = twists[2 * j], omega = twists[2 * j + 1];
        const double dt = ti - starts[j];
        const double th = omega * dt;
        double a, b, sth, cth;
        arc_terms(th, a, b, sth, cth);
        const double bx = a * v * dt, by = b * v * dt;  // the arc over dt in the segment's start frame
        const double* g = &seg[6 * j];
        // B = poses[j] (+) arc: translation, and the rotation of its yaw (+ th)
        const double px = g[0] + g[2] * bx - g[3] * by, py = g[1] + g[3] * bx + g[2] * by;
        const double cb = g[2] * cth - g[3] * sth, sb = g[3] * cth + g[2] * sth;
        // B (+) L: the lidar's position, and its rotation (yaw + th + myaw)
        const double lx = px + cb * mx - sb * my, ly = py + sb * mx + cb * my;
        const double cl = g[4] * cth - g[5] * sth, sl = g[5] * cth + g[4] * sth;
        ox = cl * x - sl * y + lx;
        oy = sl * x + cl * y + ly;
    }
};

}  // namespace fmcwlog
