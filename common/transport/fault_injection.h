#pragma once
/// @file
/// Network fault injection for the haptic link. This machine's kernel has no
/// `netem`, so the link itself can delay, jitter, drop, duplicate and reorder
/// messages, seeded and reproducible, for tests and demos.
///
/// `FaultInjector` is the core: a bounded, preallocated schedule of byte
/// payloads. `Submit` draws the message's fate (drop, extra copy, delay =
/// delay + U[0, jitter], plus `reorder_ms` with probability `reorder` so that
/// later messages overtake it); `Release(now)` hands every message whose time
/// has come to a sink, earliest first. Jitter alone also reorders (as a real
/// network with jitter does); `reorder` forces it even without jitter.
///
/// Who releases delayed messages: the caller's poll. `LcmBus` is owned by one
/// thread, so a separate scheduler thread could not publish on it; instead the
/// owner calls `Poll`/`Release` from its loop (the haptic client's LCM thread
/// runs every ≤ 1 ms, `HapticServerLink` on every `PollTool` and
/// `PublishModel`), so a message leaves at most one poll period after its due
/// time. Use `next_due_ns()` to bound a wait.
///
/// Nothing here allocates after construction or throws from `Submit`,
/// `Release` or `Poll`. Not thread-safe: one owner thread.

#include <array>
#include <cstddef>
#include <cstdint>
#include <limits>
#include <span>
#include <string>
#include <string_view>
#include <vector>

#include <google/protobuf/message_lite.h>

#include "common/transport/codec.h"
#include "common/transport/lcm_bus.h"

namespace cutsim::transport {

/// What to do to a stream of messages. All zero = pass-through.
struct FaultConfig {
  double delay_ms = 0.0;     ///< ms, fixed one-way delay (`--fault-delay-ms`).
  double jitter_ms = 0.0;    ///< ms, extra delay drawn uniformly from [0, jitter] (`--fault-jitter-ms`).
  double drop = 0.0;         ///< Probability a message is lost (`--fault-drop`).
  double duplicate = 0.0;    ///< Probability a message is sent twice, each copy with its own delay (`--fault-dup`).
  double reorder = 0.0;      ///< Probability a message is held back `reorder_ms` more (`--fault-reorder`).
  double reorder_ms = 10.0;  ///< ms, the hold-back of a reordered message (`--fault-reorder-ms`).
  uint64_t seed = 1;         ///< Random seed (`--fault-seed`); the same seed gives the same fates.

  /// True if any fault is configured.
  [[nodiscard]] bool active() const {
    return delay_ms > 0.0 || jitter_ms > 0.0 || drop > 0.0 || duplicate > 0.0 || reorder > 0.0;
  }
};

/// Throws `InputError` naming the flag (`<prefix>delay-ms`, ...) for
/// out-of-range values: negative times, probabilities outside [0, 1],
/// delays above 10 s.
void ValidateFaultConfig(const FaultConfig& config, std::string_view flag_prefix = "--fault-");

/// One line for logs ("delay 50 ms + U[0, 5] ms, drop 10%, ...").
[[nodiscard]] std::string Describe(const FaultConfig& config);

/// Counters of one injector.
struct FaultStats {
  uint64_t submitted = 0;   ///< Messages offered.
  uint64_t dropped = 0;     ///< Lost on purpose.
  uint64_t duplicated = 0;  ///< Extra copies scheduled.
  uint64_t reordered = 0;   ///< Held back by `reorder_ms`.
  uint64_t overflow = 0;    ///< Lost because the schedule was full (or the message too large).
  uint64_t released = 0;    ///< Handed to the sink.
  int64_t min_delay_ns = 0; ///< Shortest scheduled delay (0 before any).
  int64_t max_delay_ns = 0; ///< Longest scheduled delay.
  double sum_delay_ns = 0.0;  ///< Σ scheduled delays, for the mean.
};

/// A small deterministic generator (SplitMix64): the same seed gives the same
/// sequence on every platform, unlike std::uniform_real_distribution.
class SplitMix64 {
 public:
  explicit SplitMix64(uint64_t seed) : state_(seed) {}
  uint64_t Next() noexcept {
    uint64_t z = (state_ += 0x9E3779B97F4A7C15ULL);
    z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ULL;
    z = (z ^ (z >> 27)) * 0x94D049BB133111EBULL;
    return z ^ (z >> 31);
  }
  /// Uniform in [0, 1).
  double Uniform() noexcept { return static_cast<double>(Next() >> 11) * 0x1.0p-53; }

