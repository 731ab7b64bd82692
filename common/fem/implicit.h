#pragma once
/// @file
/// Backward Euler for the tetrahedral StVK model (double precision), for a
/// step of a whole physics frame that no stability limit binds.
///
/// Unknown: the end-of-step velocity v⁺ of the free nodes; x⁺ = x + h·v⁺.
/// Residual (N·s):
///   r(v⁺) = M(v⁺ − v) − h·[f_int(x⁺) − C(x)·v⁺ − α·M·v⁺ + f_load + f_pen(x⁺)],
/// f_int the plain StVK force (element.h, StvkElementForce), C(x) the
/// strain-rate damping operator with F taken at the start of the step (the
/// damping force is linear in the velocity at a fixed F; freezing F over the
/// step keeps the Jacobian exact and symmetric and gives the step a
/// potential), α the mass-proportional damping, f_load gravity + prescribed +
/// State::f_ext, f_pen the caller's penalty springs (PenaltyTerm). r is the
/// gradient of the incremental potential
///   Φ(v⁺) = ½|v⁺ − v|²_M + (h/2)·v⁺ᵀ(C + αM)v⁺ + W(x⁺) − f_load·(x⁺ − x) + U_pen(x⁺),
/// W the StVK strain energy, so the step is min Φ.
///
/// Newton on r with the Jacobian A = ∂r/∂v⁺ = M + h(C + αM) + h²(K + K_pen),
/// K = −∂f_int/∂x (tangent.h), solved by PCG (linear_solver.h), then a
/// backtracking (Armijo) line search on Φ. K may come from an earlier
/// iterate while Newton still contracts fast (tangent_reuse_contraction):
/// its assembly costs about one preconditioned solve. Stops when the force residual
/// max over free nodes |r_node|/h ≤ the force tolerance, or at the cap.
///
/// Indefinite K (StVK under compression; TangentMode): with kExact, PCG
/// stops at negative curvature with a descent direction and the line search
/// still decreases Φ; kClamped uses K⁺ (S replaced by its positive part in
/// the geometric term, positive semidefinite, = K where no element is
/// compressed); kAuto (default) uses the exact K and switches to K⁺ for the
/// rest of the step once PCG meets negative curvature. Every mode solves
/// the same equations (the residual is always the exact one) and stops on
/// the same rule; the exact Jacobian gives quadratic convergence near a
/// stable solution, K⁺ linear convergence where elements are compressed.
///
/// With the nodal-pressure element (Model::element(), nodal_pressure.h) the
/// potential also holds the nodal volumetric energy; its local part enters
/// the assembled Jacobian, its patch part Σ_a U''/V_a·∇v_a∇v_aᵀ the PCG
/// product matrix-free, and the factor an element-local positive
/// semidefinite approximation of the patch part.
///
/// The implicit path uses plain StVK for every element (the explicit path
/// switches elements with det F < 0.3 to the invertible StVK of Irving et
/// al., which has no potential); above that threshold the forces agree.
///
/// Fixed nodes and nodes without mass are eliminated (identity rows and
/// columns, zero right-hand side) and keep x and v.
///
/// Linear solves (linear_solver.h): PCG preconditioned by a CHOLMOD factor
/// of an earlier A. A factor is asked for when there is none (the first
/// solve waits for it unless wait_for_first_factor is off), when the
/// pattern changed (a cut: until the new factor lands, the old one serves
/// the old DOFs and block Jacobi the new ones), and when a solve needed more
/// than refactor_pcg_iterations. With asynchronous_factorization the worker
/// factors a copy of A while steps go on with the factor they have.

#include <array>
#include <cstdint>
#include <limits>
#include <span>
#include <vector>

#include "common/fem/linear_solver.h"
#include "common/fem/model.h"
#include "common/fem/sparse_system.h"
#include "common/fem/state.h"
#include "common/fem/tangent.h"

