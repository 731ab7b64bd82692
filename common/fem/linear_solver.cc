#include "common/fem/linear_solver.h"

#include <dlfcn.h>
#include <omp.h>
#include <suitesparse/cholmod.h>

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <functional>
#include <limits>
#include <memory>
#include <thread>

#include <Eigen/Core>
#include <Eigen/LU>

#include "common/core/clock.h"
#include "common/core/headroom.h"
#include "common/fem/node_sums.h"
#include "common/fem/threads.h"

namespace cutsim::fem {

namespace {
/// A copy of a SparseSystem's CSC pattern, shared by the snapshot and the
/// factors made from it (a correction reads the factored values on it).
struct Pattern {
  std::vector<int32_t> col_ptr, row_index;
};
}  // namespace

struct LinearSolver::Factor {
  cholmod_factor* L = nullptr;
  SupernodalSolver<float> single;   // with FactorSolve::kFloat
  SupernodalSolver<double> twin;    // with FactorSolve::kDouble
  std::shared_ptr<const Pattern> pattern;
  std::vector<double> values;       // the factored matrix  // #nnz
  int32_t dofs = 0;
  uint64_t topology_version = 0;
  int64_t pattern_id = -1;
  uint64_t request = 0;
  int32_t pins = 0;  // corrections being built from it (guarded by mutex_): not freed while > 0
};

/// What a correction's build reads besides its factor, copied on the
/// frame's thread so the build never touches the live system.
struct LinearSolver::CorrectionJob {
  Factor* factor = nullptr;  // pinned for the build
  std::shared_ptr<const Pattern> pattern;  // B's
  int64_t pattern_id = -1;
  std::vector<double> values;  // B  // #nnz
  std::vector<int32_t> changed_nodes;
  int32_t max_rank = 0;
  double drift = 0;
};

/// A copy of A for the worker and the symbolic analysis of its pattern.
struct LinearSolver::Snapshot {
  std::shared_ptr<const Pattern> pattern;
  std::vector<double> values;
  int32_t dofs = 0;
  uint64_t topology_version = 0;
  int64_t pattern_id = -1;  // SparseSystem::pattern_id() of the pattern
  uint64_t request = 0;
  bool pattern_changed = false;  // the worker drops `symbolic` and analyses anew
  cholmod_factor* symbolic = nullptr;
};

namespace {

cholmod_common* Common(void* p) { return static_cast<cholmod_common*>(p); }

double Seconds(std::chrono::steady_clock::time_point t0) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
}

/// The BLAS under CHOLMOD is OpenBLAS here; its own thread pool would
/// compete with the step's OpenMP team for the same cores, so the worker
/// factors on one BLAS thread. Looked up at run time: other BLAS builds
/// have no such function and need nothing.
void LimitBlasThreads() {
  using SetThreads = void (*)(int);
  if (void* f = dlsym(RTLD_DEFAULT, "openblas_set_num_threads")) {
    reinterpret_cast<SetThreads>(f)(1);
  }
}

/// Deterministic sums of K per-node terms over `nn` nodes (node_sums.h).
template <int K, typename Body>
std::array<double, K> SumNodes(int32_t nn, int nt, Body&& body) {
  NodeSums<K> sums(nn);
#pragma omp parallel num_threads(nt)
  sums.Team(body);
  std::array<double, K> out{};
  for (int k = 0; k < K; ++k) out[static_cast<size_t>(k)] = sums.Total(k);
  return out;
}

}  // namespace

