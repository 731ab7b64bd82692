#include "common/sim/simulation.h"

#include <array>
#include <cmath>
#include <new>
#include <optional>
#include <string>
#include <type_traits>
#include <utility>
#include <vector>

#include <fmt/format.h>

#include "common/core/clock.h"
#include "common/core/error.h"
#include "common/core/log.h"
#include "common/fem/integrator.h"
#include "common/sim/checkpoint.h"
#include "common/sim/checkpoint_part.h"
#include "common/sim/cut_pipeline.h"
#include "common/sim/dynamics.h"
#include "common/sim/integrator_choice.h"
#include "common/sim/metrics_proto.h"
#include "common/sim/output.h"
#include "common/sim/scene_fem.h"
#include "common/sim/scene_mesh.h"
#include "common/sim/session_metrics.h"
#include "common/sim/settle.h"
#include "common/sim/stage.h"
#include "common/sim/surface_tracker.h"
#include "common/sim/tool_stage.h"
#include "cutsim/v1/checkpoint.pb.h"

namespace cutsim::sim {
namespace {

/// A Simulation composed of its stages: the scene's FEM (SceneFem), the
/// surface the tool sees (SurfaceTracker), the tool and its contact
/// (ToolStage), the frame's dynamics (Dynamics, explicit or implicit) and
/// the cut test (CutPipeline). Each stage owns its state;
/// the engine hands them what they need, frame by frame.
template <typename T>
class Engine final : public Simulation {
 public:
  Engine(const LoadedScene& scene, SceneMesh scene_mesh, const SimulationOptions& options)
      : scene_(scene),
        mesh_(std::move(scene_mesh)),
        fem_(scene_, mesh_, options),
        world_access_(fem_.state().x),
        dynamics_(ChooseKind(scene_, mesh_, fem_, options),
                  ImplicitOptionsFor(scene_.scene, fem_.threads(), options.frame_budget > 0)),
        frame_budget_ns_(static_cast<int64_t>(1e9 * std::max(0.0, options.frame_budget))) {
    // The prescribed nodes start where the scene puts them at t = 0, so the
    // settle stage finds the equilibrium with them in place.
    fem_.PrescribeMotion(0.0, {});
    if (scene_.scene.settle()) SettleTissue();
    if (scene_.scene.has_tool()) SetUpTool();
    if (scene_.scene.has_planned_incision()) {
      scorer_.emplace(PlanOf(scene_.scene.planned_incision()));
      scorer_->SetTissue(mesh_.mesh);
    }
    RebuildSurface();
    dynamics_.Prime(fem_, frame_dt());
    const fem::Model<T>& model = fem_.model();
    Log().info("scene '{}': {} nodes, {} tets, {} free nodes, {} precision, {} threads, viscosity {}, {} integrator",
               scene_.scene.name(), model.num_nodes(), model.num_tets(), fem_.num_free(), PrecisionName(),
               fem_.threads(),
               fem_.step_options().viscous == fem::ViscousTreatment::kImplicit ? "implicit" : "explicit",
               IntegratorName(dynamics_.kind()));
  }

  /// One frame: the prescribed nodes take their positions at the frame's
  /// end, the tool moves and finds its contact, the tissue steps
  /// under the contact force, the cut test runs, and the session's
  /// measures take the frame in.
  SimStatus AdvanceFrame(double frame_time) override {
    if (run_.status != SimStatus::kOk) return run_.status;
    if (frame_time <= 0) frame_time = frame_dt();
    Stopwatch watch;
    const int64_t deadline_ns = frame_budget_ns_ > 0 ? MonotonicNs() + frame_budget_ns_ : 0;
    StageClock clock(frame_times_);
    const ToolPose start = BeginFrame();
    fem_.PrescribeMotion(sim_time() + frame_time, TopologyEvents());
    clock.End(FrameStage::kPrescribe);
    MoveTool(sim_time() + frame_time);
    FindContact();
    clock.End(FrameStage::kContact);
    const fem::StepResult step = StepDynamics(start, frame_time, deadline_ns);
    frame_times_.dynamics_seconds = dynamics_.last_phase_seconds();
    clock.End(FrameStage::kDynamics);
    if (CheckStep(step)) TryCut();
    clock.End(FrameStage::kCut);
    Measure(frame_time);
    clock.End(FrameStage::kMeasure);
    run_.wall_time += watch.ElapsedSeconds();
    return run_.status;
  }

