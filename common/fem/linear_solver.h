#pragma once
/// @file
/// The linear solver of the implicit step: preconditioned conjugate
/// gradients on the assembled system A (sparse_system.h), preconditioned by
/// a sparse Cholesky factor (SuiteSparse CHOLMOD, supernodal, on the BLAS
/// that libblas.so.3 resolves to) of an earlier snapshot of A.
///
/// The factor may be stale: it is reused across Newton iterations, steps
/// and frames while PCG converges in few iterations, and a new one is asked
/// for when PCG needs more than a threshold (the caller's policy). The
/// factorisation runs on a persistent worker thread on a copy of A, so a
/// solve never waits for it; the newest finished factor is picked up at the
/// start of the next solve. After a topology change (cutting appends nodes
/// at the end and re-wires tets), a factor of the old pattern still covers
/// the old DOFs, a prefix of the new ones: it preconditions that prefix and
/// block Jacobi (the inverse of each remaining node's diagonal 3×3 block of
/// the current A) the rest, until the factor of the new pattern lands. The
/// same block Jacobi serves alone before the first factor exists.
///
/// After a topology change the caller may instead correct the old factor
/// for the changed and added DOFs (CorrectFactor, factor_correction.h): a
/// low-rank term that makes it precondition the cut matrix almost as a
/// fresh factor does, until the factor of the new pattern lands. The
/// correction is built on a second worker thread of its own (a factor in
/// the making never delays it) from a copy of A, and solves pick it up as
/// they pick up a factor; until then they use the old factor and block
/// Jacobi.
///
/// A snapshot that is not positive definite (an exact, indefinite tangent)
/// is factored with a diagonal shift A + σI, σ growing from 1e-6 of the
/// mean diagonal: a shifted factor is still a good preconditioner.
///
/// The preconditioner's triangular solves run in single precision by
/// default (supernodal_solve.h) and PCG stays in double; with an inexact
/// preconditioner PCG uses the flexible (Polak–Ribière) β, which equals
/// the classical one for an exact one. A solve may carry a deadline: it
/// stops there with the iterate so far.

#include <atomic>
#include <condition_variable>
#include <cstdint>
#include <limits>
#include <memory>
#include <mutex>
#include <span>
#include <thread>
#include <vector>

#include "common/fem/factor_correction.h"
#include "common/fem/sparse_system.h"
#include "common/fem/supernodal_solve.h"

namespace cutsim::fem {

/// What one PCG solve did.
struct PcgResult {
  int iterations = 0;
  double residual = 0;  ///< Final ‖b − A x‖₂ (recursive), in the units of b.
  bool converged = false;
  /// pᵀAp ≤ 0 met: A is not positive definite along p. The solve stops
  /// there with the iterate so far (a descent direction of the quadratic
  /// model for an SPD preconditioner), or the preconditioned rhs if first.
  bool negative_curvature = false;
  bool out_of_time = false;  ///< Stopped at the deadline with the iterate so far.
};

/// How the preconditioner applies the factor.
enum class FactorSolve : uint8_t {
  kFloat,    ///< Own supernodal triangular solves in single precision (default).
  kDouble,   ///< The same solves in double precision.
  kCholmod,  ///< CHOLMOD's cholmod_solve2 (double).
};

/// A coupling outside the pattern, applied by the product only (the
/// preconditioner does not see it): A(a, b) += k and A(b, a) += kᵀ (once,
/// k, when a == b). Penalty springs between nodes that share no tet.
struct ExtraBlock {
  int32_t a = 0, b = 0;
  Eigen::Matrix3d k = Eigen::Matrix3d::Zero();
};

/// A term of the system matrix applied without assembly: the PCG product
/// adds it to the assembled part's (the preconditioner does not see it).
class MatrixFreeTerm {
 public:
  virtual ~MatrixFreeTerm() = default;
  /// q += (the term)·p on all DOFs.  // #N×3 each
  virtual void AddProduct(const double* p, double* q) const = 0;
};

/// Cumulative counters of the factorisations.
struct FactorStats {
  int64_t requested = 0;     ///< Snapshots handed to the worker.
  int64_t completed = 0;     ///< Factors finished (successful or not).
  int64_t failed = 0;        ///< Factors that failed even with the shift.
  int64_t shifted = 0;       ///< Factors that needed a diagonal shift.
  double last_seconds = 0;   ///< Wall time of the last factorisation, s.
  double total_seconds = 0;  ///< Summed factorisation time, s.
  double last_analyze_seconds = 0;  ///< Wall time of the last symbolic analysis, s.
  /// OpenMP threads the last factorisation could use (omp_get_thread_limit
  /// inside it): 1 on the worker, whose regions never take a second core.
  int32_t factor_thread_limit = 0;
  int64_t corrections = 0;          ///< Low-rank corrections built (CorrectFactor).
  int64_t corrections_refused = 0;  ///< Corrections refused (rank cap, singular).
  int32_t last_correction_rank = 0;
  int32_t last_correction_drifted_nodes = 0;  ///< Nodes the last correction took for drift alone.
  double last_correction_seconds = 0;  ///< Wall time of the last correction (drift scan and build), s.
  int32_t max_correction_rank = 0;     ///< Largest rank of a correction built.
  double max_correction_seconds = 0;   ///< Longest correction build, s.
};

/// What CorrectFactor did with a request.
enum class CorrectionStart : uint8_t {
  kStarted,  ///< Handed to the correction thread (synchronous: built, or refused as singular).
  kBusy,     ///< The thread still builds an earlier one: ask again later.
  kRefused,  ///< No factor to correct, or above the rank cap on its own nodes.
};

class LinearSolver {
 public:
  /// `asynchronous`: factor on a worker thread (else inline, when asked:
  /// deterministic, and the asking solve waits).
  explicit LinearSolver(bool asynchronous = true, FactorSolve factor_solve = FactorSolve::kFloat);
  ~LinearSolver();
  LinearSolver(const LinearSolver&) = delete;
  LinearSolver& operator=(const LinearSolver&) = delete;

