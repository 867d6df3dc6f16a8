// One bind_* per kernel file; module.cpp calls each. A new kernel: its own .cpp with a bind_*
// function, declared here and called in module.cpp (CMakeLists.txt compiles every src/core/*.cpp).
#pragma once

#include <nanobind/nanobind.h>

namespace fmcwlog {

void bind_point_to_point_icp(nanobind::module_& m);
void bind_egomotion(nanobind::module_& m);
void bind_deskew(nanobind::module_& m);
void bind_voxel(nanobind::module_& m);
void bind_segmentation(nanobind::module_& m);
void bind_tracking(nanobind::module_& m);
void bind_occupancy(nanobind::module_& m);
void bind_robust_icp(nanobind::module_& m);
void bind_correlative(nanobind::module_& m);
void bind_line_icp(nanobind::module_& m);
void bind_likelihood_grid(nanobind::module_& m);
void bind_submap(nanobind::module_& m);
void bind_keyframe_map(nanobind::module_& m);
void bind_transform(nanobind::module_& m);
void bind_local_edges(nanobind::module_& m);
void bind_rays(nanobind::module_& m);

}  // namespace fmcwlog
