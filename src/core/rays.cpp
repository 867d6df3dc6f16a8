// Free space from the last sweeps' rays (fmcwlog/frontend/tracking.py, RecentRays.sweep): which points
// of a sweep lie well short of where an earlier sweep's ray at their bearing ended, then the sweep
// kept in the ring, in one call.
//
// The ring stays in Python (RecentRays' arrays) and is written here in place. The bearing bins are
// tracking.bearing_bins' polynomial arctangent in float32 and the ranges sqrt(dx^2 + dy^2) in float64, the
// reference's IEEE operations in its order (no FMA contraction): the mask and the ring are numpy's to the bit.
#if defined(__x86_64__)
#include <immintrin.h>
#endif

#include <cstring>

#include "common.hpp"
#include "kernels.hpp"

namespace fmcwlog {
namespace {

using Times = nb::ndarray<const double, nb::shape<-1>, nb::c_contig, nb::device::cpu>;
using Ring = nb::ndarray<double, nb::shape<-1, -1>, nb::c_contig, nb::device::cpu>;
using RingOrigins = nb::ndarray<double, nb::shape<-1, -1, 2>, nb::c_contig, nb::device::cpu>;
using OutMask = nb::ndarray<bool, nb::shape<-1>, nb::c_contig, nb::device::cpu>;

// tracking._ATAN: arctan on [0, 1], Abramowitz & Stegun 4.4.47, and the other constants of
// tracking.bearing_bins, as numpy rounds Python's floats to float32
constexpr double kA1 = 0.9998660, kA3 = -0.3302995, kA5 = 0.1801410, kA7 = -0.0851330, kA9 = 0.0208351;
constexpr float kA1f = float(kA1), kA3f = float(kA3), kA5f = float(kA5), kA7f = float(kA7), kA9f = float(kA9);
constexpr float kPif = float(kPi), kHalfPif = float(kPi / 2), kTinyf = float(1e-30);

// tracking.bearing_bins of one direction (float32 throughout); scale = float32(bins / (2 pi)); floor(v)
// for v in [0, bins] (a + pi >= 0) is its truncation
inline int32_t bearing_bin(double dx, double dy, int32_t bins, float scale) {
    const float x = float(dx), y = float(dy);
    const float ax = std::abs(x), ay = std::abs(y);
    const float lo = ay < ax ? ay : ax, hi = ay > ax ? ay : ax;
    const float z = lo / (hi > kTinyf ? hi : kTinyf);
    const float s = z * z;
    float a = ((((kA9f * s + kA7f) * s + kA5f) * s + kA3f) * s + kA1f) * z;
    if (ay > ax) a = kHalfPif - a;
    if (x < 0) a = kPif - a;
    if (y < 0) a = -a;
    const int32_t f = int32_t((a + kPif) * scale);
    return f >= bins ? f - bins : f;
}

// bearing_bin of (dx[i], dy[i]), i < n, into k[i], and where r is given the range sqrt(dx^2 + dy^2)
// (float64) into r[i]
void bearing_bins_plain(const double* dx, const double* dy, int32_t* k, double* r, size_t n, int32_t bins,
                        float scale) {
    for (size_t i = 0; i < n; ++i) {
        k[i] = bearing_bin(dx[i], dy[i], bins, scale);
        if (r) r[i] = std::sqrt(dx[i] * dx[i] + dy[i] * dy[i]);
    }
}

#if defined(__x86_64__)
// the same, eight points at a time: each lane the same operations (min/max_ps pick as the ternaries do)
__attribute__((target("avx2"))) void bearing_bins_avx2(const double* dx, const double* dy, int32_t* k, double* r,
                                                       size_t n, int32_t bins, float scale) {
    const __m256 sign = _mm256_set1_ps(-0.0f), zero = _mm256_setzero_ps(), tiny = _mm256_set1_ps(kTinyf);
    const __m256 pi = _mm256_set1_ps(kPif), half_pi = _mm256_set1_ps(kHalfPif), sc = _mm256_set1_ps(scale);
    const __m256 a1 = _mm256_set1_ps(kA1f), a3 = _mm256_set1_ps(kA3f), a5 = _mm256_set1_ps(kA5f),
                 a7 = _mm256_set1_ps(kA7f), a9 = _mm256_set1_ps(kA9f);
    const __m256i nb = _mm256_set1_epi32(bins), below = _mm256_set1_epi32(bins - 1);
    size_t i = 0;
    for (; i + 8 <= n; i += 8) {
        const __m256d x0 = _mm256_loadu_pd(dx + i), x1 = _mm256_loadu_pd(dx + i + 4);
        const __m256d y0 = _mm256_loadu_pd(dy + i), y1 = _mm256_loadu_pd(dy + i + 4);
        const __m256 x = _mm256_set_m128(_mm256_cvtpd_ps(x1), _mm256_cvtpd_ps(x0));
        const __m256 y = _mm256_set_m128(_mm256_cvtpd_ps(y1), _mm256_cvtpd_ps(y0));
        const __m256 ax = _mm256_andnot_ps(sign, x), ay = _mm256_andnot_ps(sign, y);
        const __m256 lo = _mm256_min_ps(ay, ax), hi = _mm256_max_ps(ay, ax);  // ay < ax ? ay : ax; ay > ax ? ay : ax
        const __m256 z = _mm256_div_ps(lo, _mm256_max_ps(hi, tiny));
        const __m256 s = _mm256_mul_ps(z, z);
        __m256 a = _mm256_add_ps(_mm256_mul_ps(a9, s), a7);
        a = _mm256_add_ps(_mm256_mul_ps(a, s), a5);
        a = _mm256_add_ps(_mm256_mul_ps(a, s), a3);
        a = _mm256_add_ps(_mm256_mul_ps(a, s), a1);
        a = _mm256_mul_ps(a, z);
        a = _mm256_blendv_ps(a, _mm256_sub_ps(half_pi, a), _mm256_cmp_ps(ay, ax, _CMP_GT_OQ));
        a = _mm256_blendv_ps(a, _mm256_sub_ps(pi, a), _mm256_cmp_ps(x, zero, _CMP_LT_OQ));
        a = _mm256_blendv_ps(a, _mm256_xor_ps(a, sign), _mm256_cmp_ps(y, zero, _CMP_LT_OQ));
        const __m256i f = _mm256_cvttps_epi32(_mm256_mul_ps(_mm256_add_ps(a, pi), sc));
        const __m256i wrapped = _mm256_sub_epi32(f, _mm256_and_si256(_mm256_cmpgt_epi32(f, below), nb));  // f >= bins: f - bins
        _mm256_storeu_si256(reinterpret_cast<__m256i*>(k + i), wrapped);
        if (r) {
            _mm256_storeu_pd(r + i, _mm256_sqrt_pd(_mm256_add_pd(_mm256_mul_pd(x0, x0), _mm256_mul_pd(y0, y0))));
            _mm256_storeu_pd(r + i + 4, _mm256_sqrt_pd(_mm256_add_pd(_mm256_mul_pd(x1, x1), _mm256_mul_pd(y1, y1))));
        }
    }
    bearing_bins_plain(dx + i, dy + i, k + i, r ? r + i : nullptr, n - i, bins, scale);
}

// sixteen points at a time
__attribute__((target("avx512f,avx512dq,avx512vl"))) void bearing_bins_avx512(const double* dx, const double* dy,
                                                                             int32_t* k, double* r, size_t n,
                                                                             int32_t bins, float scale) {
    const __m512 sign = _mm512_set1_ps(-0.0f), zero = _mm512_setzero_ps(), tiny = _mm512_set1_ps(kTinyf);
    const __m512 pi = _mm512_set1_ps(kPif), half_pi = _mm512_set1_ps(kHalfPif), sc = _mm512_set1_ps(scale);
    const __m512 a1 = _mm512_set1_ps(kA1f), a3 = _mm512_set1_ps(kA3f), a5 = _mm512_set1_ps(kA5f),
                 a7 = _mm512_set1_ps(kA7f), a9 = _mm512_set1_ps(kA9f);
    const __m512i nb = _mm512_set1_epi32(bins);
    size_t i = 0;
    for (; i + 16 <= n; i += 16) {
        const __m512d x0 = _mm512_loadu_pd(dx + i), x1 = _mm512_loadu_pd(dx + i + 8);
        const __m512d y0 = _mm512_loadu_pd(dy + i), y1 = _mm512_loadu_pd(dy + i + 8);
        const __m512 x = _mm512_insertf32x8(_mm512_castps256_ps512(_mm512_cvtpd_ps(x0)), _mm512_cvtpd_ps(x1), 1);
        const __m512 y = _mm512_insertf32x8(_mm512_castps256_ps512(_mm512_cvtpd_ps(y0)), _mm512_cvtpd_ps(y1), 1);
        const __m512 ax = _mm512_andnot_ps(sign, x), ay = _mm512_andnot_ps(sign, y);
        const __m512 lo = _mm512_min_ps(ay, ax), hi = _mm512_max_ps(ay, ax);
        const __m512 z = _mm512_div_ps(lo, _mm512_max_ps(hi, tiny));
        const __m512 s = _mm512_mul_ps(z, z);
        __m512 a = _mm512_add_ps(_mm512_mul_ps(a9, s), a7);
        a = _mm512_add_ps(_mm512_mul_ps(a, s), a5);
        a = _mm512_add_ps(_mm512_mul_ps(a, s), a3);
        a = _mm512_add_ps(_mm512_mul_ps(a, s), a1);
        a = _mm512_mul_ps(a, z);
        a = _mm512_mask_blend_ps(_mm512_cmp_ps_mask(ay, ax, _CMP_GT_OQ), a, _mm512_sub_ps(half_pi, a));
        a = _mm512_mask_blend_ps(_mm512_cmp_ps_mask(x, zero, _CMP_LT_OQ), a, _mm512_sub_ps(pi, a));
        a = _mm512_mask_blend_ps(_mm512_cmp_ps_mask(y, zero, _CMP_LT_OQ), a, _mm512_xor_ps(a, sign));
        const __m512i f = _mm512_cvttps_epi32(_mm512_mul_ps(_mm512_add_ps(a, pi), sc));
        const __m512i wrapped = _mm512_mask_sub_epi32(f, _mm512_cmpge_epi32_mask(f, nb), f, nb);  // f >= bins: f - bins
        _mm512_storeu_si512(k + i, wrapped);
        if (r) {
            _mm512_storeu_pd(r + i, _mm512_sqrt_pd(_mm512_add_pd(_mm512_mul_pd(x0, x0), _mm512_mul_pd(y0, y0))));
            _mm512_storeu_pd(r + i + 8, _mm512_sqrt_pd(_mm512_add_pd(_mm512_mul_pd(x1, x1), _mm512_mul_pd(y1, y1))));
        }
    }
    bearing_bins_plain(dx + i, dy + i, k + i, r ? r + i : nullptr, n - i, bins, scale);
}
#endif

// the widest loops the kernel may take (tests: _rays_simd): 2 AVX-512, 1 AVX2, each where the CPU has it, 0 scalar
int g_rays_simd = 2;

#if defined(__x86_64__)
bool rays_avx512() {
    static const bool yes = __builtin_cpu_supports("avx512f") && __builtin_cpu_supports("avx512dq") &&
                            __builtin_cpu_supports("avx512vl");
    return yes && g_rays_simd >= 2;
}

bool rays_avx2() {
    static const bool yes = __builtin_cpu_supports("avx2");
    return yes && g_rays_simd >= 1;
}
#endif

void bearing_bins(const double* dx, const double* dy, int32_t* k, double* r, size_t n, int32_t bins, float scale) {
#if defined(__x86_64__)
    if (rays_avx512()) return bearing_bins_avx512(dx, dy, k, r, n, bins, scale);
    if (rays_avx2()) return bearing_bins_avx2(dx, dy, k, r, n, bins, scale);
#endif
    bearing_bins_plain(dx, dy, k, r, n, bins, scale);
}

// whether |v[i]| < 1e30 for every i < n: finite, and the differences the bins take fit a float32
bool all_within_plain(const double* v, size_t n) {
    bool ok = true;
    for (size_t i = 0; i < n; ++i) ok &= std::abs(v[i]) < 1e30;
    return ok;
}

#if defined(__x86_64__)
__attribute__((target("avx2"))) bool all_within_avx2(const double* v, size_t n) {
    const __m256d sign = _mm256_set1_pd(-0.0), limit = _mm256_set1_pd(1e30);
    __m256d ok = _mm256_castsi256_pd(_mm256_set1_epi64x(-1));
    size_t i = 0;
    for (; i + 4 <= n; i += 4)  // NaN compares false
        ok = _mm256_and_pd(ok, _mm256_cmp_pd(_mm256_andnot_pd(sign, _mm256_loadu_pd(v + i)), limit, _CMP_LT_OQ));
    return _mm256_movemask_pd(ok) == 0xf && all_within_plain(v + i, n - i);
}
#endif

bool all_within(const double* v, size_t n) {
#if defined(__x86_64__)
    if (rays_avx2()) return all_within_avx2(v, n);
#endif
    return all_within_plain(v, n);
}

// numpy's np.minimum of two non-NaN values
inline double lesser(double a, double b) { return b < a ? b : a; }

// RecentRays.sweep: false (the ring untouched) where a yaw error is not finite or a point, a time or an
// origin not under 1e30 in size
bool rays_sweep(Points map_xy, Times t, double ax, double ay, double bx, double by, Ring near, RingOrigins origin, OutVector yaw_errors, int64_t head,
                int64_t count, int64_t step, double margin, double yaw_error, double tolerance, int64_t window,
                OutMask out) {
    const size_t n = map_xy.shape(0);
    const int64_t sweeps = int64_t(near.shape(0)), bins = int64_t(near.shape(1));
    if (t.shape(0) != n || out.shape(0) != n || int64_t(origin.shape(0)) != sweeps ||
        int64_t(origin.shape(1)) != bins || int64_t(yaw_errors.shape(0)) != sweeps)
        throw nb::value_error("rays_sweep: shapes disagree");
    if (sweeps < 1 || bins < 1 || bins > (int64_t(1) << 30) || step < 1 || window < 0 || head < 0 || head >= sweeps || count < 0 || count > sweeps)
        throw nb::value_error("rays_sweep: ring out of range");
    const double* p = map_xy.data();
    const double* tt = t.data();
    if (!all_within(p, 2 * n) || !all_within(tt, n)) return false;
    if (!std::isfinite(yaw_error) || !all_within(&ax, 1) || !all_within(&ay, 1) || !all_within(&bx, 1) ||
        !all_within(&by, 1))
        return false;
    // the lidar's position when each point was taken (tracking.lidar_origins: on the chord between
    // where it was at t[0] and t[-1])
    std::vector<double> o(2 * n);
    if (n) {
        const double t0 = tt[0], span = tt[n - 1] - tt[0], ex = bx - ax, ey = by - ay;
        if (span != 0.0) {
            for (size_t i = 0; i < n; ++i) {
                const double w = (tt[i] - t0) / span;
                o[2 * i] = ax + ex * w;
                o[2 * i + 1] = ay + ey * w;
            }
        } else {
            for (size_t i = 0; i < n; ++i) {
                o[2 * i] = ax + ex * 0.0;
                o[2 * i + 1] = ay + ey * 0.0;
            }
        }
        if (!all_within(o.data(), 2 * n)) return false;
    }
    for (int64_t k = 0; k < sweeps; ++k)
        if (!std::isfinite(yaw_errors.data()[k])) return false;
    const float scale = float(double(bins) / (2 * kPi));
    double* nr = near.data();
    double* org = origin.data();
    double* ye = yaw_errors.data();
    bool* mask = out.data();

    // displaced: the lags step, 2 step, ... up to the ring's size and what it holds; each lag in
    // passes over all points (differences, bins, gathers), the bins several points at a time
    std::vector<double> dx(n), dy(n), r(n);
    std::vector<int32_t> k(n);
    std::fill(mask, mask + n, false);
    double err = yaw_error;
    for (int64_t lag = 1; lag <= sweeps && lag <= count; ++lag) {
        const int64_t slot = ((head - lag) % sweeps + sweeps) % sweeps;
        err = std::max(err, ye[slot]);
        if (lag % step != 0) continue;
        const double* ln = nr + slot * bins;
        const double* lo = org + 2 * slot * bins;
        for (size_t i = 0; i < n; ++i) {  // a first bearing, from the bin 0's origin
            dx[i] = p[2 * i] - lo[0];
            dy[i] = p[2 * i + 1] - lo[1];
        }
        bearing_bins(dx.data(), dy.data(), k.data(), nullptr, n, int32_t(bins), scale);
        for (size_t i = 0; i < n; ++i) {  // then from the ray's own origin
            dx[i] = p[2 * i] - lo[2 * k[i]];
            dy[i] = p[2 * i + 1] - lo[2 * k[i] + 1];
        }
        bearing_bins(dx.data(), dy.data(), k.data(), r.data(), n, int32_t(bins), scale);
        for (size_t i = 0; i < n; ++i) {  // seen >= 0: finite is < inf
            const double seen = ln[k[i]];
            mask[i] = mask[i] | ((seen < kInf) & (seen > r[i] + margin) & (r[i] * err <= tolerance));
        }
    }

    // add: the nearest range per bin, over window bins either side, and the last point's origin
    for (size_t i = 0; i < n; ++i) {
        dx[i] = p[2 * i] - o[2 * i];
        dy[i] = p[2 * i + 1] - o[2 * i + 1];
    }
    bearing_bins(dx.data(), dy.data(), k.data(), r.data(), n, int32_t(bins), scale);
    std::vector<double> nearest(size_t(bins), kInf);
    std::vector<int64_t> last(size_t(bins), -1);
    for (size_t i = 0; i < n; ++i) {
        nearest[size_t(k[i])] = lesser(nearest[size_t(k[i])], r[i]);
        last[size_t(k[i])] = int64_t(i);
    }
    double* nh = nr + head * bins;
    double* oh = org + 2 * head * bins;
    const double mx = n ? o[2 * (n / 2)] : 0.0, my = n ? o[2 * (n / 2) + 1] : 0.0;
    // the circle unrolled by window bins either side: ext[b + window + j] = nearest[(b + j) mod bins]
    std::vector<double> ext(size_t(bins + 2 * window));
    for (int64_t j = 0, b = ((-window) % bins + bins) % bins; j < bins + 2 * window; ++j, b = b + 1 == bins ? 0 : b + 1)
        ext[size_t(j)] = nearest[size_t(b)];
    for (int64_t b = 0; b < bins; ++b) {
        double m = nearest[size_t(b)];
        for (int64_t j = 1; j <= window; ++j)  // np.minimum(near, np.minimum(np.roll(nearest, j), np.roll(nearest, -j)))
            m = lesser(m, lesser(ext[size_t(b + window - j)], ext[size_t(b + window + j)]));
        nh[b] = m;
        const int64_t j = last[size_t(b)];
        oh[2 * b] = j >= 0 ? o[2 * j] : mx;
        oh[2 * b + 1] = j >= 0 ? o[2 * j + 1] : my;
    }
    ye[head] = yaw_error;
    return true;
}

}  // namespace

void bind_rays(nb::module_& m) {
    m.def("rays_sweep", &rays_sweep, nb::arg("map_xy"), nb::arg("t"), nb::arg("ax"), nb::arg("ay"),
          nb::arg("bx"), nb::arg("by"), nb::arg("near"), nb::arg("origin"),
          nb::arg("yaw_errors"), nb::arg("head"), nb::arg("count"), nb::arg("step"), nb::arg("margin"),
          nb::arg("yaw_error"), nb::arg("tolerance"), nb::arg("window"), nb::arg("out"));
    m.def(
        "_rays_simd",
        [](int level) {
            const int was = g_rays_simd;
            g_rays_simd = level;
            return was;
        },
        nb::arg("level"), "Tests: the widest loop of rays_sweep (2 AVX-512, 1 AVX2, each where the CPU has it, 0 scalar); the old one.");
}

}  // namespace fmcwlog
