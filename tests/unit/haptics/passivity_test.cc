#include "common/haptics/passivity.h"

#include <algorithm>
#include <cmath>
#include <numbers>
#include <vector>

#include <gtest/gtest.h>

#include "common/haptics/haptic_renderer.h"
#include "tests/unit/haptics/test_models.h"

namespace cutsim::haptics {
namespace {

using testing::kNsPerMs;
using testing::Lcg;
using testing::WallModel;

TEST(PassivityControllerTest, ObserverSignConvention) {
  PassivityController pc(PassivityConfig{.enabled = false});
  // The user pushes into a resisting force: energy flows into the environment.
  pc.Observe(Eigen::Vector3d(0, 0, 2.0), Eigen::Vector3d(0, 0, -0.1), 1e-3);
  EXPECT_NEAR(pc.observed_energy(), 2e-4, 1e-18);
  // The environment pushes the tool along its motion: it gives energy back.
  pc.Observe(Eigen::Vector3d(0, 0, 2.0), Eigen::Vector3d(0, 0, 0.3), 1e-3);
  EXPECT_NEAR(pc.observed_energy(), -4e-4, 1e-18);
  EXPECT_NEAR(pc.min_observed_energy(), -4e-4, 1e-18);
}

TEST(PassivityControllerTest, DamperCancelsExactlyTheExcessEnergy) {
  PassivityController pc;
  const Eigen::Vector3d v(0.05, 0, 0.1);
  const double dt = 1e-3;
  pc.Observe(Eigen::Vector3d(0, 0, 1.0), Eigen::Vector3d(0, 0, -0.1), dt);  // E = 1e-4 J credit
  const Eigen::Vector3d active(0, 0, 3.0);  // would deliver 3e-4 J this tick
  const Eigen::Vector3d f = pc.Control(active, v, dt);
  EXPECT_GT(pc.last_damping(), 0.0);
  EXPECT_LT((f - (active - pc.last_damping() * v)).norm(), 1e-15);
  pc.Observe(f, v, dt);
  EXPECT_NEAR(pc.observed_energy(), 0.0, 1e-15);
  EXPECT_NEAR(pc.dissipated_energy(), 2e-4, 1e-15);
  // A passive force passes unchanged.
  const Eigen::Vector3d resisting(0, 0, -1.0);
  EXPECT_EQ(pc.Control(resisting, v, dt), resisting);
  EXPECT_EQ(pc.last_damping(), 0.0);
  // No motion, no damping (α ∝ 1/|v|² would be unbounded).
  EXPECT_EQ(pc.Control(active, Eigen::Vector3d::Zero(), dt), active);
}

// A stiff wall (z ≤ 0) simulated by a 100 Hz server that sees the tool 25 ms
// late; its models reach the 1 kHz client another 25 ms ± 10 ms later (so
// some arrive out of order and are dropped). The models carry only 20 % of
// the wall's stiffness, so most of the force is a 50 ms-old spring force:
// an active environment.
struct DelayedWall {
  static constexpr double kWall = 2000.0;     // N/m
  static constexpr double kFraction = 0.2;
  static constexpr int64_t kUplinkNs = 25 * kNsPerMs;
  static constexpr int64_t kDownlinkNs = 25 * kNsPerMs;
  static constexpr int64_t kJitterNs = 10 * kNsPerMs;
  static constexpr int64_t kFrameNs = 10 * kNsPerMs;

  struct Pending {
    int64_t arrive_ns;
    LocalModel model;
  };
  std::vector<Pending> in_flight;
  std::vector<Eigen::Vector3d> tool_history;  // tool position at each 1 ms tick
  uint64_t seq = 0;
  Lcg rng{12345};