  const FrameTimes& LastFrameTimes() const override { return frame_times_; }

  bool has_tool() const override { return tool_.has_value(); }
  double path_end_time() const override { return tool_ ? tool_->path_end_time() : 0.0; }
  void SetToolPose(const ToolPose& pose) override {
    if (tool_) tool_->SetExternalPose(pose);
  }
  ToolReport Tool() const override {
    ToolReport r = tool_ ? tool_->report() : ToolReport{};
    if (cuts_) cuts_->AddToReport(r);
    return r;
  }
  Eigen::Matrix3d ContactStiffness() const override {
    return tool_ ? dynamics_.ContactStiffness(*tool_, fem_) : Eigen::Matrix3d::Zero();
  }
  Eigen::Matrix3d PatchContactStiffness() const override {
    return tool_ ? tool_->ContactStiffness(fem_.model(), fem_.state().x.data()) : Eigen::Matrix3d::Zero();
  }
  uint64_t topology_version() const override { return fem_.model().topology_version(); }
  const std::vector<CutStepTiming>& CutTimings() const override { return cuts_ ? cuts_->timings() : no_timings_; }

  const SessionMetrics& Metrics() const override { return meter_.metrics(); }
  const std::vector<ForceSample>& ForceSeries() const override { return meter_.force_series(); }
  const PlannedIncision* Plan() const override { return scorer_ ? &scorer_->plan() : nullptr; }
  std::span<const CutPoint> ScoredCutPoints() const override {
    return scorer_ ? std::span<const CutPoint>(scorer_->cut_points()) : std::span<const CutPoint>();
  }
  std::optional<IncisionScore> Score() const override {
    if (!scorer_) return std::nullopt;
    const std::span<const uint8_t> opened =
        cuts_ ? std::span<const uint8_t>(surface_.opened()) : std::span<const uint8_t>();
    return scorer_->Score(fem_.model().rest_positions(), surface_.triangles(), opened, meter_.metrics(), sim_time());
  }

  void FillMeshView(MeshView& view) const override {
    FillFemView(fem_.model(), fem_.state().x.data(), view);
    surface_.FillView(view);
  }

  bool AtRest() const override {
    if (run_.frames == 0) return false;
    return fem_.KineticEnergy() <= fem_.rest().kinetic_energy && fem_.ResidualForce() <= fem_.rest().residual_force;
  }

  double sim_time() const override { return fem_.state().time; }
  double frame_dt() const override { return scene_.scene.time_step().frame_dt(); }

  SimulationSummary QuickSummary() const override {
    SimulationSummary s = QuickSummaryOf(scene_.scene.name(), fem_, run_, AtRest());
    dynamics_.AddToSummary(s);
    if (cuts_) cuts_->AddToSummary(s);
    ReportConvergence(s);
    return s;
  }

  SimulationSummary Summary() const override {
    SimulationSummary s = QuickSummary();
    AddWholeMeshSummary(fem_, surface_, s);
    return s;
  }

  mesh::TetMesh WorldMesh() const override {
    return sim::WorldMesh(fem_.model(), fem_.state().x.data(), mesh_.mesh.regions);
  }

  void WriteVtu(const std::filesystem::path& path) const override {
    WriteStateVtu(path, fem_.model(), fem_.state(), mesh_.mesh.regions, cuts_ ? &cuts_->cut_mesh() : nullptr);
  }

