// DeviceGuard: workspace mapping, the clutch, the force clamp and the fade
// of a lost device, against a device whose readings the test sets.
#include <cmath>

#include <gtest/gtest.h>

#include "common/core/error.h"
#include "haptic_client/device_guard.h"

namespace cutsim::haptic_client {
namespace {

constexpr uint32_t kCut = 0x1;
constexpr uint32_t kClutch = 0x2;
constexpr int64_t kMs = 1'000'000;

/// Returns whatever the test put in `next`, records the last force.
class FakeDevice final : public HapticDevice {
 public:
  FakeDevice() {
    info_.name = "fake";
    info_.max_force = 2.0;
    info_.workspace_min = Eigen::Vector3d::Constant(-0.05);
    info_.workspace_max = Eigen::Vector3d::Constant(0.05);
  }
  [[nodiscard]] const DeviceInfo& info() const override { return info_; }
  void Start(int64_t) override {}
  void Read(int64_t, DeviceState* state) noexcept override { *state = next; }
  void SetForce(const Eigen::Vector3d& f) noexcept override { force = f; }
  void Stop() noexcept override {}

  DeviceInfo info_;
  DeviceState next;
  Eigen::Vector3d force = Eigen::Vector3d::Constant(NAN);
};

DeviceState At(double x, double y, double z, uint32_t buttons = kCut) {
  DeviceState s;
  s.pose.tip = {x, y, z};
  s.velocity = {0.1, 0.0, 0.0};
  s.buttons = buttons;
  return s;
}

TEST(DeviceGuard, MapsTheDeviceWorkspaceToTheTissue) {
  FakeDevice device;
  DeviceGuard guard(device, GuardOptions{.scale = 0.5, .offset = {0.01, 0.0, -0.02}});
  EXPECT_TRUE(guard.info().workspace_min.isApprox(Eigen::Vector3d(-0.015, -0.025, -0.045)));
  EXPECT_TRUE(guard.info().workspace_max.isApprox(Eigen::Vector3d(0.035, 0.025, 0.005)));
  device.next = At(0.02, -0.04, 0.01);
  DeviceState s;
  guard.Read(0, &s);
  EXPECT_TRUE(s.pose.tip.isApprox(Eigen::Vector3d(0.02, -0.02, -0.015)));
  EXPECT_NEAR(s.velocity.x(), 0.05, 1e-12);
  EXPECT_EQ(s.buttons, kCut);
}

TEST(DeviceGuard, ClutchMoveDoesNotMoveTheTool) {
  FakeDevice device;
  DeviceGuard guard(device, GuardOptions{.clutch_mask = kClutch});
  DeviceState s;
  device.next = At(0.01, 0.0, 0.0);
  guard.Read(0, &s);
  const Eigen::Vector3d before = s.pose.tip;
  // Clutch held: the hand moves the device 3 cm, the tool stays.
  for (int i = 1; i <= 30; ++i) {
    device.next = At(0.01 + 0.001 * i, 0.0, 0.0, kCut | kClutch);
    guard.Read(i * kMs, &s);
    EXPECT_EQ(s.pose.tip, before) << i;
    EXPECT_EQ(s.velocity, Eigen::Vector3d::Zero());
    EXPECT_EQ(s.buttons & kClutch, 0U);  // the clutch bit never reaches the server
    EXPECT_TRUE(guard.clutched());
  }
  // Released at the new device position: the tool is still where it was ...
  device.next = At(0.04, 0.0, 0.0);
  guard.Read(31 * kMs, &s);
  EXPECT_TRUE(s.pose.tip.isApprox(before)) << s.pose.tip.transpose();
  EXPECT_FALSE(guard.clutched());
  // ... and follows the device's moves from there.
  device.next = At(0.045, 0.002, 0.0);
  guard.Read(32 * kMs, &s);
  EXPECT_TRUE(s.pose.tip.isApprox(before + Eigen::Vector3d(0.005, 0.002, 0.0))) << s.pose.tip.transpose();
  EXPECT_EQ(guard.stats().clutch_engagements, 1U);
}

TEST(DeviceGuard, WithoutAClutchTheButtonMovesTheTool) {
  FakeDevice device;
  DeviceGuard guard(device, GuardOptions{.clutch_mask = 0});
  DeviceState s;
  device.next = At(0.01, 0.0, 0.0, kClutch);
  guard.Read(0, &s);
  device.next = At(0.02, 0.0, 0.0, kClutch);
  guard.Read(kMs, &s);
  EXPECT_NEAR(s.pose.tip.x(), 0.02, 1e-12);
}

TEST(DeviceGuard, ForcesAreClampedToTheDevice) {
  FakeDevice device;
  DeviceGuard guard(device, GuardOptions{});
  DeviceState s;
  device.next = At(0.0, 0.0, 0.0);
  guard.Read(0, &s);
  guard.SetForce(Eigen::Vector3d(3.0, 4.0, 0.0));  // 5 N on a 2 N device
  EXPECT_NEAR(device.force.norm(), 2.0, 1e-12);
  EXPECT_NEAR(device.force.x() / device.force.y(), 0.75, 1e-12);  // direction kept
  guard.SetForce(Eigen::Vector3d(0.0, 1.0, 0.0));
  EXPECT_EQ(device.force, Eigen::Vector3d(0.0, 1.0, 0.0));
  guard.SetForce(Eigen::Vector3d(NAN, 1.0, 0.0));
  EXPECT_EQ(device.force, Eigen::Vector3d::Zero());
  EXPECT_EQ(guard.stats().force_clamped, 1U);
}

TEST(DeviceGuard, InputOnlyDeviceGetsNoForce) {
  FakeDevice device;
  device.info_.max_force = 0.0;
  DeviceGuard guard(device, GuardOptions{});
  guard.SetForce(Eigen::Vector3d(0.5, 0.0, 0.0));
  EXPECT_EQ(device.force, Eigen::Vector3d::Zero());
}

TEST(DeviceGuard, LostDeviceFadesTheForceAndHoldsTheTool) {
  FakeDevice device;
  DeviceGuard guard(device, GuardOptions{.fade_s = 0.05});
  DeviceState s;
  device.next = At(0.01, 0.02, 0.0);
  guard.Read(0, &s);
  const Eigen::Vector3d held = s.pose.tip;
  guard.SetForce(Eigen::Vector3d(0.0, 0.0, 1.5));
  EXPECT_NEAR(device.force.z(), 1.5, 1e-12);
  // Unplugged: the device reports lost (its pose is junk).
  device.next = At(0.3, 0.3, 0.3);
  device.next.lost = true;
  double previous = 1.5;
  for (int i = 1; i <= 80; ++i) {
    guard.Read(i * kMs, &s);
    EXPECT_EQ(s.pose.tip, held);
    EXPECT_EQ(s.velocity, Eigen::Vector3d::Zero());
    EXPECT_EQ(s.buttons, 0U);  // no cutting with a lost device
    guard.SetForce(Eigen::Vector3d(0.0, 0.0, 1.5));  // the renderer still asks for 1.5 N
    const double f = device.force.z();
    EXPECT_LE(f, previous + 1e-12) << "the fade never rises, tick " << i;
    EXPECT_LE(previous - f, 1.5 * 1e-3 / 0.05 + 1e-9) << "a ramp, not a step, tick " << i;
    if (i >= 51) {
      EXPECT_EQ(f, 0.0) << "zero after the fade, tick " << i;
    }
    previous = f;
  }
  EXPECT_TRUE(guard.stats().lost);
  EXPECT_EQ(guard.stats().lost_ns, kMs);
}

TEST(DeviceGuard, RefusesBadSettingsNamingThem) {
  FakeDevice device;
  try {
    DeviceGuard guard(device, GuardOptions{.scale = 0.0});
    FAIL() << "scale 0 accepted";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("scale"), std::string::npos);
  }
  EXPECT_THROW(DeviceGuard(device, GuardOptions{.offset = {NAN, 0.0, 0.0}}), InputError);
  EXPECT_THROW(DeviceGuard(device, GuardOptions{.fade_s = -1.0}), InputError);
}

}  // namespace
}  // namespace cutsim::haptic_client

