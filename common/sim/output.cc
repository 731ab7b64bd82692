#include "common/sim/output.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <vector>

#include <Eigen/Eigenvalues>
#include <fmt/format.h>

#include "common/fem/forces.h"
#include "common/fem/stable_dt.h"
#include "common/mesh/mesh_io.h"
#include "common/mesh/quality.h"

namespace cutsim::sim {
namespace {

const char* StatusName(SimStatus status) {
  switch (status) {
    case SimStatus::kOk:
      return "ok";
    case SimStatus::kNonFinite:
      return "non_finite";
    case SimStatus::kEnergyRunaway:
      return "runaway";
    case SimStatus::kStepFailed:
      return "step_failed";
  }
  return "step_failed";
}

/// Per tet: principal stresses σ1 ≥ σ2 ≥ σ3, von Mises and element quality.
template <typename T>
void StressFields(const fem::Model<T>& model, const T* x, const mesh::TetMesh& world, mesh::VtkField& von_mises,
                  mesh::VtkField& principal, mesh::VtkField& quality) {
  const mesh::TetQuality q = mesh::ComputeTetQuality(world);
  std::vector<double> tet_volume;
  std::vector<double> node_pressure;
  fem::ComputeNodePressures(model, x, tet_volume, node_pressure);
  for (int32_t t = 0; t < model.num_tets(); ++t) {
    const Eigen::Matrix3d sigma =
        fem::ElementCauchyStress(model, x, t, std::span<const double>(node_pressure)).template cast<double>();
    Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> eig(sigma, Eigen::EigenvaluesOnly);
    const Eigen::Vector3d p = eig.eigenvalues().reverse();  // σ1 ≥ σ2 ≥ σ3
    for (int k = 0; k < 3; ++k) principal.values[3 * t + k] = p[k];
    von_mises.values[t] = std::sqrt(0.5 * ((p[0] - p[1]) * (p[0] - p[1]) + (p[1] - p[2]) * (p[1] - p[2]) +
                                           (p[2] - p[0]) * (p[2] - p[0])));
    quality.values[t] = q.mean_ratio[static_cast<size_t>(t)];
  }
}

}  // namespace

template <typename T>
void FillFemView(const fem::Model<T>& model, const T* x, MeshView& view) {
  const int32_t N = model.num_nodes();
  view.world.resize(N, 3);
  view.rest.resize(N, 3);
  for (int32_t i = 0; i < N; ++i) {
    for (int k = 0; k < 3; ++k) {
      view.world(i, k) = static_cast<double>(x[3 * static_cast<size_t>(i) + static_cast<size_t>(k)]);
      view.rest(i, k) = static_cast<double>(model.rest_positions()[3 * i + k]);
    }
  }
  view.tets.resize(model.num_tets(), 4);
  for (int32_t t = 0; t < model.num_tets(); ++t) {
    for (int c = 0; c < 4; ++c) view.tets(t, c) = model.tet_node(t, c);
  }
}

template <typename T>
mesh::TetMesh WorldMesh(const fem::Model<T>& model, const T* x, const std::vector<int32_t>& regions) {
  mesh::TetMesh m;
  m.nodes.resize(model.num_nodes(), 3);
  for (int32_t n = 0; n < model.num_nodes(); ++n) {
    for (int k = 0; k < 3; ++k) m.nodes(n, k) = static_cast<double>(x[3 * n + k]);
  }
  m.tets = TetsMatrix(model);
  m.regions = regions;
  return m;
}

template <typename T>
SimulationSummary QuickSummaryOf(const std::string& scene_name, const SceneFem<T>& fem, const RunCounters& run,
                                 bool at_rest) {
  const fem::Model<T>& model = fem.model();
  const fem::State<T>& state = fem.state();
  SimulationSummary s;
  s.scene = scene_name;
  s.precision = sizeof(T) == 4 ? "float" : "double";
  s.num_nodes = model.num_nodes();
  s.num_tets = model.num_tets();
  s.num_free_nodes = fem.num_free();
  s.threads = fem.threads();
  s.steps = state.step;
  s.frames = run.frames;
  s.dt = run.last_dt;
  s.stable_dt = state.dt_tree.empty() ? 0.0 : fem::EffectiveStableStep(state);
  s.sim_time = state.time;
  s.wall_time = run.wall_time;
  s.tet_steps_per_s =
      run.wall_time > 0 ? static_cast<double>(state.step) * model.num_tets() / run.wall_time : 0.0;
  s.realtime_factor = run.wall_time > 0 ? state.time / run.wall_time : 0.0;
  s.kinetic_energy = fem.KineticEnergy();
  s.residual_force = fem.ResidualForce();
  s.max_displacement = fem.MaxDisplacement();
  s.at_rest = at_rest;
  s.status = StatusName(run.status);
  s.diagnosis = run.diagnosis;
  s.topology_version = model.topology_version();
  return s;
}

void ReportConvergence(SimulationSummary& s) {
  const ImplicitCounters& c = s.implicit;
  if (s.status != kStatusOk || c.unconverged_steps <= 0) return;
  s.status = kStatusUnconverged;
  s.diagnosis = fmt::format(
      "{} of {} implicit steps stopped at the Newton cap above their force tolerance; largest residual {:.3g} N",
      c.unconverged_steps, c.steps, c.max_residual_unconverged);
}

std::string StepFailureDiagnosis(const fem::StepResult& r) {
  std::string where;
  if (r.element >= 0) where += fmt::format(" at element {}", r.element);
  if (r.node >= 0) where += fmt::format(" at node {}", r.node);
  if (r.status == fem::StepStatus::kNoAdmissibleIterate) {
    return fmt::format("step {}: the implicit step found no iterate of finite energy, even in 2, 4 and 8 substeps "
                       "(a nodal volume inverted, or an overflow); {} = {:.6g} N at its last iterate; the state "
                       "is the last completed step's",
                       r.step, r.quantity, r.value);
  }
  return fmt::format("step {}: {} = {:.6g}{}", r.step, r.quantity, r.value, where);
}

SimStatus StepFailureStatus(const fem::StepResult& r) {
  switch (r.status) {
    case fem::StepStatus::kOk:
      return SimStatus::kOk;
    case fem::StepStatus::kNonFiniteForce:
      return SimStatus::kNonFinite;
    case fem::StepStatus::kRunaway:
      return SimStatus::kEnergyRunaway;
    case fem::StepStatus::kBadTimeStep:
    case fem::StepStatus::kNoAdmissibleIterate:
      return SimStatus::kStepFailed;
  }
  return SimStatus::kStepFailed;
}

template <typename T>
void AddWholeMeshSummary(const SceneFem<T>& fem, const SurfaceTracker& surface, SimulationSummary& s) {
  const fem::Model<T>& model = fem.model();
  s.strain_energy = fem::StrainEnergy(model, fem.state().x.data());
  s.total_mass = model.TotalMass();
  int32_t components = 1;
  (void)cutting::ConnectedComponents(TetsMatrix(model), &components);
  s.components = components;
  s.opened_faces = surface.OpenedFaces();
  double min_volume = std::numeric_limits<double>::infinity();
  for (int32_t t = 0; t < model.num_tets(); ++t) {
    min_volume = std::min(min_volume, static_cast<double>(model.rest_volume(t)));
  }
  s.min_rest_volume = min_volume;
}

template <typename T>
void WriteStateVtu(const std::filesystem::path& path, const fem::Model<T>& model, const fem::State<T>& state,
                   const std::vector<int32_t>& regions, const cutting::CutMesh* cut) {
  const mesh::TetMesh world = WorldMesh(model, state.x.data(), regions);
  const int32_t N = model.num_nodes(), Tn = model.num_tets();
  mesh::VtkField displacement{"displacement", 3, std::vector<double>(3 * static_cast<size_t>(N))};
  mesh::VtkField velocity{"velocity", 3, std::vector<double>(3 * static_cast<size_t>(N))};
  mesh::VtkField fixed{"fixed", 1, std::vector<double>(static_cast<size_t>(N))};
  for (int32_t n = 0; n < N; ++n) {
    for (int k = 0; k < 3; ++k) {
      displacement.values[3 * n + k] = static_cast<double>(state.x[3 * n + k] - model.rest_positions()[3 * n + k]);
      velocity.values[3 * n + k] = static_cast<double>(state.v[3 * n + k]);
    }
    fixed.values[n] = model.fixed(n) ? 1.0 : 0.0;
  }
  mesh::VtkField von_mises{"von_mises", 1, std::vector<double>(static_cast<size_t>(Tn))};
  mesh::VtkField principal{"principal_stress", 3, std::vector<double>(3 * static_cast<size_t>(Tn))};
  mesh::VtkField quality{"quality", 1, std::vector<double>(static_cast<size_t>(Tn))};
  StressFields(model, state.x.data(), world, von_mises, principal, quality);
  // Per tet, how many of its faces a cut opened (ParaView: Threshold > 0).
  mesh::VtkField cut_faces{"cut_faces", 1, std::vector<double>(static_cast<size_t>(Tn), 0.0)};
  if (cut != nullptr) {
    for (const cutting::SurfaceFace& face : cut->surface_slots()) {
      if (face.alive && face.opened) cut_faces.values[static_cast<size_t>(face.tet)] += 1.0;
    }
  }
  const mesh::VtkField point_fields[] = {displacement, velocity, fixed};
  const mesh::VtkField cell_fields[] = {von_mises, principal, quality, cut_faces};
  mesh::WriteVtu(path.string(), world, point_fields, cell_fields);
}

#define CUTSIM_SIM_OUTPUT_INSTANTIATE(T)                                                                         \
  template void FillFemView<T>(const fem::Model<T>&, const T*, MeshView&);                                        \
  template mesh::TetMesh WorldMesh<T>(const fem::Model<T>&, const T*, const std::vector<int32_t>&);               \
  template SimulationSummary QuickSummaryOf<T>(const std::string&, const SceneFem<T>&, const RunCounters&, bool); \
  template void AddWholeMeshSummary<T>(const SceneFem<T>&, const SurfaceTracker&, SimulationSummary&);            \
  template void WriteStateVtu<T>(const std::filesystem::path&, const fem::Model<T>&, const fem::State<T>&,        \
                                 const std::vector<int32_t>&, const cutting::CutMesh*);

CUTSIM_SIM_OUTPUT_INSTANTIATE(float)
CUTSIM_SIM_OUTPUT_INSTANTIATE(double)

}  // namespace cutsim::sim
