#include "common/sim/scene_mesh.h"

#include <numeric>

#include "common/core/error.h"
#include "common/mesh/cleanup.h"
#include "common/mesh/generators.h"
#include "common/mesh/mesh_io.h"
#include "common/mesh/mesh_validation.h"

namespace cutsim::sim {
namespace {

Eigen::Vector3d ToEigen(const cutsim::v1::Vec3& v) { return {v.x(), v.y(), v.z()}; }

std::string Resolve(const LoadedScene& scene, const std::string& file) {
  const std::filesystem::path p(file);
  return p.is_absolute() ? p.string() : (scene.base_dir / p).string();
}

}  // namespace

SceneMesh BuildSceneMesh(const LoadedScene& scene) {
  const auto& src = scene.scene.mesh();
  using MS = cutsim::v1::MeshSource;
  SceneMesh out;
  switch (src.source_case()) {
    case MS::kFile:
      out.mesh = mesh::ReadMesh(Resolve(scene, src.file()));
      break;
    case MS::kBox:
      out.mesh = mesh::MakeBox(ToEigen(src.box().min()), ToEigen(src.box().max()), src.box().nx(),
                               src.box().ny(), src.box().nz());
      break;
    case MS::kCylinder:
      out.mesh = mesh::MakeCylinder(src.cylinder().radius(), src.cylinder().length(),
                                    src.cylinder().segments(), src.cylinder().rings(),
                                    src.cylinder().slices());
      break;
    case MS::kSurface:
      out.mesh = mesh::TetrahedralizeSurface(Resolve(scene, src.surface().file()),
                                             src.surface().max_edge_length());
      break;
    case MS::kOrgan: {
      mesh::OrganOptions o;
      o.semi_axes = ToEigen(src.organ().semi_axes());
      o.edge_length = src.organ().edge_length();
      o.bean_depth = src.organ().bean_depth();
      out.mesh = mesh::MakeOrgan(o);
      break;
    }
    case MS::SOURCE_NOT_SET:
      ThrowInputError({.file = scene.path.string(), .field = "mesh"}, "no mesh source");
  }
  if (src.source_case() == MS::kFile || src.source_case() == MS::kSurface) {
    mesh::CheckWholeMesh(out.mesh, Resolve(scene, src.source_case() == MS::kFile ? src.file() : src.surface().file()));
  }
  if (src.scale() != 1.0) out.mesh.nodes *= src.scale();
  out.mesh.nodes.rowwise() += ToEigen(src.translate()).transpose();

  const int32_t n = out.mesh.num_nodes();
  if (src.no_reorder()) {
    out.permutation.new_to_old.resize(static_cast<size_t>(n));
    std::iota(out.permutation.new_to_old.begin(), out.permutation.new_to_old.end(), 0);
    out.permutation.old_to_new = out.permutation.new_to_old;
  } else {
    out.permutation = mesh::ReverseCuthillMcKee(out.mesh);
    mesh::ApplyNodePermutation(out.mesh, out.permutation);
    // Tets in node order too, so the force loop's gathers stay in cache.
    (void)mesh::SortTetsByNodes(out.mesh);
  }
  return out;
}

}  // namespace cutsim::sim
