#pragma once
/// @file
/// SI units. Every quantity in cutsim is stored in SI (m, kg, s, N, Pa); these
/// helpers make literals in code and tests say what they are, and convert the
/// two elastic parameterisations used by scenes.

namespace cutsim::units {

inline constexpr double kMillimetre = 1e-3;  // m
inline constexpr double kCentimetre = 1e-2;  // m
inline constexpr double kGram = 1e-3;        // kg
inline constexpr double kKiloPascal = 1e3;   // Pa
inline constexpr double kMegaPascal = 1e6;   // Pa
inline constexpr double kMillisecond = 1e-3;  // s
inline constexpr double kMicrosecond = 1e-6;  // s
inline constexpr double kStandardGravity = 9.80665;  // m/s²

/// Lamé parameters (λ, μ) in Pa.
struct Lame {
  double lambda;  ///< First Lamé parameter λ, Pa.
  double mu;      ///< Shear modulus μ, Pa.
};

/// (E, ν) → (λ, μ). Requires E > 0 and −1 < ν < 0.5.
constexpr Lame LameFromYoungPoisson(double youngs_modulus, double poisson_ratio) {
  const double nu = poisson_ratio;
  return {youngs_modulus * nu / ((1.0 + nu) * (1.0 - 2.0 * nu)),
          youngs_modulus / (2.0 * (1.0 + nu))};
}

/// Young's modulus E = μ(3λ + 2μ)/(λ + μ), Pa.
constexpr double YoungFromLame(Lame lame) {
  return lame.mu * (3.0 * lame.lambda + 2.0 * lame.mu) / (lame.lambda + lame.mu);
}

/// Poisson's ratio ν = λ / (2(λ + μ)).
constexpr double PoissonFromLame(Lame lame) {
  return lame.lambda / (2.0 * (lame.lambda + lame.mu));
}

}  // namespace cutsim::units
