#include "common/mesh/reorder.h"

#include <algorithm>

#include "common/core/error.h"

namespace cutsim::mesh {
namespace {

// Compressed node adjacency: neighbours of n are adj[start[n] .. start[n+1]).
struct Graph {
  std::vector<int32_t> start, adj;
  [[nodiscard]] int32_t degree(int32_t n) const { return start[static_cast<size_t>(n) + 1] - start[static_cast<size_t>(n)]; }
};

Graph BuildGraph(const TetMesh& mesh) {
  const auto n = static_cast<size_t>(mesh.num_nodes());
  std::vector<std::vector<int32_t>> nbrs(n);
  for (int32_t t = 0; t < mesh.num_tets(); ++t) {
    for (int a = 0; a < 4; ++a) {
      for (int b = 0; b < 4; ++b) {
        if (a != b) nbrs[static_cast<size_t>(mesh.tets(t, a))].push_back(mesh.tets(t, b));
      }
    }
  }
  Graph g;
  g.start.assign(n + 1, 0);
  for (size_t i = 0; i < n; ++i) {
    auto& v = nbrs[i];
    std::sort(v.begin(), v.end());
    v.erase(std::unique(v.begin(), v.end()), v.end());
    g.start[i + 1] = g.start[i] + static_cast<int32_t>(v.size());
  }
  g.adj.reserve(static_cast<size_t>(g.start[n]));
  for (const auto& v : nbrs) g.adj.insert(g.adj.end(), v.begin(), v.end());
  return g;
}

// BFS from `root` over unvisited nodes, neighbours by increasing degree
// (Cuthill–McKee). Appends to `order`; returns the last level's first node.
int32_t CuthillMcKee(const Graph& g, int32_t root, std::vector<uint8_t>& visited, std::vector<int32_t>& order,
                     int32_t* depth) {
  const size_t begin = order.size();
  visited[static_cast<size_t>(root)] = 1;
  order.push_back(root);
  size_t level_begin = begin;
  int32_t levels = 0;
  std::vector<int32_t> scratch;
  for (size_t head = begin; head < order.size();) {
    const size_t level_end = order.size();
    level_begin = head;
    ++levels;
    for (; head < level_end; ++head) {
      const int32_t u = order[head];
      scratch.clear();
      for (int32_t k = g.start[static_cast<size_t>(u)]; k < g.start[static_cast<size_t>(u) + 1]; ++k) {
        const int32_t v = g.adj[static_cast<size_t>(k)];
        if (visited[static_cast<size_t>(v)] == 0) {
          visited[static_cast<size_t>(v)] = 1;
          scratch.push_back(v);
        }
      }
      std::stable_sort(scratch.begin(), scratch.end(),
                       [&](int32_t x, int32_t y) { return g.degree(x) < g.degree(y); });
      order.insert(order.end(), scratch.begin(), scratch.end());
    }
  }
  if (depth != nullptr) *depth = levels;
  // Lowest-degree node of the last level: a good next pseudo-peripheral candidate.
  return *std::min_element(order.begin() + static_cast<std::ptrdiff_t>(level_begin), order.end(),
                           [&](int32_t x, int32_t y) { return g.degree(x) < g.degree(y); });
}

}  // namespace

NodePermutation ReverseCuthillMcKee(const TetMesh& mesh) {
  const Graph g = BuildGraph(mesh);
  const auto n = static_cast<size_t>(mesh.num_nodes());
  std::vector<uint8_t> visited(n, 0);
  std::vector<int32_t> order;
  order.reserve(n);
  for (size_t start = 0; start < n; ++start) {
    if (visited[start] != 0) continue;
    // Pseudo-peripheral root (George–Liu): repeat BFS from the far end while
    // the level structure gets deeper; a few rounds suffice.
    int32_t root = static_cast<int32_t>(start), depth = 0;
    for (int round = 0; round < 4; ++round) {
      std::vector<uint8_t> probe = visited;
      std::vector<int32_t> tmp;
      int32_t d = 0;
      const int32_t far = CuthillMcKee(g, root, probe, tmp, &d);
      if (d <= depth) break;
      depth = d;
      root = far;
    }
    CuthillMcKee(g, root, visited, order, nullptr);
  }
  CUTSIM_CHECK(order.size() == n, "RCM must visit every node once");
  std::reverse(order.begin(), order.end());
  NodePermutation perm;
  perm.new_to_old = std::move(order);
  perm.old_to_new.assign(n, -1);
  for (size_t i = 0; i < n; ++i) perm.old_to_new[static_cast<size_t>(perm.new_to_old[i])] = static_cast<int32_t>(i);
  return perm;
}

void ApplyNodePermutation(TetMesh& mesh, const NodePermutation& perm) {
  CUTSIM_CHECK(perm.new_to_old.size() == static_cast<size_t>(mesh.num_nodes()) &&
                   perm.old_to_new.size() == perm.new_to_old.size(),
               "permutation size must match the node count");
  Positions nodes(mesh.nodes.rows(), 3);
  for (Eigen::Index i = 0; i < nodes.rows(); ++i) nodes.row(i) = mesh.nodes.row(perm.new_to_old[static_cast<size_t>(i)]);
  mesh.nodes = std::move(nodes);
  for (Eigen::Index t = 0; t < mesh.tets.rows(); ++t) {
    for (int k = 0; k < 4; ++k) mesh.tets(t, k) = perm.old_to_new[static_cast<size_t>(mesh.tets(t, k))];
  }
}

std::vector<int32_t> MapNodeIndices(const std::vector<int32_t>& old_indices, const NodePermutation& perm) {
  std::vector<int32_t> out;
  out.reserve(old_indices.size());
  for (const int32_t i : old_indices) out.push_back(perm.old_to_new.at(static_cast<size_t>(i)));
  return out;
}

int32_t Bandwidth(const Tets& tets) {
  int32_t bw = 0;
  for (Eigen::Index t = 0; t < tets.rows(); ++t) bw = std::max(bw, tets.row(t).maxCoeff() - tets.row(t).minCoeff());
  return bw;
}

}  // namespace cutsim::mesh
