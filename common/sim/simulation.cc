#include "common/sim/simulation.h"

#include <omp.h>

#include <algorithm>
#include <cmath>
#include <limits>

#include <Eigen/Eigenvalues>
#include <fmt/format.h>

#include "common/core/clock.h"
#include "common/core/error.h"
#include "common/core/log.h"
#include "common/fem/forces.h"
#include "common/fem/integrator.h"
#include "common/fem/model.h"
#include "common/fem/stable_dt.h"
#include "common/fem/state.h"
#include "common/mesh/mesh_io.h"
#include "common/mesh/quality.h"
#include "common/sim/scene_mesh.h"

namespace cutsim::sim {
namespace {

using v1::BoundaryCondition;
using v1::TimeStepPolicy;

Eigen::Vector3d ToEigen(const v1::Vec3& v) { return {v.x(), v.y(), v.z()}; }

/// One fem::Material per tet from the scene's region → material mapping.
std::vector<fem::Material> MaterialsPerTet(const v1::Scene& scene, const mesh::TetMesh& mesh,
                                           const std::string& source) {
  std::vector<fem::Material> by_material;
  int catch_all = -1;
  for (int i = 0; i < scene.materials_size(); ++i) {
    const auto& m = scene.materials(i);
    fem::Material fm;
    if (m.has_lame()) {
      fm.lambda = m.lame().lambda();
      fm.mu = m.lame().mu();
    } else {
      fm = fem::Material::FromYoungPoisson(m.young_poisson().youngs_modulus(),
                                           m.young_poisson().poisson_ratio(), m.density());
    }
    fm.density = m.density();
    fm.psi = m.damping_psi();
    fm.phi = m.damping_phi();
    by_material.push_back(fm);
    if (m.regions_size() == 0) catch_all = i;
  }
  std::vector<fem::Material> per_tet(static_cast<size_t>(mesh.num_tets()));
  for (int32_t t = 0; t < mesh.num_tets(); ++t) {
    const int32_t region = mesh.regions.empty() ? 0 : mesh.regions[static_cast<size_t>(t)];
    int chosen = -1;
    for (int i = 0; i < scene.materials_size() && chosen < 0; ++i) {
      for (int r : scene.materials(i).regions()) {
        if (r == region) {
          chosen = i;
          break;
        }
      }
    }
    if (chosen < 0) chosen = catch_all;
    if (chosen < 0) {
      ThrowInputError({.file = source, .field = "materials"},
                      fmt::format("mesh region {} (tet {}) has no material; list it in a "
                                  "material's `regions` or add a material without regions",
                                  region, t));
    }
    per_tet[static_cast<size_t>(t)] = by_material[static_cast<size_t>(chosen)];
  }
  return per_tet;
}

/// Nodes a boundary condition selects (in the reordered numbering).
std::vector<int32_t> SelectNodes(const BoundaryCondition& bc, const SceneMesh& sm,
                                 const std::string& source, int index) {
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
    case BoundaryCondition::kBox: {
      const Eigen::Vector3d lo = ToEigen(bc.box().min()), hi = ToEigen(bc.box().max());
      for (int32_t n = 0; n < nodes.rows(); ++n) {
        const Eigen::Vector3d p = nodes.row(n).transpose();
        if ((p.array() >= lo.array()).all() && (p.array() <= hi.array()).all()) out.push_back(n);
      }
      break;
    }
    case BoundaryCondition::kPlane: {
      const Eigen::Vector3d point = ToEigen(bc.plane().point());
      const Eigen::Vector3d normal = ToEigen(bc.plane().normal()).normalized();
      const double diag = (nodes.colwise().maxCoeff() - nodes.colwise().minCoeff()).norm();
      // Default tolerance: a millionth of the mesh size, enough for round-off in generated meshes.
      const double tol = bc.plane().tolerance() > 0 ? bc.plane().tolerance() : 1e-6 * diag;
      for (int32_t n = 0; n < nodes.rows(); ++n) {
        if (std::abs((nodes.row(n).transpose() - point).dot(normal)) <= tol) out.push_back(n);
      }
      break;
    }
    case BoundaryCondition::SELECTOR_NOT_SET:
      break;
  }
  if (out.empty()) {
    ThrowInputError({.file = source, .field = field}, "selects no node of the mesh");
  }
  return out;
}

template <typename T>
class Engine final : public Simulation {
 public:
  Engine(const LoadedScene& scene, SceneMesh scene_mesh, const SimulationOptions& options)
      : scene_(scene),
        mesh_(std::move(scene_mesh)),
        model_(mesh_.mesh, MaterialsPerTet(scene.scene, mesh_.mesh, scene.path.string()),
               MakeModelOptions(scene)),
        state_(model_) {
    const auto& s = scene.scene;
    const std::string source = scene.path.string();
    for (int i = 0; i < s.boundary_size(); ++i) {
      const auto& bc = s.boundary(i);
      const auto nodes = SelectNodes(bc, mesh_, source, i);
      if (bc.kind() == BoundaryCondition::KIND_FIXED) {
        for (int32_t n : nodes) model_.SetFixed(n, true);
      } else {
        const Eigen::Vector3d per_node = ToEigen(bc.force()) / static_cast<double>(nodes.size());
        for (int32_t n : nodes) {
          const Eigen::Vector3d prior(model_.prescribed_forces()[3 * n],
                                      model_.prescribed_forces()[3 * n + 1],
                                      model_.prescribed_forces()[3 * n + 2]);
          model_.SetPrescribedForce(n, (prior + per_node).template cast<T>());
        }
      }
    }
    num_free_ = 0;
    for (int32_t n = 0; n < model_.num_nodes(); ++n) num_free_ += model_.fixed(n) ? 0 : 1;

    threads_ = options.threads > 0 ? options.threads
                                   : (s.time_step().threads() > 0 ? s.time_step().threads()
                                                                  : omp_get_max_threads());
    step_options_.num_threads = threads_;
    step_options_.safety_factor = s.time_step().safety_factor();
    step_options_.dt_refresh_interval = s.time_step().refresh_every_steps();
    step_options_.viscous = ChooseViscous(s.time_step().viscosity());
    if (s.time_step().fixed_dt() > 0) {
      const double bound = static_cast<double>(fem::CurrentTimeStep(model_, state_, step_options_)) /
                           step_options_.safety_factor;
      if (s.time_step().fixed_dt() > bound) {
        ThrowInputError({.file = source, .field = "time_step.fixed_dt"},
                        fmt::format("{:.3g} s exceeds the stable limit {:.3g} s", s.time_step().fixed_dt(), bound));
      }
      // Advance takes min(safety × bound, max_dt): pin it to the fixed step.
      step_options_.max_dt = s.time_step().fixed_dt();
      step_options_.safety_factor = 1.0;
    }
    SetRestTolerances();
    Log().info("scene '{}': {} nodes, {} tets, {} free nodes, {} precision, {} threads, viscosity {}",
               s.name(), model_.num_nodes(), model_.num_tets(), num_free_, precision_name(),
               threads_, step_options_.viscous == fem::ViscousTreatment::kImplicit ? "implicit" : "explicit");
  }

