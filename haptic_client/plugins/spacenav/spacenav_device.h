#pragma once
/// @file
/// A 3D mouse (SpaceNavigator and kin) through spacenavd, with libspnav:
/// 6-DoF input, no force (max_force 0; the client renders the force for the
/// screen and the record only).
///
/// The cap's deflection is a velocity command: each axis, divided by
/// `full_scale` counts and clamped to ±1, moves the tip at up to `speed` m/s
/// (translations, the daemon's axes) and turns the blade at up to
/// `turn_speed` rad/s (rotations; the blade starts along +Z). The tip stays
/// inside ±half_extent. Button 0 toggles cutting (bit 0), button 1 is held
/// for the clutch (bit 1).
///
/// libspnav keeps one connection per process, so one spacenav device per
/// process. `socket=PATH` connects to that socket (libspnav's SPNAV_SOCKET)
/// instead of spacenavd's default /var/run/spnav.sock. Reads never block:
/// libspnav polls its socket with a zero timeout; a closed socket (the
/// daemon stopped) reports the device unplugged.

#include <array>
#include <cstdint>
#include <string>

#include "haptic_client/plugin/cutsim_device.h"

namespace cutsim::device_plugins {

struct SpacenavOptions {
  std::string socket;            ///< "" = libspnav's default
  double speed = 0.05;           ///< m/s at full deflection
  double turn_speed = 1.0;       ///< rad/s at full deflection
  double full_scale = 350.0;     ///< counts of a full deflection
  double half_extent = 0.05;     ///< m
  double max_stiffness = 1000.0; ///< N/m reported (the rendered force is not sent)
  double rate_hz = 1000.0;       ///< reported
};

/// Parses `--device-arg` (socket=…,speed=…,turn_speed=…,full_scale=…,
/// half_extent=…); throws `ConfigError` naming the key.
[[nodiscard]] SpacenavOptions ParseSpacenavOptions(const std::string& config);

class SpacenavDevice {
 public:
  /// Connects to spacenavd; throws `std::runtime_error` naming the socket.
  explicit SpacenavDevice(SpacenavOptions options);
  ~SpacenavDevice();
  SpacenavDevice(const SpacenavDevice&) = delete;
  SpacenavDevice& operator=(const SpacenavDevice&) = delete;

  [[nodiscard]] cutsim_device_caps Capabilities() const;
  int Read(int64_t now_ns, cutsim_device_pose* pose) noexcept;
  [[nodiscard]] const char* last_error() const { return error_.data(); }

 private:
  bool Disconnected() noexcept;

  SpacenavOptions options_;
  std::array<double, 6> deflection_{};  // x, y, z, rx, ry, rz in [-1, 1]
  std::array<double, 3> tip_{};
  std::array<double, 3> angle_{};
  uint32_t buttons_ = 0;
  bool have_prev_ = false;
  int64_t prev_ns_ = 0;
  std::array<char, 256> error_{};
};

}  // namespace cutsim::device_plugins
