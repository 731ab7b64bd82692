#pragma once
/// @file
/// The types the simulation's stages share and its interface speaks: run
/// options, status and summary, the tool's pose and report, a cut step's
/// timing, the observable mesh, and the adapter that shows the FEM state's
/// positions to the cut code. Below every stage: it includes no stage.

#include <cstddef>
#include <cstdint>
#include <string>
#include <type_traits>
#include <vector>

#include <Eigen/Core>

#include "common/core/tool_pose.h"
#include "common/cutting/world_access.h"
#include "common/mesh/mesh_frame.h"
#include "common/mesh/tet_mesh.h"

namespace cutsim::v1 {
class SessionMetrics;
}  // namespace cutsim::v1

namespace cutsim::sim {

/// Overrides a user gives on the command line (0/empty = take the scene's).
struct SimulationOptions {
  int threads = 0;
  std::string precision;   ///< "", "float" or "double"
  std::string integrator;  ///< "", "explicit", "implicit" or "auto"
  /// Wall-clock budget of a frame's dynamics, s (0: none, every step runs
  /// to its tolerance). With a budget the implicit step stops Newton and
  /// PCG at it and carries what is left of the residual into the next
  /// frame (ImplicitCounters reports it). Real-time sessions set one.
  double frame_budget = 0;
};

/// Why stepping stopped, if it did. Each names what happened: the state
/// itself stays the last completed step's and is finite in every case.
enum class SimStatus {
  kOk,
  kNonFinite,       ///< a computed value (an element force) was NaN/Inf: the diagnosis says where
  kEnergyRunaway,   ///< a node passed the speed guard
  /// The step found no admissible iterate with every value finite (an
  /// implicit step whose energy is +∞ at every trial, even in substeps, as
  /// where a nodal volume is inverted), or its step size was not usable.
  kStepFailed,
};

/// The summary's status names (`SimulationSummary::status`).
inline constexpr const char* kStatusOk = "ok";
/// The run went on, but some implicit steps stopped above their force
/// tolerance: the state is not the answer to the stated tolerance.
inline constexpr const char* kStatusUnconverged = "unconverged";

/// What the implicit step did over a run (zero with the explicit one).
struct ImplicitCounters {
  int64_t steps = 0;                 ///< backward Euler steps
  int64_t newton_iterations = 0;     ///< summed over the steps
  int max_newton_iterations = 0;     ///< largest in one step
  int64_t pcg_iterations = 0;        ///< summed over the steps
  int max_pcg_iterations = 0;        ///< largest summed over one step's solves
  int64_t unconverged_steps = 0;     ///< steps stopped at the Newton cap
  int64_t factorizations = 0;        ///< factorisations completed
  int64_t tangent_assemblies = 0;    ///< Newton iterations that assembled K
  int64_t out_of_time_steps = 0;     ///< steps stopped at the frame's budget
  int64_t over_budget_steps = 0;     ///< steps that went past it, their residual above the carry limit
  double max_residual_out_of_time = 0;  ///< N, largest residual force a budgeted step left
  double max_residual_unconverged = 0;  ///< N, largest residual force a capped step left
  int64_t recovered_steps = 0;       ///< failed steps redone in substeps
  int64_t factor_corrections = 0;    ///< low-rank corrections of the factor after cuts
  int max_correction_rank = 0;       ///< largest such correction, DOFs
  double max_correction_seconds = 0; ///< s, longest build of one (on the correction thread)
};

/// Numbers a run reports (the headless JSON summary).
struct SimulationSummary {
  std::string scene;
  std::string precision;
  int num_nodes = 0;
  int num_tets = 0;
  int num_free_nodes = 0;
  int threads = 1;
  int64_t steps = 0;
  int64_t frames = 0;
  double dt = 0.0;              ///< s, last step size
  double stable_dt = 0.0;       ///< s, last stable-limit estimate (before safety factor)
  double sim_time = 0.0;        ///< s
  double wall_time = 0.0;       ///< s spent stepping
  double tet_steps_per_s = 0.0;
  double realtime_factor = 0.0; ///< simulated s per wall s
  double kinetic_energy = 0.0;  ///< J
  double strain_energy = 0.0;   ///< J
  double residual_force = 0.0;  ///< N, largest net force on a free node
  double max_displacement = 0.0;///< m
  bool at_rest = false;
  /// "ok"; "unconverged" (the run finished, some implicit steps did not
  /// reach their tolerance: ReportConvergence); or why stepping stopped:
  /// "non_finite", "runaway", "step_failed" (SimStatus).
  std::string status = kStatusOk;
  std::string diagnosis;
  std::string integrator = "explicit";  ///< "explicit" or "implicit" (after AUTO's choice)
  ImplicitCounters implicit;
  // Tool and cutting (zero without a tool).
  uint64_t cuts = 0;             ///< executed cut steps
  uint64_t cut_attempts = 0;     ///< geometric attempts (method paper §3.1)
  uint64_t cuts_rejected = 0;    ///< attempts that passed the stress test but were rolled back
  uint64_t topology_version = 0;
  int components = 1;            ///< face-connected parts of the mesh
  int opened_faces = 0;          ///< surface faces opened by cuts
  double min_rest_volume = 0.0;  ///< m³, smallest tet rest volume
  double total_mass = 0.0;       ///< kg
  double cut_wall_time = 0.0;    ///< s spent in cut steps (criterion + split + FEM update)
};

/// Per-session measures for the instructor, from the physics
/// (session_metrics.h): the message itself (cutsim/v1/metrics.proto), which
/// the meter writes, the reports print and the checkpoint keeps, so a new
/// measure is one field there plus the code that computes it. Complete
/// where "cutsim/v1/metrics.pb.h" is included.
using SessionMetrics = v1::SessionMetrics;

/// |f| on the tool at one whole-mesh sample of the session's measures (0
/// out of contact).
struct ForceSample {
  double t = 0.0;      ///< s, simulated
  double force = 0.0;  ///< N
};

/// A tool pose: blade tip and unit direction from the tip toward the handle
/// (common/core/tool_pose.h).
using ToolPose = ::cutsim::ToolPose;

/// What the tool did in the last frame: the haptic local model's inputs.
struct ToolReport {
  bool present = false;          ///< the scene has a tool
  bool touching = false;
  ToolPose pose;
  double blade_length = 0.0;    ///< m
  Eigen::Vector3d point = Eigen::Vector3d::Zero();   ///< C_p, m
  Eigen::Vector3d normal = Eigen::Vector3d::UnitZ(); ///< outward facet normal
  Eigen::Vector3d force_on_tool = Eigen::Vector3d::Zero();  ///< N
  double depth = 0.0;            ///< indentation, m
  uint64_t cuts = 0;             ///< cut steps so far
  bool cut_this_frame = false;
  double sigma_c = 0.0;          ///< last evaluated cutting stress (eq. 10), Pa
};

/// Time of one executed cut step by phase, s (the cut benchmark's split),
/// each on the thread that ran it. On one thread the phases follow each
/// other and `wall` is their sum plus the bookkeeping between them; with
/// two, the criterion runs beside the topology's plane and split set, and
/// the surface half (slots, BVH, debris) beside the remeshing moves and the
/// FEM half: it starts inside `topology`, once the splits are final.
struct CutStepTiming {
  double wall = 0;       ///< the whole step, wall time
  double criterion = 0;  ///< contact elements + stress criterion (eqs. 6–11)
  double topology = 0;   ///< CutStepper::PrepareCut + ExecuteCut: plane, splits, singularities, remeshing
  double fem = 0;        ///< the event applied to the FEM: nodes, elements, masses, incidence, stable step
  double surface = 0;    ///< surface slots + BVH update + debris flags
  double apply = 0;      ///< wall time from the event's nodes to the end of fem and surface
  int32_t splits = 0;        ///< vertex splits in the event
  int32_t touched_tets = 0;  ///< tets whose geometry or nodes changed
};

/// The observable mesh (for viewers): world positions, tets, boundary
/// surface, which of its faces a cut opened and which belong to debris.
/// `FillMeshView` fills the mesh fields only; the frame's identity and the
/// stress field are the caller's.
using MeshView = mesh::MeshFrame;

/// World positions of the FEM state (float or double) for the cut code.
template <typename T>
class StateWorld final : public cutting::WorldAccess {
 public:
  /// `x`: #N·3 positions, m; kept by reference (the state's own vector).
  explicit StateWorld(std::vector<T>& x) : x_(x) {}
  [[nodiscard]] Eigen::Vector3d Get(int32_t n) const override {
    const size_t i = 3 * static_cast<size_t>(n);
    return {static_cast<double>(x_[i]), static_cast<double>(x_[i + 1]), static_cast<double>(x_[i + 2])};
  }
  void Set(int32_t n, const Eigen::Vector3d& p) override {
    const size_t i = 3 * static_cast<size_t>(n);
    for (int k = 0; k < 3; ++k) x_[i + static_cast<size_t>(k)] = static_cast<T>(p[k]);
  }
  [[nodiscard]] const double* Xyz() const override {
    if constexpr (std::is_same_v<T, double>) return x_.data();
    return nullptr;
  }

 private:
  std::vector<T>& x_;
};

}  // namespace cutsim::sim
