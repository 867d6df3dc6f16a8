// The back end's local edges (fmcwlog/backend/local_edges.py: LocalMatcher.edges and _match) in one
// call a node: the new node's points thinned to the query voxel, each of the few nodes before it
// thinned to the submap voxel with its normals (registration.build_submap, built once a node and
// kept while a later node may still match it), the point-to-line ICP from the front end's relative
// pose (registration.register_point_to_line), the gates, and the edge's covariance
// (keyframes.match_covariance). The same pairs and iterations as the reference; the poses and
// covariances agree to rounding.
#include <nanobind/stl/array.h>
#include <nanobind/stl/string.h>
#include <nanobind/stl/tuple.h>
#include <nanobind/stl/vector.h>

#include <map>
#include <memory>
#include <string>
#include <tuple>

#include "common.hpp"
#include "kernels.hpp"
#include "line_icp.hpp"
#include "voxel.hpp"

namespace fmcwlog {
namespace {

using Poses = nb::ndarray<const double, nb::shape<-1, 3>, nb::c_contig, nb::device::cpu>;
using EdgeOut = std::tuple<int64_t, Vec3, Mat3>;  // (the earlier node, the relative pose, its covariance)

// LocalMatcher's parameters (BackendParams' local_* and icp's, the ICP's cap and tolerance the local ones).
struct Settings {
    int64_t links;
    double query_voxel, submap_voxel;
    int64_t neighbours;
    double min_planarity, max_distance;
    int max_iterations;
    double kernel_scale, tolerance;
    int64_t min_pairs;
    double gate, gate_deg, effective_pairs, residual_sigma, sigma_xy_floor, sigma_yaw_floor;
};

// registration.Submap: the thinned points, their normals and neighbour table, and the pairing's grid.
struct Submap {
    std::vector<double> xy, normals, reach;
    std::unique_ptr<bool[]> has_normal;
    std::vector<int32_t> near;  // empty where a point is not finite (build_submap builds no table then)
    std::unique_ptr<TargetGrid> grid;
    size_t size() const { return xy.size() / 2; }
};

// One node: its points (float64, base_link, m) and, once a later node matched it, its submap.
struct Stored {
    std::vector<double> xy;
    std::unique_ptr<Submap> submap;
};

// voxel.voxel_downsample of n points (interleaved): themselves where size <= 0 or none.
std::vector<double> thinned(const std::vector<double>& xy, double size) {
    if (xy.empty() || size <= 0.0) return xy;
    return first_of_voxels(xy.data(), xy.size() / 2, size);
}

// geometry.between_floats: b in a's frame.
Vec3 between(const double* a, const double* b) {
    double c = std::cos(a[2]), s = std::sin(a[2]);
    const double ix = -c * a[0] - s * a[1], iy = s * a[0] - c * a[1], ith = wrap_angle(-a[2]);
    c = std::cos(ith);
    s = std::sin(ith);
    return {ix + c * b[0] - s * b[1], iy + s * b[0] + c * b[1], wrap_angle(ith + b[2])};
}

// keyframes.match_covariance with the local floors: the information scaled to effective_pairs pairs
// of residual_sigma, the regulariser added, inverted (np.linalg.inv: an LU solve of the identity),
// the floors' squares added, turned into the frame of the relative pose's yaw (to_local).
Mat3 match_covariance(const Mat3& h, int64_t pairs, double yaw, const Settings& p) {
    const double scale = std::min(1.0, p.effective_pairs / double(std::max<int64_t>(pairs, 1)));
    const double sigma2 = p.residual_sigma * p.residual_sigma;
    Mat3 info;
    for (size_t k = 0; k < 9; ++k) info[k] = h[k] * scale / sigma2;
    info[0] += 1e-4;  // keyframes._REGULARISER
    info[4] += 1e-4;
    info[8] += 1.0;
    Mat3 cov{};
    for (int col = 0; col < 3; ++col) {
        Vec3 e{0.0, 0.0, 0.0}, x{0.0, 0.0, 0.0};
        e[size_t(col)] = 1.0;
        if (!solve3(info, e, x)) throw std::domain_error("local edge: a singular information");
        for (int row = 0; row < 3; ++row) cov[size_t(3 * row + col)] = x[size_t(row)];
    }
    cov[0] += p.sigma_xy_floor * p.sigma_xy_floor;
    cov[4] += p.sigma_xy_floor * p.sigma_xy_floor;
    cov[8] += p.sigma_yaw_floor * p.sigma_yaw_floor;
    // a @ cov @ a.T, a = [[c, s, 0], [-s, c, 0], [0, 0, 1]] (rot2(yaw).T in its corner)
    const double c = std::cos(yaw), s = std::sin(yaw);
    const Mat3 a{c, s, 0.0, -s, c, 0.0, 0.0, 0.0, 1.0};
    Mat3 ac{}, out{};
    for (int i = 0; i < 3; ++i)
        for (int j = 0; j < 3; ++j) {
            double v = 0.0;
            for (int k = 0; k < 3; ++k) v += a[size_t(3 * i + k)] * cov[size_t(3 * k + j)];
            ac[size_t(3 * i + j)] = v;
        }
    for (int i = 0; i < 3; ++i)
        for (int j = 0; j < 3; ++j) {
            double v = 0.0;
            for (int k = 0; k < 3; ++k) v += ac[size_t(3 * i + k)] * a[size_t(3 * j + k)];
            out[size_t(3 * i + j)] = v;
        }
    return out;
}

class LocalEdges {
  public:
    explicit LocalEdges(const Settings& p) : p_(p) {}
    LocalEdges(const LocalEdges&) = delete;
    LocalEdges& operator=(const LocalEdges&) = delete;

