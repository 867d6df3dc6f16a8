// Static / moving segmentation of a sweep (fmcwlog/frontend/segmentation.py): DBSCAN over
// (x, y, sqrt(alpha) eps), the neighbourhood cut around the seeds and the per-cluster Doppler verdict.
//
// The pairs are those of the reference's cKDTree: squared distances summed in the tree's order
// (segmentation.dbscan: pairs with d^2 <= eps^2; segment_clusters' nearest-centre query: d^2 < r^2),
// found here through buckets at least the radius wide, so the labels are the reference's exactly.
#include "segmentation.hpp"

#include <nanobind/stl/optional.h>

#include <memory>
#include <optional>
#include <stdexcept>

#include "common.hpp"
#include "kernels.hpp"

namespace fmcwlog {
namespace {

// Points bucketed by (x, y) into square cells at least `reach` wide (a point's neighbours within
// `reach` lie in its own cell or the 8 around it; the cells are widened by 1e-6 so that rounding
// of a point's cell cannot put a neighbour two cells away). A wide spread doubles the cell until
// there are at most about 4 cells a point. Within a cell the points keep their order.
class Buckets {
  public:
    // point i at (pts[i * stride], pts[i * stride + 1]) (y = 0 where stride is 1)
    Buckets(const double* pts, size_t n, size_t stride, double reach) {
        px_.resize(n);
        py_.resize(n);
        double x0 = kInf, y0 = kInf, x1 = -kInf, y1 = -kInf;
        for (size_t i = 0; i < n; ++i) {
            px_[i] = pts[i * stride];
            py_[i] = stride > 1 ? pts[i * stride + 1] : 0.0;
            x0 = std::min(x0, px_[i]);
            y0 = std::min(y0, py_[i]);
            x1 = std::max(x1, px_[i]);
            y1 = std::max(y1, py_[i]);
        }
        if (n == 0) x0 = y0 = x1 = y1 = 0.0;
        cell_ = reach * (1.0 + 1e-6);
        const double most = 4.0 * double(n) + 16.0;
        while ((std::floor((x1 - x0) / cell_) + 1.0) * (std::floor((y1 - y0) / cell_) + 1.0) > most) cell_ *= 2.0;
        x0_ = x0;
        y0_ = y0;
        nx_ = int64_t(std::floor((x1 - x0) / cell_)) + 1;
        ny_ = int64_t(std::floor((y1 - y0) / cell_)) + 1;
        start_.assign(size_t(nx_ * ny_ + 1), 0);
        std::vector<int64_t> where(n);
        for (size_t i = 0; i < n; ++i) {
            const int64_t cx = std::clamp(int64_t(std::floor((px_[i] - x0_) / cell_)), int64_t(0), nx_ - 1);
            const int64_t cy = std::clamp(int64_t(std::floor((py_[i] - y0_) / cell_)), int64_t(0), ny_ - 1);
            where[i] = cy * nx_ + cx;
            ++start_[size_t(where[i] + 1)];
        }
        for (size_t c = 1; c < start_.size(); ++c) start_[c] += start_[c - 1];
        order_.resize(n);
        std::vector<int64_t> fill(start_.begin(), start_.end() - 1);
        for (size_t i = 0; i < n; ++i) order_[size_t(fill[size_t(where[i])]++)] = int64_t(i);
    }

    // f(j) for every point j in the cells about (x, y) (a superset of those within `reach`)
    template <class F>
    void around(double x, double y, F&& f) const {
        const double fx = std::floor((x - x0_) / cell_), fy = std::floor((y - y0_) / cell_);
        if (!(fx >= -1.0 && fy >= -1.0 && fx <= double(nx_) && fy <= double(ny_))) return;
        const int64_t cx = int64_t(fx), cy = int64_t(fy);
        for (int64_t yy = std::max<int64_t>(cy - 1, 0); yy <= std::min(cy + 1, ny_ - 1); ++yy) {
            const int64_t lo = yy * nx_ + std::max<int64_t>(cx - 1, 0), hi = yy * nx_ + std::min(cx + 1, nx_ - 1);
            if (lo > hi) continue;
            for (int64_t k = start_[size_t(lo)]; k < start_[size_t(hi + 1)]; ++k) f(order_[size_t(k)]);
        }
    }