namespace cutsim::fem {

enum class TangentMode : uint8_t {
  kExact,    ///< K as is; negative curvature truncates PCG.
  kClamped,  ///< K⁺ (positive semidefinite) throughout.
  kAuto,     ///< K, and K⁺ for the rest of the step after negative curvature.
};

struct ImplicitOptions {
  /// OpenMP threads; 0: one below 4096 tets, else omp_get_max_threads().
  int num_threads = 0;
  /// Absolute force tolerance, N: converged when every free node has
  /// |r_node|/h ≤ it. 0: relative_force_tolerance × the load scale.
  double force_tolerance = 0;
  /// Relative tolerance against the load scale: the largest nodal force of
  /// gravity + prescribed + f_ext + penalty, or of the total force at the
  /// initial guess if larger.
  double relative_force_tolerance = 1e-6;
  int max_newton_iterations = 20;
  int max_line_search_steps = 16;  ///< Halvings of the Newton step.
  /// Inexact Newton: PCG stops at ‖rhs − A d‖₂ ≤ linear_tolerance·‖rhs‖₂
  /// (or at a tenth of the force tolerance, whichever is larger).
  double linear_tolerance = 1e-4;
  int max_pcg_iterations = 300;
  /// Ask for a new factor when a PCG solve needs more iterations than this.
  int refactor_pcg_iterations = 12;
  /// Tangent reuse (modified Newton): K assembled at an earlier iterate,
  /// of this step or an earlier one, serves again while every Newton
  /// iteration cuts the force residual to at most this fraction of the
  /// last; K is assembled anew after one that does not, after a failed
  /// line search, and after a topology change. The residual and the
  /// stopping rule stay exact, so only the iteration count can change.
  /// 0: assemble K at every iteration (plain Newton).
  double tangent_reuse_contraction = 0.25;
  /// Factor on a worker thread (steps never wait, except for the first
  /// factor when wait_for_first_factor); false: factor inline when asked
  /// (bit-reproducible: the factor in use does not depend on timing).
  bool asynchronous_factorization = true;
  /// The very first solve waits for its factor (else block Jacobi PCG
  /// until it lands).
  bool wait_for_first_factor = true;
  TangentMode tangent = TangentMode::kAuto;
  double mass_damping = 0;  ///< α, 1/s (Rayleigh mass-proportional).
  /// After a cut, correct the old factor for the changed and added DOFs
  /// (LinearSolver::CorrectFactor) while the new one is made, up to this
  /// many DOFs; 0: never (the old factor covers the old DOFs, block Jacobi
  /// the new ones).
  int32_t max_correction_rank = 900;
  /// The correction also takes every old node whose columns of A moved by
  /// more than this fraction (‖ΔA_c‖/‖A_c‖) since the factor was asked
  /// for, largest first, within max_correction_rank: a factor asked for at
  /// a cut sees the tissue at the cut mid-transient, and those columns move
  /// most in the frames after. ∞: topology changes only.
  double correction_drift = 0.15;
  /// The most residual a step may carry past its deadline, as a multiple
  /// of the force tolerance: above it Newton goes on past the deadline
  /// (the frame overruns) rather than let an error grow from frame to frame.
  double carry_limit = 50;
  /// How far past its deadline a step above carry_limit may go, as a
  /// multiple of its budget (from the step's start to its deadline): there
  /// Newton and PCG stop whatever the residual, which carries into the next
  /// step (over_budget). ∞ (the default): no such bound, the step goes on
  /// until its residual is within carry_limit. A finite bound caps the
  /// frame after a cut, but what it carries feeds the next frame's
  /// residual, which can grow from frame to frame.
  double overrun_limit = std::numeric_limits<double>::infinity();
  /// How the preconditioner applies the factor (single precision by default).
  FactorSolve factor_solve = FactorSolve::kFloat;
  /// The nodal-pressure element's patch term Σ_a c_a ∇v_a∇v_aᵀ couples
  /// every two nodes of a node's patch, beyond the pattern; the factor gets
  /// its element-diagonal part Σ_e (Σ_{a∈e} β_a c_a/16)·∇v_e∇v_eᵀ with
  /// β_a = n_aᵞ, n_a = (Σ_{e∋a} V_e)²/Σ_{e∋a} V_e² the effective number of
  /// tets at node a. γ = 0 (each tet's term with itself) suits modes that
  /// alternate from tet to tet, whose cross terms cancel, and is n_a times
  /// too soft on a uniform dilatation; γ = 1 is exact on the dilatation and
  /// too stiff on the alternating modes; γ = 1/2 splits the error.
  double patch_lumping = 0.5;
  /// BDF2 instead of backward Euler: x⁺ = (4xₙ − xₙ₋₁)/3 + (2h/3)·v⁺ and
  /// v⁺ = (4vₙ − vₙ₋₁)/3 + (2h/3)·a⁺, i.e. backward Euler of step 2h/3 from
  /// the extrapolated start, on the same Newton machinery. Second order,
  /// far less numerical damping. Falls back to backward Euler for a step
  /// without a history of the same h (the first, after a topology change,
  /// after another integrator moved the state, or when h changes).
  bool bdf2 = false;
};

/// An extra spring inside the solve (tool penalty, grip): a point
/// p = Σ w_i x_i on up to three nodes (unused: node −1) pulled with force
/// f(p) = force − stiffness·(p − p₀), p₀ the point at the start of the step;
/// node i gets w_i·f. Enters the residual and, as w_i w_j·stiffness, the
/// Jacobian: in the assembled matrix where the pattern has block (i, j),
/// else in the PCG product only (ExtraBlock).
struct PenaltyTerm {
  std::array<int32_t, 3> nodes{-1, -1, -1};
  std::array<double, 3> weights{0, 0, 0};
  Eigen::Matrix3d stiffness = Eigen::Matrix3d::Zero();  ///< N/m, symmetric ⪰ 0.
  Eigen::Vector3d force = Eigen::Vector3d::Zero();      ///< N, at p₀.
};

enum class ImplicitStatus : uint8_t {
  kConverged = 0,
  kCapped,     ///< max_newton_iterations reached; the state holds the last iterate.
  kNonFinite,  ///< A residual or energy became NaN/Inf; the state is unchanged.
  /// The step's deadline passed: the state holds the last accepted
  /// iterate (a decrease of the step's potential), and what is left of the
  /// residual carries into the next step.
  kOutOfTime,
};

/// The implicit step's phases, for its wall-time split
/// (ImplicitResult::phase_seconds).
enum class ImplicitPhase : uint8_t {
  kSetup,        ///< pattern (after a topology change), active set, M + hC, start of step
  kEvaluate,     ///< force and potential evaluations (the first and the line search's)
  kAssemble,     ///< the Jacobian's values (tangent assembly or reuse, penalty blocks)
  kFactorSetup,  ///< a factor's request (its element signatures) and the copy handed to the correction thread
  kSolve,        ///< PCG
};
inline constexpr int kNumImplicitPhases = 5;
/// "setup", "evaluate", "assemble", "factor_setup", "solve".
[[nodiscard]] const char* ImplicitPhaseName(ImplicitPhase phase);

struct ImplicitResult {
  static constexpr int kHistory = 32;
  ImplicitStatus status = ImplicitStatus::kConverged;
  int newton_iterations = 0;
  int pcg_iterations = 0;      ///< Summed over the Newton iterations.
  int max_pcg_iterations = 0;  ///< Largest single solve.
  int line_search_halvings = 0;
  int tangent_assemblies = 0;  ///< Newton iterations that assembled K (the rest reused it).
  double residual = 0;   ///< max over free nodes |r_node|/h at the end, N.
  double tolerance = 0;  ///< The force tolerance used, N.
  bool negative_curvature = false;  ///< Some PCG solve met it.
  bool clamped = false;             ///< K⁺ was used in some iteration.
  bool pattern_rebuilt = false;     ///< The topology changed since the last step.
  bool bdf2 = false;                ///< The step was BDF2 (else backward Euler).
  bool factor_requested = false;    ///< A refactorisation was asked for.
  /// A low-rank correction of the factor was handed to the correction
  /// thread (LinearSolver::CorrectFactor; synchronous: built or refused).
  bool correction_started = false;
  /// Went on past the deadline, its residual above carry_limit: until it
  /// was within, or to the overrun_limit, where it carries what is left.
  bool over_budget = false;
  bool restarted_at_rest = false;   ///< The guess x + h·v was not finite; Newton started from v⁺ = 0.
  int32_t factor_dofs = 0;          ///< DOFs covered by the factor in use.
  /// The force residual (N) before Newton iteration k (first kHistory).
  std::array<double, kHistory> residual_history{};
  /// Wall time of each ImplicitPhase, s.
  std::array<double, kNumImplicitPhases> phase_seconds{};
  void AddPhase(ImplicitPhase phase, double seconds) { phase_seconds[static_cast<size_t>(phase)] += seconds; }
  [[nodiscard]] bool ok() const { return status == ImplicitStatus::kConverged; }
  /// The state advanced (converged, capped or out of time).
  [[nodiscard]] bool advanced() const { return status != ImplicitStatus::kNonFinite; }
};

/// The implicit integrator's persistent workspace: the sparse pattern, the
/// assembled matrices, the factor and the vectors of the solve. One per
/// model; it follows the model's topology version by itself.
class ImplicitIntegrator {
 public:
  explicit ImplicitIntegrator(const ImplicitOptions& options = {});