  /// The engine's identity and frame count, then every stage's part.
  v1::CheckpointBody CheckpointState() const override {
    v1::CheckpointBody body = MakeCheckpointBody(Identity(), run_.frames);
    for (const CheckpointedStage* stage : Stages()) {
      if (stage != nullptr) stage->Save(body);
    }
    return body;
  }

  /// Checks everything first: the tissue (CheckCheckpointBody: identity,
  /// events replayed on a copy of the cut complex, positions and
  /// velocities), then every stage's part. Then replays the events through
  /// the cut complex and the FEM as live cuts apply them, restores every
  /// stage and rebuilds the surface.
  void RestoreCheckpointState(const v1::CheckpointBody& body, const std::string& source) override {
    const CheckpointIdentity identity = Identity();
    const fem::Model<T>& model = fem_.model();
    std::vector<cutting::TopologyEvent> events =
        CheckCheckpointBody(body, source,
                            {.identity = identity,
                             .cut = cuts_ ? &cuts_->cut_mesh() : nullptr,
                             .num_nodes = model.num_nodes(),
                             .num_tets = model.num_tets(),
                             .node_capacity = model.node_capacity(),
                             .fresh = run_.frames == 0 && (!cuts_ || cuts_->events().empty())});
    const PartCheck check{.source = source, .num_nodes = body.positions_size() / 3};
    for (const CheckpointedStage* stage : Stages()) {
      if (stage != nullptr) stage->Check(body, check);
    }
    for (cutting::TopologyEvent& e : events) {
      ReplayEvent(cuts_->cut_mesh(), e);
      cuts_->ApplyRecordedEvent(std::move(e), Targets());
    }
    run_.frames = body.frames();
    for (CheckpointedStage* stage : Stages()) {
      if (stage != nullptr) stage->Restore(body);
    }
    RebuildSurface();
  }

  /// What Memo() copies: see SimulationMemo.
  struct EngineMemo final : SimulationMemo {
    EngineMemo(const fem::State<T>& s, const std::optional<ToolStage<T>>& t,
               std::optional<typename CutPipeline<T>::AttemptState> c, const RunCounters& r, const SessionMeter<T>& m,
               const SurfaceTracker& f, const std::optional<IncisionScorer>& i)
        : state(s), tool(t), tracker(std::move(c)), run(r), meter(m), surface(f), scorer(i) {}
    fem::State<T> state;
    std::optional<ToolStage<T>> tool;
    std::optional<typename CutPipeline<T>::AttemptState> tracker;
    RunCounters run;
    SessionMeter<T> meter;
    SurfaceTracker surface;  // its BVH as refit frame by frame, not rebuilt: contact queries tie-break alike
    std::optional<IncisionScorer> scorer;
  };

  std::unique_ptr<const SimulationMemo> Memo() const override {
    using Attempt = typename CutPipeline<T>::AttemptState;
    return std::make_unique<EngineMemo>(fem_.state(), tool_,
                                        cuts_ ? std::optional<Attempt>(cuts_->attempt_state()) : std::nullopt, run_,
                                        meter_, surface_, scorer_);
  }

  void RestoreMemo(const SimulationMemo& memo) override {
    const auto* m = dynamic_cast<const EngineMemo*>(&memo);
    if (m == nullptr || m->state.x.size() != fem_.state().x.size() || m->tool.has_value() != tool_.has_value() ||
        m->tracker.has_value() != cuts_.has_value()) {
      ThrowInputError({.field = "memo"}, "the memo belongs to another simulation");
    }
    fem_.state() = m->state;
    if (tool_) tool_ = m->tool;
    if (cuts_) cuts_->set_attempt_state(*m->tracker);
    run_ = m->run;
    meter_ = m->meter;
    surface_ = m->surface;
    scorer_ = m->scorer;
  }

  std::span<const cutting::TopologyEvent> TopologyEvents() const override {
    return cuts_ ? std::span<const cutting::TopologyEvent>(cuts_->events()) : std::span<const cutting::TopologyEvent>();
  }