LinearSolver::LinearSolver(bool asynchronous, FactorSolve factor_solve)
    : asynchronous_(asynchronous), factor_solve_(factor_solve) {
  solve_common_ = new cholmod_common;
  worker_common_ = new cholmod_common;
  cholmod_start(Common(solve_common_));
  cholmod_start(Common(worker_common_));
  Common(worker_common_)->supernodal = CHOLMOD_SUPERNODAL;
  Common(worker_common_)->print = 0;
  Common(solve_common_)->print = 0;
  snapshot_ = new Snapshot;
  job_ = new CorrectionJob;
  correction_ = std::make_unique<FactorCorrection>();
  correction_ready_ = std::make_unique<FactorCorrection>();
  correction_building_ = std::make_unique<FactorCorrection>();
  LimitBlasThreads();
  if (asynchronous_) {
    worker_ = std::thread([this] { Serve(cv_, request_pending_, [this] { Factorize(*snapshot_); }); });
    corrector_ = std::thread([this] { Serve(correction_cv_, correction_pending_, [this] { BuildCorrection(); }); });
  }
}

LinearSolver::~LinearSolver() {
  {
    std::lock_guard<std::mutex> lock(mutex_);
    stop_ = true;
  }
  cv_.notify_all();
  correction_cv_.notify_all();
  if (worker_.joinable()) worker_.join();
  if (corrector_.joinable()) corrector_.join();
  delete job_;
  cholmod_common* cw = Common(worker_common_);
  for (Factor* f : {front_, ready_}) {
    if (f != nullptr) {
      cholmod_free_factor(&f->L, cw);
      delete f;
    }
  }
  for (Factor* f : retired_) {
    cholmod_free_factor(&f->L, cw);
    delete f;
  }
  if (spare_ != nullptr) {
    cholmod_free_factor(&spare_->L, cw);
    delete spare_;
  }
  cholmod_free_factor(&snapshot_->symbolic, cw);
  delete snapshot_;
  cholmod_common* cs = Common(solve_common_);
  for (void* d : {dense_x_, dense_y_, dense_e_}) {
    auto* dd = static_cast<cholmod_dense*>(d);
    cholmod_free_dense(&dd, cs);
  }
  cholmod_finish(cs);
  cholmod_finish(cw);
  delete cs;
  delete cw;
}

void LinearSolver::Resize(const SparseSystem& system) {
  const auto nd = static_cast<size_t>(system.num_dofs());
  ResizeWithHeadroom(r_, nd);
  ResizeWithHeadroom(z_, nd);
  ResizeWithHeadroom(z_prev_, nd);
  ResizeWithHeadroom(p_, nd);
  ResizeWithHeadroom(q_, nd);
  ResizeWithHeadroom(jacobi_, 3 * nd);
}

bool LinearSolver::RequestFactor(const SparseSystem& system, const double* values) {
  if (busy()) return false;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    Snapshot& s = *snapshot_;
    if (s.pattern_id != system.pattern_id() || s.dofs != system.num_dofs()) {
      s.pattern_changed = true;
      auto pattern = std::make_shared<Pattern>();
      pattern->col_ptr.assign(system.col_ptr(), system.col_ptr() + system.num_dofs() + 1);
      pattern->row_index.assign(system.row_index(), system.row_index() + system.nnz());
      s.pattern = std::move(pattern);
      s.dofs = system.num_dofs();
      s.topology_version = system.topology_version();
      s.pattern_id = system.pattern_id();
    }
    ResizeWithHeadroom(s.values, static_cast<size_t>(system.nnz()));
    std::copy(values, values + system.nnz(), s.values.begin());
    ++stats_.requested;
    s.request = ++requests_;
    busy_.store(true, std::memory_order_release);
    request_pending_ = true;
  }
  if (asynchronous_) {
    cv_.notify_all();
  } else {
    Factorize(*snapshot_);
    Acquire();
  }
  return true;
}

void LinearSolver::WaitForFactor() {
  if (asynchronous_) {
    std::unique_lock<std::mutex> lock(mutex_);
    cv_.wait(lock, [this] { return !busy_.load(std::memory_order_acquire); });
  }
  Acquire();
}

int32_t LinearSolver::factor_dofs() const { return front_ != nullptr ? front_->dofs : 0; }

uint64_t LinearSolver::factor_topology_version() const {
  return front_ != nullptr ? front_->topology_version : 0;
}