  /// One backward Euler (or BDF2) step of `step_size` (s). Requires
  /// !model.topology_dirty().
  /// Never throws; allocates only when the topology changed (or on the first
  /// step). On kConverged, kCapped and kOutOfTime the state holds x⁺, v⁺
  /// and f (the total force at x⁺); time and step advance. A `deadline_ns`
  /// (CLOCK_MONOTONIC, 0: none) stops Newton and PCG there (kOutOfTime)
  /// once the residual is within carry_limit, and at the overrun_limit past
  /// it whatever the residual: the first iteration always runs, so a step
  /// always makes progress.
  ImplicitResult Step(const Model<double>& model, State<double>& state, double step_size,
                      std::span<const PenaltyTerm> penalties = {}, int64_t deadline_ns = 0);

  /// Factors the system of a step of `step_size` (s) at the state, at rest
  /// (the Jacobian at x, no contact), and waits for the factor: a scene
  /// that starts at equilibrium takes no Newton iteration until the tool
  /// arrives, and its first contact must not wait for a factorisation.
  /// The assembled tangent serves the first Newton iteration. Allocates;
  /// for load time.
  void Prime(const Model<double>& model, const State<double>& state, double step_size);

  /// The model's own stiffness at a point p = Σ w_i x_i over one step of
  /// the last Step's size h, N/m: (h²·Wᵀ A⁻¹ W)⁻¹ with A the last assembled
  /// Jacobian less its penalty springs (A/h² = K + (C + αM)/h + M/h², which
  /// tends to the static stiffness K for large h; the contact spring is
  /// the caller's to add in series). K is the one assembled at the last step's
  /// solution: when the last step reused an older K (or assembled none),
  /// it is assembled there now and serves the next step's Newton too. Then
  /// the compliance Wᵀ A⁻¹ W is the Galerkin one on the block Krylov space
  /// of P⁻¹W, P the preconditioner in use: it grows block by block (three
  /// preconditioner applications and products each, up to three blocks)
  /// until the estimated relative error of the compliance, the
  /// preconditioned norm of the Galerkin residual, is within 5 %. Zero
  /// before the first step, if the point has no free node, if A is not
  /// positive definite on that space or the estimate stays above 5 % (the
  /// caller then keeps an earlier stiffness). `model` is the last Step's.
  /// Whether the newest finished factor is of the current pattern. False
  /// while it lags a cut: then the preconditioner is corrected for the cut
  /// (several times costlier to apply) or covers only the old DOFs, and an
  /// EffectiveStiffness costs more and is more often refused.
  bool FactorIsCurrent();
  Eigen::Matrix3d EffectiveStiffness(const Model<double>& model, std::span<const int32_t> nodes,
                                     std::span<const double> weights);

