// The back end's point-to-line ICP (fmcwlog/backend/registration.py: register_point_to_line and
// _system): Gauss-Newton with Cauchy weights, each source point paired with its nearest submap
// point within the gate (the TargetGrid's answer, the KD-tree's pair), where that point has a normal.
// The sums of J^T W J and J^T W r run in point order (numpy's BLAS may order them otherwise: the
// poses agree to rounding, ~1e-12).
#include <nanobind/stl/array.h>
#include <nanobind/stl/optional.h>
#include <nanobind/stl/tuple.h>
#include <nanobind/stl/vector.h>

#include <array>
#include <optional>

#include "common.hpp"
#include "kernels.hpp"
#include "line_icp.hpp"

namespace fmcwlog {
namespace {

using Flags = nb::ndarray<const bool, nb::ndim<1>, nb::c_contig, nb::device::cpu>;

struct System {
    std::vector<double> r, j0, j1, j2, w;
    void clear() {
        r.clear();
        j0.clear();
        j1.clear();
        j2.clear();
        w.clear();
    }
};

using Near = nb::ndarray<const int32_t, nb::ndim<2>, nb::c_contig, nb::device::cpu>;
using Reach = nb::ndarray<const double, nb::ndim<2>, nb::c_contig, nb::device::cpu>;

// The pairing: each source point's nearest submap point within the gate, the TargetGrid's answer
// (equal squared distances to the lowest index), asked of the grid only where the point's pair of
// the pass before cannot tell it. The submap's neighbour table (submap_normals) lists each point
// t's k nearest, nearest first, and distances reach_j(t) that every point but the first j lies at or
// beyond. A source point at q whose last pair was t has every such point u at |q - u| >=
// |t - u| - |q - t| >= reach_j(t) - |q - t|; so the nearest of t and its first j neighbours, where
// nearer than that, is the nearest of all, and where that bound is past the gate no other point
// pairs. The neighbours are taken one at a time until that holds (most often after one or two); a
// margin covers the rounding.
class Pairing {
  public:
    Pairing(const TargetGrid& grid, const int32_t* near, int64_t k, const double* reach, size_t n)
        : grid_(grid), near_(near), k_(k), reach_(reach), gate_(grid.radius()), last_(n, -1) {}

    // The pair of source point i, now at (qx, qy): the index grid.nearest gives, or -1.
    int64_t operator()(size_t i, double qx, double qy) {
        const int64_t t = last_[i];
        if (near_ != nullptr && t >= 0 && std::isfinite(qx) && std::isfinite(qy)) {
            const int64_t a = from_neighbours(t, qx, qy);
            if (a != kAsk) return last_[i] = a;
        }
        double d;
        return last_[i] = grid_.nearest(qx, qy, d);
    }

  private:
    static constexpr int64_t kAsk = -2;

    double d2(int64_t u, double qx, double qy) const {  // the grid's arithmetic: target - query
        const double dx = grid_.x(u) - qx, dy = grid_.y(u) - qy;
        return dx * dx + dy * dy;
    }

    int64_t from_neighbours(int64_t t, double qx, double qy) const {
        double best = d2(t, qx, qy);
        int64_t bi = t;
        const double lever = std::sqrt(best) + 1e-9 * (1.0 + std::fabs(qx) + std::fabs(qy));  // |q - t| and the margin
        const int32_t* nb = near_ + t * k_;
        const double* reach = reach_ + t * (k_ + 1);
        for (int64_t j = 0;; ++j) {
            const double others = reach[j] - lever;  // every point but t and the first j neighbours
            if (others > 0.0 && best < others * others) return std::sqrt(best) < gate_ ? bi : -1;  // the grid's gate
            if (gate_ <= others) return -1;  // the nearest of those, and all others, at or past the gate
            if (j == k_ || nb[j] < 0) return kAsk;
            const int64_t u = nb[j];
            const double d = d2(u, qx, qy);
            if (d < best || (d == best && u < bi)) {
                best = d;
                bi = u;
            }
        }
    }

