// fmcwlog._core: compiled twins of numpy kernels (fmcwlog/kernels/compiled.py selects them).
//
// Frames and units as in fmcwlog/kernels/nearest.py: a pose (x, y, theta) maps source points into
// the target frame (q = R(theta) p + t), metres and radians. Every distance is the KD-tree's own
// arithmetic, sqrt((dx)^2 + (dy)^2), so that the pairs are those of the numpy reference.

#include <nanobind/nanobind.h>
#include <nanobind/ndarray.h>
#include <nanobind/stl/tuple.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <limits>
#include <vector>

namespace nb = nanobind;

using Points = nb::ndarray<const double, nb::shape<-1, 2>, nb::c_contig, nb::device::cpu>;
using OutPoints = nb::ndarray<double, nb::shape<-1, 2>, nb::c_contig, nb::device::cpu>;
using OutVector = nb::ndarray<double, nb::shape<-1>, nb::c_contig, nb::device::cpu>;
using OutIndex = nb::ndarray<int64_t, nb::shape<-1>, nb::c_contig, nb::device::cpu>;

namespace {

constexpr double kInf = std::numeric_limits<double>::infinity();
constexpr double kPi = 3.14159265358979311600;  // numpy's pi
constexpr int64_t kMaxCells = 1 << 22;

// The target points bucketed by a uniform grid of cells half the search radius wide.
// A query scans its own cell, then rings of cells about it, each cell only where the cell's box
// may hold a point nearer than the best so far, until no farther ring can; the first best is
// the radius itself. Within a cell the points keep their order (ties go to the lowest index).
class TargetGrid {
  public:
    TargetGrid(const double* xy, size_t m, double radius) : radius_(radius) {
        x_.resize(m);
        y_.resize(m);
        double x0 = kInf, y0 = kInf, x1 = -kInf, y1 = -kInf;
        for (size_t i = 0; i < m; ++i) {
            x_[i] = xy[2 * i];
            y_[i] = xy[2 * i + 1];
            x0 = std::min(x0, x_[i]);
            y0 = std::min(y0, y_[i]);
            x1 = std::max(x1, x_[i]);
            y1 = std::max(y1, y_[i]);
        }
        if (m == 0) x0 = y0 = x1 = y1 = 0.0;
        cell_ = radius / 2.0;
        while ((std::floor((x1 - x0) / cell_) + 1.0) * (std::floor((y1 - y0) / cell_) + 1.0) > double(kMaxCells))
            cell_ *= 2.0;  // a wide map: fewer, wider cells (the rings still cover the radius)
        rings_ = int64_t(std::ceil(radius / cell_)) + 1;
        margin_ = 1e-9 * cell_;  // a cell's box, widened by more than the rounding of a point's cell
        x0_ = x0;
        y0_ = y0;
        nx_ = int64_t(std::floor((x1 - x0) / cell_)) + 1;
        ny_ = int64_t(std::floor((y1 - y0) / cell_)) + 1;
        start_.assign(size_t(nx_ * ny_ + 1), 0);
        std::vector<int64_t> where(m);
        for (size_t i = 0; i < m; ++i) {
            int64_t cx = std::clamp(int64_t(std::floor((x_[i] - x0_) / cell_)), int64_t(0), nx_ - 1);
            int64_t cy = std::clamp(int64_t(std::floor((y_[i] - y0_) / cell_)), int64_t(0), ny_ - 1);
            where[i] = cy * nx_ + cx;
            ++start_[size_t(where[i] + 1)];
        }
        for (size_t c = 1; c < start_.size(); ++c) start_[c] += start_[c - 1];
        order_.resize(m);
        std::vector<int64_t> fill(start_.begin(), start_.end() - 1);
        for (size_t i = 0; i < m; ++i) order_[size_t(fill[size_t(where[i])]++)] = int64_t(i);
        ox_.resize(m);
        oy_.resize(m);
        for (size_t k = 0; k < m; ++k) {
            ox_[k] = x_[size_t(order_[k])];
            oy_[k] = y_[size_t(order_[k])];
        }
    }

    double radius() const { return radius_; }
    double x(int64_t i) const { return x_[size_t(i)]; }
    double y(int64_t i) const { return y_[size_t(i)]; }

