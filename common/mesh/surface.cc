#include "common/mesh/surface.h"

#include <algorithm>
#include <unordered_map>

#include <fmt/format.h>

#include "common/mesh/face_key.h"

namespace cutsim::mesh {

std::array<int, 3> LocalTetFace(int f) { return internal::kTetFaces.at(static_cast<size_t>(f)); }

Surface ExtractSurface(const Tets& tets) {
  // Value: first (tet·4 + face) seen, or −1 once a second tet claims the face.
  std::unordered_map<internal::FaceKey, int64_t, internal::FaceKeyHash> owner;
  owner.reserve(static_cast<size_t>(tets.rows()) * 3);
  for (int64_t t = 0; t < tets.rows(); ++t) {
    for (int f = 0; f < 4; ++f) {
      const auto& lf = internal::kTetFaces[static_cast<size_t>(f)];
      auto [it, inserted] =
          owner.try_emplace(internal::SortedKey(tets(t, lf[0]), tets(t, lf[1]), tets(t, lf[2])), t * 4 + f);
      if (!inserted) it->second = -1;
    }
  }
  std::vector<int64_t> boundary;
  boundary.reserve(owner.size());
  for (const auto& [key, tf] : owner) {
    if (tf >= 0) boundary.push_back(tf);
  }
  std::sort(boundary.begin(), boundary.end());  // hash order is not deterministic across platforms
  Surface s;
  s.tris.resize(static_cast<Eigen::Index>(boundary.size()), 3);
  s.tet.resize(boundary.size());
  s.local_face.resize(boundary.size());
  for (size_t i = 0; i < boundary.size(); ++i) {
    const auto t = boundary[i] / 4;
    const auto f = static_cast<int>(boundary[i] % 4);
    const auto& lf = internal::kTetFaces[static_cast<size_t>(f)];
    const auto r = static_cast<Eigen::Index>(i);
    s.tris.row(r) << tets(t, lf[0]), tets(t, lf[1]), tets(t, lf[2]);
    s.tet[i] = static_cast<int32_t>(t);
    s.local_face[i] = static_cast<int8_t>(f);
  }
  return s;
}

ManifoldCheck CheckClosedManifold(const Triangles& tris) {
  ManifoldCheck out;
  out.num_faces = tris.rows();
  auto fail = [&](std::string why) {
    out.ok = false;
    out.problem = std::move(why);
    return out;
  };
  if (tris.rows() == 0) return fail("no triangles");
  // Directed edge (a,b) → triangle; an edge seen twice in the same direction
  // means inconsistent orientation or more than two triangles on the edge.
  std::unordered_map<uint64_t, int64_t> directed;
  directed.reserve(static_cast<size_t>(tris.rows()) * 4);
  auto key = [](int32_t a, int32_t b) {
    return (static_cast<uint64_t>(static_cast<uint32_t>(a)) << 32) | static_cast<uint32_t>(b);
  };
  int32_t max_vertex = -1;
  for (int64_t f = 0; f < tris.rows(); ++f) {
    const int32_t a = tris(f, 0), b = tris(f, 1), c = tris(f, 2);
    if (a < 0 || b < 0 || c < 0) return fail(fmt::format("triangle {} has a negative index", f));
    if (a == b || b == c || a == c) return fail(fmt::format("triangle {} is degenerate", f));
    max_vertex = std::max({max_vertex, a, b, c});
    for (auto [u, v] : {std::pair{a, b}, std::pair{b, c}, std::pair{c, a}}) {
      if (auto [it, inserted] = directed.try_emplace(key(u, v), f); !inserted) {
        return fail(fmt::format("edge ({}, {}) is used in the same direction by triangles {} and {} "
                                "(inconsistent orientation or more than two triangles)",
                                u, v, it->second, f));
      }
    }
  }
  for (const auto& [k, f] : directed) {
    const auto u = static_cast<int32_t>(k >> 32), v = static_cast<int32_t>(k & 0xffffffffU);
    if (!directed.contains(key(v, u))) {
      return fail(fmt::format("edge ({}, {}) of triangle {} is a boundary edge (surface not closed)", u, v, f));
    }
  }
  out.num_edges = static_cast<int64_t>(directed.size()) / 2;
  // Vertex manifoldness: the link of every vertex (edges b→c of its triangles
  // (v,b,c)) must be one cycle. Edge-manifoldness makes it a union of cycles.
  const auto nv = static_cast<size_t>(max_vertex) + 1;
  std::vector<int32_t> start(nv + 1, 0);
  for (int64_t f = 0; f < tris.rows(); ++f) {
    for (int k = 0; k < 3; ++k) ++start[static_cast<size_t>(tris(f, k)) + 1];
  }
  for (size_t v = 0; v < nv; ++v) start[v + 1] += start[v];
  std::vector<std::pair<int32_t, int32_t>> link(static_cast<size_t>(start[nv]));
  std::vector<int32_t> fill(start.begin(), start.end() - 1);
  for (int64_t f = 0; f < tris.rows(); ++f) {
    for (int k = 0; k < 3; ++k) {
      const auto v = static_cast<size_t>(tris(f, k));
      link[static_cast<size_t>(fill[v]++)] = {tris(f, (k + 1) % 3), tris(f, (k + 2) % 3)};
    }
  }
  for (size_t v = 0; v < nv; ++v) {
    const auto begin = link.begin() + start[v], end = link.begin() + start[v + 1];
    if (begin == end) continue;
    ++out.num_vertices;
    std::sort(begin, end);
    // Walk the cycle from the first link edge; it must visit all of them.
    int32_t cur = begin->second;
    int64_t steps = 1;
    while (cur != begin->first) {
      auto it = std::lower_bound(begin, end, std::pair{cur, INT32_MIN});
      if (it == end || it->first != cur) break;  // cannot happen when edge-manifold
      cur = it->second;
      if (++steps > end - begin) break;
    }
    if (steps != end - begin) {
      return fail(fmt::format("vertex {} is non-manifold (its triangles form more than one fan)", v));
    }
  }
  out.ok = true;
  return out;
}

}  // namespace cutsim::mesh
