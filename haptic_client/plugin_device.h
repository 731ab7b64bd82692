#pragma once
/// @file
/// `HapticDevice` over the device plugin C ABI (plugin/cutsim_device.h): the
/// servo loop, force limits, watchdog and passivity controller treat a
/// plugin like any built-in device.

#include <cstdint>
#include <memory>
#include <string>

#include "haptic_client/device.h"
#include "haptic_client/plugin/cutsim_device.h"
#include "haptic_client/plugin_loader.h"

namespace cutsim::haptic_client {

/// Checks a plugin's capabilities (finite, positive, within the limits of
/// any real desktop device) and converts them; throws `InputError` naming
/// `source` (the plugin path) and the field.
[[nodiscard]] DeviceInfo CheckCapabilities(const cutsim_device_caps& caps, const std::string& name,
                                           const std::string& source);

/// Counters of the plugin's calls.
struct PluginDeviceStats {
  uint64_t reads = 0;
  uint64_t read_errors = 0;   ///< CUTSIM_DEVICE_ERROR from read (the last pose was held).
  uint64_t bad_poses = 0;     ///< Non-finite or zero-length values (the last pose was held).
  uint64_t write_errors = 0;  ///< Failed write_force calls.
  bool unplugged = false;     ///< read said CUTSIM_DEVICE_UNPLUGGED.
  int64_t unplugged_ns = 0;   ///< When (CLOCK_MONOTONIC ns).
};

class PluginDevice final : public HapticDevice {
 public:
  /// Opens the device with `config` (`--device-arg`) and checks its
  /// capabilities; throws `InputError` naming the plugin path on failure.
  PluginDevice(std::unique_ptr<PluginLibrary> library, const std::string& config);
  ~PluginDevice() override;
  PluginDevice(const PluginDevice&) = delete;
  PluginDevice& operator=(const PluginDevice&) = delete;

  [[nodiscard]] const DeviceInfo& info() const override { return info_; }
  void Start(int64_t start_ns) override { now_ns_ = start_ns; }
  void Read(int64_t now_ns, DeviceState* state) noexcept override;
  void SetForce(const Eigen::Vector3d& force) noexcept override;
  void Stop() noexcept override;

  [[nodiscard]] const PluginDeviceStats& stats() const { return stats_; }
  /// The plugin's last error message (outside the loop only).
  [[nodiscard]] std::string last_error() const;
  [[nodiscard]] const std::string& path() const { return library_->path(); }

 private:
  std::unique_ptr<PluginLibrary> library_;
  const cutsim_device_api& api_;
  cutsim_device* device_ = nullptr;
  DeviceInfo info_;
  DeviceState last_;  // the last good reading
  int64_t now_ns_ = 0;
  bool stopped_ = false;
  PluginDeviceStats stats_;
};

}  // namespace cutsim::haptic_client
