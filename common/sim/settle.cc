#include "common/sim/settle.h"

#include <algorithm>
#include <cmath>
#include <vector>

#include <Eigen/Core>

#include "common/fem/forces.h"

namespace cutsim::sim {

namespace {

/// Step of the settling solve, s: long enough that M/h² and (C + αM)/h are
/// negligible next to the stiffness of any tissue (E ≥ 1 Pa).
constexpr double kSettleStep = 1e3;
/// Long steps before giving up; each is a converged Newton solve, and the
/// second one normally starts converged.
constexpr int kMaxSettleSteps = 8;

/// The force tolerance when the scene sets none: the implicit step's
/// relative tolerance times the largest free-node net force at the start
/// (weight, loads and the elastic forces of the prescribed displacements).
/// Fixed for the whole solve: relative to the current residual it would
/// shrink with it and no step would ever start converged.
double StartTolerance(const fem::Model<double>& model, fem::State<double>& state,
                      const fem::ImplicitOptions& options) {
  std::vector<double> f(state.x.size(), 0.0);
  (void)fem::ComputeInternalForces(model, state, fem::ForceMode::kElastic, f.data(), options.num_threads);
  const Eigen::Vector3d g = model.gravity();
  double scale = 0;
  for (int32_t n = 0; n < model.num_nodes(); ++n) {
    if (model.fixed(n)) continue;
    const Eigen::Vector3d net = Eigen::Map<const Eigen::Vector3d>(f.data() + 3 * n) + model.node_mass(n) * g +
                                Eigen::Map<const Eigen::Vector3d>(model.prescribed_forces() + 3 * n);
    if (std::isfinite(net.norm())) scale = std::max(scale, net.norm());
  }
  return scale > 0 ? options.relative_force_tolerance * scale : 0.0;
}

}  // namespace

SettleResult Settle(const fem::Model<double>& model, fem::State<double>& state, fem::ImplicitOptions options) {
  SettleResult out;
  options.asynchronous_factorization = false;
  options.bdf2 = false;
  options.max_newton_iterations = std::max(options.max_newton_iterations, 50);
  const std::vector<double> x_start = state.x;
  if (!(options.force_tolerance > 0)) options.force_tolerance = StartTolerance(model, state, options);
  fem::ImplicitIntegrator solver(options);
  for (int k = 0; k < kMaxSettleSteps; ++k) {
    // From rest each time: a step's start velocity would extrapolate the
    // last step's whole displacement into the next guess.
    std::fill(state.v.begin(), state.v.end(), 0.0);
    const fem::ImplicitResult r = solver.Step(model, state, kSettleStep);
    ++out.steps;
    out.newton_iterations += r.newton_iterations;
    out.pcg_iterations += r.pcg_iterations;
    out.tolerance = r.tolerance;
    if (r.status == fem::ImplicitStatus::kNonFinite) break;
    if (r.ok() && r.newton_iterations == 0) {
      out.converged = true;
      break;
    }
  }
  std::fill(state.v.begin(), state.v.end(), 0.0);
  state.time = 0;
  state.step = 0;
  for (int32_t n = 0; n < model.num_nodes(); ++n) {
    const Eigen::Map<const Eigen::Vector3d> f(state.f.data() + 3 * n);
    if (!model.fixed(n)) out.residual = std::max(out.residual, f.norm());
    const Eigen::Map<const Eigen::Vector3d> x(state.x.data() + 3 * n);
    const Eigen::Map<const Eigen::Vector3d> x0(x_start.data() + 3 * n);
    out.max_displacement = std::max(out.max_displacement, (x - x0).norm());
  }
  return out;
}

}  // namespace cutsim::sim