int64_t LinearSolver::factor_pattern_id() const {
  return front_ != nullptr ? front_->pattern_id : -1;
}

uint64_t LinearSolver::factor_request() const { return front_ != nullptr ? front_->request : 0; }

int32_t LinearSolver::correction_rank() const {
  return front_ != nullptr && correction_request_ == front_->request ? correction_->rank() : 0;
}

/// Scatters each old column of A and of A0 into one dense column to
/// compare them whatever their patterns: O(nnz(A) + nnz(A0)).
std::vector<int32_t> LinearSolver::WithDriftedNodes(const Factor& factor, const CscView& b,
                                                    std::span<const int32_t> changed_nodes, int32_t max_rank,
                                                    double drift) {
  std::vector<int32_t> nodes(changed_nodes.begin(), changed_nodes.end());
  const int32_t n = b.n;
  const int32_t n0 = factor.dofs;
  const int32_t budget = max_rank - 3 * static_cast<int32_t>(nodes.size()) - (n - n0);
  if (!(drift < std::numeric_limits<double>::infinity()) || budget < 3 || n0 > n) return nodes;
  const int32_t old_nodes = n0 / 3;
  std::vector<uint8_t> taken(static_cast<size_t>(old_nodes), 0);
  for (const int32_t node : nodes) {
    if (node >= 0 && node < old_nodes) taken[static_cast<size_t>(node)] = 1;
  }
  const Pattern& p0 = *factor.pattern;
  const double* a0 = factor.values.data();
  const int32_t* col_ptr = b.col_ptr;
  const int32_t* row_index = b.row_index;
  const double* values = b.values;
  std::vector<double> column(static_cast<size_t>(n), 0.0);
  std::vector<std::pair<double, int32_t>> drifted;  // (relative drift, node)
  for (int32_t node = 0; node < old_nodes; ++node) {
    if (taken[static_cast<size_t>(node)] != 0) continue;
    double moved = 0, norm = 0;
    for (int32_t c = 3 * node; c < 3 * node + 3; ++c) {
      for (int32_t k = col_ptr[c]; k < col_ptr[c + 1]; ++k) {
        column[static_cast<size_t>(row_index[k])] = values[k];
        norm += values[k] * values[k];
      }
      for (int32_t k = p0.col_ptr[static_cast<size_t>(c)]; k < p0.col_ptr[static_cast<size_t>(c) + 1]; ++k) {
        column[static_cast<size_t>(p0.row_index[static_cast<size_t>(k)])] -= a0[k];
      }
      // Read back and clear both patterns' rows (a row in both is read once).
      for (int32_t k = col_ptr[c]; k < col_ptr[c + 1]; ++k) {
        double& v = column[static_cast<size_t>(row_index[k])];
        moved += v * v;
        v = 0;
      }
      for (int32_t k = p0.col_ptr[static_cast<size_t>(c)]; k < p0.col_ptr[static_cast<size_t>(c) + 1]; ++k) {
        double& v = column[static_cast<size_t>(p0.row_index[static_cast<size_t>(k)])];
        moved += v * v;
        v = 0;
      }
    }
    if (norm > 0 && moved > drift * drift * norm) drifted.emplace_back(std::sqrt(moved / norm), node);
  }
  const auto take = std::min<size_t>(drifted.size(), static_cast<size_t>(budget / 3));
  std::partial_sort(drifted.begin(), drifted.begin() + static_cast<std::ptrdiff_t>(take), drifted.end(),
                    std::greater<>());
  for (size_t i = 0; i < take; ++i) nodes.push_back(drifted[i].second);
  std::sort(nodes.begin(), nodes.end());
  return nodes;
}

