// Free space from the last sweeps' rays (fmcwlog/frontend/tracking.py, RecentRays.sweep): which points
// of a sweep lie well short of where an earlier sweep's ray at their bearing ended, then the sweep
// kept in the ring, in one call.
//
// The ring stays in Python (RecentRays' arrays) and is written here in place. The bearing bins are
// tracking.bearing_bins' polynomial arctangent and the ranges sqrt(dx^2 + dy^2), the reference's
// float operations in its order (no FMA contraction): the mask and the ring are numpy's to the bit.
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

// tracking._ATAN: arctan on [0, 1], Abramowitz & Stegun 4.4.47
constexpr double kA1 = 0.9998660, kA3 = -0.3302995, kA5 = 0.1801410, kA7 = -0.0851330, kA9 = 0.0208351;

// tracking.bearing_bins of one direction; scale = bins / (2 pi) as numpy computes it; floor(v) for
// v in [0, bins] (a + pi >= 0) is its truncation
inline int32_t bearing_bin(double x, double y, int32_t bins, double scale) {
    const double ax = std::abs(x), ay = std::abs(y);
    const double lo = ay < ax ? ay : ax, hi = ay > ax ? ay : ax;
    const double z = lo / (hi > 1e-300 ? hi : 1e-300);
    const double s = z * z;
    double a = ((((kA9 * s + kA7) * s + kA5) * s + kA3) * s + kA1) * z;
    if (ay > ax) a = kPi / 2 - a;
    if (x < 0) a = kPi - a;
    if (y < 0) a = -a;
    const int32_t f = int32_t((a + kPi) * scale);
    return f >= bins ? f - bins : f;
}

// bearing_bin of (dx[i], dy[i]), i < n, into k[i], and where r is given the range sqrt(dx^2 + dy^2) into r[i]
void bearing_bins_plain(const double* dx, const double* dy, int32_t* k, double* r, size_t n, int32_t bins,
                        double scale) {
    for (size_t i = 0; i < n; ++i) {
        k[i] = bearing_bin(dx[i], dy[i], bins, scale);
        if (r) r[i] = std::sqrt(dx[i] * dx[i] + dy[i] * dy[i]);
    }
}

#if defined(__x86_64__)
// the same, four points at a time: each lane the same operations (min/max_pd pick as the ternaries do)
__attribute__((target("avx2"))) void bearing_bins_avx2(const double* dx, const double* dy, int32_t* k, double* r,
                                                       size_t n, int32_t bins, double scale) {
    const __m256d sign = _mm256_set1_pd(-0.0), zero = _mm256_setzero_pd(), tiny = _mm256_set1_pd(1e-300);
    const __m256d pi = _mm256_set1_pd(kPi), half_pi = _mm256_set1_pd(kPi / 2), sc = _mm256_set1_pd(scale);
    const __m256d a1 = _mm256_set1_pd(kA1), a3 = _mm256_set1_pd(kA3), a5 = _mm256_set1_pd(kA5),
                  a7 = _mm256_set1_pd(kA7), a9 = _mm256_set1_pd(kA9);
    const __m128i nb = _mm_set1_epi32(bins), below = _mm_set1_epi32(bins - 1);
    size_t i = 0;
    for (; i + 4 <= n; i += 4) {
        const __m256d x = _mm256_loadu_pd(dx + i), y = _mm256_loadu_pd(dy + i);
        const __m256d ax = _mm256_andnot_pd(sign, x), ay = _mm256_andnot_pd(sign, y);
        const __m256d lo = _mm256_min_pd(ay, ax), hi = _mm256_max_pd(ay, ax);  // ay < ax ? ay : ax; ay > ax ? ay : ax
        const __m256d z = _mm256_div_pd(lo, _mm256_max_pd(hi, tiny));
        const __m256d s = _mm256_mul_pd(z, z);
        __m256d a = _mm256_add_pd(_mm256_mul_pd(a9, s), a7);
        a = _mm256_add_pd(_mm256_mul_pd(a, s), a5);
        a = _mm256_add_pd(_mm256_mul_pd(a, s), a3);
        a = _mm256_add_pd(_mm256_mul_pd(a, s), a1);
        a = _mm256_mul_pd(a, z);
        a = _mm256_blendv_pd(a, _mm256_sub_pd(half_pi, a), _mm256_cmp_pd(ay, ax, _CMP_GT_OQ));
        a = _mm256_blendv_pd(a, _mm256_sub_pd(pi, a), _mm256_cmp_pd(x, zero, _CMP_LT_OQ));
        a = _mm256_blendv_pd(a, _mm256_xor_pd(a, sign), _mm256_cmp_pd(y, zero, _CMP_LT_OQ));
        const __m128i f = _mm256_cvttpd_epi32(_mm256_mul_pd(_mm256_add_pd(a, pi), sc));
        const __m128i wrapped = _mm_sub_epi32(f, _mm_and_si128(_mm_cmpgt_epi32(f, below), nb));  // f >= bins: f - bins
        _mm_storeu_si128(reinterpret_cast<__m128i*>(k + i), wrapped);
        if (r) _mm256_storeu_pd(r + i, _mm256_sqrt_pd(_mm256_add_pd(_mm256_mul_pd(x, x), _mm256_mul_pd(y, y))));
    }
    bearing_bins_plain(dx + i, dy + i, k + i, r ? r + i : nullptr, n - i, bins, scale);
}