  private:
    double cell_ = 1.0, x0_ = 0.0, y0_ = 0.0;
    int64_t nx_ = 1, ny_ = 1;
    std::vector<double> px_, py_;
    std::vector<int64_t> start_, order_;
};

// The squared distance of two d-vectors as cKDTree sums it (4 running sums over blocks of 4, then
// the rest one by one: for d < 4 the plain sum in order).
inline double squared_distance(const double* u, const double* v, size_t d) {
    double acc[4] = {0.0, 0.0, 0.0, 0.0};
    size_t i = 0;
    for (; i + 4 <= d; i += 4)
        for (size_t k = 0; k < 4; ++k) {
            const double diff = u[i + k] - v[i + k];
            acc[k] += diff * diff;
        }
    double s = acc[0] + acc[1] + acc[2] + acc[3];
    for (; i < d; ++i) {
        const double diff = u[i] - v[i];
        s += diff * diff;
    }
    return s;
}

// segmentation._lowest_connected on a union-find: the root of every tree is its lowest node.
int64_t find_root(std::vector<int64_t>& parent, int64_t a) {
    while (parent[size_t(a)] != a) {
        parent[size_t(a)] = parent[size_t(parent[size_t(a)])];
        a = parent[size_t(a)];
    }
    return a;
}

// segmentation.moving_from_labels on n points.
void moving_from_labels(const int64_t* labels, const double* epsilon, size_t n, const SegmentationConfig& cfg,
                        bool* moving) {
    int64_t n_lab = 0;
    for (size_t i = 0; i < n; ++i) n_lab = std::max(n_lab, labels[i] + 1);
    std::vector<int64_t> size(size_t(n_lab), 0), strong(size_t(n_lab), 0);
    for (size_t i = 0; i < n; ++i)
        if (labels[i] >= 0) {
            ++size[size_t(labels[i])];
            strong[size_t(labels[i])] += std::abs(epsilon[i]) >= cfg.v_th;
        }
    for (size_t i = 0; i < n; ++i) {
        const bool is_strong = std::abs(epsilon[i]) >= cfg.v_th;
        if (labels[i] < 0) {
            moving[i] = is_strong;
            continue;
        }
        const size_t c = size_t(labels[i]);
        const bool cluster_moving = double(strong[c]) >= cfg.min_moving_fraction * double(size[c]);
        moving[i] = (cfg.keep_strong_points && is_strong) || cluster_moving;
    }
}

}  // namespace

constexpr int64_t kReach = 2;  // pairs_within's cells: eps / kReach wide

// Pairs of point indices, appended without initialising the storage first.
struct PairList {
    struct Pair {
        int32_t a, b;
    };
    std::unique_ptr<Pair[]> data;
    size_t size = 0, capacity = 0;
    void reserve_more(size_t extra) {
        if (size + extra <= capacity) return;
        const size_t grown = std::max(2 * capacity, size + extra);
        std::unique_ptr<Pair[]> next(new Pair[grown]);
        std::copy(data.get(), data.get() + size, next.get());
        data = std::move(next);
        capacity = grown;
    }
};

template <size_t Fixed>
void scan_rows(const double* sorted, size_t d_runtime, int64_t ny, const std::vector<int64_t>& row_start,
               const std::vector<int64_t>& col, const std::vector<int64_t>& order, double r2,
               PairList& pairs, std::integral_constant<size_t, Fixed>);

// The pairs (a, b), a < b, of n points of dimension d within `eps` (d^2 <= eps^2, cKDTree's sum):
// the query_pairs of the reference, in another order. The points are sorted into rows and columns
// of cells eps / kReach wide (counting sorts, by column then row); a point is compared with the
// points after it in its own row up to kReach columns on and with the 2 kReach + 1 columns about
// its own in each of the next kReach rows, whose ranges move forward with it (each pair is looked
// at once).
void pairs_within(const double* feats, size_t n, size_t d, double eps, PairList& pairs) {
    pairs.size = 0;
    double x0 = kInf, y0 = kInf, x1 = -kInf, y1 = -kInf;
    for (size_t i = 0; i < n; ++i) {
        const double x = feats[i * d], y = d > 1 ? feats[i * d + 1] : 0.0;
        x0 = std::min(x0, x);
        y0 = std::min(y0, y);
        x1 = std::max(x1, x);
        y1 = std::max(y1, y);
    }
    // kReach cells span more than eps, so that neighbours lie at most kReach cells apart, rounding included
    double cell = eps / double(kReach) * (1.0 + 1e-6);
    while (std::max(x1 - x0, y1 - y0) / cell > double(1 << 20)) cell *= 2.0;
    const int64_t nx = int64_t(std::floor((x1 - x0) / cell)) + 1, ny = int64_t(std::floor((y1 - y0) / cell)) + 1;
    std::vector<int64_t> cx(n), cy(n);
    for (size_t i = 0; i < n; ++i) {
        cx[i] = std::clamp(int64_t(std::floor((feats[i * d] - x0) / cell)), int64_t(0), nx - 1);
        cy[i] = d > 1 ? std::clamp(int64_t(std::floor((feats[i * d + 1] - y0) / cell)), int64_t(0), ny - 1) : 0;
    }
    // counting sort by column, then (stable) by row
    std::vector<int64_t> by_x(n), order(n), row_start(size_t(ny + 1), 0);
    {
        std::vector<int64_t> count(size_t(nx + 1), 0);
        for (size_t i = 0; i < n; ++i) ++count[size_t(cx[i] + 1)];
        for (size_t c = 1; c < count.size(); ++c) count[c] += count[c - 1];
        for (size_t i = 0; i < n; ++i) by_x[size_t(count[size_t(cx[i])]++)] = int64_t(i);
        for (size_t i = 0; i < n; ++i) ++row_start[size_t(cy[i] + 1)];
        for (size_t r = 1; r < row_start.size(); ++r) row_start[r] += row_start[r - 1];
        std::vector<int64_t> fill(row_start.begin(), row_start.end() - 1);
        for (size_t k = 0; k < n; ++k) {
            const int64_t i = by_x[k];
            order[size_t(fill[size_t(cy[size_t(i)])]++)] = i;
        }
    }
    std::vector<int64_t> col(n);  // the column of each sorted point
    std::vector<double> sorted(n * d);
    for (size_t k = 0; k < n; ++k) {
        col[k] = cx[size_t(order[k])];
        std::copy(feats + size_t(order[k]) * d, feats + size_t(order[k]) * d + d, sorted.begin() + long(k * d));
    }
    const double r2 = eps * eps;
    pairs.reserve_more(16 * n);
    if (d == 3)
        scan_rows(sorted.data(), 3, ny, row_start, col, order, r2, pairs, std::integral_constant<size_t, 3>());
    else if (d == 2)
        scan_rows(sorted.data(), 2, ny, row_start, col, order, r2, pairs, std::integral_constant<size_t, 2>());
    else
        scan_rows(sorted.data(), d, ny, row_start, col, order, r2, pairs, std::integral_constant<size_t, 0>());
}

// pairs_within's scan of the sorted points; Fixed is d where it is known when compiling (else 0).
template <size_t Fixed>
void scan_rows(const double* sorted, size_t d_runtime, int64_t ny, const std::vector<int64_t>& row_start,
               const std::vector<int64_t>& col, const std::vector<int64_t>& order, double r2,
               PairList& pairs, std::integral_constant<size_t, Fixed>) {
    const size_t d = Fixed ? Fixed : d_runtime;
    size_t found = 0;
    // the points b in [from, to) within reach of a, appended without a branch on the distance
    auto check = [&](size_t a, size_t from, size_t to) {
        pairs.size = found;
        pairs.reserve_more(to - from);
        PairList::Pair* out = pairs.data.get();
        const double* u = sorted + a * d;
        for (size_t b = from; b < to; ++b) {
            out[found] = {int32_t(order[a]), int32_t(order[b])};
            found += squared_distance(u, sorted + b * d, d) <= r2;
        }
    };
    for (int64_t r = 0; r < ny; ++r) {
        const size_t begin = size_t(row_start[size_t(r)]), end = size_t(row_start[size_t(r + 1)]);
        // the next kReach rows' points in the columns about the current one: [lo, hi) of each
        size_t lo[kReach], hi[kReach], stop[kReach];
        for (int64_t q = 0; q < kReach; ++q) {
            const int64_t row = std::min(r + 1 + q, ny);
            lo[q] = hi[q] = size_t(row_start[size_t(row)]);
            stop[q] = size_t(row_start[size_t(std::min(row + 1, ny))]);
        }
        size_t same = begin;  // the own row's points up to kReach columns on
        for (size_t a = begin; a < end; ++a) {
            const int64_t c = col[a];
            if (same <= a) same = a + 1;
            while (same < end && col[same] <= c + kReach) ++same;
            check(a, a + 1, same);
            for (int64_t q = 0; q < kReach; ++q) {
                while (lo[q] < stop[q] && col[lo[q]] < c - kReach) ++lo[q];
                if (hi[q] < lo[q]) hi[q] = lo[q];
                while (hi[q] < stop[q] && col[hi[q]] <= c + kReach) ++hi[q];
                check(a, lo[q], hi[q]);
            }
        }
    }
    pairs.size = found;
}

void dbscan_labels(const double* feats, size_t n, size_t d, double eps, int64_t min_samples, int64_t* labels) {
    std::fill(labels, labels + n, int64_t(-1));
    if (n == 0) return;
    if (n >= size_t(INT32_MAX)) throw std::length_error("dbscan: too many points");
    PairList pairs;
    pairs_within(feats, n, d, eps, pairs);
    const size_t m = pairs.size;
    const PairList::Pair* pair = pairs.data.get();
    // core points: at least min_samples neighbours, themselves counted
    std::vector<int64_t> count(n, 1);
    for (size_t k = 0; k < m; ++k) {
        ++count[size_t(pair[k].a)];
        ++count[size_t(pair[k].b)];
    }
    std::vector<char> core(n);
    bool any_core = false;
    for (size_t i = 0; i < n; ++i) {
        core[i] = count[i] >= min_samples;
        any_core |= bool(core[i]);
    }
    if (!any_core) return;
    // components of the core points under core-core pairs, rooted at their lowest point (_lowest_connected)
    std::vector<int64_t> parent(n);
    for (size_t i = 0; i < n; ++i) parent[i] = int64_t(i);
    for (size_t k = 0; k < m; ++k) {
        if (!core[size_t(pair[k].a)] || !core[size_t(pair[k].b)]) continue;
        const int64_t a = find_root(parent, pair[k].a), b = find_root(parent, pair[k].b);
        if (a != b) parent[size_t(std::max(a, b))] = std::min(a, b);
    }
    // clusters numbered in the order of their lowest point
    int64_t next = 0;
    for (size_t i = 0; i < n; ++i)
        if (core[i]) {
            const int64_t r = find_root(parent, int64_t(i));
            labels[i] = r == int64_t(i) ? next++ : labels[size_t(r)];
        }
    // a border point takes the lowest cluster among its core neighbours
    for (size_t k = 0; k < m; ++k) {
        const size_t a = size_t(pair[k].a), b = size_t(pair[k].b);
        if (core[a] == core[b]) continue;
        const size_t border = core[a] ? b : a, from = core[a] ? a : b;
        if (labels[border] < 0 || labels[from] < labels[border]) labels[border] = labels[from];
    }
}

void segment_clusters(const double* xy, const double* epsilon, size_t n, const double* seeds, size_t k,
                      const bool* seed_points, const SegmentationConfig& cfg, int64_t* labels, bool* clustered,
                      bool* moving) {
    std::fill(labels, labels + n, int64_t(-1));
    std::fill(clustered, clustered + n, false);
    std::fill(moving, moving + n, false);
    std::vector<char> centre(n);
    bool any_strong = false, any_seed_point = false;
    for (size_t i = 0; i < n; ++i) {
        const bool strong = std::abs(epsilon[i]) >= cfg.v_th;
        const bool seed = seed_points != nullptr && seed_points[i];
        any_strong |= strong;
        any_seed_point |= seed;
        centre[i] = strong || seed;
    }
    const bool extra = k > 0 || any_seed_point;
    if (n == 0 || (cfg.min_moving_fraction > 0 && !any_strong && !extra)) return;
    if (cfg.neighbourhood <= 0 || cfg.min_moving_fraction <= 0) {
        std::fill(clustered, clustered + n, true);
    } else {
        // the centres: the centre points, then the seeds (segment_clusters' `centres`)
        std::vector<double> centres;
        centres.reserve(2 * n + 2 * k);
        for (size_t i = 0; i < n; ++i)
            if (centre[i]) centres.insert(centres.end(), {xy[2 * i], xy[2 * i + 1]});
        centres.insert(centres.end(), seeds, seeds + 2 * k);
        const size_t m = centres.size() / 2;
        double lox = kInf, loy = kInf, hix = -kInf, hiy = -kInf;
        for (size_t c = 0; c < m; ++c) {
            lox = std::min(lox, centres[2 * c]);
            loy = std::min(loy, centres[2 * c + 1]);
            hix = std::max(hix, centres[2 * c]);
            hiy = std::max(hiy, centres[2 * c + 1]);
        }
        lox -= cfg.neighbourhood;
        loy -= cfg.neighbourhood;
        hix += cfg.neighbourhood;
        hiy += cfg.neighbourhood;
        const double r2 = cfg.neighbourhood * cfg.neighbourhood;
        const Buckets buckets(centres.data(), m, 2, cfg.neighbourhood);
        for (size_t i = 0; i < n; ++i) {
            const double x = xy[2 * i], y = xy[2 * i + 1];
            if (!(x >= lox && x <= hix && y >= loy && y <= hiy)) continue;
            if (centre[i]) {
                clustered[i] = true;
                continue;
            }
            bool near = false;
            buckets.around(x, y, [&](int64_t c) {
                near = near || squared_distance(xy + 2 * i, centres.data() + 2 * size_t(c), 2) < r2;
            });
            clustered[i] = near;
        }
    }
    // DBSCAN and the verdict over the clustered points (cluster_points, moving_from_labels)
    std::vector<int64_t> idx;
    for (size_t i = 0; i < n; ++i)
        if (clustered[i]) idx.push_back(int64_t(i));
    if (idx.empty()) return;
    const size_t c = idx.size();
    const double scale = std::sqrt(cfg.alpha);
    std::vector<double> feats(3 * c), eps(c);
    for (size_t a = 0; a < c; ++a) {
        const size_t i = size_t(idx[a]);
        feats[3 * a] = xy[2 * i];
        feats[3 * a + 1] = xy[2 * i + 1];
        feats[3 * a + 2] = scale * epsilon[i];
        eps[a] = epsilon[i];
    }
    std::vector<int64_t> lab(c);
    dbscan_labels(feats.data(), c, 3, cfg.eps, cfg.min_samples, lab.data());
    std::vector<char> mov(c);
    moving_from_labels(lab.data(), eps.data(), c, cfg, reinterpret_cast<bool*>(mov.data()));
    for (size_t a = 0; a < c; ++a) {
        labels[size_t(idx[a])] = lab[a];
        moving[size_t(idx[a])] = mov[a];
    }
}

namespace {

using Features = nb::ndarray<const double, nb::ndim<2>, nb::c_contig, nb::device::cpu>;
using Vector = nb::ndarray<const double, nb::shape<-1>, nb::c_contig, nb::device::cpu>;
using Mask = nb::ndarray<const bool, nb::shape<-1>, nb::c_contig, nb::device::cpu>;
using OutMask = nb::ndarray<bool, nb::shape<-1>, nb::c_contig, nb::device::cpu>;

bool all_finite(const double* a, size_t n) {
    for (size_t i = 0; i < n; ++i)
        if (!std::isfinite(a[i])) return false;
    return true;
}

// dbscan(feats, eps, min_samples, labels): False (labels untouched) where a coordinate is not finite.
bool dbscan_binding(Features feats, double eps, int64_t min_samples, OutIndex labels) {
    const size_t n = feats.shape(0), d = feats.shape(1);
    if (labels.shape(0) != n) throw nb::value_error("dbscan: labels must have the points' length");
    if (d == 0 && n > 0) throw nb::value_error("dbscan: points need at least one coordinate");
    if (!all_finite(feats.data(), n * d)) return false;
    nb::gil_scoped_release release;
    dbscan_labels(feats.data(), n, d, eps, min_samples, labels.data());
    return true;
}

// segment_clusters(xy, epsilon, seeds, seed_points, alpha, eps, min_samples, v_th, min_moving_fraction,
// keep_strong_points, neighbourhood, labels, clustered, moving): False (outputs untouched) where an
// input is not finite. seed_points may be None.
bool segment_clusters_binding(Points xy, Vector epsilon, Points seeds, std::optional<Mask> seed_points, double alpha,
                              double eps, int64_t min_samples, double v_th, double min_moving_fraction,
                              bool keep_strong_points, double neighbourhood, OutIndex labels, OutMask clustered,
                              OutMask moving) {
    const size_t n = xy.shape(0), k = seeds.shape(0);
    if (epsilon.shape(0) != n || labels.shape(0) != n || clustered.shape(0) != n || moving.shape(0) != n ||
        (seed_points && seed_points->shape(0) != n))
        throw nb::value_error("segment_clusters: every per-point array must have the points' length");
    if (!all_finite(xy.data(), 2 * n) || !all_finite(epsilon.data(), n) || !all_finite(seeds.data(), 2 * k))
        return false;
    const SegmentationConfig cfg{alpha, eps, min_samples, v_th, min_moving_fraction, keep_strong_points, neighbourhood};
    nb::gil_scoped_release release;
    segment_clusters(xy.data(), epsilon.data(), n, seeds.data(), k, seed_points ? seed_points->data() : nullptr, cfg,
                     labels.data(), clustered.data(), moving.data());
    return true;
}

}  // namespace

void bind_segmentation(nb::module_& m) {
    m.def("dbscan", &dbscan_binding, nb::arg("feats"), nb::arg("eps"), nb::arg("min_samples"), nb::arg("labels"));
    m.def("segment_clusters", &segment_clusters_binding, nb::arg("xy"), nb::arg("epsilon"), nb::arg("seeds"),
          nb::arg("seed_points").none(), nb::arg("alpha"), nb::arg("eps"), nb::arg("min_samples"), nb::arg("v_th"),
          nb::arg("min_moving_fraction"), nb::arg("keep_strong_points"), nb::arg("neighbourhood"), nb::arg("labels"),
          nb::arg("clustered"), nb::arg("moving"));
}

}  // namespace fmcwlog
