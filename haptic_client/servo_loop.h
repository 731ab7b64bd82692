#pragma once
/// @file
/// The haptic station's 1 kHz servo loop: on absolute deadlines it reads the
/// device, sends the tool pose, takes the newest local model, renders the
/// force and commands it, and records timing, latency and (optionally) a
/// CSV row. Everything it touches is allocated by the constructor; a tick
/// never allocates, blocks, throws or logs.

#include <array>
#include <atomic>
#include <cstdint>
#include <memory>

#include <Eigen/Core>

#include "common/haptics/haptic_renderer.h"
#include "common/transport/haptic_link.h"
#include "haptic_client/csv_log.h"
#include "haptic_client/device.h"
#include "haptic_client/haptic_app.h"
#include "haptic_client/loop_stats.h"

namespace cutsim::haptic_client {

/// Timing and latency histograms of the loop.
struct LoopTiming {
  Histogram period_us{1.0, 20000};       ///< 1 µs bins to 20 ms.
  Histogram jitter_us{1.0, 20000};       ///< |period − nominal|.
  Histogram lateness_us{1.0, 20000};     ///< Wake-up past the deadline.
  Histogram model_age_ms{0.01, 200000};  ///< 10 µs bins to 2 s.
  /// Device read of a pose → the model computed from it received (LCM thread).
  Histogram pose_to_model_ms{0.01, 200000};
  /// The same, to the first tick that renders that model.
  Histogram pose_to_use_ms{0.01, 200000};
};

class ServoLoop {
 public:
  /// Preallocates everything and, with a CSV path in `options`, starts the
  /// CSV writer thread (throws `FileError` if the file cannot be written).
  ServoLoop(const HapticAppOptions& options, HapticDevice& device, haptics::HapticRenderer& renderer,
            transport::HapticClientLink& link);

  /// Runs until the device is done, the duration passes or `stop` is set;
  /// returns why ("device done", "device stuck", "duration" or "signal").
  const char* Run(const std::atomic<bool>& stop);

  /// Stops the CSV writer and completes the file; returns rows written.
  uint64_t FinishCsv();

  /// A tool pose is sent every `tool_every()` ticks.
  [[nodiscard]] int tool_every() const { return tool_every_; }
  [[nodiscard]] uint64_t ticks() const { return ticks_; }
  /// The first deadline (CLOCK_MONOTONIC ns), once `Run` has started.
  [[nodiscard]] int64_t start_ns() const { return t0_; }
  [[nodiscard]] uint64_t missed_deadlines() const { return missed_; }
  [[nodiscard]] uint64_t csv_dropped() const { return ring_.dropped(); }
  [[nodiscard]] const LoopTiming& timing() const { return timing_; }

 private:
  /// When a tick woke up, relative to its deadline and the previous tick.
  struct Wake {
    int64_t now_ns;
    double dt_s;          ///< Since the previous tick (the nominal period on the first).
    double lateness_us;   ///< Past the deadline.
  };

  Wake MeasureWake(int64_t deadline_ns);
  void SendTool(int64_t now_ns);
  void TakeModel(int64_t now_ns);
  void Record(const Wake& wake, const Eigen::Vector3d& force);
  const char* EndReason(int64_t now_ns, const std::atomic<bool>& stop) const;
  int64_t NextDeadline(int64_t deadline_ns);

  static constexpr size_t kSendRing = 4096;

  HapticDevice& device_;
  haptics::HapticRenderer& renderer_;
  transport::HapticClientLink& link_;
  const int64_t period_ns_;
  const int tool_every_;
  const double duration_s_;
  const bool write_csv_;
  LoopTiming timing_;
  // Send time of each tool pose by seq (mod kSendRing), for the latency of
  // the model that answers it.
  std::array<int64_t, kSendRing> send_ns_{};
  std::array<uint64_t, kSendRing> send_seq_{};
  CsvRing ring_{size_t{1} << 16};  // 65 s at 1 kHz; the writer drains every 50 ms
  std::unique_ptr<CsvWriter> writer_;

  uint64_t ticks_ = 0;
  uint64_t missed_ = 0;
  uint64_t last_epoch_ = 0;
  bool have_model_ = false;
  transport::ReceivedModel received_;
  DeviceState state_;
  int64_t t0_ = 0;
  int64_t end_ns_ = 0;
  int64_t prev_wake_ns_ = 0;
};

}  // namespace cutsim::haptic_client