  /// Checks the events on a copy of the cut complex first (CheckEvents),
  /// then applies them as RestoreCheckpointState does and rebuilds the
  /// surface.
  void ApplyTopologyEvents(std::span<const NamedEvent> named, uint64_t cuts, const std::string& source) override {
    if (named.empty()) return;
    if (!cuts_) ThrowInputError({.file = source, .field = named.front().field}, "the scene has no cutting");
    const fem::Model<T>& model = fem_.model();
    int32_t num_nodes = 0;
    std::vector<cutting::TopologyEvent> events =
        CheckEvents(named, source, cuts_->cut_mesh(), model.num_tets(), model.node_capacity(), num_nodes);
    for (cutting::TopologyEvent& e : events) {
      ReplayEvent(cuts_->cut_mesh(), e);
      cuts_->ApplyRecordedEvent(std::move(e), Targets());
    }
    if (cuts > cuts_->cuts()) cuts_->set_cuts(cuts);
    RebuildSurface();
  }

 private:
  static const char* PrecisionName() { return sizeof(T) == 4 ? "float" : "double"; }

  /// The scene's integrator (or the command line's), AUTO resolved by the
  /// cost estimate of integrator_choice.h, which is logged.
  static IntegratorKind ChooseKind(const LoadedScene& scene, const SceneMesh& mesh, const SceneFem<T>& fem,
                                   const SimulationOptions& options) {
    const v1::TimeStepPolicy& ts = scene.scene.time_step();
    const v1::TimeStepPolicy::Integrator policy = IntegratorPolicy(ts.integrator(), options.integrator);
    fem::State<T> probe = fem.state();  // the estimate leaves the run's state untouched
    const double stable_dt = static_cast<double>(fem::CurrentTimeStep(fem.model(), probe, fem.step_options()));
    if (policy != v1::TimeStepPolicy::INTEGRATOR_AUTO) {
      const IntegratorKind kind = ChooseIntegrator(policy, IntegratorCost{}, sizeof(T) == 8, scene.path.string());
      if (kind != IntegratorKind::kImplicit) CheckStepBudget(scene, stable_dt);
      return kind;
    }
    const IntegratorCost cost = EstimateFrameCost(mesh.mesh.num_tets(), StiffnessNonzeros(mesh.mesh.tets, mesh.mesh.num_nodes()),
                                                  ts.frame_dt(), stable_dt);
    const IntegratorKind kind = ChooseIntegrator(policy, cost, sizeof(T) == 8, scene.path.string());
    if (kind != IntegratorKind::kImplicit) CheckStepBudget(scene, stable_dt);
    Log().info("integrator AUTO: explicit {:.3g} ms/frame ({} substeps of {:.3g} s), implicit {:.3g} ms/frame "
               "({} nonzeros) → {}{}",
               1e3 * cost.explicit_seconds, static_cast<int64_t>(std::ceil(ts.frame_dt() / stable_dt)), stable_dt,
               1e3 * cost.implicit_seconds, cost.nnz, IntegratorName(kind),
               sizeof(T) == 8 ? "" : " (float precision: implicit needs double)");
    return kind;
  }

  /// Refuses an explicit run whose substep `dt` (s) would need more than
  /// kMaxStepsPerSimSecond steps per simulated second: such a scene would run
  /// for days, a frame at a time, without a word.
  static void CheckStepBudget(const LoadedScene& scene, double dt) {
    const double steps = 1.0 / dt;
    if (std::isfinite(steps) && dt > 0.0 && steps <= kMaxStepsPerSimSecond) return;
    ThrowInputError({.file = scene.path.string(), .field = "materials"},
                    fmt::format("this scene needs ~{:.0e} steps per second of simulation (stable step {:.3g} s; the "
                                "limit is {:.0e}): E or ν is out of range for explicit integration (or use "
                                "INTEGRATOR_IMPLICIT)",
                                std::isfinite(steps) && dt > 0.0 ? steps : HUGE_VAL, dt, kMaxStepsPerSimSecond));
  }

