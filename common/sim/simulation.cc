#include "common/sim/simulation.h"

#include <omp.h>

#include <algorithm>
#include <array>
#include <atomic>
#include <cmath>
#include <exception>
#include <limits>
#include <optional>
#include <type_traits>

#include <Eigen/Eigenvalues>
#include <Eigen/Sparse>
#include <Eigen/SparseCholesky>
#include <fmt/format.h>

#include "common/core/clock.h"
#include "common/cutting/criterion.h"
#include "common/cutting/cut_attempt.h"
#include "common/cutting/cut_mesh.h"
#include "common/cutting/cut_params.h"
#include "common/cutting/topology_event.h"
#include "common/cutting/world_access.h"
#include "common/haptics/tool_path.h"
#include "common/mesh/bvh.h"
#include "common/mesh/surface.h"
#include "common/core/error.h"
#include "common/core/log.h"
#include "common/core/units.h"
#include "common/fem/forces.h"
#include "common/fem/integrator.h"
#include "common/fem/model.h"
#include "common/fem/stable_dt.h"
#include "common/fem/state.h"
#include "common/mesh/mesh_io.h"
#include "common/sim/debris.h"
#include "common/sim/fem_event.h"
#include "common/mesh/quality.h"
#include "common/sim/scene_mesh.h"
#include "common/sim/checkpoint.h"  // checkpoints (ops)
#include "cutsim/v1/checkpoint.pb.h"
#include "common/sim/tool_contact.h"

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

/// World positions of the FEM state (float or double) for the cut code.
template <typename T>
class StateWorld final : public cutting::WorldAccess {
 public:
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

/// Node capacity: a cut copies nodes (seed §3.2), so reserve room for them.
int32_t NodeCapacity(const v1::Scene& scene, int32_t num_nodes) {
  const bool cutting = scene.has_tool() && scene.has_cutting() && scene.cutting().enabled();
  return cutting ? 3 * num_nodes + 1024 : num_nodes;
}

template <typename T>
class Engine final : public Simulation {
 public:
  Engine(const LoadedScene& scene, SceneMesh scene_mesh, const SimulationOptions& options)
      : scene_(scene),
        mesh_(std::move(scene_mesh)),
        model_(mesh_.mesh, MaterialsPerTet(scene.scene, mesh_.mesh, scene.path.string()),
               MakeModelOptions(scene, mesh_.mesh.num_nodes())),
        state_(model_),
        world_access_(state_.x) {
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

    // Default threads: all cores for big meshes; one below 20 000 tets, where
    // a step takes microseconds and OpenMP's fork/barrier cost (worse on a
    // loaded machine) exceeds the work it would split.
    constexpr int32_t kParallelTets = 20000;
    threads_ = options.threads > 0 ? options.threads
               : s.time_step().threads() > 0 ? s.time_step().threads()
               : (model_.num_tets() >= kParallelTets ? omp_get_num_procs() : 1);
    step_options_.num_threads = threads_;
    step_options_.safety_factor = s.time_step().safety_factor();
    step_options_.dt_refresh_interval = s.time_step().refresh_every_steps();
    step_options_.viscous = ChooseViscous(s.time_step().viscosity());
    step_options_.mass_damping = s.mass_damping();
    if (s.time_step().fixed_dt() > 0) {
      (void)fem::CurrentTimeStep(model_, state_, step_options_);  // refreshes the estimate
      const double limit = fem::EffectiveStableStep(state_);
      if (s.time_step().fixed_dt() > limit) {
        ThrowInputError({.file = source, .field = "time_step.fixed_dt"},
                        fmt::format("{:.3g} s exceeds the estimated stable limit {:.3g} s",
                                    s.time_step().fixed_dt(), limit));
      }
      // Substeps are min(safety × limit, max_dt): pin them to the fixed step.
      step_options_.max_dt = s.time_step().fixed_dt();
      step_options_.safety_factor = 1.0;
    }
    SetRestTolerances();
    if (s.has_tool()) {
      SetUpTool(scene);  // builds the surface (from the cut complex when cutting)
    } else {
      RebuildSurface();  // the viewers' surface; no BVH without a tool
    }
    Log().info("scene '{}': {} nodes, {} tets, {} free nodes, {} precision, {} threads, viscosity {}",
               s.name(), model_.num_nodes(), model_.num_tets(), num_free_, precision_name(),
               threads_, step_options_.viscous == fem::ViscousTreatment::kImplicit ? "implicit" : "explicit");
  }

  SimStatus AdvanceFrame(double frame_time) override {
    if (status_ != SimStatus::kOk) return status_;
    if (frame_time <= 0) frame_time = scene_.scene.time_step().frame_dt();
    Stopwatch watch;
    report_.cut_this_frame = false;
    const ToolPose start = pose_;
    if (has_tool_) {
      pose_ = external_pose_ ? *external_pose_ : SamplePath(state_.time + frame_time);
      FindContact();
    }
    const Eigen::Vector3d tool_velocity = (pose_.tip - start.tip) / frame_time;

    // Substeps as fem::Advance takes them (equal steps under the stable
    // bound), with the penalty force refreshed before each one.
    fem::StepResult r;
    double remaining = frame_time;
    double elapsed = 0;
    while (remaining > 0) {
      double dt_max = static_cast<double>(fem::CurrentTimeStep(model_, state_, step_options_));
      if (Loaded()) dt_max = ContactLimitedStep(dt_max);
      const double n = std::ceil(remaining / dt_max * (1.0 - 1e-12));
      const double dt = remaining / std::max(1.0, n);
      if (Loaded()) {
        const double s = (elapsed + dt) / frame_time;
        ApplyContactForce(start.tip + s * (pose_.tip - start.tip), tool_velocity);
      }
      r = fem::Step(model_, state_, static_cast<T>(dt), step_options_);
      if (!r.ok()) break;
      last_dt_ = r.dt > 0 ? r.dt : dt;
      remaining -= dt;
      elapsed += dt;
      if (n <= 1) break;
    }
    ClearContactForce();
    ++frames_;
    if (!r.ok()) {
      status_ = r.status == fem::StepStatus::kRunaway ? SimStatus::kEnergyRunaway : SimStatus::kNonFinite;
      diagnosis_ = fmt::format("step {}: {} = {:.6g} at element {} / node {}", r.step, r.quantity,
                               r.value, r.element, r.node);
    } else if (cut_) {
      Stopwatch cut_watch;
      TryCut();
      cut_wall_time_ += cut_watch.ElapsedSeconds();
    }
    wall_time_ += watch.ElapsedSeconds();
    return status_;
  }

  bool has_tool() const override { return has_tool_; }
  double path_end_time() const override { return path_.empty() ? 0.0 : path_.end_time(); }
  void SetToolPose(const ToolPose& pose) override { external_pose_ = pose; }
  ToolReport Tool() const override { return report_; }
  uint64_t topology_version() const override { return model_.topology_version(); }
  const std::vector<CutStepTiming>& CutTimings() const override { return cut_timings_; }

  Eigen::Matrix3d ContactStiffness() const override {
    if (!Loaded()) return Eigen::Matrix3d::Zero();
    // The contact spring k in series with the tissue's point stiffness along
    // the direction it pushes (PatchStiffness). The tip penalty acts along
    // n: K = k_eff·n nᵀ. The edge grip acts across the blade, K = k_eff·
    // (I − d dᵀ), with the tissue taken along the stretch (or, unloaded,
    // along the facet normal's part across the blade).
    Eigen::Vector3d u = facet_.normal;
    Eigen::Matrix3d shape = u * u.transpose();
    if (grip_.active) {
      const Eigen::Vector3d d = pose_.blade_dir;
      u = grip_.stretch;
      if (u.norm() <= 1e-12 * (1.0 + indent_limit_)) u = facet_.normal - facet_.normal.dot(d) * d;
      const double u_len = u.norm();
      if (!(u_len > 0)) return Eigen::Matrix3d::Zero();
      u /= u_len;
      shape = Eigen::Matrix3d::Identity() - d * d.transpose();
    }
    const double k_tissue = PatchStiffness(ForceNodes(), ForceWeights(), u);
    const double k = contact_stiffness_;
    const double k_eff = (k + k_tissue) > 0 ? k * k_tissue / (k + k_tissue) : 0.0;
    return k_eff * shape;
  }

