#pragma once
/// @file
/// Simulation: a scene brought to life. Builds the mesh, the FEM model and
/// state (in float or double, as the scene asks), the boundary conditions,
/// and advances the tissue frame by frame. No transport inside: the server
/// feeds tool poses in and publishes what it reads out.

#include <cstdint>
#include <filesystem>
#include <memory>
#include <string>
#include <vector>

#include <Eigen/Core>

#include "common/mesh/tet_mesh.h"
#include "common/sim/scene_loader.h"

namespace cutsim::v1 {
class CheckpointBody;
}  // namespace cutsim::v1

namespace cutsim::sim {

/// Overrides a user gives on the command line (0/empty = take the scene's).
struct SimulationOptions {
  int threads = 0;
  std::string precision;  ///< "", "float" or "double"
};

/// Why stepping stopped, if it did.
enum class SimStatus {
  kOk,
  kNonFinite,       ///< NaN/Inf detected: the diagnosis says where
  kEnergyRunaway,   ///< energy grew past the guard's bound
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
  std::string status = "ok";
  std::string diagnosis;
  // Tool and cutting (zero without a tool).
  uint64_t cuts = 0;             ///< executed cut steps
  uint64_t cut_attempts = 0;     ///< geometric attempts (seed §3.1)
  uint64_t cuts_rejected = 0;    ///< attempts that passed the stress test but were rolled back
  uint64_t topology_version = 0;
  int components = 1;            ///< face-connected parts of the mesh
  int opened_faces = 0;          ///< surface faces opened by cuts
  double min_rest_volume = 0.0;  ///< m³, smallest tet rest volume
  double total_mass = 0.0;       ///< kg
  double cut_wall_time = 0.0;    ///< s spent in cut steps (criterion + split + FEM update)
};

/// A tool pose: blade tip and unit direction from the tip toward the handle.
struct ToolPose {
  Eigen::Vector3d tip = Eigen::Vector3d::Zero();       ///< m, world
  Eigen::Vector3d blade_dir = Eigen::Vector3d::UnitZ(); ///< unit
};

/// What the tool did in the last frame: the haptic local model's inputs.
struct ToolReport {
  bool present = false;          ///< the scene has a tool
  bool touching = false;
  ToolPose pose;
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
  double topology = 0;   ///< CutMesh::PrepareCut + ExecuteCut: plane, splits, singularities, remeshing
  double fem = 0;        ///< the event applied to the FEM: nodes, elements, masses, incidence, stable step
  double surface = 0;    ///< surface slots + BVH update + debris flags
  double apply = 0;      ///< wall time from the event's nodes to the end of fem and surface
  int32_t splits = 0;        ///< vertex splits in the event
  int32_t touched_tets = 0;  ///< tets whose geometry or nodes changed
};

/// The observable mesh (for viewers): world positions, tets, boundary
/// surface and which of its faces a cut opened.
struct MeshView {
  mesh::Positions world;      // #N×3, m
  mesh::Positions rest;       // #N×3, m
  mesh::Tets tets;            // #T×4
  mesh::Triangles surface;    // #F×3
  std::vector<uint8_t> opened;  // #F
  std::vector<uint8_t> debris;  // #F with cutting (else empty): 1 on a facet of a debris piece (debris.h)
};

class Simulation {
 public:
  /// Builds everything the scene describes; throws InputError on bad input.
  static std::unique_ptr<Simulation> Create(const LoadedScene& scene,
                                            const SimulationOptions& options = {});
  virtual ~Simulation() = default;

  /// Advances one frame of `frame_time` seconds (0: the scene's
  /// time_step.frame_dt) in stable substeps: tool contact, then dynamics,
  /// then the cut test of seed §3.
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
  [[nodiscard]] virtual uint64_t topology_version() const = 0;
  /// Per executed cut step, its phases' wall times (empty without cutting).
  [[nodiscard]] virtual const std::vector<CutStepTiming>& CutTimings() const = 0;
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
};

}  // namespace cutsim::sim