  /// The load-time stage: static equilibrium under the scene's loads.
  void SettleTissue() {
    if constexpr (std::is_same_v<T, double>) {
      Stopwatch watch;
      const SettleResult r = Settle(fem_.model(), fem_.state(), ImplicitOptionsFor(scene_.scene, fem_.threads()));
      Log().log(r.converged ? spdlog::level::info : spdlog::level::warn,
                "settle: {} under the scene's loads in {:.2f} s ({} Newton iterations, {} PCG), largest "
                "displacement {:.3g} m, residual {:.3g} N (tolerance {:.3g} N)",
                r.converged ? "at equilibrium" : "NOT converged", watch.ElapsedSeconds(), r.newton_iterations,
                r.pcg_iterations, r.max_displacement, r.residual, r.tolerance);
    } else {
      ThrowInputError({.file = scene_.path.string(), .field = "settle"},
                      "needs double precision (the static solve is double precision)");
    }
  }

  void SetUpTool() {
    tool_.emplace(scene_, mesh_.mesh, fem_.model());
    const auto& s = scene_.scene;
    if (s.has_cutting() && s.cutting().enabled()) {
      cuts_.emplace(scene_, mesh_.mesh, fem_.model().node_capacity(), fem_.threads() >= 2);
    }
    Log().info("tool: blade {:.3g} m, contact k = {:.3g} N/m, indent limit {:.3g} m, cutting {}",
               tool_->blade_length(), tool_->contact_stiffness(), tool_->indent_limit(), cuts_ ? "on" : "off");
  }

  /// Surface and contact structures from scratch: at set-up and after a restore.
  void RebuildSurface() {
    surface_.Rebuild(fem_.model(), fem_.state().x.data(), cuts_ ? &cuts_->cut_mesh() : nullptr, tool_.has_value());
  }

  // ---- the frame's stages -------------------------------------------------

  /// Records each stage's wall time as it ends.
  class StageClock {
   public:
    explicit StageClock(FrameTimes& times) : times_(times), last_ns_(MonotonicNs()) {}
    void End(FrameStage stage) {
      const int64_t now = MonotonicNs();
      times_.stage_seconds[static_cast<size_t>(stage)] = 1e-9 * static_cast<double>(now - last_ns_);
      last_ns_ = now;
    }

   private:
    FrameTimes& times_;
    int64_t last_ns_;
  };

  /// Clears the last frame's cut flag; returns the tool's pose at the
  /// frame's start.
  ToolPose BeginFrame() {
    if (cuts_) cuts_->BeginFrame();
    return tool_ ? tool_->pose() : ToolPose{};
  }

  /// The tool's pose at the frame's end (external, or the path's at `time`).
  void MoveTool(double time) {
    if (tool_) tool_->MoveTo(time);
  }

  void FindContact() {
    if (!tool_) return;
    surface_.RefreshWorld(fem_.model(), fem_.state().x.data());
    tool_->FindContact(surface_, fem_.model(), fem_.state().x.data());
  }

  /// The frame's dynamics (Dynamics: explicit substeps or one implicit step).
  fem::StepResult StepDynamics(const ToolPose& start, double frame_time, int64_t deadline_ns) {
    return dynamics_.StepFrame(fem_, tool_ ? &*tool_ : nullptr, start, frame_time, deadline_ns, run_);
  }

  /// Counts the frame; a failed step stops the run with its diagnosis.
  /// True if the frame's dynamics succeeded.
  bool CheckStep(const fem::StepResult& r) {
    ++run_.frames;
    if (r.ok()) return true;
    run_.status = StepFailureStatus(r);
    run_.diagnosis = StepFailureDiagnosis(r);
    return false;
  }

