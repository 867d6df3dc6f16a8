// The per-sweep segmentation (fmcwlog/frontend/segmentation.py) as plain C++, for the tracker's
// sweep (tracking.cpp) as well as for its own bindings (segmentation.cpp).
#pragma once

#include <cstddef>
#include <cstdint>
#include <vector>

namespace fmcwlog {

// SegmentationParams of the reference (units there).
struct SegmentationConfig {
    double alpha, eps;
    int64_t min_samples;
    double v_th, min_moving_fraction;
    bool keep_strong_points;
    double neighbourhood;
};

// segmentation.dbscan: labels (n,) of n points of dimension d (row-major), -1 for noise, numbered
// as the reference numbers them. Every coordinate must be finite.
void dbscan_labels(const double* feats, std::size_t n, std::size_t d, double eps, int64_t min_samples, int64_t* labels);

// segmentation.segment_clusters: xy (n, 2), epsilon (n,), seeds (k, 2), seed_points (n,) or null.
// Fills labels (n,), clustered (n,) and moving (n,). Every input must be finite.
void segment_clusters(const double* xy, const double* epsilon, std::size_t n, const double* seeds, std::size_t k,
                      const bool* seed_points, const SegmentationConfig& cfg, int64_t* labels, bool* clustered,
                      bool* moving);

}  // namespace fmcwlog
