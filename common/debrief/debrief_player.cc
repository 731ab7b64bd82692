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
                             const PrepassObserver& observer)
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
  timeline_.duration = end_time_.back();
  if (options_.checkpoint_bytes == 0) ThrowInputError({.field = "checkpoint_bytes"}, "must be positive");
  const double widest = timeline_.duration / static_cast<double>(kMaxCheckpoints - 1);
  if (options_.checkpoint_every < widest) {
    Log().info("debrief: {:.3g} s of recording: checkpoints every {:.3g} s instead of {:.3g} s (at most {})",
               timeline_.duration, widest, options_.checkpoint_every, kMaxCheckpoints);
    options_.checkpoint_every = widest;
  }
  Prepass(observer);
}

DebriefPlayer::~DebriefPlayer() = default;

size_t DebriefPlayer::checkpoints() const { return checkpoints_.size(); }

void DebriefPlayer::Apply(size_t index, sim::Simulation& simulation) const {
  const PlayerFrame& f = frames_[index];
  if (f.tool) simulation.SetToolPose(*f.tool);
  if (simulation.AdvanceFrame(f.frame_time) != sim::SimStatus::kOk) {
    ThrowInputError({.field = fmt::format("recording frame {}", index + 1)},
                    fmt::format("the simulation stopped: {}", simulation.Summary().diagnosis));
  }
}

void DebriefPlayer::Prepass(const PrepassObserver& observer) {
  sim_ = make_();
  std::vector<double> frame_force(frames_.size(), 0.0);
  uint64_t version = sim_->topology_version();
  double next_checkpoint = options_.checkpoint_every;
  // The start is a checkpoint too: a fresh simulation, nothing to restore.
  checkpoints_.push_back({.frame = 0, .body = {}, .memo = nullptr});
  for (size_t i = 0; i < frames_.size(); ++i) {
    Apply(i, *sim_);
    frame_ = i + 1;
    if (sim_->has_tool()) frame_force[i] = sim_->Tool().force_on_tool.norm();
    if (sim_->topology_version() != version) {
      version = sim_->topology_version();
      timeline_.step_t.push_back(end_time_[i + 1]);
    }
    if (end_time_[i + 1] >= next_checkpoint - kTimeSlack && i + 1 < frames_.size()) {
      checkpoints_.push_back({.frame = i + 1, .body = sim_->CheckpointState(), .memo = sim_->Memo()});
      if (checkpoints_.size() == 2) SpaceCheckpoints(checkpoints_.back().body);
      while (next_checkpoint <= end_time_[i + 1] + kTimeSlack) next_checkpoint += options_.checkpoint_every;
    }
    if (observer && !observer(i, *sim_)) {
      frames_.resize(i + 1);
      end_time_.resize(i + 2);
      timeline_.duration = end_time_.back();
      break;
    }
  }
  frame_force.resize(frames_.size());
  BuildTimeline(frame_force);
}

void DebriefPlayer::SpaceCheckpoints(const v1::CheckpointBody& first) {
  // The memo holds the FEM state's vectors (positions, velocities, forces,
  // scratch): several times the body's positions and velocities.
  const double each = 8.0 * static_cast<double>(sizeof(double)) *
                      static_cast<double>(first.positions_size() + first.velocities_size());
  const double fit = std::max(2.0, static_cast<double>(options_.checkpoint_bytes) / std::max(each, 1.0));
  const double every = timeline_.duration / std::min(fit, static_cast<double>(kMaxCheckpoints - 1));
  if (every > options_.checkpoint_every) {
    Log().info("debrief: checkpoints every {:.3g} s instead of {:.3g} s ({:.3g} MB each, {:.3g} GB at most)", every,
               options_.checkpoint_every, 1e-6 * each, 1e-9 * static_cast<double>(options_.checkpoint_bytes));
    options_.checkpoint_every = every;
  }
}

void DebriefPlayer::BuildTimeline(const std::vector<double>& frame_force) {
  // The force in equal spans of recorded time, each its largest |f|: a
  // peak shorter than a span still shows.
  const size_t n = std::min(static_cast<size_t>(options_.timeline_samples), frames_.size());
  const double span = timeline_.duration / static_cast<double>(n);
  timeline_.force_t.assign(n, 0.0);
  timeline_.force_n.assign(n, 0.0);
  for (size_t k = 0; k < n; ++k) timeline_.force_t[k] = span * static_cast<double>(k);
  for (size_t i = 0; i < frames_.size(); ++i) {
    const size_t k = std::min(n - 1, static_cast<size_t>(end_time_[i] / span));
    timeline_.force_n[k] = std::max(timeline_.force_n[k], frame_force[i]);
  }
  for (const sim::CutPoint& c : sim_->ScoredCutPoints()) {
    timeline_.cut_t.push_back(c.t);
    timeline_.cut_deviation.push_back(c.deviation);
  }
  if (const sim::PlannedIncision* plan = sim_->Plan()) timeline_.tolerance = plan->tolerance;
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
  const double target_t = std::clamp(std::isfinite(t) ? t : 0.0, 0.0, timeline_.duration);
  const size_t target = FrameAt(target_t);
  // The checkpoint at or before the target.
  const auto after = std::upper_bound(checkpoints_.begin(), checkpoints_.end(), target,
                                      [](size_t f, const Checkpoint& c) { return f < c.frame; });
  const Checkpoint& from = *(after - 1);
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
  const auto it = std::upper_bound(timeline_.step_t.begin(), timeline_.step_t.end(), position() + kTimeSlack);
  if (it == timeline_.step_t.end()) return std::nullopt;
  return *it;
}

std::optional<double> DebriefPlayer::PreviousStep() const {
  const auto it = std::lower_bound(timeline_.step_t.begin(), timeline_.step_t.end(), position() - kTimeSlack);
  if (it == timeline_.step_t.begin()) return std::nullopt;
  return *(it - 1);
}

}  // namespace cutsim::debrief