CorrectionStart LinearSolver::CorrectFactor(const SparseSystem& system, const double* values,
                                            std::span<const int32_t> changed_nodes, int32_t max_rank,
                                            double drift) {
  Acquire();
  const int32_t n = system.num_dofs();
  if (front_ == nullptr || front_->dofs > n || front_->single.empty() || !front_->pattern ||
      3 * static_cast<int32_t>(changed_nodes.size()) + (n - front_->dofs) > max_rank) {
    std::lock_guard<std::mutex> lock(mutex_);
    ++stats_.corrections_refused;
    return CorrectionStart::kRefused;
  }
  {
    std::lock_guard<std::mutex> lock(mutex_);
    if (correction_busy_) return CorrectionStart::kBusy;
    CorrectionJob& job = *job_;
    job.factor = front_;
    ++front_->pins;
    if (snapshot_->pattern_id == system.pattern_id() && snapshot_->dofs == n && snapshot_->pattern) {
      job.pattern = snapshot_->pattern;
    } else if (job.pattern_id != system.pattern_id() || !job.pattern) {
      auto pattern = std::make_shared<Pattern>();
      pattern->col_ptr.assign(system.col_ptr(), system.col_ptr() + n + 1);
      pattern->row_index.assign(system.row_index(), system.row_index() + system.nnz());
      job.pattern = std::move(pattern);
    }
    job.pattern_id = system.pattern_id();
    job.values.assign(values, values + system.nnz());
    job.changed_nodes.assign(changed_nodes.begin(), changed_nodes.end());
    job.max_rank = max_rank;
    job.drift = drift;
    correction_busy_ = true;
    correction_pending_ = asynchronous_;
  }
  if (asynchronous_) {
    correction_cv_.notify_all();
  } else {
    BuildCorrection();
    Acquire();
  }
  return CorrectionStart::kStarted;
}

void LinearSolver::WaitForCorrection() {
  if (asynchronous_) {
    std::unique_lock<std::mutex> lock(mutex_);
    correction_cv_.wait(lock, [this] { return !correction_busy_; });
  }
  Acquire();
}

bool LinearSolver::correcting() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return correction_busy_;
}

/// Builds the pending job's correction into correction_building_ (on the
/// correction thread, or inline when synchronous) and publishes it as
/// correction_ready_ for the next Acquire. Reads only the job and its
/// pinned factor.
void LinearSolver::BuildCorrection() {
  CorrectionJob& job = *job_;
  const auto t0 = std::chrono::steady_clock::now();
  const Factor& f = *job.factor;
  const CscView a0{f.pattern->col_ptr.data(), f.pattern->row_index.data(), f.values.data(), f.dofs};
  const CscView b{job.pattern->col_ptr.data(), job.pattern->row_index.data(), job.values.data(),
                  static_cast<int32_t>(job.pattern->col_ptr.size()) - 1};
  const std::vector<int32_t> nodes = WithDriftedNodes(f, b, job.changed_nodes, job.max_rank, job.drift);
  const auto drifted = static_cast<int32_t>(nodes.size() - job.changed_nodes.size());
  const bool ok = correction_building_->Build(f.single, a0, b, nodes, job.max_rank);
  const double seconds = Seconds(t0);  // the drift scan and the build
  if (const double delay = worker_delay_s_.load(); delay > 0 && asynchronous_) {
    std::this_thread::sleep_for(std::chrono::duration<double>(delay));
  }
  std::lock_guard<std::mutex> lock(mutex_);
  if (ok) {
    std::swap(correction_building_, correction_ready_);
    ready_correction_request_ = f.request;
    ready_correction_pattern_ = job.pattern_id;
    correction_landed_ = true;
    published_.store(true, std::memory_order_release);
    ++stats_.corrections;
    stats_.last_correction_rank = correction_ready_->rank();
    stats_.last_correction_drifted_nodes = drifted;
    stats_.last_correction_seconds = seconds;
    stats_.max_correction_rank = std::max(stats_.max_correction_rank, correction_ready_->rank());
    stats_.max_correction_seconds = std::max(stats_.max_correction_seconds, seconds);
  } else {
    ++stats_.corrections_refused;
  }
  --job.factor->pins;
  job.factor = nullptr;
  correction_busy_ = false;
}

