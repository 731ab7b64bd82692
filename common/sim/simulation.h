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

#include "common/mesh/tet_mesh.h"
#include "common/sim/scene_loader.h"

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
};

class Simulation {
 public:
  /// Builds everything the scene describes; throws InputError on bad input.
  static std::unique_ptr<Simulation> Create(const LoadedScene& scene,
                                            const SimulationOptions& options = {});
  virtual ~Simulation() = default;

  /// Advances one frame (scene time_step.frame_dt) in stable substeps.
  virtual SimStatus AdvanceFrame() = 0;

  /// Rest: kinetic energy and the largest residual free-node force below the
  /// scene's `rest` tolerances.
  [[nodiscard]] virtual bool AtRest() const = 0;

  [[nodiscard]] virtual double sim_time() const = 0;
  [[nodiscard]] virtual double frame_dt() const = 0;
  [[nodiscard]] virtual SimulationSummary Summary() const = 0;

  /// Current mesh (world positions) and rest mesh.
  [[nodiscard]] virtual mesh::TetMesh WorldMesh() const = 0;

  /// Writes the state to .vtu (displacement, velocity, von Mises, principal
  /// stress, element quality, fixed-node and opened-face markers).
  virtual void WriteVtu(const std::filesystem::path& path) const = 0;
};

}  // namespace cutsim::sim
