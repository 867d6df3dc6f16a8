// The baseline's point-to-point ICP (fmcwlog/frontend/point_to_point_icp.py) and the nearest
// target of every source point under a pose (fmcwlog/kernels/nearest.py).
#include <nanobind/stl/tuple.h>

#include "common.hpp"
#include "kernels.hpp"

namespace fmcwlog {
namespace {

struct Pairs {
    std::vector<int64_t> src;
    std::vector<double> tx, ty, dist;
    void clear() {
        src.clear();
        tx.clear();
        ty.clear();
        dist.clear();
    }
};

// The pairs within the grid's radius under a pose (NearestPairs.pairs of the reference).
void find_pairs(const TargetGrid& grid, const double* s, size_t n, double px, double py, double th,
                std::vector<TargetGrid::Memo>& memo, Pairs& out) {
    out.clear();
    const double c = std::cos(th), sn = std::sin(th);
    for (size_t i = 0; i < n; ++i) {
        const double x = s[2 * i], y = s[2 * i + 1];
        const double mx = c * x + (-sn) * y + px;
        const double my = c * y + sn * x + py;
        double d, at[2];
        const int64_t j = grid.nearest(mx, my, d, at, memo[i]);
        if (j < 0) continue;
        out.src.push_back(int64_t(i));
        out.tx.push_back(at[0]);
        out.ty.push_back(at[1]);
        out.dist.push_back(d);
    }
}

// Least-squares pose for the pairs (2-D Kabsch; point_to_point_icp.closed_form_pose).
void closed_form_pose(const double* s, const Pairs& p, double pose[3]) {
    const size_t n = p.src.size();
    double spx = 0, spy = 0, sqx = 0, sqy = 0;
    for (size_t k = 0; k < n; ++k) {
        const size_t i = size_t(p.src[k]);
        spx += s[2 * i];
        spy += s[2 * i + 1];
        sqx += p.tx[k];
        sqy += p.ty[k];
    }
    const double pcx = spx / double(n), pcy = spy / double(n), qcx = sqx / double(n), qcy = sqy / double(n);
    double cross = 0, dot = 0;
    for (size_t k = 0; k < n; ++k) {
        const size_t i = size_t(p.src[k]);
        const double ax = s[2 * i] - pcx, ay = s[2 * i + 1] - pcy;
        const double bx = p.tx[k] - qcx, by = p.ty[k] - qcy;
        cross += ax * by - ay * bx;
        dot += ax * bx + ay * by;
    }
    const double th = std::atan2(cross, dot);
    const double c = std::cos(th), sn = std::sin(th);
    pose[0] = qcx - (c * pcx - sn * pcy);
    pose[1] = qcy - (sn * pcx + c * pcy);
    pose[2] = th;
}

using Pose = std::tuple<double, double, double>;
using Hessian = std::tuple<double, double, double, double, double>;  // h00 h02 h11 h12 h22 (h01 = 0)

// The baseline's point-to-point ICP (point_to_point_icp.register_point_to_point), whole: the
// pairs on the target's grid and a closed-form pose each iteration, the information matrix
// of the last pairs at the final pose; the gate is the grid's radius. inlier_distance (m, at most the
// grid's radius): also count the source points within it of the target at the final pose
// (recovery.inlier_fraction's count; not counted where it is not > 0). Returns (pose, iterations,
// pairs kept, converged, rmse, hessian terms, the inlier count or -1).
std::tuple<Pose, int, int64_t, bool, double, Hessian, int64_t> point_to_point_icp(
    const TargetGrid& grid, Points source, double x, double y, double theta, int max_iterations,
    double translation_tol, double rotation_tol, int64_t min_correspondences, double inlier_distance) {
    const double* s = source.data();
    const size_t n = source.shape(0);
    double pose[3] = {x, y, theta};
    Pairs pairs, used;
    int iterations = 0;
    bool converged = false;
    int64_t inliers = -1;
    {
        nb::gil_scoped_release release;
        std::vector<TargetGrid::Memo> memo(n);  // each source point's last search, for the next iteration's
        for (iterations = 1; iterations <= max_iterations; ++iterations) {
            find_pairs(grid, s, n, pose[0], pose[1], pose[2], memo, pairs);
            if (int64_t(pairs.src.size()) < min_correspondences) break;
            double fresh[3];
            closed_form_pose(s, pairs, fresh);
            const double sx = fresh[0] - pose[0], sy = fresh[1] - pose[1];
            const double st = wrap_angle(fresh[2] - pose[2]);
            pose[0] = fresh[0];
            pose[1] = fresh[1];
            pose[2] = fresh[2];
            std::swap(used, pairs);
            if (std::hypot(sx, sy) < translation_tol && std::fabs(st) < rotation_tol) {
                converged = true;
                break;
            }
        }
        if (iterations > max_iterations) iterations = max_iterations;
        if (inlier_distance > 0.0) inliers = count_within(grid, s, n, pose[0], pose[1], pose[2], inlier_distance, &memo);
    }
    const size_t k = used.src.size();
    double rmse = std::numeric_limits<double>::quiet_NaN();
    Hessian h{0, 0, 0, 0, 0};
    if (k) {
        double sq = 0;
        for (double d : used.dist) sq += d * d;
        rmse = std::sqrt(sq / double(k));
        // gauss_newton_step's H with unit weights: ax = -(Rp)_y, ay = (Rp)_x at the final pose
        const double c = std::cos(pose[2]), sn = std::sin(pose[2]);
        double sax = 0, say = 0, saa = 0;
        for (size_t j = 0; j < k; ++j) {
            const size_t i = size_t(used.src[j]);
            const double px = s[2 * i], py = s[2 * i + 1];
            const double rx = (c * px + (-sn) * py + pose[0]) - pose[0];
            const double ry = (c * py + sn * px + pose[1]) - pose[1];
            const double ax = -ry, ay = rx;
            sax += ax;
            say += ay;
            saa += ax * ax + ay * ay;
        }
        h = Hessian{double(k), sax, double(k), say, saa};
    }
    return {Pose{pose[0], pose[1], pose[2]}, iterations, int64_t(k), converged, rmse, h, inliers};
}

// Under a pose: the moved source, each point's nearest target index (-1: none) and its distance
// (inf where none is closer than the grid's radius).
void nearest(const TargetGrid& grid, Points source, double x, double y, double theta, OutPoints moved,
             OutIndex index, OutVector distance) {
    const double* s = source.data();
    const size_t n = source.shape(0);
    if (moved.shape(0) != n || index.shape(0) != n || distance.shape(0) != n)
        throw nb::value_error("nearest: the outputs must have the source's length");
    nb::gil_scoped_release release;
    const double c = std::cos(theta), sn = std::sin(theta);
    double* m = moved.data();
    int64_t* idx = index.data();
    double* dist = distance.data();
    for (size_t i = 0; i < n; ++i)
        idx[i] = nearest_moved(grid, c, sn, x, y, s[2 * i], s[2 * i + 1], m[2 * i], m[2 * i + 1], dist[i]);
}

}  // namespace

void bind_point_to_point_icp(nb::module_& m) {
    m.def("point_to_point_icp", &point_to_point_icp, nb::arg("grid"), nb::arg("source"), nb::arg("x"), nb::arg("y"),
          nb::arg("theta"), nb::arg("max_iterations"), nb::arg("translation_tol"), nb::arg("rotation_tol"),
          nb::arg("min_correspondences"), nb::arg("inlier_distance") = -1.0);
    m.def("nearest", &nearest, nb::arg("grid"), nb::arg("source"), nb::arg("x"), nb::arg("y"), nb::arg("theta"),
          nb::arg("moved"), nb::arg("index"), nb::arg("distance"));
}

}  // namespace fmcwlog
