#pragma once
/// @file
/// A Linux input device (evdev) as a haptic device: the tip from absolute
/// axes, buttons from keys, force out through the kernel's force-feedback
/// interface. All kernel calls go through `EvdevSys` (evdev_sys.h).
///
/// * Pose: ABS_X/Y/Z map linearly from each axis's absinfo [minimum,
///   maximum] to [-half_extent, +half_extent] m (an absent Z stays at 0).
///   ABS_RX/RY/RZ, where present, map from [minimum, maximum] to
///   ±angle_span/2 rad and turn the blade from +Z (about X, then Y, then Z).
///   Velocity: the finite difference of the tip between reads, low-passed.
/// * Buttons: bit i is set while the i-th code of `keys` is down.
/// * Force: where the device has FF_CONSTANT, one constant effect is uploaded
///   (EVIOCSFF) and played (EV_FF write) at open; `WriteForce` updates its
///   level and direction from the force's X/Y components (the kernel's
///   constant effect is planar), at most `ff_rate_hz` times a second and only
///   when it changed. Without FF_CONSTANT the device reports max_force 0.
/// * The descriptor is O_NONBLOCK: `Read` drains what the kernel has and
///   returns; ENODEV or EOF means unplugged. Neither `Read` nor `WriteForce`
///   allocates.

#include <linux/input.h>

#include <array>
#include <cstdint>
#include <string>
#include <vector>

#include "haptic_client/plugin/cutsim_device.h"
#include "haptic_client/plugins/evdev/evdev_sys.h"

namespace cutsim::device_plugins {

struct EvdevOptions {
  std::string path;                   ///< /dev/input/eventN (required)
  double half_extent = 0.05;          ///< m, workspace ±half_extent on each axis
  double angle_span = 3.14159265358979;  ///< rad, full travel of a rotation axis
  double max_force = 1.0;             ///< N at the full effect level (0x7fff)
  double ff_rate_hz = 100.0;          ///< Effect updates per second at most
  double max_stiffness = 300.0;       ///< N/m reported
  double max_damping = 2.0;           ///< N·s/m reported
  double rate_hz = 1000.0;            ///< reported
  double velocity_cutoff_hz = 30.0;   ///< low-pass of the tip velocity
  /// Key codes of button bits 0, 1, …: default BTN_TRIGGER (cut), BTN_THUMB (clutch).
  std::vector<int> keys{BTN_TRIGGER, BTN_THUMB};
};

/// Parses `--device-arg` (path=…,half_extent=…,max_force=…,ff_rate_hz=…,
/// keys=288:289,…); throws `ConfigError` naming the key.
[[nodiscard]] EvdevOptions ParseEvdevOptions(const std::string& config);

class EvdevDevice {
 public:
  /// Opens and inspects the device; throws `std::runtime_error` naming the
  /// path and what is missing or failed.
  EvdevDevice(const EvdevSys& sys, EvdevOptions options);
  /// Stops and removes the effect and closes the descriptor.
  ~EvdevDevice();
  EvdevDevice(const EvdevDevice&) = delete;
  EvdevDevice& operator=(const EvdevDevice&) = delete;

  [[nodiscard]] cutsim_device_caps Capabilities() const;
  /// CUTSIM_DEVICE_OK, CUTSIM_DEVICE_UNPLUGGED or CUTSIM_DEVICE_ERROR.
  int Read(int64_t now_ns, cutsim_device_pose* pose) noexcept;
  int WriteForce(int64_t now_ns, const double force[3]) noexcept;
  [[nodiscard]] const char* last_error() const { return error_.data(); }

  [[nodiscard]] bool has_ff() const { return effect_id_ >= 0; }
  [[nodiscard]] int effect_id() const { return effect_id_; }
  [[nodiscard]] uint64_t effect_updates() const { return effect_updates_; }

 private:
  struct Axis {
    bool present = false;
    int32_t minimum = 0;
    int32_t maximum = 0;
    int32_t value = 0;
  };
  static constexpr int kAxes = 6;  // X, Y, Z, RX, RY, RZ

  void Inspect();
  void QueryAxes();
  void StartEffect();
  bool UploadEffect(int16_t level, uint16_t direction) noexcept;
  void HandleEvent(const input_event& e) noexcept;
  void Resync() noexcept;
  void Fill(int64_t now_ns, cutsim_device_pose* pose) noexcept;
  int Fail(int code, const char* what, int err) noexcept;

  const EvdevSys& sys_;
  EvdevOptions options_;
  int fd_ = -1;
  bool writable_ = false;
  std::array<Axis, kAxes> axes_{};
  uint32_t buttons_ = 0;
  int effect_id_ = -1;
  int16_t level_ = 0;
  uint16_t direction_ = 0;
  int64_t last_upload_ns_ = 0;
  uint64_t effect_updates_ = 0;
  bool have_prev_ = false;
  int64_t prev_ns_ = 0;
  std::array<double, 3> prev_tip_{};
  std::array<double, 3> velocity_{};
  std::array<input_event, 64> events_{};
  std::array<char, 256> error_{};
};

}  // namespace cutsim::device_plugins
