#include "common/mesh/generators.h"

#include <numbers>

#include <gtest/gtest.h>

#include "common/core/clock.h"
#include "common/core/error.h"
#include "common/core/log.h"
#include "common/mesh/mesh_io.h"
#include "common/mesh/quality.h"
#include "common/mesh/surface.h"
#include "tests/unit/mesh/test_util.h"

namespace cutsim::mesh {
namespace {

double TotalVolume(const TetMesh& m, double* min_volume = nullptr) {
  double sum = 0.0, lo = 1e300;
  for (int32_t t = 0; t < m.num_tets(); ++t) {
    const double v = SignedVolume(m, t);
    sum += v;
    lo = std::min(lo, v);
  }
  if (min_volume != nullptr) *min_volume = lo;
  return sum;
}

void ExpectClosedSphere(const TetMesh& m) {
  const ManifoldCheck c = CheckClosedManifold(ExtractSurface(m.tets).tris);
  EXPECT_TRUE(c.ok) << c.problem;
  EXPECT_EQ(c.euler_characteristic(), 2);
}

TEST(MakeBox, ExactVolumeAndClosedSurface) {
  const TetMesh m = MakeBox({-0.1, 0.0, 0.2}, {0.3, 0.05, 0.5}, 4, 3, 5);
  EXPECT_EQ(m.num_nodes(), 5 * 4 * 6);
  EXPECT_EQ(m.num_tets(), 6 * 4 * 3 * 5);
  double min_v = 0.0;
  EXPECT_NEAR(TotalVolume(m, &min_v), 0.4 * 0.05 * 0.3, 1e-15);
  EXPECT_GT(min_v, 0.0);
  ExpectClosedSphere(m);
}

TEST(MakeBox, RejectsBadArguments) {
  EXPECT_THROW(MakeBox({0, 0, 0}, {1, 1, 1}, 0, 1, 1), InputError);
  EXPECT_THROW(MakeBox({0, 0, 0}, {1, -1, 1}, 1, 1, 1), InputError);
}

TEST(MakeCylinder, VolumeApproachesPiR2LAndSurfaceIsClosed) {
  const double r = 0.02, length = 0.1;
  double previous_error = 1.0;
  for (int segments : {12, 24, 48, 96}) {
    const TetMesh m = MakeCylinder(r, length, segments, 4, 6);
    double min_v = 0.0;
    const double v = TotalVolume(m, &min_v);
    EXPECT_GT(min_v, 0.0);
    // Exact for the inscribed polygon: (n/2)·r²·sin(2π/n)·L.
    const double polygon = 0.5 * segments * r * r * std::sin(2.0 * std::numbers::pi / segments) * length;
    EXPECT_NEAR(v, polygon, 1e-15);
    const double error = std::abs(v - std::numbers::pi * r * r * length) / (std::numbers::pi * r * r * length);
    EXPECT_LT(error, previous_error);
    previous_error = error;
    ExpectClosedSphere(m);
    EXPECT_NEAR(m.nodes.col(0).minCoeff(), 0.0, 1e-15);
    EXPECT_NEAR(m.nodes.col(0).maxCoeff(), length, 1e-15);
  }
  EXPECT_LT(previous_error, 1e-3);
}

TEST(MakeOrgan, DeterministicLargeValidMesh) {
  Stopwatch watch;
  const TetMesh organ = MakeOrgan();
  const double seconds = watch.ElapsedSeconds();
  const TetQuality q = ComputeTetQuality(organ);
  const double min_q = *std::min_element(q.mean_ratio.begin(), q.mean_ratio.end());
  Log().info("organ: {} nodes, {} tets in {:.2f} s, volume {:.3g} m³, min mean ratio {:.3f}", organ.num_nodes(),
             organ.num_tets(), seconds, TotalVolume(organ), min_q);
  EXPECT_GE(organ.num_tets(), 20000);
  EXPECT_GT(min_q, 0.0);
  ExpectClosedSphere(organ);
  // Volume below the undeformed ellipsoid's and well above half of it.
  const double ellipsoid = 4.0 / 3.0 * std::numbers::pi * 0.06 * 0.035 * 0.03;
  EXPECT_LT(TotalVolume(organ), 1.1 * ellipsoid);
  EXPECT_GT(TotalVolume(organ), 0.6 * ellipsoid);
  // Deterministic: a second run gives the identical mesh (small options keep it fast).
  OrganOptions small;
  small.edge_length = 0.01;
  const TetMesh a = MakeOrgan(small), b = MakeOrgan(small);
  ASSERT_EQ(a.num_nodes(), b.num_nodes());
  ASSERT_EQ(a.num_tets(), b.num_tets());
  EXPECT_EQ(a.nodes, b.nodes);
  EXPECT_EQ(a.tets, b.tets);
}

TEST(TetrahedralizeSurface, FromStlAndObjFiles) {
  testing::TempDir dir;
  OrganOptions small;
  small.edge_length = 0.012;
  Positions x;
  Triangles tris;
  MakeOrganSurface(small, x, tris);
  ASSERT_TRUE(CheckClosedManifold(tris).ok);
  WriteStl(dir.File("organ.stl"), x, tris);
  const TetMesh from_stl = TetrahedralizeSurface(dir.File("organ.stl"), 0.012);
  EXPECT_GT(from_stl.num_tets(), 100);
  ExpectClosedSphere(from_stl);
  {
    std::FILE* f = std::fopen(dir.File("organ.obj").c_str(), "w");
    ASSERT_NE(f, nullptr);
    for (Eigen::Index i = 0; i < x.rows(); ++i) std::fprintf(f, "v %.17g %.17g %.17g\n", x(i, 0), x(i, 1), x(i, 2));
    for (Eigen::Index i = 0; i < tris.rows(); ++i) std::fprintf(f, "f %d %d %d\n", tris(i, 0) + 1, tris(i, 1) + 1, tris(i, 2) + 1);
    std::fclose(f);
  }
  const TetMesh from_obj = TetrahedralizeSurface(dir.File("organ.obj"), 0.012);
  // The STL stores floats, so the cleanup may delete different slivers: the
  // volumes agree to the slivers' share (observed 1.1e-5 relative).
  EXPECT_NEAR(TotalVolume(from_obj), TotalVolume(from_stl), 1e-4 * TotalVolume(from_stl));
  ExpectClosedSphere(from_obj);
  // Without the cleanup, gmsh's fill of the same surface agrees to round-off.
  TetrahedralizeOptions raw;
  raw.cleanup = false;
  EXPECT_NEAR(TotalVolume(TetrahedralizeSurface(dir.File("organ.obj"), 0.012, raw)),
              TotalVolume(TetrahedralizeSurface(dir.File("organ.stl"), 0.012, raw)), 1e-9);
  // Missing and open surfaces are input errors naming the file.
  try {
    TetrahedralizeSurface(dir.File("missing.stl"), 0.01);
    ADD_FAILURE() << "no throw";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("missing.stl"), std::string::npos);
  }
}

}  // namespace
}  // namespace cutsim::mesh