  /// The cut test of method paper §3 on the frame's contact (CutPipeline).
  void TryCut() {
    if (!cuts_) return;
    const ContactFacet& facet = tool_->facet();
    const CutContact contact{.facet = facet,
                             .facet_tet = surface_.SlotTet(facet.surface_tri),
                             .pose = tool_->pose(),
                             .blade_length = tool_->blade_length()};
    if (const std::optional<CutSweep> sweep = cuts_->TryCut(contact, Targets())) tool_->EnterCut(*sweep);
  }

  /// The session's measures (SessionMeter): the tool's every frame, the
  /// whole mesh's at the meter's sample period.
  void Measure(double frame_time) {
    if (run_.status != SimStatus::kOk) return;
    if (tool_) {
      const ToolReport tool = Tool();
      meter_.AddFrame(frame_time, tool);
      if (scorer_ && tool.cut_this_frame) ScoreCutPoint();
    }
    if (!meter_.SampleDue(sim_time())) return;
    IncisionView incision{.wall_nodes = surface_.wall_nodes()};
    if (tool_ && tool_->facet().touching) {
      incision.contact_nodes = tool_->facet().nodes;
      incision.blade_touching = true;
      incision.blade_tip = tool_->pose().tip;
      incision.blade_dir = tool_->pose().blade_dir;
      incision.blade_length = tool_->blade_length();
      incision.blade_radius = tool_->indent_limit();  // one mean edge
    }
    if (cuts_) {
      incision.surface = &surface_.triangles();
      incision.opened = surface_.opened();
      incision.cut = &cuts_->cut_mesh();
    }
    meter_.Sample(fem_.model(), fem_.state().x.data(), incision, sim_time());
  }

  /// The frame's cut step met the surface at the contact facet's
  /// barycentric point: scored on the rest mesh.
  void ScoreCutPoint() {
    const ContactFacet& facet = tool_->facet();
    if (facet.nodes[0] < 0) return;
    const T* rest = fem_.model().rest_positions();
    Eigen::Vector3d p = Eigen::Vector3d::Zero();
    for (int k = 0; k < 3; ++k) {
      const auto n = static_cast<size_t>(facet.nodes[static_cast<size_t>(k)]);
      p += facet.bary[k] * Eigen::Vector3d(static_cast<double>(rest[3 * n]), static_cast<double>(rest[3 * n + 1]),
                                           static_cast<double>(rest[3 * n + 2]));
    }
    scorer_->AddCutPoint(sim_time(), p);
  }

  CutTargets<T> Targets() {
    return {.model = fem_.model(),
            .state = fem_.state(),
            .world = world_access_,
            .surface = surface_,
            .explicit_viscous = fem_.step_options().viscous == fem::ViscousTreatment::kExplicit};
  }

  CheckpointIdentity Identity() const {
    return {.scene_name = scene_.scene.name(),
            .fingerprint = SceneFingerprint(scene_.scene.name(), fem_.model().node_capacity(), mesh_.mesh),
            .precision = PrecisionName(),
            .initial_nodes = mesh_.mesh.num_nodes(),
            .initial_tets = mesh_.mesh.num_tets()};
  }

