// The correlative search's branch and bound (fmcwlog/kernels/correlative.py: _scores, _Search,
// _descend, _search_from_top), one call per search (the best pose, or the best separate peak).
//
// Same numbers as the numpy reference, bit for bit:
// - a score is the float32 mean of the likelihoods of the points' cells: a set of several offsets
//   sums each offset's points one after another from 0 (numpy's reduction over the middle axis of
//   (R, N, T)); a set of one offset sums them pairwise as numpy's pairwise_sum_FLOAT does (the
//   reduction then runs over a contiguous axis); the sum divided by N, rounded to float32;
// - candidates are visited in the order of _descending (np.argsort(-scores, kind="stable")):
//   highest first, equal scores by index, a stable sort here.
#include <nanobind/stl/tuple.h>
#include <nanobind/stl/vector.h>

#include "common.hpp"
#include "kernels.hpp"

namespace fmcwlog {
namespace {

using Table = nb::ndarray<const float, nb::ndim<1>, nb::c_contig, nb::device::cpu>;
using Cells = nb::ndarray<const int64_t, nb::ndim<2>, nb::c_contig, nb::device::cpu>;
using Mask = nb::ndarray<const bool, nb::ndim<1>, nb::c_contig, nb::device::cpu>;

// numpy's pairwise_sum_FLOAT (numpy/_core/src/umath/loops_utils.h.src), blocks of 128, 8 partial sums.
float pairwise_sum(const float* a, int64_t n) {
    if (n < 8) {
        float res = -0.0f;
        for (int64_t i = 0; i < n; ++i) res += a[i];
        return res;
    }
    if (n <= 128) {
        float r[8];
        for (int j = 0; j < 8; ++j) r[j] = a[j];
        int64_t i = 8;
        for (; i < n - (n % 8); i += 8)
            for (int j = 0; j < 8; ++j) r[j] += a[i + j];
        float res = ((r[0] + r[1]) + (r[2] + r[3])) + ((r[4] + r[5]) + (r[6] + r[7]));
        for (; i < n; ++i) res += a[i];
        return res;
    }
    int64_t n2 = n / 2;
    n2 -= n2 % 8;
    return pairwise_sum(a, n2) + pairwise_sum(a + n2, n - n2);
}

// np.mean's last step: the float32 sum over N (computed in double, then rounded: the same float).
inline float mean_of(float sum, int64_t n) { return float(double(sum) / double(n)); }

struct Offset {
    int64_t x, y;
};

struct Search {
    std::vector<const float*> tables;  // table(level): the grid the level's candidates are scored on
    const int64_t* cells = nullptr;     // (R, N) flat cells of the rotated points
    int64_t rows = 0, n = 0, width = 0, n_fine = 0, n_top = 0;  // n_top: top candidates along x (and y)
    std::vector<int64_t> steps;
    int64_t evaluated = 0;
    // second-peak search: whether a fine offset / a yaw sample lies on another peak (_Search.exclude)
    const bool* far = nullptr;
    const bool* turned = nullptr;
    std::vector<float> scratch;

    // _scores for one yaw sample: the mean likelihood of every offset of ``flats`` (flat steps).
    void scores(int level, int64_t r, const std::vector<int64_t>& flats, std::vector<float>& out) {
        const float* t = tables[size_t(level)];
        const int64_t* c = cells + r * n;
        const size_t k = flats.size();
        out.assign(k, 0.0f);
        if (k == 1) {
            scratch.resize(size_t(n));
            for (int64_t i = 0; i < n; ++i) scratch[size_t(i)] = t[c[i] + flats[0]];
            out[0] = mean_of(pairwise_sum(scratch.data(), n), n);
            return;
        }
        for (int64_t i = 0; i < n; ++i) {
            const float* row = t + c[i];
            for (size_t j = 0; j < k; ++j) out[j] += row[flats[j]];
        }
        for (size_t j = 0; j < k; ++j) out[j] = mean_of(out[j], n);
    }

    // _descending: the indices of ``v``, highest first, equal values by index (a stable sort).
    struct Order {
        std::vector<int64_t> idx;
    };

