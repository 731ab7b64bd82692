#pragma once
/// @file
/// `DeviceGuard`: what stands between any device and the servo loop, so the
/// same safety holds for the built-in devices and every plugin.
///
/// * Workspace: tool = scale · device + offset (per scene or per device,
///   the CLI overriding the scene). The blade direction is not scaled.
/// * Clutch: while the clutch button is held the tool holds its pose and
///   the device moves freely; on release the offset takes up the difference,
///   so the tool continues from where it was held.
/// * Force: clamped to the device's `max_force` (a device with 0 gets no
///   force at all: the force is rendered, recorded and reported only).
/// * Lost device: when a read reports the device gone, the tool holds its
///   last pose with cutting off and the commanded force fades linearly to
///   zero over `fade_s`; the session goes on.
/// * Late device: while a reading is late (`DeviceState::late`: a device on
///   its own thread that did not keep up) the tool holds its last pose with
///   cutting off and the force fades toward zero at the same rate (full to
///   zero over `fade_s`); once readings are on time again it comes back at
///   that rate, so neither the hold nor its end is a jolt.
///
/// Everything is preallocated; `Read` and `SetForce` are O(1), never
/// allocate, block or throw.

#include <cstdint>

#include <Eigen/Core>

#include "haptic_client/device.h"

namespace cutsim::haptic_client {

struct GuardOptions {
  double scale = 1.0;                                ///< Tissue metres per device metre (> 0).
  Eigen::Vector3d offset = Eigen::Vector3d::Zero();  ///< m, tissue frame.
  uint32_t clutch_mask = 0x2;                        ///< Button bit(s) of the clutch; 0 = no clutch.
  double fade_s = 0.05;                              ///< s, force ramp to zero when the device is lost.
};

/// Counters for the summary and the tests.
struct GuardStats {
  uint64_t clutch_engagements = 0;
  uint64_t force_clamped = 0;  ///< Ticks whose force exceeded max_force.
  bool lost = false;
  int64_t lost_ns = 0;         ///< When the device was lost (CLOCK_MONOTONIC ns).
};

class DeviceGuard final : public HapticDevice {
 public:
  /// Throws `InputError` naming the field for a bad scale, offset or fade.
  DeviceGuard(HapticDevice& device, const GuardOptions& options);

  /// The device's limits, its workspace mapped to the tissue frame.
  [[nodiscard]] const DeviceInfo& info() const override { return info_; }
  void Start(int64_t start_ns) override;
  void Read(int64_t now_ns, DeviceState* state) noexcept override;
  void SetForce(const Eigen::Vector3d& force) noexcept override;
  void ShowModel(uint64_t cuts, bool contact) noexcept override { device_.ShowModel(cuts, contact); }
  void Stop() noexcept override { device_.Stop(); }

  [[nodiscard]] const GuardStats& stats() const { return stats_; }
  /// The force last passed to the device, N (after clamp and fade).
  [[nodiscard]] const Eigen::Vector3d& device_force() const { return device_force_; }
  [[nodiscard]] bool clutched() const { return clutched_; }
  /// The factor on the force from late readings, in [0, 1].
  [[nodiscard]] double late_gain() const { return late_gain_; }

 private:
  HapticDevice& device_;
  GuardOptions options_;
  DeviceInfo info_;
  DeviceState raw_;
  ToolPose tool_;          // the last tool pose handed to the loop
  bool have_tool_ = false;
  bool clutched_ = false;
  int64_t now_ns_ = 0;
  Eigen::Vector3d device_force_ = Eigen::Vector3d::Zero();
  double late_gain_ = 1.0;  // scales the force: falls while readings are late, recovers after
  GuardStats stats_;
};

}  // namespace cutsim::haptic_client