  SimStatus AdvanceFrame() override {
    if (status_ != SimStatus::kOk) return status_;
    Stopwatch watch;
    const fem::StepResult r =
        fem::Advance(model_, state_, scene_.scene.time_step().frame_dt(), step_options_);
    wall_time_ += watch.ElapsedSeconds();
    last_dt_ = r.dt;
    ++frames_;
    if (!r.ok()) {
      status_ = r.status == fem::StepStatus::kRunaway ? SimStatus::kEnergyRunaway : SimStatus::kNonFinite;
      diagnosis_ = fmt::format("step {}: {} = {:.6g} at element {} / node {}", r.step, r.quantity,
                               r.value, r.element, r.node);
    }
    return status_;
  }

  bool AtRest() const override {
    if (frames_ == 0) return false;
    return KineticEnergy() <= rest_kinetic_energy_ && ResidualForce() <= rest_residual_force_;
  }

  double sim_time() const override { return state_.time; }
  double frame_dt() const override { return scene_.scene.time_step().frame_dt(); }

  SimulationSummary Summary() const override {
    SimulationSummary s;
    s.scene = scene_.scene.name();
    s.precision = precision_name();
    s.num_nodes = model_.num_nodes();
    s.num_tets = model_.num_tets();
    s.num_free_nodes = num_free_;
    s.threads = threads_;
    s.steps = state_.step;
    s.frames = frames_;
    s.dt = last_dt_;
    s.stable_dt = state_.dt_tree.empty() ? 0.0 : static_cast<double>(fem::StableStepBound(state_));
    s.sim_time = state_.time;
    s.wall_time = wall_time_;
    s.tet_steps_per_s = wall_time_ > 0 ? static_cast<double>(state_.step) * model_.num_tets() / wall_time_ : 0.0;
    s.realtime_factor = wall_time_ > 0 ? state_.time / wall_time_ : 0.0;
    s.kinetic_energy = KineticEnergy();
    s.strain_energy = fem::StrainEnergy(model_, state_.x.data());
    s.residual_force = ResidualForce();
    s.max_displacement = MaxDisplacement();
    s.at_rest = AtRest();
    s.status = status_ == SimStatus::kOk ? "ok" : (status_ == SimStatus::kNonFinite ? "non_finite" : "runaway");
    s.diagnosis = diagnosis_;
    return s;
  }

