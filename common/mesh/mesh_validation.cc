#include "common/mesh/mesh_validation.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <string>
#include <unordered_map>

#include <fmt/format.h>

#include "common/core/error.h"
#include "common/mesh/face_key.h"

namespace cutsim::mesh {
namespace {

int64_t IdOf(const std::vector<int64_t>& ids, int64_t row) {
  return row < static_cast<int64_t>(ids.size()) ? ids[static_cast<size_t>(row)] : row + 1;
}

[[noreturn]] void ThrowTet(std::string_view source, const MeshOrigin& origin, int64_t t,
                           std::string_view message) {
  SourceRef ref{.file = std::string(source)};
  if (t < static_cast<int64_t>(origin.tet_lines.size())) ref.line = origin.tet_lines[static_cast<size_t>(t)];
  ref.field = fmt::format("element {}", IdOf(origin.tet_ids, t));
  ThrowInputError(std::move(ref), message);
}

[[noreturn]] void ThrowNode(std::string_view source, const MeshOrigin& origin, int64_t n,
                            std::string_view message) {
  ThrowInputError(SourceRef{.file = std::string(source),
                            .field = fmt::format("node {}", IdOf(origin.node_ids, n))},
                  message);
}

/// Two nodes at exactly the same position: the mesh is cracked there (the
/// tets on either side are not connected), which no mesher means to write.
void CheckCoincidentNodes(const TetMesh& mesh, std::string_view source, const MeshOrigin& origin) {
  std::vector<int32_t> order(static_cast<size_t>(mesh.nodes.rows()));
  for (size_t i = 0; i < order.size(); ++i) order[i] = static_cast<int32_t>(i);
  auto row = [&](int32_t i) {
    return std::array<double, 3>{mesh.nodes(i, 0), mesh.nodes(i, 1), mesh.nodes(i, 2)};
  };
  std::sort(order.begin(), order.end(), [&](int32_t a, int32_t b) { return row(a) < row(b); });
  for (size_t i = 1; i < order.size(); ++i) {
    if (row(order[i]) == row(order[i - 1])) {
      const int32_t a = std::min(order[i], order[i - 1]), b = std::max(order[i], order[i - 1]);
      ThrowNode(source, origin, b, fmt::format("at the same position as node {} (coincident nodes)",
                                               IdOf(origin.node_ids, a)));
    }
  }
}

/// Signed 6 × volume of (a, b, c, d).
double Orient(const TetMesh& mesh, int32_t a, int32_t b, int32_t c, int32_t d) {
  const Eigen::Vector3d pa = mesh.nodes.row(a), pb = mesh.nodes.row(b), pc = mesh.nodes.row(c), pd = mesh.nodes.row(d);
  return (pb - pa).cross(pc - pa).dot(pd - pa);
}

/// A face shared by two tets whose fourth nodes lie on the same side of it:
/// the tets overlap (the mesh is folded), though each is positive.
void CheckFolds(const TetMesh& mesh, std::string_view source, const MeshOrigin& origin) {
  struct Entry {
    std::array<int32_t, 3> key;
    int32_t tet;
    int8_t face;
  };
  std::vector<Entry> faces;
  faces.reserve(4 * static_cast<size_t>(mesh.tets.rows()));
  for (int32_t t = 0; t < static_cast<int32_t>(mesh.tets.rows()); ++t) {
    for (int8_t f = 0; f < 4; ++f) {
      std::array<int32_t, 3> k{};
      for (int j = 0, m = 0; j < 4; ++j) {
        if (j != f) k[static_cast<size_t>(m++)] = mesh.tets(t, j);
      }
      std::sort(k.begin(), k.end());
      faces.push_back({k, t, f});
    }
  }
  std::sort(faces.begin(), faces.end(), [](const Entry& a, const Entry& b) {
    return a.key != b.key ? a.key < b.key : a.tet < b.tet;
  });
  for (size_t i = 1; i < faces.size(); ++i) {
    if (faces[i].key != faces[i - 1].key) continue;
    const auto& [a, b, c] = faces[i].key;
    const double own = Orient(mesh, a, b, c, mesh.tets(faces[i - 1].tet, faces[i - 1].face));
    const double other = Orient(mesh, a, b, c, mesh.tets(faces[i].tet, faces[i].face));
    if ((own > 0.0 && other > 0.0) || (own < 0.0 && other < 0.0)) {
      ThrowTet(source, origin, faces[i].tet,
               fmt::format("overlaps element {} across their shared face (folded mesh)",
                           IdOf(origin.tet_ids, faces[i - 1].tet)));
    }
  }
}

}  // namespace

void CheckMeshSize(int64_t nodes, int64_t tets, std::string_view source_name) {
  if (nodes < 0 || nodes > kMaxMeshNodes) {
    ThrowFileError(source_name, fmt::format("{} nodes: meshes are limited to {} nodes", nodes, kMaxMeshNodes));
  }
  if (tets < 0 || tets > kMaxMeshTets) {
    ThrowFileError(source_name, fmt::format("{} tetrahedra: meshes are limited to {} tetrahedra", tets, kMaxMeshTets));
  }
}

void ValidateTetMesh(const TetMesh& mesh, std::string_view source_name, const MeshOrigin& origin) {
  const int64_t num_nodes = mesh.nodes.rows();
  const int64_t num_tets = mesh.tets.rows();
  if (num_tets == 0) ThrowFileError(source_name, "mesh has no tetrahedra");
  CheckMeshSize(num_nodes, num_tets, source_name);
  if (!mesh.regions.empty() && static_cast<int64_t>(mesh.regions.size()) != num_tets) {
    ThrowFileError(source_name, fmt::format("{} region tags for {} tetrahedra",
                                            mesh.regions.size(), num_tets));
  }
  for (int64_t n = 0; n < num_nodes; ++n) {
    if (!mesh.nodes.row(n).allFinite()) ThrowNode(source_name, origin, n, "coordinate is NaN or infinite");
  }
  std::vector<uint8_t> used(static_cast<size_t>(num_nodes), 0);
  for (int64_t t = 0; t < num_tets; ++t) {
    for (int k = 0; k < 4; ++k) {
      const int32_t v = mesh.tets(t, k);
      if (v < 0 || v >= num_nodes) {
        ThrowTet(source_name, origin, t,
                 fmt::format("node index {} out of range [0, {})", v, num_nodes));
      }
      used[static_cast<size_t>(v)] = 1;
    }
    for (int a = 0; a < 4; ++a) {
      for (int b = a + 1; b < 4; ++b) {
        if (mesh.tets(t, a) == mesh.tets(t, b)) ThrowTet(source_name, origin, t, "repeats a node");
      }
    }
    double max_edge2 = 0.0;
    for (int a = 0; a < 4; ++a) {
      for (int b = a + 1; b < 4; ++b) {
        max_edge2 = std::max(max_edge2,
                             (mesh.nodes.row(mesh.tets(t, a)) - mesh.nodes.row(mesh.tets(t, b))).squaredNorm());
      }
    }
    const double six_vol = 6.0 * SignedVolume(mesh, static_cast<int32_t>(t));
    // Relative threshold: "zero" must not depend on the unit of length.
    if (std::abs(six_vol) <= 1e-12 * max_edge2 * std::sqrt(max_edge2)) {
      ThrowTet(source_name, origin, t, "zero-volume (degenerate) tetrahedron");
    }
    if (six_vol < 0.0) {
      ThrowTet(source_name, origin, t, fmt::format("inverted tetrahedron (signed volume {:g} m³)", six_vol / 6.0));
    }
  }
  for (int64_t n = 0; n < num_nodes; ++n) {
    if (used[static_cast<size_t>(n)] == 0) ThrowNode(source_name, origin, n, "dangling node: used by no tetrahedron");
  }
  // Duplicate tets: same sorted node set.
  {
    std::vector<std::array<int32_t, 5>> keys(static_cast<size_t>(num_tets));
    for (int64_t t = 0; t < num_tets; ++t) {
      std::array<int32_t, 4> k{mesh.tets(t, 0), mesh.tets(t, 1), mesh.tets(t, 2), mesh.tets(t, 3)};
      std::sort(k.begin(), k.end());
      keys[static_cast<size_t>(t)] = {k[0], k[1], k[2], k[3], static_cast<int32_t>(t)};
    }
    std::sort(keys.begin(), keys.end());
    for (size_t i = 1; i < keys.size(); ++i) {
      if (std::equal(keys[i].begin(), keys[i].begin() + 4, keys[i - 1].begin())) {
        ThrowTet(source_name, origin, std::max(keys[i][4], keys[i - 1][4]),
                 fmt::format("duplicate of element {}",
                             IdOf(origin.tet_ids, std::min(keys[i][4], keys[i - 1][4]))));
      }
    }
  }
  if (const int64_t f = FindOvershardFace(mesh.tets); f >= 0) {
    ThrowTet(source_name, origin, f / 4, "a face of this tetrahedron is shared by more than two tetrahedra");
  }
}

void CheckWholeMesh(const TetMesh& mesh, std::string_view source_name, const MeshOrigin& origin) {
  CheckCoincidentNodes(mesh, source_name, origin);
  CheckFolds(mesh, source_name, origin);
}

int64_t OrientTets(TetMesh& mesh) {
  int64_t flipped = 0;
  for (int32_t t = 0; t < mesh.num_tets(); ++t) {
    if (SignedVolume(mesh, t) < 0.0) {
      std::swap(mesh.tets(t, 1), mesh.tets(t, 2));
      ++flipped;
    }
  }
  return flipped;
}

int64_t FindOvershardFace(const Tets& tets) {
  std::unordered_map<internal::FaceKey, int32_t, internal::FaceKeyHash> count;
  count.reserve(static_cast<size_t>(tets.rows()) * 3);
  for (int64_t t = 0; t < tets.rows(); ++t) {
    for (int f = 0; f < 4; ++f) {
      const auto& lf = internal::kTetFaces[static_cast<size_t>(f)];
      const auto key = internal::SortedKey(tets(t, lf[0]), tets(t, lf[1]), tets(t, lf[2]));
      if (++count[key] > 2) return t * 4 + f;
    }
  }
  return -1;
}

}  // namespace cutsim::mesh
