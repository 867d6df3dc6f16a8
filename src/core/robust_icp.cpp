// The improved method's robust ICP (fmcwlog/frontend/robust_icp.py register), whole: the pairs on
// the target's grid (fmcwlog/kernels/nearest.py), GMMSC weights with their EM fit
// (fmcwlog/frontend/gmmsc.py), Huber weights, the Gauss-Newton step with an optional Gaussian prior
// (fmcwlog/frontend/icp.py gauss_newton_step, or gauss_newton_step_lines where the target points'
// line normals are given) and the step extrapolation. Each piece names the
// numpy function it mirrors and keeps its order of operations; sums run in index order (numpy's
// pairwise sums and BLAS dot products may round differently: answers agree to ~1e-12, not bit for bit).
#include <nanobind/stl/array.h>
#include <nanobind/stl/tuple.h>
#include <nanobind/stl/vector.h>

#include <array>
#include <cstring>
#include <numeric>

#include "common.hpp"
#include "kernels.hpp"
#include "normals.hpp"

namespace fmcwlog {
namespace {

// ICPParams and its GMMSCParams, the fields register reads (fmcwlog/frontend/icp.py, gmmsc.py).
struct RobustParams {
    int max_iterations = 30;
    double translation_tol = 1e-4, rotation_tol = 5e-5;
    int64_t min_correspondences = 10;
    double huber_delta = 0.05;
    bool use_huber = true, use_gmmsc = true;
    double gmm_start_translation = 2e-3, gmm_start_rotation = 2e-3, gmm_refit_ratio = 0.25;
    bool extrapolate = true;
    double max_extrapolation = 10.0, extrapolation_min_cos = 0.9, extrapolation_lever = 3.0;
    // GMMSCParams
    int n_components = 2;
    double w_th = 0.5;
    int max_iter = 10;
    double tol = 1e-3;
    int64_t min_pairs = 10;
    double min_spread = 1e-9, merge_overlap = 0.2, reg_covar = 1e-10;
    int64_t max_fit_samples = 500;
};

// gmmsc.DistanceMixture: means, standard deviations, mixing weights (K,), the inlier group's
// threshold and the median distance it was fit to.
struct Mixture {
    std::vector<double> means, sigmas, mix;
    double merge_overlap = 0.2, fit_median = std::numeric_limits<double>::quiet_NaN();
};

// scipy.special.ndtr (cephes): the standard normal CDF by erf near 0 and erfc beyond.
double ndtr(double a) {
    if (std::isnan(a)) return a;
    const double sqrt1_2 = 0.70710678118654752440;
    const double x = a * sqrt1_2, z = std::fabs(x);
    if (z < sqrt1_2) return 0.5 + 0.5 * std::erf(x);
    const double y = 0.5 * std::erfc(z);
    return x > 0 ? 1.0 - y : y;
}

// np.argmin: the first smallest.
size_t argmin(const std::vector<double>& v) {
    size_t best = 0;
    for (size_t k = 1; k < v.size(); ++k)
        if (v[k] < v[best]) best = k;
    return best;
}

// robust_icp.median / np.median of a finite array: the middle value, or the mean of the middle two.
double median_of(std::vector<double> x) {
    const size_t n = x.size();
    if (n == 0) return std::numeric_limits<double>::quiet_NaN();
    const size_t h = n / 2;
    std::nth_element(x.begin(), x.begin() + std::ptrdiff_t(h), x.end());
    const double hi = x[h];
    if (n % 2) return hi;
    const double lo = *std::max_element(x.begin(), x.begin() + std::ptrdiff_t(h));
    return (lo + hi) / 2;
}

// The distances of a sweep's pairs in increasing order, each with its pair's index: what the
// median and the weights' running minimum read. The order among equal distances is left open:
// neither answer depends on it (equal distances have equal weights). The distances' bit patterns
// (for doubles >= +0 they order as the values) bucketed by their leading differing bits, each bucket
// then sorted; std::sort where a distance is negative or NaN.
struct SortedDistances {
    struct Keyed {
        uint64_t key;
        uint32_t index;
    };
    std::vector<std::pair<double, uint32_t>> by_d;
    std::vector<Keyed> a, b;  // the sort's two buffers
    std::vector<size_t> buckets;

