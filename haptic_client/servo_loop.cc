#include "haptic_client/servo_loop.h"

#include <algorithm>
#include <climits>
#include <cmath>

#include "common/core/clock.h"

namespace cutsim::haptic_client {

ServoLoop::ServoLoop(const HapticAppOptions& options, HapticDevice& device,
                     haptics::HapticRenderer& renderer, transport::HapticClientLink& link)
    : device_(device),
      renderer_(renderer),
      link_(link),
      period_ns_(static_cast<int64_t>(std::llround(1e9 / options.rate))),
      tool_every_(std::max(1, static_cast<int>(std::lround(options.rate / options.tool_rate)))),
      duration_s_(options.duration),
      write_csv_(!options.csv.empty() && options.csv != "-") {
  if (write_csv_) writer_ = std::make_unique<CsvWriter>(options.csv, ring_);
}

const char* ServoLoop::Run(const std::atomic<bool>& stop) {
  const int64_t start_ns = MonotonicNs() + period_ns_;
  device_.Start(start_ns);
  // A device whose start took longer than a period: the first deadline
  // follows it (its start is no missed tick).
  t0_ = std::max(start_ns, MonotonicNs() + period_ns_);
  end_ns_ = duration_s_ > 0.0 ? t0_ + static_cast<int64_t>(std::llround(duration_s_ * 1e9)) : INT64_MAX;
  int64_t deadline = t0_;
  for (;;) {
    SleepUntilNs(deadline);
    const Wake wake = MeasureWake(deadline);
    device_.Read(wake.now_ns, &state_);
    if (ticks_ % static_cast<uint64_t>(tool_every_) == 0) SendTool(wake.now_ns);
    TakeModel(wake.now_ns);
    const Eigen::Vector3d force = renderer_.Tick(state_.pose.tip, state_.velocity, wake.now_ns, wake.dt_s);
    device_.SetForce(force);
    if (have_model_) device_.ShowModel(received_.model.cut.cuts, received_.model.contact);
    Record(wake, force);
    ++ticks_;
    if (const char* reason = EndReason(wake.now_ns, stop)) return reason;
    deadline = NextDeadline(deadline);
  }
}

uint64_t ServoLoop::FinishCsv() { return writer_ ? writer_->Finish() : 0; }

ServoLoop::Wake ServoLoop::MeasureWake(int64_t deadline_ns) {
  const int64_t now = MonotonicNs();
  const double nominal_us = 1e-3 * static_cast<double>(period_ns_);
  Wake wake{.now_ns = now,
            .dt_s = 1e-9 * static_cast<double>(prev_wake_ns_ == 0 ? period_ns_ : now - prev_wake_ns_),
            .lateness_us = 1e-3 * static_cast<double>(now - deadline_ns)};
  if (prev_wake_ns_ != 0) {
    const double p = 1e-3 * static_cast<double>(now - prev_wake_ns_);
    timing_.period_us.Add(p);
    timing_.jitter_us.Add(std::abs(p - nominal_us));
  }
  timing_.lateness_us.Add(wake.lateness_us);
  prev_wake_ns_ = now;
  return wake;
}

void ServoLoop::SendTool(int64_t now_ns) {
  transport::ToolSample sample;
  sample.stamp_ns = now_ns;
  sample.pose = state_.pose;
  sample.velocity = state_.velocity;
  sample.buttons = state_.buttons;
  const uint64_t seq = link_.PublishTool(sample);
  send_ns_[seq % kSendRing] = now_ns;
  send_seq_[seq % kSendRing] = seq;
}

void ServoLoop::TakeModel(int64_t now_ns) {
  if (!link_.TakeModel(&received_)) return;
  if (have_model_ && received_.epoch != last_epoch_) renderer_.Reset();  // the server restarted
  last_epoch_ = received_.epoch;
  have_model_ = true;
  renderer_.SetModel(received_.model, received_.receive_ns);
  const uint64_t ts = received_.tool_seq;
  if (ts != 0 && send_seq_[ts % kSendRing] == ts) {
    const int64_t sent_ns = send_ns_[ts % kSendRing];
    timing_.pose_to_model_ms.Add(1e-6 * static_cast<double>(received_.receive_ns - sent_ns));
    timing_.pose_to_use_ms.Add(1e-6 * static_cast<double>(now_ns - sent_ns));
  }
}

void ServoLoop::Record(const Wake& wake, const Eigen::Vector3d& force) {
  const double age_ms = have_model_ ? 1e-6 * static_cast<double>(wake.now_ns - received_.receive_ns) : -1.0;
  if (have_model_) timing_.model_age_ms.Add(age_ms);
  if (!write_csv_) return;
  const auto& st = renderer_.stats();
  ring_.Push(CsvRow{.t = 1e-9 * static_cast<double>(wake.now_ns - t0_),
                    .x = state_.pose.tip.x(), .y = state_.pose.tip.y(), .z = state_.pose.tip.z(),
                    .fx = force.x(), .fy = force.y(), .fz = force.z(),
                    .model_age_ms = age_ms,
                    .period_us = 1e6 * wake.dt_s,
                    .lateness_us = wake.lateness_us,
                    .watchdog_gain = renderer_.watchdog_gain(),
                    .phase = static_cast<int>(renderer_.phase()),
                    .cuts = have_model_ ? received_.model.cut.cuts : 0,
                    .contact = have_model_ && received_.model.contact ? 1 : 0,
                    .energy_j = st.observed_energy,
                    .dissipated_j = st.passivity_dissipated,
                    .model_seq = have_model_ ? received_.model.seq : 0,
                    .epoch = received_.epoch});
}

const char* ServoLoop::EndReason(int64_t now_ns, const std::atomic<bool>& stop) const {
  if (state_.done) return "device done";
  if (state_.stuck) return "device stuck";
  if (now_ns >= end_ns_) return "duration";
  if (stop.load(std::memory_order_relaxed)) return "signal";
  return nullptr;
}

int64_t ServoLoop::NextDeadline(int64_t deadline_ns) {
  deadline_ns += period_ns_;
  const int64_t after = MonotonicNs();
  if (after > deadline_ns) {
    // Woke (or ran) past the next deadline: count it and skip ahead.
    const int64_t behind = (after - deadline_ns) / period_ns_ + 1;
    missed_ += static_cast<uint64_t>(behind);
    deadline_ns += behind * period_ns_;
  }
  return deadline_ns;
}

}  // namespace cutsim::haptic_client
