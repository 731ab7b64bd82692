// Everything that goes through libgmsh: .msh reading and writing, surface
// tetrahedralisation. gmsh keeps process-global state, so each use holds a
// mutex and runs between its own initialize/finalize.

#include <algorithm>
#include <array>
#include <charconv>
#include <cstring>
#include <filesystem>
#include <map>
#include <mutex>
#include <numeric>
#include <set>
#include <sstream>
#include <unordered_map>

#include <fmt/format.h>
#include <gmsh.h>

#include "common/core/error.h"
#include "common/core/finite.h"
#include "common/core/input_file.h"
#include "common/core/log.h"
#include "common/mesh/generators.h"
#include "common/mesh/mesh_io.h"
#include "common/mesh/mesh_validation.h"
#include "common/mesh/msh_check.h"
#include "common/mesh/surface.h"
#include "common/mesh/tet_mesh.h"
#include "common/mesh/text_io.h"

namespace cutsim::mesh {
namespace {

std::mutex& GmshMutex() {
  static std::mutex mutex;
  return mutex;
}

// RAII: lock, initialize quietly, finalize.
class GmshSession {
 public:
  GmshSession() : lock_(GmshMutex()) {
    gmsh::initialize(0, nullptr, /*readConfigFiles=*/false);
    gmsh::option::setNumber("General.Terminal", 0);  // no chatter on stdout
    gmsh::option::setNumber("General.Verbosity", 1);
    gmsh::option::setNumber("General.NumThreads", 1);
  }
  ~GmshSession() {
    try {
      gmsh::finalize();
    } catch (...) {  // NOLINT: a destructor must not throw
    }
  }
  GmshSession(const GmshSession&) = delete;
  GmshSession& operator=(const GmshSession&) = delete;

