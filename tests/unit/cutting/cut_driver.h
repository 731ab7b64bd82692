#pragma once
// A stand-in for the sim layer's tool contact in the cutting tests: the tool
// slides on the top face (outward normal +z in world), the closest vertex is
// found by brute force over the top surface, every attempt passes the
// physical criterion (tested separately), and events are applied to the
// test world as the FEM side would.

#include <chrono>
#include <limits>
#include <vector>

#include "common/cutting/cut_attempt.h"
#include "common/cutting/cut_mesh.h"
#include "common/cutting/cut_stepper.h"
#include "tests/unit/cutting/test_util.h"

namespace cutsim::cutting::testing {

/// Closest top-surface vertex to `p` (lowest id on ties).
inline int32_t ClosestTopVertex(const CutMesh& cm, const WorldAccess& world, const Eigen::Vector3d& p) {
  const mesh::Triangles tris = cm.SurfaceTriangles();
  int32_t best = -1;
  double best_d = std::numeric_limits<double>::infinity();
  for (int r = 0; r < tris.rows(); ++r) {
    const Eigen::Vector3d a = world.Get(tris(r, 0)), b = world.Get(tris(r, 1)), c = world.Get(tris(r, 2));
    const Eigen::Vector3d nrm = (b - a).cross(c - a);
    if (!(nrm.z() > 0.9 * nrm.norm())) continue;
    for (int k = 0; k < 3; ++k) {
      const int32_t v = tris(r, k);
      const double d = (world.Get(v) - p).norm();
      if (d < best_d || (d == best_d && v < best)) {
        best_d = d;
        best = v;
      }
    }
  }
  return best;
}

struct DriveStats {
  int attempts = 0;
  int executed = 0;
  int rejected = 0;
  int splits = 0;
  int moves_limited = 0;
  int moves_skipped = 0;
  double cut_seconds = 0.0;  ///< wall time inside ExecuteCut
};

/// Drives the tool along `points` (world, on the top face) with a blade
/// `depth` m deep below the contact point; applies every executed event to
/// `world` and `events`, and runs `check` after each. `prepare`: each step
/// through CutStepper::PrepareCut first, as the simulation does with two
/// threads.
template <typename Check>
DriveStats DrivePath(CutMesh& cm, VectorWorld& world, const std::vector<Eigen::Vector3d>& points, double depth,
                     const CutParams& params, std::vector<TopologyEvent>* events, Check&& check,
                     bool prepare = false) {
  DriveStats stats;
  CutStepper stepper;
  CutAttemptTracker tracker(params);
  for (const Eigen::Vector3d& p : points) {
    Contact c;
    c.touching = true;
    c.point = p;
    c.normal = Eigen::Vector3d::UnitZ();
    c.closest_node = ClosestTopVertex(cm, world, p);
    const CutAttempt a = tracker.Update(c, world);
    if (!a.attempt) continue;
    ++stats.attempts;
    CutStep step;
    step.v0 = a.v0;
    step.v1 = a.v1;
    step.cp0 = a.cp0;
    step.cp = a.cp;
    step.normal = a.normal;
    step.blade.emplace(Blade{p - depth * Eigen::Vector3d::UnitZ(), Eigen::Vector3d::UnitZ(), depth + 0.01});
    const auto t_start = std::chrono::steady_clock::now();
    PreparedCut prepared;
    if (prepare) prepared = stepper.PrepareCut(cm, step, world, params);
    const CutOutcome out = stepper.ExecuteCut(cm, step, world, params, prepare ? &prepared : nullptr);
    stats.cut_seconds += std::chrono::duration<double>(std::chrono::steady_clock::now() - t_start).count();
    if (out.status == CutStatus::kRejected) {
      ++stats.rejected;
      continue;
    }
    EXPECT_EQ(out.status, CutStatus::kExecuted);
    if (out.status != CutStatus::kExecuted) continue;
    ++stats.executed;
    stats.splits += static_cast<int>(out.event.splits.size());
    stats.moves_limited += out.moves_limited;
    stats.moves_skipped += out.moves_skipped;
    tracker.OnCutExecuted();
    if (!out.event.empty()) {
      EXPECT_EQ(out.event.version, cm.version());
      world.ApplyEvent(out.event);
      EXPECT_EQ(world.size(), cm.num_nodes());
      if (events) events->push_back(out.event);
    }
    check(stats.executed);
  }
  return stats;
}

/// Points from a to b, `n` + 1 of them.
inline std::vector<Eigen::Vector3d> Segment(const Eigen::Vector3d& a, const Eigen::Vector3d& b, int n) {
  std::vector<Eigen::Vector3d> out;
  for (int i = 0; i <= n; ++i) out.push_back(a + (b - a) * (static_cast<double>(i) / n));
  return out;
}

}  // namespace cutsim::cutting::testing