    // The nearest target point to (qx, qy) closer than the radius: its index and distance, or -1 and inf.
    int64_t nearest(double qx, double qy, double& dist) const {
        dist = kInf;
        if (!std::isfinite(qx) || !std::isfinite(qy)) return -1;
        const double fx = std::floor((qx - x0_) / cell_), fy = std::floor((qy - y0_) / cell_);
        const double reach = double(rings_) + 1.0;
        if (fx < -reach || fy < -reach || fx > double(nx_) + reach || fy > double(ny_) + reach) return -1;
        const int64_t cx = int64_t(fx), cy = int64_t(fy);
        double best = radius_ * radius_ * (1.0 + 1e-9);  // a bound: the root decides below
        int64_t found = -1;
        for (int64_t r = 0; r <= rings_; ++r) {
            const double gap = double(r - 1) * cell_ - margin_;  // every cell of ring r is at least this far
            if (r > 1 && gap * gap > best) break;
            for (int64_t y = cy - r; y <= cy + r; ++y) {
                if (y < 0 || y >= ny_) continue;
                const bool edge = (y == cy - r || y == cy + r);
                for (int64_t x = cx - r; x <= cx + r; x += (edge || r == 0) ? 1 : 2 * r) {
                    if (x < 0 || x >= nx_) continue;
                    const double lx = x0_ + double(x) * cell_ - margin_, hx = x0_ + double(x + 1) * cell_ + margin_;
                    const double ly = y0_ + double(y) * cell_ - margin_, hy = y0_ + double(y + 1) * cell_ + margin_;
                    const double bx = std::max({0.0, lx - qx, qx - hx}), by = std::max({0.0, ly - qy, qy - hy});
                    if (bx * bx + by * by > best) continue;
                    const int64_t c = y * nx_ + x;
                    for (int64_t k = start_[size_t(c)]; k < start_[size_t(c + 1)]; ++k) {
                        const double dx = ox_[size_t(k)] - qx;
                        const double dy = oy_[size_t(k)] - qy;
                        const double d2 = dx * dx + dy * dy;
                        if (d2 < best || (d2 == best && order_[size_t(k)] < found)) {
                            best = d2;
                            found = order_[size_t(k)];
                        }
                    }
                }
            }
        }
        if (found < 0) return -1;
        dist = std::sqrt(best);
        if (!(dist < radius_)) {
            dist = kInf;
            return -1;
        }
        return found;
    }

