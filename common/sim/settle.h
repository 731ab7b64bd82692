#pragma once
/// @file
/// Settle: the load-time stage that brings the tissue to its static
/// equilibrium under gravity and the boundary forces, with the fixed nodes
/// and the prescribed displacements (at their t = 0 values) held where
/// they are (scene `settle`), so a
/// session starts from tissue resting in its loaded shape rather than from
/// the meshed shape released at t = 0.
///
/// The static problem min W(x) − f_load·x is solved as backward Euler steps
/// of a step far longer than any time scale of the tissue (kSettleStep): the
/// inertial and damping terms of the incremental potential vanish with 1/h,
/// and what is left is Newton with line search on the static potential,
/// with the implicit step's force tolerance. Velocities are then zero and
/// the clock reads 0.

#include <cstdint>

#include "common/fem/implicit.h"
#include "common/fem/model.h"
#include "common/fem/state.h"

namespace cutsim::sim {

struct SettleResult {
  bool converged = false;
  int steps = 0;              ///< Long backward Euler steps taken.
  int newton_iterations = 0;  ///< Summed over the steps.
  int pcg_iterations = 0;
  double residual = 0;         ///< Largest free-node net force at the end, N.
  double tolerance = 0;        ///< The force tolerance used, N.
  double max_displacement = 0; ///< Largest node displacement from the start, m.
};

/// Settles `state` (positions move, velocities become zero, time and step
/// counters are reset). `options` are the implicit step's (tolerances,
/// threads); the solve uses its own workspace and inline factorisations.
/// Never throws; on non-convergence the state holds the last iterate.
SettleResult Settle(const fem::Model<double>& model, fem::State<double>& state, fem::ImplicitOptions options);

}  // namespace cutsim::sim