  [[nodiscard]] const ImplicitOptions& options() const { return options_; }
  /// Options for the next steps (asynchronous_factorization is read only
  /// at construction).
  ImplicitOptions& mutable_options() { return options_; }
  [[nodiscard]] const SparseSystem& system() const { return system_; }
  /// Values of the last assembled Jacobian A on system()'s pattern.  // #nnz
  [[nodiscard]] std::span<const double> jacobian_values() const { return a_values_; }
  [[nodiscard]] const LinearSolver& linear_solver() const { return solver_; }
  LinearSolver& mutable_linear_solver() { return solver_; }

  /// Stiffness K (or K⁺ when `clamped`) of the model at positions x (#N×3)
  /// on system()'s pattern, without elimination of fixed nodes (for tests
  /// and the haptic linearisation). Builds the pattern if stale. With the
  /// nodal-pressure element the patch term, which is not on the pattern, is
  /// left out (the implicit step applies it matrix-free).
  void AssembleStiffness(const Model<double>& model, const double* x, bool clamped,
                         std::vector<double>& values);
  /// The damping operator C(x) + α·M on system()'s pattern, likewise.
  void AssembleDamping(const Model<double>& model, const double* x, std::vector<double>& values);
  /// Plain StVK internal force at x (#N×3 into `out`, N).
  void InternalForce(const Model<double>& model, const double* x, double* out);