FactorStats LinearSolver::stats() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return stats_;
}

/// The loop of the factor worker and of the correction thread: waits for
/// `pending`, clears it and runs `work` on one core, then wakes the waiters
/// (WaitForFactor, WaitForCorrection). One core: CHOLMOD's supernodal
/// factorisation opens OpenMP regions of its own (num_threads(4) on its
/// clears of L) and Eigen's products in a correction would open teams too,
/// putting more threads on the cores of the step's team. A host teams
/// region's thread limit holds every region inside it to this thread.
template <typename Work>
void LinearSolver::Serve(std::condition_variable& cv, bool& pending, Work work) {
  std::unique_lock<std::mutex> lock(mutex_);
  while (true) {
    cv.wait(lock, [&] { return stop_ || pending; });
    if (stop_) return;
    pending = false;
    lock.unlock();
#pragma omp teams num_teams(1) thread_limit(1)
    work();
    lock.lock();
    cv.notify_all();
  }
}

/// Runs on the worker (or inline when synchronous): analyses the pattern if
/// new, factors the snapshot (shifted if it is not positive definite) and
/// publishes the factor as ready_. Frees retired factors.
void LinearSolver::Factorize(Snapshot& s) {
  cholmod_common* cw = Common(worker_common_);
  cholmod_sparse a{};
  a.nrow = a.ncol = static_cast<size_t>(s.dofs);
  a.nzmax = s.values.size();
  a.p = const_cast<int32_t*>(s.pattern->col_ptr.data());
  a.i = const_cast<int32_t*>(s.pattern->row_index.data());
  a.x = s.values.data();
  a.stype = -1;  // symmetric, lower triangle used
  a.itype = CHOLMOD_INT;
  a.xtype = CHOLMOD_REAL;
  a.dtype = CHOLMOD_DOUBLE;
  a.sorted = 1;
  a.packed = 1;
  const auto t0 = std::chrono::steady_clock::now();
  double analyze_seconds = -1;
  if (s.pattern_changed) {
    cholmod_free_factor(&s.symbolic, cw);
    s.pattern_changed = false;
  }
  if (s.symbolic == nullptr) {
    s.symbolic = cholmod_analyze(&a, cw);
    analyze_seconds = Seconds(t0);
  }
  // Reuse the memory of a retired factor of this pattern (no allocation,
  // no page faults); otherwise copy the symbolic analysis.
  if (spare_ != nullptr && spare_->pattern_id != s.pattern_id) {
    cholmod_free_factor(&spare_->L, cw);
    delete spare_;
    spare_ = nullptr;
  }
  Factor* f = spare_ != nullptr ? spare_ : new Factor;
  spare_ = nullptr;
  f->dofs = s.dofs;
  f->topology_version = s.topology_version;
  f->pattern_id = s.pattern_id;
  f->request = s.request;
  f->pattern = s.pattern;
  bool ok = false, shifted = false;
  if (s.symbolic != nullptr) {
    double mean_diag = 0;
    for (int32_t j = 0; j < s.dofs; ++j) {
      const std::vector<int32_t>& cp = s.pattern->col_ptr;
      for (int32_t k = cp[static_cast<size_t>(j)]; k < cp[static_cast<size_t>(j) + 1]; ++k) {
        if (s.pattern->row_index[static_cast<size_t>(k)] == j) mean_diag += std::abs(s.values[static_cast<size_t>(k)]);
      }
    }
    mean_diag /= std::max(1, s.dofs);
    double shift = 0;
    for (int attempt = 0; attempt < 6 && !ok; ++attempt) {
      if (f->L == nullptr) f->L = cholmod_copy_factor(s.symbolic, cw);
      double beta[2] = {shift, 0};
      cholmod_factorize_p(&a, beta, nullptr, 0, f->L, cw);
      ok = f->L != nullptr && cw->status == CHOLMOD_OK && f->L->minor == f->L->n;
      if (!ok) {
        shift = shift == 0 ? 1e-6 * mean_diag : shift * 100.0;
        shifted = true;
      }
    }
  }
  if (ok) {
    // The solve's own copy of L, and the factored values for a correction.
    if (factor_solve_ == FactorSolve::kFloat) ok = f->single.Assign(f->L);
    if (factor_solve_ == FactorSolve::kDouble) ok = f->twin.Assign(f->L);
    f->values.assign(s.values.begin(), s.values.end());
  }
  const double seconds = Seconds(t0);
  if (const double delay = worker_delay_s_.load(); delay > 0) {
    std::this_thread::sleep_for(std::chrono::duration<double>(delay));
  }
  std::vector<Factor*> to_free, kept;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    ++stats_.completed;
    stats_.failed += ok ? 0 : 1;
    stats_.shifted += ok && shifted ? 1 : 0;
    stats_.last_seconds = seconds;
    stats_.factor_thread_limit = omp_get_thread_limit();
    stats_.total_seconds += seconds;
    if (analyze_seconds >= 0) stats_.last_analyze_seconds = analyze_seconds;
    if (ok) {
      if (ready_ != nullptr) retired_.push_back(ready_);
      ready_ = f;
      f = nullptr;
      published_.store(true, std::memory_order_release);
    }
    // A factor a correction is being built from stays retired until done.
    for (Factor* g : retired_) (g->pins > 0 ? kept : to_free).push_back(g);
    retired_.swap(kept);
    request_pending_ = false;
    busy_.store(false, std::memory_order_release);
  }
  if (f != nullptr) {
    cholmod_free_factor(&f->L, cw);
    delete f;
  }
  for (Factor* g : to_free) {
    if (spare_ == nullptr && g->pattern_id == s.pattern_id) {
      spare_ = g;
      continue;
    }
    cholmod_free_factor(&g->L, cw);
    delete g;
  }
}

