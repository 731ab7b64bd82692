#pragma once
/// @file
/// Scene → FEM: the model and state a scene describes (one material per
/// tet, boundary conditions: fixed, loaded and displaced nodes), the step options (threads, safety factor,
/// viscosity treatment, fixed step) and the rest tolerances. The first
/// stage of a Simulation; every other stage takes its model and state as
/// arguments.

#include <cstdint>
#include <span>
#include <string>
#include <vector>

#include "common/fem/integrator.h"
#include "common/fem/model.h"
#include "common/fem/state.h"
#include "common/sim/prescribed_motion.h"
#include "common/sim/scene_loader.h"
#include "common/sim/stage.h"
#include "common/sim/scene_mesh.h"
#include "common/sim/types.h"

namespace cutsim::sim {

/// One fem::Material per tet: the first material whose `box` holds the
/// tet's rest centroid, else the scene's region → material mapping.
/// Throws InputError (field "materials") for a region without a material.
[[nodiscard]] std::vector<fem::Material> MaterialsPerTet(const v1::Scene& scene, const mesh::TetMesh& mesh,
                                                         const std::string& source);

/// Nodes a boundary condition selects, in the reordered numbering. Throws
/// InputError (field "boundary[i]…") for a node that does not exist or a
/// selector that selects nothing.
[[nodiscard]] std::vector<int32_t> SelectNodes(const v1::BoundaryCondition& bc, const SceneMesh& sm,
                                               const std::string& source, int index);

/// Poisson's ratio from which ELEMENT_AUTO picks the nodal-pressure element.
inline constexpr double kNodalPressurePoisson = 0.4;

/// The element a scene asks for: its `element` field, or for ELEMENT_AUTO
/// the nodal-pressure element when some material has ν ≥
/// kNodalPressurePoisson (ν = λ/(2(λ + μ)) for Lamé materials), else the
/// linear one.
[[nodiscard]] fem::ElementKind ChooseElement(const v1::Scene& scene);

/// Node capacity: a cut copies nodes (method paper §3.2), so cutting reserves room
/// for them.
[[nodiscard]] int32_t NodeCapacity(const v1::Scene& scene, int32_t num_nodes);

/// The model's tets as a matrix.  // #T×4
template <typename T>
[[nodiscard]] mesh::Tets TetsMatrix(const fem::Model<T>& model);

/// When the tissue counts as at rest (scene `rest`, else defaults tied to
/// its load; see SceneFem).
struct RestTolerances {
  double kinetic_energy = 0;  ///< J
  double residual_force = 0;  ///< N, largest net force on a free node
};

/// The FEM of a scene, set up: owns the model and state (in T, float or
/// double) and the options every step uses. Not movable: adapters hold
/// references into the state.
template <typename T>
class SceneFem final : public CheckpointedStage {
 public:
  /// Builds the model over `mesh` (materials, boundary conditions), picks
  /// threads and viscosity and checks a fixed step against the stable
  /// limit. Throws InputError naming the scene file and field.
  SceneFem(const LoadedScene& scene, const SceneMesh& mesh, const SimulationOptions& options);
  SceneFem(const SceneFem&) = delete;
  SceneFem& operator=(const SceneFem&) = delete;

  [[nodiscard]] fem::Model<T>& model() { return model_; }
  [[nodiscard]] const fem::Model<T>& model() const { return model_; }
  [[nodiscard]] fem::State<T>& state() { return state_; }
  [[nodiscard]] const fem::State<T>& state() const { return state_; }
  [[nodiscard]] const fem::StepOptions& step_options() const { return step_options_; }
  [[nodiscard]] int threads() const { return threads_; }
  [[nodiscard]] int num_free() const { return num_free_; }
  [[nodiscard]] const RestTolerances& rest() const { return rest_; }

  /// The prescribed displacements (KIND_DISPLACEMENT conditions).
  [[nodiscard]] const PrescribedMotion<T>& prescribed() const { return prescribed_; }
  /// Moves the prescribed nodes to their positions at time `t` (s), after
  /// taking in the cut's node copies from `events` (every topology event so
  /// far, in order). Nothing to do without KIND_DISPLACEMENT conditions.
  void PrescribeMotion(double t, std::span<const cutting::TopologyEvent> events);

  /// Kinetic energy, J; the largest net force on a free node, N; the largest
  /// displacement from rest, m.
  [[nodiscard]] double KineticEnergy() const;
  [[nodiscard]] double ResidualForce() const;
  [[nodiscard]] double MaxDisplacement() const;

  // ---- checkpoint part (stage.h) -------------------------------------------
  /// Time, step count, the live nodes' positions and velocities, and what
  /// the next steps start from: the stable-step estimator's held step, its
  /// per-element bounds and history, and the implicit viscous solve's warm
  /// start and preconditioner. (Positions and velocities are checked with
  /// the tissue, CheckCheckpointBody.)
  void Save(v1::CheckpointBody& body) const override;
  void Check(const v1::CheckpointBody& body, const PartCheck& check) const override;
  void Restore(const v1::CheckpointBody& body) override;

 private:
  void ApplyBoundaryConditions(const LoadedScene& scene, const SceneMesh& mesh);
  void SetStepOptions(const LoadedScene& scene, const SimulationOptions& options);
  [[nodiscard]] fem::ViscousTreatment ChooseViscous(v1::TimeStepPolicy::Viscosity v);
  void SetRestTolerances(const LoadedScene& scene, const mesh::TetMesh& mesh);

  fem::Model<T> model_;
  fem::State<T> state_;
  fem::StepOptions step_options_;
  PrescribedMotion<T> prescribed_;
  int threads_ = 1;
  int num_free_ = 0;
  RestTolerances rest_;
};

extern template class SceneFem<float>;
extern template class SceneFem<double>;

}  // namespace cutsim::sim