// eight points at a time
__attribute__((target("avx512f,avx512dq,avx512vl"))) void bearing_bins_avx512(const double* dx, const double* dy,
                                                                             int32_t* k, double* r, size_t n,
                                                                             int32_t bins, double scale) {
    const __m512d sign = _mm512_set1_pd(-0.0), zero = _mm512_setzero_pd(), tiny = _mm512_set1_pd(1e-300);
    const __m512d pi = _mm512_set1_pd(kPi), half_pi = _mm512_set1_pd(kPi / 2), sc = _mm512_set1_pd(scale);
    const __m512d a1 = _mm512_set1_pd(kA1), a3 = _mm512_set1_pd(kA3), a5 = _mm512_set1_pd(kA5),
                  a7 = _mm512_set1_pd(kA7), a9 = _mm512_set1_pd(kA9);
    const __m256i nb = _mm256_set1_epi32(bins), below = _mm256_set1_epi32(bins - 1);
    size_t i = 0;
    for (; i + 8 <= n; i += 8) {
        const __m512d x = _mm512_loadu_pd(dx + i), y = _mm512_loadu_pd(dy + i);
        const __m512d ax = _mm512_andnot_pd(sign, x), ay = _mm512_andnot_pd(sign, y);
        const __m512d lo = _mm512_min_pd(ay, ax), hi = _mm512_max_pd(ay, ax);
        const __m512d z = _mm512_div_pd(lo, _mm512_max_pd(hi, tiny));
        const __m512d s = _mm512_mul_pd(z, z);
        __m512d a = _mm512_add_pd(_mm512_mul_pd(a9, s), a7);
        a = _mm512_add_pd(_mm512_mul_pd(a, s), a5);
        a = _mm512_add_pd(_mm512_mul_pd(a, s), a3);
        a = _mm512_add_pd(_mm512_mul_pd(a, s), a1);
        a = _mm512_mul_pd(a, z);
        a = _mm512_mask_blend_pd(_mm512_cmp_pd_mask(ay, ax, _CMP_GT_OQ), a, _mm512_sub_pd(half_pi, a));
        a = _mm512_mask_blend_pd(_mm512_cmp_pd_mask(x, zero, _CMP_LT_OQ), a, _mm512_sub_pd(pi, a));
        a = _mm512_mask_blend_pd(_mm512_cmp_pd_mask(y, zero, _CMP_LT_OQ), a, _mm512_xor_pd(a, sign));
        const __m256i f = _mm512_cvttpd_epi32(_mm512_mul_pd(_mm512_add_pd(a, pi), sc));
        const __m256i wrapped = _mm256_sub_epi32(f, _mm256_and_si256(_mm256_cmpgt_epi32(f, below), nb));
        _mm256_storeu_si256(reinterpret_cast<__m256i*>(k + i), wrapped);
        if (r) _mm512_storeu_pd(r + i, _mm512_sqrt_pd(_mm512_add_pd(_mm512_mul_pd(x, x), _mm512_mul_pd(y, y))));
    }
    bearing_bins_plain(dx + i, dy + i, k + i, r ? r + i : nullptr, n - i, bins, scale);
}
#endif

void bearing_bins(const double* dx, const double* dy, int32_t* k, double* r, size_t n, int32_t bins, double scale) {
#if defined(__x86_64__)
    static const bool avx512 = __builtin_cpu_supports("avx512f") && __builtin_cpu_supports("avx512dq") &&
                               __builtin_cpu_supports("avx512vl");
    static const bool avx2 = __builtin_cpu_supports("avx2");
    if (avx512) return bearing_bins_avx512(dx, dy, k, r, n, bins, scale);
    if (avx2) return bearing_bins_avx2(dx, dy, k, r, n, bins, scale);
#endif
    bearing_bins_plain(dx, dy, k, r, n, bins, scale);
}

// whether v[0..n) are all finite (by their exponent bits: a loop the compiler widens)
bool all_finite(const double* v, size_t n) {
    uint64_t bad = 0;
    for (size_t i = 0; i < n; ++i) {
        uint64_t bits;
        std::memcpy(&bits, v + i, sizeof bits);
        bad |= uint64_t((bits & 0x7ff0000000000000ULL) == 0x7ff0000000000000ULL);
    }
    return bad == 0;
}

// numpy's np.minimum of two non-NaN values
inline double lesser(double a, double b) { return b < a ? b : a; }

// RecentRays.sweep: false (the ring untouched) where a point, an origin or a yaw error is not finite
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
    if (!all_finite(p, 2 * n) || !all_finite(tt, n)) return false;
    if (!std::isfinite(yaw_error) || !std::isfinite(ax) || !std::isfinite(ay) || !std::isfinite(bx) ||
        !std::isfinite(by))
        return false;
    // the lidar's position when each point was taken (tracking.lidar_origins: on the chord between
    // where it was at t[0] and t[-1])
    std::vector<double> o(2 * n);
    if (n) {
        const double t0 = tt[0], span = tt[n - 1] - tt[0];
        for (size_t i = 0; i < n; ++i) {
            const double w = span != 0.0 ? (tt[i] - t0) / span : 0.0;
            o[2 * i] = ax + (bx - ax) * w;
            o[2 * i + 1] = ay + (by - ay) * w;
            if (!std::isfinite(o[2 * i]) || !std::isfinite(o[2 * i + 1])) return false;
        }
    }
    for (int64_t k = 0; k < sweeps; ++k)
        if (!std::isfinite(yaw_errors.data()[k])) return false;
    const double scale = double(bins) / (2 * kPi);
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
    for (int64_t b = 0; b < bins; ++b) {
        double m = nearest[size_t(b)];
        for (int64_t j = 1; j <= window; ++j) {
            const int64_t before = b - j % bins, after = b + j % bins;
            m = lesser(m, lesser(nearest[size_t(before < 0 ? before + bins : before)],
                                 nearest[size_t(after >= bins ? after - bins : after)]));
        }
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
}

}  // namespace fmcwlog
