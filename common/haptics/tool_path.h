#pragma once
/// @file
/// The tool path format: keyframes of time and tool pose (tip position and
/// blade direction).
/// One format for headless scenes and for the haptic client's scripted device
/// (documented in scenes/README.md):
///
///     # comment
///     # t[s]   tip x y z [m]          blade direction x y z (tip → handle)
///     0.00     0.000 0.010 0.030      0 0 1
///     0.50     0.000 0.010 0.018      0 0 1
///
/// Times increase strictly; directions are normalised on load (zero is an
/// error). Between keyframes the tip moves along the straight segment; the
/// timing inside a segment is linear or minimum-jerk (a human-like speed
/// profile: zero velocity and acceleration at each keyframe).

#include <cstdint>
#include <filesystem>
#include <string>
#include <vector>

#include <Eigen/Core>

#include "common/core/tool_pose.h"

namespace cutsim::haptics {

/// Largest |t| of a keyframe, s (one day): a path cannot make a run endless.
inline constexpr double kMaxToolPathSeconds = 86400.0;
/// Largest tool path file, bytes (64 MiB).
inline constexpr uint64_t kMaxToolPathBytes = uint64_t{64} << 20;

/// A keyframe of a tool path: a pose and the time the tool reaches it.
struct ToolKeyframe {
  double t = 0.0;  ///< s
  ToolPose pose;   ///< Blade direction normalised on load.
};

/// Timing inside a segment between two keyframes.
enum class PathTiming { kLinear, kMinimumJerk };

class ToolPath {
 public:
  ToolPath() = default;
  /// Throws InputError naming `source_name` and the keyframe when times do not
  /// increase or a direction is zero/non-finite.
  explicit ToolPath(std::vector<ToolKeyframe> keyframes, const std::string& source_name = "tool path");

  /// Reads the text format above; errors name file:line.
  static ToolPath Read(const std::filesystem::path& path);
  static ToolPath Parse(const std::string& text, const std::string& source_name);
  /// Writes the text format (atomically: temp file then rename).
  void Write(const std::filesystem::path& path) const;

  [[nodiscard]] bool empty() const { return keyframes_.empty(); }
  [[nodiscard]] double start_time() const { return empty() ? 0.0 : keyframes_.front().t; }
  [[nodiscard]] double end_time() const { return empty() ? 0.0 : keyframes_.back().t; }
  [[nodiscard]] const std::vector<ToolKeyframe>& keyframes() const { return keyframes_; }

  /// Pose at time t (clamped to the path's ends). Does not allocate.
  [[nodiscard]] ToolPose Sample(double t, PathTiming timing = PathTiming::kLinear) const;

 private:
  std::vector<ToolKeyframe> keyframes_;
};

}  // namespace cutsim::haptics