namespace cutsim::haptic_client {
namespace {

// A late reading: the tool holds, nothing cuts, the force ramps to zero
// over the fade; once readings are on time the force ramps back, and the
// device is not taken as lost.
TEST(DeviceGuard, LateReadingsHoldTheToolAndTheForceRampsDownAndBack) {
  FakeDevice device;
  DeviceGuard guard(device, GuardOptions{.fade_s = 0.01});
  DeviceState s;
  device.next = At(0.01, 0.02, 0.0);
  guard.Read(0, &s);
  const Eigen::Vector3d held = s.pose.tip;
  guard.SetForce(Eigen::Vector3d(0.0, 0.0, 1.5));
  EXPECT_EQ(device.force.z(), 1.5);
  device.next = At(0.03, 0.03, 0.03);
  device.next.late = true;
  double previous = 1.5;
  for (int i = 1; i <= 15; ++i) {
    guard.Read(i * kMs, &s);
    EXPECT_EQ(s.pose.tip, held);
    EXPECT_EQ(s.velocity, Eigen::Vector3d::Zero());
    EXPECT_EQ(s.buttons, 0U);
    guard.SetForce(Eigen::Vector3d(0.0, 0.0, 1.5));
    EXPECT_TRUE(device.force.z() < previous || device.force.z() == 0.0) << "falls until zero, tick " << i;
    EXPECT_LE(previous - device.force.z(), 1.5 * 1e-3 / 0.01 + 1e-9) << "a ramp, tick " << i;
    previous = device.force.z();
  }
  EXPECT_EQ(previous, 0.0);
  device.next.late = false;
  for (int i = 16; i <= 30; ++i) {
    guard.Read(i * kMs, &s);
    guard.SetForce(Eigen::Vector3d(0.0, 0.0, 1.5));
    EXPECT_GE(device.force.z(), previous) << i;
    EXPECT_LE(device.force.z() - previous, 1.5 * 1e-3 / 0.01 + 1e-9) << "a ramp back, tick " << i;
    previous = device.force.z();
  }
  EXPECT_EQ(device.force.z(), 1.5);
  EXPECT_EQ(s.pose.tip, Eigen::Vector3d(0.03, 0.03, 0.03));
  EXPECT_FALSE(guard.stats().lost);
}

}  // namespace
}  // namespace cutsim::haptic_client
