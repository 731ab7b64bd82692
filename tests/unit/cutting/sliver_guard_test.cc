// The remeshing sliver guard (CutParams::keep_quality, cut_stepper.h step 5):
// many parallel passes over one block, with the world pushed apart under
// the blade as by the contact, keep every element at ≥ min(keep_quality,
// uncut quality), the property the stable time step rests on (it needs
// ≥ 0.5 of the uncut mesh's quality). This synthetic push costs the
// unguarded rule only 0.76 → 0.60; the sim's contact grinds it to 0.05
// (cut_bench "block", bench/README.md), which is the end-to-end check.
#include <algorithm>
#include <string>

#include <gtest/gtest.h>

#include "common/cutting/cut_mesh.h"
#include "common/cutting/cut_stepper.h"
#include "common/mesh/quality.h"
#include "tests/unit/cutting/cut_driver.h"
#include "tests/unit/cutting/test_util.h"

namespace cutsim::cutting {
namespace {

using Eigen::Vector3d;

struct PassResult {
  double min_rest_quality = 1.0;
  int executed = 0;
};

double MinQuality(const CutMesh& cm, const WorldAccess* world) {
  double q = 1.0;
  for (int32_t t = 0; t < cm.num_tets(); ++t) {
    const auto& n = cm.tet(t);
    auto x = [&](int c) { return world ? world->Get(n[static_cast<size_t>(c)]) : cm.rest(n[static_cast<size_t>(c)]); };
    q = std::min(q, mesh::MeanRatio(x(0), x(1), x(2), x(3)));
  }
  return q;
}

// World under the blade: the contact pushes the nodes near the contact
// point apart from the blade and down (by up to `push`, fading to zero at 3
// cells), as in the sim, where the blade shifts nodes by more than a
// millimetre; elsewhere world = rest. The remeshing moves project these
// displaced nodes onto P and map the target back to rest through the
// deformed tets, which is where slivers come from.
VectorWorld PushedWorld(const CutMesh& cm, const Vector3d& contact, const Vector3d& motion, double push) {
  std::vector<Vector3d> x(static_cast<size_t>(cm.num_nodes()));
  const double radius = 0.0075;
  const Vector3d side = Vector3d::UnitZ().cross(motion).normalized();
  for (int32_t v = 0; v < cm.num_nodes(); ++v) {
    const Vector3d r = cm.rest(v);
    const double d = (r - contact).norm();
    // Apart from the blade's plane on either side, and down.
    const Vector3d dir = (side.dot(r - contact) >= 0.0 ? side : Vector3d(-side)) - 0.5 * Vector3d::UnitZ();
    x[static_cast<size_t>(v)] = d < radius ? Vector3d(r + push * (1.0 - d / radius) * dir) : r;
  }
  return VectorWorld(std::move(x));
}

// scenes/block's geometry (40 × 20 × 10 mm, 2.5 mm cells), cut like
// cut_bench's "block" part: parallel half-depth passes 0.1 mm beside the
// node rows, so every pass moves the twins of the previous one again.
PassResult CutParallelPasses(const CutParams& params, double* uncut_quality) {
  const mesh::TetMesh box = testing::KuhnBox(Vector3d::Zero(), Vector3d(0.04, 0.02, 0.01), 16, 8, 4);
  CutMesh cm(box);
  CutStepper stepper;
  *uncut_quality = MinQuality(cm, nullptr);
  PassResult r;
  for (int pass = 0; pass < 14; ++pass) {  // each line twice, there and back
    const double y = 0.0026 + 0.0025 * (pass / 2);
    CutAttemptTracker tracker(params);
    const double x0 = pass % 2 == 0 ? 0.0005 : 0.0395;
    const auto pts = testing::Segment(Vector3d(x0, y, 0.01), Vector3d(0.04 - x0, y, 0.01), 78);
    for (const Vector3d& p : pts) {
      const VectorWorld world = PushedWorld(cm, p, Vector3d::UnitX(), 0.001);
      Contact c;
      c.touching = true;
      c.point = p;
      c.normal = Vector3d::UnitZ();
      c.closest_node = testing::ClosestTopVertex(cm, world, p);
      const CutAttempt a = tracker.Update(c, world);
      if (!a.attempt) continue;
      CutStep step;
      step.v0 = a.v0;
      step.v1 = a.v1;
      step.cp0 = a.cp0;
      step.cp = a.cp;
      step.normal = a.normal;
      step.blade.emplace(Blade{p - 0.005 * Vector3d::UnitZ(), Vector3d::UnitZ(), 0.015});
      const CutOutcome out = stepper.ExecuteCut(cm, step, world, params);
      if (out.status != CutStatus::kExecuted) continue;
      ++r.executed;
      tracker.OnCutExecuted();
      for (int32_t t = 0; t < cm.num_tets(); ++t) {  // no inverted or zero-volume tet, ever
        const auto& n = cm.tet(t);
        EXPECT_GT(mesh::MeanRatio(cm.rest(n[0]), cm.rest(n[1]), cm.rest(n[2]), cm.rest(n[3])), 0.0);
      }
    }
  }
  r.min_rest_quality = MinQuality(cm, nullptr);
  return r;
}

TEST(SliverGuard, ParallelPassesKeepElementQuality) {
  CutParams params;
  params.alpha = 0.4;
  double q0 = 0.0;
  const PassResult guarded = CutParallelPasses(params, &q0);
  if (::testing::Test::HasFailure()) return;
  EXPECT_GE(guarded.executed, 100);
  // Moves may not take a tet below min(keep_quality, its quality before),
  // and splits do not change shapes: nothing falls below the floor.
  const double floor_q = std::min(q0, params.keep_quality);
  EXPECT_GE(guarded.min_rest_quality, floor_q - 1e-12);

}

}  // namespace
}  // namespace cutsim::cutting
