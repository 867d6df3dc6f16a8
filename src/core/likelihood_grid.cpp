// The correlative search's likelihood grids (fmcwlog/kernels/correlative.py: LikelihoodGrid).
//
// likelihood_fill mirrors __init__'s distance transform of the grid's inside (scipy's
// distance_transform_edt, then _likelihood): the squared distance, in cells, from each cell to the
// nearest target cell is an integer, exact here (Felzenszwalb and Huttenlocher's lower envelope of
// parabolas, "Distance Transforms of Sampled Functions", 2012, per column then per row); the
// likelihood of a squared distance d2 is read from ``table[d2]``, the numpy reference's own
// arithmetic on sqrt(d2) (computed in numpy, so the float32 values are bit for bit its own).
//
// max_filter_framed mirrors coarse(): scipy's maximum_filter over [i, i + k) in each axis, zeros
// outside the grid, then _framed. A maximum is exact, so the same floats in any order.
#include "common.hpp"
#include "kernels.hpp"

namespace fmcwlog {
namespace {

using Cells = nb::ndarray<const int64_t, nb::shape<-1, 2>, nb::c_contig, nb::device::cpu>;
using Grid = nb::ndarray<float, nb::ndim<2>, nb::c_contig, nb::device::cpu>;
using ConstGrid = nb::ndarray<const float, nb::ndim<2>, nb::c_contig, nb::device::cpu>;
using Table = nb::ndarray<const float, nb::ndim<1>, nb::c_contig, nb::device::cpu>;

constexpr int64_t kFar = std::numeric_limits<int64_t>::max() / 4;  // no target cell in the column

// The squared distance from every cell of ``occupied`` (rows x cols, row-major) to the nearest
// occupied cell, exact (at least one cell must be occupied).
std::vector<int64_t> squared_distances(const std::vector<uint8_t>& occupied, int64_t rows, int64_t cols) {
    // per column: the distance along y to the nearest occupied cell, squared (kFar: none)
    std::vector<int64_t> g(size_t(rows * cols), kFar);
    for (int64_t x = 0; x < cols; ++x) {
        int64_t last = -1;
        for (int64_t y = 0; y < rows; ++y) {
            if (occupied[size_t(y * cols + x)]) last = y;
            if (last >= 0) g[size_t(y * cols + x)] = y - last;
        }
        last = -1;
        for (int64_t y = rows - 1; y >= 0; --y) {
            if (occupied[size_t(y * cols + x)]) last = y;
            int64_t& d = g[size_t(y * cols + x)];
            if (last >= 0 && last - y < d) d = last - y;
        }
        for (int64_t y = 0; y < rows; ++y) {
            int64_t& d = g[size_t(y * cols + x)];
            if (d != kFar) d *= d;
        }
    }
    // per row: the lower envelope of the parabolas (x - q)^2 + g(q) over the columns q with a target
    std::vector<int64_t> out(size_t(rows * cols));
    std::vector<int64_t> v(static_cast<size_t>(cols));
    std::vector<double> z(size_t(cols) + 1);
    for (int64_t y = 0; y < rows; ++y) {
        const int64_t* f = g.data() + y * cols;
        int64_t k = -1;
        for (int64_t q = 0; q < cols; ++q) {
            if (f[q] == kFar) continue;
            double s = 0.0;
            while (k >= 0) {
                const int64_t p = v[size_t(k)];
                // where the parabolas of p and q meet: a rational number, exact enough in double for
                // the integers here (two different meeting points differ by more than 1 / (2 cols)^2)
                s = double((f[q] + q * q) - (f[p] + p * p)) / double(2 * (q - p));
                if (s > z[size_t(k)]) break;
                --k;
            }
            ++k;
            v[size_t(k)] = q;
            z[size_t(k)] = k == 0 ? -kInf : s;
            z[size_t(k) + 1] = kInf;
        }
        int64_t j = 0;
        for (int64_t x = 0; x < cols; ++x) {
            while (z[size_t(j) + 1] < double(x)) ++j;
            const int64_t p = v[size_t(j)];
            out[size_t(y * cols + x)] = (x - p) * (x - p) + f[p];
        }
    }
    return out;
}

// LikelihoodGrid.__init__, the inside branch: ``grid`` (h, w), zeros, gets table[d2] (0 where d2 is
// beyond the table) on its inside, the cells ``frame`` or more from every edge; ``cells`` (N, 2):
// the targets' (ix, iy), all inside.
void likelihood_fill(Cells cells, Grid grid, int64_t frame, Table table) {
    const int64_t h = int64_t(grid.shape(0)), w = int64_t(grid.shape(1));
    const int64_t rows = h - 2 * frame, cols = w - 2 * frame, n = int64_t(cells.shape(0));
    if (frame < 0 || rows <= 0 || cols <= 0) throw nb::value_error("no inside");
    if (n == 0) throw nb::value_error("no target");
    const int64_t* ij = cells.data();
    std::vector<uint8_t> occupied(size_t(rows * cols), 0);
    for (int64_t i = 0; i < n; ++i) {
        const int64_t x = ij[2 * i] - frame, y = ij[2 * i + 1] - frame;
        if (x < 0 || y < 0 || x >= cols || y >= rows) throw nb::value_error("a target outside the inside");
        occupied[size_t(y * cols + x)] = 1;
    }
    const float* t = table.data();
    const int64_t size = int64_t(table.shape(0));
    float* out = grid.data();
    nb::gil_scoped_release release;
    const std::vector<int64_t> d2 = squared_distances(occupied, rows, cols);
    for (int64_t y = 0; y < rows; ++y)
        for (int64_t x = 0; x < cols; ++x) {
            const int64_t d = d2[size_t(y * cols + x)];
            out[(y + frame) * w + x + frame] = d < size ? t[d] : 0.0f;
        }
}

// LikelihoodGrid.coarse: ``out`` (h, w) = the maximum of ``fine`` over cells [i, i + k) in each
// axis (zeros beyond the grid), then a frame of ``frame`` cells zeroed.
void max_filter_framed(ConstGrid fine, Grid out, int64_t k, int64_t frame) {
    const int64_t h = int64_t(fine.shape(0)), w = int64_t(fine.shape(1));
    if (int64_t(out.shape(0)) != h || int64_t(out.shape(1)) != w) throw nb::value_error("grids of different shapes");
    if (k < 1 || frame < 0) throw nb::value_error("k >= 1 and frame >= 0");
    const float* in = fine.data();
    float* o = out.data();
    nb::gil_scoped_release release;
    std::fill(o, o + h * w, 0.0f);
    if (h <= 2 * frame || w <= 2 * frame) return;
    // only the cells inside the frame are kept; they read rows [frame, h) of the row pass
    const int64_t x0 = frame, x1 = w - frame, y0 = frame, y1 = h - frame;
    std::vector<float> along(size_t(h * w));  // max over [x, x + k) in each row
    for (int64_t y = y0; y < h; ++y)
        for (int64_t x = x0; x < x1; ++x) {
            float m = 0.0f;  // scipy's constant mode: zeros beyond the grid
            const float* row = in + y * w;
            for (int64_t i = x, end = std::min(x + k, w); i < end; ++i) m = std::max(m, row[i]);
            along[size_t(y * w + x)] = m;
        }
    for (int64_t y = y0; y < y1; ++y)
        for (int64_t x = x0; x < x1; ++x) {
            float m = 0.0f;
            for (int64_t j = y, end = std::min(y + k, h); j < end; ++j) m = std::max(m, along[size_t(j * w + x)]);
            o[y * w + x] = m;
        }
}

}  // namespace

void bind_likelihood_grid(nb::module_& m) {
    m.def("likelihood_fill", &likelihood_fill, nb::arg("cells"), nb::arg("grid"), nb::arg("frame"), nb::arg("table"));
    m.def("max_filter_framed", &max_filter_framed, nb::arg("fine"), nb::arg("out"), nb::arg("k"), nb::arg("frame"));
}

}  // namespace fmcwlog
