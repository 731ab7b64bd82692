#pragma once
/// @file
/// Keeps only the newest message of a stream by its sequence number. The
/// haptic link wants the freshest tool pose or local model and nothing else:
/// an older or repeated message (UDP reordering, a replayed log, a duplicate
/// publisher) is dropped and counted, never applied.

#include <cstdint>
#include <utility>

namespace cutsim::transport {

/// Newest-by-`seq()` holder for a message type with a `uint64 seq` field.
///
/// A sender that restarts begins again at a small sequence number. A message
/// whose sequence is more than `restart_window` below the held one is taken
/// as such a restart and accepted (and counted); anything closer below is
/// stale. The default window, 1000 messages, is one second of the 1 kHz tool
/// stream: a restarted sender is at most that long unheard, which the haptic
/// watchdog already covers by fading force to zero.
///
/// Copy-assigning a protobuf message reuses its storage, so after the first
/// few messages `Offer` does not allocate. Not thread-safe.
template <class Msg>
class LatestSlot {
 public:
  static constexpr uint64_t kDefaultRestartWindow = 1000;

  explicit LatestSlot(uint64_t restart_window = kDefaultRestartWindow)
      : restart_window_(restart_window) {}

  /// Keeps `msg` if it is newer than the held message; returns whether it was kept.
  bool Offer(const Msg& msg) {
    if (!Accept(msg.seq())) return false;
    value_ = msg;
    return true;
  }

  /// As `Offer(const Msg&)`, moving (swapping) the message in.
  bool Offer(Msg&& msg) {
    if (!Accept(msg.seq())) return false;
    value_ = std::move(msg);
    return true;
  }

  /// True once any message was accepted (and until `Reset`).
  [[nodiscard]] bool has_value() const { return has_value_; }
  /// The newest message; only meaningful if `has_value()`.
  [[nodiscard]] const Msg& value() const { return value_; }
  /// Sequence number of the newest message (0 if none).
  [[nodiscard]] uint64_t seq() const { return has_value_ ? value_.seq() : 0; }

  /// True if a message arrived since the last `MarkConsumed()`.
  [[nodiscard]] bool fresh() const { return fresh_; }
  /// Marks the held message as seen; `fresh()` turns false until the next accept.
  void MarkConsumed() { fresh_ = false; }

  /// Forgets the held message (counters are kept).
  void Reset() {
    has_value_ = false;
    fresh_ = false;
  }

  [[nodiscard]] uint64_t accepted() const { return accepted_; }
  [[nodiscard]] uint64_t dropped_stale() const { return dropped_stale_; }
  [[nodiscard]] uint64_t dropped_duplicate() const { return dropped_duplicate_; }
  [[nodiscard]] uint64_t restarts() const { return restarts_; }

 private:
  bool Accept(uint64_t seq) {
    if (has_value_) {
      const uint64_t held = value_.seq();
      if (seq == held) {
        ++dropped_duplicate_;
        return false;
      }
      if (seq < held) {
        if (held - seq <= restart_window_) {
          ++dropped_stale_;
          return false;
        }
        ++restarts_;
      }
    }
    has_value_ = true;
    fresh_ = true;
    ++accepted_;
    return true;
  }

  Msg value_{};
  uint64_t restart_window_;
  bool has_value_ = false;
  bool fresh_ = false;
  uint64_t accepted_ = 0;
  uint64_t dropped_stale_ = 0;
  uint64_t dropped_duplicate_ = 0;
  uint64_t restarts_ = 0;
};

}  // namespace cutsim::transport
