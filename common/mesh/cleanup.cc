#include "common/mesh/cleanup.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <numeric>
#include <unordered_map>
#include <utility>
#include <vector>

#include "common/mesh/face_key.h"
#include "common/mesh/quality.h"

namespace cutsim::mesh {

namespace {

using internal::FaceKey;
using internal::FaceKeyHash;
using internal::kTetFaces;
using internal::SortedKey;
using Eigen::Vector3d;

Vector3d Node(const TetMesh& m, int32_t n) { return m.nodes.row(n).transpose(); }

double Quality(const TetMesh& m, int32_t t) {
  return MeanRatio(Node(m, m.tets(t, 0)), Node(m, m.tets(t, 1)), Node(m, m.tets(t, 2)), Node(m, m.tets(t, 3)));
}

FaceKey TetFace(const TetMesh& m, int32_t t, int f) {
  const auto& lf = kTetFaces[static_cast<size_t>(f)];
  return SortedKey(m.tets(t, lf[0]), m.tets(t, lf[1]), m.tets(t, lf[2]));
}

std::vector<std::vector<int32_t>> NodeTets(const TetMesh& m) {
  std::vector<std::vector<int32_t>> inc(static_cast<size_t>(m.num_nodes()));
  for (int32_t t = 0; t < m.num_tets(); ++t) {
    for (int c = 0; c < 4; ++c) inc[static_cast<size_t>(m.tets(t, c))].push_back(t);
  }
  return inc;
}

using FaceCount = std::unordered_map<FaceKey, int, FaceKeyHash>;

FaceCount CountFaces(const TetMesh& m, const std::vector<char>& alive) {
  FaceCount count;
  count.reserve(static_cast<size_t>(2 * m.num_tets() + 16));
  for (int32_t t = 0; t < m.num_tets(); ++t) {
    if (alive[static_cast<size_t>(t)] == 0) continue;
    for (int f = 0; f < 4; ++f) ++count[TetFace(m, t, f)];
  }
  return count;
}

int Count(const FaceCount& c, const FaceKey& k) {
  const auto it = c.find(k);
  return it == c.end() ? 0 : it->second;
}

/// Would the surface around every vertex of `t` stay a single closed fan
/// (or vanish, the vertex becoming interior or unused) if `t` were deleted?
bool RemovalKeepsManifold(const TetMesh& m, int32_t t, const std::vector<char>& alive,
                          const std::vector<std::vector<int32_t>>& inc, const FaceCount& count) {
  std::array<FaceKey, 4> own{};
  for (int f = 0; f < 4; ++f) own[static_cast<size_t>(f)] = TetFace(m, t, f);
  for (int c = 0; c < 4; ++c) {
    const int32_t v = m.tets(t, c);
    // Link edges (a, b) of the boundary faces (v, a, b) after the deletion.
    std::vector<std::pair<int32_t, int32_t>> link;
    for (const int32_t s : inc[static_cast<size_t>(v)]) {
      if (s == t || alive[static_cast<size_t>(s)] == 0) continue;
      for (int f = 0; f < 4; ++f) {
        const FaceKey k = TetFace(m, s, f);
        if (k[0] != v && k[1] != v && k[2] != v) continue;
        int n = Count(count, k);
        if (std::find(own.begin(), own.end(), k) != own.end()) --n;
        if (n != 1) continue;
        int32_t a = -1, b = -1;
        for (const int32_t w : k) {
          if (w == v) continue;
          (a < 0 ? a : b) = w;
        }
        link.emplace_back(a, b);
      }
    }
    if (link.empty()) continue;
    // Every link vertex has degree 2 and the link is one cycle.
    std::vector<int32_t> verts;
    for (const auto& [a, b] : link) {
      verts.push_back(a);
      verts.push_back(b);
    }
    std::sort(verts.begin(), verts.end());
    for (size_t i = 0; i < verts.size(); i += 2) {
      if (i + 1 >= verts.size() || verts[i] != verts[i + 1] || (i + 2 < verts.size() && verts[i + 2] == verts[i])) {
        return false;
      }
    }
    // Walk the cycle from the first edge.
    size_t visited = 1;
    const int32_t start = link[0].first;
    int32_t prev_edge = 0, cur = link[0].second;
    while (cur != start) {
      int32_t next_edge = -1;
      for (size_t e = 0; e < link.size(); ++e) {
        if (static_cast<int32_t>(e) == prev_edge) continue;
        if (link[e].first == cur || link[e].second == cur) {
          next_edge = static_cast<int32_t>(e);
          break;
        }
      }
      if (next_edge < 0) return false;
      const auto& ed = link[static_cast<size_t>(next_edge)];
      cur = ed.first == cur ? ed.second : ed.first;
      prev_edge = next_edge;
      if (++visited > link.size()) return false;
    }
    if (visited != link.size()) return false;
  }
  return true;
}

/// Drops dead tets and unused nodes, keeping the order of the rest.
int32_t Compact(TetMesh& m, const std::vector<char>& alive) {
  std::vector<int32_t> keep;
  for (int32_t t = 0; t < m.num_tets(); ++t) {
    if (alive[static_cast<size_t>(t)] != 0) keep.push_back(t);
  }
  std::vector<int32_t> node_map(static_cast<size_t>(m.num_nodes()), -1);
  for (const int32_t t : keep) {
    for (int c = 0; c < 4; ++c) node_map[static_cast<size_t>(m.tets(t, c))] = 0;
  }
  int32_t next = 0;
  for (auto& n : node_map) {
    if (n == 0) n = next++;
  }
  const int32_t dropped = m.num_nodes() - next;
  Positions nodes(next, 3);
  for (int32_t n = 0; n < m.num_nodes(); ++n) {
    if (node_map[static_cast<size_t>(n)] >= 0) nodes.row(node_map[static_cast<size_t>(n)]) = m.nodes.row(n);
  }
  Tets tets(static_cast<Eigen::Index>(keep.size()), 4);
  std::vector<int32_t> regions;
  for (size_t i = 0; i < keep.size(); ++i) {
    for (int c = 0; c < 4; ++c) {
      tets(static_cast<Eigen::Index>(i), c) = node_map[static_cast<size_t>(m.tets(keep[i], c))];
    }
    if (!m.regions.empty()) regions.push_back(m.regions[static_cast<size_t>(keep[i])]);
  }
  m.nodes = std::move(nodes);
  m.tets = std::move(tets);
  m.regions = std::move(regions);
  return dropped;
}

double StarMinQuality(const TetMesh& m, const std::vector<int32_t>& star) {
  double q = 1.0;
  for (const int32_t t : star) q = std::min(q, Quality(m, t));
  return q;
}

}  // namespace

int32_t RemoveBoundarySlivers(TetMesh& mesh, double min_quality, double* removed_volume,
                              int32_t* removed_nodes) {
  if (removed_volume != nullptr) *removed_volume = 0;
  if (removed_nodes != nullptr) *removed_nodes = 0;
  if (!(min_quality > 0) || mesh.num_tets() == 0) return 0;
  std::vector<char> alive(static_cast<size_t>(mesh.num_tets()), 1);
  const auto inc = NodeTets(mesh);
  FaceCount count = CountFaces(mesh, alive);
  std::vector<double> q(static_cast<size_t>(mesh.num_tets()));
  for (int32_t t = 0; t < mesh.num_tets(); ++t) q[static_cast<size_t>(t)] = Quality(mesh, t);
  auto boundary_faces = [&](int32_t t) {
    int nb = 0;
    for (int f = 0; f < 4; ++f) nb += Count(count, TetFace(mesh, t, f)) == 1 ? 1 : 0;
    return nb;
  };
  int32_t removed = 0;
  int32_t alive_count = mesh.num_tets();
  for (bool changed = true; changed;) {
    changed = false;
    std::vector<int32_t> cand;
    for (int32_t t = 0; t < mesh.num_tets(); ++t) {
      if (alive[static_cast<size_t>(t)] != 0 && q[static_cast<size_t>(t)] < min_quality && boundary_faces(t) >= 2) {
        cand.push_back(t);
      }
    }
    std::sort(cand.begin(), cand.end(), [&](int32_t a, int32_t b) {
      return std::pair(q[static_cast<size_t>(a)], a) < std::pair(q[static_cast<size_t>(b)], b);
    });
    for (const int32_t t : cand) {
      if (alive_count <= 1) break;
      if (boundary_faces(t) < 2 || !RemovalKeepsManifold(mesh, t, alive, inc, count)) continue;
      alive[static_cast<size_t>(t)] = 0;
      --alive_count;
      for (int f = 0; f < 4; ++f) {
        const FaceKey k = TetFace(mesh, t, f);
        if (--count[k] == 0) count.erase(k);
      }
      if (removed_volume != nullptr) *removed_volume += SignedVolume(mesh, t);
      ++removed;
      changed = true;
    }
  }
  if (removed > 0) {
    const int32_t dropped = Compact(mesh, alive);
    if (removed_nodes != nullptr) *removed_nodes = dropped;
  }
  return removed;
}

int32_t SmoothInteriorNodes(TetMesh& mesh, double min_quality, int passes) {
  if (!(min_quality > 0) || passes <= 0) return 0;
  const std::vector<char> alive(static_cast<size_t>(mesh.num_tets()), 1);
  const FaceCount count = CountFaces(mesh, alive);
  std::vector<char> on_boundary(static_cast<size_t>(mesh.num_nodes()), 0);
  for (const auto& [k, n] : count) {
    if (n == 1) {
      for (const int32_t v : k) on_boundary[static_cast<size_t>(v)] = 1;
    }
  }
  const auto inc = NodeTets(mesh);
  int32_t moves = 0;
  for (int pass = 0; pass < passes; ++pass) {
    std::vector<int32_t> nodes;
    for (int32_t t = 0; t < mesh.num_tets(); ++t) {
      if (Quality(mesh, t) >= min_quality) continue;
      for (int c = 0; c < 4; ++c) {
        if (on_boundary[static_cast<size_t>(mesh.tets(t, c))] == 0) nodes.push_back(mesh.tets(t, c));
      }
    }
    std::sort(nodes.begin(), nodes.end());
    nodes.erase(std::unique(nodes.begin(), nodes.end()), nodes.end());
    int32_t pass_moves = 0;
    for (const int32_t n : nodes) {
      const auto& star = inc[static_cast<size_t>(n)];
      const Vector3d p0 = Node(mesh, n);
      double best = StarMinQuality(mesh, star);
      Vector3d centroid = Vector3d::Zero();
      double h = 0;
      int k = 0;
      for (const int32_t t : star) {
        for (int c = 0; c < 4; ++c) {
          const int32_t w = mesh.tets(t, c);
          if (w == n) continue;
          centroid += Node(mesh, w);
          h += (Node(mesh, w) - p0).norm();
          ++k;
        }
      }
      centroid /= k;
      h /= k;
      auto try_at = [&](const Vector3d& p) {
        mesh.nodes.row(n) = p.transpose();
        const double qn = StarMinQuality(mesh, star);
        if (qn > best + 1e-9) {
          best = qn;
          return true;
        }
        mesh.nodes.row(n) = p0.transpose();
        return false;
      };
      bool moved = false;
      for (double s = 1.0; s >= 0.125 && !moved; s *= 0.5) moved = try_at(p0 + s * (centroid - p0));
      // Then a few steps of ascent on the worst tet of the star (numerical
      // gradient of its mean ratio with respect to this node).
      for (int it = 0; it < 10; ++it) {
        const Vector3d p = Node(mesh, n);
        int32_t worst = star[0];
        double wq = 2;
        for (const int32_t t : star) {
          const double qt = Quality(mesh, t);
          if (qt < wq) {
            wq = qt;
            worst = t;
          }
        }
        Vector3d g;
        const double e = 1e-4 * h;
        for (int d = 0; d < 3; ++d) {
          Vector3d pp = p, pm = p;
          pp(d) += e;
          pm(d) -= e;
          mesh.nodes.row(n) = pp.transpose();
          const double qp = Quality(mesh, worst);
          mesh.nodes.row(n) = pm.transpose();
          const double qm = Quality(mesh, worst);
          g(d) = (qp - qm) / (2 * e);
        }
        mesh.nodes.row(n) = p.transpose();
        if (!(g.norm() > 0) || !g.allFinite()) break;
        const Vector3d dir = g.normalized();
        bool step_ok = false;
        for (double s = 0.2 * h; s >= 0.2 * h / 64; s *= 0.5) {
          const Vector3d cand = p + s * dir;
          mesh.nodes.row(n) = cand.transpose();
          const double qn = StarMinQuality(mesh, star);
          if (qn > best + 1e-9) {
            best = qn;
            step_ok = true;
            break;
          }
          mesh.nodes.row(n) = p.transpose();
        }
        if (!step_ok) break;
        moved = true;
      }
      pass_moves += moved ? 1 : 0;
    }
    moves += pass_moves;
    if (pass_moves == 0) break;
  }
  return moves;
}

CleanupReport CleanupMesh(TetMesh& mesh, const CleanupOptions& options) {
  CleanupReport r;
  auto min_q = [&] {
    double m = 1.0;
    for (int32_t t = 0; t < mesh.num_tets(); ++t) m = std::min(m, Quality(mesh, t));
    return m;
  };
  r.min_quality_before = min_q();
  double vol = 0;
  int32_t nodes = 0;
  r.removed_tets += RemoveBoundarySlivers(mesh, options.sliver_quality, &vol, &nodes);
  r.removed_volume += vol;
  r.removed_nodes += nodes;
  r.moved_nodes += SmoothInteriorNodes(mesh, options.smooth_quality, options.smooth_passes);
  r.removed_tets += RemoveBoundarySlivers(mesh, options.sliver_quality, &vol, &nodes);
  r.removed_volume += vol;
  r.removed_nodes += nodes;
  r.min_quality_after = min_q();
  return r;
}

std::vector<int32_t> SortTetsByNodes(TetMesh& mesh) {
  const int32_t nt = mesh.num_tets();
  std::vector<std::array<int32_t, 4>> keys(static_cast<size_t>(nt));
  for (int32_t t = 0; t < nt; ++t) {
    std::array<int32_t, 4> k{mesh.tets(t, 0), mesh.tets(t, 1), mesh.tets(t, 2), mesh.tets(t, 3)};
    std::sort(k.begin(), k.end());
    keys[static_cast<size_t>(t)] = k;
  }
  std::vector<int32_t> order(static_cast<size_t>(nt));
  std::iota(order.begin(), order.end(), 0);
  std::stable_sort(order.begin(), order.end(),
                   [&](int32_t a, int32_t b) { return keys[static_cast<size_t>(a)] < keys[static_cast<size_t>(b)]; });
  Tets tets(nt, 4);
  std::vector<int32_t> regions;
  for (int32_t i = 0; i < nt; ++i) {
    tets.row(i) = mesh.tets.row(order[static_cast<size_t>(i)]);
    if (!mesh.regions.empty()) regions.push_back(mesh.regions[static_cast<size_t>(order[static_cast<size_t>(i)])]);
  }
  mesh.tets = std::move(tets);
  mesh.regions = std::move(regions);
  return order;
}

}  // namespace cutsim::mesh
