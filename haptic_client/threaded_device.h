#pragma once
/// @file
/// `ThreadedDevice`: a device whose calls may block (a plugin's `read` or
/// `write_force` waiting on USB, a driver that stalls) run on a thread of
/// their own, so the 1 kHz loop never waits on them.
///
/// * The loop's `SetForce` posts the tick's force (with the tick's time and
///   the model's cut state) to a wait-free mailbox and wakes the device
///   thread; `Read` takes the newest reading from another mailbox. Neither
///   allocates, blocks or throws (transport::Mailbox; the wake-up is a
///   futex wake that never waits).
/// * The device thread, woken by a tick, passes the newest force to the
///   device and then reads it at that tick's time; a slow device skips the
///   ticks it could not serve (only the newest force matters).
/// * Each reading carries the tick it answers. A reading more than
///   `late_ticks` ticks behind the loop is late: the state says so
///   (`DeviceState::late`, the pose the last reading's) and the device
///   guard holds the tool and fades the force. A reading `stuck_ticks`
///   behind says the device is stuck (`DeviceState::stuck`): the loop ends
///   and the station names the device.
/// * `Stop` sends zero force and ends the thread, waiting at most
///   `stop_grace_s`; a thread still inside the device after that is left
///   to finish on its own with the device (which it owns jointly), so a
///   device blocked for good never hangs the station's exit.

#include <atomic>
#include <cstdint>
#include <memory>
#include <thread>

#include <Eigen/Core>

#include "common/transport/mailbox.h"
#include "haptic_client/device.h"

namespace cutsim::haptic_client {

struct ThreadedDeviceOptions {
  int64_t late_ticks = 3;      ///< A reading more ticks behind than this is late.
  int64_t stuck_ticks = 1000;  ///< One this many ticks behind: the device is stuck.
  double stop_grace_s = 0.5;   ///< s, how long Stop waits for the device thread.
  double start_timeout_s = 1.0;  ///< s, how long Start waits for the first reading.
};

/// Counters for the summary and the tests.
struct ThreadedDeviceStats {
  uint64_t io_cycles = 0;      ///< Readings the device thread completed (the first, then force-then-read cycles).
  uint64_t late_ticks = 0;     ///< Ticks whose reading was late.
  uint64_t late_episodes = 0;  ///< Runs of late ticks.
  int64_t max_lag_ticks = 0;   ///< The most ticks a reading was behind.
  bool stuck = false;          ///< A reading fell stuck_ticks behind.
  bool abandoned = false;      ///< Stop left the device thread inside the device.
};

class ThreadedDevice final : public HapticDevice {
 public:
  /// Takes `device` (its Read and SetForce may block; they run on the
  /// device thread only). Throws `InputError` for bad options.
  ThreadedDevice(std::unique_ptr<HapticDevice> device, const ThreadedDeviceOptions& options);
  ~ThreadedDevice() override;
  ThreadedDevice(const ThreadedDevice&) = delete;
  ThreadedDevice& operator=(const ThreadedDevice&) = delete;

  [[nodiscard]] const DeviceInfo& info() const override { return info_; }
  /// Starts the device and the device thread, which reads it first at
  /// `start_ns`; waits for that reading at most `start_timeout_s` (so the
  /// first tick has a pose unless the device is stuck from the start).
  void Start(int64_t start_ns) override;
  void Read(int64_t now_ns, DeviceState* state) noexcept override;
  void SetForce(const Eigen::Vector3d& force) noexcept override;
  void ShowModel(uint64_t cuts, bool contact) noexcept override;
  void Stop() noexcept override;

  /// The wrapped device. Its own counters are safe to read once Stop has
  /// returned without abandoning the thread.
  [[nodiscard]] const HapticDevice& device() const;
  /// Loop-side counters (after the loop) with the device thread's cycles.
  [[nodiscard]] ThreadedDeviceStats stats() const;
  /// Cycles the device thread completed so far (any thread; for readiness
  /// waits in tests).
  [[nodiscard]] uint64_t io_cycles() const;

 private:
  struct Shared;
  /// The device thread: on every wake-up, the newest force to the device,
  /// then a reading at that command's time, until Stop.
  static void DeviceThread(const std::shared_ptr<Shared>& shared, int64_t start_ns);

  std::shared_ptr<Shared> shared_;
  ThreadedDeviceOptions options_;
  DeviceInfo info_;
  std::thread thread_;
  // Loop-side state.
  DeviceState last_;
  int64_t ticks_ = 0;   // SetForce calls so far: the next command's tick
  int64_t now_ns_ = 0;  // the current tick's time
  uint64_t cuts_ = 0;
  bool contact_ = false;
  bool was_late_ = false;
  bool have_reading_ = false;
  bool started_ = false;
  bool stopped_ = false;
  ThreadedDeviceStats stats_;
};

}  // namespace cutsim::haptic_client