  mesh::TetMesh WorldMesh() const override {
    mesh::TetMesh m;
    m.nodes.resize(model_.num_nodes(), 3);
    for (int32_t n = 0; n < model_.num_nodes(); ++n) {
      for (int k = 0; k < 3; ++k) m.nodes(n, k) = static_cast<double>(state_.x[3 * n + k]);
    }
    m.tets.resize(model_.num_tets(), 4);
    for (int32_t t = 0; t < model_.num_tets(); ++t) {
      for (int c = 0; c < 4; ++c) m.tets(t, c) = model_.tet_node(t, c);
    }
    m.regions = mesh_.mesh.regions;
    return m;
  }

  void WriteVtu(const std::filesystem::path& path) const override {
    const mesh::TetMesh world = WorldMesh();
    const int32_t N = model_.num_nodes(), Tn = model_.num_tets();
    mesh::VtkField displacement{"displacement", 3, std::vector<double>(3 * static_cast<size_t>(N))};
    mesh::VtkField velocity{"velocity", 3, std::vector<double>(3 * static_cast<size_t>(N))};
    mesh::VtkField fixed{"fixed", 1, std::vector<double>(static_cast<size_t>(N))};
    for (int32_t n = 0; n < N; ++n) {
      for (int k = 0; k < 3; ++k) {
        displacement.values[3 * n + k] = static_cast<double>(state_.x[3 * n + k] - model_.rest_positions()[3 * n + k]);
        velocity.values[3 * n + k] = static_cast<double>(state_.v[3 * n + k]);
      }
      fixed.values[n] = model_.fixed(n) ? 1.0 : 0.0;
    }
    mesh::VtkField von_mises{"von_mises", 1, std::vector<double>(static_cast<size_t>(Tn))};
    mesh::VtkField principal{"principal_stress", 3, std::vector<double>(3 * static_cast<size_t>(Tn))};
    mesh::VtkField quality{"quality", 1, std::vector<double>(static_cast<size_t>(Tn))};
    const mesh::TetQuality q = mesh::ComputeTetQuality(world);
    for (int32_t t = 0; t < Tn; ++t) {
      const Eigen::Matrix3d sigma = fem::ElementCauchyStress(model_, state_.x.data(), t).template cast<double>();
      Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> eig(sigma, Eigen::EigenvaluesOnly);
      const Eigen::Vector3d p = eig.eigenvalues().reverse();  // σ1 ≥ σ2 ≥ σ3
      for (int k = 0; k < 3; ++k) principal.values[3 * t + k] = p[k];
      von_mises.values[t] = std::sqrt(0.5 * ((p[0] - p[1]) * (p[0] - p[1]) + (p[1] - p[2]) * (p[1] - p[2]) +
                                             (p[2] - p[0]) * (p[2] - p[0])));
      quality.values[t] = q.mean_ratio[static_cast<size_t>(t)];
    }
    const mesh::VtkField point_fields[] = {displacement, velocity, fixed};
    const mesh::VtkField cell_fields[] = {von_mises, principal, quality};
    mesh::WriteVtu(path.string(), world, point_fields, cell_fields);
  }

