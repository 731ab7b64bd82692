#pragma once
/// @file
/// The device part of cutsim-haptic-loop-bench (`--devices`): a paced 1 kHz
/// loop that reads each device and commands a force every tick (jitter, and
/// the time the device calls take), and a tight loop of the same calls that
/// gives the cost of one tick's device calls for a built-in virtual device,
/// the same device behind the plugin C ABI, and both behind DeviceGuard.

#include <filesystem>
#include <string>

namespace cutsim::haptic_client {

struct DeviceBenchOptions {
  double seconds = 3.0;              ///< s of paced loop per device
  double rate = 1000.0;              ///< Hz
  long calls = 2'000'000;            ///< calls of the tight loop
  std::filesystem::path plugin_dir;  ///< where libcutsim_device_example_spring.so is
  std::filesystem::path work_dir;    ///< for the replay device's LCM log
};

/// Runs the benchmark and returns one JSON object (kind "device_loop_bench").
[[nodiscard]] std::string RunDeviceBench(const DeviceBenchOptions& options);

}  // namespace cutsim::haptic_client
