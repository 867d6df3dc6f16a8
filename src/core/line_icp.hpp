// The back end's point-to-line ICP (line_icp.cpp) and submap normals (submap.cpp) on raw arrays,
// shared with the fused local matching (local_edges.cpp).
#pragma once

#include <array>
#include <vector>

#include "common.hpp"

namespace fmcwlog {

using Vec3 = std::array<double, 3>;
using Mat3 = std::array<double, 9>;

// What registration.register_point_to_line returns: the pose, J^T W J at it (row major; zeros where
// no pair), the final residuals (one per pair), the iterations and whether the steps converged.
struct LineIcpRun {
    Vec3 pose{};
    Mat3 h{};
    std::vector<double> r;
    int iterations = 0;
    bool converged = false;
};

LineIcpRun run_line_icp(const TargetGrid& grid, const double* normals, const bool* has_normal, const double* s,
                        size_t n, Vec3 pose, int max_iterations, double kernel_scale, double tolerance,
                        const Vec3* prior_pose, const Mat3* prior_info, const int32_t* near, int64_t k,
                        const double* reach);

// LAPACK's dgesv on 3 x 3 (row major a): false where a pivot is 0.
bool solve3(Mat3 a, Vec3 b, Vec3& x);

// registration.build_submap's normals of the m points xy (interleaved): normals (m, 2) and
// has_normal (m,) filled; near (m, neighbours) and reach (m, neighbours + 1) too where not null.
void submap_normals_into(const double* xy, int64_t m, int64_t neighbours, double min_planarity, double* normals,
                         bool* has_normal, int32_t* near, double* reach);

}  // namespace fmcwlog
