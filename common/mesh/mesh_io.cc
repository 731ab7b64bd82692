#include "common/mesh/mesh_io.h"

#include <algorithm>
#include <charconv>
#include <cmath>
#include <filesystem>
#include <iterator>
#include <optional>

#include <fmt/format.h>
#include <fmt/ranges.h>

#include "common/core/error.h"
#include "common/core/finite.h"
#include "common/core/log.h"
#include "common/mesh/mesh_validation.h"
#include "common/mesh/text_io.h"

namespace cutsim::mesh {

namespace internal {

void FinishRead(TetMesh& mesh, const std::string& path, const MeshOrigin& origin) {
  if (const int64_t flipped = OrientTets(mesh); flipped > 0) {
    Log().debug("{}: flipped {} of {} tets to positive orientation", path, flipped, mesh.num_tets());
  }
  ValidateTetMesh(mesh, path, origin);
}

}  // namespace internal

using internal::Tokenizer;

namespace {

std::string Lower(std::string s) {
  std::transform(s.begin(), s.end(), s.begin(), [](unsigned char c) { return static_cast<char>(std::tolower(c)); });
  return s;
}

std::string Extension(const std::string& path) { return Lower(std::filesystem::path(path).extension().string()); }

// Throws unless every token of the current record stayed on its first line.
void EndRecord(Tokenizer& tk, int64_t record_line, std::string_view what) {
  if (tk.line() != record_line) {
    ThrowInputError(SourceRef{.file = tk.path(), .line = record_line}, fmt::format("{} has too few fields", what));
  }
}

}  // namespace

// ---------------------------------------------------------------- dispatch

TetMesh ReadMesh(const std::string& path) {
  const std::string ext = Extension(path);
  if (ext == ".msh") return ReadGmsh(path);
  if (ext == ".node" || ext == ".ele") return ReadTetGen(path);
  if (ext == ".mesh") return ReadMedit(path);
  if (ext == ".vtu") return ReadVtu(path).mesh;
  ThrowFileError(path, fmt::format("unknown mesh format '{}' (expected .msh, .node/.ele, .mesh or .vtu)",
                                   ext.empty() ? std::string("no extension") : ext));
}

// ---------------------------------------------------------------- TetGen

TetMesh ReadTetGen(const std::string& path) {
  std::string base = path;
  if (const std::string ext = Extension(path); ext == ".node" || ext == ".ele") {
    base = path.substr(0, path.size() - ext.size());
  }
  const std::string node_path = base + ".node", ele_path = base + ".ele";
  TetMesh mesh;
  MeshOrigin origin;
  int64_t first_node_id = 0;
  {
    Tokenizer tk(node_path, internal::ReadFileOrThrow(node_path), /*hash_comments=*/true);
    const int64_t n = tk.NextInt("node count");
    const int64_t header_line = tk.line();
    const int64_t dim = tk.NextInt("dimension");
    const int64_t num_attr = tk.NextInt("attribute count");
    const int64_t num_markers = tk.NextInt("boundary marker flag");
    EndRecord(tk, header_line, "header");
    if (n <= 0) tk.Fail(fmt::format("node count {} must be positive", n));
    if (dim != 3) tk.Fail(fmt::format("dimension {} is not 3", dim));
    if (num_attr < 0 || num_markers < 0 || num_markers > 1 || num_attr > 1000) {
      tk.Fail("bad attribute/marker counts in header");
    }
    tk.RequireCountFits(n, 2 * (4 + num_attr + num_markers), "node count");
    CheckMeshSize(n, 0, node_path);
    mesh.nodes.resize(n, 3);
    origin.node_ids.resize(static_cast<size_t>(n));
    for (int64_t i = 0; i < n; ++i) {
      const int64_t id = tk.NextInt("node id");
      const int64_t line = tk.line();
      if (i == 0) {
        first_node_id = id;
      } else if (id != first_node_id + i) {
        tk.Fail(fmt::format("node id {} out of sequence (expected {})", id, first_node_id + i));
      }
      origin.node_ids[static_cast<size_t>(i)] = id;
      for (int k = 0; k < 3; ++k) mesh.nodes(i, k) = tk.NextDouble(fmt::format("node {} coordinate", id));
      for (int64_t a = 0; a < num_attr + num_markers; ++a) tk.Next("node attribute");
      EndRecord(tk, line, fmt::format("node {}", id));
      if (!mesh.nodes.row(i).allFinite()) tk.Fail(fmt::format("node {}: coordinate is NaN or infinite", id));
    }
  }
  {
    Tokenizer tk(ele_path, internal::ReadFileOrThrow(ele_path), /*hash_comments=*/true);
    const int64_t t = tk.NextInt("tetrahedron count");
    const int64_t header_line = tk.line();
    const int64_t nodes_per = tk.NextInt("nodes per tetrahedron");
    const int64_t num_attr = tk.NextInt("attribute count");
    EndRecord(tk, header_line, "header");
    if (t <= 0) tk.Fail(fmt::format("tetrahedron count {} must be positive", t));
    if (nodes_per != 4) tk.Fail(fmt::format("{}-node elements are not supported (only 4-node tetrahedra)", nodes_per));
    if (num_attr < 0 || num_attr > 1000) tk.Fail("bad attribute count in header");
    tk.RequireCountFits(t, 2 * (5 + num_attr), "tetrahedron count");
    CheckMeshSize(0, t, ele_path);
    mesh.tets.resize(t, 4);
    if (num_attr > 0) mesh.regions.resize(static_cast<size_t>(t));
    origin.tet_ids.resize(static_cast<size_t>(t));
    origin.tet_lines.resize(static_cast<size_t>(t));
    for (int64_t e = 0; e < t; ++e) {
      const int64_t id = tk.NextInt("element id");
      const int64_t line = tk.line();
      origin.tet_ids[static_cast<size_t>(e)] = id;
      origin.tet_lines[static_cast<size_t>(e)] = line;
      for (int k = 0; k < 4; ++k) {
        const int64_t node = tk.NextInt(fmt::format("element {} node", id));
        const int64_t index = node - first_node_id;
        if (index < 0 || index >= mesh.nodes.rows()) {
          tk.Fail(fmt::format("element {}: node {} does not exist in {}", id, node, node_path));
        }
        mesh.tets(e, k) = static_cast<int32_t>(index);
      }
      for (int64_t a = 0; a < num_attr; ++a) {
        const double attr = tk.NextDouble(fmt::format("element {} attribute", id));
        if (a == 0) {
          if (!(std::abs(attr) < 2e9)) tk.Fail(fmt::format("element {}: region attribute {} is out of range", id, attr));
          mesh.regions[static_cast<size_t>(e)] = static_cast<int32_t>(std::lround(attr));
        }
      }
      EndRecord(tk, line, fmt::format("element {}", id));
    }
  }
  internal::FinishRead(mesh, ele_path, origin);
  return mesh;
}

void WriteTetGen(const std::string& base_path, const TetMesh& mesh) {
  fmt::memory_buffer node, ele;
  fmt::format_to(std::back_inserter(node), "{} 3 0 0\n", mesh.num_nodes());
  for (int32_t i = 0; i < mesh.num_nodes(); ++i) {
    fmt::format_to(std::back_inserter(node), "{} {} {} {}\n", i + 1, mesh.nodes(i, 0), mesh.nodes(i, 1), mesh.nodes(i, 2));
  }
  const bool regions = !mesh.regions.empty();
  fmt::format_to(std::back_inserter(ele), "{} 4 {}\n", mesh.num_tets(), regions ? 1 : 0);
  for (int32_t t = 0; t < mesh.num_tets(); ++t) {
    fmt::format_to(std::back_inserter(ele), "{} {} {} {} {}", t + 1, mesh.tets(t, 0) + 1, mesh.tets(t, 1) + 1,
                   mesh.tets(t, 2) + 1, mesh.tets(t, 3) + 1);
    if (regions) fmt::format_to(std::back_inserter(ele), " {}", mesh.regions[static_cast<size_t>(t)]);
    ele.push_back('\n');
  }
  internal::WriteFileAtomically(base_path + ".node", std::string_view(node.data(), node.size()));
  internal::WriteFileAtomically(base_path + ".ele", std::string_view(ele.data(), ele.size()));
}

// ---------------------------------------------------------------- Medit

TetMesh ReadMedit(const std::string& path) {
  Tokenizer tk(path, internal::ReadFileOrThrow(path), /*hash_comments=*/true);
  // Sections we skip: keyword → numbers per entry.
  static const std::pair<const char*, int> kSkip[] = {
      {"edges", 3},     {"triangles", 4}, {"quadrilaterals", 5}, {"hexahedra", 9},  {"prisms", 7},
      {"pyramids", 6},  {"corners", 1},   {"requiredvertices", 1}, {"ridges", 1},   {"requirededges", 1},
      {"requiredtriangles", 1}, {"normals", 3}, {"tangents", 3}, {"normalatvertices", 2},
      {"tangentatvertices", 2}, {"identifier", 0}};
  TetMesh mesh;
  MeshOrigin origin;
  bool have_vertices = false, have_tets = false, ended = false;
  int64_t dimension = 3;
  std::vector<std::string> other_elements;
  while (tk.HasNext()) {
    const std::string key = Lower(std::string(tk.Next("keyword")));
    if (key == "end") {
      ended = true;
      break;
    }
    if (key == "meshversionformatted") {
      const int64_t v = tk.NextInt("version");
      if (v < 1 || v > 3) tk.Fail(fmt::format("unsupported MeshVersionFormatted {}", v));
    } else if (key == "dimension") {
      dimension = tk.NextInt("dimension");
      if (dimension != 3) tk.Fail(fmt::format("dimension {} is not 3", dimension));
    } else if (key == "vertices") {
      const int64_t n = tk.NextInt("vertex count");
      if (n <= 0) tk.Fail("vertex count must be positive");
      tk.RequireCountFits(n, 8, "vertex count");
      CheckMeshSize(n, 0, path);
      mesh.nodes.resize(n, 3);
      for (int64_t i = 0; i < n; ++i) {
        for (int k = 0; k < 3; ++k) mesh.nodes(i, k) = tk.NextDouble(fmt::format("vertex {} coordinate", i + 1));
        const int64_t line = tk.line();
        tk.NextInt(fmt::format("vertex {} reference", i + 1));
        if (!mesh.nodes.row(i).allFinite()) {
          ThrowInputError(SourceRef{.file = path, .line = line},
                          fmt::format("vertex {}: coordinate is NaN or infinite", i + 1));
        }
      }
      have_vertices = true;
    } else if (key == "tetrahedra") {
      const int64_t t = tk.NextInt("tetrahedron count");
      if (t <= 0) tk.Fail("tetrahedron count must be positive");
      tk.RequireCountFits(t, 10, "tetrahedron count");
      CheckMeshSize(0, t, path);
      mesh.tets.resize(t, 4);
      mesh.regions.resize(static_cast<size_t>(t));
      origin.tet_lines.resize(static_cast<size_t>(t));
      for (int64_t e = 0; e < t; ++e) {
        for (int k = 0; k < 4; ++k) {
          const int64_t v = tk.NextInt(fmt::format("tetrahedron {} vertex", e + 1));
          if (k == 0) origin.tet_lines[static_cast<size_t>(e)] = tk.line();
          if (v < 1 || (have_vertices && v > mesh.nodes.rows())) {
            tk.Fail(fmt::format("tetrahedron {}: vertex {} does not exist", e + 1, v));
          }
          mesh.tets(e, k) = static_cast<int32_t>(v - 1);
        }
        const int64_t ref = tk.NextInt(fmt::format("tetrahedron {} reference", e + 1));
        if (ref < INT32_MIN || ref > INT32_MAX) tk.Fail(fmt::format("tetrahedron {}: reference {} is out of range", e + 1, ref));
        mesh.regions[static_cast<size_t>(e)] = static_cast<int32_t>(ref);
      }
      have_tets = true;
    } else {
      const auto* skip = std::find_if(std::begin(kSkip), std::end(kSkip),
                                      [&](const auto& s) { return key == s.first; });
      if (skip == std::end(kSkip)) tk.Fail(fmt::format("unsupported Medit keyword '{}'", key));
      if (skip->second == 0) {
        tk.SkipLine();
        continue;
      }
      const int64_t n = tk.NextInt(fmt::format("{} count", key));
      tk.RequireCountFits(n, 2 * std::max(skip->second, 1), fmt::format("{} count", key));
      for (int64_t i = 0; i < n * skip->second; ++i) tk.Next(key);
      if (n > 0 && key != "corners" && key.find("required") == std::string::npos && key.find("normal") == std::string::npos &&
          key.find("tangent") == std::string::npos && key != "ridges") {
        other_elements.push_back(key);
      }
    }
  }
  if (!ended) Log().debug("{}: no End keyword", path);
  if (!have_tets) {
    ThrowFileError(path, other_elements.empty()
                             ? "no Tetrahedra section"
                             : fmt::format("no tetrahedra (only {})", fmt::join(other_elements, ", ")));
  }
  if (!have_vertices) ThrowFileError(path, "no Vertices section");
  for (int64_t e = 0; e < mesh.tets.rows(); ++e) {
    if (mesh.tets.row(e).maxCoeff() >= mesh.nodes.rows()) {
      ThrowInputError(SourceRef{.file = path, .line = origin.tet_lines[static_cast<size_t>(e)]},
                      fmt::format("tetrahedron {}: vertex {} does not exist", e + 1, mesh.tets.row(e).maxCoeff() + 1));
    }
  }
  internal::FinishRead(mesh, path, origin);
  return mesh;
}

void WriteMedit(const std::string& path, const TetMesh& mesh) {
  fmt::memory_buffer b;
  auto out = std::back_inserter(b);
  fmt::format_to(out, "MeshVersionFormatted 2\nDimension 3\nVertices\n{}\n", mesh.num_nodes());
  for (int32_t i = 0; i < mesh.num_nodes(); ++i) {
    fmt::format_to(out, "{} {} {} 0\n", mesh.nodes(i, 0), mesh.nodes(i, 1), mesh.nodes(i, 2));
  }
  fmt::format_to(out, "Tetrahedra\n{}\n", mesh.num_tets());
  for (int32_t t = 0; t < mesh.num_tets(); ++t) {
    fmt::format_to(out, "{} {} {} {} {}\n", mesh.tets(t, 0) + 1, mesh.tets(t, 1) + 1, mesh.tets(t, 2) + 1,
                   mesh.tets(t, 3) + 1, mesh.regions.empty() ? 0 : mesh.regions[static_cast<size_t>(t)]);
  }
  fmt::format_to(out, "End\n");
  internal::WriteFileAtomically(path, std::string_view(b.data(), b.size()));
}

// ---------------------------------------------------------------- VTK

namespace {

void CheckFields(std::span<const VtkField> fields, Eigen::Index rows, const char* kind) {
  for (const auto& f : fields) {
    CUTSIM_CHECK(f.components >= 1 && f.values.size() == static_cast<size_t>(rows) * static_cast<size_t>(f.components),
                 fmt::format("{} field '{}' has {} values, expected {}×{}", kind, f.name, f.values.size(), rows,
                             f.components));
    CUTSIM_CHECK(!f.name.empty() && f.name.find_first_of("\"<>& \t\n") == std::string::npos,
                 fmt::format("VTK field name '{}' must be non-empty without spaces or XML specials", f.name));
  }
}

void AppendDataArray(fmt::memory_buffer& b, const VtkField& f) {
  auto out = std::back_inserter(b);
  fmt::format_to(out, "        <DataArray type=\"Float64\" Name=\"{}\" NumberOfComponents=\"{}\" format=\"ascii\">\n",
                 f.name, f.components);
  for (size_t i = 0; i < f.values.size(); ++i) {
    fmt::format_to(out, "{}{}", f.values[i], (i + 1) % static_cast<size_t>(f.components) == 0 ? '\n' : ' ');
  }
  fmt::format_to(out, "        </DataArray>\n");
}

std::optional<std::string> Attribute(std::string_view tag, std::string_view name) {
  const std::string needle = fmt::format(" {}=\"", name);
  const size_t at = tag.find(needle);
  if (at == std::string_view::npos) return std::nullopt;
  const size_t begin = at + needle.size();
  const size_t end = tag.find('"', begin);
  if (end == std::string_view::npos) return std::nullopt;
  return std::string(tag.substr(begin, end - begin));
}

}  // namespace

void WriteVtu(const std::string& path, const Positions& positions, const Tets& tets,
              std::span<const VtkField> point_fields, std::span<const VtkField> cell_fields) {
  CheckFields(point_fields, positions.rows(), "point");
  CheckFields(cell_fields, tets.rows(), "cell");
  fmt::memory_buffer b;
  auto out = std::back_inserter(b);
  fmt::format_to(out,
                 "<?xml version=\"1.0\"?>\n"
                 "<VTKFile type=\"UnstructuredGrid\" version=\"1.0\" byte_order=\"LittleEndian\" "
                 "header_type=\"UInt64\">\n  <UnstructuredGrid>\n"
                 "    <Piece NumberOfPoints=\"{}\" NumberOfCells=\"{}\">\n",
                 positions.rows(), tets.rows());
  fmt::format_to(out, "      <PointData>\n");
  for (const auto& f : point_fields) AppendDataArray(b, f);
  fmt::format_to(out, "      </PointData>\n      <CellData>\n");
  for (const auto& f : cell_fields) AppendDataArray(b, f);
  fmt::format_to(out, "      </CellData>\n      <Points>\n"
                      "        <DataArray type=\"Float64\" NumberOfComponents=\"3\" format=\"ascii\">\n");
  for (Eigen::Index i = 0; i < positions.rows(); ++i) {
    fmt::format_to(out, "{} {} {}\n", positions(i, 0), positions(i, 1), positions(i, 2));
  }
  fmt::format_to(out, "        </DataArray>\n      </Points>\n      <Cells>\n"
                      "        <DataArray type=\"Int32\" Name=\"connectivity\" format=\"ascii\">\n");
  for (Eigen::Index t = 0; t < tets.rows(); ++t) {
    fmt::format_to(out, "{} {} {} {}\n", tets(t, 0), tets(t, 1), tets(t, 2), tets(t, 3));
  }
  fmt::format_to(out, "        </DataArray>\n        <DataArray type=\"Int64\" Name=\"offsets\" format=\"ascii\">\n");
  for (Eigen::Index t = 0; t < tets.rows(); ++t) fmt::format_to(out, "{}\n", 4 * (t + 1));
  fmt::format_to(out, "        </DataArray>\n        <DataArray type=\"UInt8\" Name=\"types\" format=\"ascii\">\n");
  for (Eigen::Index t = 0; t < tets.rows(); ++t) fmt::format_to(out, "10\n");  // VTK_TETRA
  fmt::format_to(out, "        </DataArray>\n      </Cells>\n    </Piece>\n  </UnstructuredGrid>\n</VTKFile>\n");
  internal::WriteFileAtomically(path, std::string_view(b.data(), b.size()));
}

void WriteVtu(const std::string& path, const TetMesh& mesh, std::span<const VtkField> point_fields,
              std::span<const VtkField> cell_fields) {
  if (mesh.regions.empty()) return WriteVtu(path, mesh.nodes, mesh.tets, point_fields, cell_fields);
  std::vector<VtkField> cells(cell_fields.begin(), cell_fields.end());
  cells.push_back({"region", 1, std::vector<double>(mesh.regions.begin(), mesh.regions.end())});
  WriteVtu(path, mesh.nodes, mesh.tets, point_fields, cells);
}

VtuData ReadVtu(const std::string& path) {
  const std::string text = internal::ReadFileOrThrow(path);
  auto line_at = [&](size_t pos) {
    return 1 + static_cast<int64_t>(std::count(text.begin(), text.begin() + static_cast<std::ptrdiff_t>(pos), '\n'));
  };
  auto fail_at = [&](size_t pos, std::string_view msg) -> void {
    ThrowInputError(SourceRef{.file = path, .line = line_at(pos)}, msg);
  };
  const size_t file_tag = text.find("<VTKFile");
  if (file_tag == std::string::npos || Attribute(text.substr(file_tag, text.find('>', file_tag) - file_tag), "type") !=
                                           std::optional<std::string>("UnstructuredGrid")) {
    ThrowFileError(path, "not a VTK XML UnstructuredGrid (.vtu) file");
  }
  if (text.find("</VTKFile>") == std::string::npos) ThrowFileError(path, "no closing </VTKFile> (truncated file?)");
  const size_t piece = text.find("<Piece");
  if (piece == std::string::npos) ThrowFileError(path, "no <Piece>");
  const std::string piece_tag = text.substr(piece, text.find('>', piece) - piece);
  int64_t num_points = -1, num_cells = -1;
  for (auto [name, value] : {std::pair{"NumberOfPoints", &num_points}, std::pair{"NumberOfCells", &num_cells}}) {
    const auto a = Attribute(piece_tag, name);
    if (!a || std::from_chars(a->data(), a->data() + a->size(), *value).ec != std::errc() || *value < 0) {
      fail_at(piece, fmt::format("<Piece> needs a valid {}", name));
    }
  }
  CheckMeshSize(num_points, num_cells, path);
  auto section = [&](const char* open, const char* close) {
    const size_t b = text.find(open, piece), e = text.find(close, piece);
    return std::pair{b, e == std::string::npos ? b : e};
  };
  const auto point_data = section("<PointData", "</PointData>");
  const auto cell_data = section("<CellData", "</CellData>");
  const auto points = section("<Points", "</Points>");
  const auto cells = section("<Cells", "</Cells>");
  auto inside = [](size_t pos, std::pair<size_t, size_t> s) {
    return s.first != std::string::npos && pos > s.first && pos < s.second;
  };
  VtuData data;
  std::vector<double> connectivity, offsets, types;
  bool have_points = false;
  for (size_t pos = text.find("<DataArray", piece); pos != std::string::npos; pos = text.find("<DataArray", pos + 1)) {
    const size_t tag_end = text.find('>', pos);
    if (tag_end == std::string::npos) fail_at(pos, "unterminated <DataArray> tag");
    const std::string tag = text.substr(pos, tag_end - pos);
    const size_t end = text.find("</DataArray>", tag_end);
    if (end == std::string::npos) fail_at(pos, "no </DataArray> (truncated file?)");
    if (Attribute(tag, "format").value_or("") != "ascii") {
      fail_at(pos, "only format=\"ascii\" data arrays are supported");
    }
    const std::string name = Attribute(tag, "Name").value_or("");
    int components = 1;
    if (const auto c = Attribute(tag, "NumberOfComponents")) {
      if (std::from_chars(c->data(), c->data() + c->size(), components).ec != std::errc() || components < 1 ||
          components > 64) {
        fail_at(pos, "bad NumberOfComponents");
      }
    }
    std::vector<double> values;
    const int64_t max_values = std::max<int64_t>(std::max(num_points, num_cells), 1) * std::max(components, 4);
    for (const char* p = text.data() + tag_end + 1; p < text.data() + end;) {
      while (p < text.data() + end && std::isspace(static_cast<unsigned char>(*p))) ++p;
      if (p >= text.data() + end) break;
      double v = 0.0;
      const auto [q, ec] = std::from_chars(p, text.data() + end, v);
      if (ec != std::errc()) fail_at(static_cast<size_t>(p - text.data()), fmt::format("bad number in array '{}'", name));
      if (static_cast<int64_t>(values.size()) >= max_values) {
        fail_at(pos, fmt::format("array '{}' has more values than the piece's counts allow", name));
      }
      values.push_back(v);
      p = q;
    }
    auto expect = [&](int64_t rows) {
      if (static_cast<int64_t>(values.size()) != rows * components) {
        fail_at(pos, fmt::format("array '{}' has {} values, expected {}×{}", name, values.size(), rows, components));
      }
    };
    if (inside(pos, points)) {
      if (components != 3) fail_at(pos, "points must have 3 components");
      expect(num_points);
      data.mesh.nodes = Eigen::Map<const Positions>(values.data(), num_points, 3);
      have_points = true;
    } else if (inside(pos, cells)) {
      if (name == "connectivity") connectivity = std::move(values);
      else if (name == "offsets") offsets = std::move(values);
      else if (name == "types") types = std::move(values);
    } else if (inside(pos, point_data)) {
      expect(num_points);
      data.point_fields.push_back({name, components, std::move(values)});
    } else if (inside(pos, cell_data)) {
      expect(num_cells);
      if (name == "region" && components == 1) {
        data.mesh.regions.resize(values.size());
        for (size_t c = 0; c < values.size(); ++c) {
          data.mesh.regions[c] = static_cast<int32_t>(
              RequireIndex(values[c], INT32_MIN, INT32_MAX,
                           SourceRef{.file = path, .line = line_at(pos), .field = fmt::format("region of cell {}", c + 1)},
                           "region"));
        }
      } else {
        data.cell_fields.push_back({name, components, std::move(values)});
      }
    }
  }
  if (!have_points) ThrowFileError(path, "no <Points> array");
  if (static_cast<int64_t>(types.size()) != num_cells || static_cast<int64_t>(offsets.size()) != num_cells) {
    ThrowFileError(path, "<Cells> needs connectivity, offsets and types with NumberOfCells entries");
  }
  data.mesh.tets.resize(num_cells, 4);
  for (int64_t c = 0; c < num_cells; ++c) {
    if (types[static_cast<size_t>(c)] != 10.0) {
      ThrowInputError(SourceRef{.file = path, .field = fmt::format("cell {}", c + 1)},
                      fmt::format("VTK cell type {} is not a tetrahedron (10)", types[static_cast<size_t>(c)]));
    }
    if (offsets[static_cast<size_t>(c)] != 4.0 * static_cast<double>(c + 1) ||
        connectivity.size() < static_cast<size_t>(4 * (c + 1))) {
      ThrowInputError(SourceRef{.file = path, .field = fmt::format("cell {}", c + 1)}, "bad offsets/connectivity");
    }
    for (int k = 0; k < 4; ++k) {
      data.mesh.tets(c, k) = static_cast<int32_t>(
          RequireIndex(connectivity[static_cast<size_t>(4 * c + k)], 0, num_points - 1,
                       SourceRef{.file = path, .field = fmt::format("cell {}", c + 1)}, "node index"));
    }
  }
  internal::FinishRead(data.mesh, path, {});
  return data;
}

void WriteVtk(const std::string& path, const Positions& positions, const Tets& tets,
              std::span<const VtkField> point_fields, std::span<const VtkField> cell_fields) {
  CheckFields(point_fields, positions.rows(), "point");
  CheckFields(cell_fields, tets.rows(), "cell");
  fmt::memory_buffer b;
  auto out = std::back_inserter(b);
  fmt::format_to(out, "# vtk DataFile Version 3.0\ncutsim\nASCII\nDATASET UNSTRUCTURED_GRID\nPOINTS {} double\n",
                 positions.rows());
  for (Eigen::Index i = 0; i < positions.rows(); ++i) {
    fmt::format_to(out, "{} {} {}\n", positions(i, 0), positions(i, 1), positions(i, 2));
  }
  fmt::format_to(out, "CELLS {} {}\n", tets.rows(), 5 * tets.rows());
  for (Eigen::Index t = 0; t < tets.rows(); ++t) {
    fmt::format_to(out, "4 {} {} {} {}\n", tets(t, 0), tets(t, 1), tets(t, 2), tets(t, 3));
  }
  fmt::format_to(out, "CELL_TYPES {}\n", tets.rows());
  for (Eigen::Index t = 0; t < tets.rows(); ++t) fmt::format_to(out, "10\n");
  auto write_block = [&](const char* kind, Eigen::Index rows, std::span<const VtkField> fields) {
    if (fields.empty()) return;
    fmt::format_to(out, "{} {}\n", kind, rows);
    std::vector<const VtkField*> other;
    for (const auto& f : fields) {
      if (f.components == 1) {
        fmt::format_to(out, "SCALARS {} double 1\nLOOKUP_TABLE default\n", f.name);
      } else if (f.components == 3) {
        fmt::format_to(out, "VECTORS {} double\n", f.name);
      } else {
        other.push_back(&f);
        continue;
      }
      for (size_t i = 0; i < f.values.size(); ++i) {
        fmt::format_to(out, "{}{}", f.values[i], (i + 1) % static_cast<size_t>(f.components) == 0 ? '\n' : ' ');
      }
    }
    if (other.empty()) return;
    fmt::format_to(out, "FIELD FieldData {}\n", other.size());
    for (const auto* f : other) {
      fmt::format_to(out, "{} {} {} double\n", f->name, f->components, rows);
      for (size_t i = 0; i < f->values.size(); ++i) {
        fmt::format_to(out, "{}{}", f->values[i], (i + 1) % static_cast<size_t>(f->components) == 0 ? '\n' : ' ');
      }
    }
  };
  write_block("POINT_DATA", positions.rows(), point_fields);
  write_block("CELL_DATA", tets.rows(), cell_fields);
  internal::WriteFileAtomically(path, std::string_view(b.data(), b.size()));
}

// ---------------------------------------------------------------- STL, msh 2.2

void WriteStl(const std::string& path, const Positions& positions, const Triangles& tris) {
  fmt::memory_buffer b;
  auto out = std::back_inserter(b);
  fmt::format_to(out, "solid cutsim\n");
  for (Eigen::Index f = 0; f < tris.rows(); ++f) {
    const Eigen::Vector3d p0 = positions.row(tris(f, 0)), p1 = positions.row(tris(f, 1)), p2 = positions.row(tris(f, 2));
    const Eigen::Vector3d n = (p1 - p0).cross(p2 - p0).normalized();
    fmt::format_to(out, " facet normal {} {} {}\n  outer loop\n", n.x(), n.y(), n.z());
    for (const auto* p : {&p0, &p1, &p2}) fmt::format_to(out, "   vertex {} {} {}\n", p->x(), p->y(), p->z());
    fmt::format_to(out, "  endloop\n endfacet\n");
  }
  fmt::format_to(out, "endsolid cutsim\n");
  internal::WriteFileAtomically(path, std::string_view(b.data(), b.size()));
}

namespace internal {

std::vector<int32_t> GmshTags(const std::string& path, const TetMesh& mesh) {
  std::vector<int32_t> tags = mesh.regions.empty() ? std::vector<int32_t>(static_cast<size_t>(mesh.num_tets()), 1)
                                                   : mesh.regions;
  for (size_t t = 0; t < tags.size(); ++t) {
    if (tags[t] <= 0) {
      ThrowInputError(SourceRef{.file = path, .field = fmt::format("element {}", t + 1)},
                      fmt::format("region {} cannot be a gmsh tag (must be positive)", tags[t]));
    }
  }
  return tags;
}

void WriteMsh22Ascii(const std::string& path, const TetMesh& mesh) {
  const std::vector<int32_t> tags = GmshTags(path, mesh);
  fmt::memory_buffer b;
  auto out = std::back_inserter(b);
  fmt::format_to(out, "$MeshFormat\n2.2 0 8\n$EndMeshFormat\n$Nodes\n{}\n", mesh.num_nodes());
  for (int32_t i = 0; i < mesh.num_nodes(); ++i) {
    fmt::format_to(out, "{} {} {} {}\n", i + 1, mesh.nodes(i, 0), mesh.nodes(i, 1), mesh.nodes(i, 2));
  }
  fmt::format_to(out, "$EndNodes\n$Elements\n{}\n", mesh.num_tets());
  for (int32_t t = 0; t < mesh.num_tets(); ++t) {
    const int32_t tag = tags[static_cast<size_t>(t)];
    // id, type 4 (tet4), 2 tags: physical, elementary, then nodes.
    fmt::format_to(out, "{} 4 2 {} {} {} {} {} {}\n", t + 1, tag, tag, mesh.tets(t, 0) + 1, mesh.tets(t, 1) + 1,
                   mesh.tets(t, 2) + 1, mesh.tets(t, 3) + 1);
  }
  fmt::format_to(out, "$EndElements\n");
  WriteFileAtomically(path, std::string_view(b.data(), b.size()));
}

}  // namespace internal

}  // namespace cutsim::mesh
