#include "common/sim/cut_pipeline.h"

#include <algorithm>
#include <cmath>
#include <utility>

#include <fmt/format.h>

#include "common/core/error.h"
#include "common/core/log.h"
#include "common/fem/forces.h"
#include "common/sim/checkpoint.h"
#include "common/sim/checkpoint_part.h"
#include "cutsim/v1/checkpoint.pb.h"

namespace cutsim::sim {
namespace {

/// Below this many free node slots a cut step could run out of room for
/// its copies: no more cuts.
constexpr int32_t kMinRoom = 64;

cutting::CutParams CutParamsOf(const LoadedScene& scene) {
  const auto& c = scene.scene.cutting();
  cutting::CutParams params;
  params.alpha = c.alpha();
  params.kappa = c.kappa();
  params.zeta = c.zeta();
  params.critical_stress = c.critical_stress();
  params.min_quality = c.min_quality();
  cutting::ValidateCutParams(params, {.file = scene.path.string(), .field = "cutting"});
  return params;
}

}  // namespace

/// An attempt that passed the tracker and the tool-motion test.
template <typename T>
struct CutPipeline<T>::Attempted {
  cutting::CutStep step;
  int32_t facet_tet = -1;
};

/// One cut step in progress: what its phases hand to each other.
template <typename T>
struct CutPipeline<T>::StepRun {
  const cutting::CutStep& step;
  int32_t facet_tet = -1;
  int32_t room = 0;  // free node slots for the step's copies
  Stopwatch watch;
  cutting::CriterionResult crit;
  std::atomic<bool> cancel{false};  // the walk's result is not wanted
  cutting::PreparedCut prepared;
  double prepare_time = 0;
  cutting::CutOutcome outcome;
  std::span<const cutting::Split> splits;  // the event's, once the topology is final
  TaskRef surface_half;
  bool surface_started = false;
  double surface_time = 0;
  double apply_begin = 0;  // from `watch`, s
  double fem_end = 0;
  CutSweep sweep;
};

template <typename T>
CutPipeline<T>::CutPipeline(const LoadedScene& scene, const mesh::TetMesh& mesh, int32_t node_capacity,
                            bool two_threads)
    : params_(CutParamsOf(scene)),
      cut_(mesh, node_capacity),
      tracker_(params_),
      lanes_(two_threads),
      log_cuts_(Log().should_log(spdlog::level::debug)) {}

template <typename T>
std::optional<CutSweep> CutPipeline<T>::TryCut(const CutContact& contact, const CutTargets<T>& targets) {
  Stopwatch watch;
  std::optional<CutSweep> sweep;
  if (const std::optional<Attempted> attempted = Attempt(contact, targets.world)) {
    sweep = RunStep(*attempted, targets);
  }
  cut_wall_time_ += watch.ElapsedSeconds();
  return sweep;
}

/// Phase `attempt`: the tracker's cut attempt (method paper §3.1). The method paper's
/// attempt reads the closest vertex only; a tool pressing straight down
/// also changes it as the surface deforms under the blade. A cut step needs
/// the tool itself to have moved along the surface since t0, by at least
/// half the cut segment d_v (scenes/README.md documents the choice).
template <typename T>
auto CutPipeline<T>::Attempt(const CutContact& contact, const cutting::WorldAccess& world)
    -> std::optional<Attempted> {
  cutting::Contact c;
  c.touching = contact.facet.touching;
  if (c.touching) {
    c.point = contact.facet.point;
    c.normal = contact.facet.normal;
    c.closest_node = contact.facet.closest_node;
    c.facet_tet = contact.facet_tet;
  }
  const int32_t anchor_before = tracker_.anchor_node();
  const cutting::CutAttempt attempt = tracker_.Update(c, world);
  if (tracker_.anchor_node() != anchor_before) anchor_tip_ = contact.pose.tip;
  if (!attempt.attempt) return std::nullopt;
  const Eigen::Vector3d moved = contact.pose.tip - anchor_tip_;
  const Eigen::Vector3d tangential = moved - moved.dot(attempt.normal) * attempt.normal;
  const double d_v = (world.Get(attempt.v1) - world.Get(attempt.v0)).norm();
  if (tangential.norm() < 0.5 * d_v) return std::nullopt;
  Attempted out;
  out.step.v0 = attempt.v0;
  out.step.v1 = attempt.v1;
  out.step.cp0 = attempt.cp0;
  out.step.cp = attempt.cp;
  out.step.normal = attempt.normal;
  // The blade's swept plane (tip at t0 → tip now) is the cut plane.
  out.step.blade = cutting::Blade{contact.pose.tip, contact.pose.blade_dir, contact.blade_length, anchor_tip_};
  out.facet_tet = attempt.facet_tet;
  return out;
}

/// The phases of one cut step after its attempt.
template <typename T>
std::optional<CutSweep> CutPipeline<T>::RunStep(const Attempted& attempted, const CutTargets<T>& t) {
  ++cut_attempts_;
  timing_ = {};
  StepRun run{.step = attempted.step, .facet_tet = attempted.facet_tet};
  run.room = t.model.node_capacity() - t.model.num_nodes();
  params_.max_splits_per_step = std::min(4096, run.room);
  WalkBesideCriterion(run, t);
  if (!CutDecided(run.crit, run.room)) return std::nullopt;
  if (!Separate(run, t)) return std::nullopt;
  Finish(run, t);
  return run.sweep;
}

/// Phases `walk` and `criterion`, side by side. With one thread the
/// criterion runs first, and a no skips the walk.
template <typename T>
void CutPipeline<T>::WalkBesideCriterion(StepRun& run, const CutTargets<T>& t) {
  run.cancel.store(run.room < kMinRoom, std::memory_order_relaxed);  // no room: no cut, no walk
  auto criterion = [&] {
    run.crit = Criterion(run, t);
    if (!run.crit.cut) run.cancel.store(true, std::memory_order_relaxed);
  };
  lanes_.Run(criterion, [&] {
    Stopwatch w;
    if (!run.cancel.load(std::memory_order_relaxed)) {
      run.prepared = stepper_.PrepareCut(cut_, run.step, t.world, params_, &run.cancel);
    }
    run.prepare_time = w.ElapsedSeconds();
  });
}

/// The stress criterion (method paper eqs. 6–11) on the contact elements around v1
/// and the contact facet's tet.
template <typename T>
cutting::CriterionResult CutPipeline<T>::Criterion(const StepRun& run, const CutTargets<T>& t) {
  const std::vector<int32_t> candidates = cut_.ContactElements(run.step.v1, run.facet_tet);
  const T* x = t.state.x.data();
  cutting::CriterionResult crit = cutting::EvaluateCriterion(
      candidates,
      [&](int32_t tet) { return fem::ElementCauchyStress(t.model, x, tet).template cast<double>().eval(); },
      params_);
  timing_.criterion = run.watch.ElapsedSeconds();
  return crit;
}

/// After the criterion: whether to cut (it says so and there is room for copies).
template <typename T>
bool CutPipeline<T>::CutDecided(const cutting::CriterionResult& crit, int32_t room) {
  sigma_c_ = crit.sigma_c;
  if (!crit.cut) return false;
  if (room < kMinRoom) {
    if (!warned_capacity_) Log().warn("node capacity exhausted: no more cuts");
    warned_capacity_ = true;
    return false;
  }
  return true;
}

/// Phase `topology`, then the FEM half here beside the surface half, which
/// the cut complex starts once its topology is final. True if the step
/// executed.
template <typename T>
bool CutPipeline<T>::Separate(StepRun& run, const CutTargets<T>& t) {
  auto surface_half = [&] {
    Stopwatch w;
    t.surface.UpdateAfterCut(cut_, run.splits);
    run.surface_time = w.ElapsedSeconds();
  };
  run.surface_half = TaskRef(surface_half);
  const cutting::SeparatedCallback on_separated = [this, &run](std::span<const cutting::Split> splits) {
    run.splits = splits;
    run.surface_started = true;
    lanes_.Start(run.surface_half);
  };
  SideBySide::JoinGuard join(lanes_);
  Stopwatch topology_watch;
  run.outcome = stepper_.ExecuteCut(cut_, run.step, t.world, params_, &run.prepared, &on_separated);
  // With one thread the surface half ran inside ExecuteCut: not topology.
  const double surface_here = lanes_.two_threads() ? 0.0 : run.surface_time;
  timing_.topology = run.prepare_time + topology_watch.ElapsedSeconds() - surface_here;
  const bool executed = TakeOutcome(run, t);
  if (executed && !run.outcome.event.empty()) {
    run.apply_begin = run.watch.ElapsedSeconds();
    FemHalf(run.outcome.event, t);
    run.fem_end = run.watch.ElapsedSeconds();
  }
  join.Join();
  return executed;
}

/// After ExecuteCut: counts a rejected step, or moves t0 to here for an
/// executed one (true) and records the area the blade swept.
template <typename T>
bool CutPipeline<T>::TakeOutcome(StepRun& run, const CutTargets<T>& t) {
  const cutting::CutOutcome& outcome = run.outcome;
  if (outcome.status != cutting::CutStatus::kExecuted) {
    ++cuts_rejected_;
    return false;
  }
  tracker_.OnCutExecuted();
  const cutting::Blade& blade = *run.step.blade;
  run.sweep = {anchor_tip_, blade.tip, blade.direction};
  anchor_tip_ = blade.tip;  // t0 := t: the next step sweeps from here
  if (log_cuts_) {
    Log().debug("cut {} at t={:.4f}: v0={} v1={} sigma_c={:.4g} Pa, {} splits, {} moves ({} limited, {} skipped)",
                cuts_ + 1, t.state.time, run.step.v0, run.step.v1, run.crit.sigma_c, outcome.event.splits.size(),
                outcome.event.moves.size(), outcome.moves_limited, outcome.moves_skipped);
  }
  timing_.splits = static_cast<int32_t>(outcome.event.splits.size());
  timing_.touched_tets = static_cast<int32_t>(outcome.event.touched_tets.size());
  return true;
}

/// The FEM half of a cut step (fem_event.h): the event's nodes, then the
/// elements, node masses and stable-step leaves.
template <typename T>
void CutPipeline<T>::FemHalf(const cutting::TopologyEvent& event, const CutTargets<T>& t) {
  ApplyEventNodesToFem(event, t.model, t.state);
  RecomputeAfterEvent(event, t.model, t.state, t.explicit_viscous, fem_event_);
}

/// Phase `finish`: the debris flags (they need both halves), the event
/// kept for checkpoints, counters and timing.
template <typename T>
void CutPipeline<T>::Finish(StepRun& run, const CutTargets<T>& t) {
  if (!run.outcome.event.empty()) {
    // Every executed step calls on_separated (cut_stepper.h); without it the
    // surface would silently miss this cut.
    CUTSIM_CHECK(run.surface_started, "cut executed without its surface half");
    Stopwatch flags_watch;
    t.surface.FlagDebrisFacets(cut_);
    timing_.fem = run.fem_end - run.apply_begin;
    timing_.surface = run.surface_time + flags_watch.ElapsedSeconds();
    timing_.apply = run.watch.ElapsedSeconds() - run.apply_begin;
    events_.push_back(std::move(run.outcome.event));
  }
  timing_.wall = run.watch.ElapsedSeconds();
  cut_timings_.push_back(timing_);
  ++cuts_;
  cut_this_frame_ = true;
}

template <typename T>
void CutPipeline<T>::ApplyRecordedEvent(cutting::TopologyEvent&& event, const CutTargets<T>& targets) {
  FemHalf(event, targets);
  targets.surface.UpdateAfterCut(cut_, event.splits);
  targets.surface.FlagDebrisFacets(cut_);
  events_.push_back(std::move(event));
}

template <typename T>
void CutPipeline<T>::AddToSummary(SimulationSummary& s) const {
  s.cuts = cuts_;
  s.cut_attempts = cut_attempts_;
  s.cuts_rejected = cuts_rejected_;
  s.cut_wall_time = cut_wall_time_;
}

template <typename T>
void CutPipeline<T>::AddToReport(ToolReport& r) const {
  r.cuts = cuts_;
  r.cut_this_frame = cut_this_frame_;
  r.sigma_c = sigma_c_;
}

template <typename T>
void CutPipeline<T>::Save(v1::CheckpointBody& body) const {
  body.set_cuts(cuts_);
  body.set_topology_version(cut_.version());
  for (const cutting::TopologyEvent& e : events_) *body.add_events() = EventToProto(e);
  v1::CutAttemptPart& p = *body.mutable_cut_attempt();
  const cutting::CutAttemptTracker::Memory m = tracker_.memory();
  p.set_anchor_node(m.anchor_node);
  Vec3ToProto(m.anchor_point, p.mutable_anchor_point());
  p.set_last_node(m.last_node);
  Vec3ToProto(m.last_point, p.mutable_last_point());
  p.set_frames_outside(m.frames_outside);
  Vec3ToProto(anchor_tip_, p.mutable_anchor_tip());
  p.set_cut_attempts(cut_attempts_);
  p.set_cuts_rejected(cuts_rejected_);
  p.set_sigma_c(sigma_c_);
}

template <typename T>
void CutPipeline<T>::Check(const v1::CheckpointBody& body, const PartCheck& check) const {
  const std::string& src = check.source;
  if (!body.has_cut_attempt()) FailPart(src, "cut_attempt", "missing: the checkpoint does not hold the cut test's state");
  const v1::CutAttemptPart& p = body.cut_attempt();
  CheckNodeOrNone(p.anchor_node(), check.num_nodes, src, "cut_attempt.anchor_node");
  CheckNodeOrNone(p.last_node(), check.num_nodes, src, "cut_attempt.last_node");
  (void)Vec3FromPart(p.anchor_point(), src, "cut_attempt.anchor_point");
  (void)Vec3FromPart(p.last_point(), src, "cut_attempt.last_point");
  (void)Vec3FromPart(p.anchor_tip(), src, "cut_attempt.anchor_tip");
  if (p.frames_outside() < 0) FailPart(src, "cut_attempt.frames_outside", "negative");
  if (!std::isfinite(p.sigma_c())) FailPart(src, "cut_attempt.sigma_c", "not finite");
}

template <typename T>
void CutPipeline<T>::Restore(const v1::CheckpointBody& body) {
  const v1::CutAttemptPart& p = body.cut_attempt();
  const std::string none;  // checked before: nothing throws here
  cuts_ = body.cuts();
  tracker_.set_memory({.anchor_node = p.anchor_node(),
                       .anchor_point = Vec3FromPart(p.anchor_point(), none, ""),
                       .last_node = p.last_node(),
                       .last_point = Vec3FromPart(p.last_point(), none, ""),
                       .frames_outside = p.frames_outside()});
  anchor_tip_ = Vec3FromPart(p.anchor_tip(), none, "");
  cut_attempts_ = p.cut_attempts();
  cuts_rejected_ = p.cuts_rejected();
  sigma_c_ = p.sigma_c();
}

template class CutPipeline<float>;
template class CutPipeline<double>;

}  // namespace cutsim::sim