 private:
  static fem::ModelOptions MakeModelOptions(const LoadedScene& scene) {
    fem::ModelOptions o;
    o.gravity = ToEigen(scene.scene.gravity());
    o.source = scene.path.string();
    return o;
  }

  static const char* precision_name() { return sizeof(T) == 4 ? "float" : "double"; }

  /// AUTO: implicit viscosity only where the explicit viscous limit would cut
  /// the step below 80% of the elastic one (then it costs a CG solve per step
  /// but saves more in step count).
  fem::ViscousTreatment ChooseViscous(TimeStepPolicy::Viscosity v) {
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
  void SetRestTolerances() {
    const auto& nodes = mesh_.mesh.nodes;
    const double diag = (nodes.colwise().maxCoeff() - nodes.colwise().minCoeff()).norm();
    const double g = model_.gravity().template cast<double>().norm();
    const double mass = model_.TotalMass();
    double prescribed = 0;
    for (int32_t n = 0; n < model_.num_nodes(); ++n) {
      prescribed += Eigen::Vector3d(model_.prescribed_forces()[3 * n], model_.prescribed_forces()[3 * n + 1],
                                    model_.prescribed_forces()[3 * n + 2]).norm();
    }
    const double load = mass * g + prescribed;
    const auto& rest = scene_.scene.rest();
    rest_kinetic_energy_ = rest.kinetic_energy() > 0 ? rest.kinetic_energy()
                                                     : (load > 0 ? 1e-8 * load * diag : 1e-12);
    rest_residual_force_ = rest.residual_force() > 0
                               ? rest.residual_force()
                               : (load > 0 ? 1e-3 * load / std::max(1, num_free_) : 1e-9);
  }

  double KineticEnergy() const { return fem::KineticEnergy(model_, state_.v.data()); }

  double ResidualForce() const {
    double worst = 0;
    for (int32_t n = 0; n < model_.num_nodes(); ++n) {
      if (model_.fixed(n)) continue;
      const double f2 = static_cast<double>(state_.f[3 * n] * state_.f[3 * n] + state_.f[3 * n + 1] * state_.f[3 * n + 1] +
                                            state_.f[3 * n + 2] * state_.f[3 * n + 2]);
      worst = std::max(worst, f2);
    }
    return std::sqrt(worst);
  }

  double MaxDisplacement() const {
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

  LoadedScene scene_;
  SceneMesh mesh_;
  fem::Model<T> model_;
  fem::State<T> state_;
  fem::StepOptions step_options_;
  int num_free_ = 0;
  int threads_ = 1;
  int64_t frames_ = 0;
  double wall_time_ = 0;
  double last_dt_ = 0;
  double rest_kinetic_energy_ = 0;
  double rest_residual_force_ = 0;
  SimStatus status_ = SimStatus::kOk;
  std::string diagnosis_;
};

}  // namespace

std::unique_ptr<Simulation> Simulation::Create(const LoadedScene& scene, const SimulationOptions& options) {
  SceneMesh scene_mesh = BuildSceneMesh(scene);
  const bool use_float = options.precision.empty()
                             ? scene.scene.time_step().precision() == TimeStepPolicy::PRECISION_FLOAT
                             : options.precision == "float";
  if (use_float) return std::make_unique<Engine<float>>(scene, std::move(scene_mesh), options);
  return std::make_unique<Engine<double>>(scene, std::move(scene_mesh), options);
}

}  // namespace cutsim::sim