    // A node the matcher has not seen as a new one (the first, or one before a matcher was made).
    void add(int64_t index, Points points) { store(index, points); }

    // LocalMatcher.edges: the new node ``index`` with its points, matched against nodes index - J ..
    // index - 1, J = len(poses) - 1 (each added before, as a new node or by add); poses (J + 1, 3): the
    // front end's poses of those nodes and the new one's last. Returns the edges and the reasons of
    // the matches that gave none, in node order, and each match's ICP iterations (0 where none ran);
    // forgets the nodes no later node will match.
    std::tuple<std::vector<EdgeOut>, std::vector<std::string>, std::vector<int>> edges(int64_t index, Points points, Poses poses) {
        const int64_t before = int64_t(poses.shape(0)) - 1;
        if (before < 0) throw nb::value_error("poses: one row a node and the new one's");
        for (int64_t j = index - before; j < index; ++j)
            if (!nodes_.count(j)) throw nb::value_error("local edges: a node before the new one was not added");
        store(index, points);
        std::vector<EdgeOut> out;
        std::vector<std::string> rejected;
        std::vector<int> iterations;
        {
            nb::gil_scoped_release release;
            const std::vector<double> q = thinned(nodes_[index].xy, p_.query_voxel);
            const double* pi = poses.data() + 3 * before;
            for (int64_t k = 0; k < before; ++k) {
                const int64_t j = index - before + k;
                iterations.push_back(0);
                const char* failed = match(j, q, poses.data() + 3 * k, pi, out, iterations.back());
                if (failed != nullptr) rejected.emplace_back(failed);
            }
            nodes_.erase(nodes_.begin(), nodes_.lower_bound(index - p_.links));
        }
        return {std::move(out), std::move(rejected), std::move(iterations)};
    }

    size_t held() const { return nodes_.size(); }

  private:
    void store(int64_t index, Points points) {
        Stored& s = nodes_[index];
        s.xy.assign(points.data(), points.data() + 2 * points.shape(0));
        s.submap.reset();
    }

    // LocalMatcher._submap
    const Submap& submap(Stored& node) {
        if (!node.submap) {
            auto sub = std::make_unique<Submap>();
            sub->xy = thinned(node.xy, p_.submap_voxel);
            const size_t m = sub->size();
            sub->normals.assign(2 * m, 0.0);
            sub->has_normal.reset(new bool[std::max<size_t>(m, 1)]);
            bool finite = true;
            for (double v : sub->xy) finite = finite && std::isfinite(v);
            if (finite) {
                sub->near.assign(m * size_t(p_.neighbours), 0);
                sub->reach.assign(m * size_t(p_.neighbours + 1), 0.0);
            }
            submap_normals_into(sub->xy.data(), int64_t(m), p_.neighbours, p_.min_planarity, sub->normals.data(),
                                sub->has_normal.get(), finite ? sub->near.data() : nullptr,
                                finite ? sub->reach.data() : nullptr);
            sub->grid = std::make_unique<TargetGrid>(sub->xy.data(), m, p_.max_distance);
            node.submap = std::move(sub);
        }
        return *node.submap;
    }