    static Order sorted(const std::vector<float>& v) {
        Order o;
        o.idx.resize(v.size());
        for (size_t i = 0; i < v.size(); ++i) o.idx[i] = int64_t(i);
        std::stable_sort(o.idx.begin(), o.idx.end(), [&](int64_t a, int64_t b) { return v[size_t(a)] > v[size_t(b)]; });
        return o;
    }

    // _Search.children: the next level's offsets under ``offset`` of level ``level``, in the window.
    void children(int level, Offset offset, std::vector<Offset>& out, std::vector<int64_t>& flats) const {
        const int64_t k = steps[size_t(level)] / steps[size_t(level + 1)], child = steps[size_t(level + 1)];
        out.clear();
        flats.clear();
        for (int64_t j = 0; j < k; ++j)
            for (int64_t i = 0; i < k; ++i) {
                const Offset o{i * child + offset.x, j * child + offset.y};
                if (o.x <= n_fine && o.y <= n_fine) {
                    out.push_back(o);
                    flats.push_back(o.y * width + o.x);
                }
            }
    }

    bool separate(int64_t r, Offset o) const {
        return turned[r] || far[(o.y + n_fine) * (2 * n_fine + 1) + (o.x + n_fine)];
    }

    struct Best {
        double score;
        int64_t r = -1;
        Offset at{0, 0};
    };

    // _descend: best first through ``offsets`` of ``level`` at yaw sample ``r`` scored ``sc``.
    void descend(int level, int64_t r, const std::vector<Offset>& offsets, const std::vector<float>& sc, Best& best,
                 bool exclude) {
        float highest = -std::numeric_limits<float>::infinity();
        for (float s : sc) highest = std::max(highest, s);
        if (double(highest) <= best.score) return;
        Order order = sorted(sc);
        const bool finest = level == int(steps.size()) - 1;
        std::vector<Offset> child;
        std::vector<int64_t> flats;
        std::vector<float> child_sc;
        for (size_t k = 0; k < order.idx.size(); ++k) {
            const size_t i = size_t(order.idx[k]);
            const double score = sc[i];
            if (score <= best.score) break;
            if (finest) {
                if (exclude && !separate(r, offsets[i])) continue;
                best.score = score;
                best.r = r;
                best.at = offsets[i];
            } else {
                children(level, offsets[i], child, flats);
                evaluated += int64_t(flats.size());
                scores(level + 1, r, flats, child_sc);
                descend(level + 1, r, child, child_sc, best, exclude);
            }
        }
    }

