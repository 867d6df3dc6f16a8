// Ray casting of one scan into log-odds increments, and their application to a grid: the compiled
// twins of fmcwlog/kernels/occupancy.py cast_numpy and OccupancyGrid._apply_numpy.
//
// Frames and units as there: the map frame, metres; lattice cell (ix, iy) covers
// [ix res, (ix+1) res) x [iy res, (iy+1) res). Every coordinate is computed with the numpy
// reference's operations in its order (no FMA: CMakeLists.txt), so the samples fall in the same
// cells and the cells, counts and float32 increments are those of the reference, bit for bit.
#include "common.hpp"
#include "deskew.hpp"
#include "kernels.hpp"

#include <nanobind/stl/optional.h>
#include <nanobind/stl/tuple.h>
#include <nanobind/stl/vector.h>

#include <cstring>

#if defined(__SSE2__)
#include <emmintrin.h>
#endif
#if defined(__x86_64__) && (defined(__GNUC__) || defined(__clang__))
#include <immintrin.h>
#define FMCWLOG_OCCUPANCY_AVX2 1
#endif

namespace fmcwlog {

namespace {

using Cells = nb::ndarray<nb::numpy, int32_t, nb::ndim<1>>;
using Increments = nb::ndarray<nb::numpy, float, nb::ndim<1>>;
using InCells = nb::ndarray<const int32_t, nb::shape<-1>, nb::c_contig, nb::device::cpu>;
using InIncrements = nb::ndarray<const float, nb::shape<-1>, nb::c_contig, nb::device::cpu>;
using LogOdds = nb::ndarray<float, nb::ndim<2>, nb::c_contig, nb::device::cpu>;
using Observed = nb::ndarray<bool, nb::ndim<2>, nb::c_contig, nb::device::cpu>;

// A numpy array that owns the vector's buffer (freed with the array).
template <class T>
nb::ndarray<nb::numpy, T, nb::ndim<1>> owned(std::vector<T>&& values) {
    auto* heap = new std::vector<T>(std::move(values));
    nb::capsule owner(heap, [](void* p) noexcept { delete static_cast<std::vector<T>*>(p); });
    return nb::ndarray<nb::numpy, T, nb::ndim<1>>(heap->data(), {heap->size()}, owner);
}

// One beam (occupancy.rays): its direction, length, whether it ends in a hit, its end cell and
// its number of samples (whole numbers held as doubles until the scan's window is known to fit).
struct Ray {
    double ux, uy, length, ex, ey, samples;
    bool hit;
};

// The lattice cell of a ray's sample at s (m) along it: cast_numpy's floor((o + u s) / res).
inline double sample_cell(double u, double s, double o, double res) { return std::floor((u * s + o) / res); }

// floor(q) for a q well inside int64's range.
inline int64_t floor_int(double q) {
    const int64_t t = int64_t(q);
    return t - int64_t(double(t) > q);
}

// The fast cells: q = a (1 / res) is within 3.3e-16 |a / res| of the rounded a / res that
// cast_numpy floors (two roundings each way), so where q lies farther than `guard` >= 1e-12 (1 + |q|)
// from a whole number both have one floor; nearer, the division decides.
inline bool clear_of_whole(double frac, double guard) { return frac > guard && frac < 1.0 - guard; }

// The guard of a ray's samples: |q| is largest at a ray's first or last sample (monotone).
inline double ray_guard(const Ray& r, double ox, double oy, double s_last, double inv_res) {
    const double qmax = std::max({std::fabs(ox * inv_res), std::fabs(oy * inv_res), std::fabs((r.ux * s_last + ox) * inv_res),
                                  std::fabs((r.uy * s_last + oy) * inv_res)});
    return 1e-12 * (2.0 + qmax);
}

// int64_t(sample_cell(u, s, o, res)), the same number, for a sample inside the scan's window.
inline int64_t fast_sample_cell(double u, double s, double o, double res, double inv_res, double guard) {
    const double a = u * s + o;
    const double q = a * inv_res;
    const int64_t c = floor_int(q);
    if (clear_of_whole(q - double(c), guard)) return c;
    return floor_int(a / res);
}

struct ScanParams {
    double res, step, l_occ, l_free;
    bool has_max_range;
    double max_range;
    bool protect_hits;
};

// occupancy.rays, then the direction u = d / length (0 for a zero-length beam), the end cell
// floor((o + d) / res) and the sample count floor(length / step) + 1 of cast_numpy.
Ray make_ray(double px, double py, double ox, double oy, const ScanParams& p) {
    double dx = px - ox, dy = py - oy;
    double length = std::hypot(dx, dy);
    bool hit = true;
    if (p.has_max_range && length > p.max_range) {
        const double f = p.max_range / length;
        dx *= f;
        dy *= f;
        length = p.max_range;
        hit = false;
    }
    Ray r;
    r.ux = length > 0.0 ? dx / length : 0.0;
    r.uy = length > 0.0 ? dy / length : 0.0;
    r.length = length;
    r.ex = std::floor((ox + dx) / p.res);
    r.ey = std::floor((oy + dy) / p.res);
    r.samples = std::floor(length / p.step) + 1.0;
    r.hit = hit;
    return r;
}

// Sample k of a ray (of `last` + 1) at k step, the last cut at the ray's length (cast_numpy's
// min(s, length)).
inline double sample_s(const Ray& r, int64_t k, int64_t last, double step) {
    const double s = double(k) * step;
    return k == last ? std::min(s, r.length) : s;
}

// A window cell's count of rays that traverse it (in a sample not in their end cell) and that end
// in it with a hit: 16 bits each where the scan has fewer than 2^16 rays (neither count can exceed
// the rays), so that the window takes half the cache, else 32.
template <class T>
struct CountsOf {
    T free, hit;
};
using Counts16 = CountsOf<uint16_t>;
using Counts32 = CountsOf<int32_t>;
constexpr size_t kKeptCells = size_t(1) << 21;  // at most 16 MB kept
// the window buffers a thread keeps (clean between casts)
template <class C>
std::vector<C>& kept_counts() {
    static thread_local std::vector<C> counts;
    return counts;
}

// The cells of a window with nonzero counts (touched), and those with a hit among them.
struct Tally {
    size_t touched = 0, hits = 0;
};

// The widest sample loop count_ray may use: 3 AVX-512, 2 AVX2 (each where the CPU has it), 1 SSE2,
// 0 scalar. They give the same cells (the same operations per sample); tests set lower ones to
// compare them.
int g_simd = 3;

// A ray's new cells that are not its end cell, in order (count_ray), as window flat indices (the
// window holds at most 2^31 - 1 cells).
struct Kept {
    int32_t* cells;
    size_t n;
    int64_t prev, end_flat;
    void keep(int64_t flat) {  // no branch: one on each sample would mispredict often
        cells[n] = int32_t(flat);
        n += size_t((flat != prev) & (flat != end_flat));
        prev = flat;
    }
};

#if defined(FMCWLOG_OCCUPANCY_AVX2)
// kPack[m]: the byte shuffle that moves the int32 lanes set in m (4 bits) to the front, in order.
struct PackTable {
    alignas(16) uint8_t at[16][16];
    constexpr PackTable() : at() {
        for (int m = 0; m < 16; ++m) {
            int to = 0;
            for (int lane = 0; lane < 4; ++lane) {
                if (!(m & (1 << lane))) continue;
                for (int b = 0; b < 4; ++b) at[m][4 * to + b] = uint8_t(4 * lane + b);
                ++to;
            }
            for (int b = 4 * to; b < 16; ++b) at[m][b] = 0x80;
        }
    }
};
constexpr PackTable kPackTable{};
constexpr const uint8_t (&kPack)[16][16] = kPackTable.at;

// count_ray's samples 0, 1, ... four at a time (AVX2), before the last; returns the next sample.
// The window's cells lie within +-2^30 and it holds at most 2^31 - 1 cells (int32 lanes).
__attribute__((target("avx2"))) int64_t keep_samples_avx2(const Ray& r, double ox, double oy, double res, double step,
                                                           double inv_res, double guard, int64_t last, int64_t x0,
                                                           int64_t y0, int64_t ww, Kept& kept) {
    const __m256d ux = _mm256_set1_pd(r.ux), uy = _mm256_set1_pd(r.uy), vox = _mm256_set1_pd(ox),
                  voy = _mm256_set1_pd(oy), inv = _mm256_set1_pd(inv_res), lo = _mm256_set1_pd(guard),
                  hi = _mm256_set1_pd(1.0 - guard), vstep = _mm256_set1_pd(step), lanes = _mm256_set_pd(3.0, 2.0, 1.0, 0.0);
    const __m128i vx0 = _mm_set1_epi32(int32_t(x0)), vy0 = _mm_set1_epi32(int32_t(y0)), vww = _mm_set1_epi32(int32_t(ww));
    const __m128i vend = _mm_set1_epi32(int32_t(kept.end_flat));
    // the kept cells' count and the cell before (lane 3) held in registers, not in `kept`
    int32_t* out = kept.cells;
    size_t n = kept.n;
    __m128i before_last = _mm_set1_epi32(int32_t(kept.prev));
    int64_t k = 0;
    for (; k + 3 < last; k += 4) {
        const __m256d s = _mm256_mul_pd(_mm256_add_pd(_mm256_set1_pd(double(k)), lanes), vstep);  // double(k + j) step
        const __m256d ax = _mm256_add_pd(_mm256_mul_pd(ux, s), vox), ay = _mm256_add_pd(_mm256_mul_pd(uy, s), voy);
        const __m256d qx = _mm256_mul_pd(ax, inv), qy = _mm256_mul_pd(ay, inv);
        const __m256d fx = _mm256_floor_pd(qx), fy = _mm256_floor_pd(qy);
        const __m256d rx = _mm256_sub_pd(qx, fx), ry = _mm256_sub_pd(qy, fy);
        const __m256d clear = _mm256_and_pd(
            _mm256_and_pd(_mm256_cmp_pd(rx, lo, _CMP_GT_OQ), _mm256_cmp_pd(rx, hi, _CMP_LT_OQ)),
            _mm256_and_pd(_mm256_cmp_pd(ry, lo, _CMP_GT_OQ), _mm256_cmp_pd(ry, hi, _CMP_LT_OQ)));
        if (_mm256_movemask_pd(clear) == 15) {
            // the four cells, each kept where it differs from the one before and from the end cell:
            // compared side by side, the kept ones packed to the front and stored at once
            const __m128i cx = _mm_sub_epi32(_mm256_cvttpd_epi32(fx), vx0), cy = _mm_sub_epi32(_mm256_cvttpd_epi32(fy), vy0);
            const __m128i flat = _mm_add_epi32(_mm_mullo_epi32(cy, vww), cx);
            const __m128i before = _mm_alignr_epi8(flat, before_last, 12);  // the cell before each: prev, f0, f1, f2
            const __m128i drop = _mm_or_si128(_mm_cmpeq_epi32(flat, before), _mm_cmpeq_epi32(flat, vend));
            const int keep = ~_mm_movemask_ps(_mm_castsi128_ps(drop)) & 15;
            _mm_storeu_si128(reinterpret_cast<__m128i*>(out + n),
                             _mm_shuffle_epi8(flat, _mm_load_si128(reinterpret_cast<const __m128i*>(kPack[keep]))));
            n += size_t(__builtin_popcount(unsigned(keep)));
            before_last = flat;
        } else {  // near a cell's edge: the division decides (rare)
            alignas(32) double px[4], py[4];
            _mm256_store_pd(px, ax);
            _mm256_store_pd(py, ay);
            kept.n = n;
            kept.prev = _mm_cvtsi128_si32(_mm_shuffle_epi32(before_last, 3));
            for (int j = 0; j < 4; ++j) kept.keep((floor_int(py[j] / res) - y0) * ww + (floor_int(px[j] / res) - x0));
            n = kept.n;
            before_last = _mm_set1_epi32(int32_t(kept.prev));
        }
    }
    kept.n = n;
    kept.prev = _mm_cvtsi128_si32(_mm_shuffle_epi32(before_last, 3));
    return k;
}

// keep_samples_avx2 eight at a time (AVX-512: the same operations per lane, the kept cells packed
// by the CPU); returns the next sample.
__attribute__((target("avx512f,avx512vl"))) int64_t keep_samples_avx512(const Ray& r, double ox, double oy, double res,
                                                                           double step, double inv_res, double guard,
                                                                           int64_t last, int64_t x0, int64_t y0, int64_t ww,
                                                                           Kept& kept) {
    const __m512d ux = _mm512_set1_pd(r.ux), uy = _mm512_set1_pd(r.uy), vox = _mm512_set1_pd(ox),
                  voy = _mm512_set1_pd(oy), inv = _mm512_set1_pd(inv_res), lo = _mm512_set1_pd(guard),
                  hi = _mm512_set1_pd(1.0 - guard), vstep = _mm512_set1_pd(step),
                  lanes = _mm512_set_pd(7.0, 6.0, 5.0, 4.0, 3.0, 2.0, 1.0, 0.0);
    const __m256i vx0 = _mm256_set1_epi32(int32_t(x0)), vy0 = _mm256_set1_epi32(int32_t(y0)),
                  vww = _mm256_set1_epi32(int32_t(ww)), vend = _mm256_set1_epi32(int32_t(kept.end_flat));
    constexpr int kFloor = _MM_FROUND_TO_NEG_INF | _MM_FROUND_NO_EXC;
    int32_t* out = kept.cells;
    size_t n = kept.n;
    __m256i before_last = _mm256_set1_epi32(int32_t(kept.prev));  // lane 7: the cell before
    int64_t k = 0;
    for (; k + 7 < last; k += 8) {
        const __m512d s = _mm512_mul_pd(_mm512_add_pd(_mm512_set1_pd(double(k)), lanes), vstep);  // double(k + j) step
        const __m512d ax = _mm512_add_pd(_mm512_mul_pd(ux, s), vox), ay = _mm512_add_pd(_mm512_mul_pd(uy, s), voy);
        const __m512d qx = _mm512_mul_pd(ax, inv), qy = _mm512_mul_pd(ay, inv);
        const __m512d fx = _mm512_roundscale_pd(qx, kFloor), fy = _mm512_roundscale_pd(qy, kFloor);
        const __m512d rx = _mm512_sub_pd(qx, fx), ry = _mm512_sub_pd(qy, fy);
        const __mmask8 clear = _mm512_cmp_pd_mask(rx, lo, _CMP_GT_OQ) & _mm512_cmp_pd_mask(rx, hi, _CMP_LT_OQ) &
                               _mm512_cmp_pd_mask(ry, lo, _CMP_GT_OQ) & _mm512_cmp_pd_mask(ry, hi, _CMP_LT_OQ);
        if (clear == 0xFF) {
            const __m256i cx = _mm256_sub_epi32(_mm512_cvttpd_epi32(fx), vx0), cy = _mm256_sub_epi32(_mm512_cvttpd_epi32(fy), vy0);
            const __m256i flat = _mm256_add_epi32(_mm256_mullo_epi32(cy, vww), cx);
            const __m256i before = _mm256_alignr_epi32(flat, before_last, 7);  // prev, f0, ..., f6
            const __mmask8 keep = __mmask8(~(_mm256_cmpeq_epi32_mask(flat, before) | _mm256_cmpeq_epi32_mask(flat, vend)));
            _mm256_storeu_si256(reinterpret_cast<__m256i*>(out + n), _mm256_maskz_compress_epi32(keep, flat));
            n += size_t(__builtin_popcount(unsigned(keep)));
            before_last = flat;
        } else {  // near a cell's edge: the division decides (rare)
            alignas(64) double px[8], py[8];
            _mm512_store_pd(px, ax);
            _mm512_store_pd(py, ay);
            kept.n = n;
            kept.prev = _mm256_extract_epi32(before_last, 7);
            for (int j = 0; j < 8; ++j) kept.keep((floor_int(py[j] / res) - y0) * ww + (floor_int(px[j] / res) - x0));
            n = kept.n;
            before_last = _mm256_set1_epi32(int32_t(kept.prev));
        }
    }
    kept.n = n;
    kept.prev = _mm256_extract_epi32(before_last, 7);
    return k;
}

bool has_avx512() {
    static const bool yes = __builtin_cpu_supports("avx512f") && __builtin_cpu_supports("avx512vl");
    return yes;
}

bool has_avx2() {
    static const bool yes = __builtin_cpu_supports("avx2");
    return yes;
}
#endif

// cast_numpy's free and hit counts of one ray into the window (x0, y0, width ww) `counts`: one free
// update per (ray, cell) at the cell's first sample, not in the ray's end cell (cast_numpy excludes
// the end cell too, or, where protect_hits and every ray hits, zeroes it as a hit cell: the same
// increments); the cells along a ray are monotone, so its samples in a cell are consecutive.
// `int32_cells`: the window's cells lie within +-2^30 (SSE2 converts through int32).
// `tally` counts the window cells reached for the first time (touched) and first hit (hits).
template <class C>
void count_ray(const Ray& r, double ox, double oy, int64_t x0, int64_t y0, int64_t ww, const ScanParams& p,
               bool int32_cells, C* counts, Tally& tally) {
    const int64_t end_flat = (int64_t(r.ey) - y0) * ww + (int64_t(r.ex) - x0);
    if (r.hit) {
        C& c = counts[end_flat];
        tally.touched += size_t((c.free == 0) & (c.hit == 0));
        tally.hits += size_t(c.hit == 0);
        ++c.hit;
    }
    const int64_t last = int64_t(r.samples) - 1;
    const double inv_res = 1.0 / p.res;
    const double guard = ray_guard(r, ox, oy, std::min(double(last) * p.step, r.length), inv_res);
    // the ray's new cells that are not its end cell, in order, then their counts; a ray has at
    // most its samples' cells
    static thread_local std::vector<int32_t> t_cells;  // 8 spare: the AVX-512 loop stores 8 cells at once
    if (t_cells.size() < size_t(last) + 10) t_cells.resize(size_t(last) + 10);
    Kept kept{t_cells.data(), 0, -1, end_flat};
    int64_t k = 0;
#if defined(FMCWLOG_OCCUPANCY_AVX2)
    if (int32_cells && g_simd >= 3 && has_avx512())
        k = keep_samples_avx512(r, ox, oy, p.res, p.step, inv_res, guard, last, x0, y0, ww, kept);
    else if (int32_cells && g_simd >= 2 && has_avx2())
        k = keep_samples_avx2(r, ox, oy, p.res, p.step, inv_res, guard, last, x0, y0, ww, kept);
#endif
#if defined(__SSE2__)
    if (int32_cells && g_simd >= 1) {  // samples k and k + 1 side by side, the same operations per lane
        const __m128d ux = _mm_set1_pd(r.ux), uy = _mm_set1_pd(r.uy), vox = _mm_set1_pd(ox), voy = _mm_set1_pd(oy);
        const __m128d inv = _mm_set1_pd(inv_res), one = _mm_set1_pd(1.0);
        const __m128d lo = _mm_set1_pd(guard), hi = _mm_set1_pd(1.0 - guard), step = _mm_set1_pd(p.step);
        auto floor_clear = [&](__m128d q, int& clear) {  // floor(q), and whether clear_of_whole in both lanes
            const __m128d t = _mm_cvtepi32_pd(_mm_cvttpd_epi32(q));
            const __m128d c = _mm_sub_pd(t, _mm_and_pd(_mm_cmpgt_pd(t, q), one));
            const __m128d frac = _mm_sub_pd(q, c);
            clear &= _mm_movemask_pd(_mm_and_pd(_mm_cmpgt_pd(frac, lo), _mm_cmplt_pd(frac, hi)));
            return _mm_cvttpd_epi32(c);
        };
        auto keep = [&](int64_t cx, int64_t cy) { kept.keep((cy - y0) * ww + (cx - x0)); };
        for (; k + 1 < last; k += 2) {  // the last sample (cut at the length) is left to the scalar code
            const __m128d s = _mm_mul_pd(_mm_set_pd(double(k + 1), double(k)), step);
            const __m128d ax = _mm_add_pd(_mm_mul_pd(ux, s), vox), ay = _mm_add_pd(_mm_mul_pd(uy, s), voy);
            int clear = 3;
            const __m128i cx = floor_clear(_mm_mul_pd(ax, inv), clear), cy = floor_clear(_mm_mul_pd(ay, inv), clear);
            if (clear == 3) {
                keep(_mm_cvtsi128_si32(cx), _mm_cvtsi128_si32(cy));
                keep(_mm_cvtsi128_si32(_mm_shuffle_epi32(cx, 1)), _mm_cvtsi128_si32(_mm_shuffle_epi32(cy, 1)));
            } else {
                keep(floor_int(_mm_cvtsd_f64(ax) / p.res), floor_int(_mm_cvtsd_f64(ay) / p.res));
                keep(floor_int(_mm_cvtsd_f64(_mm_unpackhi_pd(ax, ax)) / p.res),
                     floor_int(_mm_cvtsd_f64(_mm_unpackhi_pd(ay, ay)) / p.res));
            }
        }
    }
#endif
    for (; k <= last; ++k) {
        const double s = sample_s(r, k, last, p.step);
        kept.keep((fast_sample_cell(r.uy, s, oy, p.res, inv_res, guard) - y0) * ww +
                  (fast_sample_cell(r.ux, s, ox, p.res, inv_res, guard) - x0));
    }
    size_t touched = 0;
    for (size_t i = 0; i < kept.n; ++i) {
        C& c = counts[kept.cells[i]];
        touched += size_t((c.free == 0) & (c.hit == 0));
        ++c.free;
    }
    tally.touched += touched;
}

// cast_numpy's cells and increments from the window's counts (`size` cells, width ww), which are
// zeroed on the way: the cells only traversed, by flat index, then the hit cells, by flat index
// (protect_hits: a hit cell gets no free update). `tally` says how many of each there are, so the
// outputs are sized exactly (they are kept with the scan until every grid holding it has applied
// them) and each cell is written without a branch to the traversed run's next slot, taken where it
// belongs there (the few hit cells go to their own run). 32 bytes of empty cells are skipped at once.
// `rays`: the scan's, the most a count can be.
template <class C>
void collect(C* counts, int64_t size, int64_t ww, size_t rays, const ScanParams& p, const Tally& tally,
             std::vector<int32_t>& rows, std::vector<int32_t>& cols, std::vector<float>& increment) {
    const size_t traversed_only = tally.touched - tally.hits, total = tally.touched;
    // one spare slot: the traversed run's slot past its last cell is written (unused) until the end
    rows.resize(total + 1);
    cols.resize(total + 1);
    increment.resize(total + 1);
    static thread_local std::vector<int32_t> t_hit_rows, t_hit_cols;
    static thread_local std::vector<float> t_hit_inc;
    if (t_hit_rows.size() < tally.hits + 1) {
        t_hit_rows.resize(tally.hits + 1);
        t_hit_cols.resize(tally.hits + 1);
        t_hit_inc.resize(tally.hits + 1);
    }
    int32_t* fr = rows.data();
    int32_t* fc = cols.data();
    float* fi = increment.data();
    int32_t* hr = t_hit_rows.data();
    int32_t* hc = t_hit_cols.data();
    float* hi = t_hit_inc.data();
    size_t f = 0, h = 0;  // where the next traversed-only and hit cell go
    // a traversed-only cell's increment by its count (at most one a ray): float(l_free count)
    static thread_local std::vector<float> t_free_inc;
    t_free_inc.resize(rays + 1);
    for (size_t k = 0; k <= rays; ++k) t_free_inc[k] = float(p.l_free * double(k));
    const float* free_inc = t_free_inc.data();
    const double free_scale = p.protect_hits ? 0.0 : 1.0;
    auto take = [&](int32_t row, int32_t col, C k) {
        fr[f] = row;
        fc[f] = col;
        fi[f] = free_inc[k.free];
        f += size_t((k.hit == 0) & (k.free != 0));
        if (k.hit != 0) {  // few: about one a ray
            hr[h] = row;
            hc[h] = col;
            hi[h++] = float(p.l_free * (free_scale * double(k.free)) + p.l_occ * double(k.hit));
        }
    };
    const int32_t height = int32_t(size / ww), width = int32_t(ww);
    for (int32_t row = 0; row < height; ++row) {
        C* line = counts + int64_t(row) * ww;
        int32_t col = 0;
        constexpr int32_t kBlock = int32_t(32 / sizeof(C));  // cells in 32 bytes
        for (; col + kBlock <= width; col += kBlock) {
            uint64_t w[4];
            std::memcpy(w, line + col, sizeof w);
            if ((w[0] | w[1] | w[2] | w[3]) == 0) continue;
            for (int32_t j = 0; j < kBlock; ++j) take(row, col + j, line[col + j]);
            std::memset(static_cast<void*>(line + col), 0, sizeof w);
        }
        for (; col < width; ++col) {
            take(row, col, line[col]);
            line[col] = C{0, 0};
        }
    }
    std::memcpy(fr + traversed_only, hr, tally.hits * sizeof(int32_t));
    std::memcpy(fc + traversed_only, hc, tally.hits * sizeof(int32_t));
    std::memcpy(fi + traversed_only, hi, tally.hits * sizeof(float));
    rows.resize(total);
    cols.resize(total);
    increment.resize(total);
}

// count_ray over the scan's rays into its window (x0, y0, width ww, `size` cells), then collect: in
// a buffer kept by the thread up to kKeptCells cells (clean between casts), else in its own.
template <class C>
void count_window(const std::vector<Ray>& rays, double ox, double oy, int64_t x0, int64_t y0, int64_t ww, int64_t size,
                  const ScanParams& p, bool int32_cells, std::vector<int32_t>& rows, std::vector<int32_t>& cols,
                  std::vector<float>& increment) {
    std::vector<C> own;
    std::vector<C>& counts = size_t(size) <= kKeptCells ? kept_counts<C>() : own;
    if (counts.size() < size_t(size)) counts.resize(size_t(size));
    try {
        Tally tally;
        for (const Ray& r : rays) count_ray(r, ox, oy, x0, y0, ww, p, int32_cells, counts.data(), tally);
        collect(counts.data(), size, ww, rays.size(), p, tally, rows, cols, increment);
    } catch (...) {  // out of memory: the kept buffer may hold counts, so let it go
        kept_counts<C>() = std::vector<C>();
        throw;
    }
}

// cast_numpy: (y0, x0, rows, cols, increment) of the scan, or None where a coordinate is not
// finite or the scan's window of the lattice would exceed max_cells (the caller casts in numpy).
nb::object occupancy_cast(Points points, double ox, double oy, double resolution, double step_fraction, double l_occ,
                          double l_free, bool has_max_range, double max_range, bool protect_hits, int64_t max_cells) {
    const size_t n = points.shape(0);
    const double* xy = points.data();
    if (n == 0 || !std::isfinite(ox) || !std::isfinite(oy)) return nb::none();
    for (size_t i = 0; i < 2 * n; ++i)
        if (!std::isfinite(xy[i])) return nb::none();
    const ScanParams p{resolution, step_fraction * resolution, l_occ, l_free, has_max_range, max_range, protect_hits};
    std::vector<int32_t> rows, cols;
    std::vector<float> increment;
    int64_t x0 = 0, y0 = 0;
    bool fits = true;
    {
        nb::gil_scoped_release release;
        std::vector<Ray> rays(n);
        // the scan's window: a ray's cells are monotone in s, so its extreme cells are those of
        // its first and last samples; the end cells join them
        double wx0 = kInf, wy0 = kInf, wx1 = -kInf, wy1 = -kInf;
        for (size_t i = 0; i < n; ++i) {
            Ray& r = rays[i];
            r = make_ray(xy[2 * i], xy[2 * i + 1], ox, oy, p);
            const double s_last = std::min((r.samples - 1.0) * p.step, r.length);
            const double cx[3] = {sample_cell(r.ux, 0.0, ox, p.res), sample_cell(r.ux, s_last, ox, p.res), r.ex};
            const double cy[3] = {sample_cell(r.uy, 0.0, oy, p.res), sample_cell(r.uy, s_last, oy, p.res), r.ey};
            for (int j = 0; j < 3; ++j) {
                wx0 = std::min(wx0, cx[j]);
                wx1 = std::max(wx1, cx[j]);
                wy0 = std::min(wy0, cy[j]);
                wy1 = std::max(wy1, cy[j]);
            }
        }
        const double cells = (wx1 - wx0 + 1.0) * (wy1 - wy0 + 1.0);
        fits = cells <= double(max_cells) && cells <= double(std::numeric_limits<int32_t>::max());
        if (fits) {
            x0 = int64_t(wx0);
            y0 = int64_t(wy0);
            const int64_t ww = int64_t(wx1) + 1 - x0, size = (int64_t(wy1) + 1 - y0) * ww;
            const double small = double(int64_t(1) << 30);
            const bool int32_cells = wx0 > -small && wy0 > -small && wx1 < small && wy1 < small;
            if (n < 65536)
                count_window<Counts16>(rays, ox, oy, x0, y0, ww, size, p, int32_cells, rows, cols, increment);
            else
                count_window<Counts32>(rays, ox, oy, x0, y0, ww, size, p, int32_cells, rows, cols, increment);
        }
    }
    if (!fits) return nb::none();
    return nb::make_tuple(y0, x0, owned(std::move(rows)), owned(std::move(cols)), owned(std::move(increment)));
}

// OccupancyGrid._apply_numpy: cell (row0 + rows[i], col0 + cols[i]) of the grid gets increment[i]
// in float32, clamped to [l_min, l_max] (as float32), and is marked observed.
void occupancy_apply(LogOdds log_odds, Observed observed, int64_t row0, int64_t col0, InCells rows, InCells cols,
                     InIncrements increment, double l_min, double l_max) {
    const size_t m = rows.shape(0);
    if (cols.shape(0) != m || increment.shape(0) != m)
        throw nb::value_error("occupancy_apply: rows, cols and increment must have one length");
    const int64_t height = int64_t(log_odds.shape(0)), width = int64_t(log_odds.shape(1));
    if (int64_t(observed.shape(0)) != height || int64_t(observed.shape(1)) != width)
        throw nb::value_error("occupancy_apply: log_odds and observed must have one shape");
    const int32_t* r = rows.data();
    const int32_t* c = cols.data();
    if (m == 0) return;
    // every cell inside the grid, from the extremes of rows and cols (a loop without branches)
    int32_t r_lo = r[0], r_hi = r[0], c_lo = c[0], c_hi = c[0];
    for (size_t i = 0; i < m; ++i) {
        r_lo = std::min(r_lo, r[i]);
        r_hi = std::max(r_hi, r[i]);
        c_lo = std::min(c_lo, c[i]);
        c_hi = std::max(c_hi, c[i]);
    }
    if (row0 + r_lo < 0 || row0 + r_hi >= height || col0 + c_lo < 0 || col0 + c_hi >= width)
        throw nb::index_error("occupancy_apply: a cell lies outside the grid");
    const float lo = float(l_min), hi = float(l_max);
    // the window's cell (0, 0) in the grid: row0 width + col0 >= -(r_lo width + c_lo), so
    // corner + rows[i] width + cols[i] is a cell of the grid
    const int64_t corner = row0 * width + col0;
    float* value = log_odds.data();
    bool* seen = observed.data();
    const float* inc = increment.data();
    nb::gil_scoped_release release;
    for (size_t i = 0; i < m; ++i) {
        const int64_t at = corner + int64_t(r[i]) * width + c[i];
        value[at] = std::min(std::max(value[at] + inc[i], lo), hi);
        seen[at] = true;
    }
}

// --- lookups: fmcwlog/frontend/recent_grid.py --------------------------------------------------

using GridLogOdds = nb::ndarray<const float, nb::ndim<2>, nb::c_contig, nb::device::cpu>;
using Flags = nb::ndarray<const bool, nb::shape<-1>, nb::c_contig, nb::device::cpu>;
using OutFlags = nb::ndarray<bool, nb::shape<-1>, nb::c_contig, nb::device::cpu>;
using OutValues = nb::ndarray<float, nb::shape<-1>, nb::c_contig, nb::device::cpu>;

// _GridView: a grid's log-odds by lattice cell, 0 outside it.
struct View {
    const float* data;
    int64_t height, width, ix0, iy0;
    float at(int64_t ix, int64_t iy) const {
        const uint64_t r = uint64_t(iy - iy0), c = uint64_t(ix - ix0);  // negatives wrap past, as there
        return r < uint64_t(height) && c < uint64_t(width) ? data[r * uint64_t(width) + c] : 0.0f;
    }
};

std::vector<View> views(const std::vector<GridLogOdds>& grids, const std::vector<int64_t>& ix0,
                        const std::vector<int64_t>& iy0) {
    if (ix0.size() != grids.size() || iy0.size() != grids.size())
        throw nb::value_error("occupancy lookups: one ix0 and one iy0 per grid");
    std::vector<View> out;
    for (size_t g = 0; g < grids.size(); ++g)
        out.push_back(View{grids[g].data(), int64_t(grids[g].shape(0)), int64_t(grids[g].shape(1)), ix0[g], iy0[g]});
    return out;
}

// occupancy.lattice_cells of one point: floor(xy / res) as int64. Where that is not within +-2^62
// (not finite, or beyond any grid: numpy's conversion gives some far or wrapped index there),
// `far` is set: every lookup about it gives 0.
inline void lattice_cell(double x, double y, double res, int64_t& ix, int64_t& iy, bool& far) {
    const double qx = std::floor(x / res), qy = std::floor(y / res), lim = 4611686018427387904.0;
    far = !(std::fabs(qx) < lim && std::fabs(qy) < lim);
    ix = far ? 0 : int64_t(qx);
    iy = far ? 0 : int64_t(qy);
}

// The summed log-odds (double, in the grids' order, as recent_grid adds them) of cell (ix, iy).
inline double summed(const std::vector<View>& grids, int64_t ix, int64_t iy) {
    double sum = 0.0;
    for (const View& v : grids) sum += double(v.at(ix, iy));
    return sum;
}

// occupancy.scan_cells_numpy: the lattice cells (ix, iy) of the lower-left and upper-right corners of the
// box holding the sensor (ox, oy) and every beam's end (occupancy.rays: cut at max_range where
// has_max_range), floor(corner / resolution). None where a coordinate is not finite or a cell is
// beyond +-2^62 (numpy's conversion decides there).
nb::object occupancy_scan_cells(Points points, double ox, double oy, bool has_max_range, double max_range,
                                double resolution) {
    const size_t n = points.shape(0);
    const double* p = points.data();
    double x0 = ox, y0 = oy, x1 = ox, y1 = oy;
    bool finite = std::isfinite(ox) && std::isfinite(oy);
    {
        nb::gil_scoped_release release;
        for (size_t i = 0; i < n && finite; ++i) {
            double dx = p[2 * i] - ox, dy = p[2 * i + 1] - oy;
            if (has_max_range) {
                const double length = std::hypot(dx, dy);
                if (length > max_range) {
                    const double k = max_range / length;
                    dx *= k;
                    dy *= k;
                }
            }
            const double ex = ox + dx, ey = oy + dy;
            finite = std::isfinite(ex) && std::isfinite(ey);
            x0 = std::min(x0, ex);
            y0 = std::min(y0, ey);
            x1 = std::max(x1, ex);
            y1 = std::max(y1, ey);
        }
    }
    const double lim = 4611686018427387904.0;
    const double c[4] = {std::floor(x0 / resolution), std::floor(y0 / resolution), std::floor(x1 / resolution),
                         std::floor(y1 / resolution)};
    for (double q : c)
        if (!finite || !(std::fabs(q) < lim)) return nb::none();
    return nb::make_tuple(int64_t(c[0]), int64_t(c[1]), int64_t(c[2]), int64_t(c[3]));
}

// RecentOccupancy.seen_free of one candidate point (x, y): the summed log-odds of its cell and of
// each of its 8 neighbours are all <= threshold.
inline bool seen_free_at(const std::vector<View>& v, double x, double y, double threshold, double resolution) {
    int64_t ix, iy;
    bool far;
    lattice_cell(x, y, resolution, ix, iy, far);
    bool free = (far ? 0.0 : summed(v, ix, iy)) <= threshold;
    for (int64_t dr = -1; free && dr <= 1; ++dr)
        for (int64_t dc = -1; free && dc <= 1; ++dc) free = (far ? 0.0 : summed(v, ix + dc, iy + dr)) <= threshold;
    return free;
}

// RecentOccupancy.seen_free: out[i] = candidates[i] and seen_free_at the point.
void occupancy_seen_free(const std::vector<GridLogOdds>& grids, const std::vector<int64_t>& ix0,
                         const std::vector<int64_t>& iy0, Points map_xy, Flags candidates, double threshold,
                         double resolution, OutFlags out) {
    const size_t n = map_xy.shape(0);
    if (candidates.shape(0) != n || out.shape(0) != n)
        throw nb::value_error("occupancy_seen_free: candidates and out must have the points' length");
    const std::vector<View> v = views(grids, ix0, iy0);
    const double* xy = map_xy.data();
    const bool* cand = candidates.data();
    bool* o = out.data();
    nb::gil_scoped_release release;
    for (size_t i = 0; i < n; ++i) o[i] = cand[i] && seen_free_at(v, xy[2 * i], xy[2 * i + 1], threshold, resolution);
}

using Column = nb::ndarray<const double, nb::shape<-1>, nb::c_contig, nb::device::cpu>;

// tracking.placed_free_space_numpy: a sweep's points xy (N, 2) seen at t (N,) s de-skewed (twist v m/s,
// omega rad/s; mount (mx, my, myaw)) and placed in the map by (c, s, tx, ty) as deskew.deskew_placed
// places them, written to map_xy (N, 2); and out[i] = the point is a candidate (ranges[i] * yaw_error <=
// tolerance, ranges (N,) m given or np.hypot of xy's rows) and seen_free_at its placed position.
void occupancy_placed_free(const std::vector<GridLogOdds>& grids, const std::vector<int64_t>& ix0,
                           const std::vector<int64_t>& iy0, Points xy, Column t, std::optional<Column> ranges,
                           double v, double omega, double mx, double my, double myaw, double c, double s, double tx,
                           double ty, double yaw_error, double tolerance, double threshold, double resolution,
                           OutPoints map_xy, OutFlags out) {
    const size_t n = xy.shape(0);
    if (t.shape(0) != n || map_xy.shape(0) != n || out.shape(0) != n || (ranges && ranges->shape(0) != n))
        throw nb::value_error("occupancy_placed_free: xy, t, ranges, map_xy and out differ in length");
    const std::vector<View> views_ = views(grids, ix0, iy0);
    const double* p = xy.data();
    const double* tt = t.data();
    const double* r = ranges ? ranges->data() : nullptr;
    double* m = map_xy.data();
    bool* o = out.data();
    nb::gil_scoped_release release;
    const Deskewer at(0.0, v, 0.0, omega, mx, my, myaw);
    for (size_t i = 0; i < n; ++i) {
        double dx, dy;
        at(p[2 * i], p[2 * i + 1], tt[i], dx, dy);
        m[2 * i] = c * dx - s * dy + tx;
        m[2 * i + 1] = s * dx + c * dy + ty;
        const double range = r ? r[i] : std::hypot(p[2 * i], p[2 * i + 1]);
        o[i] = range * yaw_error <= tolerance && seen_free_at(views_, m[2 * i], m[2 * i + 1], threshold, resolution);
    }
}

// local_max_log_odds: the largest float32 log-odds of each point's cell and its 8 neighbours.
void occupancy_local_max(GridLogOdds grid, int64_t ix0, int64_t iy0, Points map_xy, double resolution, OutValues out) {
    const size_t n = map_xy.shape(0);
    if (out.shape(0) != n) throw nb::value_error("occupancy_local_max: out must have the points' length");
    const View v{grid.data(), int64_t(grid.shape(0)), int64_t(grid.shape(1)), ix0, iy0};
    const double* xy = map_xy.data();
    float* o = out.data();
    nb::gil_scoped_release release;
    for (size_t i = 0; i < n; ++i) {
        int64_t ix, iy;
        bool far;
        lattice_cell(xy[2 * i], xy[2 * i + 1], resolution, ix, iy, far);
        float best = -std::numeric_limits<float>::infinity();
        for (int64_t dr = -1; dr <= 1; ++dr)
            for (int64_t dc = -1; dc <= 1; ++dc) best = std::max(best, far ? 0.0f : v.at(ix + dc, iy + dr));
        o[i] = best;
    }
}

// --- export: OccupancyGrid.to_ros_int8 -----------------------------------------------------------

using ObservedIn = nb::ndarray<const bool, nb::ndim<2>, nb::c_contig, nb::device::cpu>;
using OutInt8 = nb::ndarray<int8_t, nb::shape<-1>, nb::c_contig, nb::device::cpu>;

// to_ros_int8_numpy of one observed cell's log-odds l: rint(100 / (1 + exp(-l))) in float64, rounded
// half to even as np.rint. std::exp and numpy's exp may differ in the last bit, so where 100 p lies
// within 1e-7 of a half `sure` is false and numpy decides.
inline int8_t ros_value(float l, bool& sure) {
    const double v = 100.0 * (1.0 / (1.0 + std::exp(-double(l))));
    sure = std::fabs(v - std::floor(v) - 0.5) > 1e-7;
    return int8_t(std::nearbyint(v));
}

// to_ros_int8_numpy into `out` (H W,): -1 where never observed; returns the flat indices of the
// cells numpy must decide (ros_value). The grid holds few distinct values, so each cell looks its
// value up in a small cache by its bits first (the answers do not depend on the cache).
nb::ndarray<nb::numpy, int64_t, nb::ndim<1>> occupancy_ros_int8(GridLogOdds log_odds, ObservedIn observed, OutInt8 out) {
    const size_t n = log_odds.shape(0) * log_odds.shape(1);
    if (observed.shape(0) != log_odds.shape(0) || observed.shape(1) != log_odds.shape(1) || out.shape(0) != n)
        throw nb::value_error("occupancy_ros_int8: log_odds, observed and out must have one size");
    const float* l = log_odds.data();
    const bool* seen = observed.data();
    int8_t* o = out.data();
    std::vector<int64_t> unsure;
    {
        nb::gil_scoped_release release;
        struct Entry {
            uint32_t bits;
            bool filled, sure;
            int8_t value;
        };
        std::vector<Entry> cache(4096, Entry{0, false, false, 0});
        for (size_t i = 0; i < n; ++i) {
            if (!seen[i]) {
                o[i] = -1;
                continue;
            }
            uint32_t bits;
            std::memcpy(&bits, &l[i], sizeof bits);
            Entry& e = cache[(bits ^ (bits >> 12) ^ (bits >> 24)) & 4095u];
            if (!e.filled || e.bits != bits) {
                e.bits = bits;
                e.filled = true;
                e.value = ros_value(l[i], e.sure);
            }
            o[i] = e.value;
            if (!e.sure) unsure.push_back(int64_t(i));
        }
    }
    return owned(std::move(unsure));
}

}  // namespace

void bind_occupancy(nb::module_& m) {
    m.def("occupancy_cast", &occupancy_cast, nb::arg("points"), nb::arg("ox"), nb::arg("oy"), nb::arg("resolution"),
          nb::arg("step_fraction"), nb::arg("l_occ"), nb::arg("l_free"), nb::arg("has_max_range"), nb::arg("max_range"),
          nb::arg("protect_hits"), nb::arg("max_cells"));
    m.def("occupancy_apply", &occupancy_apply, nb::arg("log_odds"), nb::arg("observed"), nb::arg("row0"),
          nb::arg("col0"), nb::arg("rows"), nb::arg("cols"), nb::arg("increment"), nb::arg("l_min"), nb::arg("l_max"));
    m.def(
        "_occupancy_simd",
        [](int level) {
            const int was = g_simd;
            g_simd = level;
            return was;
        },
        nb::arg("level"), "Tests: the widest ray-sample loop (3 AVX-512, 2 AVX2, each where the CPU has it, 1 SSE2, 0 scalar); the old one.");
    m.def("occupancy_ros_int8", &occupancy_ros_int8, nb::arg("log_odds"), nb::arg("observed"), nb::arg("out"));
    m.def("occupancy_seen_free", &occupancy_seen_free, nb::arg("grids"), nb::arg("ix0"), nb::arg("iy0"),
          nb::arg("map_xy"), nb::arg("candidates"), nb::arg("threshold"), nb::arg("resolution"), nb::arg("out"));
    m.def("occupancy_scan_cells", &occupancy_scan_cells, nb::arg("points"), nb::arg("ox"), nb::arg("oy"),
          nb::arg("has_max_range"), nb::arg("max_range"), nb::arg("resolution"));
    m.def("occupancy_placed_free", &occupancy_placed_free, nb::arg("grids"), nb::arg("ix0"), nb::arg("iy0"),
          nb::arg("xy"), nb::arg("t"), nb::arg("ranges").none(), nb::arg("v"), nb::arg("omega"), nb::arg("mx"),
          nb::arg("my"), nb::arg("myaw"), nb::arg("c"), nb::arg("s"), nb::arg("tx"), nb::arg("ty"),
          nb::arg("yaw_error"), nb::arg("tolerance"), nb::arg("threshold"), nb::arg("resolution"), nb::arg("map_xy"),
          nb::arg("out"));
    m.def("occupancy_local_max", &occupancy_local_max, nb::arg("grid"), nb::arg("ix0"), nb::arg("iy0"),
          nb::arg("map_xy"), nb::arg("resolution"), nb::arg("out"));
}

}  // namespace fmcwlog
