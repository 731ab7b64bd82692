#pragma once
/// @file
/// What the fem tests' energy checks share: the paper's damped tissue and
/// the total mechanical energy of a state.

#include "common/fem/forces.h"
#include "common/fem/model.h"
#include "common/fem/state.h"

namespace cutsim::fem::testing {

/// The paper's tissue (λ = 140 kPa, μ = 11 kPa) with its viscous damping.
inline const Material kPaperTissueDamped{.lambda = 140000, .mu = 11000, .psi = 10, .phi = 80, .density = 1000};

/// Strain + kinetic + gravitational potential energy, J.
inline double TotalEnergy(const Model<double>& m, const State<double>& s) {
  return StrainEnergy(m, s.x.data()) + KineticEnergy(m, s.v.data()) + GravityPotential(m, s.x.data());
}

}  // namespace cutsim::fem::testing
