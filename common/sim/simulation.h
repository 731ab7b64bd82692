#pragma once
/// @file
/// Simulation: a scene brought to life. Builds the mesh, the FEM model and
/// state (in float or double, as the scene asks), the boundary conditions,
/// and advances the tissue frame by frame. No transport inside: the server
/// feeds tool poses in and publishes what it reads out.

#include <cstdint>
#include <filesystem>
#include <memory>
#include <optional>
#include <span>
#include <string>
#include <vector>

#include <Eigen/Core>

#include "common/cutting/topology_event.h"
#include "common/mesh/tet_mesh.h"
#include "common/sim/frame_times.h"
#include "common/sim/incision_score.h"
#include "common/sim/scene_loader.h"
#include "common/sim/types.h"  // re-exported: the types the interface speaks
#include "cutsim/v1/metrics.pb.h"

namespace cutsim::v1 {
class CheckpointBody;
class CheckpointEvent;
}  // namespace cutsim::v1

namespace cutsim::sim {

/// A stored topology event and the field that names it in errors (e.g.
/// "events[3]" in a checkpoint, "record at byte 812.event" in a journal).
struct NamedEvent {
  const v1::CheckpointEvent* event = nullptr;
  std::string field;
};

/// What a checkpoint body leaves out, copied exactly in memory
/// (Simulation::Memo): the integrator's held and cached step state, the
/// tool's contact and grip, the cut test's anchor and the tip when it was
/// set, the surface as tracked (its BVH refit frame by frame), the
/// counters, the measures' and the score's running state. Opaque; only the
/// Simulation that made it reads it.
class SimulationMemo {
 public:
  virtual ~SimulationMemo() = default;
};

class Simulation {
 public:
  /// Builds everything the scene describes; throws InputError on bad input.
  static std::unique_ptr<Simulation> Create(const LoadedScene& scene,
                                            const SimulationOptions& options = {});
  virtual ~Simulation() = default;

  /// Advances one frame of `frame_time` seconds (0: the scene's
  /// time_step.frame_dt) in stable substeps: tool contact, then dynamics,
  /// then the cut test of method paper §3, then the session's measures.
  virtual SimStatus AdvanceFrame(double frame_time = 0.0) = 0;

  /// Whether the scene has a tool, and when its scripted path ends (0: none).
  [[nodiscard]] virtual bool has_tool() const = 0;
  [[nodiscard]] virtual double path_end_time() const = 0;
  /// Drives the tool from outside (haptic link) instead of the scene's path,
  /// from the next frame on.
  virtual void SetToolPose(const ToolPose& pose) = 0;
  [[nodiscard]] virtual ToolReport Tool() const = 0;
  /// K = −∂f_tool/∂x_tool at the current contact (see tool_contact.h), N/m;
  /// zero without contact. Computed on demand (only a haptic client needs it).
  [[nodiscard]] virtual Eigen::Matrix3d ContactStiffness() const = 0;
  /// The same K with the tissue's part taken from the static patch of free
  /// nodes around the contact only (PatchStiffness in contact_stiffness.h),
  /// whatever the integrator: without the implicit step's whole-body
  /// response. For comparisons of the haptic side's stiffness term.
  [[nodiscard]] virtual Eigen::Matrix3d PatchContactStiffness() const = 0;
  [[nodiscard]] virtual uint64_t topology_version() const = 0;
  /// Wall time of the last frame's stages (frame_times.h).
  [[nodiscard]] virtual const FrameTimes& LastFrameTimes() const = 0;
  /// Per executed cut step, its phases' wall times (empty without cutting).
  [[nodiscard]] virtual const std::vector<CutStepTiming>& CutTimings() const = 0;
  /// The session's measures so far (session_metrics.h).
  [[nodiscard]] virtual const SessionMetrics& Metrics() const = 0;
  /// |f| on the tool at each sample of the measures (for the session report).
  [[nodiscard]] virtual const std::vector<ForceSample>& ForceSeries() const = 0;
  /// The scene's planned incision (null without one) and the score against
  /// it so far (incision_score.h), with the cut points it scored.
  [[nodiscard]] virtual const PlannedIncision* Plan() const = 0;
  [[nodiscard]] virtual std::optional<IncisionScore> Score() const = 0;
  [[nodiscard]] virtual std::span<const CutPoint> ScoredCutPoints() const = 0;
  /// Copies the observable mesh into `view` (reusing its storage).
  virtual void FillMeshView(MeshView& view) const = 0;