    void assign(const std::vector<double>& d) {
        const size_t n = d.size();
        by_d.resize(n);
        a.resize(n);
        b.resize(n);
        uint64_t differ = 0, negative = 0;
        for (size_t i = 0; i < n; ++i) {
            uint64_t k;
            std::memcpy(&k, &d[i], sizeof k);
            a[i] = Keyed{k, uint32_t(i)};
            negative |= k;
            differ |= k ^ a[0].key;
        }
        bool ordinal = (negative >> 63) == 0;
        for (size_t i = 0; i < n && ordinal; ++i) ordinal = !std::isnan(d[i]);
        if (!ordinal) {
            for (size_t i = 0; i < n; ++i) by_d[i] = {d[i], uint32_t(i)};
            std::sort(by_d.begin(), by_d.end(), [](const std::pair<double, uint32_t>& x,
                                                   const std::pair<double, uint32_t>& y) { return x.first < y.first; });
            return;
        }
        // a counting sort by the keys' leading bits from the highest that differs, then each
        // bucket in order (by insertion where it holds a few keys)
        if (differ != 0) {
            int top = 63;
            while (!((differ >> top) & 1)) --top;
            int bits = 4;
            while (bits < 11 && (size_t(1) << bits) < 2 * n) ++bits;
            const int shift = top + 1 > bits ? top + 1 - bits : 0;
            // the bits above top are every key's: the bucket is the next `bits` bits down
            const uint64_t mask = (uint64_t(1) << (top + 1 - shift)) - 1;
            std::vector<size_t>& count = buckets;
            count.assign(mask + 2, 0);
            for (size_t i = 0; i < n; ++i) ++count[((a[i].key >> shift) & mask) + 1];
            for (size_t c = 1; c < count.size(); ++c) count[c] += count[c - 1];
            for (size_t i = 0; i < n; ++i) b[count[(a[i].key >> shift) & mask]++] = a[i];
            a.swap(b);
            // count[c] is now where bucket c ends: each bucket in order, by insertion where small
            size_t from = 0;
            for (size_t c = 0; c <= mask; ++c) {
                const size_t to = count[c];
                if (to - from > 16) {
                    std::sort(a.begin() + std::ptrdiff_t(from), a.begin() + std::ptrdiff_t(to),
                              [](const Keyed& x, const Keyed& y) { return x.key < y.key; });
                } else {
                    for (size_t i = from + 1; i < to; ++i) {
                        const Keyed e = a[i];
                        size_t j = i;
                        for (; j > from && a[j - 1].key > e.key; --j) a[j] = a[j - 1];
                        a[j] = e;
                    }
                }
                from = to;
            }
        }
        for (size_t i = 0; i < n; ++i) {
            double v;
            std::memcpy(&v, &a[i].key, sizeof v);
            by_d[i] = {v, a[i].index};
        }
    }
    // robust_icp.median / np.median of finite distances: the middle value, or the mean of the middle two.
    double median() const {
        const size_t n = by_d.size();
        if (n == 0) return std::numeric_limits<double>::quiet_NaN();
        const size_t h = n / 2;
        return n % 2 ? by_d[h].first : (by_d[h - 1].first + by_d[h].first) / 2;
    }
};

// DistanceMixture.weights: eq. 21 at max(d, mu_inlier), the inlier group's summed posterior, made
// non-increasing in the distance (running minimum in stable distance order). d: the distances,
// sorted: the same in increasing order. A weight is a function of its distance alone, so the running
// minimum over any order of increasing distance gives each pair the minimum over all distances up
// to its own: the reference's numbers.
void mixture_weights(const Mixture& m, const std::vector<double>& d, const SortedDistances& sorted,
                     std::vector<double>& w) {
    const size_t n = d.size(), k = m.means.size();
    w.assign(n, 0.0);
    if (n == 0) return;
    const size_t inl = argmin(m.means);
    std::vector<double> log_scale(k), logp(k);
    std::vector<char> group(k);
    const double band = m.means[inl] + 3.0 * m.sigmas[inl];
    for (size_t j = 0; j < k; ++j) {
        log_scale[j] = std::log(m.mix[j]) - std::log(m.sigmas[j]);
        group[j] = ndtr((band - m.means[j]) / m.sigmas[j]) > m.merge_overlap;
    }
    group[inl] = 1;
    for (size_t i = 0; i < n; ++i) {  // DistanceMixture.posterior
        const double x = std::max(d[i], m.means[inl]);
        double top = -kInf;
        for (size_t j = 0; j < k; ++j) {
            const double z = (x - m.means[j]) / m.sigmas[j];
            logp[j] = log_scale[j] - 0.5 * z * z;
            top = j == 0 ? logp[j] : std::max(top, logp[j]);
        }
        double num = 0.0, den = 0.0;
        for (size_t j = 0; j < k; ++j) {
            const double e = logp[j] - top;
            const double p = e == 0.0 ? 1.0 : std::exp(e);  // exp(0) is 1 exactly
            if (group[j]) num += p;
            den += p;
        }
        w[i] = num / den;
    }
    double run = w[sorted.by_d[0].second];
    for (size_t i = 0; i < n; ++i) {
        const size_t at = sorted.by_d[i].second;
        run = std::min(run, w[at]);
        w[at] = run;
    }
}

// np.quantile(x, q) with the default "linear" method on the sorted sample s.
double quantile(const std::vector<double>& s, double q) {
    const size_t n = s.size();
    const double v = double(n - 1) * q;
    double prev = std::floor(v);
    size_t lo, hi;
    if (v >= double(n - 1)) {
        lo = hi = n - 1;
        prev = -1.0;
    } else {
        lo = size_t(prev);
        hi = lo + 1;
    }
    const double gamma = v - prev, a = s[lo], b = s[hi];
    const double diff = b - a;  // numpy's _lerp
    return gamma >= 0.5 ? b - diff * (1 - gamma) : a + diff * gamma;
}

// np.var (ddof 0): the mean, then the mean of the squared deviations.
double variance(const std::vector<double>& x) {
    double s = 0.0;
    for (double v : x) s += v;
    const double mean = s / double(x.size());
    double ss = 0.0;
    for (double v : x) ss += (v - mean) * (v - mean);
    return ss / double(x.size());
}

// gmmsc._initial_guess: means at spread quantiles (np.linspace(0.2, 0.9, k)), variances of the
// nearest-mean groups floored, equal weights.
void initial_guess(const std::vector<double>& d, int k, std::vector<double>& means, std::vector<double>& var,
                   std::vector<double>& mix) {
    std::vector<double> sorted(d);
    std::sort(sorted.begin(), sorted.end());
    const double ptp = sorted.back() - sorted.front();
    means.assign(size_t(k), 0.0);
    const double step = (0.9 - 0.2) / double(k - 1);
    for (int j = 0; j < k; ++j) {
        const double q = k > 1 ? (j == k - 1 ? 0.9 : double(j) * step + 0.2) : 0.5;
        means[size_t(j)] = quantile(sorted, q) + double(j) * 1e-9 * std::max(ptp, 1.0);
    }
    std::vector<std::vector<double>> groups(static_cast<size_t>(k));
    for (double v : d) {
        size_t best = 0;
        for (size_t j = 1; j < size_t(k); ++j)
            if (std::fabs(v - means[j]) < std::fabs(v - means[best])) best = j;
        groups[best].push_back(v);
    }
    const double f = 1e-3 * std::max(ptp, 1e-9);
    const double floor = f * f;
    var.assign(size_t(k), 0.0);
    for (size_t j = 0; j < size_t(k); ++j) var[j] = std::max(groups[j].empty() ? 0.0 : variance(groups[j]), floor);
    mix.assign(size_t(k), 1.0 / double(k));
}

// gmmsc._em_1d: sklearn's EM for a 1-D mixture (log-sum-exp E-step, weighted moments with
// reg_covar), stopped when the mean log-likelihood per sample moves by less than tol.
void em_1d(const std::vector<double>& d, std::vector<double>& means, std::vector<double>& var,
           std::vector<double>& mix, int max_iter, double tol, double reg_covar) {
    const size_t n = d.size(), k = means.size();
    const double log_2pi = std::log(2.0 * kPi);
    const double eps10 = 10 * std::numeric_limits<double>::epsilon();
    double lower = -kInf;
    std::vector<double> logp(k * n), norm(n), c(k), nk(k), rd(k), rdd(k);
    for (int it = 0; it < max_iter; ++it) {
        for (size_t j = 0; j < k; ++j) c[j] = std::log(mix[j]) - 0.5 * (log_2pi + std::log(var[j]));
        for (size_t i = 0; i < n; ++i) {
            double top = -kInf;
            for (size_t j = 0; j < k; ++j) {
                const double z = d[i] - means[j];
                const double v = c[j] - 0.5 * z * z / var[j];
                logp[j * n + i] = v;
                top = j == 0 ? v : std::max(top, v);
            }
            double s = 0.0;
            for (size_t j = 0; j < k; ++j) s += std::exp(logp[j * n + i] - top);
            norm[i] = top + std::log(s);
        }
        for (size_t j = 0; j < k; ++j) {
            double sr = 0.0, srd = 0.0, srdd = 0.0;
            for (size_t i = 0; i < n; ++i) {
                const double r = std::exp(logp[j * n + i] - norm[i]);
                sr += r;
                srd += r * d[i];
                srdd += r * (d[i] * d[i]);
            }
            nk[j] = sr + eps10;
            rd[j] = srd;
            rdd[j] = srdd;
        }
        double total = 0.0;
        for (size_t j = 0; j < k; ++j) total += nk[j];
        for (size_t j = 0; j < k; ++j) {
            means[j] = rd[j] / nk[j];
            var[j] = rdd[j] / nk[j] - means[j] * means[j] + reg_covar;
            mix[j] = nk[j] / total;
        }
        double sn = 0.0;
        for (double v : norm) sn += v;
        const double prev = lower;
        lower = sn / double(n);
        if (std::fabs(lower - prev) < tol) break;
    }
}

// gmmsc.fit_distance_mixture: false where degenerate (too few distances, or all within min_spread).
bool fit_mixture(const std::vector<double>& distances, const RobustParams& p, const Mixture* init, Mixture& out) {
    std::vector<double> d;
    d.reserve(distances.size());
    for (double v : distances)
        if (std::isfinite(v)) d.push_back(v);
    const int k = p.n_components;
    if (d.empty() || int64_t(d.size()) < std::max(p.min_pairs, int64_t(k))) return false;
    const auto [lo, hi] = std::minmax_element(d.begin(), d.end());
    if (*hi - *lo < p.min_spread) return false;
    if (int64_t(d.size()) > p.max_fit_samples) {
        const size_t stride = size_t(std::ceil(double(d.size()) / double(p.max_fit_samples)));
        std::vector<double> sub;
        for (size_t i = 0; i < d.size(); i += stride) sub.push_back(d[i]);
        d.swap(sub);
    }
    std::vector<double> means, var, mix;
    if (init != nullptr && init->means.size() == size_t(k)) {
        means = init->means;
        mix = init->mix;
        var.resize(size_t(k));
        for (size_t j = 0; j < size_t(k); ++j) var[j] = std::max(init->sigmas[j] * init->sigmas[j], p.reg_covar);
    } else {
        initial_guess(d, k, means, var, mix);
    }
    double total = 0.0;
    for (double v : mix) total += v;
    for (double& v : mix) v = v / total;
    em_1d(d, means, var, mix, p.max_iter, p.tol, p.reg_covar);
    out.means = means;
    out.sigmas.resize(size_t(k));
    for (size_t j = 0; j < size_t(k); ++j) out.sigmas[j] = std::sqrt(var[j]);
    out.mix = mix;
    out.merge_overlap = p.merge_overlap;
    out.fit_median = median_of(d);
    return true;
}

// robust_icp.huber_weights: 1 for |r| <= delta, delta/|r| beyond.
double huber(double r, double delta) {
    const double a = std::fabs(r);
    return a <= delta ? 1.0 : delta / std::max(a, 1e-300);
}

using Mat3 = std::array<double, 9>;  // row-major
using Vec3 = std::array<double, 3>;

// np.linalg.lstsq's minimum-norm solution of h x = g (singular h): the pseudo-inverse from the
// eigenvectors of hT h (cyclic Jacobi), singular values below eps * 3 * the largest dropped.
Vec3 least_squares(const Mat3& h, const Vec3& g) {
    Mat3 a{}, v{1, 0, 0, 0, 1, 0, 0, 0, 1};
    for (int i = 0; i < 3; ++i)
        for (int j = 0; j < 3; ++j)
            for (int r = 0; r < 3; ++r) a[size_t(3 * i + j)] += h[size_t(3 * r + i)] * h[size_t(3 * r + j)];
    for (int sweep = 0; sweep < 64; ++sweep) {
        const double off = std::fabs(a[1]) + std::fabs(a[2]) + std::fabs(a[5]);
        if (off == 0.0) break;
        for (int p = 0; p < 2; ++p)
            for (int q = p + 1; q < 3; ++q) {
                const double apq = a[size_t(3 * p + q)];
                if (apq == 0.0) continue;
                const double theta = (a[size_t(3 * q + q)] - a[size_t(3 * p + p)]) / (2.0 * apq);
                const double t = (theta >= 0 ? 1.0 : -1.0) / (std::fabs(theta) + std::sqrt(theta * theta + 1.0));
                const double c = 1.0 / std::sqrt(t * t + 1.0), s = t * c;
                for (int r = 0; r < 3; ++r) {  // a = J^T a J, v = v J
                    const double arp = a[size_t(3 * r + p)], arq = a[size_t(3 * r + q)];
                    a[size_t(3 * r + p)] = c * arp - s * arq;
                    a[size_t(3 * r + q)] = s * arp + c * arq;
                }
                for (int r = 0; r < 3; ++r) {
                    const double apr = a[size_t(3 * p + r)], aqr = a[size_t(3 * q + r)];
                    a[size_t(3 * p + r)] = c * apr - s * aqr;
                    a[size_t(3 * q + r)] = s * apr + c * aqr;
                }
                for (int r = 0; r < 3; ++r) {
                    const double vrp = v[size_t(3 * r + p)], vrq = v[size_t(3 * r + q)];
                    v[size_t(3 * r + p)] = c * vrp - s * vrq;
                    v[size_t(3 * r + q)] = s * vrp + c * vrq;
                }
            }
    }
    Vec3 sv{};
    double smax = 0.0;
    for (int i = 0; i < 3; ++i) smax = std::max(smax, sv[size_t(i)] = std::sqrt(std::max(a[size_t(4 * i)], 0.0)));
    const double cut = std::numeric_limits<double>::epsilon() * 3.0 * smax;
    Vec3 htg{};  // hT g
    for (int i = 0; i < 3; ++i)
        for (int r = 0; r < 3; ++r) htg[size_t(i)] += h[size_t(3 * r + i)] * g[size_t(r)];
    Vec3 x{};
    for (int i = 0; i < 3; ++i) {
        if (!(sv[size_t(i)] > cut)) continue;
        double proj = 0.0;
        for (int r = 0; r < 3; ++r) proj += v[size_t(3 * r + i)] * htg[size_t(r)];
        proj /= sv[size_t(i)] * sv[size_t(i)];
        for (int r = 0; r < 3; ++r) x[size_t(r)] += v[size_t(3 * r + i)] * proj;
    }
    return x;
}

// np.linalg.solve (LAPACK gesv: LU with partial pivoting) for 3x3; false where a pivot is exactly 0.
bool solve3(Mat3 a, Vec3 b, Vec3& x) {
    for (int col = 0; col < 3; ++col) {
        int piv = col;
        for (int r = col + 1; r < 3; ++r)
            if (std::fabs(a[size_t(3 * r + col)]) > std::fabs(a[size_t(3 * piv + col)])) piv = r;
        if (a[size_t(3 * piv + col)] == 0.0) return false;
        if (piv != col) {
            for (int j = 0; j < 3; ++j) std::swap(a[size_t(3 * piv + j)], a[size_t(3 * col + j)]);
            std::swap(b[size_t(piv)], b[size_t(col)]);
        }
        for (int r = col + 1; r < 3; ++r) {
            const double f = a[size_t(3 * r + col)] / a[size_t(3 * col + col)];
            for (int j = col; j < 3; ++j) a[size_t(3 * r + j)] -= f * a[size_t(3 * col + j)];
            b[size_t(r)] -= f * b[size_t(col)];
        }
    }
    for (int r = 2; r >= 0; --r) {
        double s = b[size_t(r)];
        for (int j = r + 1; j < 3; ++j) s -= a[size_t(3 * r + j)] * x[size_t(j)];
        x[size_t(r)] = s / a[size_t(3 * r + r)];
    }
    return true;
}

// The pairs within the gate under a pose, with each moved source point (NearestPairs.pairs).
struct Pairs {
    std::vector<double> mx, my, tx, ty, dist;
    std::vector<int64_t> at;  // the target points' indices
    void clear() {
        at.clear();
        mx.clear();
        my.clear();
        tx.clear();
        ty.clear();
        dist.clear();
    }
};

void find_pairs(const TargetGrid& grid, const double* s, size_t n, const double pose[3],
                std::vector<TargetGrid::Memo>& memo, Pairs& out) {
    out.clear();
    const double c = std::cos(pose[2]), sn = std::sin(pose[2]);
    for (size_t i = 0; i < n; ++i) {
        const double x = s[2 * i], y = s[2 * i + 1];
        const double mx = c * x + (-sn) * y + pose[0];  // NearestPairs._moved's order
        const double my = c * y + sn * x + pose[1];
        double d, at[2];
        const int64_t j = grid.nearest(mx, my, d, at, memo[i]);
        if (j < 0) continue;
        out.mx.push_back(mx);
        out.my.push_back(my);
        out.tx.push_back(at[0]);
        out.ty.push_back(at[1]);
        out.dist.push_back(d);
        out.at.push_back(j);
    }
}


// icp.gauss_newton_step on the kept pairs (keep empty: all) with weights w: delta and H = JT W J
// (+ the prior's information); where lines is given, gauss_newton_step_lines: a pair whose
// target is on a line gives the one residual n . e (row (n_x, n_y, n . a)), its sums kept apart and
// added to the point-to-point ones at the end, as the reference adds them.
void gauss_newton_step(const Pairs& pr, const std::vector<size_t>& keep, const std::vector<double>& w,
                       const double pose[3], const double* prior_pose, const Mat3* prior_info, LineNormals* lines,
                       Vec3& delta, Mat3& h) {
    double sw = 0, swax = 0, sway = 0, saa = 0, g0 = 0, g1 = 0, g2 = 0;
    Mat3 hl{};  // the line residuals' J^T W J and J^T W r
    Vec3 gl{};
    for (size_t k = 0; k < w.size(); ++k) {
        const size_t i = keep.empty() ? k : keep[k];
        const double rpx = pr.mx[i] - pose[0], rpy = pr.my[i] - pose[1];
        const double ax = -rpy, ay = rpx;
        const double ex = pr.mx[i] - pr.tx[i], ey = pr.my[i] - pr.ty[i];
        const double wk = w[k];
        const double* nrm = nullptr;
        if (lines != nullptr && lines->on_line(pr.at[i], nrm)) {
            const double nx = nrm[0], ny = nrm[1];
            const double j[3] = {nx, ny, nx * ax + ny * ay};
            const double r = nx * ex + ny * ey;
            for (size_t a = 0; a < 3; ++a) {
                const double wa = j[a] * wk;
                for (size_t b = 0; b < 3; ++b) hl[3 * a + b] += wa * j[b];
                gl[a] += wa * r;
            }
            continue;
        }
        sw += wk;
        swax += wk * ax;
        sway += wk * ay;
        saa += wk * (ax * ax + ay * ay);
        g0 += wk * ex;
        g1 += wk * ey;
        g2 += wk * (ax * ex + ay * ey);
    }
    h = Mat3{sw, 0.0, swax, 0.0, sw, sway, swax, sway, saa};
    Vec3 g{g0, g1, g2};
    if (lines != nullptr) {
        for (size_t e = 0; e < 9; ++e) h[e] = h[e] + hl[e];
        for (size_t r = 0; r < 3; ++r) g[r] = g[r] + gl[r];
    }
    if (prior_pose != nullptr && prior_info != nullptr) {
        const double dp[3] = {pose[0] - prior_pose[0], pose[1] - prior_pose[1],
                              wrap_angle(pose[2] - prior_pose[2])};
        const Mat3& lam = *prior_info;
        for (size_t e = 0; e < 9; ++e) h[e] = h[e] + lam[e];
        for (size_t r = 0; r < 3; ++r) g[r] = g[r] + (lam[3 * r] * dp[0] + lam[3 * r + 1] * dp[1] + lam[3 * r + 2] * dp[2]);
    }
    Vec3 x{};
    if (!solve3(h, g, x)) x = least_squares(h, g);
    delta = Vec3{-x[0], -x[1], -x[2]};
}

// robust_icp._extrapolation_factor.
double extrapolation_factor(const Vec3& delta, const Vec3& prev, const RobustParams& p) {
    const double a[3] = {delta[0], delta[1], delta[2] * p.extrapolation_lever};
    const double b[3] = {prev[0], prev[1], prev[2] * p.extrapolation_lever};
    const double na = std::sqrt(a[0] * a[0] + a[1] * a[1] + a[2] * a[2]);
    const double nb = std::sqrt(b[0] * b[0] + b[1] * b[1] + b[2] * b[2]);
    if (na == 0.0 || nb == 0.0) return 1.0;
    const double rho = na / nb;
    if ((a[0] * b[0] + a[1] * b[1] + a[2] * b[2]) / (na * nb) < p.extrapolation_min_cos || rho >= 0.98) return 1.0;
    return 1.0 + std::min(rho / (1.0 - rho), p.max_extrapolation);
}

using Pose = std::tuple<double, double, double>;
using Flags = nb::ndarray<bool, nb::shape<-1>, nb::c_contig, nb::device::cpu>;
// (has a mixture, means, sigmas, mix, merge_overlap, fit_median)
using MixtureOut = std::tuple<bool, std::vector<double>, std::vector<double>, std::vector<double>, double, double>;

// robust_icp.register, whole. mixture_in: the given mixture (has, means, sigmas, mix, merge_overlap,
// fit_median); prior: has, pose (3), information (3x3 row-major); inlier_distance (m, at most the
// grid's radius): also count the source points within it of the target at the final pose
// (recovery.inlier_fraction's count; not counted where it is not > 0). Returns (pose, iterations, pairs
// kept, converged, rmse, H row-major, EM fits, whether the mixture was replaced, the mixture, the
// inlier count or -1). lines: the line normals of the grid's points (the same points, in the same
// order), for point-to-line residuals on lines; None: point-to-point.
std::tuple<Pose, int, int64_t, bool, double, Mat3, int, bool, MixtureOut, int64_t> robust_icp(
    const TargetGrid& grid, Points source, double x, double y, double theta, const RobustParams& p,
    const MixtureOut& mixture_in, bool has_prior, Vec3 prior_pose, Mat3 prior_info, double inlier_distance,
    LineNormals* lines) {
    const double* s = source.data();
    const size_t n = source.shape(0);
    if (lines != nullptr && size_t(lines->size()) != grid.size())
        throw nb::value_error("robust_icp: lines of another point set than the grid's");
    double pose[3] = {x, y, theta};
    Mixture mix;
    bool has_mix = std::get<0>(mixture_in), replaced = false;
    if (has_mix) {
        mix.means = std::get<1>(mixture_in);
        mix.sigmas = std::get<2>(mixture_in);
        mix.mix = std::get<3>(mixture_in);
        mix.merge_overlap = std::get<4>(mixture_in);
        mix.fit_median = std::get<5>(mixture_in);
        if (mix.sigmas.size() != mix.means.size() || mix.mix.size() != mix.means.size() || mix.means.empty())
            throw nb::value_error("robust_icp: the mixture's means, sigmas and mix must have one length");
    }
    bool gmm_on = false, converged = false, have_prev = false;
    int n_fits = 0, iterations = 0;
    int64_t n_kept = 0;
    Mat3 h{};
    Vec3 prev{};
    Pairs pairs;
    std::vector<double> gmm_w, w, last_d, kept_d;
    std::vector<size_t> keep;
    SortedDistances sorted;
    int64_t inliers = -1;
    {
        nb::gil_scoped_release release;
        std::vector<TargetGrid::Memo> memo(n);  // each source point's last search, for the next iteration's
        for (iterations = 1; iterations <= p.max_iterations; ++iterations) {
            find_pairs(grid, s, n, pose, memo, pairs);
            const size_t np = pairs.dist.size();
            if (int64_t(np) < p.min_correspondences) break;
            bool weighted = false;  // GMMSC weights (and the keep list) in use
            keep.clear();
            if (gmm_on) {
                sorted.assign(pairs.dist);
                const double med = sorted.median();
                const double r = p.gmm_refit_ratio;
                const double ref = has_mix ? mix.fit_median : std::numeric_limits<double>::quiet_NaN();
                const bool refit = !has_mix || r >= 1.0 || med < r * ref || med * r > ref;
                if (refit) {  // gmmsc_weights(refit=True): a fit warm-started from the mixture
                    Mixture fresh;
                    const bool ok = fit_mixture(pairs.dist, p, has_mix ? &mix : nullptr, fresh);
                    if (ok) mix = fresh;
                    has_mix = ok;
                    replaced = true;
                    n_fits += ok;
                    have_prev = false;
                }
                if (!has_mix || p.n_components == 1) {
                    gmm_w.assign(np, 1.0);
                } else {
                    mixture_weights(mix, pairs.dist, sorted, gmm_w);
                }
                weighted = true;
                for (size_t i = 0; i < np; ++i)
                    if (!(has_mix && p.n_components != 1) || gmm_w[i] >= p.w_th) keep.push_back(i);
            }
            const size_t n_pairs = weighted ? keep.size() : np;
            if (int64_t(n_pairs) < p.min_correspondences) break;
            // robust_icp._kept: distances and W = GMM x Huber of the kept pairs
            kept_d.resize(n_pairs);
            w.resize(n_pairs);
            for (size_t k = 0; k < n_pairs; ++k) {
                const size_t i = weighted ? keep[k] : k;
                const double d = pairs.dist[i];
                kept_d[k] = d;
                if (!weighted)
                    w[k] = p.use_huber ? huber(d, p.huber_delta) : 1.0;
                else
                    w[k] = p.use_huber ? gmm_w[i] * huber(d, p.huber_delta) : gmm_w[i];
            }
            if (!weighted) keep.clear();
            Vec3 delta;
            gauss_newton_step(pairs, keep, w, pose, has_prior ? prior_pose.data() : nullptr,
                              has_prior ? &prior_info : nullptr, lines, delta, h);
            Vec3 step = delta;
            if (p.extrapolate && have_prev) {
                const double f = extrapolation_factor(delta, prev, p);
                step = Vec3{delta[0] * f, delta[1] * f, delta[2] * f};
            }
            prev = delta;
            have_prev = true;
            pose[0] = pose[0] + step[0];
            pose[1] = pose[1] + step[1];
            pose[2] = wrap_angle(pose[2] + step[2]);
            n_kept = int64_t(n_pairs);
            last_d.swap(kept_d);
            if (p.use_gmmsc && !gmm_on) {
                gmm_on = std::hypot(delta[0], delta[1]) < p.gmm_start_translation &&
                         std::fabs(delta[2]) < p.gmm_start_rotation;
                if (gmm_on) have_prev = false;  // new weights: a new fixed point
                continue;                       // never stop before GMMSC has been applied
            }
            if (std::hypot(delta[0], delta[1]) < p.translation_tol && std::fabs(delta[2]) < p.rotation_tol) {
                converged = true;
                break;
            }
        }
        if (iterations > p.max_iterations) iterations = p.max_iterations;
        if (inlier_distance > 0.0) inliers = count_within(grid, s, n, pose[0], pose[1], pose[2], inlier_distance, &memo);
    }
    double rmse = std::numeric_limits<double>::quiet_NaN();
    if (n_kept > 0) {
        double sq = 0.0;
        for (double d : last_d) sq += d * d;
        rmse = std::sqrt(sq / double(last_d.size()));
    }
    MixtureOut out{has_mix, mix.means, mix.sigmas, mix.mix, mix.merge_overlap, mix.fit_median};
    return {Pose{pose[0], pose[1], pose[2]}, iterations, n_kept, converged, rmse, h, n_fits, replaced, out, inliers};
}

}  // namespace

void bind_robust_icp(nb::module_& m) {
    nb::class_<RobustParams>(m, "RobustICPParams")
        .def(nb::init<>())
        .def_rw("max_iterations", &RobustParams::max_iterations)
        .def_rw("translation_tol", &RobustParams::translation_tol)
        .def_rw("rotation_tol", &RobustParams::rotation_tol)
        .def_rw("min_correspondences", &RobustParams::min_correspondences)
        .def_rw("huber_delta", &RobustParams::huber_delta)
        .def_rw("use_huber", &RobustParams::use_huber)
        .def_rw("use_gmmsc", &RobustParams::use_gmmsc)
        .def_rw("gmm_start_translation", &RobustParams::gmm_start_translation)
        .def_rw("gmm_start_rotation", &RobustParams::gmm_start_rotation)
        .def_rw("gmm_refit_ratio", &RobustParams::gmm_refit_ratio)
        .def_rw("extrapolate", &RobustParams::extrapolate)
        .def_rw("max_extrapolation", &RobustParams::max_extrapolation)
        .def_rw("extrapolation_min_cos", &RobustParams::extrapolation_min_cos)
        .def_rw("extrapolation_lever", &RobustParams::extrapolation_lever)
        .def_rw("n_components", &RobustParams::n_components)
        .def_rw("w_th", &RobustParams::w_th)
        .def_rw("max_iter", &RobustParams::max_iter)
        .def_rw("tol", &RobustParams::tol)
        .def_rw("min_pairs", &RobustParams::min_pairs)
        .def_rw("min_spread", &RobustParams::min_spread)
        .def_rw("merge_overlap", &RobustParams::merge_overlap)
        .def_rw("reg_covar", &RobustParams::reg_covar)
        .def_rw("max_fit_samples", &RobustParams::max_fit_samples);
    m.def("robust_icp", &robust_icp, nb::arg("grid"), nb::arg("source"), nb::arg("x"), nb::arg("y"),
          nb::arg("theta"), nb::arg("params"), nb::arg("mixture"), nb::arg("has_prior"), nb::arg("prior_pose"),
          nb::arg("prior_information"), nb::arg("inlier_distance") = -1.0, nb::arg("lines").none() = nb::none());
    // LineNormals(points (M, 2), neighbours, min_planarity): fmcwlog/kernels/normals.py line_normals,
    // each point's at its first use; fill(normals (M, 2), on_line (M,)) asks for every point's,
    // computed() counts those computed so far.
    nb::class_<LineNormals>(m, "LineNormals")
        .def("__init__",
             [](LineNormals* t, Points points, int64_t neighbours, double min_planarity) {
                 if (neighbours < 1) throw nb::value_error("neighbours >= 1");
                 new (t) LineNormals(points.data(), int64_t(points.shape(0)), neighbours, min_planarity);
             },
             nb::arg("points"), nb::arg("neighbours"), nb::arg("min_planarity"))
        .def("fill",
             [](LineNormals& t, OutPoints normals, Flags on_line) {
                 if (int64_t(normals.shape(0)) != t.size() || int64_t(on_line.shape(0)) != t.size())
                     throw nb::value_error("outputs of M rows");
                 for (int64_t j = 0; j < t.size(); ++j) {
                     const double* nrm = nullptr;
                     on_line.data()[j] = t.on_line(j, nrm);
                     normals.data()[2 * j] = nrm[0];
                     normals.data()[2 * j + 1] = nrm[1];
                 }
             },
             nb::arg("normals"), nb::arg("on_line"))
        .def("computed", &LineNormals::computed)
        .def("__len__", &LineNormals::size);
}

}  // namespace fmcwlog