/// Makes the finished factor current; the old one is retired (the next
/// factorisation frees it or keeps it as its spare, so solves never free
/// CHOLMOD memory).
void LinearSolver::Acquire() {
  std::lock_guard<std::mutex> lock(mutex_);
  published_.store(false, std::memory_order_relaxed);
  if (correction_landed_) {
    std::swap(correction_, correction_ready_);
    correction_request_ = ready_correction_request_;
    correction_pattern_ = ready_correction_pattern_;
    correction_landed_ = false;
  }
  if (ready_ == nullptr) return;
  if (front_ != nullptr) retired_.push_back(front_);
  front_ = ready_;
  ready_ = nullptr;
}

void LinearSolver::BuildBlockJacobi(const SparseSystem& system, const double* values,
                                    const uint8_t* active, int32_t first_node, int num_threads) {
  const int32_t nn = system.num_nodes();
  double* jac = jacobi_.data();
#pragma omp parallel for schedule(static) num_threads(num_threads)
  for (int32_t n = first_node; n < nn; ++n) {
    Eigen::Map<Eigen::Matrix3d> out(jac + 9 * n);
    const Eigen::Matrix3d d = system.GetBlock(values, system.diagonal_block(n), n);
    bool invertible = false;
    if (active[n] != 0) d.computeInverseWithCheck(out, invertible);
    if (!invertible) out.setZero();
  }
}

/// DOFs (a prefix) the factor in use preconditions, with its correction
/// all of them; the rest get block Jacobi.
int32_t LinearSolver::CoveredDofs(const SparseSystem& system) const {
  if (front_ == nullptr || front_->dofs > system.num_dofs()) return 0;
  if (correction_request_ == front_->request && correction_pattern_ == system.pattern_id() &&
      correction_->size() == system.num_dofs()) {
    return system.num_dofs();
  }
  return front_->dofs;
}

