#pragma once
/// @file
/// Fixed-bin histograms for loop timing and latencies: preallocated at
/// construction, `Add` is O(1) with no allocation, so the 1 kHz loop can
/// record every tick and quantiles come out exact to one bin afterwards.

#include <algorithm>
#include <cstdint>
#include <vector>

#include "common/transport/report_json.h"
#include "cutsim/v1/report.pb.h"

namespace cutsim::haptic_client {

class Histogram {
 public:
  /// Bins of `bin_width` from 0 to `bin_width · bins`; larger values go to an
  /// overflow bin (their maximum is still exact).
  Histogram(double bin_width, size_t bins) : width_(bin_width), counts_(bins + 1, 0) {}

  void Add(double value) noexcept {
    const double v = value < 0.0 ? 0.0 : value;
    const size_t last = counts_.size() - 1;
    const double b = v / width_;
    const size_t i = b >= static_cast<double>(last) ? last : static_cast<size_t>(b);
    ++counts_[i];
    ++count_;
    max_ = std::max(max_, value);
    sum_ += value;
  }

  /// Upper edge of the bin holding quantile q ∈ [0, 1] (the max for the overflow bin).
  [[nodiscard]] double Quantile(double q) const {
    if (count_ == 0) return 0.0;
    const auto target = static_cast<uint64_t>(std::max<double>(1.0, q * static_cast<double>(count_)));
    uint64_t seen = 0;
    for (size_t i = 0; i < counts_.size(); ++i) {
      seen += counts_[i];
      if (seen >= target) return i + 1 == counts_.size() ? max_ : std::min(max_, width_ * static_cast<double>(i + 1));
    }
    return max_;
  }
  [[nodiscard]] uint64_t count() const { return count_; }
  [[nodiscard]] double max() const { return max_; }
  [[nodiscard]] double mean() const { return count_ == 0 ? 0.0 : sum_ / static_cast<double>(count_); }

 private:
  double width_;
  std::vector<uint64_t> counts_;
  uint64_t count_ = 0;
  double max_ = 0.0;
  double sum_ = 0.0;
};

/// The histogram's quantiles as the report message both loop programs print.
inline v1::Quantiles QuantilesReport(const Histogram& h) {
  v1::Quantiles q;
  q.set_p50(h.Quantile(0.5));
  q.set_p99(h.Quantile(0.99));
  q.set_max(h.max());
  q.set_mean(h.mean());
  q.set_n(transport::ReportCount(h.count()));
  return q;
}

}  // namespace cutsim::haptic_client