    // LocalMatcher._match: null where an edge was appended to out, else the reason it gave none;
    // iterations: the ICP's, where it ran.
    const char* match(int64_t j, const std::vector<double>& q, const double* pose_j, const double* pose_i,
                      std::vector<EdgeOut>& out, int& iterations) {
        Stored& node = nodes_[j];
        if (node.xy.empty() || q.empty()) return "empty";  // a keyframe without static points
        const Vec3 prior = between(pose_j, pose_i);
        const Submap& sub = submap(node);
        const size_t nq = q.size() / 2;
        if (int64_t(std::min(nq, sub.size())) < p_.min_pairs) return "points";
        const bool table = !sub.near.empty();
        LineIcpRun icp = run_line_icp(*sub.grid, sub.normals.data(), sub.has_normal.get(), q.data(), nq, prior,
                                      p_.max_iterations, p_.kernel_scale, p_.tolerance, nullptr, nullptr,
                                      table ? sub.near.data() : nullptr, table ? p_.neighbours : 0,
                                      table ? sub.reach.data() : nullptr);
        iterations = icp.iterations;
        const double mx = icp.pose[0] - prior[0], my = icp.pose[1] - prior[1];
        const double myaw = wrap_angle(icp.pose[2] - prior[2]);
        const bool far = std::hypot(mx, my) > p_.gate || std::abs(myaw) > p_.gate_deg * (kPi / 180.0);  // np.radians
        const int64_t pairs = int64_t(icp.r.size());
        if (!icp.converged) return "converged";
        if (pairs < p_.min_pairs) return "pairs";
        if (far) return "gate";
        out.emplace_back(j, icp.pose, match_covariance(icp.h, pairs, icp.pose[2], p_));
        return nullptr;
    }

    Settings p_;
    std::map<int64_t, Stored> nodes_;
};

}  // namespace

void bind_local_edges(nb::module_& m) {
    nb::class_<LocalEdges>(m, "LocalEdges")
        .def(
            "__init__",
            [](LocalEdges* self, int64_t links, double query_voxel, double submap_voxel, int64_t neighbours,
               double min_planarity, double max_distance, int max_iterations, double kernel_scale, double tolerance,
               int64_t min_pairs, double gate, double gate_deg, double effective_pairs, double residual_sigma,
               double sigma_xy_floor, double sigma_yaw_floor) {
                if (neighbours < 1) throw nb::value_error("neighbours >= 1");
                if (!(max_distance > 0.0) || !std::isfinite(max_distance)) throw nb::value_error("max_distance > 0");
                new (self) LocalEdges(Settings{links, query_voxel, submap_voxel, neighbours, min_planarity,
                                               max_distance, max_iterations, kernel_scale, tolerance, min_pairs, gate,
                                               gate_deg, effective_pairs, residual_sigma, sigma_xy_floor,
                                               sigma_yaw_floor});
            },
            nb::arg("links"), nb::arg("query_voxel"), nb::arg("submap_voxel"), nb::arg("neighbours"),
            nb::arg("min_planarity"), nb::arg("max_distance"), nb::arg("max_iterations"), nb::arg("kernel_scale"),
            nb::arg("tolerance"), nb::arg("min_pairs"), nb::arg("gate"), nb::arg("gate_deg"),
            nb::arg("effective_pairs"), nb::arg("residual_sigma"), nb::arg("sigma_xy_floor"),
            nb::arg("sigma_yaw_floor"))
        .def("add", &LocalEdges::add, nb::arg("index"), nb::arg("points"))
        .def("edges", &LocalEdges::edges, nb::arg("index"), nb::arg("points"), nb::arg("poses"))
        .def_prop_ro("held", &LocalEdges::held);
}

}  // namespace fmcwlog