void LinearSolver::ApplyPreconditioner(const SparseSystem& system, const uint8_t* active,
                                       const double* r, double* z, int num_threads) {
  const int32_t nn = system.num_nodes();
  const int32_t covered = CoveredDofs(system);
  if (covered == system.num_dofs() && covered > front_->dofs) {
    correction_->Apply(front_->single, r, z);
  } else if (covered > 0 && factor_solve_ == FactorSolve::kFloat) {
    if (work_f_.size() < static_cast<size_t>(front_->single.work_size())) {
      work_f_.resize(static_cast<size_t>(front_->single.work_size()));
    }
    front_->single.Solve(r, z, work_f_.data());
  } else if (covered > 0 && factor_solve_ == FactorSolve::kDouble) {
    if (work_d_.size() < static_cast<size_t>(front_->twin.work_size())) {
      work_d_.resize(static_cast<size_t>(front_->twin.work_size()));
    }
    front_->twin.Solve(r, z, work_d_.data());
  } else if (covered > 0) {
    cholmod_common* cs = Common(solve_common_);
    cholmod_dense b{};
    b.nrow = b.nzmax = b.d = static_cast<size_t>(front_->dofs);
    b.ncol = 1;
    b.x = const_cast<double*>(r);
    b.xtype = CHOLMOD_REAL;
    b.dtype = CHOLMOD_DOUBLE;
    auto* x = static_cast<cholmod_dense*>(dense_x_);
    auto* y = static_cast<cholmod_dense*>(dense_y_);
    auto* e = static_cast<cholmod_dense*>(dense_e_);
    if (cholmod_solve2(CHOLMOD_A, front_->L, &b, nullptr, &x, nullptr, &y, &e, cs) != 0) {
      const auto* xs = static_cast<const double*>(x->x);
      std::copy(xs, xs + front_->dofs, z);
    }
    dense_x_ = x;
    dense_y_ = y;
    dense_e_ = e;
  }
  const int32_t first_node = covered / 3;
  const double* jac = jacobi_.data();
#pragma omp parallel for schedule(static) num_threads(num_threads)
  for (int32_t n = 0; n < nn; ++n) {
    if (active[n] == 0) {
      z[3 * n] = z[3 * n + 1] = z[3 * n + 2] = 0;
    } else if (n >= first_node) {
      Eigen::Map<Eigen::Vector3d>(z + 3 * n) =
          Eigen::Map<const Eigen::Matrix3d>(jac + 9 * n) * Eigen::Map<const Eigen::Vector3d>(r + 3 * n);
    }
  }
}

void LinearSolver::Precondition(const SparseSystem& system, const double* values, const uint8_t* active,
                                const double* r, double* z, int num_threads) {
  const int nt = Threads(num_threads);
  Acquire();
  const int32_t covered = CoveredDofs(system) / 3;
  if (covered < system.num_nodes()) BuildBlockJacobi(system, values, active, covered, nt);
  ApplyPreconditioner(system, active, r, z, nt);
}