    // _search_from_top: the levels' walk from the top candidates' bounds ``upper`` (R × T) in ``order``.
    Best from_top(const std::vector<float>& upper, Order& order, const std::vector<Offset>& top, double floor,
                  bool exclude) {
        Best best{floor};
        std::vector<Offset> child;
        std::vector<int64_t> flats;
        std::vector<float> child_sc;
        for (size_t k = 0; k < order.idx.size(); ++k) {
            const int64_t flat = order.idx[k];
            const double bound = upper[size_t(flat)];
            if (bound <= best.score) break;
            const int64_t per_yaw = int64_t(top.size()), r = flat / per_yaw, t = flat % per_yaw;
            if (steps.size() == 1) {
                if (!exclude || separate(r, top[size_t(t)])) {
                    best.score = bound;
                    best.r = r;
                    best.at = top[size_t(t)];
                }
                continue;
            }
            children(0, top[size_t(t)], child, flats);
            evaluated += int64_t(flats.size());
            scores(1, r, flats, child_sc);
            descend(1, r, child, child_sc, best, exclude);
        }
        return best;
    }
};

using Found = std::tuple<double, int64_t, int64_t, int64_t>;  // score, yaw sample (-1: none), offset x, y

// correlative_match's two searches: the best pose, then, where ``exclude`` is not None, the best
// separate peak (``exclude(r, x, y)`` gives _Search.exclude's two masks for the best pose: the
// (2 n_fine + 1)^2 fine offsets, rows y, and the R yaw samples that lie on another peak).
// Returns (best, second, evaluated), a pose as (score, yaw sample, offset x, offset y); the second's
// yaw sample is -1 where none was found (score 0).
std::tuple<Found, Found, int64_t> correlative_search(std::vector<Table> tables, Cells cells, std::vector<int64_t> steps,
                                                     int64_t n_fine, int64_t width,
                                                     nb::handle exclude) {
    if (tables.size() != steps.size() || steps.empty()) throw nb::value_error("one table per level");
    for (size_t l = 0; l + 1 < steps.size(); ++l)
        if (steps[l + 1] < 1 || steps[l] % steps[l + 1] != 0) throw nb::value_error("steps must divide each other");
    Search s;
    s.cells = cells.data();
    s.rows = int64_t(cells.shape(0));
    s.n = int64_t(cells.shape(1));
    s.width = width;
    s.n_fine = n_fine;
    s.steps = steps;
    const int64_t size = int64_t(tables[0].shape(0));
    for (auto& t : tables) {
        if (int64_t(t.shape(0)) != size) throw nb::value_error("tables of different sizes");
        s.tables.push_back(t.data());
    }
    // every lookup: a cell plus an offset within [-n_fine, n_fine + top step] each way
    const int64_t reach = n_fine + steps[0];
    int64_t lo = std::numeric_limits<int64_t>::max(), hi = std::numeric_limits<int64_t>::min();
    for (int64_t i = 0; i < s.rows * s.n; ++i) {
        lo = std::min(lo, s.cells[i]);
        hi = std::max(hi, s.cells[i]);
    }
    if (s.rows * s.n == 0) throw nb::value_error("no points");
    if (lo - reach * (width + 1) < 0 || hi + reach * (width + 1) >= size)
        throw nb::value_error("cells beyond the grid's frame");
    s.n_top = (2 * n_fine + 1 + steps[0] - 1) / steps[0];
    std::vector<Offset> top;
    std::vector<int64_t> top_flats;
    for (int64_t j = 0; j < s.n_top; ++j)
        for (int64_t i = 0; i < s.n_top; ++i) {
            top.push_back({i * steps[0] - n_fine, j * steps[0] - n_fine});
            top_flats.push_back(top.back().y * width + top.back().x);
        }
    Found best, second{0.0, -1, 0, 0};
    std::vector<float> upper(size_t(s.rows * s.n_top * s.n_top));
    Search::Order order;
    Search::Best b{-1.0};
    {
        nb::gil_scoped_release release;
        std::vector<float> row;
        for (int64_t r = 0; r < s.rows; ++r) {
            s.scores(0, r, top_flats, row);
            std::copy(row.begin(), row.end(), upper.begin() + r * int64_t(row.size()));
        }
        s.evaluated += int64_t(upper.size());
        order = s.sorted(upper);
        b = s.from_top(upper, order, top, -1.0, false);
    }
    best = {b.score, b.r, b.at.x, b.at.y};
    if (!exclude.is_none() && b.r >= 0) {
        nb::tuple masks = nb::cast<nb::tuple>(exclude(b.r, b.at.x, b.at.y));
        Mask far = nb::cast<Mask>(masks[0]), turned = nb::cast<Mask>(masks[1]);
        if (int64_t(far.shape(0)) != (2 * n_fine + 1) * (2 * n_fine + 1) || int64_t(turned.shape(0)) != s.rows)
            throw nb::value_error("exclude gave masks of the wrong size");
        s.far = far.data();
        s.turned = turned.data();
        nb::gil_scoped_release release;
        Search::Best b2 = s.from_top(upper, order, top, 0.0, true);
        second = {b2.score, b2.r, b2.at.x, b2.at.y};
    }
    return {best, second, s.evaluated};
}

}  // namespace

void bind_correlative(nb::module_& m) {
    m.def("correlative_search", &correlative_search, nb::arg("tables"), nb::arg("cells"), nb::arg("steps"),
          nb::arg("n_fine"), nb::arg("width"), nb::arg("exclude").none());
}

}  // namespace fmcwlog