  /// The session's measures and the incision's score as one stage: their
  /// part is the metrics and the report's series (metrics_proto.h).
  class MeasuresStage final : public CheckpointedStage {
   public:
    explicit MeasuresStage(Engine& engine) : e_(engine) {}
    void Save(v1::CheckpointBody& body) const override {
      *body.mutable_metrics() = e_.meter_.metrics();
      SeriesToProto(e_.meter_.force_series(), e_.ScoredCutPoints(), &body);
      const typename SessionMeter<T>::Running running = e_.meter_.running();
      v1::MeterPart& p = *body.mutable_meter();
      p.set_have_tip(running.have_tip);
      Vec3ToProto(running.last_tip, p.mutable_last_tip());
      p.set_last_force(running.last_force);
    }
    void Check(const v1::CheckpointBody& body, const PartCheck& check) const override {
      (void)SessionMetricsFromProto(body.metrics(), check.source);
      (void)SeriesFromProto(body, check.source);
      (void)Vec3FromPart(body.meter().last_tip(), check.source, "meter.last_tip");
      if (!std::isfinite(body.meter().last_force()) || body.meter().last_force() < 0) {
        FailPart(check.source, "meter.last_force", "negative or not finite");
      }
    }
    void Restore(const v1::CheckpointBody& body) override {
      const SessionSeries series = SeriesFromProto(body, "");
      const v1::MeterPart& p = body.meter();
      e_.meter_.Restore(SessionMetricsFromProto(body.metrics(), ""), series.force, e_.sim_time(),
                        {.have_tip = p.have_tip(),
                         .last_tip = Vec3FromPart(p.last_tip(), "", ""),
                         .last_force = p.last_force()});
      if (e_.scorer_) e_.scorer_->Restore(series.cut_points);
    }

   private:
    Engine& e_;
  };

  /// Every stage of the frame, in restore order (null: not in this scene).
  /// A checkpoint is the list of their parts: a stage added to the frame
  /// is added here and says what it persists (stage.h). The FEM comes
  /// first (time and positions), the surface last (the engine rebuilds it
  /// from the restored tissue).
  std::array<CheckpointedStage*, 6> Stages() {
    return {&fem_, &dynamics_, tool_ ? &*tool_ : nullptr, cuts_ ? &*cuts_ : nullptr, &measures_, &surface_};
  }
  std::array<const CheckpointedStage*, 6> Stages() const {
    return {&fem_, &dynamics_, tool_ ? &*tool_ : nullptr, cuts_ ? &*cuts_ : nullptr, &measures_, &surface_};
  }

  LoadedScene scene_;
  SceneMesh mesh_;
  SceneFem<T> fem_;
  StateWorld<T> world_access_;  // the cut code's view of fem_'s positions
  Dynamics<T> dynamics_;
  int64_t frame_budget_ns_;  // the dynamics' wall-clock budget per frame (0: none)
  FrameTimes frame_times_;   // the last frame's stages
  SurfaceTracker surface_;
  std::optional<ToolStage<T>> tool_;      // with a tool
  std::optional<CutPipeline<T>> cuts_;    // with a tool and cutting
  RunCounters run_;
  SessionMeter<T> meter_{{.threads = fem_.threads()}};
  std::optional<IncisionScorer> scorer_;  // with a planned incision
  MeasuresStage measures_{*this};          // meter_ and scorer_'s checkpoint part
  const std::vector<CutStepTiming> no_timings_;
};

}  // namespace

std::unique_ptr<Simulation> Simulation::Create(const LoadedScene& scene, const SimulationOptions& options) {
  // Mesh sizes are capped before this point, so running out of memory here is
  // the machine's limit: said with the scene and the mesh it was building.
  int64_t nodes = -1, tets = -1;
  try {
    SceneMesh scene_mesh = BuildSceneMesh(scene);
    nodes = scene_mesh.mesh.num_nodes();
    tets = scene_mesh.mesh.num_tets();
    const bool use_float = options.precision.empty()
                               ? scene.scene.time_step().precision() == v1::TimeStepPolicy::PRECISION_FLOAT
                               : options.precision == "float";
    if (use_float) return std::make_unique<Engine<float>>(scene, std::move(scene_mesh), options);
    return std::make_unique<Engine<double>>(scene, std::move(scene_mesh), options);
  } catch (const std::bad_alloc&) {
    ThrowInputError({.file = scene.path.string(), .field = "mesh"},
                    nodes < 0 ? std::string("out of memory building the mesh")
                              : fmt::format("out of memory setting up the simulation of {} nodes and {} tets", nodes,
                                            tets));
  }
}

}  // namespace cutsim::sim
