#pragma once
/// @file
/// The cut test of a frame (method paper §3), written once as a sequence of named
/// phases:
///
///   attempt → [walk | criterion] → topology → [FEM half | surface half] → finish
///
/// - attempt: the contact feeds the cut-attempt tracker (t0, v0, v1); a
///   step needs the tool itself to have moved along the surface since t0.
/// - walk: CutStepper::PrepareCut, the blade's plane and the split set
///   (reads the cut complex and the world positions only);
///   criterion: the stress criterion (eqs. 6–11) on the contact elements,
///   which cancels the walk when it says no.
/// - topology: CutStepper::ExecuteCut on the cut complex (CutMesh):
///   splits, singularities, then the remeshing moves.
/// - FEM half: the event's nodes, elements, node masses and stable-step
///   leaves (fem_event.h); surface half: surface slots, BVH and debris
///   (SurfaceTracker::UpdateAfterCut), started as soon as the topology is
///   final (cutting::SeparatedCallback), beside the moves and the FEM half.
/// - finish: the debris flags of the changed facets (they need both
///   halves), the event kept for checkpoints, counters and timing.
///
/// The bracketed pairs run side by side through one SideBySide helper:
/// with one thread, in order on the caller; with two, on the caller and a
/// worker. Neither phase of a pair reads what the other writes, so both
/// give the same results bit for bit.

#include <atomic>
#include <cstdint>
#include <optional>
#include <span>
#include <vector>

#include <Eigen/Core>

#include "common/core/clock.h"
#include "common/cutting/criterion.h"
#include "common/cutting/cut_attempt.h"
#include "common/cutting/cut_mesh.h"
#include "common/cutting/cut_params.h"
#include "common/cutting/cut_stepper.h"
#include "common/cutting/topology_event.h"
#include "common/cutting/world_access.h"
#include "common/fem/model.h"
#include "common/fem/state.h"
#include "common/sim/fem_event.h"
#include "common/sim/scene_loader.h"
#include "common/sim/side_by_side.h"
#include "common/sim/stage.h"
#include "common/sim/surface_tracker.h"
#include "common/sim/tool_contact.h"
#include "common/sim/types.h"

namespace cutsim::sim {

/// What the cut test reads of the frame's tool contact.
struct CutContact {
  const ContactFacet& facet;  ///< the frame's contact facet
  int32_t facet_tet = -1;     ///< its owning tet (−1: none)
  ToolPose pose;              ///< the tool this frame
  double blade_length = 0;    ///< m
};

/// What a cut step changes: the FEM, the world access over its positions
/// and the surface.
template <typename T>
struct CutTargets {
  fem::Model<T>& model;
  fem::State<T>& state;
  cutting::WorldAccess& world;
  SurfaceTracker& surface;
  bool explicit_viscous = true;  ///< the step options' viscosity treatment
};

template <typename T>
class CutPipeline final : public CheckpointedStage {
 public:
  /// The scene's cutting parameters (InputError naming the scene's
  /// `cutting` field if invalid) and cut complex over the uncut `mesh`.
  /// `two_threads`: run the paired phases side by side.
  CutPipeline(const LoadedScene& scene, const mesh::TetMesh& mesh, int32_t node_capacity, bool two_threads);

  void BeginFrame() { cut_this_frame_ = false; }
  /// The cut test after the frame's dynamics. Returns the area the blade
  /// swept if a cut step executed (the blade is then in its own cut).
  std::optional<CutSweep> TryCut(const CutContact& contact, const CutTargets<T>& targets);
  /// A recorded event (checkpoint replay; the cut complex has applied it
  /// already): its FEM and surface halves in order on this thread.
  void ApplyRecordedEvent(cutting::TopologyEvent&& event, const CutTargets<T>& targets);

  [[nodiscard]] cutting::CutMesh& cut_mesh() { return cut_; }
  [[nodiscard]] const cutting::CutMesh& cut_mesh() const { return cut_; }
  [[nodiscard]] const std::vector<cutting::TopologyEvent>& events() const { return events_; }
  [[nodiscard]] const std::vector<CutStepTiming>& timings() const { return cut_timings_; }
  [[nodiscard]] uint64_t cuts() const { return cuts_; }
  void set_cuts(uint64_t cuts) { cuts_ = cuts; }
  /// The cut test's state across frames: the attempt's anchor and the tip
  /// when it was set (Simulation::Memo copies it).
  struct AttemptState {
    cutting::CutAttemptTracker tracker;
    Eigen::Vector3d anchor_tip;
  };
  [[nodiscard]] AttemptState attempt_state() const { return {tracker_, anchor_tip_}; }
  void set_attempt_state(const AttemptState& s) {
    tracker_ = s.tracker;
    anchor_tip_ = s.anchor_tip;
  }
  // ---- checkpoint part (stage.h) -------------------------------------------
  /// Every topology event so far, the cut complex's version, the counters,
  /// and the attempt's anchor t0 with the tip when it was set. The events
  /// are checked and replayed by the engine (CheckCheckpointBody,
  /// ApplyRecordedEvent) before Restore, which sets the rest.
  void Save(v1::CheckpointBody& body) const override;
  void Check(const v1::CheckpointBody& body, const PartCheck& check) const override;
  void Restore(const v1::CheckpointBody& body) override;

  /// Cut counters and time into a summary; cut fields into a tool report.
  void AddToSummary(SimulationSummary& s) const;
  void AddToReport(ToolReport& r) const;

 private:
  struct Attempted;
  struct StepRun;
  [[nodiscard]] std::optional<Attempted> Attempt(const CutContact& contact, const cutting::WorldAccess& world);
  std::optional<CutSweep> RunStep(const Attempted& attempted, const CutTargets<T>& t);
  void WalkBesideCriterion(StepRun& run, const CutTargets<T>& t);
  [[nodiscard]] cutting::CriterionResult Criterion(const StepRun& run, const CutTargets<T>& t);
  [[nodiscard]] bool CutDecided(const cutting::CriterionResult& crit, int32_t room);
  bool Separate(StepRun& run, const CutTargets<T>& t);
  bool TakeOutcome(StepRun& run, const CutTargets<T>& t);
  void FemHalf(const cutting::TopologyEvent& event, const CutTargets<T>& t);
  void Finish(StepRun& run, const CutTargets<T>& t);

  cutting::CutParams params_;
  cutting::CutMesh cut_;
  cutting::CutStepper stepper_;  // runs the cut steps on cut_, with their scratch
  cutting::CutAttemptTracker tracker_;
  SideBySide lanes_;
  std::vector<cutting::TopologyEvent> events_;
  Eigen::Vector3d anchor_tip_ = Eigen::Vector3d::Zero();  // tool tip when t0 was set
  FemEventScratch fem_event_;
  CutStepTiming timing_;  // the cut step in progress
  std::vector<CutStepTiming> cut_timings_;
  uint64_t cuts_ = 0;
  uint64_t cut_attempts_ = 0;
  uint64_t cuts_rejected_ = 0;
  double cut_wall_time_ = 0;
  double sigma_c_ = 0;  // Pa, the last criterion's
  bool cut_this_frame_ = false;
  bool warned_capacity_ = false;
  // Whether the per-cut debug line is wanted, asked once: the logger's
  // level is set once, in main, and asking costs cold code per cut step.
  bool log_cuts_ = false;
};

extern template class CutPipeline<float>;
extern template class CutPipeline<double>;

}  // namespace cutsim::sim