  void FillMeshView(MeshView& view) const override {
    const int32_t N = model_.num_nodes();
    view.world.resize(N, 3);
    view.rest.resize(N, 3);
    for (int32_t i = 0; i < N; ++i) {
      for (int k = 0; k < 3; ++k) {
        view.world(i, k) = static_cast<double>(state_.x[3 * static_cast<size_t>(i) + static_cast<size_t>(k)]);
        view.rest(i, k) = static_cast<double>(model_.rest_positions()[3 * i + k]);
      }
    }
    view.tets.resize(model_.num_tets(), 4);
    for (int32_t t = 0; t < model_.num_tets(); ++t) {
      for (int c = 0; c < 4; ++c) view.tets(t, c) = model_.tet_node(t, c);
    }
    // The surface is kept by slot (cutting: dead slots are rows of −1);
    // viewers get the live triangles only, in slot order.
    int32_t live = 0;
    for (int32_t f = 0; f < num_slots_; ++f) live += surface_(f, 0) >= 0 ? 1 : 0;
    view.surface.resize(live, 3);
    view.opened.resize(static_cast<size_t>(live));
    view.debris.resize(debris_facet_.empty() ? 0 : static_cast<size_t>(live));
    int32_t row = 0;
    for (int32_t f = 0; f < num_slots_; ++f) {
      if (surface_(f, 0) < 0) continue;
      view.surface.row(row) = surface_.row(f);
      if (!view.debris.empty()) view.debris[static_cast<size_t>(row)] = debris_facet_[static_cast<size_t>(f)];
      view.opened[static_cast<size_t>(row++)] = opened_[static_cast<size_t>(f)];
    }
  }

  bool AtRest() const override {
    if (frames_ == 0) return false;
    return KineticEnergy() <= rest_kinetic_energy_ && ResidualForce() <= rest_residual_force_;
  }

  double sim_time() const override { return state_.time; }
  double frame_dt() const override { return scene_.scene.time_step().frame_dt(); }

  SimulationSummary QuickSummary() const override {
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
    s.stable_dt = state_.dt_tree.empty() ? 0.0 : fem::EffectiveStableStep(state_);
    s.sim_time = state_.time;
    s.wall_time = wall_time_;
    s.tet_steps_per_s = wall_time_ > 0 ? static_cast<double>(state_.step) * model_.num_tets() / wall_time_ : 0.0;
    s.realtime_factor = wall_time_ > 0 ? state_.time / wall_time_ : 0.0;
    s.kinetic_energy = KineticEnergy();
    s.residual_force = ResidualForce();
    s.max_displacement = MaxDisplacement();
    s.at_rest = AtRest();
    s.status = status_ == SimStatus::kOk ? "ok" : (status_ == SimStatus::kNonFinite ? "non_finite" : "runaway");
    s.diagnosis = diagnosis_;
    s.cuts = cuts_;
    s.cut_attempts = cut_attempts_;
    s.cuts_rejected = cuts_rejected_;
    s.topology_version = model_.topology_version();
    s.cut_wall_time = cut_wall_time_;
    return s;
  }

  SimulationSummary Summary() const override {
    SimulationSummary s = QuickSummary();
    s.strain_energy = fem::StrainEnergy(model_, state_.x.data());
    s.total_mass = model_.TotalMass();
    int32_t components = 1;
    (void)cutting::ConnectedComponents(TetsMatrix(), &components);
    s.components = components;
    s.opened_faces = static_cast<int>(std::count(opened_.begin(), opened_.begin() + num_slots_, uint8_t{1}));
    double min_volume = std::numeric_limits<double>::infinity();
    for (int32_t t = 0; t < model_.num_tets(); ++t) {
      min_volume = std::min(min_volume, static_cast<double>(model_.rest_volume(t)));
    }
    s.min_rest_volume = min_volume;
    return s;
  }

  mesh::TetMesh WorldMesh() const override {
    mesh::TetMesh m;
    m.nodes.resize(model_.num_nodes(), 3);
    for (int32_t n = 0; n < model_.num_nodes(); ++n) {
      for (int k = 0; k < 3; ++k) m.nodes(n, k) = static_cast<double>(state_.x[3 * n + k]);
    }
    m.tets = TetsMatrix();
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
    // Per tet, how many of its faces a cut opened (ParaView: Threshold > 0).
    mesh::VtkField cut_faces{"cut_faces", 1, std::vector<double>(static_cast<size_t>(Tn), 0.0)};
    if (cut_) {
      for (const cutting::SurfaceFace& face : cut_->surface_slots()) {
        if (face.alive && face.opened) cut_faces.values[static_cast<size_t>(face.tet)] += 1.0;
      }
    }
    const mesh::VtkField point_fields[] = {displacement, velocity, fixed};
    const mesh::VtkField cell_fields[] = {von_mises, principal, quality, cut_faces};
    mesh::WriteVtu(path.string(), world, point_fields, cell_fields);
  }

