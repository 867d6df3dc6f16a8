// The sensor's velocity from one sweep's Doppler (fmcwlog/frontend/egomotion.py): unit bearings
// and the robust fit (RANSAC on pairs, then least-squares refits).
//
// Frames and units as there: xy (N, 2) m in the lidar frame, v_r (N,) m/s radial Doppler, v_s (2,)
// m/s the lidar origin's velocity in the lidar frame; a static point has v_r = -u.v_s.
// The random pairs are not drawn here: fit_sensor_velocity asks the caller's `draws(n)` for them
// (numpy's generator, as the reference draws them), so both pick the same hypotheses and inliers.
#include <nanobind/stl/optional.h>
#include <nanobind/stl/pair.h>
#include <nanobind/stl/tuple.h>

#if defined(__SSE2__)
#include <emmintrin.h>
#endif

#include "common.hpp"
#include "kernels.hpp"

namespace fmcwlog {
namespace {

using Vector = nb::ndarray<const double, nb::shape<-1>, nb::c_contig, nb::device::cpu>;
using Draws = nb::ndarray<const int64_t, nb::shape<-1, 2>, nb::c_contig, nb::device::cpu>;
using PyArray = nb::ndarray<nb::numpy, double>;
using PyMask = nb::ndarray<nb::numpy, bool, nb::ndim<1>>;

template <typename T>
T* owned(size_t count, nb::capsule& owner) {
    T* data = new T[count > 0 ? count : 1]();
    owner = nb::capsule(data, [](void* d) noexcept { delete[] static_cast<T*>(d); });
    return data;
}

// egomotion.unit_bearings: xy / hypot(x, y), (0, 0) where the range is not > 0 (u null: none); the
// ranges hypot(x, y) into `ranges` where given.
void bearings_into(const double* xy, size_t n, double* u, double* ranges = nullptr) {
    for (size_t i = 0; i < n; ++i) {
        const double x = xy[2 * i], y = xy[2 * i + 1];
        const double r = std::hypot(x, y);
        if (ranges) ranges[i] = r;
        if (!u) continue;
        if (r > 0.0) {
            u[2 * i] = x / r;
            u[2 * i + 1] = y / r;
        } else {
            u[2 * i] = u[2 * i + 1] = 0.0;
        }
    }
}

PyArray unit_bearings(Points xy) {
    const size_t n = xy.shape(0);
    nb::capsule owner;
    double* u = owned<double>(2 * n, owner);
    {
        nb::gil_scoped_release release;
        bearings_into(xy.data(), n, u);
    }
    return PyArray(u, {n, 2}, owner);
}

// sweep_geometry.sweep_geometry_numpy: the ranges np.hypot(x, y) (N,) of the points xy, the mask ranges <
// min_range (N,), where `bearings` unit_bearings(xy) (N, 2) (else None); of the times t (N,): the last,
// np.maximum.reduce(t, initial=0.0), where every time is finite and one is > 0 (else None: numpy
// decides a NaN's or a zero's sign), and where they are sorted (t[i] >= t[i-1], a NaN fails) and N > 0
// tracking.middle_time's middle value (or the mean of the two middle values, 0.0 + a + b then / 2.0)
// (else None: np.median decides).
nb::tuple sweep_geometry(Points xy, Vector t, double min_range, bool bearings) {
    const size_t n = xy.shape(0);
    if (t.shape(0) != n) throw nb::value_error("sweep_geometry: xy and t differ in length");
    nb::capsule range_owner, near_owner, u_owner;
    double* r = owned<double>(n, range_owner);
    bool* near = owned<bool>(n, near_owner);
    double* u = bearings ? owned<double>(2 * n, u_owner) : nullptr;
    const double* tt = t.data();
    double last = 0.0, middle = 0.0;
    bool finite = true, sorted = n > 0;
    {
        nb::gil_scoped_release release;
        bearings_into(xy.data(), n, u, r);
        for (size_t i = 0; i < n; ++i) near[i] = r[i] < min_range;
        for (size_t i = 0; i < n; ++i) {
            finite = finite && std::isfinite(tt[i]);
            last = last >= tt[i] ? last : tt[i];
            if (i > 0) sorted = sorted && tt[i] >= tt[i - 1];
        }
        if (sorted) middle = n % 2 ? 0.0 + tt[n / 2] : (0.0 + tt[n / 2 - 1] + tt[n / 2]) / 2.0;
    }
    nb::object u_out = bearings ? nb::cast(PyArray(u, {n, 2}, u_owner)) : nb::none();
    nb::object last_out = finite && last > 0.0 ? nb::cast(last) : nb::none();
    nb::object middle_out = sorted ? nb::cast(middle) : nb::none();
    return nb::make_tuple(nb::ndarray<nb::numpy, double, nb::shape<-1>>(r, {n}, range_owner),
                          nb::ndarray<nb::numpy, bool, nb::shape<-1>>(near, {n}, near_owner), u_out, last_out,
                          middle_out);
}

// A hypothesis' score: how many of the n points have |r + (hx x + hy y)| < threshold (the row sum of
// fit_sensor_velocity's (|res| < inlier_threshold)). SSE2 two points at a time, the same products
// and sums as the scalar tail (the compiler keeps this loop scalar at the x86-64 baseline).
int64_t count_within(const double* r, const double* x, const double* y, size_t n, double hx, double hy,
                     double threshold) {
    size_t s = 0;
    int64_t count = 0;
#if defined(__SSE2__)
    const __m128d vhx = _mm_set1_pd(hx), vhy = _mm_set1_pd(hy), vt = _mm_set1_pd(threshold);
    const __m128d sign = _mm_set1_pd(-0.0);
    __m128i acc0 = _mm_setzero_si128(), acc1 = _mm_setzero_si128();
    auto within = [&](size_t at) {  // all ones in a lane where |eps| < threshold
        const __m128d dot = _mm_add_pd(_mm_mul_pd(vhx, _mm_loadu_pd(x + at)), _mm_mul_pd(vhy, _mm_loadu_pd(y + at)));
        const __m128d eps = _mm_add_pd(_mm_loadu_pd(r + at), dot);
        return _mm_castpd_si128(_mm_cmplt_pd(_mm_andnot_pd(sign, eps), vt));
    };
    for (; s + 4 <= n; s += 4) {
        acc0 = _mm_sub_epi64(acc0, within(s));
        acc1 = _mm_sub_epi64(acc1, within(s + 2));
    }
    int64_t lanes[2];
    _mm_storeu_si128(reinterpret_cast<__m128i*>(lanes), _mm_add_epi64(acc0, acc1));
    count = lanes[0] + lanes[1];
#endif
    for (; s < n; ++s) count += std::fabs(r[s] + (hx * x[s] + hy * y[s])) < threshold;
    return count;
}

struct Fit {
    bool ok = false;
    double v[2] = {0, 0};
    double ata_inv[4] = {0, 0, 0, 0};
    double sigma = 0;
    std::vector<uint8_t> inliers;
};

// np.linalg.inv of the symmetric 2x2 [[a, b], [b, d]] (LAPACK's LU: singular where a pivot is
// exactly 0); false where numpy raises LinAlgError.
bool inverse_2x2(double a, double b, double c, double d, double out[4]) {
    const bool swap = std::fabs(c) > std::fabs(a);  // partial pivoting on the first column
    const double p = swap ? c : a, q = swap ? d : b, r = swap ? a : c, s = swap ? b : d;
    if (p == 0.0) return false;
    if (s - (r / p) * q == 0.0) return false;
    const double det = a * d - b * c;
    out[0] = d / det;
    out[1] = -b / det;
    out[2] = -c / det;
    out[3] = a / det;
    return true;
}

// One pass over the points for a velocity v: its inliers (valid and |eps| < threshold, eps =
// v_r + u.v), their count, the normal equations' sums of egomotion._lstsq_2 over them (A = -u:
// A'A = u'u, A'b = -u'v_r) and the sum of their eps^2 (for sigma). An outlier adds +0.0 to each
// sum (no branch to mispredict; a NaN Doppler is not read into one).
struct Pass {
    size_t count = 0;
    double s00 = 0, s01 = 0, s11 = 0, b0 = 0, b1 = 0, sq = 0;
};

Pass select_inliers(const double* u, const double* vr, const std::vector<uint8_t>& valid, const double v[2],
                    double threshold, std::vector<uint8_t>& inliers) {
    Pass p;
    inliers.resize(valid.size());
    for (size_t i = 0; i < valid.size(); ++i) {
        const double eps = vr[i] + (u[2 * i] * v[0] + u[2 * i + 1] * v[1]);
        const uint8_t in = valid[i] & uint8_t(std::fabs(eps) < threshold);
        inliers[i] = in;
        p.count += in;
        const double x = in ? u[2 * i] : 0.0, y = in ? u[2 * i + 1] : 0.0, r = in ? vr[i] : 0.0;
        const double e = in ? eps : 0.0;
        p.s00 += x * x;
        p.s01 += x * y;
        p.s11 += y * y;
        p.b0 += x * r;
        p.b1 += y * r;
        p.sq += e * e;
    }
    return p;
}

// egomotion._lstsq_2 from a pass' sums: v of v_r = -u v and (A'A)^-1; false where numpy raises.
bool lstsq_2(const Pass& p, double v[2], double inv[4]) {
    if (!inverse_2x2(p.s00, p.s01, p.s01, p.s11, inv)) return false;
    const double b0 = -p.b0, b1 = -p.b1;
    v[0] = inv[0] * b0 + inv[1] * b1;
    v[1] = inv[2] * b0 + inv[3] * b1;
    return true;
}

// egomotion._refine: least squares on the inliers of v, re-selected `refinements` times, then the
// final inliers, their (A'A)^-1 and the robust sigma.
Fit refine(const double* u, const double* vr, const std::vector<uint8_t>& valid, const double start[2],
           double threshold, int refinements) {
    Fit fit;
    double v[2] = {start[0], start[1]};
    std::vector<uint8_t> inliers, fitted;
    for (int k = 0; k < std::max(1, refinements); ++k) {
        const Pass p = select_inliers(u, vr, valid, v, threshold, inliers);
        if (p.count < 3) return fit;
        if (!lstsq_2(p, v, fit.ata_inv)) return fit;
        std::swap(fitted, inliers);
    }
    const Pass last = select_inliers(u, vr, valid, v, threshold, inliers);
    if (last.count < 3) return fit;
    if (inliers != fitted) {  // else (A'A)^-1 of these inliers is the one in hand
        double unused[2];
        if (!lstsq_2(last, unused, fit.ata_inv)) return fit;
    }
    const double dof = double(std::max<int64_t>(int64_t(last.count) - 2, 1));
    fit.sigma = std::sqrt(last.sq / dof);
    fit.v[0] = v[0];
    fit.v[1] = v[1];
    fit.inliers = std::move(inliers);
    fit.ok = true;
    return fit;
}

using Result = std::tuple<PyArray, PyArray, PyMask, double>;  // v_sensor, covariance, inliers, sigma

Result to_python(const Fit& fit) {
    nb::capsule ov, oc, om;
    double* v = owned<double>(2, ov);
    double* cov = owned<double>(4, oc);
    const size_t n = fit.inliers.size();
    bool* mask = owned<bool>(n, om);
    v[0] = fit.v[0];
    v[1] = fit.v[1];
    const double s2 = fit.sigma * fit.sigma;
    for (int k = 0; k < 4; ++k) cov[k] = s2 * fit.ata_inv[k];
    for (size_t i = 0; i < n; ++i) mask[i] = fit.inliers[i] != 0;
    return Result(PyArray(v, {2}, ov), PyArray(cov, {2, 2}, oc), PyMask(mask, {n}, om), fit.sigma);
}

using Answer = std::tuple<std::optional<Result>, bool, std::optional<Result>>;

// egomotion.fit_sensor_velocity: (fit, gate_changed, unconstrained); fit None where numpy returns its
// failed fit, gate_changed where numpy sets `unconstrained` (None there: that refit failed).
// `bearings`: unit_bearings(xy) if the caller has them; `draws(n)`: the (H, 2) int64 positions of
// the random pairs among the n usable points (numpy's rng.integers(0, n, size=(H, 2))), called
// once, only where at least 3 points are usable; `prior`: the finite prior, or None.
Answer fit_sensor_velocity(
    Points xy, Vector v_r, std::optional<Points> bearings, nb::callable draws, double inlier_threshold,
    double min_pair_sine, int refinements, int64_t score_points, std::optional<std::pair<double, double>> prior,
    double prior_gate) {
    const size_t n = xy.shape(0);
    if (v_r.shape(0) != n || (bearings && bearings->shape(0) != n))
        throw nb::value_error("fit_sensor_velocity: xy, v_r and bearings differ in length");
    if (score_points == 0) throw nb::value_error("fit_sensor_velocity: score_points must not be 0");
    const double* vr = v_r.data();
    std::vector<double> own_u;
    const double* u;
    if (bearings) {
        u = bearings->data();
    } else {
        own_u.resize(2 * n);
        bearings_into(xy.data(), n, own_u.data());
        u = own_u.data();
    }
    // egomotion.usable: a finite Doppler and a bearing
    std::vector<uint8_t> valid(n);
    std::vector<int64_t> idx(n);
    size_t n_valid = 0;
    for (size_t i = 0; i < n; ++i) {
        valid[i] = uint8_t(std::isfinite(vr[i])) & uint8_t(u[2 * i] != 0.0 || u[2 * i + 1] != 0.0);
        idx[n_valid] = int64_t(i);
        n_valid += valid[i];
    }
    idx.resize(n_valid);
    const Answer failed{std::nullopt, false, std::nullopt};
    if (idx.size() < 3) return failed;
    const Draws ij = nb::cast<Draws>(draws(idx.size()));
    const size_t n_draws = ij.shape(0);
    const int64_t* pick = ij.data();
    for (size_t k = 0; k < 2 * n_draws; ++k)
        if (pick[k] < 0 || pick[k] >= int64_t(idx.size())) throw nb::value_error("draws: a position out of range");

    Fit fit, free_fit;
    bool has_free = false, any_ok = false;
    {
        nb::gil_scoped_release release;
        // Pair hypotheses by Cramer's rule, pairs nearer than asin(min_pair_sine) to parallel dropped
        std::vector<double> hyp;
        hyp.reserve(2 * n_draws + 2);
        for (size_t k = 0; k < n_draws; ++k) {
            const size_t i = size_t(idx[size_t(pick[2 * k])]), j = size_t(idx[size_t(pick[2 * k + 1])]);
            const double uix = u[2 * i], uiy = u[2 * i + 1], ujx = u[2 * j], ujy = u[2 * j + 1];
            const double det = uix * ujy - uiy * ujx;
            if (!(std::fabs(det) > min_pair_sine)) continue;
            const double bi = -vr[i], bj = -vr[j];
            hyp.push_back((bi * ujy - bj * uiy) / det);
            hyp.push_back((uix * bj - ujx * bi) / det);
        }
        any_ok = !hyp.empty();
        if (any_ok) {
            if (prior) {
                hyp.push_back(prior->first);
                hyp.push_back(prior->second);
            }
            const size_t h = hyp.size() / 2;
            // scored on every stride-th usable point, gathered once
            const size_t stride = score_points < 0 ? 1 : size_t(std::max<int64_t>(1, int64_t(idx.size()) / score_points));
            std::vector<double> sx, sy, sr;
            for (size_t s = 0; s < idx.size(); s += stride) {
                const size_t i = size_t(idx[s]);
                sx.push_back(u[2 * i]);
                sy.push_back(u[2 * i + 1]);
                sr.push_back(vr[i]);
            }
            std::vector<int64_t> score(h, 0);
            for (size_t k = 0; k < h; ++k)
                score[k] = count_within(sr.data(), sx.data(), sy.data(), sr.size(), hyp[2 * k], hyp[2 * k + 1],
                                        inlier_threshold);
            auto argmax = [&](size_t end, const std::vector<uint8_t>* gate) {
                size_t best = 0;
                int64_t top = std::numeric_limits<int64_t>::min();
                for (size_t k = 0; k < end; ++k) {
                    const int64_t sk = (gate && !(*gate)[k]) ? -1 : score[k];
                    if (sk > top) {
                        top = sk;
                        best = k;
                    }
                }
                return best;
            };
            if (!prior) {
                fit = refine(u, vr, valid, &hyp[2 * argmax(h, nullptr)], inlier_threshold, refinements);
            } else {
                std::vector<uint8_t> in_gate(h);
                for (size_t k = 0; k < h; ++k)
                    in_gate[k] = std::hypot(hyp[2 * k] - prior->first, hyp[2 * k + 1] - prior->second) <= prior_gate;
                const size_t best = argmax(h, &in_gate);
                fit = refine(u, vr, valid, &hyp[2 * best], inlier_threshold, refinements);
                const size_t free = h > 1 ? argmax(h - 1, nullptr) : best;
                if (!in_gate[free] && score[free] > score[best]) {
                    free_fit = refine(u, vr, valid, &hyp[2 * free], inlier_threshold, refinements);
                    has_free = true;
                }
            }
        }
    }
    if (!any_ok) return failed;
    std::optional<Result> main_result, free_result;
    if (fit.ok) main_result = to_python(fit);
    if (has_free && free_fit.ok) free_result = to_python(free_fit);
    return {main_result, has_free, free_result};
}

}  // namespace

void bind_egomotion(nb::module_& m) {
    m.def("unit_bearings", &unit_bearings, nb::arg("xy"));
    m.def("sweep_geometry", &sweep_geometry, nb::arg("xy"), nb::arg("t"), nb::arg("min_range"), nb::arg("bearings"));
    m.def("fit_sensor_velocity", &fit_sensor_velocity, nb::arg("xy"), nb::arg("v_r"), nb::arg("bearings").none(),
          nb::arg("draws"), nb::arg("inlier_threshold"), nb::arg("min_pair_sine"), nb::arg("refinements"),
          nb::arg("score_points"), nb::arg("prior").none(), nb::arg("prior_gate"));
}

}  // namespace fmcwlog