PcgResult LinearSolver::Solve(const SparseSystem& system, const double* values, const uint8_t* active,
                              const double* b, double* x, double tolerance, int max_iterations,
                              int num_threads, std::span<const ExtraBlock> extra,
                              const MatrixFreeTerm* matrix_free, int64_t deadline_ns) {
  const int nt = Threads(num_threads);
  const int32_t nn = system.num_nodes();
  Acquire();
  int32_t covered = CoveredDofs(system) / 3;  // nodes the factor (and its correction) cover
  if (covered < nn) BuildBlockJacobi(system, values, active, covered, nt);
  double* r = r_.data();
  double* z = z_.data();
  double* z_prev = z_prev_.data();
  double* p = p_.data();
  double* q = q_.data();
  PcgResult res;
  // x = 0, r = b (masked).
  const auto init = SumNodes<1>(nn, nt, [&](int32_t n, std::array<double, 1>& acc) {
    for (int d = 0; d < 3; ++d) {
      const int32_t i = 3 * n + d;
      x[i] = 0;
      r[i] = active[n] != 0 ? b[i] : 0.0;
      acc[0] += r[i] * r[i];
    }
  });
  res.residual = std::sqrt(init[0]);
  if (res.residual <= tolerance) {
    res.converged = true;
    return res;
  }
  double rz_old = 0;
  bool restart = false;
  for (int it = 0; it < max_iterations; ++it) {
    // A factor or correction that lands mid-solve is taken at once (the
    // frame after a cut need not finish on the stale preconditioner); the
    // iteration that changes it restarts the directions (β = 0).
    if (it > 0 && published_.load(std::memory_order_acquire)) {
      Acquire();
      restart = true;
      // A factor of an older pattern can cover fewer nodes than the
      // correction it replaces: block Jacobi takes the rest.
      const int32_t now_covered = CoveredDofs(system) / 3;
      if (now_covered < covered) BuildBlockJacobi(system, values, active, now_covered, nt);
      covered = now_covered;
    }
    std::swap(z, z_prev);
    ApplyPreconditioner(system, active, r, z, nt);
    // Flexible (Polak–Ribière) β = rᵀ(z − z_prev)/rz_old: robust to a
    // preconditioner that is not exactly the same linear map every time.
    const auto sums = SumNodes<2>(nn, nt, [&](int32_t n, std::array<double, 2>& acc) {
      for (int d = 0; d < 3; ++d) {
        acc[0] += r[3 * n + d] * z[3 * n + d];
        acc[1] += it == 0 ? 0.0 : r[3 * n + d] * z_prev[3 * n + d];
      }
    });
    const double rz = sums[0];
    const double beta = it == 0 || restart ? 0.0 : std::max(0.0, (rz - sums[1]) / rz_old);
    rz_old = rz;
    restart = false;
#pragma omp parallel num_threads(nt)
    {
#pragma omp for schedule(static)
      for (int32_t i = 0; i < 3 * nn; ++i) p[i] = z[i] + beta * p[i];
      system.MultiplyTeam(values, p, q);
    }
    if (matrix_free != nullptr) matrix_free->AddProduct(p, q);
    for (const ExtraBlock& e : extra) {
      Eigen::Map<Eigen::Vector3d>(q + 3 * e.a) += e.k * Eigen::Map<const Eigen::Vector3d>(p + 3 * e.b);
      if (e.a != e.b) {
        Eigen::Map<Eigen::Vector3d>(q + 3 * e.b) += e.k.transpose() * Eigen::Map<const Eigen::Vector3d>(p + 3 * e.a);
      }
    }
    const double pq = SumNodes<1>(nn, nt, [&](int32_t n, std::array<double, 1>& acc) {
      for (int d = 0; d < 3; ++d) {
        const int32_t i = 3 * n + d;
        if (active[n] == 0) q[i] = 0;
        acc[0] += p[i] * q[i];
      }
    })[0];
    if (!(pq > 0)) {
      res.negative_curvature = true;
      if (it == 0) std::copy(z, z + 3 * nn, x);  // preconditioned rhs: a descent direction
      res.iterations = it + 1;
      return res;
    }
    const double alpha = rz / pq;
    const auto rr = SumNodes<1>(nn, nt, [&](int32_t n, std::array<double, 1>& acc) {
      for (int d = 0; d < 3; ++d) {
        const int32_t i = 3 * n + d;
        x[i] += alpha * p[i];
        r[i] -= alpha * q[i];
        acc[0] += r[i] * r[i];
      }
    });
    res.iterations = it + 1;
    res.residual = std::sqrt(rr[0]);
    if (!std::isfinite(res.residual)) return res;
    if (res.residual <= tolerance) {
      res.converged = true;
      return res;
    }
    if (deadline_ns > 0 && MonotonicNs() >= deadline_ns) {
      res.out_of_time = true;
      return res;
    }
  }
  return res;
}

}  // namespace cutsim::fem
