#include "common/mesh/mesh_io.h"

#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <functional>
#include <numeric>

#include <fmt/format.h>
#include <gtest/gtest.h>

#include "common/core/error.h"
#include "common/mesh/generators.h"
#include "tests/unit/mesh/test_util.h"

namespace cutsim::mesh {
namespace {

using testing::TempDir;

TetMesh SampleMesh() {
  TetMesh m = MakeBox({0.0, -0.01, 0.02}, {0.03, 0.01, 0.05}, 3, 2, 2);
  m.regions.resize(static_cast<size_t>(m.num_tets()));
  for (int32_t t = 0; t < m.num_tets(); ++t) m.regions[static_cast<size_t>(t)] = 1 + (t % 3);
  m.nodes(5, 0) += 1.0 / 3.0 * 1e-3;  // a coordinate with a long decimal expansion
  return m;
}

// Same mesh with tets stably sorted by region.
TetMesh SortedByRegion(const TetMesh& m) {
  std::vector<int32_t> order(static_cast<size_t>(m.num_tets()));
  std::iota(order.begin(), order.end(), 0);
  std::stable_sort(order.begin(), order.end(), [&](int32_t a, int32_t b) {
    return m.regions[static_cast<size_t>(a)] < m.regions[static_cast<size_t>(b)];
  });
  TetMesh out = m;
  for (size_t i = 0; i < order.size(); ++i) {
    out.tets.row(static_cast<Eigen::Index>(i)) = m.tets.row(order[i]);
    out.regions[i] = m.regions[static_cast<size_t>(order[i])];
  }
  return out;
}

void WriteText(const std::string& path, const std::string& text) {
  std::ofstream(path, std::ios::binary) << text;
}

void ExpectSameMesh(const TetMesh& a, const TetMesh& b, bool regions = true, double tolerance = 0.0) {
  ASSERT_EQ(a.num_nodes(), b.num_nodes());
  ASSERT_EQ(a.num_tets(), b.num_tets());
  if (tolerance == 0.0) {
    EXPECT_EQ(a.nodes, b.nodes);  // exact: our writers print shortest round-trip decimals
  } else {
    EXPECT_LE((a.nodes - b.nodes).cwiseAbs().maxCoeff(), tolerance);
  }
  EXPECT_EQ(a.tets, b.tets);
  if (regions) {
    EXPECT_EQ(a.regions, b.regions);
  }
}

TEST(MeshIo, RoundTripThroughEveryWriterAndReader) {
  TempDir dir;
  const TetMesh m = SampleMesh();
  WriteVtu(dir.File("m.vtu"), m);
  ExpectSameMesh(ReadMesh(dir.File("m.vtu")), m);
  WriteTetGen(dir.File("m"), m);
  ExpectSameMesh(ReadMesh(dir.File("m.ele")), m);
  ExpectSameMesh(ReadMesh(dir.File("m.node")), m);
  WriteMedit(dir.File("m.mesh"), m);
  ExpectSameMesh(ReadMesh(dir.File("m.mesh")), m);
  for (const MshFormat format : {MshFormat{2.2, false}, MshFormat{2.2, true}, MshFormat{4.1, false}, MshFormat{4.1, true}}) {
    const std::string path = dir.File(fmt::format("m{}{}.msh", format.version, format.binary ? "b" : "a"));
    WriteMsh(path, m, format);
    SCOPED_TRACE(path);
    // gmsh's own 4.1 ASCII writer prints 16 significant digits: not bit-exact.
    TetMesh back = ReadMesh(path);
    if (format.version == 2.2 && format.binary) {
      // gmsh's 2.2 binary writer renumbers elements grouped by region.
      back = SortedByRegion(back);
      ExpectSameMesh(back, SortedByRegion(m));
      continue;
    }
    ExpectSameMesh(back, m, true, format.version == 4.1 && !format.binary ? 1e-16 : 0.0);
  }
  // No temp files left behind.
  for (const auto& entry : std::filesystem::directory_iterator(dir.File(""))) {
    EXPECT_EQ(entry.path().string().find(".tmp"), std::string::npos) << entry.path();
  }
}

TEST(MeshIo, VtuFieldsRoundTrip) {
  TempDir dir;
  const TetMesh m = SampleMesh();
  std::vector<double> disp(3 * static_cast<size_t>(m.num_nodes())), mises(static_cast<size_t>(m.num_tets()));
  for (size_t i = 0; i < disp.size(); ++i) disp[i] = 1e-4 * static_cast<double>(i);
  for (size_t i = 0; i < mises.size(); ++i) mises[i] = 1e3 + static_cast<double>(i);
  const std::vector<VtkField> point{{"displacement", 3, disp}};
  const std::vector<VtkField> cell{{"von_mises", 1, mises}, {"stress6", 6, std::vector<double>(6 * mises.size(), 2.5)}};
  WriteVtu(dir.File("f.vtu"), m, point, cell);
  const VtuData d = ReadVtu(dir.File("f.vtu"));
  ExpectSameMesh(d.mesh, m);
  ASSERT_EQ(d.point_fields.size(), 1U);
  EXPECT_EQ(d.point_fields[0].name, "displacement");
  EXPECT_EQ(d.point_fields[0].values, disp);
  ASSERT_EQ(d.cell_fields.size(), 2U);
  EXPECT_EQ(d.cell_fields[0].values, mises);
  EXPECT_EQ(d.cell_fields[1].components, 6);
  WriteVtk(dir.File("f.vtk"), m.nodes, m.tets, point, cell);
  EXPECT_GT(std::filesystem::file_size(dir.File("f.vtk")), 1000U);
}

// meshio is an independent reader: it must agree on counts and a field.
TEST(MeshIo, IndependentReaderMeshio) {
  if (std::system("/usr/bin/python3 -c 'import meshio' >/dev/null 2>&1") != 0) {
    GTEST_SKIP() << "/usr/bin/python3 cannot import meshio";
  }
  TempDir dir;
  const TetMesh m = SampleMesh();
  std::vector<double> disp(3 * static_cast<size_t>(m.num_nodes()), 0.0);
  disp[3 * 7 + 1] = 0.125;
  const std::vector<VtkField> point{{"displacement", 3, disp}};
  const std::vector<VtkField> cell{{"quality", 1, std::vector<double>(static_cast<size_t>(m.num_tets()), 0.75)}};
  for (const char* ext : {"vtu", "vtk"}) {
    const std::string path = dir.File(std::string("m.") + ext);
    if (std::string(ext) == "vtu") {
      WriteVtu(path, m, point, cell);
    } else {
      WriteVtk(path, m.nodes, m.tets, point, cell);
    }
    const std::string cmd = fmt::format(
        "/usr/bin/python3 -c \"import meshio; m = meshio.read('{}'); "
        "assert len(m.points) == {}, len(m.points); "
        "assert sum(len(c.data) for c in m.cells if c.type == 'tetra') == {}; "
        "assert abs(m.point_data['displacement'][7][1] - 0.125) < 1e-15; "
        "assert abs(m.cell_data['quality'][0][3] - 0.75) < 1e-15\"",
        path, m.num_nodes(), m.num_tets());
    EXPECT_EQ(std::system(cmd.c_str()), 0) << cmd;
  }
}

// Each bad input: InputError whose message names the file and the place.
TEST(MeshIo, BadInputsGiveInputErrors) {
  TempDir dir;
  const TetMesh m = SampleMesh();
  WriteTetGen(dir.File("good"), m);
  WriteMedit(dir.File("good.mesh"), m);
  WriteMsh(dir.File("good.msh"), m, {2.2, false});
  WriteVtu(dir.File("good.vtu"), m);
  auto read_text = [&](const std::string& name) {
    std::ifstream in(dir.File(name));
    return std::string(std::istreambuf_iterator<char>(in), {});
  };
  const std::string node = read_text("good.node"), ele = read_text("good.ele"), medit = read_text("good.mesh"),
                    msh = read_text("good.msh"), vtu = read_text("good.vtu");
  auto replace_line = [](std::string text, int line, const std::string& with) {
    size_t pos = 0;
    for (int i = 1; i < line; ++i) pos = text.find('\n', pos) + 1;
    return text.replace(pos, text.find('\n', pos) - pos, with);
  };
  struct Case {
    std::string name;        // file to read
    std::function<void()> setup;
    std::string expect;      // substring besides the file name
  };
  const std::vector<Case> cases = {
      {"missing.msh", [] {}, "No such file"},
      {"missing.node", [] {}, "No such file"},
      {"data.xyz", [&] { WriteText(dir.File("data.xyz"), "1 2 3\n"); }, "unknown mesh format"},
      {"noext", [&] { WriteText(dir.File("noext"), "1 2 3\n"); }, "unknown mesh format"},
      // TetGen: NaN coordinate on line 4 (node 3), inverted is fixed but a
      // zero-volume tet on line 3 of .ele is not, dangling node, truncation.
      {"nan.node", [&] {
         WriteText(dir.File("nan.node"), replace_line(node, 4, "3 nan 0 0"));
         WriteText(dir.File("nan.ele"), ele);
       }, "nan.node:4: node 3: coordinate is NaN"},
      {"flat.ele", [&] {
         WriteText(dir.File("flat.node"), node);
         WriteText(dir.File("flat.ele"), replace_line(ele, 3, "2 1 2 3 3 1"));
       }, "flat.ele:3: element 2: repeats a node"},
      {"zero.ele", [&] {
         WriteText(dir.File("zero.node"), node);
         WriteText(dir.File("zero.ele"), replace_line(ele, 3, "2 1 2 3 4 1"));  // 4 nodes on the z=0.02, y=-0.01 edge row
       }, "zero.ele:3: element 2: zero-volume"},
      {"dangling.ele", [&] {
         std::string n2 = node;
         n2.replace(0, n2.find(' '), std::to_string(m.num_nodes() + 1));
         n2 += fmt::format("{} 9 9 9\n", m.num_nodes() + 1);
         WriteText(dir.File("dangling.node"), n2);
         WriteText(dir.File("dangling.ele"), ele);
       }, fmt::format("node {}: dangling", m.num_nodes() + 1)},
      {"trunc.ele", [&] {
         WriteText(dir.File("trunc.node"), node);
         WriteText(dir.File("trunc.ele"), ele.substr(0, ele.size() / 2));
       }, "cannot fit"},
      {"short.ele", [&] {
         WriteText(dir.File("short.node"), node);
         WriteText(dir.File("short.ele"), replace_line(ele, 5, "4 1 2"));
       }, "short.ele:5: element 4 has too few fields"},
      {"range.ele", [&] {
         WriteText(dir.File("range.node"), node);
         WriteText(dir.File("range.ele"), replace_line(ele, 2, "1 1 2 3 999 1"));
       }, "range.ele:2: element 1: node 999 does not exist"},
      // Medit.
      {"trunc.mesh", [&] { WriteText(dir.File("trunc.mesh"), medit.substr(0, medit.size() * 2 / 3)); },
       "cannot fit"},
      {"tris.mesh", [&] {
         WriteText(dir.File("tris.mesh"), "MeshVersionFormatted 2\nDimension 3\nVertices\n3\n0 0 0 0\n1 0 0 0\n0 1 0 0\n"
                                          "Triangles\n1\n1 2 3 0\nEnd\n");
       }, "no tetrahedra (only triangles)"},
      {"nan.mesh", [&] { WriteText(dir.File("nan.mesh"), replace_line(medit, 6, "0 nan 0 0")); },
       "nan.mesh:6: vertex 2: coordinate is NaN"},
      // Gmsh (parsed by libgmsh).
      {"trunc.msh", [&] { WriteText(dir.File("trunc.msh"), msh.substr(0, msh.size() / 2)); }, "cannot fit"},
      {"garbage.msh", [&] { WriteText(dir.File("garbage.msh"), "this is not a mesh\n"); }, "start with $MeshFormat"},
      {"hex.msh", [&] {
         WriteText(dir.File("hex.msh"),
                   "$MeshFormat\n2.2 0 8\n$EndMeshFormat\n$Nodes\n8\n1 0 0 0\n2 1 0 0\n3 1 1 0\n4 0 1 0\n"
                   "5 0 0 1\n6 1 0 1\n7 1 1 1\n8 0 1 1\n$EndNodes\n$Elements\n1\n1 5 2 1 1 1 2 3 4 5 6 7 8\n$EndElements\n");
       }, "only 4-node tetrahedra"},
      {"flat.msh", [&] {
         WriteText(dir.File("flat.msh"),
                   "$MeshFormat\n2.2 0 8\n$EndMeshFormat\n$Nodes\n4\n1 0 0 0\n2 1 0 0\n3 0 1 0\n4 1 1 0\n$EndNodes\n"
                   "$Elements\n1\n7 4 2 1 1 1 2 3 4\n$EndElements\n");
       }, "element 7: zero-volume"},
      {"tris.msh", [&] {
         WriteText(dir.File("tris.msh"),
                   "$MeshFormat\n2.2 0 8\n$EndMeshFormat\n$Nodes\n3\n1 0 0 0\n2 1 0 0\n3 0 1 0\n$EndNodes\n"
                   "$Elements\n1\n1 2 2 1 1 1 2 3\n$EndElements\n");
       }, "no 4-node tetrahedra"},
      // VTU.
      {"trunc.vtu", [&] { WriteText(dir.File("trunc.vtu"), vtu.substr(0, vtu.size() / 2)); }, "truncated"},
      {"nan.vtu", [&] {
         std::string v = vtu;
         const size_t points = v.find("<Points>");
         const size_t first = v.find('\n', v.find("<DataArray", points)) + 1;
         v.replace(first, v.find(' ', first) - first, "nan");
         WriteText(dir.File("nan.vtu"), v);
       }, "node 1: coordinate is NaN"},
  };
  for (const auto& c : cases) {
    c.setup();
    try {
      (void)ReadMesh(dir.File(c.name));
      ADD_FAILURE() << c.name << ": no exception";
    } catch (const InputError& e) {
      const std::string what = e.what();
      EXPECT_NE(what.find(dir.File(c.name.substr(0, c.name.find('.')))), std::string::npos) << c.name << ": " << what;
      EXPECT_NE(what.find(c.expect), std::string::npos) << c.name << ": " << what;
    } catch (const std::exception& e) {
      ADD_FAILURE() << c.name << ": not an InputError: " << e.what();
    }
  }
}

TEST(MeshIo, AtomicWriteKeepsOldFileWhenTargetDirIsMissing) {
  TempDir dir;
  const TetMesh m = SampleMesh();
  EXPECT_THROW(WriteVtu(dir.File("no_such_dir/m.vtu"), m), InputError);
  WriteVtu(dir.File("m.vtu"), m);
  EXPECT_FALSE(std::filesystem::exists(dir.File("m.vtu.tmp")));
}

}  // namespace
}  // namespace cutsim::mesh