 private:
  std::lock_guard<std::mutex> lock_;
};

std::string LastGmshError() {
  std::string error;
  try {
    gmsh::logger::getLastError(error);
  } catch (...) {  // NOLINT: best effort
  }
  return error.empty() ? std::string("unknown gmsh error") : error;
}

std::vector<std::string> SplitWhitespace(const std::string& line);

// Runs `fn`, turning whatever gmsh throws (it throws std::string, int or
// exceptions depending on the call) into an InputError naming `path`.
template <typename Fn>
void GmshCall(const std::string& path, std::string_view what, Fn&& fn) {
  try {
    fn();
  } catch (const InputError&) {
    throw;
  } catch (const std::exception& e) {
    ThrowFileError(path, fmt::format("gmsh {} failed: {}", what, e.what()));
  } catch (...) {
    ThrowFileError(path, fmt::format("gmsh {} failed: {}", what, LastGmshError()));
  }
}

// Tets of every volume of the current gmsh model, nodes compacted to those used.
TetMesh ExtractTetsFromModel(const std::string& path) {
  TetMesh mesh;
  MeshOrigin origin;
  std::vector<std::size_t> tet_nodes;  // gmsh node tags, 4 per tet
  std::map<int, int64_t> other_types;  // element type → count (3-D non-tets)
  std::vector<std::size_t> node_tags;
  std::vector<double> coords;
  GmshCall(path, "reading the mesh", [&] {
    gmsh::vectorpair volumes;
    gmsh::model::getEntities(volumes, 3);
    for (const auto& [dim, tag] : volumes) {
      std::vector<int> types;
      std::vector<std::vector<std::size_t>> etags, ntags;
      gmsh::model::mesh::getElements(types, etags, ntags, dim, tag);
      std::vector<int> physical;
      gmsh::model::getPhysicalGroupsForEntity(dim, tag, physical);
      const int32_t region = physical.empty() ? tag : physical.front();
      for (size_t k = 0; k < types.size(); ++k) {
        if (types[k] != 4) {
          other_types[types[k]] += static_cast<int64_t>(etags[k].size());
          continue;
        }
        for (const std::size_t id : etags[k]) origin.tet_ids.push_back(static_cast<int64_t>(id));
        tet_nodes.insert(tet_nodes.end(), ntags[k].begin(), ntags[k].end());
        mesh.regions.insert(mesh.regions.end(), etags[k].size(), region);
      }
    }
    std::vector<double> param;
    gmsh::model::mesh::getNodes(node_tags, coords, param, -1, -1, /*includeBoundary=*/false,
                                /*returnParametricCoord=*/false);
  });
  if (!other_types.empty()) {
    std::string list;
    for (const auto& [type, count] : other_types) list += fmt::format("{}{} of type {}", list.empty() ? "" : ", ", count, type);
    ThrowFileError(path, fmt::format("unsupported 3-D elements ({}); only 4-node tetrahedra (type 4) are supported", list));
  }
  if (tet_nodes.empty()) ThrowFileError(path, "no 4-node tetrahedra (gmsh element type 4) in the file");
  // gmsh groups elements by entity; restore the file's element-id order.
  {
    std::vector<size_t> order(origin.tet_ids.size());
    std::iota(order.begin(), order.end(), size_t{0});
    std::stable_sort(order.begin(), order.end(),
                     [&](size_t a, size_t b) { return origin.tet_ids[a] < origin.tet_ids[b]; });
    std::vector<std::size_t> nodes_sorted(tet_nodes.size());
    std::vector<int64_t> ids_sorted(order.size());
    std::vector<int32_t> regions_sorted(order.size());
    for (size_t i = 0; i < order.size(); ++i) {
      std::copy_n(tet_nodes.begin() + static_cast<std::ptrdiff_t>(4 * order[i]), 4,
                  nodes_sorted.begin() + static_cast<std::ptrdiff_t>(4 * i));
      ids_sorted[i] = origin.tet_ids[order[i]];
      regions_sorted[i] = mesh.regions[order[i]];
    }
    tet_nodes = std::move(nodes_sorted);
    origin.tet_ids = std::move(ids_sorted);
    mesh.regions = std::move(regions_sorted);
  }
  // Keep only nodes used by tets, in increasing tag order.
  std::vector<std::size_t> used(tet_nodes);
  std::sort(used.begin(), used.end());
  used.erase(std::unique(used.begin(), used.end()), used.end());
  std::unordered_map<std::size_t, int32_t> index;
  index.reserve(used.size());
  for (size_t i = 0; i < used.size(); ++i) index.emplace(used[i], static_cast<int32_t>(i));
  mesh.nodes.resize(static_cast<Eigen::Index>(used.size()), 3);
  CheckMeshSize(static_cast<int64_t>(used.size()), static_cast<int64_t>(tet_nodes.size() / 4), path);
  std::vector<uint8_t> seen(used.size(), 0);
  for (size_t i = 0; i < node_tags.size(); ++i) {
    if (auto it = index.find(node_tags[i]); it != index.end()) {
      for (int k = 0; k < 3; ++k) mesh.nodes(it->second, k) = coords[3 * i + static_cast<size_t>(k)];
      seen[static_cast<size_t>(it->second)] = 1;
    }
  }
  for (size_t i = 0; i < used.size(); ++i) {
    if (seen[i] == 0) ThrowFileError(path, fmt::format("node {} is used by a tetrahedron but not defined", used[i]));
  }
  origin.node_ids.assign(used.begin(), used.end());
  mesh.tets.resize(static_cast<Eigen::Index>(tet_nodes.size() / 4), 4);
  for (size_t i = 0; i < tet_nodes.size(); ++i) {
    mesh.tets(static_cast<Eigen::Index>(i / 4), static_cast<Eigen::Index>(i % 4)) = index.at(tet_nodes[i]);
  }
  if (node_tags.size() > used.size()) {
    Log().debug("{}: dropped {} nodes not used by any tetrahedron", path, node_tags.size() - used.size());
  }
  internal::FinishRead(mesh, path, origin);
  return mesh;
}

}  // namespace

TetMesh ReadGmsh(const std::string& path) {
  internal::CheckMshBeforeGmsh(path, ReadInputFile(path, "mesh file"));
  GmshSession session;
  GmshCall(path, "open", [&] { gmsh::open(path); });
  return ExtractTetsFromModel(path);
}

void WriteMsh(const std::string& path, const TetMesh& mesh, MshFormat format) {
  if (format.version != 2.2 && format.version != 4.1) {
    ThrowFileError(path, fmt::format("unsupported .msh version {} (2.2 or 4.1)", format.version));
  }
  if (format.version == 2.2 && !format.binary) return internal::WriteMsh22Ascii(path, mesh);
  const std::vector<int32_t> tags = internal::GmshTags(path, mesh);
  // gmsh picks the format from the extension, so the temp file must end in .msh.
  CheckOutputPath(path, "mesh");  // the rename below would replace a device or a pipe
  const std::string tmp = path + ".tmp.msh";
  {
    GmshSession session;
    GmshCall(path, "write", [&] {
      gmsh::model::add("cutsim");
      std::vector<int32_t> regions(tags);
      std::sort(regions.begin(), regions.end());
      regions.erase(std::unique(regions.begin(), regions.end()), regions.end());
      for (const int32_t r : regions) gmsh::model::addDiscreteEntity(3, r);
      std::vector<std::size_t> node_tags(static_cast<size_t>(mesh.num_nodes()));
      std::vector<double> coords(3 * node_tags.size());
      for (int32_t i = 0; i < mesh.num_nodes(); ++i) {
        node_tags[static_cast<size_t>(i)] = static_cast<std::size_t>(i) + 1;
        for (int k = 0; k < 3; ++k) coords[3 * static_cast<size_t>(i) + static_cast<size_t>(k)] = mesh.nodes(i, k);
      }
      gmsh::model::mesh::addNodes(3, regions.front(), node_tags, coords);
      for (const int32_t r : regions) {
        std::vector<std::size_t> etags, enodes;
        for (int32_t t = 0; t < mesh.num_tets(); ++t) {
          if (tags[static_cast<size_t>(t)] != r) continue;
          etags.push_back(static_cast<std::size_t>(t) + 1);
          for (int k = 0; k < 4; ++k) enodes.push_back(static_cast<std::size_t>(mesh.tets(t, k)) + 1);
        }
        gmsh::model::mesh::addElementsByType(r, 4, etags, enodes);
        gmsh::model::addPhysicalGroup(3, {r}, r);
      }
      gmsh::option::setNumber("Mesh.MshFileVersion", format.version);
      gmsh::option::setNumber("Mesh.Binary", format.binary ? 1 : 0);
      gmsh::option::setNumber("Mesh.SaveAll", 0);
      gmsh::write(tmp);
    });
  }
  std::error_code ec;
  std::filesystem::rename(tmp, path, ec);
  if (ec) ThrowFileError(path, fmt::format("cannot rename {} into place: {}", tmp, ec.message()));
}

namespace {

// Fills the closed surface(s) already in the current model with tets.
TetMesh FillSurfaces(const std::string& source, double max_edge_length, const TetrahedralizeOptions& options) {
  if (!(max_edge_length > 0.0)) ThrowFileError(source, "max_edge_length must be positive");
  GmshCall(source, "tetrahedralization", [&] {
    gmsh::vectorpair surfaces;
    gmsh::model::getEntities(surfaces, 2);
    if (surfaces.empty()) ThrowFileError(source, "no surface triangles");
    std::vector<int> tags;
    for (const auto& dt : surfaces) tags.push_back(dt.second);
    // A volume bounded by the input surfaces: gmsh keeps the discrete surface
    // triangles (they have no parametrisation to remesh) and fills the inside.
    const int loop = gmsh::model::geo::addSurfaceLoop(tags);
    gmsh::model::geo::addVolume({loop});
    gmsh::model::geo::synchronize();
    gmsh::option::setNumber("Mesh.MeshSizeMax", max_edge_length);
    // Delaunay: deterministic run to run (HXT gives better minimum quality
    // but different meshes from run to run, which breaks reproducible scenes).
    gmsh::option::setNumber("Mesh.Algorithm3D", 1);
    gmsh::option::setNumber("Mesh.Optimize", 1);
    gmsh::option::setNumber("Mesh.OptimizeThreshold", options.gmsh_optimize_threshold);
    gmsh::model::mesh::generate(3);
  });
  TetMesh mesh = ExtractTetsFromModel(source);
  if (options.cleanup) {
    const CleanupReport r = CleanupMesh(mesh, options.cleanup_options);
    if (options.report != nullptr) *options.report = r;
    ValidateTetMesh(mesh, source);
  }
  return mesh;
}

std::vector<std::string> SplitWhitespace(const std::string& line) {
  std::vector<std::string> out;
  std::istringstream ss(line);
  for (std::string tok; ss >> tok;) out.push_back(tok);
  return out;
}

// Refuses a surface gmsh cannot fill: one that is not a closed, consistently
// oriented 2-manifold, or that has a triangle of no area. gmsh's Delaunay
// does not fail on such input but can search for minutes (a lone triangle
// with a repeated vertex did), so it must never see it.
void CheckFillable(const Positions& positions, const Triangles& tris, const std::string& source) {
  const ManifoldCheck manifold = CheckClosedManifold(tris);
  if (!manifold.ok) {
    ThrowFileError(source, fmt::format("the surface is not closed and consistently oriented: {} (triangles and "
                                       "vertices numbered from 0; weld duplicate vertices before export)",
                                       manifold.problem));
  }
  // Twice a triangle's area must exceed 1e-12 of the bounding box's squared
  // diagonal; the enclosed volume (divergence theorem: tets on a corner of
  // the box) 1e-9 of the box's. A closed surface folded flat bounds nothing.
  const Eigen::Vector3d lo = positions.colwise().minCoeff().transpose();
  const Eigen::Vector3d hi = positions.colwise().maxCoeff().transpose();
  const double min_twice_area = 1e-12 * (hi - lo).squaredNorm();
  double volume = 0.0;
  for (Eigen::Index f = 0; f < tris.rows(); ++f) {
    const Eigen::Vector3d a = positions.row(tris(f, 0)).transpose();
    const Eigen::Vector3d b = positions.row(tris(f, 1)).transpose();
    const Eigen::Vector3d c = positions.row(tris(f, 2)).transpose();
    if (!((b - a).cross(c - a).norm() > min_twice_area)) {
      ThrowFileError(source, fmt::format("triangle {} (numbered from 0) has no area: its corners are on one line", f));
    }
    volume += SignedVolume(lo, a, b, c);
  }
  if (!(std::abs(volume) > 1e-9 * (hi - lo).prod() && std::abs(volume) > 0.0)) {
    ThrowFileError(source, fmt::format("the surface encloses no volume ({} m³ in a {} × {} × {} m box)", volume,
                                       hi.x() - lo.x(), hi.y() - lo.y(), hi.z() - lo.z()));
  }
}

// The facets of an STL file with equal corners welded: what gmsh's merge
// builds, for CheckFillable. `xyz` holds 9 coordinates per facet.
void CheckStlFillable(const std::vector<double>& xyz, const std::string& path) {
  std::map<std::array<double, 3>, int32_t> index;
  std::vector<double> v;
  const auto facets = static_cast<Eigen::Index>(xyz.size() / 9);
  Triangles tris(facets, 3);
  for (Eigen::Index f = 0; f < facets; ++f) {
    for (int k = 0; k < 3; ++k) {
      const size_t at = 9 * static_cast<size_t>(f) + 3 * static_cast<size_t>(k);
      const std::array<double, 3> p{xyz[at], xyz[at + 1], xyz[at + 2]};
      const auto [it, added] = index.try_emplace(p, static_cast<int32_t>(v.size() / 3));
      if (added) v.insert(v.end(), p.begin(), p.end());
      tris(f, k) = it->second;
    }
  }
  const Positions positions = Eigen::Map<const Positions>(v.data(), static_cast<Eigen::Index>(v.size() / 3), 3);
  CheckFillable(positions, tris, path);
}

// Refuses what gmsh must never see: non-finite vertices (gmsh aborts on
// them) and binary files whose triangle count disagrees with their size.
// ASCII files are those starting with "solid" whose size is not that of a
// binary file of the count they would claim.
void CheckStl(const std::string& path, const std::string& text) {
  constexpr size_t kHeader = 80, kTriangle = 50;
  uint32_t count = 0;
  const bool sized_binary = text.size() >= kHeader + 4 &&
                            (std::memcpy(&count, text.data() + kHeader, 4), true) &&
                            text.size() == kHeader + 4 + kTriangle * static_cast<size_t>(count);
  std::vector<double> xyz;  // 9 per facet
  if (!sized_binary && text.compare(0, 5, "solid") == 0) {
    std::istringstream in(text);
    int64_t line_no = 0, vertices = 0;
    for (std::string line; std::getline(in, line);) {
      ++line_no;
      const auto tok = SplitWhitespace(line);
      if (tok.empty()) continue;
      // gmsh reads a "solid" file it cannot parse as ASCII as binary, with a
      // triangle count taken from bytes 80–83: only well-formed ASCII passes.
      static const std::set<std::string, std::less<>> kKeywords = {"solid", "facet", "outer", "vertex",
                                                                   "endloop", "endfacet", "endsolid"};
      if (!kKeywords.contains(tok[0])) {
        ThrowInputError(SourceRef{.file = path, .line = line_no},
                        fmt::format("'{}' is not an ASCII STL keyword (solid, facet, outer, vertex, ...)", tok[0]));
      }
      if (tok[0] != "vertex" && tok[0] != "facet") continue;
      const size_t first = tok[0] == "facet" ? 2 : 1;
      if (tok[0] == "vertex" && tok.size() != 4) {
        ThrowInputError(SourceRef{.file = path, .line = line_no}, "a vertex needs 3 coordinates");
      }
      if (tok[0] == "vertex" && ++vertices > 3 * kMaxMeshTets) {
        ThrowInputError(SourceRef{.file = path, .line = line_no}, fmt::format("more than {} facets", kMaxMeshTets));
      }
      for (size_t k = first; k < tok.size() && k < first + 3; ++k) {
        double x = 0.0;
        const auto [end, ec] = std::from_chars(tok[k].data(), tok[k].data() + tok[k].size(), x);
        if (ec != std::errc() || end != tok[k].data() + tok[k].size()) {
          ThrowInputError(SourceRef{.file = path, .line = line_no}, fmt::format("bad number '{}'", tok[k]));
        }
        if (tok[0] == "vertex") {
          RequireFinite(x, SourceRef{.file = path, .line = line_no}, "vertex coordinate");
          xyz.push_back(x);
        }
      }
    }
    if (vertices == 0 || vertices % 3 != 0) {
      ThrowFileError(path, fmt::format("{} vertices: an ASCII STL needs 3 per facet and at least one facet", vertices));
    }
    CheckStlFillable(xyz, path);
    return;
  }
  if (!sized_binary) {
    ThrowFileError(path, fmt::format("not an ASCII STL (no 'solid') and not a binary STL ({} bytes for {} triangles)",
                                     text.size(), count));
  }
  if (count > kMaxMeshTets) ThrowFileError(path, fmt::format("{} triangles: more than {}", count, kMaxMeshTets));
  for (size_t t = 0; t < count; ++t) {
    float corners[9];
    std::memcpy(corners, text.data() + kHeader + 4 + kTriangle * t + 12, sizeof(corners));  // after the normal
    for (const float x : corners) {
      RequireFinite(x, SourceRef{.file = path, .field = fmt::format("triangle {}", t + 1)}, "vertex coordinate");
      xyz.push_back(static_cast<double>(x));
    }
  }
  CheckStlFillable(xyz, path);
}

// Minimal Wavefront OBJ: 'v x y z' and polygonal 'f' lines (fan-triangulated).
void ReadObj(const std::string& path, Positions& positions, Triangles& tris) {
  std::istringstream in(ReadInputFile(path, "surface file"));
  std::vector<double> v;
  std::vector<int32_t> f;
  int64_t line_no = 0;
  for (std::string line; std::getline(in, line);) {
    ++line_no;
    const auto tok = SplitWhitespace(line);
    if (tok.empty()) continue;
    auto fail = [&](std::string_view msg) { ThrowInputError(SourceRef{.file = path, .line = line_no}, msg); };
    if (tok[0] == "v") {
      if (tok.size() < 4) fail("vertex needs 3 coordinates");
      for (int k = 1; k <= 3; ++k) {
        const std::string& t = tok[static_cast<size_t>(k)];
        double x = 0.0;
        const auto [end, ec] = std::from_chars(t.data(), t.data() + t.size(), x);
        if (ec != std::errc() || end != t.data() + t.size()) fail(fmt::format("bad coordinate '{}'", t));
        RequireFinite(x, SourceRef{.file = path, .line = line_no}, fmt::format("vertex coordinate '{}'", t));
        v.push_back(x);
      }
      if (static_cast<int64_t>(v.size() / 3) > kMaxMeshNodes) {
        fail(fmt::format("more than {} vertices", kMaxMeshNodes));
      }
    } else if (tok[0] == "f") {
      if (tok.size() < 4) fail("face needs at least 3 vertices");
      std::vector<int32_t> idx;
      for (size_t k = 1; k < tok.size(); ++k) {
        int64_t i = 0;
        try {
          i = std::stoll(tok[k].substr(0, tok[k].find('/')));
        } catch (const std::exception&) {
          fail(fmt::format("bad face index '{}'", tok[k]));
        }
        const auto nv = static_cast<int64_t>(v.size() / 3);
        if (i < 0) i += nv + 1;  // negative = relative to the end
        if (i < 1 || i > nv) fail(fmt::format("face index {} out of range", i));
        idx.push_back(static_cast<int32_t>(i - 1));
      }
      for (size_t k = 1; k + 1 < idx.size(); ++k) f.insert(f.end(), {idx[0], idx[k], idx[k + 1]});
      if (static_cast<int64_t>(f.size() / 3) > kMaxMeshTets) fail(fmt::format("more than {} faces", kMaxMeshTets));
    }
  }
  if (f.empty()) ThrowFileError(path, "no faces");
  positions = Eigen::Map<const Positions>(v.data(), static_cast<Eigen::Index>(v.size() / 3), 3);
  tris = Eigen::Map<const Triangles>(f.data(), static_cast<Eigen::Index>(f.size() / 3), 3);
}

}  // namespace

TetMesh TetrahedralizeSurface(const Positions& positions, const Triangles& tris, double max_edge_length,
                              const std::string& source_name) {
  return TetrahedralizeSurface(positions, tris, max_edge_length, source_name, TetrahedralizeOptions{});
}

TetMesh TetrahedralizeSurface(const Positions& positions, const Triangles& tris, double max_edge_length,
                              const std::string& source_name, const TetrahedralizeOptions& options) {
  CheckFillable(positions, tris, source_name);
  GmshSession session;
  GmshCall(source_name, "surface import", [&] {
    gmsh::model::add("surface");
    const int surf = gmsh::model::addDiscreteEntity(2);
    std::vector<std::size_t> node_tags(static_cast<size_t>(positions.rows()));
    std::vector<double> coords(3 * node_tags.size());
    for (Eigen::Index i = 0; i < positions.rows(); ++i) {
      node_tags[static_cast<size_t>(i)] = static_cast<std::size_t>(i) + 1;
      for (int k = 0; k < 3; ++k) coords[3 * static_cast<size_t>(i) + static_cast<size_t>(k)] = positions(i, k);
    }
    gmsh::model::mesh::addNodes(2, surf, node_tags, coords);
    std::vector<std::size_t> tri_nodes;
    tri_nodes.reserve(3 * static_cast<size_t>(tris.rows()));
    for (Eigen::Index f = 0; f < tris.rows(); ++f) {
      for (int k = 0; k < 3; ++k) tri_nodes.push_back(static_cast<std::size_t>(tris(f, k)) + 1);
    }
    gmsh::model::mesh::addElementsByType(surf, 2, {}, tri_nodes);  // type 2: 3-node triangle
  });
  return FillSurfaces(source_name, max_edge_length, options);
}

TetMesh TetrahedralizeSurface(const std::string& path, double max_edge_length) {
  return TetrahedralizeSurface(path, max_edge_length, TetrahedralizeOptions{});
}

TetMesh TetrahedralizeSurface(const std::string& path, double max_edge_length,
                              const TetrahedralizeOptions& options) {
  const std::string text = ReadInputFile(path, "surface file");
  std::string ext = std::filesystem::path(path).extension().string();
  std::transform(ext.begin(), ext.end(), ext.begin(), [](unsigned char c) { return static_cast<char>(std::tolower(c)); });
  if (ext == ".obj") {
    Positions positions;
    Triangles tris;
    ReadObj(path, positions, tris);
    return TetrahedralizeSurface(positions, tris, max_edge_length, path, options);
  }
  if (ext != ".stl") ThrowFileError(path, fmt::format("unsupported surface format '{}' (expected .stl or .obj)", ext));
  CheckStl(path, text);
  GmshSession session;
  GmshCall(path, "merge", [&] { gmsh::merge(path); });
  return FillSurfaces(path, max_edge_length, options);
}

}  // namespace cutsim::mesh
