#pragma once
/// @file
/// The haptic station's per-tick CSV: the servo loop pushes rows into a
/// preallocated wait-free ring, a writer thread drains it to the file.

#include <atomic>
#include <cstdint>
#include <cstdio>
#include <string>
#include <thread>
#include <vector>

namespace cutsim::haptic_client {

/// One CSV row, written by the servo loop into a preallocated ring.
struct CsvRow {
  double t;                 ///< s since the loop started
  double x, y, z;           ///< m
  double fx, fy, fz;        ///< N
  double model_age_ms;      ///< ms since the model in use arrived (−1: none yet)
  double period_us;         ///< µs since the previous tick
  double lateness_us;       ///< µs past the deadline at wake-up
  double watchdog_gain;     ///< 0..1
  int phase;                ///< 0 buffer model, 1 cut decay, 2 blend back
  uint64_t cuts;            ///< cut counter of the model in use
  int contact;              ///< model in use reports contact
  double energy_j;          ///< passivity observer E_obs, J
  double dissipated_j;      ///< passivity controller Σ, J
  uint64_t model_seq;       ///< seq of the model in use
  uint64_t epoch;           ///< server stream epoch
};

/// Single-producer (servo loop) single-consumer (writer thread) ring.
class CsvRing {
 public:
  explicit CsvRing(size_t capacity_pow2) : rows_(capacity_pow2), mask_(capacity_pow2 - 1) {}
  /// Wait-free; false (and counted) when the ring is full.
  bool Push(const CsvRow& row) noexcept {
    const uint64_t head = head_.load(std::memory_order_relaxed);
    if (head - tail_.load(std::memory_order_acquire) > mask_) {
      ++dropped_;
      return false;
    }
    rows_[head & mask_] = row;
    head_.store(head + 1, std::memory_order_release);
    return true;
  }
  /// Calls `fn` on every row pushed so far; returns how many.
  template <class Fn>
  size_t Drain(Fn&& fn) {
    const uint64_t head = head_.load(std::memory_order_acquire);
    uint64_t tail = tail_.load(std::memory_order_relaxed);
    const size_t n = head - tail;
    for (; tail != head; ++tail) fn(rows_[tail & mask_]);
    tail_.store(tail, std::memory_order_release);
    return n;
  }
  /// Rows the ring had no room for (read by the producer's thread).
  [[nodiscard]] uint64_t dropped() const { return dropped_; }

 private:
  std::vector<CsvRow> rows_;
  uint64_t mask_;
  std::atomic<uint64_t> head_{0};
  std::atomic<uint64_t> tail_{0};
  uint64_t dropped_ = 0;  // servo-loop only
};

/// Writes the ring to `path` from its own thread; the file appears under its
/// name only when complete (temp file, then rename).
class CsvWriter {
 public:
  /// Creates the file (and its directory) and starts the thread. Throws
  /// `FileError` naming the path when the file cannot be written.
  CsvWriter(std::string path, CsvRing& ring);
  ~CsvWriter() { Finish(); }
  CsvWriter(const CsvWriter&) = delete;
  CsvWriter& operator=(const CsvWriter&) = delete;

  /// Joins the thread, closes and renames. Returns rows written.
  uint64_t Finish();

 private:
  void Flush();

  std::string path_;
  std::string tmp_;
  CsvRing& ring_;
  std::FILE* file_ = nullptr;
  uint64_t rows_ = 0;
  std::atomic<bool> stop_{false};
  std::thread thread_;
};

}  // namespace cutsim::haptic_client
