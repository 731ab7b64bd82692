#pragma once
/// @file
/// Scene parameters of the cut algorithm (method paper §3), mapped by the sim layer
/// from the scene file, and their validation.

#include <cstdint>

#include "common/core/error.h"

namespace cutsim::cutting {

struct CutParams {
  /// Neighbourhood size factor of eq. (4): r = α·d_v, dimensionless.
  double alpha = 0.5;
  /// Tool sharpness κ of eqs. (6)–(8): the stress is scaled by 1/κ, dimensionless.
  double kappa = 1.0;
  /// Damage factor ζ ∈ (0, 1] of eq. (10), dimensionless.
  double zeta = 1.0;
  /// Critical stress K_I of eq. (11), Pa (the method paper calls it toughness but
  /// compares it with a stress).
  double critical_stress = 1.0e4;
  /// Smallest mean-ratio quality a remeshing move may leave in a touched
  /// tet (rest and world), dimensionless in (0, 1).
  double min_quality = 0.05;
  /// t0 also resets after this many consecutive frames in which the closest
  /// vertex differs from v_c(t0) but C_p stays outside the neighbourhood
  /// (the tool wandered off without cutting). 0 disables this reset.
  int32_t t0_timeout_frames = 60;
  /// Half-width of the blade's swept slab around the cut plane, as a
  /// fraction of the local mean edge length ("half an element").
  double band_fraction = 0.5;
  /// Sliver guard of the remeshing moves: a move must also keep every
  /// touched tet (rest and world) at mean-ratio quality ≥ min(keep_quality,
  /// its quality before), dimensionless in [0, 1). min_quality alone lets
  /// repeated moves in one region grind elements down to it (see cut_stepper.h).
  double keep_quality = 0.4;
  /// Remeshing moves are halved at most this many times before being skipped.
  int32_t max_move_halvings = 8;
  /// Cap on vertex copies one cut step may create (singularity removal
  /// included); a step needing more is rejected and rolled back.
  int32_t max_splits_per_step = 4096;
  /// Fragment guard: a step must not cut loose a piece of fewer tets than
  /// this (discretisation debris, see cut_stepper.h); 0 disables the guard. It
  /// is also off on meshes of fewer than 4× this many tets.
  int32_t min_fragment_tets = 8;
};

/// Throws `InputError` naming `source` and the offending field (e.g.
/// "cutting.alpha") if a parameter is out of range or not finite.
void ValidateCutParams(const CutParams& params, const SourceRef& source);

}  // namespace cutsim::cutting