 private:
  struct Eval {
    double phi = 0;       // Φ without its constant, J
    double scale = 0;     // Σ |terms of Φ|, J: the size of its round-off
    double residual = 0;  // max free |r_node| / h, N
    bool finite = true;
  };
  void Prepare(const Model<double>& model, ImplicitResult& result);
  double StartStep(const State<double>& state, double step_size, bool pattern_rebuilt);
  [[nodiscard]] int NumThreads() const;
  /// Element pass at positions x: internal node forces into node_force_,
  /// energies into tet_energy_, and, when `tangent_scale` > 0,
  /// tangent_scale·K (K⁺ when clamped) added into `values` (colour by
  /// colour: deterministic).
  void ElementPass(const Model<double>& model, const double* x, double tangent_scale, bool clamped,
                   bool skip_inactive, double* values);
  /// values = mass_scale·M (identity on inactive nodes when skip_inactive)
  /// + scale·C(x).
  void DampingPass(const Model<double>& model, const double* x, double scale, double mass_scale,
                   bool skip_inactive, double* values);
  /// a_values_ = b_values_ + h²(K + K_pen), K assembled at x0 + h v_ when
  /// `assemble`, else the last one assembled.
  void AssembleJacobian(const Model<double>& model, double h, std::span<const PenaltyTerm> penalties,
                        bool clamped, bool assemble);
  /// Φ, the residual (into `residual`, #N×3) and the total force (force_)
  /// at velocity v.
  Eval Evaluate(const Model<double>& model, const State<double>& state, double h,
                std::span<const PenaltyTerm> penalties, const double* v, double* residual);
  bool LineSearch(const Model<double>& model, const State<double>& state, double h,
                  std::span<const PenaltyTerm> penalties, Eval& current, ImplicitResult& result);
  /// Returns whether PCG stopped at the deadline.
  bool SolveDirection(double h, double tolerance, int64_t deadline_ns, ImplicitResult& result, bool* clamped);
  /// Asks the worker for a factor of the current A; records the elements'
  /// signature under the request, to find what a later cut changed.
  bool RequestFactor(const Model<double>& model, ImplicitResult& result);
  /// After a topology change: corrects the factor in use for the nodes of
  /// the elements changed since it was asked for (and the new nodes).
  void CorrectFactor(const Model<double>& model, ImplicitResult& result);
  double LoadScale(const Model<double>& model, const State<double>& state,
                   std::span<const PenaltyTerm> penalties) const;

  /// The nodal-pressure element's patch term h²·Σ_a c_a ∇v_a∇v_aᵀ at the
  /// last tangent point, applied by the PCG product (implicit_volumetric.cc).
  class PatchTerm final : public MatrixFreeTerm {
   public:
    explicit PatchTerm(const ImplicitIntegrator& owner) : owner_(owner) {}
    void AddProduct(const double* p, double* q) const override;

   private:
    const ImplicitIntegrator& owner_;
  };
  /// The nodal-pressure element's volumetric pass at x: energy into
  /// volumetric_energy_, forces added into node_force_; with tangent_scale
  /// > 0 also tangent_scale·Σ_e p̄_e ∂²v_e (not when clamped: it is
  /// indefinite) into `values`, and ∇v_e and c_a = U''(J_a)/V_a kept for
  /// the patch term.
  void VolumetricPass(const Model<double>& model, const double* x, double tangent_scale, bool clamped,
                      const uint8_t* active, double* values);
  /// patch_lump_ = β_a of ImplicitOptions::patch_lumping, from the rest
  /// volumes (after a topology change).
  void LumpPatchTerm(const Model<double>& model);
  /// Adds scale·w_i w_j·k of every penalty term to the blocks (i, j) of
  /// `values` that the pattern has; with `extra`, appends the others (i < j)
  /// there.
  void AddPenaltyBlocks(std::span<const PenaltyTerm> penalties, double scale, double* values,
                        std::vector<ExtraBlock>* extra) const;
  /// The values to factor, in factor_values_: the tissue's a_values_ less
  /// the penalty springs (a contact moves every frame and a factor lives
  /// for many: factored in, the spring of a contact that has moved on is a
  /// rank-3 error of the preconditioner at the old point, and one at the
  /// new point is missing; factored out, only the latter, and the tissue's
  /// compliance at the contact comes from the factor at once), plus with the
  /// nodal-pressure element the patch term's element-diagonal part
  /// h²·Σ_e (Σ_{a∈e} c_a/16)·∇v_e∇v_eᵀ (positive semidefinite, on the
  /// pattern).
  const double* FactorValues();
  [[nodiscard]] const MatrixFreeTerm* matrix_free() const { return nodal_pressure_ ? &patch_ : nullptr; }
  /// q = A·p with the last Jacobian (assembled part, patch term, extra
  /// blocks), zero on inactive DOFs.  // #N×3 each
  void ApplyJacobian(const double* p, double* q) const;
  /// The same without the penalty springs in it: the tissue's own
  /// M + h(C + αM) + h²K.
  void ApplyTissueJacobian(const double* p, double* q) const;