 private:
  static fem::ModelOptions MakeModelOptions(const LoadedScene& scene, int32_t num_nodes) {
    fem::ModelOptions o;
    o.node_capacity = NodeCapacity(scene.scene, num_nodes);
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

  // ---- tool and cutting -------------------------------------------------

  void SetUpTool(const LoadedScene& scene) {
    const auto& tool = scene.scene.tool();
    has_tool_ = true;
    if (!tool.path_file().empty()) {
      const std::filesystem::path p(tool.path_file());
      path_ = haptics::ToolPath::Read(p.is_absolute() ? p : scene.base_dir / p);
    } else if (tool.keyframes_size() > 0) {
      std::vector<haptics::ToolKeyframe> frames;
      for (const auto& k : tool.keyframes()) {
        frames.push_back({k.t(), ToEigen(k.tip()), ToEigen(k.blade_dir())});
      }
      path_ = haptics::ToolPath(std::move(frames), scene.path.string() + ": tool.keyframes");
    }
    blade_length_ = tool.blade_length();
    // Defaults tied to the tissue: a penalty spring as stiff as one element
    // of the first material (E·h̄), an indentation limit of one mean edge.
    mean_edge_ = MeanSurfaceEdge();
    const double E = units::YoungFromLame({static_cast<double>(model_.lambdas()[0]),
                                           static_cast<double>(model_.mus()[0])});
    contact_stiffness_ = tool.contact_stiffness() > 0 ? tool.contact_stiffness() : E * mean_edge_;
    contact_damping_ = tool.contact_damping();
    indent_limit_ = 0.5 * mean_edge_;
    grip_limit_ = mean_edge_;
    if (blade_length_ <= 0) blade_length_ = 2.0 * mean_edge_;
    report_.present = true;
    if (path_.empty()) {
      // No path: until a client sets a pose the tool is parked clear of the
      // tissue, blade vertical with its tip one blade length above the top
      // of the body (the default pose, tip at the origin, would lie on the
      // body of any scene built from the origin, e.g. along a box's edge).
      Eigen::Vector3d lo = Eigen::Vector3d::Constant(std::numeric_limits<double>::infinity());
      Eigen::Vector3d hi = -lo;
      for (int32_t n = 0; n < mesh_.mesh.num_nodes(); ++n) {
        lo = lo.cwiseMin(mesh_.mesh.nodes.row(n).transpose());
        hi = hi.cwiseMax(mesh_.mesh.nodes.row(n).transpose());
      }
      if (mesh_.mesh.num_nodes() > 0) {
        pose_ = {Eigen::Vector3d(0.5 * (lo.x() + hi.x()), 0.5 * (lo.y() + hi.y()), hi.z() + blade_length_),
                 Eigen::Vector3d::UnitZ()};
      }
    }
    pose_ = SamplePath(0.0);
    report_.pose = pose_;
    if (scene.scene.has_cutting() && scene.scene.cutting().enabled()) {
      const auto& c = scene.scene.cutting();
      params_.alpha = c.alpha();
      params_.kappa = c.kappa();
      params_.zeta = c.zeta();
      params_.critical_stress = c.critical_stress();
      params_.min_quality = c.min_quality();
      cutting::ValidateCutParams(params_, {.file = scene.path.string(), .field = "cutting"});
      cut_.emplace(mesh_.mesh, model_.node_capacity());
      tracker_.emplace(params_);
    }
    RebuildSurface();
    Log().info("tool: blade {:.3g} m, contact k = {:.3g} N/m, indent limit {:.3g} m, cutting {}",
               blade_length_, contact_stiffness_, indent_limit_, cut_ ? "on" : "off");
  }

  ToolPose SamplePath(double t) const {
    if (path_.empty()) return pose_;
    const haptics::ToolKeyframe k = path_.Sample(t);
    return {k.tip, k.blade_dir};
  }

  double MeanSurfaceEdge() const {
    const mesh::Surface surf = mesh::ExtractSurface(mesh_.mesh.tets);
    double sum = 0;
    int64_t count = 0;
    for (int32_t f = 0; f < surf.tris.rows(); ++f) {
      for (int k = 0; k < 3; ++k) {
        sum += (mesh_.mesh.nodes.row(surf.tris(f, k)) - mesh_.mesh.nodes.row(surf.tris(f, (k + 1) % 3))).norm();
        ++count;
      }
    }
    return count > 0 ? sum / static_cast<double>(count) : 1e-3;
  }

  /// Surface triangles (from the cut complex when cutting, else extracted)
  /// and the BVH over them, from scratch: at set-up and after a restore.
  /// Cuts update both locally (UpdateSurface).
  void RebuildSurface() {
    if (cut_) {
      cut_->set_track_slot_changes(has_tool_);
      const auto& slots = cut_->surface_slots();
      num_slots_ = static_cast<int32_t>(slots.size());
      // Room for as many slots again: cuts add slots, and growing inside a
      // cut step copies and clears every per-slot array here and in the
      // BVH (built over these rows, dead ones included): at 100k tets that
      // was 42 % of the simulated cache misses of the first 15 cut steps
      // (cut_bench, callgrind). Doubling still takes over beyond.
      surface_.resize(std::max<int32_t>(2 * num_slots_, 16), 3);
      surface_.setConstant(-1);
      opened_.assign(static_cast<size_t>(surface_.rows()), 0);
      surface_tet_.assign(static_cast<size_t>(surface_.rows()), -1);
      wall_node_.assign(static_cast<size_t>(model_.node_capacity()), 0);
      for (int32_t f = 0; f < num_slots_; ++f) {
        const cutting::SurfaceFace& face = slots[static_cast<size_t>(f)];
        if (!face.alive) continue;
        const std::array<int32_t, 3> tri = cut_->SurfaceTriangle(f);
        surface_.row(f) << tri[0], tri[1], tri[2];
        opened_[static_cast<size_t>(f)] = face.opened ? 1 : 0;
        surface_tet_[static_cast<size_t>(f)] = face.tet;
        if (face.opened) FlagWallNodes(tri);
      }
      std::vector<int32_t> drained;
      cut_->TakeChangedSlots(drained);  // all covered above
    } else {
      mesh::Surface surf = mesh::ExtractSurface(TetsMatrix());
      surface_ = std::move(surf.tris);
      surface_tet_ = std::move(surf.tet);
      num_slots_ = static_cast<int32_t>(surface_.rows());
      opened_.assign(static_cast<size_t>(surface_.rows()), 0);
    }
    CUTSIM_CHECK(surface_tet_.size() == static_cast<size_t>(surface_.rows()), "surface/tet map size");
    if (!has_tool_) return;  // contact structures only serve the tool
    FlagDebris();
    CopyWorld();
    bvh_ = mesh::TriangleBvh(world_, surface_);
  }

  /// Marks the nodes of a face a cut opened (tool_contact.h: walls and lips
  /// of a cut). A node stays on a cut once it is: cuts never close.
  void FlagWallNodes(const std::array<int32_t, 3>& tri) {
    if (wall_node_.size() < static_cast<size_t>(model_.node_capacity())) {
      wall_node_.resize(static_cast<size_t>(model_.node_capacity()), 0);
    }
    for (const int32_t v : tri) wall_node_[static_cast<size_t>(v)] = 1;
  }

  /// Surface update after a cut: only the slots the cut created or freed
  /// (the CutMesh's change log, kept in changed_slots_), each removed from
  /// or inserted into the BVH. Their debris flags: FlagDebrisFacets.
  /// Reads the topology (final once `splits` are made) and world_, not the
  /// FEM's positions, so it may run beside the remeshing moves and the FEM
  /// half (SeparatedCallback). The boxes of the inserted faces are then
  /// those of the frame's start (world_, a copy's row from its original's:
  /// a copy starts where its original is), not the moved ones: the next
  /// FindContact refits every box from the current positions before any
  /// query, and the BVH's answers do not depend on how its tree was built
  /// (bvh.h), so the contact is the same.
  void UpdateSurface(std::span<const cutting::Split> splits) {
    // The copies this cut made are the last splits.size() nodes, in order.
    const int32_t first_copy = cut_->num_nodes() - static_cast<int32_t>(splits.size());
    for (size_t i = 0; i < splits.size(); ++i) {
      CUTSIM_CHECK(splits[i].new_node == first_copy + static_cast<int32_t>(i), "split copies out of order");
      world_.row(splits[i].new_node) = world_.row(splits[i].node);
    }
    cut_->TakeChangedSlots(changed_slots_);
    std::sort(changed_slots_.begin(), changed_slots_.end());
    changed_slots_.erase(std::unique(changed_slots_.begin(), changed_slots_.end()), changed_slots_.end());
    const auto& slots = cut_->surface_slots();
    num_slots_ = static_cast<int32_t>(slots.size());
    if (num_slots_ > surface_.rows()) {  // grow by doubling: amortised O(1) per slot
      const auto old_rows = static_cast<int32_t>(surface_.rows());
      const int32_t rows = std::max(num_slots_, 2 * old_rows);
      surface_.conservativeResize(rows, 3);
      surface_.bottomRows(rows - old_rows).setConstant(-1);
      opened_.resize(static_cast<size_t>(rows), 0);
      surface_tet_.resize(static_cast<size_t>(rows), -1);
      if (debris_) debris_facet_.resize(static_cast<size_t>(rows), 0);
    }
    for (const int32_t f : changed_slots_) {
      const cutting::SurfaceFace& face = slots[static_cast<size_t>(f)];
      const auto i = static_cast<size_t>(f);
      if (!face.alive) {
        surface_.row(f).setConstant(-1);
        opened_[i] = 0;
        surface_tet_[i] = -1;
        if (!debris_facet_.empty()) debris_facet_[i] = 0;
        bvh_.Remove(f);
        continue;
      }
      const std::array<int32_t, 3> tri = cut_->SurfaceTriangle(f);
      surface_.row(f) << tri[0], tri[1], tri[2];
      opened_[i] = face.opened ? 1 : 0;
      surface_tet_[i] = face.tet;
      if (face.opened) FlagWallNodes(tri);
      // A local insert: amortised O(log F), the tree is rebuilt only after
      // as many inserts as half its faces (see bvh.h).
      bvh_.Insert(f, tri, world_);
    }
  }

  /// Facets the blade does not touch: those of debris (debris.h), whole-mesh
  /// here (set-up, restore); UpdateDebris and FlagDebrisFacets update them after each cut.
  void FlagDebris() {
    debris_facet_.clear();
    debris_.reset();
    if (!cut_) return;
    const int32_t T_count = model_.num_tets();
    std::vector<double> element_mass(static_cast<size_t>(T_count));
    for (int32_t t = 0; t < T_count; ++t) element_mass[static_cast<size_t>(t)] = static_cast<double>(model_.element_mass(t));
    debris_.emplace(std::move(element_mass), model_.TotalMass(),
                    DebrisTracker::Limits{.mass_fraction = kDebrisMassFraction, .max_tets = kDebrisMaxTets});
    debris_->Reset(*cut_);
    debris_facet_.assign(static_cast<size_t>(surface_.rows()), 0);
    for (int32_t f = 0; f < num_slots_; ++f) {
      const int32_t t = surface_tet_[static_cast<size_t>(f)];
      if (t >= 0) debris_facet_[static_cast<size_t>(f)] = debris_->is_debris(t) ? 1 : 0;
    }
  }

  /// After a cut: the debris pieces it cut loose (DebrisTracker::Update,
  /// local; reads only the cut complex and the event).
  void UpdateDebris(std::span<const cutting::Split> splits) {
    flagged_.clear();
    if (debris_) debris_->Update(*cut_, splits, &flagged_);
  }

  /// After UpdateSurface and UpdateDebris: the flags of the slots the cut
  /// changed, and of every facet of the tets it made debris (a tet stays
  /// debris once it is, so this equals a rescan of those slots).
  void FlagDebrisFacets() {
    if (!debris_) return;
    const auto& slots = cut_->surface_slots();
    for (const int32_t f : changed_slots_) {
      const cutting::SurfaceFace& face = slots[static_cast<size_t>(f)];
      debris_facet_[static_cast<size_t>(f)] = face.alive && debris_->is_debris(face.tet) ? 1 : 0;
    }
    for (const int32_t t : flagged_) {
      for (int f = 0; f < 4; ++f) {
        const int32_t slot = cut_->SurfaceSlot(t, f);
        if (slot >= 0) debris_facet_[static_cast<size_t>(slot)] = 1;
      }
    }
  }

  mesh::Tets TetsMatrix() const {
    mesh::Tets tets(model_.num_tets(), 4);
    for (int32_t t = 0; t < model_.num_tets(); ++t) {
      for (int c = 0; c < 4; ++c) tets(t, c) = model_.tet_node(t, c);
    }
    return tets;
  }

  /// world_ holds node_capacity rows (allocated once), the first
  /// num_nodes() of them current.
  void CopyWorld() {
    const int32_t N = model_.num_nodes();
    if (world_.rows() < model_.node_capacity()) world_.resize(model_.node_capacity(), 3);
    for (int32_t i = 0; i < N; ++i) CopyWorldRow(i);
  }

  void CopyWorldRow(int32_t i) {
    for (int k = 0; k < 3; ++k) world_(i, k) = static_cast<double>(state_.x[3 * static_cast<size_t>(i) + static_cast<size_t>(k)]);
  }

  void FindContact() {
    CopyWorld();
    bvh_.Refit(world_, model_.num_nodes());
    facet_ = FindContactFacet(bvh_, world_, surface_, pose_.tip, pose_.blade_dir, blade_length_,
                              mean_edge_, hits_scratch_, box_scratch_, debris_facet_, in_cut_, wall_node_);
    if (!facet_.touching) {
      in_cut_ = false;  // the blade left the tissue (see tool_contact.h)
      sweeps_.clear();
    }
    // Behind its own cut front the tissue is cut (tool_contact.h, in its own cut).
    if (in_cut_ && facet_.touching && !facet_.on_cut) {
      facet_.on_cut = InSweptArea(sweeps_, facet_.point, indent_limit_);
    }
    // Capped at the indentation limit; none in its own cut, where the tip
    // never pushes (tool_contact.h, in its own cut).
    if (facet_.touching) {
      facet_.depth = facet_.on_cut || facet_.in_slit ? 0.0 : std::min(facet_.depth, indent_limit_);
    }
    UpdateGrip();
    report_.touching = facet_.touching;
    report_.pose = pose_;
    report_.point = facet_.point;
    report_.normal = facet_.normal;
    report_.depth = facet_.depth;
    if (!Loaded()) report_.force_on_tool.setZero();
  }

  /// The blade loads the tissue this frame: it touches it, not only a wall
  /// or lip of its own cut, and in its slit it still holds a grip. Other
  /// in-cut contacts keep the cut's t0 but take no load (tool_contact.h).
  bool Loaded() const {
    return facet_.touching && !facet_.on_cut && (!facet_.in_slit || grip_.active);
  }

  /// Edge coupling (tool_contact.h): the blade is inside once the contact
  /// point is more than the indentation limit up the blade from its tip.
  /// A grip from an older topology is released (a cut: the tissue gave
  /// way, the spring restarts unloaded at the new crossing); one whose
  /// tissue end drifted more than half the limit from its material point
  /// moves to the current crossing, keeping its world point. In its own
  /// cut a facet on the cut releases the grip, and an in-slit contact keeps
  /// one but never takes one (tool_contact.h, in its own cut).
  void UpdateGrip() {
    const bool inside = facet_.touching && !facet_.on_cut &&
                        (facet_.point - pose_.tip).dot(pose_.blade_dir) > indent_limit_;
    if (!inside) {
      grip_.active = false;
      return;
    }
    const uint64_t version = model_.topology_version();
    if (!grip_.active || grip_.topology_version != version) {
      // A new grip only where the edge crosses uncut tissue; in the slit it
      // may only keep the one it holds (tool_contact.h, in-cut rule).
      if (facet_.in_slit) {
        grip_.active = false;
        return;
      }
      grip_ = MakeGrip(facet_, facet_.point, version);
    } else if (grip_.offset.norm() > 0.5 * grip_limit_) {
      const auto& nd = grip_.nodes;
      grip_ = MakeGrip(facet_, GripPoint(grip_, NodeX(nd[0]), NodeX(nd[1]), NodeX(nd[2])), version);
    }
    facet_.depth = 0.0;  // no tip penalty inside: the edge carries the load
  }

  /// Nodes and weights the contact force goes to this frame.
  const std::array<int32_t, 3>& ForceNodes() const { return grip_.active ? grip_.nodes : facet_.nodes; }
  const Eigen::Vector3d& ForceWeights() const { return grip_.active ? grip_.bary : facet_.bary; }

  Eigen::Vector3d NodeX(int32_t n) const {
    const size_t i = 3 * static_cast<size_t>(n);
    return {static_cast<double>(state_.x[i]), static_cast<double>(state_.x[i + 1]),
            static_cast<double>(state_.x[i + 2])};
  }

  void ApplyContactForce(const Eigen::Vector3d& tip, const Eigen::Vector3d& tool_velocity) {
    const auto& nd = ForceNodes();
    const Eigen::Vector3d x0 = NodeX(nd[0]), x1 = NodeX(nd[1]), x2 = NodeX(nd[2]);
    Eigen::Vector3d F;
    if (grip_.active) {
      F = EdgeGripForce(grip_, x0, x1, x2, tip, pose_.blade_dir, contact_stiffness_, grip_limit_);
      facet_.point = facet_.bary[0] * NodeX(facet_.nodes[0]) + facet_.bary[1] * NodeX(facet_.nodes[1]) +
                     facet_.bary[2] * NodeX(facet_.nodes[2]);
    } else {
      F = PenaltyForce(facet_, x0, x1, x2, tip, tool_velocity, contact_stiffness_, contact_damping_, indent_limit_);
    }
    const Eigen::Vector3d& w = ForceWeights();
    for (int i = 0; i < 3; ++i) {
      const size_t b = 3 * static_cast<size_t>(nd[static_cast<size_t>(i)]);
      for (int k = 0; k < 3; ++k) state_.f_ext[b + static_cast<size_t>(k)] = static_cast<T>(w[i] * F[k]);
    }
    applied_nodes_ = nd;
    report_.force_on_tool = -F;
    report_.depth = grip_.active ? grip_.stretch.norm() : facet_.depth;
    report_.point = facet_.point;
    // The haptic side renders unilaterally along this direction: the push
    // on the tool (against the blade's sideways motion when gripping).
    const double f = F.norm();
    report_.normal = grip_.active && f > 0 ? Eigen::Vector3d(-F / f) : facet_.normal;
  }

  /// The penalty spring is stiffness the FEM's stable-step estimate does
  /// not see: K_c = k·(b ⊗ b)·n nᵀ on the facet nodes. Its largest
  /// frequency is ω_c² ≤ k·Σ bᵢ²/mᵢ; with the elastic one, ω² ≤ ω_e² + ω_c²
  /// (Weyl: both parts are positive semi-definite), ω_e taken as
  /// 2·safety/dt_max (conservative: dt_max is at most safety × the limit).
  /// The approach damper c adds dt ≤ min mᵢ/(c·bᵢ). On a finely cut body the
  /// facet nodes are split copies of a few milligrams, where a spring sized
  /// for the body (E·h̄) otherwise sets the limit (random-cut stress test).
  double ContactLimitedStep(double dt_max) const {
    double w2 = 0;
    double damper_limit = std::numeric_limits<double>::infinity();
    for (int i = 0; i < 3; ++i) {
      const double b = ForceWeights()[i];
      const double m = static_cast<double>(model_.node_mass(ForceNodes()[static_cast<size_t>(i)]));
      if (!(m > 0) || b <= 0) continue;
      w2 += contact_stiffness_ * b * b / m;
      if (contact_damping_ > 0) damper_limit = std::min(damper_limit, m / (contact_damping_ * b));
    }
    const double safety = std::min(1.0, step_options_.safety_factor);
    const double we = 2.0 * safety / dt_max;
    const double limited = 2.0 * safety / std::sqrt(we * we + w2);
    return std::min({dt_max, limited, safety * damper_limit});
  }

  void ClearContactForce() {
    for (const int32_t n : applied_nodes_) {
      if (n < 0) continue;
      for (int k = 0; k < 3; ++k) state_.f_ext[3 * static_cast<size_t>(n) + static_cast<size_t>(k)] = T(0);
    }
    applied_nodes_ = {-1, -1, -1};
  }

  /// Point stiffness of the tissue (N/m) along unit `u` for a load spread
  /// as wᵢ·u over `nodes`: 1/(fᵀK⁻¹f), f = w ⊗ u, K = −∂f/∂x the tangent
  /// stiffness (fem::StvkElementStiffness at the current state) of the
  /// free nodes within kStiffnessRings rings of the facet, with every
  /// element touching them; nodes beyond are held. The facet nodes'
  /// diagonal blocks alone (every other node held) made the haptic K about
  /// 4× too stiff on the ligament (bench/README.md, buffer model). Falls
  /// back to that diagonal estimate if the patch solve fails. Runs once per
  /// physics frame with a haptic client in contact; the node → unknown map
  /// is a scratch row kept at −1 between calls.
  double PatchStiffness(const std::array<int32_t, 3>& nodes, const Eigen::Vector3d& w,
                        const Eigen::Vector3d& u) const {
    constexpr int kStiffnessRings = 2;
    std::vector<int32_t>& column = patch_column_;  // node id → unknown index, −1 if none
    if (column.size() < static_cast<size_t>(model_.node_capacity())) {
      column.assign(static_cast<size_t>(model_.node_capacity()), -1);
    }
    std::vector<int32_t>& unknown = patch_unknown_;  // node ids, in discovery order
    unknown.clear();
    auto visit = [&](int32_t node) {
      if (column[static_cast<size_t>(node)] >= 0 || model_.fixed(node)) return;
      column[static_cast<size_t>(node)] = static_cast<int32_t>(unknown.size());
      unknown.push_back(node);
    };
    for (const int32_t node : nodes) visit(node);
    const int32_t* slots = model_.incidence_slots();
    size_t ring_begin = 0;
    for (int ring = 0; ring < kStiffnessRings; ++ring) {
      const size_t ring_end = unknown.size();
      for (size_t k = ring_begin; k < ring_end; ++k) {
        const int32_t node = unknown[k];
        for (int32_t s = model_.incidence_begin(node); s < model_.incidence_end(node); ++s) {
          for (int c = 0; c < 4; ++c) visit(model_.tet_node(slots[s] / 12, c));
        }
      }
      ring_begin = ring_end;
    }
    const double k_tissue = unknown.empty() ? 0.0 : SolvePatchCompliance(nodes, w, u);
    for (const int32_t node : unknown) column[static_cast<size_t>(node)] = -1;
    if (k_tissue > 0) return k_tissue;
    double k_diagonal = 0;
    for (int i = 0; i < 3; ++i) k_diagonal += w[i] * NodeNormalStiffness(nodes[static_cast<size_t>(i)], u);
    return std::max(k_diagonal, 0.0);
  }

  /// PatchStiffness's solve over patch_unknown_ (mapped by patch_column_):
  /// 1/(fᵀK⁻¹f), or 0 if the patch matrix cannot be factored or the
  /// compliance is not positive.
  double SolvePatchCompliance(const std::array<int32_t, 3>& nodes, const Eigen::Vector3d& w,
                              const Eigen::Vector3d& u) const {
    std::vector<int32_t>& tets = patch_tets_;  // every element touching an unknown, once
    model_.IncidentTets(patch_unknown_, tets);
    // The lower triangle only: the element tangents are symmetric and
    // SimplicialLDLT reads the lower part.
    std::vector<Eigen::Triplet<double>>& entries = patch_entries_;
    entries.clear();
    for (const int32_t t : tets) {
      std::array<int32_t, 4> local{};  // unknown index of each corner, −1 if held
      for (int c = 0; c < 4; ++c) local[static_cast<size_t>(c)] = patch_column_[static_cast<size_t>(model_.tet_node(t, c))];
      const Eigen::Matrix<double, 12, 12> Ke = ElementStiffness(t);
      for (int cj = 0; cj < 4; ++cj) {
        const int32_t col = local[static_cast<size_t>(cj)];
        if (col < 0) continue;
        for (int ci = 0; ci < 4; ++ci) {
          const int32_t row = local[static_cast<size_t>(ci)];
          if (row < col) continue;  // held (−1) or above the diagonal
          for (int a = 0; a < 3; ++a) {
            for (int b = row == col ? a : 0; b < 3; ++b) {
              entries.emplace_back(3 * row + b, 3 * col + a, Ke(3 * ci + b, 3 * cj + a));
            }
          }
        }
      }
    }
    const int n = 3 * static_cast<int>(patch_unknown_.size());
    Eigen::SparseMatrix<double> K(n, n);
    K.setFromTriplets(entries.begin(), entries.end());
    Eigen::VectorXd f = Eigen::VectorXd::Zero(n);
    for (int i = 0; i < 3; ++i) {
      const int32_t col = patch_column_[static_cast<size_t>(nodes[static_cast<size_t>(i)])];
      if (col >= 0) f.segment<3>(3 * col) = w[i] * u;
    }
    Eigen::SimplicialLDLT<Eigen::SparseMatrix<double>> solver(K);
    if (solver.info() != Eigen::Success) return 0.0;
    const double compliance = f.dot(solver.solve(f));
    return solver.info() == Eigen::Success && std::isfinite(compliance) && compliance > 0 ? 1.0 / compliance : 0.0;
  }

  /// StVK tangent of element t at the current state (12×12, double).
  Eigen::Matrix<double, 12, 12> ElementStiffness(int32_t t) const {
    fem::Mat34<double> x;
    for (int c = 0; c < 4; ++c) x.col(c) = NodeX(model_.tet_node(t, c));
    return fem::StvkElementStiffness<double>(x, model_.DmInv(t).template cast<double>(),
                                             static_cast<double>(model_.rest_volume(t)),
                                             static_cast<double>(model_.lambdas()[t]),
                                             static_cast<double>(model_.mus()[t]));
  }

  /// nᵀKᵢᵢn for one node: its diagonal block of the incident element tangents.
  double NodeNormalStiffness(int32_t node, const Eigen::Vector3d& n) const {
    const int32_t* slots = model_.incidence_slots();
    double k = 0;
    for (int32_t s = model_.incidence_begin(node); s < model_.incidence_end(node); ++s) {
      const int corner = (slots[s] % 12) / 3;
      k += n.dot(ElementStiffness(slots[s] / 12).template block<3, 3>(3 * corner, 3 * corner) * n);
    }
    return k;
  }

  /// Seed §3: cut attempt (geometric), criterion (stress), then separation
  /// and remeshing, applied to the FEM as a topology event.
  void TryCut() {
    cutting::Contact contact;
    contact.touching = facet_.touching;
    if (facet_.touching) {
      contact.point = facet_.point;
      contact.normal = facet_.normal;
      contact.closest_node = facet_.closest_node;
      contact.facet_tet = SurfaceTriTet(facet_.surface_tri);
    }
    const int32_t anchor_before = tracker_->anchor_node();
    const cutting::CutAttempt attempt = tracker_->Update(contact, world_access_);
    if (tracker_->anchor_node() != anchor_before) anchor_tip_ = pose_.tip;
    if (!attempt.attempt) return;
    // The seed's attempt reads the closest vertex only; a tool pressing
    // straight down also changes it as the surface deforms under the blade.
    // A cut needs the tool itself to have moved along the surface since t0,
    // by at least half the cut segment d_v (choice documented in scenes/README.md).
    const Eigen::Vector3d moved = pose_.tip - anchor_tip_;
    const Eigen::Vector3d tangential = moved - moved.dot(attempt.normal) * attempt.normal;
    const double d_v = (world_access_.Get(attempt.v1) - world_access_.Get(attempt.v0)).norm();
    if (tangential.norm() < 0.5 * d_v) return;
    ++cut_attempts_;
    timing_ = {};
    Stopwatch step_watch;
    const int32_t room = model_.node_capacity() - model_.num_nodes();
    params_.max_splits_per_step = std::min(4096, room);
    cutting::CutStep step;
    step.v0 = attempt.v0;
    step.v1 = attempt.v1;
    step.cp0 = attempt.cp0;
    step.cp = attempt.cp;
    step.normal = attempt.normal;
    // The blade's swept plane (tip at t0 → tip now) is the cut plane.
    step.blade = cutting::Blade{pose_.tip, pose_.blade_dir, blade_length_, anchor_tip_};
    if (threads_ >= 2 && room >= 64 && CutStepOnTwoThreads(step, attempt.facet_tet, room, step_watch)) return;
    const cutting::CriterionResult crit = Criterion(step.v1, attempt.facet_tet, step_watch, nullptr);
    if (!CutDecided(crit, room)) return;
    Stopwatch topology_watch;
    cutting::CutOutcome outcome = cut_->ExecuteCut(step, world_access_, params_);
    timing_.topology = topology_watch.ElapsedSeconds();
    if (!TakeOutcome(outcome, step, crit)) return;
    if (!outcome.event.empty()) ApplyEvent(std::move(outcome.event));
    FinishCutStep(step_watch);
  }

  /// The stress criterion (seed eqs. 6–11) on the contact elements around
  /// v1 (and the contact facet's tet); sets `cancel` if it says no.
  cutting::CriterionResult Criterion(int32_t v1, int32_t facet_tet, const Stopwatch& step_watch,
                                     std::atomic<bool>* cancel) {
    const std::vector<int32_t> candidates = cut_->ContactElements(v1, facet_tet);
    cutting::CriterionResult crit = cutting::EvaluateCriterion(
        candidates,
        [this](int32_t t) {
          return fem::ElementCauchyStress(model_, state_.x.data(), t).template cast<double>().eval();
        },
        params_);
    timing_.criterion = step_watch.ElapsedSeconds();
    if (!crit.cut && cancel != nullptr) cancel->store(true, std::memory_order_relaxed);
    return crit;
  }

  /// After the criterion: whether to cut (it says so and there is room for copies).
  bool CutDecided(const cutting::CriterionResult& crit, int32_t room) {
    report_.sigma_c = crit.sigma_c;
    if (!crit.cut) return false;
    if (room < 64) {
      if (!warned_capacity_) Log().warn("node capacity exhausted: no more cuts");
      warned_capacity_ = true;
      return false;
    }
    return true;
  }

  /// After ExecuteCut: counts a rejected step, or moves t0 to here for an
  /// executed one (true).
  bool TakeOutcome(const cutting::CutOutcome& outcome, const cutting::CutStep& step,
                   const cutting::CriterionResult& crit) {
    if (outcome.status != cutting::CutStatus::kExecuted) {
      ++cuts_rejected_;
      return false;
    }
    tracker_->OnCutExecuted();
    in_cut_ = true;  // the blade is in its own slit now (tool_contact.h, in-cut test)
    sweeps_.push_back({anchor_tip_, pose_.tip, pose_.blade_dir});
    anchor_tip_ = pose_.tip;  // t0 := t: the next step sweeps from here
    if (log_cuts_)
      Log().debug("cut {} at t={:.4f}: v0={} v1={} sigma_c={:.4g} Pa, {} splits, {} moves ({} limited, {} skipped)",
                  cuts_ + 1, state_.time, step.v0, step.v1, crit.sigma_c, outcome.event.splits.size(),
                  outcome.event.moves.size(), outcome.moves_limited, outcome.moves_skipped);
    timing_.splits = static_cast<int32_t>(outcome.event.splits.size());
    timing_.touched_tets = static_cast<int32_t>(outcome.event.touched_tets.size());
    return true;
  }

  void FinishCutStep(const Stopwatch& step_watch) {
    timing_.wall = step_watch.ElapsedSeconds();
    cut_timings_.push_back(timing_);
    ++cuts_;
    report_.cuts = cuts_;
    report_.cut_this_frame = true;
  }

  static void SpinPause() {
#if defined(__x86_64__) || defined(__i386__)
    __builtin_ia32_pause();
#endif
  }

  /// The cut step with a second thread, in one OpenMP region. The other
  /// thread evaluates the criterion while this one finds the plane and the
  /// split set (PrepareCut reads only the cut complex and the world
  /// positions; a criterion that says no cancels it). This one then cuts;
  /// as soon as the topology is final (SeparatedCallback, before the
  /// remeshing moves) the other thread updates the surface slots, the BVH
  /// and the debris, which need the topology only, while this one moves v0
  /// and v1, applies the event's nodes and recomputes the FEM half
  /// (elements, node masses, stable-step leaves). Neither reads what the
  /// other writes, so the results are those of one thread, bit for bit.
  /// One fork per step (a fork took 1–3 µs before its threads started in
  /// cut_bench at 100k tets), hand-overs by spinning on two flags. This
  /// thread walks and cuts so that the walk's lines are in the cache of the
  /// core that cuts. False (nothing done) if the runtime gives one thread.
  bool CutStepOnTwoThreads(const cutting::CutStep& step, int32_t facet_tet, int32_t room,
                           const Stopwatch& step_watch) {
    enum : int { kWait, kRun, kSkip };
    cutting::CriterionResult crit;
    cutting::PreparedCut prepared;
    cutting::CutOutcome outcome;
    std::atomic<bool> cancel{false};
    std::atomic<bool> criterion_done{false};
    std::atomic<int> surface_half{kWait};
    std::span<const cutting::Split> splits;  // the event's, set before surface_half = kRun
    const cutting::SeparatedCallback on_separated = [&](std::span<const cutting::Split> s) {
      splits = s;
      surface_half.store(kRun, std::memory_order_release);
    };
    std::array<std::exception_ptr, 2> error;
    bool two = true, executed = false;
    double surface_time = 0, apply_begin = 0, fem_end = 0;
#pragma omp parallel num_threads(2)
    {
      if (omp_get_num_threads() < 2) {
        two = false;
      } else if (omp_get_thread_num() == 1) {
        try {
          crit = Criterion(step.v1, facet_tet, step_watch, &cancel);
        } catch (...) {
          error[1] = std::current_exception();
          crit.cut = false;
          cancel.store(true, std::memory_order_relaxed);
        }
        criterion_done.store(true, std::memory_order_release);
        int go = kWait;
        while ((go = surface_half.load(std::memory_order_acquire)) == kWait) SpinPause();
        if (go == kRun) {
          try {
            Stopwatch w;
            UpdateSurfaceAndDebris(splits);
            surface_time = w.ElapsedSeconds();
          } catch (...) {
            error[1] = std::current_exception();
          }
        }
      } else {
        // Whatever happens here, the other thread stops waiting.
        struct Release {
          std::atomic<int>& flag;
          ~Release() {
            int expected = kWait;
            flag.compare_exchange_strong(expected, kSkip, std::memory_order_release);
          }
        } release{surface_half};
        try {
          Stopwatch w;
          prepared = cut_->PrepareCut(step, world_access_, params_, &cancel);
          const double prepare_time = w.ElapsedSeconds();
          while (!criterion_done.load(std::memory_order_acquire)) SpinPause();
          if (error[1] == nullptr && CutDecided(crit, room)) {
            Stopwatch topology_watch;
            outcome = cut_->ExecuteCut(step, world_access_, params_, &prepared, &on_separated);
            timing_.topology = prepare_time + topology_watch.ElapsedSeconds();
            executed = TakeOutcome(outcome, step, crit);
            if (executed && !outcome.event.empty()) {
              apply_begin = step_watch.ElapsedSeconds();
              ApplyEventNodesToFem(outcome.event, model_, state_);
              RecomputeFemHalf(outcome.event);
              fem_end = step_watch.ElapsedSeconds();
            }
          }
        } catch (...) {
          error[0] = std::current_exception();
        }
      }
    }
    if (!two) return false;
    for (const std::exception_ptr& e : error)
      if (e) std::rethrow_exception(e);
    if (!executed) return true;
    if (!outcome.event.empty()) {
      // Every executed step calls on_separated (cut_mesh.h); without it the
      // surface would silently miss this cut.
      CUTSIM_CHECK(surface_half.load(std::memory_order_acquire) == kRun, "cut executed without its surface half");
      Stopwatch flags_watch;
      FlagDebrisFacets();
      // The surface half began during the moves, inside `topology`; `apply`
      // is from the event's nodes to the end of both halves.
      timing_.fem = fem_end - apply_begin;
      timing_.surface = surface_time + flags_watch.ElapsedSeconds();
      timing_.apply = step_watch.ElapsedSeconds() - apply_begin;
      events_.push_back(std::move(outcome.event));
    }
    FinishCutStep(step_watch);
    return true;
  }

  int32_t SurfaceTriTet(int32_t tri) const {
    if (tri < 0 || static_cast<size_t>(tri) >= surface_tet_.size()) return -1;
    return surface_tet_[static_cast<size_t>(tri)];
  }

  /// The FEM half of a cut step (fem_event.h): elements, node masses and
  /// stable-step leaves, after the event's nodes.
  void RecomputeFemHalf(const cutting::TopologyEvent& event) {
    RecomputeAfterEvent(event, model_, state_, step_options_.viscous == fem::ViscousTreatment::kExplicit,
                        fem_event_);
  }

  /// The surface half of a cut step: surface slots and BVH, then the debris
  /// flood. Needs the topology only (see UpdateSurface).
  void UpdateSurfaceAndDebris(std::span<const cutting::Split> splits) {
    UpdateSurface(splits);
    UpdateDebris(splits);
  }

  /// Applies a cut's topology event to the FEM in the order the cut code
  /// documents (topology_event.h), then refreshes what depends on topology,
  /// on this thread (a one-thread cut step, a checkpoint's replay;
  /// CutStepOnTwoThreads runs the same halves side by side). The event is
  /// kept (moved, not copied) for checkpoints.
  void ApplyEvent(cutting::TopologyEvent&& event) {
    Stopwatch watch;
    ApplyEventNodesToFem(event, model_, state_);
    // Every node is final now (copies, moves). The FEM half recomputes the
    // elements, node masses and stable-step leaves; the surface half edits
    // the surface slots and the BVH, reading only the tets' nodes (in the
    // cut complex) and the world positions, then floods for debris (which
    // reads only the cut complex and the event). Neither reads what the
    // other writes. The debris flags of the facets need both.
    RecomputeFemHalf(event);
    timing_.fem = watch.ElapsedSeconds();
    if (has_tool_) {
      Stopwatch surface_watch;
      UpdateSurfaceAndDebris(event.splits);
      FlagDebrisFacets();
      timing_.surface = surface_watch.ElapsedSeconds();
    }
    timing_.apply = watch.ElapsedSeconds();
    events_.push_back(std::move(event));
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
  StateWorld<T> world_access_;

  // Tool (absent: none of this is used).
  bool has_tool_ = false;
  haptics::ToolPath path_;
  std::optional<ToolPose> external_pose_;
  ToolPose pose_;
  double blade_length_ = 0;        // m
  double contact_stiffness_ = 0;   // N/m
  double contact_damping_ = 0;     // N·s/m
  double indent_limit_ = 0;        // m, tip penalty cap (and the depth at which the blade is inside)
  double grip_limit_ = 0;          // m, edge-grip stretch cap (tool_contact.h)
  double mean_edge_ = 0;           // m
  mesh::Positions world_;          // #N_cap×3 double copy for the BVH (first #N rows current)
  // Surface by slot (cutting: CutMesh surface slots, stable ids; else the
  // extracted surface's rows). #S rows of capacity, the first num_slots_
  // used; dead slots are rows of −1 (not in the BVH).
  mesh::Triangles surface_;        // #S×3
  int32_t num_slots_ = 0;
  std::vector<uint8_t> opened_;    // #S
  std::vector<uint8_t> wall_node_;  // #node_capacity (or empty): node on a face a cut opened
  std::vector<int32_t> surface_tet_;  // #S owning tet (−1: dead)
  std::vector<uint8_t> debris_facet_; // #S (or empty): facet of a debris piece
  std::optional<DebrisTracker> debris_;  // with cutting only
  std::vector<int32_t> changed_slots_, flagged_;  // scratch
  FemEventScratch fem_event_;  // scratch
  CutStepTiming timing_;              // the cut step in progress
  std::vector<CutStepTiming> cut_timings_;
  // Debris: a piece cut loose that the blade passes through rather than
  // flings with a force sized for the body. Small in mass and in elements:
  // what makes a crumb fly is a few elements (each node's mass is set by
  // its elements, not by the piece), and the element bound keeps the flood
  // that finds one local (see UpdateDebris).
  static constexpr double kDebrisMassFraction = 0.01;
  static constexpr int32_t kDebrisMaxTets = 64;
  mesh::TriangleBvh bvh_;
  std::vector<mesh::SegmentHit> hits_scratch_;
  std::vector<int32_t> box_scratch_;
  ContactFacet facet_;
  EdgeGrip grip_;                                  // the blade's hold on tissue it is inside
  // PatchStiffness scratch (reused across frames; the column row stays −1).
  mutable std::vector<int32_t> patch_column_;
  mutable std::vector<int32_t> patch_unknown_;
  mutable std::vector<int32_t> patch_tets_;
  mutable std::vector<Eigen::Triplet<double>> patch_entries_;
  std::array<int32_t, 3> applied_nodes_{-1, -1, -1};  // nodes holding a contact force in f_ext
  ToolReport report_;

  // Cutting (absent without `cutting.enabled`).
  cutting::CutParams params_;
  std::optional<cutting::CutMesh> cut_;
  std::optional<cutting::CutAttemptTracker> tracker_;
  std::vector<cutting::TopologyEvent> events_;
  Eigen::Vector3d anchor_tip_ = Eigen::Vector3d::Zero();  // tool tip when t0 was set
  uint64_t cuts_ = 0;
  uint64_t cut_attempts_ = 0;
  uint64_t cuts_rejected_ = 0;
  double cut_wall_time_ = 0;
  bool warned_capacity_ = false;
  // Whether the per-cut debug line is wanted, asked once: the call into the
  // logger cost ~3 µs of cold code per cut step at 100k tets in cut_bench
  // even with debug off (the level is set once, in main).
  const bool log_cuts_ = Log().should_log(spdlog::level::debug);
  bool in_cut_ = false;  // a cut executed since the blade last lost contact
  std::vector<CutSweep> sweeps_;  // areas those cuts swept (tool_contact.h)

  // ---- checkpoints (engineer ops; common/sim/checkpoint.h) ---------------
 public:
  v1::CheckpointBody CheckpointState() const override {
    v1::CheckpointBody b;
    b.set_scene_name(scene_.scene.name());
    b.set_scene_fingerprint(SceneFingerprint());
    b.set_precision(precision_name());
    b.set_initial_nodes(mesh_.mesh.num_nodes());
    b.set_initial_tets(mesh_.mesh.num_tets());
    b.set_sim_time(state_.time);
    b.set_steps(state_.step);
    b.set_frames(frames_);
    b.set_cuts(cuts_);
    b.set_topology_version(cut_ ? cut_->version() : 0);
    for (const cutting::TopologyEvent& e : events_) *b.add_events() = EventToProto(e);
    const size_t n3 = 3 * static_cast<size_t>(model_.num_nodes());
    b.mutable_positions()->Reserve(static_cast<int>(n3));
    b.mutable_velocities()->Reserve(static_cast<int>(n3));
    for (size_t i = 0; i < n3; ++i) {
      b.add_positions(static_cast<double>(state_.x[i]));
      b.add_velocities(static_cast<double>(state_.v[i]));
    }
    return b;
  }

  void RestoreCheckpointState(const v1::CheckpointBody& b, const std::string& source) override {
    auto fail = [&](const std::string& field, const std::string& why) {
      ThrowInputError({.file = source, .field = field}, why);
    };
    if (frames_ != 0 || !events_.empty()) fail("", "restore needs a freshly created simulation");
    if (b.scene_name() != scene_.scene.name()) {
      fail("scene_name", fmt::format("checkpoint of scene '{}', this server runs '{}'", b.scene_name(),
                                     scene_.scene.name()));
    }
    if (b.scene_fingerprint() != SceneFingerprint() || b.initial_nodes() != mesh_.mesh.num_nodes() ||
        b.initial_tets() != mesh_.mesh.num_tets()) {
      fail("scene_fingerprint", fmt::format("checkpoint of another mesh of scene '{}' ({} nodes, {} tets; "
                                            "this one has {} nodes, {} tets, or its mesh/settings changed)",
                                            b.scene_name(), b.initial_nodes(), b.initial_tets(),
                                            mesh_.mesh.num_nodes(), mesh_.mesh.num_tets()));
    }
    if (b.precision() != precision_name()) {
      fail("precision", fmt::format("checkpoint written in {} precision, this server runs {} "
                                    "(use --precision {})", b.precision(), precision_name(), b.precision()));
    }
    if (!std::isfinite(b.sim_time()) || b.sim_time() < 0 || b.steps() < 0 || b.frames() < 0) {
      fail("sim_time", "negative or non-finite time or counters");
    }
    if (b.events_size() > 0 && !cut_) fail("events", "the scene has no cutting but the checkpoint has cuts");
    // Dry run: convert and replay every event on a copy of the cut complex,
    // so a bad event is reported before the real mesh or the FEM changes.
    std::vector<cutting::TopologyEvent> events;
    events.reserve(static_cast<size_t>(b.events_size()));
    int32_t num_nodes = model_.num_nodes();
    if (cut_) {
      cutting::CutMesh trial = *cut_;
      for (int i = 0; i < b.events_size(); ++i) {
        const std::string field = fmt::format("events[{}]", i);
        events.push_back(EventFromProto(b.events(i), source, field));
        const cutting::TopologyEvent& e = events.back();
        if (e.version <= trial.version()) fail(field + ".version", "versions must increase");
        try {
          ReplayEvent(trial, e);
        } catch (const InputError& err) {
          fail(field + "." + err.source().field, err.message());
        }
        const int32_t tets = model_.num_tets();
        for (const int32_t t : e.touched_tets) {
          if (t < 0 || t >= tets) fail(field + ".touched_tets", fmt::format("tet {} out of range", t));
        }
        for (const int32_t n : e.touched_nodes) {
          if (n < 0 || n >= trial.num_nodes()) fail(field + ".touched_nodes", fmt::format("node {} out of range", n));
        }
      }
      if (b.topology_version() < trial.version()) {
        fail("topology_version", fmt::format("{} is below the last event's version {}", b.topology_version(),
                                             trial.version()));
      }
      num_nodes = trial.num_nodes();
    }
    if (num_nodes > model_.node_capacity()) {
      fail("events", fmt::format("{} nodes exceed the node capacity {}", num_nodes, model_.node_capacity()));
    }
    const int n3 = 3 * num_nodes;
    if (b.positions_size() != n3) {
      fail("positions", fmt::format("{} values, the replayed mesh needs {} (3 per node)", b.positions_size(), n3));
    }
    if (b.velocities_size() != n3) {
      fail("velocities", fmt::format("{} values, the replayed mesh needs {} (3 per node)", b.velocities_size(), n3));
    }
    for (int i = 0; i < n3; ++i) {
      if (!std::isfinite(b.positions(i))) fail(fmt::format("positions[{}]", i), "non-finite");
      if (!std::isfinite(b.velocities(i))) fail(fmt::format("velocities[{}]", i), "non-finite");
    }

    // Apply for real: the cut complex, then the FEM (the same ApplyEvent as a live cut).
    for (cutting::TopologyEvent& e : events) {
      ReplayEvent(*cut_, e);
      ApplyEvent(std::move(e));
    }
    for (size_t i = 0; i < static_cast<size_t>(n3); ++i) {
      state_.x[i] = static_cast<T>(b.positions(static_cast<int>(i)));
      state_.v[i] = static_cast<T>(b.velocities(static_cast<int>(i)));
    }
    state_.time = b.sim_time();
    state_.step = b.steps();
    state_.dt_refreshed_step = -1;  // positions changed: refresh the stable step
    state_.cg_precond_step = -1;    // and the viscous solve's preconditioner
    frames_ = b.frames();
    cuts_ = b.cuts();
    report_.cuts = cuts_;
    if (has_tool_) pose_ = SamplePath(state_.time);
    RebuildSurface();
  }

 private:
  /// Identity of the uncut scene: name, node capacity and the reordered mesh.
  uint64_t SceneFingerprint() const {
    uint64_t h = Fnv1a64(scene_.scene.name().data(), scene_.scene.name().size());
    const int32_t cap = model_.node_capacity();
    h = Fnv1a64(&cap, sizeof(cap), h);
    const mesh::Positions& p = mesh_.mesh.nodes;
    h = Fnv1a64(p.data(), static_cast<size_t>(p.size()) * sizeof(double), h);
    const mesh::Tets& t = mesh_.mesh.tets;
    return Fnv1a64(t.data(), static_cast<size_t>(t.size()) * sizeof(t(0, 0)), h);
  }

  /// Applies `e` to a cut complex, first bumping its version across cut
  /// steps that changed nothing (their empty events are not recorded).
  static void ReplayEvent(cutting::CutMesh& cut, const cutting::TopologyEvent& e) {
    while (cut.version() + 1 < e.version) {
      cutting::TopologyEvent empty;
      empty.version = cut.version() + 1;
      cut.ApplyEvent(empty);
    }
    cut.ApplyEvent(e);
  }
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
