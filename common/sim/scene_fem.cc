#include "common/sim/scene_fem.h"

#include <omp.h>

#include <algorithm>
#include <cmath>
#include <limits>

#include <Eigen/Core>
#include <fmt/format.h>

#include "common/core/error.h"
#include "common/core/log.h"
#include "common/fem/forces.h"
#include "common/fem/stable_dt.h"
#include "common/sim/checkpoint_part.h"
#include "cutsim/v1/checkpoint.pb.h"

namespace cutsim::sim {
namespace {

using v1::BoundaryCondition;
using v1::TimeStepPolicy;

Eigen::Vector3d ToEigen(const v1::Vec3& v) { return {v.x(), v.y(), v.z()}; }

fem::Material MaterialOf(const v1::Material& m) {
  fem::Material fm;
  if (m.has_lame()) {
    fm.lambda = m.lame().lambda();
    fm.mu = m.lame().mu();
  } else {
    fm = fem::Material::FromYoungPoisson(m.young_poisson().youngs_modulus(), m.young_poisson().poisson_ratio(),
                                         m.density());
  }
  fm.density = m.density();
  fm.psi = m.damping_psi();
  fm.phi = m.damping_phi();
  return fm;
}

/// The scene's material for a mesh region: the first that lists it, else
/// the one without regions or box (`catch_all`), else −1.
int MaterialOfRegion(const v1::Scene& scene, int32_t region, int catch_all) {
  for (int i = 0; i < scene.materials_size(); ++i) {
    for (int r : scene.materials(i).regions()) {
      if (r == region) return i;
    }
  }
  return catch_all;
}

}  // namespace

fem::ElementKind ChooseElement(const v1::Scene& scene) {
  switch (scene.element()) {
    case v1::Scene::ELEMENT_LINEAR:
      return fem::ElementKind::kLinear;
    case v1::Scene::ELEMENT_NODAL_PRESSURE:
      return fem::ElementKind::kNodalPressure;
    default:
      break;
  }
  // AUTO: the linear tet locks as ν → ½ and is already markedly too stiff
  // at 0.45 (bench/README "Run time against error"), so any nearly
  // incompressible material takes the nodal-pressure element.
  for (const v1::Material& m : scene.materials()) {
    const fem::Material fm = MaterialOf(m);
    const double nu = fm.lambda / (2.0 * (fm.lambda + fm.mu));
    if (nu >= kNodalPressurePoisson) return fem::ElementKind::kNodalPressure;
  }
  return fem::ElementKind::kLinear;
}

namespace {

fem::ModelOptions MakeModelOptions(const LoadedScene& scene, int32_t num_nodes) {
  fem::ModelOptions o;
  o.node_capacity = NodeCapacity(scene.scene, num_nodes);
  o.gravity = ToEigen(scene.scene.gravity());
  o.source = scene.path.string();
  o.element = ChooseElement(scene.scene);
  return o;
}

/// The nodes a box or a plane selects.
std::vector<int32_t> NodesInBox(const v1::Box& box, const mesh::Positions& nodes) {
  std::vector<int32_t> out;
  const Eigen::Vector3d lo = ToEigen(box.min()), hi = ToEigen(box.max());
  for (int32_t n = 0; n < nodes.rows(); ++n) {
    const Eigen::Vector3d p = nodes.row(n).transpose();
    if ((p.array() >= lo.array()).all() && (p.array() <= hi.array()).all()) out.push_back(n);
  }
  return out;
}

std::vector<int32_t> NodesOnPlane(const v1::Plane& plane, const mesh::Positions& nodes) {
  std::vector<int32_t> out;
  const Eigen::Vector3d point = ToEigen(plane.point());
  const Eigen::Vector3d normal = ToEigen(plane.normal()).normalized();
  const double diag = (nodes.colwise().maxCoeff() - nodes.colwise().minCoeff()).norm();
  // Default tolerance: a millionth of the mesh size, enough for round-off in generated meshes.
  const double tol = plane.tolerance() > 0 ? plane.tolerance() : 1e-6 * diag;
  for (int32_t n = 0; n < nodes.rows(); ++n) {
    if (std::abs((nodes.row(n).transpose() - point).dot(normal)) <= tol) out.push_back(n);
  }
  return out;
}

}  // namespace

std::vector<fem::Material> MaterialsPerTet(const v1::Scene& scene, const mesh::TetMesh& mesh,
                                           const std::string& source) {
  std::vector<fem::Material> by_material;
  std::vector<int> boxed;  // materials that select by box, in scene order
  int catch_all = -1;
  for (int i = 0; i < scene.materials_size(); ++i) {
    by_material.push_back(MaterialOf(scene.materials(i)));
    if (scene.materials(i).has_box()) {
      boxed.push_back(i);
    } else if (scene.materials(i).regions_size() == 0) {
      catch_all = i;
    }
  }
  std::vector<fem::Material> per_tet(static_cast<size_t>(mesh.num_tets()));
  for (int32_t t = 0; t < mesh.num_tets(); ++t) {
    const int32_t region = mesh.regions.empty() ? 0 : mesh.regions[static_cast<size_t>(t)];
    int chosen = -1;
    if (!boxed.empty()) {
      Eigen::Vector3d centroid = Eigen::Vector3d::Zero();
      for (int c = 0; c < 4; ++c) centroid += mesh.nodes.row(mesh.tets(t, c)).transpose() / 4.0;
      for (int i : boxed) {
        const v1::Box& box = scene.materials(i).box();
        if ((centroid.array() >= ToEigen(box.min()).array()).all() &&
            (centroid.array() <= ToEigen(box.max()).array()).all()) {
          chosen = i;
          break;
        }
      }
    }
    if (chosen < 0) chosen = MaterialOfRegion(scene, region, catch_all);
    if (chosen < 0) {
      ThrowInputError({.file = source, .field = "materials"},
                      fmt::format("mesh region {} (tet {}) has no material; list it in a "
                                  "material's `regions`, cover it with a `box` or add a material without either",
                                  region, t));
    }
    per_tet[static_cast<size_t>(t)] = by_material[static_cast<size_t>(chosen)];
  }
  return per_tet;
}

std::vector<int32_t> SelectNodes(const BoundaryCondition& bc, const SceneMesh& sm, const std::string& source,
                                 int index) {
  const auto& nodes = sm.mesh.nodes;
  std::vector<int32_t> out;
  const std::string field = fmt::format("boundary[{}]", index);
  switch (bc.selector_case()) {
    case BoundaryCondition::kNodes:
      for (int k = 0; k < bc.nodes().ids_size(); ++k) {
        const int32_t id = bc.nodes().ids(k);
        if (id >= static_cast<int32_t>(nodes.rows())) {
          ThrowInputError({.file = source, .field = fmt::format("{}.nodes.ids[{}]", field, k)},
                          fmt::format("node {} does not exist (mesh has {} nodes)", id, nodes.rows()));
        }
        out.push_back(sm.permutation.old_to_new[static_cast<size_t>(id)]);
      }
      break;
    case BoundaryCondition::kBox:
      out = NodesInBox(bc.box(), nodes);
      break;
    case BoundaryCondition::kPlane:
      out = NodesOnPlane(bc.plane(), nodes);
      break;
    case BoundaryCondition::SELECTOR_NOT_SET:
      break;
  }
  if (out.empty()) {
    ThrowInputError({.file = source, .field = field}, "selects no node of the mesh");
  }
  return out;
}

int32_t NodeCapacity(const v1::Scene& scene, int32_t num_nodes) {
  const bool cutting = scene.has_tool() && scene.has_cutting() && scene.cutting().enabled();
  return cutting ? 3 * num_nodes + 1024 : num_nodes;
}

template <typename T>
mesh::Tets TetsMatrix(const fem::Model<T>& model) {
  mesh::Tets tets(model.num_tets(), 4);
  for (int32_t t = 0; t < model.num_tets(); ++t) {
    for (int c = 0; c < 4; ++c) tets(t, c) = model.tet_node(t, c);
  }
  return tets;
}

template <typename T>
SceneFem<T>::SceneFem(const LoadedScene& scene, const SceneMesh& mesh, const SimulationOptions& options)
    : model_(mesh.mesh, MaterialsPerTet(scene.scene, mesh.mesh, scene.path.string()),
             MakeModelOptions(scene, mesh.mesh.num_nodes())),
      state_(model_) {
  ApplyBoundaryConditions(scene, mesh);
  SetStepOptions(scene, options);
  SetRestTolerances(scene, mesh.mesh);
}

template <typename T>
void SceneFem<T>::ApplyBoundaryConditions(const LoadedScene& scene, const SceneMesh& mesh) {
  const auto& s = scene.scene;
  const std::string source = scene.path.string();
  // Which condition holds each node still and which moves it: a node both
  // fixed and displaced (or loaded and displaced) has no meaning.
  std::vector<int> fixed_by(static_cast<size_t>(model_.num_nodes()), -1);
  std::vector<int> moved_by(fixed_by), loaded_by(fixed_by);
  for (int i = 0; i < s.boundary_size(); ++i) {
    const auto& bc = s.boundary(i);
    const auto nodes = SelectNodes(bc, mesh, source, i);
    std::vector<int>& mark = bc.kind() == BoundaryCondition::KIND_FIXED          ? fixed_by
                             : bc.kind() == BoundaryCondition::KIND_DISPLACEMENT ? moved_by
                                                                                : loaded_by;
    for (int32_t n : nodes) mark[static_cast<size_t>(n)] = i;
    if (bc.kind() == BoundaryCondition::KIND_FIXED) {
      for (int32_t n : nodes) model_.SetFixed(n, true);
      continue;
    }
    if (bc.kind() == BoundaryCondition::KIND_DISPLACEMENT) {
      // Once per node, however often the ids list it.
      std::vector<int32_t> unique = nodes;
      std::sort(unique.begin(), unique.end());
      unique.erase(std::unique(unique.begin(), unique.end()), unique.end());
      for (int32_t n : unique) prescribed_.Add(model_, n, ToEigen(bc.displacement()), bc.ramp_time());
      continue;
    }
    // A force condition spreads its total force evenly over its nodes.
    const Eigen::Vector3d per_node = ToEigen(bc.force()) / static_cast<double>(nodes.size());
    for (int32_t n : nodes) {
      const Eigen::Vector3d prior(model_.prescribed_forces()[3 * n], model_.prescribed_forces()[3 * n + 1],
                                  model_.prescribed_forces()[3 * n + 2]);
      model_.SetPrescribedForce(n, (prior + per_node).template cast<T>());
    }
  }
  for (size_t n = 0; n < moved_by.size(); ++n) {
    const int other = fixed_by[n] >= 0 ? fixed_by[n] : loaded_by[n];
    if (moved_by[n] < 0 || other < 0) continue;
    ThrowInputError({.file = source, .field = fmt::format("boundary[{}]", moved_by[n])},
                    fmt::format("prescribes the displacement of node {} that boundary[{}] {}; a node is either "
                                "displaced or {}",
                                mesh.permutation.new_to_old.empty() ? static_cast<int64_t>(n)
                                                                    : mesh.permutation.new_to_old[n],
                                other, fixed_by[n] >= 0 ? "fixes" : "loads", fixed_by[n] >= 0 ? "fixed" : "loaded"));
  }
  num_free_ = 0;
  for (int32_t n = 0; n < model_.num_nodes(); ++n) num_free_ += model_.fixed(n) ? 0 : 1;
}

template <typename T>
void SceneFem<T>::PrescribeMotion(double t, std::span<const cutting::TopologyEvent> events) {
  if (prescribed_.empty()) return;
  prescribed_.Follow(events);
  prescribed_.Apply(model_, state_, t);
}

template <typename T>
void SceneFem<T>::SetStepOptions(const LoadedScene& scene, const SimulationOptions& options) {
  const auto& s = scene.scene;
  // Default threads: all cores for big meshes; one below 20 000 tets, where
  // a step takes microseconds and OpenMP's fork/barrier cost (worse on a
  // loaded machine) exceeds the work it would split.
  constexpr int32_t kParallelTets = 20000;
  CheckThreads(options.threads, {.field = "threads"});
  threads_ = options.threads > 0                ? options.threads
             : s.time_step().threads() > 0      ? s.time_step().threads()
             : model_.num_tets() >= kParallelTets ? omp_get_num_procs()
                                                : 1;
  step_options_.num_threads = threads_;
  step_options_.safety_factor = s.time_step().safety_factor();
  step_options_.dt_refresh_interval = s.time_step().refresh_every_steps();
  step_options_.viscous = ChooseViscous(s.time_step().viscosity());
  step_options_.mass_damping = s.mass_damping();
  if (s.time_step().fixed_dt() <= 0) return;
  (void)fem::CurrentTimeStep(model_, state_, step_options_);  // refreshes the estimate
  const double limit = fem::EffectiveStableStep(state_);
  if (s.time_step().fixed_dt() > limit) {
    ThrowInputError({.file = scene.path.string(), .field = "time_step.fixed_dt"},
                    fmt::format("{:.3g} s exceeds the estimated stable limit {:.3g} s", s.time_step().fixed_dt(),
                                limit));
  }
  // Substeps are min(safety × limit, max_dt): pin them to the fixed step.
  step_options_.max_dt = s.time_step().fixed_dt();
  step_options_.safety_factor = 1.0;
}

/// AUTO: implicit viscosity only where the explicit viscous limit would cut
/// the step below 80% of the elastic one (then it costs a CG solve per step
/// but saves more in step count).
template <typename T>
fem::ViscousTreatment SceneFem<T>::ChooseViscous(TimeStepPolicy::Viscosity v) {
  if (v == TimeStepPolicy::VISCOSITY_EXPLICIT || !model_.damped()) return fem::ViscousTreatment::kExplicit;
  if (v == TimeStepPolicy::VISCOSITY_IMPLICIT) return fem::ViscousTreatment::kImplicit;
  T with_visc = std::numeric_limits<T>::infinity(), elastic = with_visc;
  for (int32_t t = 0; t < model_.num_tets(); ++t) {
    with_visc = std::min(with_visc, fem::ElementStableStep(model_, state_.x.data(), t, true));
    elastic = std::min(elastic, fem::ElementStableStep(model_, state_.x.data(), t, false));
  }
  const bool implicit = with_visc < T(0.8) * elastic;
  Log().info("stable step: elastic {:.3g} s, with explicit viscosity {:.3g} s → {} viscosity",
             static_cast<double>(elastic), static_cast<double>(with_visc), implicit ? "implicit" : "explicit");
  return implicit ? fem::ViscousTreatment::kImplicit : fem::ViscousTreatment::kExplicit;
}

/// Rest tolerances (scene `rest`, else defaults): kinetic energy below
/// 1e-8 × m·|g|·L (L the bounding-box diagonal: the gravity work scale),
/// residual force below 1e-3 × the mean nodal load (weight + prescribed).
/// With no load at all, absolute 1e-12 J and 1e-9 N.
template <typename T>
void SceneFem<T>::SetRestTolerances(const LoadedScene& scene, const mesh::TetMesh& mesh) {
  const auto& nodes = mesh.nodes;
  const double diag = (nodes.colwise().maxCoeff() - nodes.colwise().minCoeff()).norm();
  const double g = model_.gravity().template cast<double>().norm();
  const double mass = model_.TotalMass();
  double prescribed = 0;
  for (int32_t n = 0; n < model_.num_nodes(); ++n) {
    prescribed += Eigen::Vector3d(model_.prescribed_forces()[3 * n], model_.prescribed_forces()[3 * n + 1],
                                  model_.prescribed_forces()[3 * n + 2])
                      .norm();
  }
  const double load = mass * g + prescribed;
  const auto& rest = scene.scene.rest();
  rest_.kinetic_energy = rest.kinetic_energy() > 0 ? rest.kinetic_energy() : (load > 0 ? 1e-8 * load * diag : 1e-12);
  rest_.residual_force = rest.residual_force() > 0 ? rest.residual_force()
                                                   : (load > 0 ? 1e-3 * load / std::max(1, num_free_) : 1e-9);
}

template <typename T>
double SceneFem<T>::KineticEnergy() const {
  return fem::KineticEnergy(model_, state_.v.data());
}

template <typename T>
double SceneFem<T>::ResidualForce() const {
  double worst = 0;
  const auto& f = state_.f;
  for (int32_t n = 0; n < model_.num_nodes(); ++n) {
    if (model_.fixed(n)) continue;
    const double f2 = static_cast<double>(f[3 * n] * f[3 * n] + f[3 * n + 1] * f[3 * n + 1] +
                                          f[3 * n + 2] * f[3 * n + 2]);
    worst = std::max(worst, f2);
  }
  return std::sqrt(worst);
}

template <typename T>
double SceneFem<T>::MaxDisplacement() const {
  double worst = 0;
  for (int32_t i = 0; i < 3 * model_.num_nodes(); i += 3) {
    double d2 = 0;
    for (int k = 0; k < 3; ++k) {
      const double d = static_cast<double>(state_.x[i + k] - model_.rest_positions()[i + k]);
      d2 += d * d;
    }
    worst = std::max(worst, d2);
  }
  return std::sqrt(worst);
}

namespace {

template <typename T, typename Repeated>
void AppendValues(const std::vector<T>& values, size_t count, Repeated* out) {
  out->Reserve(static_cast<int>(count));
  for (size_t i = 0; i < count; ++i) out->Add(static_cast<double>(values[i]));
}

/// Values of `in` into the first in.size() entries of `out` (sized before).
template <typename T, typename Repeated>
void CopyValues(const Repeated& in, std::vector<T>& out) {
  for (int i = 0; i < in.size(); ++i) out[static_cast<size_t>(i)] = static_cast<T>(in[i]);
}

/// `values` has `expected` entries (or none when `may_be_empty`), none NaN.
template <typename Repeated>
void CheckValues(const Repeated& values, size_t expected, bool may_be_empty, const std::string& source,
                 const std::string& field) {
  const auto n = static_cast<size_t>(values.size());
  if (n != expected && !(may_be_empty && n == 0)) {
    FailPart(source, field, fmt::format("{} values, this simulation needs {}", n, expected));
  }
  for (int i = 0; i < values.size(); ++i) {
    if (std::isnan(values[i])) FailPart(source, fmt::format("{}[{}]", field, i), "not a number");
  }
}

}  // namespace

template <typename T>
void SceneFem<T>::Save(v1::CheckpointBody& b) const {
  const fem::State<T>& s = state_;
  b.set_sim_time(s.time);
  b.set_steps(s.step);
  const size_t n3 = 3 * static_cast<size_t>(model_.num_nodes());
  AppendValues(s.x, n3, b.mutable_positions());
  AppendValues(s.v, n3, b.mutable_velocities());
  v1::FemStepPart& p = *b.mutable_fem_step();
  if (s.viscous_dv.size() >= n3) AppendValues(s.viscous_dv, n3, p.mutable_viscous_dv());
  AppendValues(s.element_dt, s.element_dt.size(), p.mutable_element_dt());
  AppendValues(s.dt_tree, s.dt_tree.size(), p.mutable_dt_tree());
  AppendValues(s.element_dt_at_spectral, s.element_dt_at_spectral.size(), p.mutable_element_dt_at_spectral());
  if (s.cg_precond_step >= 0) {
    AppendValues(s.cg_precond, 6 * static_cast<size_t>(model_.num_nodes()), p.mutable_cg_precond());
  }
  p.set_dt_leaves(s.dt_leaves);
  p.set_dt_refreshed_step(s.dt_refreshed_step);
  p.set_dt_topology_version(s.dt_topology_version);
  p.set_dt_ratio(s.dt_ratio);
  p.set_dt_spectral_step(s.dt_spectral_step);
  p.set_dt_bound_at_spectral(s.dt_bound_at_spectral);
  p.set_dt_element_drift(s.dt_element_drift);
  p.set_dt_held(s.dt_held);
  p.set_dt_grow_since(s.dt_grow_since);
  p.set_dt_grow_delay(s.dt_grow_delay);
  p.set_dt_last_grow_step(s.dt_last_grow_step);
  p.set_dt_calm_refreshes(s.dt_calm_refreshes);
  p.set_dt_trusted(s.dt_trusted);
  p.set_dt_spectral_topology_version(s.dt_spectral_topology_version);
  p.set_cg_precond_step(s.cg_precond_step);
  p.set_cg_precond_dt(s.cg_precond_dt);
  p.set_cg_precond_topology(s.cg_precond_topology);
}

template <typename T>
void SceneFem<T>::Check(const v1::CheckpointBody& b, const PartCheck& check) const {
  const std::string& src = check.source;
  if (!b.has_fem_step()) FailPart(src, "fem_step", "missing: the checkpoint does not hold the step's state");
  const v1::FemStepPart& p = b.fem_step();
  const fem::State<T>& s = state_;
  const size_t n = static_cast<size_t>(check.num_nodes);
  CheckValues(p.viscous_dv(), 3 * n, true, src, "fem_step.viscous_dv");
  CheckValues(p.element_dt(), s.element_dt.size(), false, src, "fem_step.element_dt");
  CheckValues(p.dt_tree(), s.dt_tree.size(), false, src, "fem_step.dt_tree");
  CheckValues(p.element_dt_at_spectral(), s.element_dt_at_spectral.size(), true, src,
              "fem_step.element_dt_at_spectral");
  CheckValues(p.cg_precond(), 6 * n, true, src, "fem_step.cg_precond");
  if (p.dt_leaves() != s.dt_leaves) {
    FailPart(src, "fem_step.dt_leaves", fmt::format("{}, this simulation has {}", p.dt_leaves(), s.dt_leaves));
  }
  for (const double v : {p.dt_ratio(), p.dt_bound_at_spectral(), p.dt_element_drift(), p.dt_held(), p.cg_precond_dt()}) {
    if (!std::isfinite(v) || v < 0) FailPart(src, "fem_step", "a negative or non-finite step or ratio");
  }
  if (p.dt_grow_delay() < 0 || p.dt_calm_refreshes() < 0) {
    FailPart(src, "fem_step", "negative step-growth counters");
  }
}

template <typename T>
void SceneFem<T>::Restore(const v1::CheckpointBody& b) {
  fem::State<T>& s = state_;
  CopyValues(b.positions(), s.x);
  CopyValues(b.velocities(), s.v);
  s.time = b.sim_time();
  s.step = b.steps();
  const v1::FemStepPart& p = b.fem_step();
  CopyValues(p.viscous_dv(), s.viscous_dv);
  CopyValues(p.element_dt(), s.element_dt);
  CopyValues(p.dt_tree(), s.dt_tree);
  if (p.element_dt_at_spectral_size() > 0) CopyValues(p.element_dt_at_spectral(), s.element_dt_at_spectral);
  const bool has_precond = p.cg_precond_size() > 0;
  if (has_precond) CopyValues(p.cg_precond(), s.cg_precond);
  s.dt_refreshed_step = p.dt_refreshed_step();
  s.dt_topology_version = p.dt_topology_version();
  s.dt_ratio = p.dt_ratio();
  s.dt_spectral_step = p.dt_spectral_step();
  s.dt_bound_at_spectral = p.dt_bound_at_spectral();
  s.dt_element_drift = p.dt_element_drift();
  s.dt_held = p.dt_held();
  s.dt_grow_since = p.dt_grow_since();
  s.dt_grow_delay = p.dt_grow_delay();
  s.dt_last_grow_step = p.dt_last_grow_step();
  s.dt_calm_refreshes = p.dt_calm_refreshes();
  s.dt_trusted = p.dt_trusted();
  s.dt_spectral_topology_version = p.dt_spectral_topology_version();
  // Without the preconditioner's values, it is rebuilt at the next step.
  s.cg_precond_step = has_precond ? p.cg_precond_step() : -1;
  s.cg_precond_dt = p.cg_precond_dt();
  s.cg_precond_topology = p.cg_precond_topology();
}

template mesh::Tets TetsMatrix<float>(const fem::Model<float>&);
template mesh::Tets TetsMatrix<double>(const fem::Model<double>&);
template class SceneFem<float>;
template class SceneFem<double>;

}  // namespace cutsim::sim
