#include "common/debrief/debrief_player.h"

#include <algorithm>
#include <cmath>
#include <utility>

#include <fmt/format.h>

#include "common/core/clock.h"
#include "common/core/error.h"
#include "common/core/log.h"
#include "cutsim/v1/checkpoint.pb.h"

namespace cutsim::debrief {
namespace {

/// Checkpoints kept at most: a long recording spaces them wider so memory
/// stays bounded (each holds the FEM state twice: body and memo).
constexpr size_t kMaxCheckpoints = 512;
/// Frame ends within this of a target count as at it (round-off of the
/// frame sums), s.
constexpr double kTimeSlack = 1e-9;

}  // namespace

struct DebriefPlayer::Checkpoint {
  size_t frame = 0;  // frames applied when it was taken
  v1::CheckpointBody body;
  std::unique_ptr<const sim::SimulationMemo> memo;
};

DebriefPlayer::DebriefPlayer(SimulationFactory make, std::vector<PlayerFrame> frames, PlayerOptions options,
                             PrepassObserver observer)
    : make_(std::move(make)), frames_(std::move(frames)), options_(options) {
  if (frames_.empty()) ThrowInputError({.field = "recording"}, "the recording has no frames");
  if (!(options_.checkpoint_every > 0.0) || !std::isfinite(options_.checkpoint_every)) {
    ThrowInputError({.field = "--checkpoint-every"},
                    fmt::format("{:g} s: the debrief's checkpoints need a positive period", options_.checkpoint_every));
  }
  if (options_.timeline_samples < 2 || options_.timeline_samples > 100'000) {
    ThrowInputError({.field = "timeline_samples"}, fmt::format("{} is outside [2, 100000]", options_.timeline_samples));
  }
  end_time_.resize(frames_.size() + 1, 0.0);
  for (size_t i = 0; i < frames_.size(); ++i) end_time_[i + 1] = end_time_[i] + frames_[i].frame_time;
  if (options_.checkpoint_bytes == 0) ThrowInputError({.field = "checkpoint_bytes"}, "must be positive");
  const double widest = duration() / static_cast<double>(kMaxCheckpoints - 1);
  if (options_.checkpoint_every < widest) {
    Log().info("debrief: {:.3g} s of recording: checkpoints every {:.3g} s instead of {:.3g} s (at most {})",
               duration(), widest, options_.checkpoint_every, kMaxCheckpoints);
    options_.checkpoint_every = widest;
  }
  checkpoint_every_ = options_.checkpoint_every;
  timeline_.duration = duration();
  // The start is a checkpoint too: a fresh simulation, nothing to restore.
  checkpoints_.push_back({.frame = 0, .body = {}, .memo = nullptr});
  sim_ = make_();
  producer_ = std::thread([this, observer = std::move(observer)] { Produce(observer); });
}

DebriefPlayer::~DebriefPlayer() {
  stop_ = true;
  if (producer_.joinable()) producer_.join();
}

size_t DebriefPlayer::checkpoints() const {
  const std::lock_guard lock(mu_);
  return checkpoints_.size();
}

double DebriefPlayer::checkpoint_every() const {
  const std::lock_guard lock(mu_);
  return checkpoint_every_;
}

Timeline DebriefPlayer::timeline() const {
  const std::lock_guard lock(mu_);
  return timeline_;
}

void DebriefPlayer::WaitProduced() {
  std::unique_lock lock(mu_);
  done_cv_.wait(lock, [this] { return producer_done_.load(); });
  if (failure_) std::rethrow_exception(failure_);
}

void DebriefPlayer::Apply(size_t index, sim::Simulation& simulation) const {
  const PlayerFrame& f = frames_[index];
  if (f.tool) simulation.SetToolPose(*f.tool);
  if (simulation.AdvanceFrame(f.frame_time) != sim::SimStatus::kOk) {
    ThrowInputError({.field = fmt::format("recording frame {}", index + 1)},
                    fmt::format("the simulation stopped: {}", simulation.Summary().diagnosis));
  }
}

void DebriefPlayer::Produce(const PrepassObserver& observer) {
  try {
    std::unique_ptr<sim::Simulation> producer = make_();
    std::vector<double> frame_force(frames_.size(), 0.0);
    uint64_t version = producer->topology_version();
    double every = options_.checkpoint_every;
    double next_checkpoint = every;
    bool spaced = false;
    for (size_t i = 0; i < frames_.size() && !stop_; ++i) {
      Apply(i, *producer);
      if (producer->has_tool()) frame_force[i] = producer->Tool().force_on_tool.norm();
      const bool stepped = producer->topology_version() != version;
      version = producer->topology_version();
      const bool checkpoint = end_time_[i + 1] >= next_checkpoint - kTimeSlack && i + 1 < frames_.size();
      if (stepped || checkpoint) {
        // Taken outside the lock: the player's seeks do not wait for a copy.
        std::optional<Checkpoint> taken;
        if (checkpoint) taken = Checkpoint{.frame = i + 1, .body = producer->CheckpointState(), .memo = producer->Memo()};
        if (taken && !spaced) {
          // The first checkpoint sizes the others (their memory bound).
          every = std::max(every, SpacedPeriod(taken->body));
          spaced = true;
        }
        Timeline timeline = BuildTimeline(frame_force, i + 1, *producer);
        const std::lock_guard lock(mu_);
        if (stepped) step_t_.push_back(end_time_[i + 1]);
        timeline.step_t = step_t_;
        timeline_ = std::move(timeline);
        if (taken) checkpoints_.push_back(std::move(*taken));
        checkpoint_every_ = every;
      }
      if (checkpoint) {
        while (next_checkpoint <= end_time_[i + 1] + kTimeSlack) next_checkpoint += every;
      }
      produced_ = i + 1;
      if (observer && !observer(i, *producer)) break;
    }
    Timeline timeline = BuildTimeline(frame_force, produced_, *producer);
    const std::lock_guard lock(mu_);
    timeline.step_t = step_t_;
    timeline_ = std::move(timeline);
  } catch (...) {
    const std::lock_guard lock(mu_);
    failure_ = std::current_exception();
  }
  {
    const std::lock_guard lock(mu_);
    producer_done_ = true;
  }
  done_cv_.notify_all();
}

double DebriefPlayer::SpacedPeriod(const v1::CheckpointBody& first) const {
  // The memo holds the FEM state's vectors (positions, velocities, forces,
  // scratch): several times the body's positions and velocities.
  const double each = 8.0 * static_cast<double>(sizeof(double)) *
                      static_cast<double>(first.positions_size() + first.velocities_size());
  const double fit = std::max(2.0, static_cast<double>(options_.checkpoint_bytes) / std::max(each, 1.0));
  const double every = duration() / std::min(fit, static_cast<double>(kMaxCheckpoints - 1));
  if (every > options_.checkpoint_every) {
    Log().info("debrief: checkpoints every {:.3g} s instead of {:.3g} s ({:.3g} MB each, {:.3g} GB at most)", every,
               options_.checkpoint_every, 1e-6 * each, 1e-9 * static_cast<double>(options_.checkpoint_bytes));
  }
  return every;
}

Timeline DebriefPlayer::BuildTimeline(const std::vector<double>& frame_force, size_t produced,
                                      const sim::Simulation& producer) const {
  // The force in equal spans of recorded time, each its largest |f|: a
  // peak shorter than a span still shows. Spans not produced yet stay 0.
  Timeline timeline;
  timeline.duration = duration();
  const size_t n = std::min(static_cast<size_t>(options_.timeline_samples), frames_.size());
  const double span = duration() / static_cast<double>(n);
  timeline.force_t.assign(n, 0.0);
  timeline.force_n.assign(n, 0.0);
  for (size_t k = 0; k < n; ++k) timeline.force_t[k] = span * static_cast<double>(k);
  for (size_t i = 0; i < produced; ++i) {
    const size_t k = std::min(n - 1, static_cast<size_t>(end_time_[i] / span));
    timeline.force_n[k] = std::max(timeline.force_n[k], frame_force[i]);
  }
  for (const sim::CutPoint& c : producer.ScoredCutPoints()) {
    timeline.cut_t.push_back(c.t);
    timeline.cut_deviation.push_back(c.deviation);
  }
  if (const sim::PlannedIncision* plan = producer.Plan()) timeline.tolerance = plan->tolerance;
  return timeline;
}

bool DebriefPlayer::StepFrame() {
  if (at_end()) return false;
  Apply(frame_, *sim_);
  ++frame_;
  return true;
}

size_t DebriefPlayer::AdvanceTo(double t) {
  size_t stepped = 0;
  while (!at_end() && end_time_[frame_ + 1] <= t + kTimeSlack) {
    StepFrame();
    ++stepped;
  }
  return stepped;
}

size_t DebriefPlayer::FrameAt(double t) const {
  // The last k with end_time_[k] <= t.
  const auto it = std::upper_bound(end_time_.begin(), end_time_.end(), t + kTimeSlack);
  return static_cast<size_t>(std::max<std::ptrdiff_t>(0, (it - end_time_.begin()) - 1));
}

SeekReport DebriefPlayer::Seek(double t) {
  const double target_t = std::clamp(std::isfinite(t) ? t : 0.0, 0.0, duration());
  const size_t target = FrameAt(target_t);
  // The checkpoint at or before the target, among those produced so far
  // (the deque keeps it in place while the producer adds more).
  const Checkpoint* found = nullptr;
  {
    const std::lock_guard lock(mu_);
    const auto after = std::upper_bound(checkpoints_.begin(), checkpoints_.end(), target,
                                        [](size_t f, const Checkpoint& c) { return f < c.frame; });
    found = &*(after - 1);
  }
  const Checkpoint& from = *found;
  SeekReport report;
  // Stepping on from here is cheaper than a restore when the target is
  // ahead and no farther than from the checkpoint (same frames, same state).
  if (target >= frame_ && target - frame_ <= target - from.frame) {
    const Stopwatch watch;
    while (frame_ < target) {
      StepFrame();
      ++report.frames_stepped;
    }
    report.step_s = watch.ElapsedSeconds();
    return report;
  }
  const Stopwatch watch;
  std::unique_ptr<sim::Simulation> fresh = make_();
  if (from.memo) {
    fresh->RestoreCheckpointState(from.body, "debrief checkpoint");
    fresh->RestoreMemo(*from.memo);
  }
  report.restored = true;
  report.restore_from = end_time_[from.frame];
  report.restore_s = watch.ElapsedSeconds();
  for (size_t i = from.frame; i < target; ++i) {
    Apply(i, *fresh);
    ++report.frames_stepped;
  }
  report.step_s = watch.ElapsedSeconds() - report.restore_s;
  sim_ = std::move(fresh);
  frame_ = target;
  return report;
}

std::optional<double> DebriefPlayer::NextStep() const {
  const std::lock_guard lock(mu_);
  const auto it = std::upper_bound(step_t_.begin(), step_t_.end(), position() + kTimeSlack);
  if (it == step_t_.end()) return std::nullopt;
  return *it;
}

std::optional<double> DebriefPlayer::PreviousStep() const {
  const std::lock_guard lock(mu_);
  const auto it = std::lower_bound(step_t_.begin(), step_t_.end(), position() - kTimeSlack);
  if (it == step_t_.begin()) return std::nullopt;
  return *(it - 1);
}

}  // namespace cutsim::debrief
