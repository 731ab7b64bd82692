// Tissue under tension, cut along its shipped paths: the pre-tensioned
// ligament's stumps retract apart and its cut scores as a transection; the
// skin pad's layers take their own materials and its incision gapes.
#include <algorithm>
#include <cstdio>
#include <cstdlib>
#include <span>
#include <cmath>
#include <memory>
#include <numeric>
#include <optional>
#include <string>
#include <vector>

#include <Eigen/Core>
#include <gtest/gtest.h>

#include "common/fem/model.h"
#include "common/render/camera.h"
#include "common/render/image.h"
#include "common/render/surface_renderer.h"
#include "common/sim/scene_fem.h"
#include "common/sim/scene_loader.h"
#include "common/sim/scene_mesh.h"
#include "common/sim/simulation.h"

namespace cutsim::sim {
namespace {

std::string ScenePath(const std::string& name) { return std::string(CUTSIM_SOURCE_DIR) + "/scenes/" + name; }

/// Runs the scene headless (its scripted cut) to `end` s.
std::unique_ptr<Simulation> RunScene(const std::string& name, double end) {
  auto sim = Simulation::Create(LoadScene(ScenePath(name)), {.threads = 1});
  while (sim->sim_time() < end - 1e-9) {
    const SimStatus status = sim->AdvanceFrame();
    EXPECT_EQ(status, SimStatus::kOk) << "at t = " << sim->sim_time();
    if (status != SimStatus::kOk) break;
  }
  return sim;
}

/// The connected piece of each node (nodes joined by shared tets).
std::vector<int32_t> Pieces(const MeshView& view) {
  std::vector<int32_t> parent(static_cast<size_t>(view.world.rows()));
  std::iota(parent.begin(), parent.end(), 0);
  const auto find = [&parent](int32_t a) {
    while (parent[static_cast<size_t>(a)] != a) a = parent[static_cast<size_t>(a)] = parent[static_cast<size_t>(parent[static_cast<size_t>(a)])];
    return a;
  };
  for (Eigen::Index t = 0; t < view.tets.rows(); ++t) {
    for (int c = 1; c < 4; ++c) parent[static_cast<size_t>(find(view.tets(t, c)))] = find(view.tets(t, 0));
  }
  std::vector<int32_t> piece(parent.size());
  for (size_t n = 0; n < parent.size(); ++n) piece[n] = find(static_cast<int32_t>(n));
  return piece;
}

TEST(PretensionTest, SeveredLigamentRetractsAndScoresAsATransection) {
  const auto sim = RunScene("ligament.pbtxt", 4.0);
  MeshView view;
  sim->FillMeshView(view);
  const std::vector<int32_t> piece = Pieces(view);
  // The stumps: the pieces attached at x = 0 and at x = 30 mm (rest).
  int32_t left = -1, right = -1;
  for (Eigen::Index n = 0; n < view.rest.rows(); ++n) {
    if (view.rest(n, 0) < 1e-9) left = piece[static_cast<size_t>(n)];
    if (view.rest(n, 0) > 0.03 - 1e-9) right = piece[static_cast<size_t>(n)];
  }
  ASSERT_NE(left, right) << "the ligament is not severed";
  // The gap along the ligament between the stumps' ends (world).
  double left_end = -1e9, right_end = 1e9;
  for (Eigen::Index n = 0; n < view.world.rows(); ++n) {
    if (piece[static_cast<size_t>(n)] == left) left_end = std::max(left_end, view.world(n, 0));
    if (piece[static_cast<size_t>(n)] == right) right_end = std::min(right_end, view.world(n, 0));
  }
  const double gap = right_end - left_end;
  RecordProperty("stump_gap_mm", std::to_string(1e3 * gap));
  std::printf("ligament: stumps %.3f mm apart, coverage %.4f\n", 1e3 * gap, sim->Score() ? sim->Score()->coverage() : 0.0);
  EXPECT_GE(gap, 0.002);
  const std::optional<IncisionScore> score = sim->Score();
  ASSERT_TRUE(score.has_value());
  RecordProperty("coverage", std::to_string(score->coverage()));
  EXPECT_GE(score->coverage(), 0.9);
}

TEST(PretensionTest, SkinPadLayersTakeTheirOwnMaterials) {
  const LoadedScene scene = LoadScene(ScenePath("skin_pad.pbtxt"));
  const SceneMesh mesh = BuildSceneMesh(scene);
  const std::vector<fem::Material> per_tet = MaterialsPerTet(scene.scene, mesh.mesh, scene.path.string());
  std::vector<double> mu(3);
  for (int i = 0; i < 3; ++i) {
    const auto& yp = scene.scene.materials(i).young_poisson();
    mu[static_cast<size_t>(i)] = yp.youngs_modulus() / (2 * (1 + yp.poisson_ratio()));
  }
  // Each tet's material is the one of its centroid's layer.
  for (int32_t t = 0; t < mesh.mesh.num_tets(); ++t) {
    double z = 0;
    for (int c = 0; c < 4; ++c) z += mesh.mesh.nodes(mesh.mesh.tets(t, c), 2) / 4;
    const size_t layer = z > -0.002 ? 0 : z > -0.006 ? 1 : 2;
    ASSERT_NEAR(per_tet[static_cast<size_t>(t)].mu, mu[layer], 1e-9 * mu[layer]) << "tet " << t << " at z = " << z;
  }
}

TEST(PretensionTest, SkinPadIncisionGapes) {
  const auto sim = RunScene("skin_pad.pbtxt", 3.5);
  MeshView view;
  sim->FillMeshView(view);
  // Each node's side of the cut: the mean rest y of the tets it belongs to
  // (a node the cut split has one copy on each side).
  std::vector<double> side(static_cast<size_t>(view.world.rows()), 0.0);
  for (Eigen::Index t = 0; t < view.tets.rows(); ++t) {
    double y = 0;
    for (int c = 0; c < 4; ++c) y += view.rest(view.tets(t, c), 1) / 4;
    for (int c = 0; c < 4; ++c) side[static_cast<size_t>(view.tets(t, c))] += y;
  }
  // The wound's lips at the middle of the line: the nodes of opened faces
  // on the skin's surface (rest z ≈ 0) within a cell of x = 0.
  ASSERT_EQ(view.opened.size(), static_cast<size_t>(view.surface.rows()));
  double lip_minus = -1e9, lip_plus = 1e9;
  int lips = 0;
  for (Eigen::Index f = 0; f < view.surface.rows(); ++f) {
    if (!view.opened[static_cast<size_t>(f)]) continue;
    for (int c = 0; c < 3; ++c) {
      const int32_t n = view.surface(f, c);
      if (view.rest(n, 2) < -1e-4 || std::abs(view.rest(n, 0)) > 0.0015) continue;
      ++lips;
      if (side[static_cast<size_t>(n)] < 0) lip_minus = std::max(lip_minus, view.world(n, 1));
      if (side[static_cast<size_t>(n)] > 0) lip_plus = std::min(lip_plus, view.world(n, 1));
    }
  }
  ASSERT_GT(lips, 0) << "no opened face at the middle of the line";
  const double gap = lip_plus - lip_minus;
  RecordProperty("gap_mm", std::to_string(1e3 * gap));
  std::printf("skin pad: gap at the middle %.3f mm\n", 1e3 * gap);
  EXPECT_GE(gap, 0.002);
  EXPECT_EQ(sim->Summary().components, 1) << "an incision, not a transection";
  const std::optional<IncisionScore> score = sim->Score();
  ASSERT_TRUE(score.has_value());
  RecordProperty("coverage", std::to_string(score->coverage()));
  EXPECT_GE(score->coverage(), 0.9);
  EXPECT_LE(score->mean_deviation(), 0.0015);

  // Drawn from above (OSMesa), the wound's walls show in the cut colour and
  // the scalpel stands over the pad.
  render::Camera camera = render::FrameBoundingBox(render::BoundingBox(view.world), 480, 360, {0.35, -0.9, 1.2});
  render::RenderOptions options;
  const ToolReport tool = sim->Tool();
  options.tool = render::ToolSegment{.pose = tool.pose, .length = tool.blade_length};
  render::SurfaceRenderer renderer;
  const render::Image image = renderer.Render(
      camera, {.positions = view.world, .triangles = view.surface, .opened = std::span<const uint8_t>(view.opened)},
      options);
  if (const char* dir = std::getenv("CUTSIM_RENDER_DUMP")) render::WritePng(std::string(dir) + "/skin_pad.png", image);
  EXPECT_GT(render::CountCutFacePixels(image), 50);
}

}  // namespace
}  // namespace cutsim::sim
