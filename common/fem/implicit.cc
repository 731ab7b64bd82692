#include "common/fem/implicit.h"

#include <omp.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <limits>

#include <Eigen/Cholesky>

#include "common/core/clock.h"
#include "common/core/hash.h"
#include "common/core/headroom.h"
#include "common/fem/implicit_internal.h"
#include "common/fem/node_sums.h"

namespace cutsim::fem {

namespace {

using internal::ForEachTetByColor;
using internal::ScatterBlocks;
using internal::TetPositions;

/// Below this many tets the automatic thread count is one: the element
/// pass has a barrier per colour and PCG a few per iteration, which cost
/// more than a small mesh's work (and much more on an oversubscribed
/// machine, where a barrier can wait for a time slice).
constexpr int32_t kMinTetsForThreads = 4096;

/// Out-of-pattern penalty couplings kept without allocation (more allocate).
constexpr size_t kExtraBlockReserve = 64;
/// EffectiveStiffness: the most blocks of its Krylov space, and the
/// estimated relative error of the compliance that ends it.
constexpr int kComplianceBlocks = 3;
constexpr double kComplianceError = 5e-2;
/// Armijo sufficient-decrease constant of the line search.
constexpr double kArmijo = 1e-4;
/// Relative round-off of Φ: near the solution the decrease Φ can show is
/// below it, so a trial within it that lowers the residual is accepted.
constexpr double kPhiRoundOff = 1e-12;

/// p = Σ w_i x_i of a penalty term.
Eigen::Vector3d PenaltyPoint(const PenaltyTerm& p, const double* x) {
  Eigen::Vector3d s = Eigen::Vector3d::Zero();
  for (int i = 0; i < 3; ++i) {
    const int32_t n = p.nodes[static_cast<size_t>(i)];
    if (n >= 0) s += p.weights[static_cast<size_t>(i)] * Eigen::Map<const Eigen::Vector3d>(x + 3 * n);
  }
  return s;
}

/// A hash of what tet t contributes to the system's pattern and values at
/// rest: its nodes, Dm⁻¹ and rest volume.
uint64_t TetSignature(const Model<double>& model, int32_t t) {
  std::array<int32_t, 4> nodes{};
  for (int c = 0; c < 4; ++c) nodes[static_cast<size_t>(c)] = model.tet_node(t, c);
  const Mat3<double> dm_inv = model.DmInv(t);
  const double vol = model.rest_volume(t);
  uint64_t h = Fnv1a64(nodes.data(), sizeof(nodes));
  h = Fnv1a64(dm_inv.data(), 9 * sizeof(double), h);
  return Fnv1a64(&vol, sizeof(vol), h);
}

/// Σ a[ao + i]·b[bo + i] over the #N×3 DOFs.
double Dot(const std::vector<double>& a, const std::vector<double>& b, size_t ao, size_t bo, int32_t nn, int nt) {
  NodeSums<1> sums(nn);
#pragma omp parallel num_threads(nt)
  sums.Team([&](int32_t n, std::array<double, 1>& acc) {
    for (int d = 0; d < 3; ++d) acc[0] += a[ao + static_cast<size_t>(3 * n + d)] * b[bo + static_cast<size_t>(3 * n + d)];
  });
  return sums.Total(0);
}

double Dot(const std::vector<double>& a, const std::vector<double>& b, int32_t nn, int nt) {
  NodeSums<1> sums(nn);
#pragma omp parallel num_threads(nt)
  sums.Team([&](int32_t n, std::array<double, 1>& acc) {
    for (int d = 0; d < 3; ++d) acc[0] += a[static_cast<size_t>(3 * n + d)] * b[static_cast<size_t>(3 * n + d)];
  });
  return sums.Total(0);
}

}  // namespace

const char* ImplicitPhaseName(ImplicitPhase phase) {
  switch (phase) {
    case ImplicitPhase::kSetup:
      return "setup";
    case ImplicitPhase::kEvaluate:
      return "evaluate";
    case ImplicitPhase::kAssemble:
      return "assemble";
    case ImplicitPhase::kFactorSetup:
      return "factor_setup";
    case ImplicitPhase::kSolve:
      return "solve";
  }
  return "setup";
}

ImplicitIntegrator::ImplicitIntegrator(const ImplicitOptions& options)
    : options_(options), solver_(options.asynchronous_factorization, options.factor_solve) {
  last_penalties_.reserve(kExtraBlockReserve);
  jacobian_penalties_.reserve(kExtraBlockReserve);
}

int ImplicitIntegrator::NumThreads() const {
  if (options_.num_threads > 0) return options_.num_threads;
  return system_.num_tets() < kMinTetsForThreads ? 1 : omp_get_max_threads();
}

void ImplicitIntegrator::Prepare(const Model<double>& model, ImplicitResult& result) {
  if (system_.Stale(model)) {
    system_.Build(model);
    const auto nd = static_cast<size_t>(system_.num_dofs());
    const auto nnz = static_cast<size_t>(system_.nnz());
    AssignWithHeadroom(b_values_, nnz, 0.0);
    AssignWithHeadroom(a_values_, nnz, 0.0);
    AssignWithHeadroom(k_values_, nnz, 0.0);
    for (auto* v : {&x0_, &v0_, &v_, &v_try_, &x_, &force_, &node_force_, &residual_, &residual_try_,
                    &bv_, &dir_, &rhs_}) {
      AssignWithHeadroom(*v, nd, 0.0);
    }
    AssignWithHeadroom(compliance_z_, 3 * kComplianceBlocks * nd, 0.0);
    AssignWithHeadroom(compliance_q_, 3 * kComplianceBlocks * nd, 0.0);
    AssignWithHeadroom(compliance_r_, 3 * nd, 0.0);
    AssignWithHeadroom(tet_energy_, static_cast<size_t>(system_.num_tets()), 0.0);
    AssignWithHeadroom(active_, static_cast<size_t>(system_.num_nodes()), uint8_t{0});
    extra_.clear();
    extra_.reserve(kExtraBlockReserve);
    nodal_pressure_ = model.element() == ElementKind::kNodalPressure;
    if (nodal_pressure_) {
      AssignWithHeadroom(volume_grad_, 12 * static_cast<size_t>(system_.num_tets()), 0.0);
      for (auto* v : {&node_volume_now_, &node_pressure_, &patch_curvature_, &patch_slope_}) {
        AssignWithHeadroom(*v, static_cast<size_t>(system_.num_nodes()), 0.0);
      }
      LumpPatchTerm(model);
    }
    AssignWithHeadroom(factor_values_, nnz, 0.0);
    ++a_values_version_;
    solver_.Resize(system_);
    have_k_ = false;
    b_values_valid_ = false;
    result.pattern_rebuilt = true;
  }
  model_ = &model;
  for (int32_t n = 0; n < system_.num_nodes(); ++n) {
    const uint8_t on = !model.fixed(n) && model.node_mass(n) > 0 ? 1 : 0;
    if (active_[static_cast<size_t>(n)] != on) have_k_ = b_values_valid_ = false;  // identity rows moved
    active_[static_cast<size_t>(n)] = on;
  }
}

void ImplicitIntegrator::ElementPass(const Model<double>& model, const double* x, double tangent_scale,
                                     bool clamped, bool skip_inactive, double* values) {
  const int nt = NumThreads();
  const uint8_t* active = skip_inactive ? active_.data() : nullptr;
  double* force = node_force_.data();
  double* energy = tet_energy_.data();
  const int32_t nd = system_.num_dofs();
#pragma omp parallel num_threads(nt)
  {
#pragma omp for schedule(static)
    for (int32_t i = 0; i < nd; ++i) force[i] = 0;
    ForEachTetByColor(system_, [&](int32_t t) {
      const double vol = model.rest_volume(t);
      energy[t] = 0;
      if (!(vol > 0)) return;  // a degenerate cut element carries no stiffness
      const Mat3<double> dm_inv = model.DmInv(t);
      const Mat34<double> g = ShapeGradients(dm_inv);
      const Mat3<double> F = EdgeMatrix(TetPositions(model, x, t)) * dm_inv;
      const double lambda = model.element_lambdas()[t], mu = model.mus()[t];
      Mat3<double> S;
      Mat34<double> fe;
      energy[t] = StvkEnergyAndForce(F, g, vol, lambda, mu, &S, &fe);
      for (int c = 0; c < 4; ++c) {
        Eigen::Map<Eigen::Vector3d>(force + 3 * model.tet_node(t, c)) += fe.col(c);
      }
      if (tangent_scale > 0) {
        ElementBlocks blocks;
        ElementTangentBlocks(F, clamped ? PositivePart(S) : S, g, vol, lambda, mu, blocks);
        ScatterBlocks(system_, model, t, blocks, tangent_scale, active, values);
      }
    });
  }
  if (nodal_pressure_) VolumetricPass(model, x, tangent_scale, clamped, active, values);
}

void ImplicitIntegrator::DampingPass(const Model<double>& model, const double* x, double scale,
                                     double mass_scale, bool skip_inactive, double* values) {
  const int nt = NumThreads();
  const uint8_t* active = skip_inactive ? active_.data() : nullptr;
  const auto nnz = static_cast<size_t>(system_.nnz());
  std::fill(values, values + nnz, 0.0);
  for (int32_t n = 0; n < system_.num_nodes(); ++n) {
    const bool on = active == nullptr || active[n] != 0;
    const double d = on ? mass_scale * model.node_mass(n) : 1.0;
    system_.AddBlock(values, system_.diagonal_block(n), n, d * Eigen::Matrix3d::Identity());
  }
  if (!model.damped() || scale == 0) return;
#pragma omp parallel num_threads(nt)
  ForEachTetByColor(system_, [&](int32_t t) {
    const double vol = model.rest_volume(t);
    if (!(vol > 0)) return;
    const Mat3<double> dm_inv = model.DmInv(t);
    const Mat3<double> F = EdgeMatrix(TetPositions(model, x, t)) * dm_inv;
    ElementBlocks blocks;
    ElementTangentBlocks(F, Mat3<double>::Zero(), ShapeGradients(dm_inv), vol, model.phis()[t],
                         model.psis()[t], blocks);
    ScatterBlocks(system_, model, t, blocks, scale, active, values);
  });
}

void ImplicitIntegrator::AssembleJacobian(const Model<double>& model, double h,
                                          std::span<const PenaltyTerm> penalties, bool clamped, bool assemble) {
  const int32_t nd = system_.num_dofs();
  if (assemble) {
    for (int32_t i = 0; i < nd; ++i) {
      const auto s = static_cast<size_t>(i);
      x_[s] = x0_[s] + (active_[s / 3] != 0 ? h * v_[s] : 0.0);
    }
    std::fill(k_values_.begin(), k_values_.end(), 0.0);
    ElementPass(model, x_.data(), 1.0, clamped, true, k_values_.data());
    have_k_ = true;
    k_clamped_ = clamped;
  }
  const double h2 = h * h;
  patch_scale_ = h2;
  const auto nnz = static_cast<int64_t>(a_values_.size());
#pragma omp parallel for schedule(static) num_threads(NumThreads())
  for (int64_t k = 0; k < nnz; ++k) {
    a_values_[static_cast<size_t>(k)] = b_values_[static_cast<size_t>(k)] + h2 * k_values_[static_cast<size_t>(k)];
  }
  extra_.clear();
  jacobian_penalties_.assign(penalties.begin(), penalties.end());
  AddPenaltyBlocks(penalties, h2, a_values_.data(), &extra_);
  ++a_values_version_;
}

void ImplicitIntegrator::AddPenaltyBlocks(std::span<const PenaltyTerm> penalties, double scale, double* values,
                                          std::vector<ExtraBlock>* extra) const {
  for (const PenaltyTerm& p : penalties) {
    const Eigen::Matrix3d ks = 0.5 * (p.stiffness + p.stiffness.transpose());
    for (int i = 0; i < 3; ++i) {
      const int32_t a = p.nodes[static_cast<size_t>(i)];
      if (a < 0 || active_[static_cast<size_t>(a)] == 0) continue;
      for (int j = 0; j < 3; ++j) {
        const int32_t b = p.nodes[static_cast<size_t>(j)];
        if (b < 0 || active_[static_cast<size_t>(b)] == 0) continue;
        const double w = p.weights[static_cast<size_t>(i)] * p.weights[static_cast<size_t>(j)];
        const int32_t off = system_.FindBlock(a, b);
        if (off >= 0) {
          system_.AddBlock(values, off, b, (scale * w) * ks);
        } else if (extra != nullptr && i < j) {  // outside the pattern: applied by the PCG product
          extra->push_back({a, b, (scale * w) * ks});
        }
      }
    }
  }
}

ImplicitIntegrator::Eval ImplicitIntegrator::Evaluate(const Model<double>& model, const State<double>& state,
                                                      double h, std::span<const PenaltyTerm> penalties,
                                                      const double* v, double* residual) {
  const int nt = NumThreads();
  const int32_t nn = system_.num_nodes();
  const uint8_t* active = active_.data();
  for (int32_t i = 0; i < 3 * nn; ++i) x_[static_cast<size_t>(i)] = x0_[static_cast<size_t>(i)] + (active[i / 3] != 0 ? h * v[i] : 0.0);
  ElementPass(model, x_.data(), 0, false, true, nullptr);
  Eval e;
  // Penalty springs: forces into node_force_, energy U_pen.
  double u_pen = 0;
  for (const PenaltyTerm& p : penalties) {
    const Eigen::Vector3d d = PenaltyPoint(p, x_.data()) - PenaltyPoint(p, x0_.data());
    const Eigen::Matrix3d ks = 0.5 * (p.stiffness + p.stiffness.transpose());
    const Eigen::Vector3d f = p.force - ks * d;
    u_pen += -p.force.dot(d) + 0.5 * d.dot(ks * d);
    for (int i = 0; i < 3; ++i) {
      const int32_t n = p.nodes[static_cast<size_t>(i)];
      if (n >= 0) Eigen::Map<Eigen::Vector3d>(node_force_.data() + 3 * n) += p.weights[static_cast<size_t>(i)] * f;
    }
  }
  const double* mass = model.node_masses();
  const double* pf = model.prescribed_forces();
  const double* fext = state.f_ext.data();
  const Vec3<double> g = model.gravity();
  NodeSums<2> sums(nn);
#pragma omp parallel num_threads(nt)
  {
    system_.MultiplyTeam(b_values_.data(), v, bv_.data());
    sums.Team([&](int32_t n, std::array<double, 2>& acc) {
      for (int d = 0; d < 3; ++d) {
        const int32_t i = 3 * n + d;
        const double load = mass[n] * g(d) + pf[i] + fext[i];
        force_[static_cast<size_t>(i)] = node_force_[static_cast<size_t>(i)] + load;
        if (active[n] == 0) {
          residual[i] = 0;
          continue;
        }
        residual[i] = bv_[static_cast<size_t>(i)] - mass[n] * v0_[static_cast<size_t>(i)] - h * force_[static_cast<size_t>(i)];
        acc[0] += 0.5 * v[i] * bv_[static_cast<size_t>(i)] - mass[n] * v[i] * v0_[static_cast<size_t>(i)];
        acc[1] -= load * h * v[i];
      }
    });
  }
  double w = 0;
  for (int32_t t = 0; t < system_.num_tets(); ++t) w += tet_energy_[static_cast<size_t>(t)];
  if (nodal_pressure_) w += volumetric_energy_;
  e.phi = sums.Total(0) + sums.Total(1) + w + u_pen;
  e.scale = std::abs(sums.Total(0)) + std::abs(sums.Total(1)) + std::abs(w) + std::abs(u_pen);
  double rmax = 0;
  for (int32_t n = 0; n < nn; ++n) {
    rmax = std::max(rmax, Eigen::Map<const Eigen::Vector3d>(residual + 3 * n).norm());
  }
  e.residual = rmax / h;
  e.finite = std::isfinite(e.phi) && std::isfinite(e.residual);
  return e;
}

double ImplicitIntegrator::LoadScale(const Model<double>& model, const State<double>& state,
                                     std::span<const PenaltyTerm> penalties) const {
  double s = 0;
  const Vec3<double> g = model.gravity();
  for (int32_t n = 0; n < system_.num_nodes(); ++n) {
    if (active_[static_cast<size_t>(n)] == 0) continue;
    const Eigen::Vector3d load = model.node_mass(n) * g +
                                 Eigen::Map<const Eigen::Vector3d>(model.prescribed_forces() + 3 * n) +
                                 Eigen::Map<const Eigen::Vector3d>(state.f_ext.data() + 3 * n);
    s = std::max({s, load.norm(), Eigen::Map<const Eigen::Vector3d>(force_.data() + 3 * n).norm()});
  }
  for (const PenaltyTerm& p : penalties) s = std::max(s, p.force.norm());
  return s;
}

/// Backtracking on Φ along dir_ from v_; on success v_, residual_ and the
/// cached evaluation hold the accepted point. Returns false if no step
/// length in max_line_search_steps halvings was acceptable.
bool ImplicitIntegrator::LineSearch(const Model<double>& model, const State<double>& state, double h,
                                    std::span<const PenaltyTerm> penalties, Eval& current,
                                    ImplicitResult& result) {
  const int nt = NumThreads();
  const int32_t nn = system_.num_nodes();
  const double slope = Dot(residual_, dir_, nn, nt);  // ∇Φ·d
  double alpha = 1.0;
  for (int k = 0; k <= options_.max_line_search_steps; ++k, alpha *= 0.5) {
    for (int32_t i = 0; i < 3 * nn; ++i) v_try_[static_cast<size_t>(i)] = v_[static_cast<size_t>(i)] + alpha * dir_[static_cast<size_t>(i)];
    const Eval trial = Evaluate(model, state, h, penalties, v_try_.data(), residual_try_.data());
    if (!trial.finite) continue;
    const bool armijo = trial.phi <= current.phi + kArmijo * alpha * std::min(slope, 0.0) && slope < 0;
    const bool within_round_off = trial.phi <= current.phi + kPhiRoundOff * current.scale &&
                                  trial.residual < current.residual;
    if (armijo || within_round_off) {
      v_.swap(v_try_);
      residual_.swap(residual_try_);
      current = trial;
      result.line_search_halvings += k;
      return true;
    }
  }
  result.line_search_halvings += options_.max_line_search_steps;
  return false;
}

bool ImplicitIntegrator::RequestFactor(const Model<double>& model, ImplicitResult& result) {
  // FactorValues copies A: only when the worker can take it.
  if (solver_.busy() || !solver_.RequestFactor(system_, FactorValues())) return false;
  result.factor_requested = true;
  if (options_.max_correction_rank <= 0) return true;
  Signature& sig = signatures_[solver_.requests() % 2];
  sig.request = solver_.requests();
  sig.tets.resize(static_cast<size_t>(model.num_tets()));
  sig.nodes.resize(4 * static_cast<size_t>(model.num_tets()));
  for (int32_t t = 0; t < model.num_tets(); ++t) {
    sig.tets[static_cast<size_t>(t)] = TetSignature(model, t);
    for (int c = 0; c < 4; ++c) sig.nodes[static_cast<size_t>(4 * t + c)] = model.tet_node(t, c);
  }
  return true;
}

/// The changed nodes are every node, then and now, of a tet whose signature
/// differs from the one recorded with the factor's request (a node a cut
/// took out of a tet lost couplings too); new nodes are the correction's own.
void ImplicitIntegrator::CorrectFactor(const Model<double>& model, ImplicitResult& result) {
  const uint64_t request = solver_.factor_request();
  if (options_.max_correction_rank <= 0 || request == 0 || solver_.factor_dofs() > system_.num_dofs() ||
      (corrected_request_ == request && corrected_pattern_ == system_.pattern_id())) {
    return;
  }
  const Signature& sig = signatures_[request % 2];
  if (sig.request != request) {  // no record of what the factor saw
    corrected_request_ = request;
    corrected_pattern_ = system_.pattern_id();
    return;
  }
  const int32_t old_nodes = solver_.factor_dofs() / 3;
  std::vector<uint8_t> mark(static_cast<size_t>(old_nodes), 0);
  for (int32_t t = 0; t < model.num_tets(); ++t) {
    const bool same = static_cast<size_t>(t) < sig.tets.size() && sig.tets[static_cast<size_t>(t)] == TetSignature(model, t);
    if (same) continue;
    for (int c = 0; c < 4; ++c) {
      for (const int32_t n : {model.tet_node(t, c), static_cast<size_t>(t) < sig.tets.size()
                                                        ? sig.nodes[static_cast<size_t>(4 * t + c)]
                                                        : -1}) {
        if (n >= 0 && n < old_nodes) mark[static_cast<size_t>(n)] = 1;
      }
    }
  }
  changed_nodes_.clear();
  for (int32_t n = 0; n < old_nodes; ++n) {
    if (mark[static_cast<size_t>(n)] != 0) changed_nodes_.push_back(n);
  }
  const CorrectionStart start = solver_.CorrectFactor(system_, FactorValues(), changed_nodes_,
                                                      options_.max_correction_rank, options_.correction_drift);
  // A busy correction thread is asked again at the next solve.
  if (start == CorrectionStart::kBusy) return;
  corrected_request_ = request;
  corrected_pattern_ = system_.pattern_id();
  result.correction_started = start == CorrectionStart::kStarted;
}

/// Direction: PCG on A d = −r; negative curvature switches kAuto to K⁺.
bool ImplicitIntegrator::SolveDirection(double h, double tolerance, int64_t deadline_ns, ImplicitResult& result,
                                        bool* clamped) {
  const int nt = NumThreads();
  const int32_t nn = system_.num_nodes();
  for (int32_t i = 0; i < 3 * nn; ++i) rhs_[static_cast<size_t>(i)] = -residual_[static_cast<size_t>(i)];
  Stopwatch watch;
  solver_.Acquire();
  if (!solver_.has_factor() || solver_.factor_pattern_id() != system_.pattern_id()) {
    RequestFactor(*model_, result);
    if (!solver_.has_factor() && options_.wait_for_first_factor) solver_.WaitForFactor();
    if (solver_.has_factor() && solver_.factor_pattern_id() != system_.pattern_id()) CorrectFactor(*model_, result);
  }
  result.AddPhase(ImplicitPhase::kFactorSetup, watch.ElapsedSeconds());
  watch.Reset();
  const double rhs_norm = std::sqrt(Dot(rhs_, rhs_, nn, nt));
  const double lin_tol = std::max(options_.linear_tolerance * rhs_norm, 0.1 * h * tolerance);
  const PcgResult pr = solver_.Solve(system_, a_values_.data(), active_.data(), rhs_.data(), dir_.data(), lin_tol,
                                     options_.max_pcg_iterations, NumThreads(), extra_, matrix_free(), deadline_ns);
  result.AddPhase(ImplicitPhase::kSolve, watch.ElapsedSeconds());
  result.pcg_iterations += pr.iterations;
  result.max_pcg_iterations = std::max(result.max_pcg_iterations, pr.iterations);
  result.factor_dofs = solver_.factor_dofs();
  // A step whose solves needed many iterations asks for a fresher factor
  // (counted over the step: a solve cut short by the deadline stays short).
  if (result.pcg_iterations > options_.refactor_pcg_iterations) {
    watch.Reset();
    RequestFactor(*model_, result);
    result.AddPhase(ImplicitPhase::kFactorSetup, watch.ElapsedSeconds());
  }
  if (pr.negative_curvature) {
    result.negative_curvature = true;
    if (options_.tangent == TangentMode::kAuto) *clamped = true;
  }
  return pr.out_of_time;
}

/// Sets the start of the step: x0_, v0_ (backward Euler: the state; BDF2:
/// (4·xₙ − xₙ₋₁)/3 and (4·vₙ − vₙ₋₁)/3), the initial guess v_ = vₙ, and the
/// history for the next BDF2 step. Returns the effective step: h, or 2h/3
/// for BDF2, which then is backward Euler from (x0_, v0_).
double ImplicitIntegrator::StartStep(const State<double>& state, double step_size, bool pattern_rebuilt) {
  const int32_t nd = system_.num_dofs();
  const bool bdf2 = options_.bdf2 && !pattern_rebuilt && history_step_ == state.step &&
                    history_h_ == step_size && static_cast<int32_t>(x_prev_.size()) == nd;
  for (int32_t i = 0; i < nd; ++i) {
    const auto s = static_cast<size_t>(i);
    x0_[s] = bdf2 ? (4.0 * state.x[s] - x_prev_[s]) / 3.0 : state.x[s];
    v0_[s] = bdf2 ? (4.0 * state.v[s] - v_prev_[s]) / 3.0 : state.v[s];
    v_[s] = active_[s / 3] != 0 ? state.v[s] : 0.0;
  }
  if (options_.bdf2) {
    x_prev_.assign(state.x.begin(), state.x.begin() + nd);
    v_prev_.assign(state.v.begin(), state.v.begin() + nd);
    history_step_ = state.step + 1;
    history_h_ = step_size;
  }
  return bdf2 ? 2.0 * step_size / 3.0 : step_size;
}

ImplicitResult ImplicitIntegrator::Step(const Model<double>& model, State<double>& state, double step_size,
                                        std::span<const PenaltyTerm> penalties, int64_t deadline_ns) {
  ImplicitResult result;
  if (!(step_size > 0) || !std::isfinite(step_size)) {
    result.status = ImplicitStatus::kNonFinite;
    return result;
  }
  Stopwatch watch;
  // Past hard_ns (0: none) the step stops whatever its residual.
  int64_t hard_ns = 0;
  if (deadline_ns > 0 && std::isfinite(options_.overrun_limit)) {
    const int64_t budget = std::max<int64_t>(0, deadline_ns - MonotonicNs());
    hard_ns = deadline_ns + static_cast<int64_t>(std::max(0.0, options_.overrun_limit) * static_cast<double>(budget));
  }
  Prepare(model, result);
  const int32_t nn = system_.num_nodes();
  const double h = StartStep(state, step_size, result.pattern_rebuilt);
  result.bdf2 = h != step_size;
  // M + h(C + αM): C depends on the state; without strain-rate damping the
  // values stay those of the last step while h, the pattern and the active
  // set do.
  if (model.damped() || b_values_h_ != h || !b_values_valid_) {
    DampingPass(model, x0_.data(), h, 1.0 + h * options_.mass_damping, true, b_values_.data());
    b_values_h_ = h;
    b_values_valid_ = true;
  }
  result.AddPhase(ImplicitPhase::kSetup, watch.ElapsedSeconds());
  watch.Reset();
  Eval current = Evaluate(model, state, h, penalties, v_.data(), residual_.data());
  if (!current.finite) {
    // The guess x + h·v (the velocity held over the step) can invert a
    // nodal patch after a cut or a fast stroke, where Φ is +∞; the state
    // itself, v⁺ = 0, is a finite start.
    std::fill(v_.begin(), v_.end(), 0.0);
    current = Evaluate(model, state, h, penalties, v_.data(), residual_.data());
    result.restarted_at_rest = true;
  }
  result.AddPhase(ImplicitPhase::kEvaluate, watch.ElapsedSeconds());
  result.tolerance = options_.force_tolerance > 0
                         ? options_.force_tolerance
                         : options_.relative_force_tolerance * LoadScale(model, state, penalties);
  bool clamped = options_.tangent == TangentMode::kClamped;
  k_fresh_ = false;
  bool x_stale = false;  // x_ and force_ hold a rejected trial, not v_
  for (int it = 0;; ++it) {
    result.residual = current.residual;
    if (it < ImplicitResult::kHistory) result.residual_history[static_cast<size_t>(it)] = current.residual;
    if (!current.finite) {
      result.status = ImplicitStatus::kNonFinite;
      return result;
    }
    if (current.residual <= result.tolerance) break;
    const int64_t now = it > 0 && deadline_ns > 0 ? MonotonicNs() : 0;
    const bool late = now > 0 && now >= deadline_ns;
    const bool above_limit = current.residual > options_.carry_limit * result.tolerance;
    const bool out_of_time = late && (!above_limit || (hard_ns > 0 && now >= hard_ns));
    result.over_budget = result.over_budget || (late && above_limit);
    if (out_of_time || it >= options_.max_newton_iterations) {
      result.status = out_of_time ? ImplicitStatus::kOutOfTime : ImplicitStatus::kCapped;
      watch.Reset();
      if (x_stale) current = Evaluate(model, state, h, penalties, v_.data(), residual_.data());
      result.AddPhase(ImplicitPhase::kEvaluate, watch.ElapsedSeconds());
      result.residual = current.residual;
      break;
    }
    result.newton_iterations = it + 1;
    const bool assemble = !have_k_ || reassemble_k_ || k_clamped_ != clamped ||
                          options_.tangent_reuse_contraction <= 0;
    watch.Reset();
    AssembleJacobian(model, h, penalties, clamped, assemble);
    result.AddPhase(ImplicitPhase::kAssemble, watch.ElapsedSeconds());
    result.tangent_assemblies += assemble ? 1 : 0;
    k_fresh_ = k_fresh_ || assemble;
    const bool was_clamped = clamped;
    const double last_residual = current.residual;
    const bool truncated =
        SolveDirection(h, result.tolerance, result.over_budget ? hard_ns : deadline_ns, result, &clamped);
    result.clamped = result.clamped || was_clamped;
    watch.Reset();
    const bool accepted = LineSearch(model, state, h, penalties, current, result);
    result.AddPhase(ImplicitPhase::kEvaluate, watch.ElapsedSeconds());
    // A solve cut short by the deadline says nothing about the tangent.
    reassemble_k_ = !accepted ||
                    (!truncated && !(current.residual <= options_.tangent_reuse_contraction * last_residual));
    x_stale = !accepted;
    if (!accepted) {
      if (clamped != was_clamped) continue;  // retry the iteration with K⁺
      if (!assemble) continue;                // retry with K assembled here
      // No acceptable step: the state gets the last accepted iterate.
      watch.Reset();
      current = Evaluate(model, state, h, penalties, v_.data(), residual_.data());
      result.AddPhase(ImplicitPhase::kEvaluate, watch.ElapsedSeconds());
      result.residual = current.residual;
      result.status = ImplicitStatus::kCapped;
      break;
    }
  }
  for (int32_t i = 0; i < 3 * nn; ++i) {
    const auto s = static_cast<size_t>(i);
    if (active_[s / 3] != 0) {
      state.x[s] = x_[s];
      state.v[s] = v_[s];
    }
    state.f[s] = force_[s];
  }
  state.time += step_size;
  ++state.step;
  last_h_ = h;
  last_clamped_ = clamped;
  last_penalties_.assign(penalties.begin(), penalties.end());
  return result;
}

bool ImplicitIntegrator::FactorIsCurrent() {
  solver_.Acquire();
  return solver_.has_factor() && solver_.factor_pattern_id() == system_.pattern_id();
}

Eigen::Matrix3d ImplicitIntegrator::EffectiveStiffness(const Model<double>& model, std::span<const int32_t> nodes,
                                                       std::span<const double> weights) {
  if (!(last_h_ > 0) || system_.Stale(model)) return Eigen::Matrix3d::Zero();
  const int32_t nn = system_.num_nodes();
  const bool any_free = std::any_of(nodes.begin(), nodes.end(), [&](int32_t n) {
    return n >= 0 && n < nn && active_[static_cast<size_t>(n)] != 0;
  });
  if (!any_free) return Eigen::Matrix3d::Zero();  // no tangent to assemble for a point off the tissue
  if (!k_fresh_) {
    // x_ holds the last step's solution (its last evaluation).
    AssembleJacobian(model, last_h_, last_penalties_, last_clamped_, true);
    k_fresh_ = true;
    reassemble_k_ = false;
  }
  // W (#N×3·3): column c holds the weights on DOF c of the point's nodes.
  // The compliance Wᵀ A⁻¹ W is the Galerkin one on the block Krylov space
  // V = [P⁻¹W, P⁻¹R₀, P⁻¹R₁] of the preconditioner in use (block PCG's
  // space): C_b = (VᵀW)ᵀ(VᵀAV)⁻¹(VᵀW) on the first b + 1 blocks, with
  // Galerkin residual R_b = W − AV·Y. Its error is WᵀA⁻¹W − C_b = R_bᵀA⁻¹R_b
  // (positive semidefinite: C_b approaches the compliance from below), so
  // tr(R_bᵀP⁻¹R_b)/tr(C_b) estimates its relative error; P⁻¹R_b is the next
  // block, and the estimate that the error of C_b is within
  // kComplianceError accepts C_{b+1}, which is better. One block is exact
  // when P = A.
  const int nt = NumThreads();
  const auto nd = static_cast<size_t>(3 * nn);
  auto column = [&](std::vector<double>& v, int c) { return v.data() + static_cast<size_t>(c) * nd; };
  auto set_weights = [&](int c) {
    double* r = column(compliance_r_, c);
    std::fill(r, r + nd, 0.0);
    for (size_t i = 0; i < nodes.size(); ++i) {
      const int32_t n = nodes[i];
      if (n < 0 || n >= nn || active_[static_cast<size_t>(n)] == 0) continue;
      r[3 * n + c] += weights[i];
    }
  };
  for (int c = 0; c < 3; ++c) set_weights(c);
  // Fixed-capacity matrices: the frame thread allocates nothing here.
  using Small = Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, 0, 3 * kComplianceBlocks, 3 * kComplianceBlocks>;
  using Thin = Eigen::Matrix<double, Eigen::Dynamic, 3, 0, 3 * kComplianceBlocks, 3>;
  Small vav = Small::Zero(3 * kComplianceBlocks, 3 * kComplianceBlocks);  // VᵀAV
  Thin vw = Thin::Zero(3 * kComplianceBlocks, 3);                          // VᵀW
  Eigen::Matrix3d compliance = Eigen::Matrix3d::Zero();
  for (int block = 0; block < kComplianceBlocks; ++block) {
    const int k0 = 3 * block, k = k0 + 3;
    double error = 0;  // tr(R_{b−1}ᵀ P⁻¹ R_{b−1})
    for (int c = 0; c < 3; ++c) {
      std::copy(column(compliance_r_, c), column(compliance_r_, c) + nd, rhs_.begin());
      solver_.Precondition(system_, a_values_.data(), active_.data(), rhs_.data(), column(compliance_z_, k0 + c), nt);
      ApplyTissueJacobian(column(compliance_z_, k0 + c), column(compliance_q_, k0 + c));
      if (block > 0) {
        error += Dot(compliance_r_, compliance_z_, static_cast<size_t>(c) * nd, static_cast<size_t>(k0 + c) * nd,
                     nn, nt);
      }
    }
    const bool converged = block > 0 && error <= kComplianceError * compliance.trace();
    for (int a = k0; a < k; ++a) {
      for (int b = 0; b <= a; ++b) {
        vav(a, b) = vav(b, a) =
            Dot(compliance_z_, compliance_q_, static_cast<size_t>(a) * nd, static_cast<size_t>(b) * nd, nn, nt);
      }
      for (int c = 0; c < 3; ++c) {
        double sum = 0;
        for (size_t i = 0; i < nodes.size(); ++i) {
          const int32_t n = nodes[i];
          if (n < 0 || n >= nn || active_[static_cast<size_t>(n)] == 0) continue;
          sum += weights[i] * column(compliance_z_, a)[3 * n + c];
        }
        vw(a, c) = sum;
      }
    }
    const Eigen::LLT<Small> llt(vav.topLeftCorner(k, k));
    if (llt.info() != Eigen::Success) return Eigen::Matrix3d::Zero();  // V lost rank or A is indefinite on it
    const Thin y = llt.solve(vw.topRows(k));  // k×3
    compliance = vw.topRows(k).transpose() * y;
    if (converged) break;
    if (block + 1 == kComplianceBlocks) return Eigen::Matrix3d::Zero();
    // R_b = W − AV·Y, column by column.
    for (int c = 0; c < 3; ++c) {
      set_weights(c);
      double* r = column(compliance_r_, c);
      for (int a = 0; a < k; ++a) {
        const double ya = y(a, c);
        const double* q = column(compliance_q_, a);
        for (size_t i = 0; i < nd; ++i) r[i] -= ya * q[i];
      }
    }
  }
  compliance *= last_h_ * last_h_;
  const Eigen::Matrix3d sym = 0.5 * (compliance + compliance.transpose());
  const Eigen::Matrix3d stiffness = sym.inverse();
  return stiffness.allFinite() ? stiffness : Eigen::Matrix3d::Zero();
}

void ImplicitIntegrator::ApplyJacobian(const double* p, double* q) const {
  const int32_t nn = system_.num_nodes();
#pragma omp parallel num_threads(NumThreads())
  system_.MultiplyTeam(a_values_.data(), p, q);
  if (const MatrixFreeTerm* term = matrix_free()) term->AddProduct(p, q);
  for (const ExtraBlock& e : extra_) {
    Eigen::Map<Eigen::Vector3d>(q + 3 * e.a) += e.k * Eigen::Map<const Eigen::Vector3d>(p + 3 * e.b);
    if (e.a != e.b) {
      Eigen::Map<Eigen::Vector3d>(q + 3 * e.b) += e.k.transpose() * Eigen::Map<const Eigen::Vector3d>(p + 3 * e.a);
    }
  }
  for (int32_t n = 0; n < nn; ++n) {
    if (active_[static_cast<size_t>(n)] == 0) q[3 * n] = q[3 * n + 1] = q[3 * n + 2] = 0.0;
  }
}

void ImplicitIntegrator::ApplyTissueJacobian(const double* p, double* q) const {
  ApplyJacobian(p, q);
  // Less the penalty springs in it, h²·W·k·Wᵀ (in the pattern or in
  // extra_), on the active nodes.
  const double h2 = patch_scale_;
  for (const PenaltyTerm& t : jacobian_penalties_) {
    const Eigen::Matrix3d ks = 0.5 * (t.stiffness + t.stiffness.transpose());
    Eigen::Vector3d point = Eigen::Vector3d::Zero();
    for (int i = 0; i < 3; ++i) {
      const int32_t n = t.nodes[static_cast<size_t>(i)];
      if (n >= 0 && active_[static_cast<size_t>(n)] != 0) point += t.weights[static_cast<size_t>(i)] * Eigen::Map<const Eigen::Vector3d>(p + 3 * n);
    }
    const Eigen::Vector3d f = h2 * (ks * point);
    for (int i = 0; i < 3; ++i) {
      const int32_t n = t.nodes[static_cast<size_t>(i)];
      if (n >= 0 && active_[static_cast<size_t>(n)] != 0) Eigen::Map<Eigen::Vector3d>(q + 3 * n) -= t.weights[static_cast<size_t>(i)] * f;
    }
  }
}

void ImplicitIntegrator::Prime(const Model<double>& model, const State<double>& state, double step_size) {
  if (!(step_size > 0) || !std::isfinite(step_size)) return;
  ImplicitResult unused;
  Prepare(model, unused);
  const double h = step_size;
  const int32_t nd = system_.num_dofs();
  for (int32_t i = 0; i < nd; ++i) {
    x0_[static_cast<size_t>(i)] = state.x[static_cast<size_t>(i)];
    v_[static_cast<size_t>(i)] = 0.0;
  }
  DampingPass(model, x0_.data(), h, 1.0 + h * options_.mass_damping, true, b_values_.data());
  b_values_h_ = h;
  b_values_valid_ = true;
  AssembleJacobian(model, h, {}, options_.tangent == TangentMode::kClamped, true);
  RequestFactor(model, unused);
  solver_.WaitForFactor();
}

void ImplicitIntegrator::AssembleStiffness(const Model<double>& model, const double* x, bool clamped,
                                           std::vector<double>& values) {
  ImplicitResult unused;
  Prepare(model, unused);
  values.assign(static_cast<size_t>(system_.nnz()), 0.0);
  ElementPass(model, x, 1.0, clamped, false, values.data());
}

void ImplicitIntegrator::AssembleDamping(const Model<double>& model, const double* x,
                                         std::vector<double>& values) {
  ImplicitResult unused;
  Prepare(model, unused);
  values.assign(static_cast<size_t>(system_.nnz()), 0.0);
  DampingPass(model, x, 1.0, options_.mass_damping, false, values.data());
}

void ImplicitIntegrator::InternalForce(const Model<double>& model, const double* x, double* out) {
  ImplicitResult unused;
  Prepare(model, unused);
  ElementPass(model, x, 0, false, false, nullptr);
  std::copy(node_force_.begin(), node_force_.end(), out);
}

}  // namespace cutsim::fem
