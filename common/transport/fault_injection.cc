#include "common/transport/fault_injection.h"

#include <cmath>
#include <cstring>

#include <fmt/format.h>

#include "common/core/error.h"

namespace cutsim::transport {
namespace {

constexpr double kMaxDelayMs = 10'000.0;  // 10 s: anything longer is a typo, not a network

void CheckTime(double value, std::string_view prefix, std::string_view name) {
  if (!std::isfinite(value) || value < 0.0 || value > kMaxDelayMs) {
    ThrowInputError(SourceRef{.field = fmt::format("{}{}", prefix, name)},
                    fmt::format("{} ms is out of range (0 to {} ms)", value, kMaxDelayMs));
  }
}

void CheckProbability(double value, std::string_view prefix, std::string_view name) {
  if (!std::isfinite(value) || value < 0.0 || value > 1.0) {
    ThrowInputError(SourceRef{.field = fmt::format("{}{}", prefix, name)},
                    fmt::format("{} is not a probability (0 to 1)", value));
  }
}

int64_t MsToNs(double ms) { return static_cast<int64_t>(std::llround(ms * 1e6)); }

}  // namespace

void ValidateFaultConfig(const FaultConfig& config, std::string_view flag_prefix) {
  CheckTime(config.delay_ms, flag_prefix, "delay-ms");
  CheckTime(config.jitter_ms, flag_prefix, "jitter-ms");
  CheckTime(config.reorder_ms, flag_prefix, "reorder-ms");
  CheckProbability(config.drop, flag_prefix, "drop");
  CheckProbability(config.duplicate, flag_prefix, "dup");
  CheckProbability(config.reorder, flag_prefix, "reorder");
}

std::string Describe(const FaultConfig& c) {
  if (!c.active()) return "none";
  return fmt::format("delay {} ms + U[0, {}] ms, drop {:.1f}%, duplicate {:.1f}%, reorder {:.1f}% "
                     "(+{} ms), seed {}",
                     c.delay_ms, c.jitter_ms, 100.0 * c.drop, 100.0 * c.duplicate,
                     100.0 * c.reorder, c.reorder_ms, c.seed);
}

FaultInjector::FaultInjector(const FaultConfig& config, size_t capacity)
    : config_(config), rng_(config.seed), slots_(capacity) {
  ValidateFaultConfig(config);
}

bool FaultInjector::Schedule(std::span<const uint8_t> bytes, int64_t due_ns, int64_t delay_ns) noexcept {
  if (bytes.size() > kMaxMessageBytes || in_flight_ == slots_.size()) {
    ++stats_.overflow;
    return false;
  }
  for (Slot& s : slots_) {
    if (s.used) continue;
    s.used = true;
    s.due_ns = due_ns;
    s.order = next_order_++;
    s.size = bytes.size();
    if (!bytes.empty()) std::memcpy(s.data.data(), bytes.data(), bytes.size());
    ++in_flight_;
    stats_.min_delay_ns = any_scheduled_ ? std::min(stats_.min_delay_ns, delay_ns) : delay_ns;
    any_scheduled_ = true;
    stats_.max_delay_ns = std::max(stats_.max_delay_ns, delay_ns);
    stats_.sum_delay_ns += static_cast<double>(delay_ns);
    return true;
  }
  ++stats_.overflow;  // unreachable: in_flight_ < size means a free slot exists
  return false;
}

int FaultInjector::Submit(std::span<const uint8_t> bytes, int64_t now_ns) noexcept {
  ++stats_.submitted;
  // Draw every random number for this message up front, in a fixed order, so
  // a message's fate does not depend on the fates of earlier ones' branches.
  const double u_drop = rng_.Uniform();
  const double u_dup = rng_.Uniform();
  const double u_jitter[2] = {rng_.Uniform(), rng_.Uniform()};
  const double u_reorder[2] = {rng_.Uniform(), rng_.Uniform()};
  if (u_drop < config_.drop) {
    ++stats_.dropped;
    return 0;
  }
  const int copies = u_dup < config_.duplicate ? 2 : 1;
  int scheduled = 0;
  for (int c = 0; c < copies; ++c) {
    double delay_ms = config_.delay_ms + config_.jitter_ms * u_jitter[c];
    if (u_reorder[c] < config_.reorder) {
      delay_ms += config_.reorder_ms;
      ++stats_.reordered;
    }
    const int64_t delay_ns = MsToNs(delay_ms);
    if (Schedule(bytes, now_ns + delay_ns, delay_ns)) {
      ++scheduled;
      if (c == 1) ++stats_.duplicated;
    }
  }
  return scheduled;
}

int FaultInjector::NextDue(int64_t now_ns) const noexcept {
  int best = -1;
  for (size_t i = 0; i < slots_.size() && in_flight_ > 0; ++i) {
    const Slot& s = slots_[i];
    if (!s.used || s.due_ns > now_ns) continue;
    if (best < 0) {
      best = static_cast<int>(i);
      continue;
    }
    const Slot& b = slots_[static_cast<size_t>(best)];
    if (s.due_ns < b.due_ns || (s.due_ns == b.due_ns && s.order < b.order)) best = static_cast<int>(i);
  }
  return best;
}

int64_t FaultInjector::next_due_ns() const noexcept {
  int64_t due = std::numeric_limits<int64_t>::max();
  if (in_flight_ == 0) return due;
  for (const Slot& s : slots_) {
    if (s.used) due = std::min(due, s.due_ns);
  }
  return due;
}

FaultyLcmPublisher::FaultyLcmPublisher(LcmBus& bus, std::string channel, const FaultConfig& config)
    : bus_(bus),
      channel_(std::move(channel)),
      active_(config.active()),
      injector_(config, config.active() ? 512 : 0) {}

PublishStatus FaultyLcmPublisher::Publish(const google::protobuf::MessageLite& msg, int64_t now_ns) noexcept {
  if (!active_) return bus_.Publish(channel_, msg);
  size_t size = 0;
  std::optional<std::span<const uint8_t>> bytes;
  try {
    bytes = encoder_.Encode(msg, kLcmMaxPayloadBytes, &size);
  } catch (...) {
    return PublishStatus::kFailed;
  }
  if (!bytes) return size > kLcmMaxPayloadBytes ? PublishStatus::kTooLarge : PublishStatus::kFailed;
  injector_.Submit(*bytes, now_ns);
  Poll(now_ns);  // zero-delay copies leave at once
  return PublishStatus::kOk;
}

PublishStatus FaultyLcmPublisher::PublishBytes(std::span<const uint8_t> bytes, int64_t now_ns) noexcept {
  if (!active_) return bus_.PublishBytes(channel_, bytes);
  if (bytes.size() > kLcmMaxPayloadBytes) return PublishStatus::kTooLarge;
  injector_.Submit(bytes, now_ns);
  Poll(now_ns);
  return PublishStatus::kOk;
}

int FaultyLcmPublisher::Poll(int64_t now_ns) noexcept {
  if (!active_) return 0;
  return injector_.Release(now_ns, [&](std::span<const uint8_t> bytes) { bus_.PublishBytes(channel_, bytes); });
}

}  // namespace cutsim::transport
