// fmcwlog._core: compiled twins of numpy kernels (fmcwlog/kernels/compiled.py selects them).
// The module, its source digest and the types several kernels share; each kernel binds itself.
#include "common.hpp"
#include "kernels.hpp"

using namespace fmcwlog;

NB_MODULE(_core, m) {
    m.doc() = "Compiled twins of fmcwlog's numpy kernels";
    m.attr("SOURCE_SHA256") = FMCWLOG_CORE_SOURCE_SHA256;
    // Grids kept by objects that live to the interpreter's exit (fmcwlog's command freezes its
    // objects out of the last collections; a test's traceback holds its frames) are not leaks:
    // no warning about them after a command's last line.
    nb::set_leak_warnings(false);
    nb::class_<TargetGrid>(m, "TargetGrid")
        .def(
            "__init__",
            [](TargetGrid* self, Points target, double radius) {
                if (!(radius > 0.0) || !std::isfinite(radius)) throw nb::value_error("radius must be finite and > 0");
                new (self) TargetGrid(target.data(), target.shape(0), radius);
            },
            nb::arg("target"), nb::arg("radius"))
        .def_prop_ro("radius", &TargetGrid::radius);
    bind_point_to_point_icp(m);
    bind_egomotion(m);
    bind_deskew(m);
    bind_voxel(m);
    bind_segmentation(m);
    bind_tracking(m);
    bind_occupancy(m);
    bind_robust_icp(m);
    bind_correlative(m);
    bind_line_icp(m);
    bind_likelihood_grid(m);
    bind_submap(m);
    bind_keyframe_map(m);
    bind_transform(m);
    bind_local_edges(m);
    bind_rays(m);
}