  private:
    double radius_, cell_ = 1.0, margin_ = 0.0, x0_ = 0.0, y0_ = 0.0;
    int64_t nx_ = 1, ny_ = 1, rings_ = 5;
    std::vector<double> x_, y_, ox_, oy_;
    std::vector<int64_t> start_, order_;
};

// geometry.wrap_angle on a scalar: (a + pi) mod 2 pi - pi, the modulo with the divisor's sign
double wrap_angle(double a) {
    const double two_pi = 2.0 * kPi;
    double r = std::fmod(a + kPi, two_pi);
    if (r != 0.0 && (r < 0.0) != (two_pi < 0.0)) r += two_pi;
    return r - kPi;
}

struct Pairs {
    std::vector<int64_t> src;
    std::vector<double> tx, ty, dist;
    void clear() {
        src.clear();
        tx.clear();
        ty.clear();
        dist.clear();
    }
};

// The pairs within the grid's radius under a pose (NearestPairs.pairs of the reference).
void find_pairs(const TargetGrid& grid, const double* s, size_t n, double px, double py, double th, Pairs& out) {
    out.clear();
    const double c = std::cos(th), sn = std::sin(th);
    for (size_t i = 0; i < n; ++i) {
        const double x = s[2 * i], y = s[2 * i + 1];
        const double mx = c * x + (-sn) * y + px;
        const double my = c * y + sn * x + py;
        double d;
        const int64_t j = grid.nearest(mx, my, d);
        if (j < 0) continue;
        out.src.push_back(int64_t(i));
        out.tx.push_back(grid.x(j));
        out.ty.push_back(grid.y(j));
        out.dist.push_back(d);
    }
}

// Least-squares pose for the pairs (2-D Kabsch; point_to_point_icp.closed_form_pose).
void closed_form_pose(const double* s, const Pairs& p, double pose[3]) {
    const size_t n = p.src.size();
    double spx = 0, spy = 0, sqx = 0, sqy = 0;
    for (size_t k = 0; k < n; ++k) {
        const size_t i = size_t(p.src[k]);
        spx += s[2 * i];
        spy += s[2 * i + 1];
        sqx += p.tx[k];
        sqy += p.ty[k];
    }
    const double pcx = spx / double(n), pcy = spy / double(n), qcx = sqx / double(n), qcy = sqy / double(n);
    double cross = 0, dot = 0;
    for (size_t k = 0; k < n; ++k) {
        const size_t i = size_t(p.src[k]);
        const double ax = s[2 * i] - pcx, ay = s[2 * i + 1] - pcy;
        const double bx = p.tx[k] - qcx, by = p.ty[k] - qcy;
        cross += ax * by - ay * bx;
        dot += ax * bx + ay * by;
    }
    const double th = std::atan2(cross, dot);
    const double c = std::cos(th), sn = std::sin(th);
    pose[0] = qcx - (c * pcx - sn * pcy);
    pose[1] = qcy - (sn * pcx + c * pcy);
    pose[2] = th;
}

using Pose = std::tuple<double, double, double>;
using Hessian = std::tuple<double, double, double, double, double>;  // h00 h02 h11 h12 h22 (h01 = 0)

// The baseline's point-to-point ICP (point_to_point_icp.register_point_to_point), whole: the
// pairs on the target's grid and a closed-form pose each iteration, the information matrix
// of the last pairs at the final pose; the gate is the grid's radius. Returns (pose, iterations,
// pairs kept, converged, rmse, hessian terms).
std::tuple<Pose, int, int64_t, bool, double, Hessian> point_to_point_icp(
    const TargetGrid& grid, Points source, double x, double y, double theta, int max_iterations,
    double translation_tol, double rotation_tol, int64_t min_correspondences) {
    const double* s = source.data();
    const size_t n = source.shape(0);
    double pose[3] = {x, y, theta};
    Pairs pairs, used;
    int iterations = 0;
    bool converged = false;
    {
        nb::gil_scoped_release release;
        for (iterations = 1; iterations <= max_iterations; ++iterations) {
            find_pairs(grid, s, n, pose[0], pose[1], pose[2], pairs);
            if (int64_t(pairs.src.size()) < min_correspondences) break;
            double fresh[3];
            closed_form_pose(s, pairs, fresh);
            const double sx = fresh[0] - pose[0], sy = fresh[1] - pose[1];
            const double st = wrap_angle(fresh[2] - pose[2]);
            pose[0] = fresh[0];
            pose[1] = fresh[1];
            pose[2] = fresh[2];
            std::swap(used, pairs);
            if (std::hypot(sx, sy) < translation_tol && std::fabs(st) < rotation_tol) {
                converged = true;
                break;
            }
        }
        if (iterations > max_iterations) iterations = max_iterations;
    }
    const size_t k = used.src.size();
    double rmse = std::numeric_limits<double>::quiet_NaN();
    Hessian h{0, 0, 0, 0, 0};
    if (k) {
        double sq = 0;
        for (double d : used.dist) sq += d * d;
        rmse = std::sqrt(sq / double(k));
        // gauss_newton_step's H with unit weights: ax = -(Rp)_y, ay = (Rp)_x at the final pose
        const double c = std::cos(pose[2]), sn = std::sin(pose[2]);
        double sax = 0, say = 0, saa = 0;
        for (size_t j = 0; j < k; ++j) {
            const size_t i = size_t(used.src[j]);
            const double px = s[2 * i], py = s[2 * i + 1];
            const double rx = (c * px + (-sn) * py + pose[0]) - pose[0];
            const double ry = (c * py + sn * px + pose[1]) - pose[1];
            const double ax = -ry, ay = rx;
            sax += ax;
            say += ay;
            saa += ax * ax + ay * ay;
        }
        h = Hessian{double(k), sax, double(k), say, saa};
    }
    return {Pose{pose[0], pose[1], pose[2]}, iterations, int64_t(k), converged, rmse, h};
}

// Under a pose: the moved source, each point's nearest target index (-1: none) and its distance
// (inf where none is closer than the grid's radius).
void nearest(const TargetGrid& grid, Points source, double x, double y, double theta, OutPoints moved,
             OutIndex index, OutVector distance) {
    const double* s = source.data();
    const size_t n = source.shape(0);
    if (moved.shape(0) != n || index.shape(0) != n || distance.shape(0) != n)
        throw nb::value_error("nearest: the outputs must have the source's length");
    nb::gil_scoped_release release;
    const double c = std::cos(theta), sn = std::sin(theta);
    double* m = moved.data();
    int64_t* idx = index.data();
    double* dist = distance.data();
    for (size_t i = 0; i < n; ++i) {
        const double px = s[2 * i], py = s[2 * i + 1];
        m[2 * i] = c * px + (-sn) * py + x;
        m[2 * i + 1] = c * py + sn * px + y;
        idx[i] = grid.nearest(m[2 * i], m[2 * i + 1], dist[i]);
    }
}

}  // namespace

NB_MODULE(_core, m) {
    m.doc() = "Compiled twins of fmcwlog's numpy kernels";
    m.attr("SOURCE_SHA256") = FMCWLOG_CORE_SOURCE_SHA256;
    nb::class_<TargetGrid>(m, "TargetGrid")
        .def(
            "__init__",
            [](TargetGrid* self, Points target, double radius) {
                if (!(radius > 0.0) || !std::isfinite(radius)) throw nb::value_error("radius must be finite and > 0");
                new (self) TargetGrid(target.data(), target.shape(0), radius);
            },
            nb::arg("target"), nb::arg("radius"))
        .def_prop_ro("radius", &TargetGrid::radius);
    m.def("point_to_point_icp", &point_to_point_icp, nb::arg("grid"), nb::arg("source"), nb::arg("x"), nb::arg("y"),
          nb::arg("theta"), nb::arg("max_iterations"), nb::arg("translation_tol"), nb::arg("rotation_tol"),
          nb::arg("min_correspondences"));
    m.def("nearest", &nearest, nb::arg("grid"), nb::arg("source"), nb::arg("x"), nb::arg("y"), nb::arg("theta"),
          nb::arg("moved"), nb::arg("index"), nb::arg("distance"));
}