  // Called once per 1 ms tick before rendering; `now_ns` is a multiple of 1 ms.
  void Step(int64_t now_ns, const Eigen::Vector3d& tool, HapticRenderer& renderer) {
    tool_history.push_back(tool);
    if (now_ns % kFrameNs == 0) {
      const int64_t seen_ns = std::max<int64_t>(0, now_ns - kUplinkNs);
      const Eigen::Vector3d seen = tool_history[static_cast<size_t>(seen_ns / kNsPerMs)];
      const auto jitter = static_cast<int64_t>((2.0 * rng.Next() - 1.0) * static_cast<double>(kJitterNs));
      in_flight.push_back({now_ns + kDownlinkNs + jitter, WallModel(++seq, seen, kWall, kFraction)});
    }
    // Deliver in arrival order.
    std::sort(in_flight.begin(), in_flight.end(),
              [](const Pending& a, const Pending& b) { return a.arrive_ns < b.arrive_ns; });
    size_t delivered = 0;
    while (delivered < in_flight.size() && in_flight[delivered].arrive_ns <= now_ns) {
      renderer.SetModel(in_flight[delivered].model, in_flight[delivered].arrive_ns);
      ++delivered;
    }
    in_flight.erase(in_flight.begin(), in_flight.begin() + static_cast<std::ptrdiff_t>(delivered));
  }
};

struct PrescribedResult {
  RendererStats stats;
  double max_force = 0.0;
  bool all_finite = true;
};

// The user moves the tool in and out of the wall on a prescribed path (2 Hz,
// 3 mm deep, with some sideways motion) for 5 s.
PrescribedResult RunPrescribed(bool passivity_on) {
  RendererConfig config;
  config.passivity.enabled = passivity_on;
  HapticRenderer renderer(config);
  DelayedWall wall;
  PrescribedResult result;
  const double w = 2.0 * std::numbers::pi * 2.0;  // rad/s
  for (int i = 1; i <= 5000; ++i) {
    const int64_t now_ns = i * kNsPerMs;
    const double t = 1e-3 * i;
    const Eigen::Vector3d x(0.004 * std::sin(0.7 * w * t), 0.0, 0.001 - 0.002 * (1.0 - std::cos(w * t)));
    const Eigen::Vector3d v(0.004 * 0.7 * w * std::cos(0.7 * w * t), 0.0, -0.002 * w * std::sin(w * t));
    wall.Step(now_ns, x, renderer);
    const Eigen::Vector3d f = renderer.Tick(x, v, now_ns, 1e-3);
    result.all_finite = result.all_finite && f.allFinite();
    result.max_force = std::max(result.max_force, f.norm());
  }
  result.stats = renderer.stats();
  return result;
}

TEST(PassivityTest, DelayedWallGeneratesEnergyWithoutTheController) {
  const PrescribedResult off = RunPrescribed(false);
  EXPECT_TRUE(off.all_finite);
  EXPECT_GT(off.stats.models_stale, 0u);  // jitter reordered some models
  EXPECT_EQ(off.stats.watchdog_trips, 0u);
  // The environment delivered net energy to the user: active.
  EXPECT_LT(off.stats.observed_energy, -5e-3);
  EXPECT_LT(off.stats.min_observed_energy, -5e-3);
  EXPECT_EQ(off.stats.passivity_dissipated, 0.0);
}

TEST(PassivityTest, ControllerKeepsTheDevicePortPassive) {
  const PrescribedResult off = RunPrescribed(false);
  const PrescribedResult on = RunPrescribed(true);
  EXPECT_TRUE(on.all_finite);
  // Never net generated energy (to round-off of the energy sum), even with
  // the rate limit active, thanks to the braking reserve.
  EXPECT_GE(on.stats.min_observed_energy, -1e-12);
  EXPECT_GE(on.stats.observed_energy, -1e-12);
  EXPECT_GT(on.stats.passivity_dissipated, 0.0);
  // The damper removes what the uncontrolled environment generated.
  EXPECT_GE(on.stats.passivity_dissipated, 0.99 * -off.stats.observed_energy);
  EXPECT_LE(on.max_force, 8.0 + 1e-12);
  EXPECT_LE(on.stats.max_force_step, 2000.0 * 1e-3 + 1e-12);
}

struct CoupledResult {
  double late_speed_peak = 0.0;  // m/s, largest |v| in the last second
  double max_force = 0.0;        // N
  RendererStats stats;
};

// A hand (0.3 kg effective mass with the device, 2 N·s/m) pressed onto the
// delayed wall with a constant 2 N: the loop is unstable without the PC.
CoupledResult RunCoupled(bool passivity_on) {
  RendererConfig config;
  config.passivity.enabled = passivity_on;
  HapticRenderer renderer(config);
  DelayedWall wall;
  constexpr double kMass = 0.3;          // kg
  constexpr double kHandDamping = 2.0;  // N·s/m
  const Eigen::Vector3d user_force(0, 0, -2.0);  // N
  Eigen::Vector3d x(0, 0, 0.002);
  Eigen::Vector3d v = Eigen::Vector3d::Zero();
  CoupledResult result;
  for (int i = 1; i <= 6000; ++i) {
    const int64_t now_ns = i * kNsPerMs;
    wall.Step(now_ns, x, renderer);
    const Eigen::Vector3d f = renderer.Tick(x, v, now_ns, 1e-3);
    result.max_force = std::max(result.max_force, f.norm());
    // Semi-implicit Euler for the hand.
    v += 1e-3 * (f + user_force - kHandDamping * v) / kMass;
    x += 1e-3 * v;
    if (i > 5000) result.late_speed_peak = std::max(result.late_speed_peak, v.norm());
  }
  result.stats = renderer.stats();
  return result;
}

TEST(PassivityTest, ControllerStabilisesAHandOnTheDelayedWall) {
  const CoupledResult off = RunCoupled(false);
  const CoupledResult on = RunCoupled(true);
  // Without PC the environment pumps joules into the hand, which keeps
  // bouncing; with it the bouncing is an order of magnitude slower.
  EXPECT_LT(off.stats.min_observed_energy, -1.0);
  EXPECT_GT(off.late_speed_peak, 0.5);
  EXPECT_LT(on.late_speed_peak, 0.1 * off.late_speed_peak);
  // A bounce reverses v within a tick, faster than the rate-limited force can
  // follow, so a transient deficit of < 1 mJ (vs > 1 J without PC) can occur;
  // the PC recovers it (observed: −0.15 mJ, final E_obs ≥ 0).
  EXPECT_GE(on.stats.min_observed_energy, -1e-3);
  EXPECT_GE(on.stats.observed_energy, -1e-6);
  EXPECT_LE(on.max_force, 8.0 + 1e-12);
  EXPECT_GT(on.stats.passivity_dissipated, 0.0);
}

}  // namespace
}  // namespace cutsim::haptics
