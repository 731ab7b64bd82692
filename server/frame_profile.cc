#include "server/frame_profile.h"

#include <algorithm>
#include <string>

namespace cutsim::server {

namespace {

constexpr std::array<const char*, kNumServerStages> kServerStageNames{
    "tool_pose", "journal", "local_model", "record", "viewer", "status", "checkpoint"};
constexpr int kFirstSimStage = kNumServerStages;
constexpr int kFirstPhase = kNumServerStages + sim::kNumFrameStages;

/// The dynamics' phases as "dynamics.<phase>".
const std::array<std::string, sim::kNumDynamicsPhases>& PhaseNames() {
  static const std::array<std::string, sim::kNumDynamicsPhases> names = [] {
    std::array<std::string, sim::kNumDynamicsPhases> n;
    for (int i = 0; i < sim::kNumDynamicsPhases; ++i) n[static_cast<size_t>(i)] = std::string("dynamics.") + sim::DynamicsPhaseName(i);
    return n;
  }();
  return names;
}

}  // namespace

const char* FrameProfile::EntryName(int entry) {
  if (entry < kFirstSimStage) return kServerStageNames[static_cast<size_t>(entry)];
  if (entry < kFirstPhase) return sim::FrameStageName(static_cast<sim::FrameStage>(entry - kFirstSimStage));
  return PhaseNames()[static_cast<size_t>(entry - kFirstPhase)].c_str();
}

int FrameProfile::Leader(const Split& split) {
  return static_cast<int>(std::max_element(split.begin(), split.begin() + kFirstPhase) - split.begin());
}

void FrameProfile::BeginFrame(int64_t now_ns) {
  frame_.fill(0.0);
  mark_ns_ = now_ns;
}

void FrameProfile::End(ServerStage stage, int64_t now_ns) {
  frame_[static_cast<size_t>(stage)] += 1e-9 * static_cast<double>(now_ns - mark_ns_);
  mark_ns_ = now_ns;
}

void FrameProfile::EndSimulation(const sim::FrameTimes& times, int64_t now_ns) {
  for (int s = 0; s < sim::kNumFrameStages; ++s) frame_[static_cast<size_t>(kFirstSimStage + s)] += times.stage_seconds[static_cast<size_t>(s)];
  for (int p = 0; p < sim::kNumDynamicsPhases; ++p) frame_[static_cast<size_t>(kFirstPhase + p)] += times.dynamics_seconds[static_cast<size_t>(p)];
  mark_ns_ = now_ns;
}

void FrameProfile::EndFrame(uint64_t frame, double sim_time, double seconds, bool overran) {
  ++frames_;
  for (size_t e = 0; e < frame_.size(); ++e) {
    sum_[e] += frame_[e];
    max_[e] = std::max(max_[e], frame_[e]);
  }
  if (overran) ++led_[static_cast<size_t>(Leader(frame_))];
  const auto fastest = std::min_element(slowest_.begin(), slowest_.end(),
                                        [](const SlowFrame& a, const SlowFrame& b) { return a.seconds < b.seconds; });
  if (seconds > fastest->seconds) *fastest = {.frame = frame, .sim_time = sim_time, .seconds = seconds, .split = frame_};
}

void FrameProfile::AddToStats(v1::ServerSessionStats& stats) const {
  const double frames = static_cast<double>(std::max<uint64_t>(frames_, 1));
  for (int e = 0; e < kNumEntries; ++e) {
    v1::FrameStageTime* s = stats.add_frame_stages();
    s->set_stage(EntryName(e));
    s->set_mean_ms(1e3 * sum_[static_cast<size_t>(e)] / frames);
    s->set_max_ms(1e3 * max_[static_cast<size_t>(e)]);
    s->set_overruns_led(led_[static_cast<size_t>(e)]);
  }
  std::array<SlowFrame, kSlowest> slowest = slowest_;
  std::sort(slowest.begin(), slowest.end(), [](const SlowFrame& a, const SlowFrame& b) { return a.seconds > b.seconds; });
  for (const SlowFrame& f : slowest) {
    if (f.seconds < 0) continue;
    v1::SlowFrame* out = stats.add_slowest_frames();
    out->set_frame(static_cast<uint32_t>(f.frame));
    out->set_sim_time(f.sim_time);
    out->set_total_ms(1e3 * f.seconds);
    for (int e = 0; e < kNumEntries; ++e) {
      const double ms = 1e3 * f.split[static_cast<size_t>(e)];
      if (ms >= 0.05) (*out->mutable_stage_ms())[EntryName(e)] = ms;
    }
  }
}

}  // namespace cutsim::server
