#pragma once
/// @file
/// The haptic device interface, shaped like the common haptics toolkits'
/// (OpenHaptics HD, CHAI3D's cGenericHapticDevice, Force Dimension DHD):
/// read position, velocity and buttons once per servo tick, command a force,
/// and publish the device's limits (max force, max stiffness, workspace) so
/// the renderer never asks for more than the hardware can do.
///
/// A vendor driver implements the same four calls: `Start` may block and
/// allocate (open the device, calibrate); `Read` and `SetForce` run inside
/// the 1 kHz loop and must not allocate, block or throw; `Stop` zeroes the
/// force and releases the device. Built in are two virtual devices,
/// `ScriptedDevice` (a tool path) and `ReplayDevice` (a recorded tool
/// stream), and `BrowserDevice` (browser_device.h: a trainee's page);
/// hardware comes through device plugins (plugin/cutsim_device.h, wrapped
/// by `PluginDevice`), whose calls may block and so run on a thread of
/// their own behind `ThreadedDevice` (threaded_device.h). `DeviceGuard` (device_guard.h) sits between
/// any device and the loop: workspace mapping, clutch, force clamp and the
/// fade when a device is lost.

#include <cstdint>
#include <string>

#include <Eigen/Core>

#include "common/core/tool_pose.h"

namespace cutsim::haptic_client {

/// What a device can do.
struct DeviceInfo {
  std::string name;
  double max_force = 8.0;         ///< N, continuous force the device can exert (0: none, input only).
  double max_stiffness = 2000.0;  ///< N/m, stiffest spring it renders stably.
  double max_damping = 20.0;      ///< N·s/m.
  double rate_hz = 0.0;           ///< Highest useful read rate, Hz (0 = any).
  Eigen::Vector3d workspace_min{-0.5, -0.5, -0.5};  ///< m, world-frame box the tip can reach.
  Eigen::Vector3d workspace_max{0.5, 0.5, 0.5};     ///< m.
};

/// One reading of the device.
struct DeviceState {
  ToolPose pose;                                       ///< The tool in the world frame.
  Eigen::Vector3d velocity = Eigen::Vector3d::Zero();  ///< m/s, of the tip.
  uint32_t buttons = 0;  ///< bit 0: cutting enabled; bit 1: clutch (by default).
  bool done = false;     ///< A virtual device's script has ended (a real one: never).
  /// The device stopped answering (unplugged): `pose` is the last good one.
  bool lost = false;
  /// The reading is older than the device's deadline (a device on its own
  /// thread, threaded_device.h, that did not keep up): `pose` is the last
  /// reading's; the guard holds the tool and fades the force.
  bool late = false;
  /// No reading for so long that the device counts as stuck: the loop ends.
  bool stuck = false;
};

class HapticDevice {
 public:
  virtual ~HapticDevice() = default;
  [[nodiscard]] virtual const DeviceInfo& info() const = 0;
  /// Before the loop, with the loop's start time (CLOCK_MONOTONIC ns).
  virtual void Start(int64_t start_ns) = 0;
  /// Servo tick: the state at `now_ns`. No allocation, blocking or throwing.
  virtual void Read(int64_t now_ns, DeviceState* state) noexcept = 0;
  /// Servo tick: the force to exert on the user's hand, N. Same rules as Read.
  virtual void SetForce(const Eigen::Vector3d& force) noexcept = 0;
  /// Servo tick, after SetForce, once a model has arrived: the model's cut
  /// count and contact, for a device that shows them (the browser's page).
  /// Same rules as Read; by default nothing.
  virtual void ShowModel(uint64_t /*cuts*/, bool /*contact*/) noexcept {}
  /// After the loop: zero force, release the device.
  virtual void Stop() noexcept = 0;
};

}  // namespace cutsim::haptic_client
