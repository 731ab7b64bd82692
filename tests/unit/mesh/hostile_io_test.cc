// Hostile mesh and surface files: every reader checks indices before use,
// counts against the bytes present, values for finiteness and sizes against
// the caps, and names the file and element.

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <string>

#include <fmt/format.h>
#include <gtest/gtest.h>

#include "common/core/error.h"
#include "common/mesh/generators.h"
#include "common/mesh/mesh_io.h"
#include "common/mesh/mesh_validation.h"
#include "tests/unit/mesh/test_util.h"

namespace cutsim::mesh {
namespace {

using testing::TempDir;

void WriteBytes(const std::string& path, const std::string& text) { std::ofstream(path, std::ios::binary) << text; }

template <typename Fn>
std::string ErrorOf(Fn&& fn) {
  try {
    fn();
  } catch (const InputError& e) {
    return e.what();
  }
  return "";
}

/// A one-tet .vtu whose connectivity is `conn`.
std::string OneTetVtu(const std::string& conn) {
  return fmt::format(
      "<VTKFile type=\"UnstructuredGrid\" version=\"1.0\">\n<UnstructuredGrid>\n"
      "<Piece NumberOfPoints=\"4\" NumberOfCells=\"1\">\n<Points>\n"
      "<DataArray type=\"Float64\" NumberOfComponents=\"3\" format=\"ascii\">0 0 0 1 0 0 0 1 0 0 0 1</DataArray>\n"
      "</Points>\n<Cells>\n"
      "<DataArray type=\"Int32\" Name=\"connectivity\" format=\"ascii\">{}</DataArray>\n"
      "<DataArray type=\"Int64\" Name=\"offsets\" format=\"ascii\">4</DataArray>\n"
      "<DataArray type=\"UInt8\" Name=\"types\" format=\"ascii\">10</DataArray>\n"
      "</Cells>\n</Piece>\n</UnstructuredGrid>\n</VTKFile>\n",
      conn);
}

TEST(HostileMesh, VtuConnectivityIsCheckedBeforeTheTetsAreOriented) {
  TempDir dir;
  const std::string path = dir.File("t.vtu");
  WriteBytes(path, OneTetVtu("0 1 2 3"));
  EXPECT_EQ(ReadVtu(path).mesh.num_tets(), 1);
  for (const char* conn : {"0 1 2 4", "0 1 2 -1", "0 1 2 nan", "0 1 2 1e20", "0 1 2 -1e20", "0 1 2 2.5",
                           "0 1 2 2147483648", "0 1 2 inf"}) {
    WriteBytes(path, OneTetVtu(conn));
    const std::string what = ErrorOf([&] { (void)ReadVtu(path); });
    EXPECT_NE(what.find("cell 1"), std::string::npos) << conn << ": " << what;
    EXPECT_NE(what.find("node index"), std::string::npos) << conn << ": " << what;
  }
}

TEST(HostileMesh, VtuHeaderCountsAreCapped) {
  TempDir dir;
  const std::string path = dir.File("t.vtu");
  std::string text = OneTetVtu("0 1 2 3");
  text.replace(text.find("NumberOfPoints=\"4\""), 18, "NumberOfPoints=\"100000000000\"");
  WriteBytes(path, text);
  EXPECT_NE(ErrorOf([&] { (void)ReadVtu(path); }).find("limited to"), std::string::npos);
}

TEST(HostileMesh, TetGenCountsAreCheckedAgainstTheFileSize) {
  TempDir dir;
  // 20 bytes claiming 10^8 nodes: refused before any allocation.
  WriteBytes(dir.File("m.node"), "100000000 3 0 0\n1 0");
  WriteBytes(dir.File("m.ele"), "1 4 0\n1 1 2 3 4\n");
  const std::string what = ErrorOf([&] { (void)ReadTetGen(dir.File("m.node")); });
  EXPECT_NE(what.find("m.node:1"), std::string::npos) << what;
  EXPECT_NE(what.find("cannot fit"), std::string::npos) << what;
  WriteBytes(dir.File("m.node"), "4 3 0 0\n1 0 0 0\n2 1 0 0\n3 0 1 0\n4 0 0 1\n");
  WriteBytes(dir.File("m.ele"), "2000000000 4 0\n1 1 2 3 4\n");
  EXPECT_NE(ErrorOf([&] { (void)ReadTetGen(dir.File("m.node")); }).find("m.ele:1"), std::string::npos);
}

TEST(HostileMesh, MeditCountsAreCheckedAgainstTheFileSize) {
  TempDir dir;
  const std::string path = dir.File("m.mesh");
  WriteBytes(path, "MeshVersionFormatted 2\nDimension 3\nVertices\n100000000\n0 0 0 1\n");
  EXPECT_NE(ErrorOf([&] { (void)ReadMedit(path); }).find("cannot fit"), std::string::npos);
  // A skipped section whose count times its width overflows.
  WriteBytes(path, "MeshVersionFormatted 2\nDimension 3\nTriangles\n4611686018427387904\n");
  EXPECT_NE(ErrorOf([&] { (void)ReadMedit(path); }).find("cannot fit"), std::string::npos);
}

// Found by the mesh fuzzer: libgmsh dereferences an element's node that the
// file never defines and crashes. The node references are checked first.
TEST(HostileMesh, MshElementNamingAnUndefinedNodeIsRefusedBeforeGmsh) {
  TempDir dir;
  const std::string path = dir.File("u.msh");
  WriteBytes(path,
            "$MeshFormat\n2.2 0 8\n$EndMeshFormat\n$Nodes\n3\n1 0 0 0\n2 1 0 0\n3 0 1 0\n$EndNodes\n"
            "$Elements\n1\n1 4 2 1 1 1 2 3 4\n$EndElements\n");
  const std::string what = ErrorOf([&] { (void)ReadGmsh(path); });
  EXPECT_NE(what.find("u.msh:12"), std::string::npos) << what;
  EXPECT_NE(what.find("node 4"), std::string::npos) << what;
  // The node count disagreeing with the lines (the fuzzer's input).
  WriteBytes(path,
            "$MeshFormat\n2.2 0 8\n$EndMeshFormat\n$Nodes\n3\n1 0 0 0\n2 1 0 0\n3 0 1 0\n4 1 00\n$EndNodes\n"
            "$Elements\n1\n1 4 2 1 1 1 2 3 4\n$EndElements\n");
  EXPECT_NE(ErrorOf([&] { (void)ReadGmsh(path); }).find("$EndNodes"), std::string::npos);
  // A version cutsim does not check (gmsh reads 1.2 as 2.x and crashed on
  // this file): refused, naming the version.
  WriteBytes(path,
            "$MeshFormat\n1.2 0 8\n$EndMeshFormat\n$Nodes\n3\n1 0 0 0\n2 1 0 0\n3 0 1 0\n$EndNodes\n"
            "$Elements\n1\n1 4 2 1 1 1 2 3 4\n$EndElements\n");
  const std::string version = ErrorOf([&] { (void)ReadGmsh(path); });
  EXPECT_NE(version.find("u.msh"), std::string::npos) << version;
  EXPECT_NE(version.find("1.2"), std::string::npos) << version;
}

/// Bytes of `path`.
std::string ReadBytes(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  return {std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
}

/// `bytes` with the little-endian `value` of `size` bytes written at `at`.
std::string Patched(std::string bytes, size_t at, uint64_t value, size_t size) {
  for (size_t i = 0; i < size; ++i) bytes[at + i] = static_cast<char>((value >> (8 * i)) & 0xff);
  return bytes;
}

// Versions 4.1 (ASCII and binary) and 2.2 binary pass the same check as 2.2
// ASCII before libgmsh sees them: a file gmsh writes reads back, and the
// same file naming an undefined node, claiming more data than it holds,
// holding a NaN, or using a format cutsim does not check is refused naming
// the file and line or byte offset.
TEST(HostileMesh, Msh41AndBinaryFilesAreCheckedBeforeGmsh) {
  TempDir dir;
  const TetMesh box = MakeBox(Eigen::Vector3d::Zero(), Eigen::Vector3d::Ones(), 2, 2, 2);
  const std::string a41 = dir.File("a41.msh"), b41 = dir.File("b41.msh"), b22 = dir.File("b22.msh");
  WriteMsh(a41, box, {4.1, false});
  WriteMsh(b41, box, {4.1, true});
  WriteMsh(b22, box, {2.2, true});
  for (const std::string& p : {a41, b41, b22}) EXPECT_EQ(ReadGmsh(p).num_tets(), box.num_tets()) << p;
  const std::string t41 = ReadBytes(a41), u41 = ReadBytes(b41), u22 = ReadBytes(b22);
  const std::string bad = dir.File("bad.msh");
  auto error_for = [&](const std::string& bytes) {
    WriteBytes(bad, bytes);
    return ErrorOf([&] { (void)ReadGmsh(bad); });
  };

  // 4.1 ASCII: the last element's last node undefined, on its line.
  {
    std::string t = t41;
    const size_t end = t.find("$EndElements");
    const size_t line_start = t.rfind('\n', end - 2) + 1;
    const size_t last = t.find_last_not_of(" \n", end - 1);
    const size_t tok = t.find_last_of(' ', last) + 1;
    t.replace(tok, last + 1 - tok, "999999");
    const std::string what = error_for(t);
    const int64_t line = 1 + std::count(t.begin(), t.begin() + static_cast<std::ptrdiff_t>(line_start), '\n');
    EXPECT_NE(what.find(fmt::format("bad.msh:{}", line)), std::string::npos) << what;
    EXPECT_NE(what.find("node 999999"), std::string::npos) << what;
  }
  // 4.1 ASCII: more nodes claimed than the blocks hold; a NaN coordinate.
  {
    std::string t = t41;
    const size_t nodes = t.find("$Nodes\n") + 7;
    const size_t sp = t.find(' ', nodes);
    t.replace(sp + 1, t.find(' ', sp + 1) - sp - 1, "100000");
    EXPECT_NE(error_for(t).find("node"), std::string::npos);
    std::string n = t41;
    const size_t coord = n.find("\n0 0 0\n", n.find("$Nodes")) + 1;
    n.replace(coord, 1, "nan");
    EXPECT_NE(error_for(n).find("NaN"), std::string::npos) << error_for(n);
  }
  // 4.1 binary: the last element's last node (8 bytes before "\n$EndElements").
  {
    const size_t at = u41.find("\n$EndElements") - 8;
    const std::string what = error_for(Patched(u41, at, 999999, 8));
    EXPECT_NE(what.find("node 999999"), std::string::npos) << what;
    EXPECT_NE(what.find(fmt::format("byte {}", at)), std::string::npos) << what;
    // A node count of 2^40: refused before anything is allocated.
    const size_t count = u41.find("$Nodes\n") + 7 + 8;
    EXPECT_NE(error_for(Patched(u41, count, uint64_t{1} << 40, 8)).find("exceed the limit"), std::string::npos);
    // Cut short anywhere: an error, never a crash.
    for (const size_t keep : {u41.size() / 3, u41.size() / 2, u41.size() - 20}) {
      EXPECT_NE(error_for(u41.substr(0, keep)), "") << keep;
    }
  }
  // 2.2 binary: the last element's last node (4 bytes before "\n$EndElements").
  {
    const size_t at = u22.find("\n$EndElements") - 4;
    const std::string what = error_for(Patched(u22, at, 999999, 4));
    EXPECT_NE(what.find("node 999999"), std::string::npos) << what;
    EXPECT_NE(what.find("byte"), std::string::npos) << what;
    EXPECT_NE(error_for(u22.substr(0, u22.size() / 2)), "");
  }
  // Formats and sections the check does not read are refused by name.
  const size_t one = u41.find("4.1 1 8\n") + 8;
  EXPECT_NE(error_for(Patched(u41, one, 0x01000000, 4)).find("big-endian"), std::string::npos);
  std::string v40 = t41;
  v40.replace(v40.find("4.1 0 8"), 7, "4 0 8");
  EXPECT_NE(error_for(v40).find("version 4:"), std::string::npos) << error_for(v40);
  EXPECT_NE(error_for(t41 + "$Periodic\n0\n$EndPeriodic\n").find("$Periodic"), std::string::npos);
  EXPECT_NE(error_for("$NOD\n1\n1 0 0 0\n$ENDNOD\n").find("$MeshFormat"), std::string::npos);
}

TEST(HostileMesh, NonRegularFilesAreRefusedByEveryReader) {
  TempDir dir;
  for (const std::string ext : {".msh", ".mesh", ".vtu", ".node"}) {
    const std::string p = dir.File("d" + ext);  // a directory named like a mesh
    std::filesystem::create_directories(p);
    const std::string what = ErrorOf([&] { (void)ReadMesh(p); });
    EXPECT_NE(what.find("only regular files"), std::string::npos) << p << ": " << what;
  }
  EXPECT_NE(ErrorOf([] { (void)ReadVtu("/dev/zero"); }).find("character device"), std::string::npos);
  EXPECT_NE(ErrorOf([] { (void)TetrahedralizeSurface("/dev/zero", 0.01); }).find("only regular files"),
            std::string::npos);
}

TEST(HostileSurface, ObjWithANanVertexIsRefusedBeforeGmsh) {
  TempDir dir;
  const std::string path = dir.File("s.obj");
  WriteBytes(path, "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 nan\nf 1 2 3\nf 1 2 4\nf 2 3 4\nf 1 3 4\n");
  const std::string what = ErrorOf([&] { (void)TetrahedralizeSurface(path, 0.1); });
  EXPECT_NE(what.find("s.obj:4"), std::string::npos) << what;
  EXPECT_NE(what.find("NaN or infinite"), std::string::npos) << what;
}

TEST(HostileSurface, StlWithANanVertexIsRefusedBeforeGmsh) {
  TempDir dir;
  const std::string ascii = dir.File("s.stl");
  WriteBytes(ascii,
            "solid x\n facet normal 0 0 1\n  outer loop\n   vertex 0 0 0\n   vertex 1 0 0\n   vertex 0 nan 0\n"
            "  endloop\n endfacet\nendsolid x\n");
  std::string what = ErrorOf([&] { (void)TetrahedralizeSurface(ascii, 0.1); });
  EXPECT_NE(what.find("s.stl:6"), std::string::npos) << what;
  // Binary: header, count 1, normal, three vertices (one NaN), attribute.
  std::string bin(80, ' ');
  const uint32_t count = 1;
  bin.append(reinterpret_cast<const char*>(&count), 4);
  float tri[12] = {0, 0, 1, 0, 0, 0, 1, 0, 0, 0, std::nanf(""), 0};
  bin.append(reinterpret_cast<const char*>(tri), sizeof(tri));
  bin.append(2, '\0');
  WriteBytes(dir.File("b.stl"), bin);
  what = ErrorOf([&] { (void)TetrahedralizeSurface(dir.File("b.stl"), 0.1); });
  EXPECT_NE(what.find("triangle 1"), std::string::npos) << what;
  // A binary file whose triangle count disagrees with its size.
  bin.resize(bin.size() - 10);
  WriteBytes(dir.File("c.stl"), bin);
  EXPECT_NE(ErrorOf([&] { (void)TetrahedralizeSurface(dir.File("c.stl"), 0.1); }).find("binary STL"),
            std::string::npos);
}

// Found by the surface fuzzer: gmsh reads a "solid" file it cannot parse as
// ASCII as binary, taking a triangle count from bytes 80–83, and allocates
// gigabytes. Only well-formed ASCII STL reaches gmsh.
TEST(HostileSurface, MalformedAsciiStlIsRefusedBeforeGmshReadsItAsBinary) {
  TempDir dir;
  const std::string path = dir.File("m.stl");
  WriteBytes(path, "solid t\n facet normal 0 0 0\n  o" + std::string(90, 'u') + "ter \nv l0 0");
  const std::string what = ErrorOf([&] { (void)TetrahedralizeSurface(path, 0.5); });
  EXPECT_NE(what.find("m.stl:3"), std::string::npos) << what;
  EXPECT_NE(what.find("not an ASCII STL keyword"), std::string::npos) << what;
  WriteBytes(path, "solid t\nendsolid t\n");
  EXPECT_NE(ErrorOf([&] { (void)TetrahedralizeSurface(path, 0.5); }).find("at least one facet"), std::string::npos);
}

/// An OBJ tetrahedron surface on points `v` (4 lines "x y z"), outward
/// faces of the tet (1, 2, 3, 4) when the points are positively oriented.
std::string TetSurfaceObj(const std::array<const char*, 4>& v) {
  return fmt::format("v {}\nv {}\nv {}\nv {}\nf 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\n", v[0], v[1], v[2], v[3]);
}

// Found by the surface fuzzer: a lone triangle with a repeated corner kept
// gmsh's Delaunay searching for minutes. A surface reaches gmsh only when it
// is closed and consistently oriented, its triangles have area and it
// encloses a volume.
TEST(HostileSurface, SurfacesGmshCannotFillAreRefusedBeforeIt) {
  TempDir dir;
  const std::string path = dir.File("s.obj");
  auto error = [&](const std::string& text) {
    WriteBytes(path, text);
    return ErrorOf([&] { (void)TetrahedralizeSurface(path, 0.5); });
  };
  std::string what = error("v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 2 3\nf 1 4 1\n");
  EXPECT_NE(what.find("s.obj"), std::string::npos) << what;
  EXPECT_NE(what.find("triangle 0 is degenerate"), std::string::npos) << what;
  what = error("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n");
  EXPECT_NE(what.find("not closed"), std::string::npos) << what;
  what = error(TetSurfaceObj({"0 0 0", "1 0 0", "2 0 0", "0 0 1"}));  // three corners on a line
  EXPECT_NE(what.find("has no area"), std::string::npos) << what;
  what = error(TetSurfaceObj({"0 0 0", "1 0 0", "0 1 0", "1 1 0"}));  // folded flat
  EXPECT_NE(what.find("encloses no volume"), std::string::npos) << what;
  // The faces of one triangle flipped: not consistently oriented.
  what = error("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 2 3\nf 1 2 4\nf 1 4 3\nf 2 3 4\n");
  EXPECT_NE(what.find("same direction"), std::string::npos) << what;
  // An STL facet alone is not closed either.
  const std::string stl = dir.File("s.stl");
  WriteBytes(stl, "solid x\n facet normal 0 0 1\n  outer loop\n   vertex 0 0 0\n   vertex 1 0 0\n   vertex 0 1 0\n"
                  "  endloop\n endfacet\nendsolid x\n");
  what = ErrorOf([&] { (void)TetrahedralizeSurface(stl, 0.5); });
  EXPECT_NE(what.find("s.stl"), std::string::npos) << what;
  EXPECT_NE(what.find("not closed"), std::string::npos) << what;
  // The same tetrahedron, well formed, is filled.
  WriteBytes(path, TetSurfaceObj({"0 0 0", "1 0 0", "0 1 0", "0 0 1"}));
  EXPECT_GE(TetrahedralizeSurface(path, 0.5).num_tets(), 1);
}

TEST(HostileMesh, GeneratorSizesAreCappedBeforeAnyArithmeticOverflows) {
  const std::string what = ErrorOf([] { (void)MakeBox({0, 0, 0}, {1, 1, 1}, 2147483647, 1, 1); });
  EXPECT_NE(what.find("limited to"), std::string::npos) << what;
  EXPECT_THROW((void)MakeBox({0, 0, 0}, {1, 1, 1}, 1000, 1000, 1000), InputError);
  EXPECT_THROW((void)MakeCylinder(1, 1, 2147483647, 2147483647, 2147483647), InputError);
}

TEST(HostileMesh, CoincidentNodesAreRefusedNamingTheNode) {
  // Two tets sharing a face geometrically, but with the face's nodes doubled.
  TetMesh m;
  m.nodes.resize(8, 3);
  m.nodes << 0, 0, 0, 1, 0, 0, 0, 1, 0, 0, 0, 1,  //
      0, 0, 0, 1, 0, 0, 0, 1, 0, 0, 0, -1;
  m.tets.resize(2, 4);
  m.tets << 0, 1, 2, 3, 4, 6, 5, 7;
  const std::string what = ErrorOf([&] { CheckWholeMesh(m, "two.mesh"); });
  EXPECT_NE(what.find("node 5"), std::string::npos) << what;
  EXPECT_NE(what.find("coincident"), std::string::npos) << what;
}

TEST(HostileMesh, FoldedMeshIsRefusedNamingTheTet) {
  // Both tets on the same side of their shared face (0, 1, 2): they overlap.
  TetMesh m;
  m.nodes.resize(5, 3);
  m.nodes << 0, 0, 0, 1, 0, 0, 0, 1, 0, 0, 0, 1, 0.2, 0.2, 0.5;
  m.tets.resize(2, 4);
  m.tets << 0, 1, 2, 3, 0, 1, 2, 4;
  const std::string what = ErrorOf([&] { CheckWholeMesh(m, "fold.mesh"); });
  EXPECT_NE(what.find("element 2"), std::string::npos) << what;
  EXPECT_NE(what.find("folded"), std::string::npos) << what;
  // Unfolded: the second tet below the face.
  m.nodes(4, 2) = -0.5;
  m.tets.row(1) << 0, 2, 1, 4;
  EXPECT_NO_THROW(ValidateTetMesh(m, "ok.mesh"));
  EXPECT_NO_THROW(CheckWholeMesh(m, "ok.mesh"));
}

}  // namespace
}  // namespace cutsim::mesh
