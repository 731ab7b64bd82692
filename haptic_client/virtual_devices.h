#pragma once
/// @file
/// Virtual devices for runs without hardware. Both are position sources
/// without dynamics: the tip follows the script exactly and the commanded
/// force is only recorded (the loop writes it to the CSV), which is what a
/// stiff, well-held real stylus approximates.

#include <cstdint>
#include <filesystem>
#include <string>
#include <vector>

#include "common/core/tool_pose.h"
#include "common/haptics/tool_path.h"
#include "haptic_client/device.h"

namespace cutsim::haptic_client {

/// Follows a tool path (common/haptics/tool_path.h) in real time, with the
/// minimum-jerk speed profile between keyframes (human-like: zero velocity
/// and acceleration at each keyframe). `done` once the path's end time is
/// reached. Buttons: bit 0 (cutting enabled) always set.
class ScriptedDevice final : public HapticDevice {
 public:
  ScriptedDevice(haptics::ToolPath path, DeviceInfo info,
                 haptics::PathTiming timing = haptics::PathTiming::kMinimumJerk);
  [[nodiscard]] const DeviceInfo& info() const override { return info_; }
  void Start(int64_t start_ns) override { start_ns_ = start_ns; }
  void Read(int64_t now_ns, DeviceState* state) noexcept override;
  void SetForce(const Eigen::Vector3d& force) noexcept override { force_ = force; }
  void Stop() noexcept override { force_.setZero(); }
  [[nodiscard]] const Eigen::Vector3d& force() const { return force_; }

 private:
  haptics::ToolPath path_;
  DeviceInfo info_;
  haptics::PathTiming timing_;
  int64_t start_ns_ = 0;
  Eigen::Vector3d force_ = Eigen::Vector3d::Zero();
};

/// One recorded tool pose.
struct ReplaySample {
  double t = 0.0;  ///< s since the first recorded pose.
  ToolPose pose;
  Eigen::Vector3d velocity = Eigen::Vector3d::Zero();  ///< m/s, of the tip.
  uint32_t buttons = 0;                                ///< bit 0: cutting enabled.
};

/// Replays the tool stream of an LCM log (`lcm-logger` or the server's
/// recorder) at the recorded timing: events on `channel`
/// (CUTSIM_<session>_TOOL) decoded as ToolState, in log order, dropping
/// undecodable, non-finite and out-of-order (by seq) ones. The tip is
/// interpolated linearly between recorded poses; the velocity is the
/// recorded one. `done` after the last pose.
class ReplayDevice final : public HapticDevice {
 public:
  /// Reads the whole log (before the loop). Throws `InputError` naming the
  /// file if it cannot be read or has no usable pose on `channel`.
  ReplayDevice(const std::filesystem::path& log, const std::string& channel, DeviceInfo info);
  [[nodiscard]] const DeviceInfo& info() const override { return info_; }
  void Start(int64_t start_ns) override {
    start_ns_ = start_ns;
    cursor_ = 0;
  }
  void Read(int64_t now_ns, DeviceState* state) noexcept override;
  void SetForce(const Eigen::Vector3d& force) noexcept override { force_ = force; }
  void Stop() noexcept override { force_.setZero(); }
  [[nodiscard]] const std::vector<ReplaySample>& samples() const { return samples_; }
  [[nodiscard]] double duration() const { return samples_.empty() ? 0.0 : samples_.back().t; }

 private:
  std::vector<ReplaySample> samples_;
  DeviceInfo info_;
  int64_t start_ns_ = 0;
  size_t cursor_ = 0;  // index of the last sample at or before the current time
  Eigen::Vector3d force_ = Eigen::Vector3d::Zero();
};

}  // namespace cutsim::haptic_client