  /// Rest: kinetic energy and the largest residual free-node force below the
  /// scene's `rest` tolerances.
  [[nodiscard]] virtual bool AtRest() const = 0;

  [[nodiscard]] virtual double sim_time() const = 0;
  [[nodiscard]] virtual double frame_dt() const = 0;
  [[nodiscard]] virtual SimulationSummary Summary() const = 0;
  /// Summary without the whole-mesh passes (strain energy, components,
  /// opened faces, smallest rest volume, total mass stay 0): cheap enough
  /// for progress lines and the per-second session status.
  [[nodiscard]] virtual SimulationSummary QuickSummary() const = 0;

  /// Current mesh (world positions) and rest mesh.
  [[nodiscard]] virtual mesh::TetMesh WorldMesh() const = 0;

  /// Writes the state to .vtu (displacement, velocity, von Mises, principal
  /// stress, element quality, fixed-node markers, and per tet the number of
  /// its faces opened by cuts, `cut_faces`, so ParaView can show the cut).
  virtual void WriteVtu(const std::filesystem::path& path) const = 0;

  // ---- checkpoints (common/sim/checkpoint.h writes and reads the files) ----
  /// The state a checkpoint keeps: scene identity, every topology event so
  /// far in order, time and counters, world positions and velocities.
  [[nodiscard]] virtual v1::CheckpointBody CheckpointState() const = 0;
  /// Brings a Simulation freshly created from the same scene to `body`:
  /// replays its events through the cut complex and the FEM, then sets
  /// positions and velocities. Everything is checked first: on an InputError
  /// (naming `source` and the field) nothing has been applied.
  virtual void RestoreCheckpointState(const v1::CheckpointBody& body, const std::string& source) = 0;
  /// Every topology event so far, in order (what a checkpoint stores; the
  /// event journal appends the new ones after each frame).
  [[nodiscard]] virtual std::span<const cutting::TopologyEvent> TopologyEvents() const = 0;
  /// Applies stored events on top of the current tissue (an event journal's
  /// after its checkpoint, before the first frame): checked first exactly as
  /// a checkpoint's events are (CheckEvents in checkpoint.h), then replayed
  /// through the cut complex and the FEM. Positions and velocities of the
  /// existing nodes stay; node copies start at their originals'. The cut
  /// count becomes at least `cuts`. On an InputError (naming `source` and
  /// the event's field) nothing has been applied.
  virtual void ApplyTopologyEvents(std::span<const NamedEvent> events, uint64_t cuts, const std::string& source) = 0;

  // ---- exact restore in memory (a debrief's seek) ---------------------------
  /// The state CheckpointState() leaves out, copied (allocates about the
  /// size of the FEM state). With the body taken at the same moment, a
  /// fresh Simulation restored from both continues exactly as this one
  /// does: the explicit integrator's held step, its caches and the tool's
  /// contact are part of it. The implicit integrator's factor is not: it is
  /// rebuilt, so an implicit scene continues to within its tolerances.
  [[nodiscard]] virtual std::unique_ptr<const SimulationMemo> Memo() const = 0;
  /// After RestoreCheckpointState(body) on a fresh Simulation of the same
  /// scene and precision: applies a Memo() taken with `body`. Throws
  /// InputError when `memo` comes from another kind of Simulation or its
  /// sizes differ (nothing is applied then).
  virtual void RestoreMemo(const SimulationMemo& memo) = 0;
};

}  // namespace cutsim::sim