  /// Sizes the PCG workspace for `system` (allocates when it grew).
  void Resize(const SparseSystem& system);

  /// Hands a copy of A (`values`, #nnz of `system`'s pattern) to the worker
  /// unless it is busy; returns whether it was taken. Synchronous mode
  /// factors it now. The copy allocates only when the pattern changed.
  bool RequestFactor(const SparseSystem& system, const double* values);
  /// Blocks until the worker is idle and picks up its factor.
  void WaitForFactor();
  /// True while the worker factors a snapshot.
  [[nodiscard]] bool busy() const { return busy_.load(std::memory_order_acquire); }
  /// True once a factor is available to solves (after a solve picked it up).
  [[nodiscard]] bool has_factor() const { return front_ != nullptr; }
  /// DOFs the current factor covers (a prefix of the system's), 0 if none.
  [[nodiscard]] int32_t factor_dofs() const;
  /// Topology version of the pattern the current factor was made from.
  [[nodiscard]] uint64_t factor_topology_version() const;
  /// SparseSystem::pattern_id() of that pattern (−1: no factor).
  [[nodiscard]] int64_t factor_pattern_id() const;
  /// RequestFactor's count when the current factor was asked for (0: none):
  /// tells the caller which of its requests the factor answers.
  [[nodiscard]] uint64_t factor_request() const;
  /// The count of accepted RequestFactor calls.
  [[nodiscard]] uint64_t requests() const { return requests_; }

  /// Corrects the current factor (of an older pattern whose DOFs are a
  /// prefix of `system`'s) toward `values` on the DOFs of `changed_nodes`
  /// (old nodes whose elements changed since the factor was asked for,
  /// ascending) and of every new node (factor_correction.h). Copies
  /// `values` and the pattern and hands them to the correction thread
  /// (synchronous mode: builds now); solves use the correction from the
  /// first Acquire after it is built until a factor of `system`'s pattern
  /// is acquired. Refused without a factor or above `max_rank` DOFs; a
  /// singular one is refused by the build (FactorStats counts both), and
  /// solves then keep the factor on the old DOFs and block Jacobi.
  /// Allocates (a topology change).
  /// Old nodes outside `changed_nodes` whose columns moved by more than
  /// `drift` (relative, ‖A_c − A0_c‖/‖A_c‖ over the node's three columns)
  /// join the correction too, largest first, while the rank allows.
  CorrectionStart CorrectFactor(const SparseSystem& system, const double* values,
                                std::span<const int32_t> changed_nodes, int32_t max_rank,
                                double drift = std::numeric_limits<double>::infinity());
  /// Blocks until the correction thread is idle and picks up its correction.
  void WaitForCorrection();
  /// True while a correction is pending or being built.
  [[nodiscard]] bool correcting() const;
  /// Rank of the correction in use (0: none).
  [[nodiscard]] int32_t correction_rank() const;

  /// z = P⁻¹ r with the preconditioner a Solve would use now (the newest
  /// factor, its correction, block Jacobi on what they do not cover) on the
  /// DOFs with active[dof/3] != 0; `values` give the block Jacobi blocks.
  void Precondition(const SparseSystem& system, const double* values, const uint8_t* active, const double* r,
                    double* z, int num_threads = 1);

