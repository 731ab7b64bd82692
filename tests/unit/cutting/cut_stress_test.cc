// Randomised cut paths on three meshes, every invariant after every step.
#include <algorithm>
#include <random>
#include <tuple>
#include <vector>

#include <gtest/gtest.h>

#include "common/core/hash.h"

#include "common/core/log.h"
#include "common/cutting/cut_mesh.h"
#include "tests/unit/cutting/cut_driver.h"
#include "tests/unit/cutting/test_util.h"

namespace cutsim::cutting {
namespace {

using Eigen::Matrix3d;
using Eigen::Vector3d;

struct MeshCase {
  const char* name;
  mesh::TetMesh mesh;
  Matrix3d A;  // world = A·rest (an affine deformation; identity = undeformed)
};

// FNV-1a over the cut result (tets, rest and world positions, the surface
// faces, the events' splits and moves): logged per case so a change that
// claims to keep results identical can be checked by comparing the log
// before/after. The surface enters as the set of live faces (tet, local
// face, opened), not by slot id: which free slot a new face takes is
// bookkeeping, not a result.
struct ResultHash {
  uint64_t h = Fnv1a64(nullptr, 0);
  template <typename T>
  void Add(const T& v) {
    h = Fnv1a64(&v, sizeof(v), h);
  }
  void Add(const Vector3d& v) { h = Fnv1a64(v.data(), 3 * sizeof(double), h); }
};

uint64_t HashResult(const CutMesh& cm, const WorldAccess& world, const std::vector<TopologyEvent>& events) {
  ResultHash r;
  for (int32_t t = 0; t < cm.num_tets(); ++t) r.Add(cm.tet(t));
  for (int32_t v = 0; v < cm.num_nodes(); ++v) {
    r.Add(cm.rest(v));
    r.Add(world.Get(v));
  }
  std::vector<std::tuple<int32_t, int8_t, bool>> faces;
  for (const SurfaceFace& s : cm.surface_slots())
    if (s.alive) faces.emplace_back(s.tet, s.local_face, s.opened);
  std::sort(faces.begin(), faces.end());
  for (const auto& [tet, local_face, opened] : faces) {
    r.Add(tet);
    r.Add(local_face);
    r.Add(opened);
  }
  for (const TopologyEvent& e : events) {
    r.Add(e.version);
    for (const Split& sp : e.splits) {
      r.Add(sp.node);
      r.Add(sp.new_node);
      for (const int32_t t : sp.tets) r.Add(t);
    }
    for (const Move& m : e.moves) {
      r.Add(m.node);
      r.Add(m.rest);
      r.Add(m.world);
    }
    for (const int32_t t : e.touched_tets) r.Add(t);
    for (const int32_t v : e.touched_nodes) r.Add(v);
  }
  return r.h;
}

std::vector<MeshCase> Cases() {
  constexpr double h = 0.01;
  Matrix3d shear;
  shear << 1.1, 0.05, 0.0, 0.0, 0.95, 0.0, 0.0, 0.0, 1.02;
  return {
      {"box", testing::KuhnBox(Vector3d::Zero(), Vector3d(6 * h, 4 * h, 3 * h), 6, 4, 3), Matrix3d::Identity()},
      {"jittered", testing::KuhnBox(Vector3d::Zero(), Vector3d(5 * h, 5 * h, 3 * h), 5, 5, 3, 0.2, 7), shear},
      {"slab", testing::KuhnBox(Vector3d::Zero(), Vector3d(8 * h, 3 * h, 1 * h), 8, 3, 1), Matrix3d::Identity()},
  };
}

TEST(CutStress, RandomPathsKeepEveryInvariant) {
  int total_steps = 0, total_rejected = 0, total_splits = 0, total_limited = 0, total_skipped = 0;
  double cut_seconds = 0.0;
  for (const MeshCase& mc : Cases()) {
    for (uint32_t seed = 1; seed <= 3; ++seed) {
      SCOPED_TRACE(std::string(mc.name) + " seed " + std::to_string(seed));
      CutMesh cm(mc.mesh);
      mesh::TetMesh world_mesh = mc.mesh;
      world_mesh.nodes = (mc.mesh.nodes * mc.A.transpose()).eval();
      VectorWorld world = testing::WorldFromRest(world_mesh);
      const testing::Reference ref(mc.mesh);
      Vector3d lo = world_mesh.nodes.colwise().minCoeff().transpose();
      Vector3d hi = world_mesh.nodes.colwise().maxCoeff().transpose();
      std::mt19937 rng(seed * 7919 + static_cast<uint32_t>(mc.mesh.num_tets()));
      std::uniform_real_distribution<double> u(0.0, 1.0);
      CutParams params;
      params.alpha = 0.3 + 0.4 * u(rng);
      std::vector<TopologyEvent> events;
      // Random strokes per run: a straight chord that bounces off the sides
      // of the top face, then wandering polylines crossing earlier cuts.
      for (int stroke = 0; stroke < 3; ++stroke) {
        const double top = hi.z();
        std::vector<Vector3d> pts;
        Vector3d p(lo.x() + (hi.x() - lo.x()) * u(rng), lo.y() + (hi.y() - lo.y()) * u(rng), top);
        Vector3d dir(std::cos(2.0 * M_PI * u(rng)), std::sin(2.0 * M_PI * u(rng)), 0.0);
        dir.normalize();
        const double step = 0.0015;  // m per frame, ~1/7 of an edge
        for (int i = 0; i < 120; ++i) {
          if (stroke > 0 && i % 20 == 19) {
            const double turn = (u(rng) - 0.5) * 1.5;
            dir = Vector3d(std::cos(turn) * dir.x() - std::sin(turn) * dir.y(),
                           std::sin(turn) * dir.x() + std::cos(turn) * dir.y(), 0.0);
          }
          Vector3d q = p + step * dir;
          // Bounce off the sides of the (affinely deformed) top face.
          for (int a = 0; a < 2; ++a) {
            if (q[a] < lo[a] + 1e-4 || q[a] > hi[a] - 1e-4) {
              dir[a] = -dir[a];
              q = p + step * dir;
            }
          }
          q.z() = top;
          pts.push_back(q);
          p = q;
        }
        const double depth = (0.3 + 1.2 * u(rng)) * (hi.z() - lo.z());
        const auto stats = testing::DrivePath(cm, world, pts, depth, params, &events, [&](int k) {
          testing::ExpectInvariants(cm, world, ref, "step " + std::to_string(k));
          // Affine world: every node keeps world = A·rest (rest preimage of C_p).
          for (int32_t v = 0; v < cm.num_nodes(); ++v) {
            ASSERT_LT((world.Get(v) - mc.A * cm.rest(v)).norm(), 1e-12) << "node " << v;
          }
        });
        if (::testing::Test::HasFatalFailure()) return;
        total_steps += stats.executed;
        total_rejected += stats.rejected;
        total_splits += stats.splits;
        total_limited += stats.moves_limited;
        total_skipped += stats.moves_skipped;
        cut_seconds += stats.cut_seconds;
      }
      Log().info("cut stress {} seed {}: result hash {:016x}", mc.name, seed, HashResult(cm, world, events));
      // Replay reproduces the topology bit-exactly.
      CutMesh replay(mc.mesh);
      for (const TopologyEvent& e : events) replay.ApplyEvent(e);
      ASSERT_TRUE(replay.TetsMatrix() == cm.TetsMatrix());
      for (int32_t v = 0; v < cm.num_nodes(); ++v) ASSERT_TRUE(replay.rest(v) == cm.rest(v));
    }
  }
  Log().info("cut stress: {} executed steps, {} rejected, {} splits, {} moves limited, {} skipped, {:.1f} us/step",
             total_steps, total_rejected, total_splits, total_limited, total_skipped,
             1e6 * cut_seconds / std::max(1, total_steps + total_rejected));
  EXPECT_GE(total_steps, 100);
  EXPECT_LE(total_rejected, total_steps / 10) << "rejections should be rare";
}

}  // namespace
}  // namespace cutsim::cutting
