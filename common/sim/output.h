#pragma once
/// @file
/// What a Simulation shows: the mesh view for viewers, the world mesh, the
/// run summary, and the .vtu state file. Reads the FEM and the surface,
/// changes nothing.

#include <filesystem>
#include <string>
#include <vector>

#include "common/cutting/cut_mesh.h"
#include "common/fem/integrator.h"
#include "common/fem/model.h"
#include "common/fem/state.h"
#include "common/mesh/tet_mesh.h"
#include "common/sim/scene_fem.h"
#include "common/sim/surface_tracker.h"
#include "common/sim/types.h"

namespace cutsim::sim {

/// The run's own counters, as the frame loop keeps them.
struct RunCounters {
  int64_t frames = 0;
  double wall_time = 0;  ///< s spent stepping
  double last_dt = 0;    ///< s
  SimStatus status = SimStatus::kOk;
  std::string diagnosis;
};

/// Copies world and rest positions and the tets of the model into `view`
/// (the surface part: SurfaceTracker::FillView).
template <typename T>
void FillFemView(const fem::Model<T>& model, const T* x, MeshView& view);

/// The mesh at its world positions `x`, with the scene mesh's `regions`.
template <typename T>
[[nodiscard]] mesh::TetMesh WorldMesh(const fem::Model<T>& model, const T* x, const std::vector<int32_t>& regions);

/// Summary without the whole-mesh passes (the cut fields are the cut
/// pipeline's: CutPipeline::AddToSummary).
template <typename T>
[[nodiscard]] SimulationSummary QuickSummaryOf(const std::string& scene_name, const SceneFem<T>& fem,
                                               const RunCounters& run, bool at_rest);

/// Makes `s`'s status honest about the implicit step: a run that went on
/// while some steps stopped at the Newton cap above their force tolerance
/// is "unconverged", its diagnosis the count and the largest residual (N).
/// Steps stopped at a frame budget within its carry limit are not: their
/// residual is bounded and carries into the next frame (their own counters
/// report them). A stopped run keeps its own status.
void ReportConvergence(SimulationSummary& s);

/// The status a failed step stops the run with: "non_finite" only for a
/// non-finite computed value, "runaway" for the speed guard, "step_failed"
/// for a step that found no admissible iterate (all values finite) or had
/// no usable step size.
[[nodiscard]] SimStatus StepFailureStatus(const fem::StepResult& r);

/// What a failed step's diagnosis says: the step, the quantity and its
/// value, and the element or node when the step names one.
[[nodiscard]] std::string StepFailureDiagnosis(const fem::StepResult& r);

/// The whole-mesh passes of a summary: strain energy, total mass,
/// face-connected parts, opened faces, smallest rest volume.
template <typename T>
void AddWholeMeshSummary(const SceneFem<T>& fem, const SurfaceTracker& surface, SimulationSummary& s);

/// Writes the state to .vtu (see Simulation::WriteVtu); `cut` (or null)
/// gives the per-tet count of opened faces.
template <typename T>
void WriteStateVtu(const std::filesystem::path& path, const fem::Model<T>& model, const fem::State<T>& state,
                   const std::vector<int32_t>& regions, const cutting::CutMesh* cut);

}  // namespace cutsim::sim