  /// Test hook: the factor worker and the correction thread wait this long
  /// after each factorisation or correction before publishing it, standing
  /// in for a slow machine.
  void set_worker_delay_for_testing(double seconds) { worker_delay_s_.store(seconds); }
  /// Makes the newest finished factor current (never waits).
  void Acquire();
  [[nodiscard]] FactorStats stats() const;

  /// Solves A x = b on the DOFs with active[dof/3] != 0 (others stay 0) by
  /// PCG from x = 0, until ‖r‖₂ ≤ tolerance or max_iterations. Picks up the
  /// newest finished factor first. Block Jacobi blocks come from `values`.
  /// `matrix_free`, if given, adds its product to A's. A `deadline_ns`
  /// (CLOCK_MONOTONIC, 0: none) ends the solve after the iteration that
  /// passes it, out_of_time, with the iterate so far (at least one
  /// iteration runs).
  /// Allocates nothing once Resize ran and a factor of this size was used.
  PcgResult Solve(const SparseSystem& system, const double* values, const uint8_t* active,
                  const double* b, double* x, double tolerance, int max_iterations,
                  int num_threads, std::span<const ExtraBlock> extra = {},
                  const MatrixFreeTerm* matrix_free = nullptr, int64_t deadline_ns = 0);

 private:
  struct Factor;
  struct Snapshot;
  struct CorrectionJob;
  template <typename Work>
  void Serve(std::condition_variable& cv, bool& pending, Work work);
  void BuildCorrection();
  void Factorize(Snapshot& s);
  void BuildBlockJacobi(const SparseSystem& system, const double* values, const uint8_t* active,
                        int32_t first_node, int num_threads);
  [[nodiscard]] int32_t CoveredDofs(const SparseSystem& system) const;
  /// `changed_nodes` and the old nodes whose columns of `b` drifted by
  /// more than `drift` from `factor`'s values, ascending, within `max_rank`
  /// DOFs with the new nodes'.
  [[nodiscard]] static std::vector<int32_t> WithDriftedNodes(const Factor& factor, const CscView& b,
                                                             std::span<const int32_t> changed_nodes,
                                                             int32_t max_rank, double drift);
  void ApplyPreconditioner(const SparseSystem& system, const uint8_t* active, const double* r,
                           double* z, int num_threads);

  bool asynchronous_;
  FactorSolve factor_solve_;
  void* solve_common_ = nullptr;   // cholmod_common of the solving thread
  void* worker_common_ = nullptr;  // cholmod_common of the factorising thread
  // Factor slots: front_ is used by solves; ready_ is finished and waits to
  // be picked up; retired_ waits for the worker to free it.
  Factor* front_ = nullptr;
  Factor* ready_ = nullptr;
  std::vector<Factor*> retired_;
  Factor* spare_ = nullptr;  // a retired factor of the current pattern, owned by the worker
  Snapshot* snapshot_ = nullptr;
  mutable std::mutex mutex_;
  std::condition_variable cv_;
  std::atomic<bool> busy_{false};
  bool request_pending_ = false;
  uint64_t requests_ = 0;
  std::atomic<double> worker_delay_s_{0};
  // The low-rank correction of front_ toward the pattern `correction_pattern_`
  // (the solves'); the one built and waiting for Acquire; the one the
  // correction thread builds into. Swapped, never copied.
  std::unique_ptr<FactorCorrection> correction_, correction_ready_, correction_building_;
  uint64_t correction_request_ = 0;  // factor_request() of the factor it corrects
  int64_t correction_pattern_ = -1;
  uint64_t ready_correction_request_ = 0;  // the same for correction_ready_
  int64_t ready_correction_pattern_ = -1;
  bool correction_landed_ = false;   // correction_ready_ waits for Acquire
  std::atomic<bool> published_{false};  // a factor or correction waits for Acquire (read by Solve's loop)
  bool correction_busy_ = false;     // a job is pending or being built
  bool correction_pending_ = false;  // job_ waits for the correction thread
  CorrectionJob* job_ = nullptr;
  std::condition_variable correction_cv_;
  bool stop_ = false;
  FactorStats stats_;
  std::thread worker_;
  std::thread corrector_;
  // Solve workspace.  // #3N each
  std::vector<double> r_, z_, z_prev_, p_, q_;
  std::vector<float> work_f_;   // supernodal solve scratch
  std::vector<double> work_d_;
  std::vector<double> jacobi_;  // #N×9: inverse diagonal blocks, column-major
  void* dense_x_ = nullptr;     // cholmod_dense results and workspace, reused
  void* dense_y_ = nullptr;
  void* dense_e_ = nullptr;
};

}  // namespace cutsim::fem