  ImplicitOptions options_;
  SparseSystem system_;
  LinearSolver solver_;
  std::vector<uint8_t> active_;      // #N: free and with mass
  std::vector<double> b_values_;     // M + h(C + αM)  // #nnz
  double b_values_h_ = 0;            // the h of b_values_
  bool b_values_valid_ = false;      // b_values_ is for the current pattern, active set and masses
  std::vector<double> a_values_;     // b_values_ + h²K          // #nnz
  std::vector<double> k_values_;     // K (K⁺ if k_clamped_) at an earlier iterate  // #nnz
  std::vector<double> x0_, v0_;      // start of step  // #N×3
  std::vector<double> v_, v_try_;    // iterate, trial  // #N×3
  std::vector<double> x_;            // x0 + h v  // #N×3
  std::vector<double> force_;        // total nodal force at x_  // #N×3
  std::vector<double> node_force_;   // internal + penalty force at x_  // #N×3
  std::vector<double> residual_, residual_try_;  // #N×3
  std::vector<double> bv_;           // b_values_ · v  // #N×3
  std::vector<double> dir_;          // Newton direction  // #N×3
  std::vector<double> tet_energy_;   // #T
  std::vector<double> rhs_;          // #N×3
  // EffectiveStiffness: the Krylov basis V and AV (#N×3 · 3 per block),
  // the Galerkin residual (#N×3 · 3).
  std::vector<double> compliance_z_, compliance_q_, compliance_r_;
  std::vector<ExtraBlock> extra_;    // penalty couplings outside the pattern
  std::vector<double> x_prev_, v_prev_;  // BDF2: the previous step's start  // #N×3
  int64_t history_step_ = -1;  // state.step at which the history is current
  double history_h_ = 0;       // step size of that history, s
  double last_h_ = 0;
  bool have_k_ = false;        // k_values_ holds K of the current pattern and active set
  bool k_clamped_ = false;     // k_values_ is K⁺
  bool reassemble_k_ = true;   // the last iteration contracted too little to reuse K
  bool k_fresh_ = false;       // K was assembled during the last step
  bool last_clamped_ = false;  // the last step ended with K⁺
  std::vector<PenaltyTerm> last_penalties_;  // the last step's, for a re-formed A
  std::vector<PenaltyTerm> jacobian_penalties_;  // those in a_values_ and extra_
  // Element signatures (a hash of nodes, Dm⁻¹ and volume per tet) at the
  // last two factor requests, by LinearSolver request count.
  struct Signature {
    uint64_t request = 0;
    std::vector<uint64_t> tets;   // #T
    std::vector<int32_t> nodes;   // #T×4: the tets' nodes then
  };
  std::array<Signature, 2> signatures_;
  uint64_t corrected_request_ = 0;  // the (factor, pattern) last corrected or refused
  int64_t corrected_pattern_ = -1;
  std::vector<int32_t> changed_nodes_;
  // The nodal-pressure element (implicit_volumetric.cc).
  bool nodal_pressure_ = false;
  const Model<double>* model_ = nullptr;     // the model of the last pass
  std::vector<double> volume_grad_;          // ∇v_e at the tangent point  // #T×12
  std::vector<double> node_volume_now_;      // v_a  // #N
  std::vector<double> node_pressure_;        // p_a = U'(J_a)  // #N
  std::vector<double> patch_curvature_;      // c_a = U''(J_a)/V_a at the tangent point  // #N
  mutable std::vector<double> patch_slope_;  // product scratch  // #N
  std::vector<double> factor_values_;        // #nnz
  uint64_t a_values_version_ = 1;        // bumped by every AssembleJacobian
  uint64_t factor_values_version_ = 0;   // a_values_version_ factor_values_ was made from
  std::vector<double> patch_lump_;           // β_a of the factor's patch term  // #N
  double volumetric_energy_ = 0;             // J
  double patch_scale_ = 0;                   // h² of a_values_
  PatchTerm patch_{*this};
};

}  // namespace cutsim::fem
