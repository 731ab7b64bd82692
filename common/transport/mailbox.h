#pragma once
/// @file
/// A one-slot, newest-wins mailbox between exactly one writer thread and one
/// reader thread, for handing local models from the LCM thread to the 1 kHz
/// haptic loop (and tool samples the other way). Both sides are wait-free:
/// neither ever blocks, spins, allocates or makes a system call, so the
/// real-time side can call it inside its loop.
///
/// Implementation: a triple buffer. Three slots; the writer owns one (back),
/// the reader owns one (front), the third (middle) is exchanged through one
/// atomic byte that also carries a "fresh" bit. `Write` fills the back slot
/// and swaps it with the middle (release); `Read` swaps its front with the
/// middle only when the fresh bit is set (acquire). A slot is never touched
/// by both threads at once, so T needs no atomics and no seqlock retry (a
/// seqlock would copy T while it may be written, which is a data race in the
/// C++ memory model unless T is copied through atomics). Intermediate values
/// the reader did not pick up are overwritten: only the newest matters.

#include <atomic>
#include <cstdint>
#include <utility>

namespace cutsim::transport {

/// Single-producer single-consumer newest-value mailbox. T must be
/// copy-assignable without allocating (fixed-size types) for the no-allocation
/// guarantee to hold.
template <class T>
class Mailbox {
 public:
  Mailbox() = default;
  Mailbox(const Mailbox&) = delete;
  Mailbox& operator=(const Mailbox&) = delete;

  /// Writer side: publishes `value` (replacing any value not read yet).
  void Write(const T& value) noexcept {
    slots_[back_] = value;
    Publish();
  }

  /// Writer side, zero-copy form: fill `back()` then call `Publish()`.
  [[nodiscard]] T& back() noexcept { return slots_[back_]; }
  void Publish() noexcept {
    const uint8_t old = middle_.exchange(static_cast<uint8_t>(back_ | kFresh), std::memory_order_acq_rel);
    back_ = old & kIndexMask;
    written_.fetch_add(1, std::memory_order_relaxed);
  }

  /// Reader side: if a value was written since the last successful `Read`,
  /// copies it to `*out` and returns true; otherwise leaves `*out` alone.
  bool Read(T* out) noexcept {
    if (!TakeFresh()) return false;
    *out = slots_[front_];
    return true;
  }

  /// Reader side, zero-copy form: true if a fresh value is now in `front()`.
  bool TakeFresh() noexcept {
    if ((middle_.load(std::memory_order_relaxed) & kFresh) == 0) return false;
    const uint8_t old = middle_.exchange(front_, std::memory_order_acq_rel);
    front_ = old & kIndexMask;
    return true;
  }
  /// The reader's current value (the last one taken; default-constructed before).
  [[nodiscard]] const T& front() const noexcept { return slots_[front_]; }

  /// Values written so far (writer-side counter; approximate from the reader).
  [[nodiscard]] uint64_t written() const noexcept { return written_.load(std::memory_order_relaxed); }

 private:
  static constexpr uint8_t kFresh = 0x4;
  static constexpr uint8_t kIndexMask = 0x3;

  T slots_[3]{};
  uint8_t back_ = 0;                 // writer-owned slot index
  uint8_t front_ = 1;                // reader-owned slot index
  std::atomic<uint8_t> middle_{2};   // shared slot index | kFresh
  std::atomic<uint64_t> written_{0};
};

}  // namespace cutsim::transport
