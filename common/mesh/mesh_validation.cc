#include "common/mesh/mesh_validation.h"

#include <algorithm>
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

}  // namespace

void ValidateTetMesh(const TetMesh& mesh, std::string_view source_name, const MeshOrigin& origin) {
  const int64_t num_nodes = mesh.nodes.rows();
  const int64_t num_tets = mesh.tets.rows();
  if (num_tets == 0) ThrowFileError(source_name, "mesh has no tetrahedra");
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
