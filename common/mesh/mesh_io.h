#pragma once
/// @file
/// Mesh files in and out. Every reader orients tets positively, then runs
/// `ValidateTetMesh`, so a returned mesh is always usable; every problem is an
/// `InputError` naming the file and, where known, the line or element.
/// Writers write `path + ".tmp"` (or a sibling temp name) and rename it over
/// `path`, so a crash never leaves a half-written file in place of a good one.

#include <span>
#include <string>
#include <vector>

#include "common/mesh/tet_mesh.h"

namespace cutsim::mesh {

/// A named per-node or per-tet array for VTK output (displacement, von Mises…).
struct VtkField {
  std::string name;
  int components = 1;          ///< 1 = scalar, 3 = vector; any count ≥ 1 in .vtu.
  std::vector<double> values;  ///< #N·components (point data) or #T·components (cell data), row-major.
};

/// What `ReadVtu` returns: the mesh and every data array except "region",
/// which becomes `mesh.regions`.
struct VtuData {
  TetMesh mesh;
  std::vector<VtkField> point_fields;
  std::vector<VtkField> cell_fields;
};

/// Reads a mesh by extension: .msh (gmsh 2.2/4.1, ASCII or binary), .node or
/// .ele (TetGen; both files are read), .mesh (Medit), .vtu (our own writer).
TetMesh ReadMesh(const std::string& path);

/// Gmsh .msh via libgmsh: 4-node tets (type 4) of every volume; region = first
/// physical tag of the tet's entity, else the elementary tag. Lower-dimensional
/// elements are ignored, other 3-D element types are an error. Nodes used by no
/// tet (gmsh keeps geometry points such as circle centres) are dropped.
TetMesh ReadGmsh(const std::string& path);

/// TetGen `<base>.node` + `<base>.ele`; `path` is either file or the base name.
/// Region = first element attribute (rounded), if any.
TetMesh ReadTetGen(const std::string& path);

/// Medit .mesh (ASCII): Vertices and Tetrahedra; region = tet reference.
TetMesh ReadMedit(const std::string& path);

/// VTK XML .vtu, ASCII, as written by `WriteVtu` (tets only).
VtuData ReadVtu(const std::string& path);

/// VTK XML unstructured grid, ASCII. `positions` #N×3, `tets` #T×4. Field
/// sizes must match (checked: a mismatch is a programming error).
void WriteVtu(const std::string& path, const Positions& positions, const Tets& tets,
              std::span<const VtkField> point_fields = {}, std::span<const VtkField> cell_fields = {});
/// As above; non-empty `mesh.regions` are written as cell data "region".
void WriteVtu(const std::string& path, const TetMesh& mesh, std::span<const VtkField> point_fields = {},
              std::span<const VtkField> cell_fields = {});

/// Legacy VTK (.vtk) ASCII unstructured grid; 1-component fields as SCALARS,
/// 3-component as VECTORS, others as FIELD arrays.
void WriteVtk(const std::string& path, const Positions& positions, const Tets& tets,
              std::span<const VtkField> point_fields = {}, std::span<const VtkField> cell_fields = {});

/// Gmsh format choice for `WriteMsh`.
struct MshFormat {
  double version = 4.1;  ///< 2.2 or 4.1.
  bool binary = false;
};

/// Gmsh .msh. 2.2 ASCII is written by hand; the others through libgmsh. Regions
/// become physical (and elementary) tags; tets without regions get tag 1.
/// Tet order is kept, except in 2.2 binary, where gmsh's writer groups tets by region.
void WriteMsh(const std::string& path, const TetMesh& mesh, MshFormat format = {});

/// TetGen `<base>.node` and `<base>.ele` (1-based, region as an attribute).
void WriteTetGen(const std::string& base_path, const TetMesh& mesh);

/// Medit .mesh (ASCII, MeshVersionFormatted 2), region as tet reference.
void WriteMedit(const std::string& path, const TetMesh& mesh);

/// ASCII STL of a triangle surface (outward normals from the winding).
void WriteStl(const std::string& path, const Positions& positions, const Triangles& tris);

}  // namespace cutsim::mesh