    const TargetGrid& grid_;
    const int32_t* near_;
    int64_t k_;
    const double* reach_;
    double gate_;
    std::vector<int64_t> last_;  // each source point's pair of the pass before (-1: none yet, or none)
};

// _system: the residuals, Jacobian rows and Cauchy weights of the pairs at ``pose``.
void build_system(const TargetGrid& grid, Pairing& pairing, const double* s, size_t n, const double* normals,
                  const bool* has_normal, const Vec3& pose, double c, System& out) {
    out.clear();
    const double cs = std::cos(pose[2]), sn = std::sin(pose[2]);
    for (size_t i = 0; i < n; ++i) {
        const double x = s[2 * i], y = s[2 * i + 1];
        // NearestPairs._moved: c x + (-s) y + t_x, c y + s x + t_y
        const double mx = (x * cs + y * (-sn)) + pose[0];
        const double my = (y * cs + x * sn) + pose[1];
        const int64_t k = pairing(i, mx, my);
        if (k < 0 || !has_normal[k]) continue;
        const double nx = normals[2 * k], ny = normals[2 * k + 1];
        const double dx = mx - grid.x(k), dy = my - grid.y(k);
        const double r = nx * dx + ny * dy;
        const double rpx = mx - pose[0], rpy = my - pose[1];
        out.r.push_back(r);
        out.j0.push_back(nx);
        out.j1.push_back(ny);
        out.j2.push_back(nx * -rpy + ny * rpx);
        const double q = r / c;
        out.w.push_back(1.0 / (1.0 + q * q));
    }
}

// J^T W J (row major) and J^T W r.
void normal_equations(const System& sys, Mat3& h, Vec3& g) {
    h.fill(0.0);
    g.fill(0.0);
    for (size_t k = 0; k < sys.r.size(); ++k) {
        const double j[3] = {sys.j0[k], sys.j1[k], sys.j2[k]};
        for (int a = 0; a < 3; ++a) {
            const double jw = j[a] * sys.w[k];
            for (int b = 0; b < 3; ++b) h[size_t(3 * a + b)] += jw * j[b];
            g[size_t(a)] += jw * sys.r[k];
        }
    }
}

}  // namespace

// LAPACK's dgesv on 3 x 3: LU with partial pivoting (the first largest |pivot|); false where a pivot is 0.
bool solve3(Mat3 a, Vec3 b, Vec3& x) {
    for (int col = 0; col < 3; ++col) {
        int piv = col;
        for (int row = col + 1; row < 3; ++row)
            if (std::abs(a[size_t(3 * row + col)]) > std::abs(a[size_t(3 * piv + col)])) piv = row;
        if (a[size_t(3 * piv + col)] == 0.0) return false;
        if (piv != col) {
            for (int k = 0; k < 3; ++k) std::swap(a[size_t(3 * col + k)], a[size_t(3 * piv + k)]);
            std::swap(b[size_t(col)], b[size_t(piv)]);
        }
        for (int row = col + 1; row < 3; ++row) {
            const double f = a[size_t(3 * row + col)] / a[size_t(3 * col + col)];
            for (int k = col; k < 3; ++k) a[size_t(3 * row + k)] -= f * a[size_t(3 * col + k)];
            b[size_t(row)] -= f * b[size_t(col)];
        }
    }
    for (int row = 2; row >= 0; --row) {
        double v = b[size_t(row)];
        for (int k = row + 1; k < 3; ++k) v -= a[size_t(3 * row + k)] * x[size_t(k)];
        x[size_t(row)] = v / a[size_t(3 * row + row)];
    }
    return true;
}

// The iterations of line_icp (registration.register_point_to_line), on raw arrays: normals (M, 2) and
// has_normal (M,) the grid's points' rows; s (n, 2) the source; the prior held where both pointers are
// given; near (M, k) / reach (M, k + 1) the submap's neighbour table or null.
LineIcpRun run_line_icp(const TargetGrid& grid, const double* normals, const bool* has_normal, const double* s,
                        size_t n, Vec3 pose, int max_iterations, double kernel_scale, double tolerance,
                        const Vec3* prior_pose, const Mat3* prior_info, const int32_t* near, int64_t k,
                        const double* reach) {
    bool converged = false;
    int it = 0;
    System sys;
    Pairing pairing(grid, near, k, reach, n);
    Mat3 h;
    Vec3 g;
    for (it = 1; it <= max_iterations; ++it) {
        build_system(grid, pairing, s, n, normals, has_normal, pose, kernel_scale, sys);
        if (sys.r.size() < 3) break;
        normal_equations(sys, h, g);
        if (prior_pose && prior_info) {
            Vec3 dp{pose[0] - (*prior_pose)[0], pose[1] - (*prior_pose)[1], pose[2] - (*prior_pose)[2]};
            dp[2] = wrap_angle(dp[2]);
            for (int a = 0; a < 3; ++a) {
                double add = 0.0;
                for (int b = 0; b < 3; ++b) add += (*prior_info)[size_t(3 * a + b)] * dp[size_t(b)];
                g[size_t(a)] += add;
            }
            for (size_t q = 0; q < 9; ++q) h[q] += (*prior_info)[q];
        }
        Mat3 damped = h;
        for (int a = 0; a < 3; ++a) damped[size_t(4 * a)] += 1e-9;  // registration._DAMPING
        Vec3 step;
        if (!solve3(damped, g, step)) break;
        const Vec3 delta{-step[0], -step[1], -step[2]};
        pose = {pose[0] + delta[0], pose[1] + delta[1], wrap_angle(pose[2] + delta[2])};
        if (std::hypot(delta[0], delta[1]) < tolerance && std::abs(delta[2]) < tolerance) {
            converged = true;
            break;
        }
    }
    if (it > max_iterations) it = max_iterations;
    build_system(grid, pairing, s, n, normals, has_normal, pose, kernel_scale, sys);
    normal_equations(sys, h, g);
    return {pose, h, std::move(sys.r), it, converged};
}

namespace {

using Residuals = nb::ndarray<nb::numpy, double, nb::ndim<1>>;
using Result = std::tuple<Vec3, Mat3, Residuals, int64_t, int, bool>;

// The residuals handed to numpy as they are (no list of floats between).
Residuals to_numpy(std::vector<double>&& r) {
    if (r.empty()) r.reserve(1);
    auto* kept = new std::vector<double>(std::move(r));
    nb::capsule owner(kept, [](void* v) noexcept { delete static_cast<std::vector<double>*>(v); });
    return Residuals(kept->data(), {kept->size()}, owner);
}

// register_point_to_line, whole: (pose, hessian at it (row major), residuals (an array), pairs, iterations,
// converged).
Result line_icp(const TargetGrid& grid, Points normals, Flags has_normal, Points source, double x, double y,
                double theta, int max_iterations, double kernel_scale, double tolerance, std::optional<Vec3> prior_pose,
                std::optional<Mat3> prior_info, std::optional<Near> near, std::optional<Reach> reach) {
    if (normals.shape(0) != has_normal.shape(0)) throw nb::value_error("one normal flag per normal");
    if (near.has_value() != reach.has_value()) throw nb::value_error("near and reach together");
    if (near && (near->shape(0) != normals.shape(0) || reach->shape(0) != normals.shape(0)))
        throw nb::value_error("near (M, k) and reach (M, k + 1): one row per submap point");
    if (near && reach->shape(1) != near->shape(1) + 1) throw nb::value_error("reach (M, k + 1)");
    if (near) {  // indices the grid has (its points are the normals' rows)
        const int32_t* v = near->data();
        for (size_t i = 0; i < near->size(); ++i)
            if (v[i] < -1 || int64_t(v[i]) >= int64_t(normals.shape(0))) throw nb::value_error("near: an index past M");
    }
    const bool held = prior_pose && prior_info;
    LineIcpRun run;
    {
        nb::gil_scoped_release release;
        run = run_line_icp(grid, normals.data(), has_normal.data(), source.data(), source.shape(0), Vec3{x, y, theta},
                           max_iterations, kernel_scale, tolerance, held ? &*prior_pose : nullptr,
                           held ? &*prior_info : nullptr, near ? near->data() : nullptr,
                           near ? int64_t(near->shape(1)) : 0, reach ? reach->data() : nullptr);
    }
    const int64_t pairs = int64_t(run.r.size());
    return {run.pose, run.h, to_numpy(std::move(run.r)), pairs, run.iterations, run.converged};
}

}  // namespace

void bind_line_icp(nb::module_& m) {
    m.def("line_icp", &line_icp, nb::arg("grid"), nb::arg("normals"), nb::arg("has_normal"), nb::arg("source"),
          nb::arg("x"), nb::arg("y"), nb::arg("theta"), nb::arg("max_iterations"), nb::arg("kernel_scale"),
          nb::arg("tolerance"), nb::arg("prior_pose").none(), nb::arg("prior_info").none(), nb::arg("near").none() = nb::none(),
          nb::arg("reach").none() = nb::none());
}

}  // namespace fmcwlog
