// The mover tracker's sweep (fmcwlog/frontend/tracking.py, MoverTracker.segment after the free-space
// lookup): the seeds, the segmentation, the clusters as detections, the association (predict,
// gate, assignment, Kalman update, births, pruning) and the points the tracks claim, in one call.
//
// The track state stays in Python (MoverTracker's arrays); it comes in and the new state goes back.
// Sums over a cluster's points are taken in the points' order, as np.bincount takes them, so the
// detections are the reference's to the last bit; the Kalman algebra (4x4 products, 3x3 solves by
// hand) agrees with numpy's to rounding. The assignment is the shortest augmenting path algorithm
// of scipy.optimize.linear_sum_assignment (Crouse 2016), with its order of scans and ties.
#include <nanobind/stl/optional.h>
#include <nanobind/stl/tuple.h>

#include <optional>

#if defined(__SSE2__)
#include <emmintrin.h>
#endif

#include "common.hpp"
#include "kernels.hpp"
#include "segmentation.hpp"

namespace fmcwlog {
namespace {

constexpr double kNoMatch = 1e9;  // tracking._NO_MATCH

// TrackingParams of the reference, the fields the sweep reads (units there).
struct TrackConfig {
    double gate_distance, gate_chi2, position_sigma, doppler_sigma, accel_sigma, birth_tangential_sigma, max_coast;
    int64_t min_moving_hits;
    double min_speed, max_object_radius, claim_radius, claim_doppler, free_fraction;
    int64_t max_tracks;
};

// MoverTracker's arrays: x (T, 4), cov (T, 4, 4), time, last_update (T,) and moving_hits (T,).
struct Tracks {
    std::vector<double> x, cov, time, last;
    std::vector<int64_t> hits;
    size_t size() const { return time.size(); }
    // MoverTracker.confirmed
    bool confirmed(size_t k, const TrackConfig& p) const {
        return hits[k] >= p.min_moving_hits && std::hypot(x[4 * k + 2], x[4 * k + 3]) >= p.min_speed;
    }
};

// tracking.Detections: one entry a cluster.
struct Detections {
    size_t c = 0;
    std::vector<double> cx, cy, ux, uy, doppler, radius, time;
    std::vector<char> moving, free_space;
};

// tracking.detections over the clustered points `idx` (their labels `lab`, -1 for none).
Detections detections(const double* map_xy, const double* t, const double* epsilon, const bool* moving,
                      const bool* seen_free, const std::vector<int64_t>& idx, const std::vector<int64_t>& lab,
                      double ox, double oy, double stamp, double max_radius, double free_fraction) {
    Detections d;
    int64_t c = 0;
    for (int64_t l : lab) c = std::max(c, l + 1);
    d.c = size_t(c);
    const size_t nc = d.c;
    std::vector<double> count(nc, 0.0), sx(nc, 0.0), sy(nc, 0.0), se(nc, 0.0), st(nc, 0.0), sm(nc, 0.0), sf(nc, 0.0);
    for (size_t a = 0; a < idx.size(); ++a) {
        if (lab[a] < 0) continue;
        const size_t k = size_t(lab[a]), i = size_t(idx[a]);
        count[k] += 1.0;
        sx[k] += map_xy[2 * i];
        sy[k] += map_xy[2 * i + 1];
        se[k] += epsilon[i];
        st[k] += stamp + t[i];
        sm[k] += moving[i] ? 1.0 : 0.0;
        sf[k] += seen_free[i] ? 1.0 : 0.0;
    }
    d.cx.resize(nc);
    d.cy.resize(nc);
    d.ux.resize(nc);
    d.uy.resize(nc);
    d.doppler.resize(nc);
    d.radius.assign(nc, 0.0);
    d.time.resize(nc);
    d.moving.resize(nc);
    d.free_space.resize(nc);
    for (size_t k = 0; k < nc; ++k) {
        count[k] = std::max(count[k], 1.0);
        d.cx[k] = sx[k] / count[k];
        d.cy[k] = sy[k] / count[k];
    }
    for (size_t a = 0; a < idx.size(); ++a) {
        if (lab[a] < 0) continue;
        const size_t k = size_t(lab[a]), i = size_t(idx[a]);
        d.radius[k] = std::max(d.radius[k], std::hypot(map_xy[2 * i] - d.cx[k], map_xy[2 * i + 1] - d.cy[k]));
    }
    for (size_t k = 0; k < nc; ++k) {
        const double dx = d.cx[k] - ox, dy = d.cy[k] - oy;
        const double norm = std::max(std::hypot(dx, dy), 1e-9);
        d.ux[k] = dx / norm;
        d.uy[k] = dy / norm;
        d.doppler[k] = se[k] / count[k];
        d.time[k] = st[k] / count[k];
        d.moving[k] = sm[k] > 0.5 * count[k];
        d.free_space[k] = sf[k] >= free_fraction * count[k] && d.radius[k] <= max_radius && !d.moving[k];
    }
    return d;
}

// MoverTracker.predict: every track's state and covariance moved to `when`.
void predict(Tracks& tr, double when, const TrackConfig& p) {
    const double q = p.accel_sigma * p.accel_sigma;
    for (size_t k = 0; k < tr.size(); ++k) {
        const double dt = when - tr.time[k];
        double* x = &tr.x[4 * k];
        x[0] = x[0] + dt * x[2];
        x[1] = x[1] + dt * x[3];
        double f[4][4] = {{1, 0, dt, 0}, {0, 1, 0, dt}, {0, 0, 1, 0}, {0, 0, 0, 1}};
        double* c = &tr.cov[16 * k];
        double fp[4][4];
        for (int i = 0; i < 4; ++i)
            for (int j = 0; j < 4; ++j) {
                double s = 0.0;
                for (int m = 0; m < 4; ++m) s += f[i][m] * c[4 * m + j];
                fp[i][j] = s;
            }
        double g[4][4] = {};
        g[0][0] = g[1][1] = std::pow(dt, 4) / 4;
        g[0][2] = g[1][3] = g[2][0] = g[3][1] = std::pow(dt, 3) / 2;
        g[2][2] = g[3][3] = std::pow(dt, 2);
        for (int i = 0; i < 4; ++i)
            for (int j = 0; j < 4; ++j) {
                double s = 0.0;
                for (int m = 0; m < 4; ++m) s += fp[i][m] * f[j][m];
                c[4 * i + j] = s + q * g[i][j];
            }
        tr.time[k] = when;
    }
}

// X = S^-1 B for a 3x3 S and a 3xM B (Gaussian elimination with partial pivoting, as LAPACK's gesv).
template <int M>
void solve3(const double s_in[9], const double b_in[3 * M], double out[3 * M]) {
    double a[3][3], b[3][M];
    for (int i = 0; i < 3; ++i) {
        for (int j = 0; j < 3; ++j) a[i][j] = s_in[3 * i + j];
        for (int j = 0; j < M; ++j) b[i][j] = b_in[M * i + j];
    }
    for (int col = 0; col < 3; ++col) {
        int piv = col;
        for (int r = col + 1; r < 3; ++r)
            if (std::abs(a[r][col]) > std::abs(a[piv][col])) piv = r;
        if (piv != col) {
            std::swap(a[piv], a[col]);
            std::swap(b[piv], b[col]);
        }
        for (int r = col + 1; r < 3; ++r) {
            const double f = a[r][col] / a[col][col];
            for (int j = col; j < 3; ++j) a[r][j] -= f * a[col][j];
            for (int j = 0; j < M; ++j) b[r][j] -= f * b[col][j];
        }
    }
    for (int j = 0; j < M; ++j)
        for (int r = 2; r >= 0; --r) {
            double s = b[r][j];
            for (int m = r + 1; m < 3; ++m) s -= a[r][m] * out[M * m + j];
            out[M * r + j] = s / a[r][r];
        }
}

// One gated (track, cluster) pair: MoverTracker._innovations and the Mahalanobis distance of _gate.
struct Gated {
    size_t t, c;
    double d2;
    double y[3], s[9], h[12];
};

bool innovation(const Tracks& tr, const Detections& det, size_t t, size_t c, double when, const TrackConfig& p,
                Gated& g) {
    const double delay = det.time[c] - when;
    double* h = g.h;
    std::fill(h, h + 12, 0.0);
    h[0] = h[5] = 1.0;
    h[2] = h[7] = delay;
    h[10] = det.ux[c];
    h[11] = det.uy[c];
    const double* x = &tr.x[4 * t];
    const double z[3] = {det.cx[c], det.cy[c], det.doppler[c]};
    for (int i = 0; i < 3; ++i) {
        double s = 0.0;
        for (int m = 0; m < 4; ++m) s += h[4 * i + m] * x[m];
        g.y[i] = z[i] - s;
    }
    const double* cov = &tr.cov[16 * t];
    double hp[12];
    for (int i = 0; i < 3; ++i)
        for (int j = 0; j < 4; ++j) {
            double s = 0.0;
            for (int m = 0; m < 4; ++m) s += h[4 * i + m] * cov[4 * m + j];
            hp[4 * i + j] = s;
        }
    const double half = 0.5 * det.radius[c];
    const double pos = p.position_sigma * p.position_sigma + half * half;
    const double r[3] = {pos, pos, p.doppler_sigma * p.doppler_sigma};
    for (int i = 0; i < 3; ++i)
        for (int j = 0; j < 3; ++j) {
            double s = 0.0;
            for (int m = 0; m < 4; ++m) s += hp[4 * i + m] * h[4 * j + m];
            g.s[3 * i + j] = s + (i == j ? r[i] : 0.0);
        }
    double w[3];
    solve3<1>(g.s, g.y, w);
    g.d2 = g.y[0] * w[0] + g.y[1] * w[1] + g.y[2] * w[2];
    g.t = t;
    g.c = c;
    return g.d2 <= p.gate_chi2;
}

// scipy.optimize.linear_sum_assignment on a dense nr x nc cost (row-major, finite): the column of
// every row (-1 where none). A tall matrix is solved transposed, as scipy solves it.
std::vector<int64_t> assignment(size_t nr, size_t nc, const std::vector<double>& cost_in) {
    std::vector<int64_t> result(nr, -1);
    if (nr == 0 || nc == 0) return result;
    const bool transpose = nc < nr;
    std::vector<double> cost(cost_in);
    size_t rows = nr, cols = nc;
    if (transpose) {
        for (size_t i = 0; i < nr; ++i)
            for (size_t j = 0; j < nc; ++j) cost[j * nr + i] = cost_in[i * nc + j];
        std::swap(rows, cols);
    }
    std::vector<double> u(rows, 0.0), v(cols, 0.0), dist(cols);
    std::vector<int64_t> path(cols, -1), col4row(rows, -1), row4col(cols, -1), remaining(cols);
    std::vector<char> seen_row(rows), seen_col(cols);
    for (size_t cur = 0; cur < rows; ++cur) {
        // the shortest augmenting path from row `cur` (Dijkstra over the reduced costs)
        double min_val = 0.0;
        size_t left = cols;
        for (size_t it = 0; it < cols; ++it) remaining[it] = int64_t(cols - it - 1);
        std::fill(seen_row.begin(), seen_row.end(), 0);
        std::fill(seen_col.begin(), seen_col.end(), 0);
        std::fill(dist.begin(), dist.end(), kInf);
        int64_t sink = -1;
        size_t i = cur;
        while (sink == -1) {
            int64_t index = -1;
            double lowest = kInf;
            seen_row[i] = 1;
            for (size_t it = 0; it < left; ++it) {
                const size_t j = size_t(remaining[it]);
                const double r = min_val + cost[i * cols + j] - u[i] - v[j];
                if (r < dist[j]) {
                    path[j] = int64_t(i);
                    dist[j] = r;
                }
                if (dist[j] < lowest || (dist[j] == lowest && row4col[j] == -1)) {
                    lowest = dist[j];
                    index = int64_t(it);
                }
            }
            min_val = lowest;
            if (min_val == kInf) return result;  // infeasible: not with finite costs
            const size_t j = size_t(remaining[size_t(index)]);
            if (row4col[j] == -1)
                sink = int64_t(j);
            else
                i = size_t(row4col[j]);
            seen_col[j] = 1;
            remaining[size_t(index)] = remaining[--left];
        }
        // the dual variables, then the path's edges flipped
        u[cur] += min_val;
        for (size_t r = 0; r < rows; ++r)
            if (seen_row[r] && r != cur) u[r] += min_val - dist[size_t(col4row[r])];
        for (size_t j = 0; j < cols; ++j)
            if (seen_col[j]) v[j] -= min_val - dist[j];
        int64_t j = sink;
        while (true) {
            const int64_t r = path[size_t(j)];
            row4col[size_t(j)] = r;
            std::swap(col4row[size_t(r)], j);
            if (size_t(r) == cur) break;
        }
    }
    if (transpose) {
        for (size_t r = 0; r < rows; ++r)
            if (col4row[r] >= 0) result[size_t(col4row[r])] = int64_t(r);
    } else {
        result.assign(col4row.begin(), col4row.end());
    }
    return result;
}

// MoverTracker._update of track g.t with its innovation.
void update(Tracks& tr, const Gated& g) {
    double* cov = &tr.cov[16 * g.t];
    double hp[12];
    for (int i = 0; i < 3; ++i)
        for (int j = 0; j < 4; ++j) {
            double s = 0.0;
            for (int m = 0; m < 4; ++m) s += g.h[4 * i + m] * cov[4 * m + j];
            hp[4 * i + j] = s;
        }
    double sol[12];  // S^-1 H P (3x4); the gain is its transpose
    solve3<4>(g.s, hp, sol);
    double* x = &tr.x[4 * g.t];
    for (int i = 0; i < 4; ++i) {
        double s = 0.0;
        for (int m = 0; m < 3; ++m) s += sol[4 * m + i] * g.y[m];
        x[i] += s;
    }
    double ikh[4][4];  // I - K H
    for (int i = 0; i < 4; ++i)
        for (int j = 0; j < 4; ++j) {
            double s = 0.0;
            for (int m = 0; m < 3; ++m) s += sol[4 * m + i] * g.h[4 * m + j];
            ikh[i][j] = (i == j ? 1.0 : 0.0) - s;
        }
    double next[16];
    for (int i = 0; i < 4; ++i)
        for (int j = 0; j < 4; ++j) {
            double s = 0.0;
            for (int m = 0; m < 4; ++m) s += ikh[i][m] * cov[4 * m + j];
            next[4 * i + j] = s;
        }
    for (int i = 0; i < 4; ++i)
        for (int j = 0; j < 4; ++j) cov[4 * i + j] = 0.5 * (next[4 * i + j] + next[4 * j + i]);
}

// MoverTracker._birth of a track on cluster c.
void birth(Tracks& tr, const Detections& det, size_t c, double when, const TrackConfig& p) {
    const double ux = det.ux[c], uy = det.uy[c], nx = -uy, ny = ux;
    const double vx = det.doppler[c] * ux, vy = det.doppler[c] * uy;
    const double lag = when - det.time[c];
    tr.x.insert(tr.x.end(), {det.cx[c] + vx * lag, det.cy[c] + vy * lag, vx, vy});
    const double half = 0.5 * det.radius[c];
    const double pos = p.position_sigma * p.position_sigma + half * half;
    const double dv = p.doppler_sigma * p.doppler_sigma, tv = p.birth_tangential_sigma * p.birth_tangential_sigma;
    const double u[2] = {ux, uy}, n[2] = {nx, ny};
    double cov[16] = {};
    cov[0] = cov[5] = pos;
    for (int i = 0; i < 2; ++i)
        for (int j = 0; j < 2; ++j) cov[4 * (2 + i) + 2 + j] = dv * u[i] * u[j] + tv * n[i] * n[j];
    tr.cov.insert(tr.cov.end(), cov, cov + 16);
    tr.time.push_back(when);
    tr.last.push_back(when);
    tr.hits.push_back(1);
}

// MoverTracker._prune: drop tracks not updated for max_coast, then all but the max_tracks latest.
void prune(Tracks& tr, double when, const TrackConfig& p) {
    const size_t n = tr.size();
    std::vector<char> keep(n);
    std::vector<double> kept;
    for (size_t k = 0; k < n; ++k) {
        keep[k] = when - tr.last[k] <= p.max_coast;
        if (keep[k]) kept.push_back(tr.last[k]);
    }
    if (int64_t(kept.size()) > p.max_tracks) {
        std::sort(kept.begin(), kept.end());
        const double floor = kept[kept.size() - size_t(p.max_tracks)];
        for (size_t k = 0; k < n; ++k) keep[k] = keep[k] && tr.last[k] >= floor;
    }
    size_t w = 0;
    for (size_t k = 0; k < n; ++k) {
        if (!keep[k]) continue;
        std::copy(&tr.x[4 * k], &tr.x[4 * k] + 4, &tr.x[4 * w]);
        std::copy(&tr.cov[16 * k], &tr.cov[16 * k] + 16, &tr.cov[16 * w]);
        tr.time[w] = tr.time[k];
        tr.last[w] = tr.last[k];
        tr.hits[w] = tr.hits[k];
        ++w;
    }
    tr.x.resize(4 * w);
    tr.cov.resize(16 * w);
    tr.time.resize(w);
    tr.last.resize(w);
    tr.hits.resize(w);
}

// MoverTracker.associate: the clusters (C,) a confirmed track claims; the tracks are updated.
std::vector<char> associate(Tracks& tr, const Detections& det, double when, const TrackConfig& p) {
    std::vector<char> claimed(det.c, 0), assigned(det.c, 0);
    bool any_candidate = false;
    for (size_t c = 0; c < det.c; ++c) any_candidate = any_candidate || det.moving[c] || det.free_space[c];
    if (tr.size() == 0 && !any_candidate) return claimed;
    predict(tr, when, p);
    const size_t nt = tr.size();
    if (nt && det.c) {
        std::vector<char> confirmed(nt);
        for (size_t k = 0; k < nt; ++k) confirmed[k] = tr.confirmed(k, p);
        std::vector<Gated> gated;
        std::vector<double> cost(nt * det.c, kNoMatch);
        std::vector<int64_t> pair(nt * det.c, -1);
        for (size_t k = 0; k < nt; ++k)
            for (size_t c = 0; c < det.c; ++c) {
                if (!(std::hypot(tr.x[4 * k] - det.cx[c], tr.x[4 * k + 1] - det.cy[c]) <= p.gate_distance)) continue;
                Gated g;
                if (!innovation(tr, det, k, c, when, p, g)) continue;
                if (confirmed[k] && det.radius[c] <= p.max_object_radius) claimed[c] = 1;
                cost[k * det.c + c] = g.d2;
                pair[k * det.c + c] = int64_t(gated.size());
                gated.push_back(g);
            }
        const std::vector<int64_t> col = assignment(nt, det.c, cost);
        for (size_t k = 0; k < nt; ++k) {
            if (col[k] < 0 || !(cost[k * det.c + size_t(col[k])] < kNoMatch)) continue;
            const size_t c = size_t(col[k]);
            update(tr, gated[size_t(pair[k * det.c + c])]);
            tr.last[k] = when;
            tr.hits[k] += (det.moving[c] || det.free_space[c]) ? 1 : 0;
            assigned[c] = 1;
        }
    }
    for (size_t c = 0; c < det.c; ++c)
        if ((det.moving[c] || det.free_space[c]) && !assigned[c]) birth(tr, det, c, when, p);
    prune(tr, when, p);
    return claimed;
}

using Vector = nb::ndarray<const double, nb::shape<-1>, nb::c_contig, nb::device::cpu>;
using Mask = nb::ndarray<const bool, nb::shape<-1>, nb::c_contig, nb::device::cpu>;
using OutMask = nb::ndarray<bool, nb::shape<-1>, nb::c_contig, nb::device::cpu>;
using States = nb::ndarray<const double, nb::shape<-1, 4>, nb::c_contig, nb::device::cpu>;
using Covariances = nb::ndarray<const double, nb::shape<-1, 4, 4>, nb::c_contig, nb::device::cpu>;
using Counts = nb::ndarray<const int64_t, nb::shape<-1>, nb::c_contig, nb::device::cpu>;
using Pose3 = nb::ndarray<const double, nb::shape<3>, nb::c_contig, nb::device::cpu>;
using Config = nb::ndarray<const double, nb::shape<-1>, nb::c_contig, nb::device::cpu>;

// A numpy array owning a vector's data, of the given shape.
template <class T>
nb::ndarray<nb::numpy, T> owned(std::vector<T>&& data, std::initializer_list<size_t> shape) {
    auto* heap = new std::vector<T>(std::move(data));
    nb::capsule owner(heap, [](void* p) noexcept { delete static_cast<std::vector<T>*>(p); });
    return nb::ndarray<nb::numpy, T>(heap->data(), shape, owner);
}

// Whether every a[i] is finite: x - x is 0 for a finite x and NaN for an infinite or NaN one, and a
// sum of such terms is NaN from the first NaN on (four sums of two lanes, no branch a value).
bool finite(const double* a, size_t n) {
    size_t i = 0;
    bool ok = true;
#if defined(__SSE2__)
    __m128d s0 = _mm_setzero_pd(), s1 = _mm_setzero_pd(), s2 = _mm_setzero_pd(), s3 = _mm_setzero_pd();
    for (; i + 8 <= n; i += 8) {
        const __m128d v0 = _mm_loadu_pd(a + i), v1 = _mm_loadu_pd(a + i + 2);
        const __m128d v2 = _mm_loadu_pd(a + i + 4), v3 = _mm_loadu_pd(a + i + 6);
        s0 = _mm_add_pd(s0, _mm_sub_pd(v0, v0));
        s1 = _mm_add_pd(s1, _mm_sub_pd(v1, v1));
        s2 = _mm_add_pd(s2, _mm_sub_pd(v2, v2));
        s3 = _mm_add_pd(s3, _mm_sub_pd(v3, v3));
    }
    const __m128d s = _mm_add_pd(_mm_add_pd(s0, s1), _mm_add_pd(s2, s3));
    ok = _mm_movemask_pd(_mm_cmpeq_pd(s, s)) == 3;  // no lane NaN
#endif
    for (; i < n; ++i) ok = ok && std::isfinite(a[i]);
    return ok;
}

using Arr = nb::ndarray<nb::numpy, double>;
using Idx = nb::ndarray<nb::numpy, int64_t>;
using SweepResult = std::tuple<Idx, Arr, Arr, Arr, Arr, Idx>;

// MoverTracker.segment after the free-space lookup: xy (N, 2) lidar frame, map_xy (N, 2) the
// deskewed points in map, t (N,) s after stamp, epsilon (N,) m/s, seen_free (N,); lidar (3,) the
// lidar's pose in map, when (s) the sweep's middle time; seg / track: SegmentationParams and
// TrackingParams fields (tracking.py's _compiled_config). Fills moving (N,) with the Doppler
// verdict and returns (the points the tracks or free space label, left for the structure check;
// the new x, cov, time, last_update, moving_hits), or None where an input is not finite.
std::optional<SweepResult> track_sweep(Points xy, Points map_xy, Vector t, Vector epsilon, Mask seen_free, Pose3 lidar,
                                       double stamp, double when, Config seg, Config track, States x_in,
                                       Covariances cov_in, Vector time_in, Vector last_in, Counts hits_in,
                                       OutMask moving) {
    const size_t n = xy.shape(0), nt = x_in.shape(0);
    if (map_xy.shape(0) != n || t.shape(0) != n || epsilon.shape(0) != n || seen_free.shape(0) != n ||
        moving.shape(0) != n)
        throw nb::value_error("track_sweep: every per-point array must have the points' length");
    if (cov_in.shape(0) != nt || time_in.shape(0) != nt || last_in.shape(0) != nt || hits_in.shape(0) != nt)
        throw nb::value_error("track_sweep: every track array must have the tracks' length");
    if (seg.shape(0) != 7 || track.shape(0) != 14) throw nb::value_error("track_sweep: 7 + 14 parameters");
    if (!finite(xy.data(), 2 * n) || !finite(map_xy.data(), 2 * n) || !finite(t.data(), n) ||
        !finite(epsilon.data(), n) || !finite(lidar.data(), 3) || !std::isfinite(stamp) || !std::isfinite(when) ||
        !finite(x_in.data(), 4 * nt) || !finite(time_in.data(), nt))
        return std::nullopt;
    const double* sp = seg.data();
    const SegmentationConfig scfg{sp[0], sp[1], int64_t(sp[2]), sp[3], sp[4], sp[5] != 0.0, sp[6]};
    const double* tp = track.data();
    const TrackConfig p{tp[0], tp[1], tp[2], tp[3], tp[4], tp[5], tp[6], int64_t(tp[7]), tp[8], tp[9], tp[10], tp[11],
                        tp[12], int64_t(tp[13])};
    Tracks tr;
    tr.x.assign(x_in.data(), x_in.data() + 4 * nt);
    tr.cov.assign(cov_in.data(), cov_in.data() + 16 * nt);
    tr.time.assign(time_in.data(), time_in.data() + nt);
    tr.last.assign(last_in.data(), last_in.data() + nt);
    tr.hits.assign(hits_in.data(), hits_in.data() + nt);
    std::vector<int64_t> fresh;
    {
        nb::gil_scoped_release release;
        const double* pts = xy.data();
        const double* mxy = map_xy.data();
        const double* eps = epsilon.data();
        const bool* free = seen_free.data();
        bool* mov = moving.data();
        const double ax = lidar.data()[0], ay = lidar.data()[1], ath = lidar.data()[2];
        // MoverTracker.seeds: the confirmed tracks where expected at `when`, in the lidar frame
        std::vector<double> seeds;
        {
            const double c = std::cos(ath), s = std::sin(ath);
            const double ix = -c * ax - s * ay, iy = s * ax - c * ay, ith = wrap_angle(-ath);
            const double c2 = std::cos(ith), s2 = std::sin(ith);
            for (size_t k = 0; k < nt; ++k) {
                if (!tr.confirmed(k, p)) continue;
                const double px = tr.x[4 * k] + tr.x[4 * k + 2] * (when - tr.time[k]);
                const double py = tr.x[4 * k + 1] + tr.x[4 * k + 3] * (when - tr.time[k]);
                seeds.push_back(c2 * px - s2 * py + ix);
                seeds.push_back(s2 * px + c2 * py + iy);
            }
        }
        std::vector<int64_t> labels(n);
        std::vector<char> clustered(n);
        segment_clusters(pts, eps, n, seeds.data(), seeds.size() / 2, free, scfg, labels.data(),
                         reinterpret_cast<bool*>(clustered.data()), mov);
        std::vector<int64_t> idx, lab;
        for (size_t i = 0; i < n; ++i)
            if (clustered[i]) {
                idx.push_back(int64_t(i));
                lab.push_back(labels[i]);
            }
        const Detections det =
            detections(mxy, t.data(), eps, mov, free, idx, lab, ax, ay, stamp, p.max_object_radius, p.free_fraction);
        const std::vector<char> claimed = associate(tr, det, when, p);
        // the points of clusters claimed or in free space, and the loose points near a confirmed track
        std::vector<size_t> ok;
        for (size_t k = 0; k < tr.size(); ++k)
            if (tr.confirmed(k, p)) ok.push_back(k);
        for (size_t a = 0; a < idx.size(); ++a) {
            const size_t i = size_t(idx[a]);
            if (mov[i]) continue;
            const int64_t l = lab[a];
            bool by_cluster = l >= 0 && (claimed[size_t(l)] || det.free_space[size_t(l)]);
            const bool large = l < 0 || det.radius[size_t(l)] > p.max_object_radius;
            if (!by_cluster && large && p.claim_radius > 0 && !ok.empty()) {
                // MoverTracker.claim_points
                const double dx = mxy[2 * i] - ax, dy = mxy[2 * i + 1] - ay;
                const double norm = std::max(std::hypot(dx, dy), 1e-9);
                const double bx = dx / norm, by = dy / norm;
                for (size_t k : ok) {
                    const double* s = &tr.x[4 * k];
                    if (std::hypot(mxy[2 * i] - s[0], mxy[2 * i + 1] - s[1]) <= p.claim_radius &&
                        std::abs(eps[i] - (bx * s[2] + by * s[3])) <= p.claim_doppler) {
                        by_cluster = true;
                        break;
                    }
                }
            }
            if (by_cluster) fresh.push_back(int64_t(i));
        }
    }
    const size_t m = tr.size(), nf = fresh.size();
    return SweepResult(owned(std::move(fresh), {nf}), owned(std::move(tr.x), {m, 4}), owned(std::move(tr.cov), {m, 4, 4}),
                       owned(std::move(tr.time), {m}), owned(std::move(tr.last), {m}), owned(std::move(tr.hits), {m}));
}

}  // namespace

void bind_tracking(nb::module_& m) {
    m.def("track_sweep", &track_sweep, nb::arg("xy"), nb::arg("map_xy"), nb::arg("t"), nb::arg("epsilon"),
          nb::arg("seen_free"), nb::arg("lidar"), nb::arg("stamp"), nb::arg("when"), nb::arg("seg"), nb::arg("track"),
          nb::arg("x"), nb::arg("cov"), nb::arg("time"), nb::arg("last_update"), nb::arg("moving_hits"),
          nb::arg("moving"));
}

}  // namespace fmcwlog