 private:
  uint64_t state_;
};

/// Schedules byte payloads according to a `FaultConfig`.
class FaultInjector {
 public:
  /// Largest payload kept, bytes (one LCM datagram).
  static constexpr size_t kMaxMessageBytes = kLcmMaxPayloadBytes;

  /// `capacity`: messages in flight at once (at 1 kHz with 50 ms delay about 50).
  /// Throws `InputError` if `config` is out of range.
  explicit FaultInjector(const FaultConfig& config, size_t capacity = 512);

  /// Offers one message sent at `now_ns`. Returns how many copies were
  /// scheduled (0: dropped or overflow). Copies the bytes.
  int Submit(std::span<const uint8_t> bytes, int64_t now_ns) noexcept;

  /// Calls `sink(std::span<const uint8_t>)` for each message due at `now_ns`,
  /// earliest due first (ties in submission order). Returns the count.
  template <class Sink>
  int Release(int64_t now_ns, Sink&& sink) {
    int n = 0;
    for (;;) {
      const int i = NextDue(now_ns);
      if (i < 0) break;
      Slot& s = slots_[static_cast<size_t>(i)];
      s.used = false;
      --in_flight_;
      ++stats_.released;
      ++n;
      sink(std::span<const uint8_t>(s.data.data(), s.size));
    }
    return n;
  }

  /// Due time of the earliest scheduled message, or INT64_MAX if none.
  [[nodiscard]] int64_t next_due_ns() const noexcept;
  [[nodiscard]] size_t in_flight() const { return in_flight_; }
  [[nodiscard]] const FaultStats& stats() const { return stats_; }
  [[nodiscard]] const FaultConfig& config() const { return config_; }

 private:
  struct Slot {
    bool used = false;
    int64_t due_ns = 0;
    uint64_t order = 0;
    size_t size = 0;
    std::array<uint8_t, kMaxMessageBytes> data{};
  };
  /// Index of the earliest slot due at `now_ns`, or −1.
  int NextDue(int64_t now_ns) const noexcept;
  bool Schedule(std::span<const uint8_t> bytes, int64_t due_ns, int64_t delay_ns) noexcept;

  FaultConfig config_;
  SplitMix64 rng_;
  std::vector<Slot> slots_;  // preallocated
  size_t in_flight_ = 0;
  uint64_t next_order_ = 0;
  bool any_scheduled_ = false;
  FaultStats stats_;
};

/// Publish-side decorator: encodes a message and sends it on `channel` now
/// (no faults configured) or when the injector releases it (`Poll`).
class FaultyLcmPublisher {
 public:
  FaultyLcmPublisher(LcmBus& bus, std::string channel, const FaultConfig& config);

  /// Encodes `msg` (refused if over one datagram) and sends or schedules it.
  PublishStatus Publish(const google::protobuf::MessageLite& msg, int64_t now_ns) noexcept;
  /// Sends already serialised bytes (at most one datagram) or schedules them.
  PublishStatus PublishBytes(std::span<const uint8_t> bytes, int64_t now_ns) noexcept;
  /// Sends the messages that are due. Returns how many were sent.
  int Poll(int64_t now_ns) noexcept;

  [[nodiscard]] bool active() const { return active_; }
  [[nodiscard]] const FaultInjector& injector() const { return injector_; }
  [[nodiscard]] const std::string& channel() const { return channel_; }

 private:
  LcmBus& bus_;
  std::string channel_;
  bool active_;
  FaultInjector injector_;
  Encoder encoder_;
};

}  // namespace cutsim::transport
