#pragma once
/// @file
/// Stable explicit time step of symplectic Euler for the StVK + strain-rate
/// damping model.
///
/// Derivation (per element e, lumped node mass m = ρ·vol₀/4, frozen):
///  * Element eigenvalue inequality: for the assembled system,
///    λ_max(M⁻¹K) ≤ max_e λ_max(M_e⁻¹K_e) because uᵀKu/uᵀMu is a ratio of
///    sums of element terms (M = Σ M_e exactly, since node masses are sums of
///    the elements' quarters). Same for the damping matrix C.
///  * Tangent bound: with dF = Σᵢ uᵢgᵢᵀ (gᵢ rows of G = [−1ᵀDm⁻¹; Dm⁻¹]),
///    |dF|² ≤ λ_max(GᵀG)|u|². For StVK, dF:∂P/∂F:dF = dF:(dF S) + dE:ℂ:dE
///    ≤ (max(0, λ_max(S)) + max(3λ+2μ, 2μ)·σ_max(F)²)|dF|², dE = sym(FᵀdF).
///    So ω_e² ≤ vol·k·λ_max(GᵀG)/m: the current deformation enters through
///    S and σ_max(F)² (StVK stiffens under stretch). λ_max(S) and σ_max(F)² =
///    λ_max(FᵀF) are bounded by Gershgorin (exact at rest and for pure
///    stretch).
///  * Damping: Ḟ:∂P_visc/∂Ḟ:Ḟ = φ tr(Ė)² + 2ψ|Ė|² ≤ (3φ+2ψ)σ_max(F)²|Ḟ|², so
///    the modal damping rate c_e ≤ vol·(3φ+2ψ)·σ_max(F)²·λ_max(GᵀG)/m.
///  * Symplectic Euler on ẍ + cẋ + ω²x = 0 has the amplification polynomial
///    z² − (2 − hc − h²ω²)z + (1 − hc); Jury's conditions give stability iff
///    h²ω² + 2hc ≤ 4, i.e. h ≤ 4/(c + √(c² + 4ω²)): 2/ω undamped, 2/c when
///    damping dominates. Since c ∝ (3φ+2ψ)/(ρh²), the viscous limit shrinks
///    with the element size squared: λ_max(GᵀG) ~ a/h_e² and m ~ ρ·vol/4 give
///    dt_visc ≈ 2/c = ρ·h_e²/(2a·(3φ+2ψ)σ_max²) (a ≈ 4–8 for good tets).
/// The bound is an upper bound of the true global eigenvalues, so the
/// resulting step is conservative; the tests measure by how much.
///
/// Global (Lanczos) estimate — how far the bound is from the truth:
///  * The per-element bound loses twice: max_e λ(M_e⁻¹K_e) uses the element's
///    quarter masses while a node's lumped mass collects the quarters of all
///    its ~20 elements, and Gershgorin/|dF|² inequalities are not tight.
///    Measured: the true limit 2/ω_max of the assembled M⁻¹K is 1.6–2.0× the
///    bound (box 2.0×, organ after cleanup 1.9×, tests below).
///  * EstimateStableStep runs k Lanczos steps (k = 30 by default) on the
///    symmetric A = M^-½ K M^-½ over the free DOFs, K·z by a one-sided finite
///    difference of the real internal force (so it sees the current
///    deformation, the ITF branch and fixed nodes), and C·z (damping) exactly
///    (linear in v). The largest Ritz value of the tridiagonal Lanczos matrix
///    (Sturm bisection) is a lower bound of λ_max that converges from below
///    much faster than power iteration (Kaniel–Paige); measured against the
///    exact eigenvalue of small meshes it is within 1–3% after 30 steps.
///    Damping and stiffness use h ≤ 4/(c + √(c² + 4ω²)) with the two maxima
///    (possibly from different modes: conservative).
///  * The estimate costs ~k force evaluations, so it is refreshed rarely
///    (StepOptions::spectral_refresh_interval) and stored as the ratio
///    r = dt_Lanczos / dt_bound (clamped to [1, kMaxSpectralRatio]). In
///    between, the per-element bound (cheap, refreshed every few steps)
///    tracks stiffening under deformation and the step is
///    safety · r · dt_bound. A failed estimate (non-finite) falls back to
///    r = 1, the provably safe bound.
///  * Safety factor 0.85 (StepOptions): covers the Lanczos under-estimate
///    (≤ 3% measured, i.e. ≤ 1.5% in dt), the drift of r between refreshes,
///    and the nonlinearity (symplectic Euler's linear limit is exact only for
///    the tangent). The stress tests (dynamics_test: stretch ×3, compression
///    to ~10% volume, random deformations, thousands of steps) run at 1.0 of
///    the Lanczos limit without blow-up and at 0.85 with bounded energy.

#include <cstdint>
#include <span>

#include "common/fem/model.h"
#include "common/fem/state.h"

namespace cutsim::fem {

/// Unscaled stable step of tet t at positions x, s (∞ for inert elements).
/// `explicit_viscous`: include the viscous limit (false when the viscous
/// term is integrated implicitly).
template <typename T>
T ElementStableStep(const Model<T>& model, const T* x, int32_t t, bool explicit_viscous);

/// Recomputes every element's limit from state.x and rebuilds the min tree.
template <typename T>
void RefreshStableStep(const Model<T>& model, State<T>& state, bool explicit_viscous,
                       int num_threads = 0);

/// Recomputes the limits of `tets` only (after a cut), O(k log T).
template <typename T>
void UpdateStableStep(const Model<T>& model, State<T>& state, std::span<const int32_t> tets,
                      bool explicit_viscous);

/// The global unscaled bound min_e dt_e, s (O(1): the min tree's root).
template <typename T>
T StableStepBound(const State<T>& state) {
  return state.dt_tree[1];
}

/// Upper clamp of the Lanczos/bound ratio (the bound is never trusted to be
/// more than this far from the truth; measured ratios are 1.6–2.0).
inline constexpr double kMaxSpectralRatio = 2.0;

/// A global estimate of the stable step (see the file comment).
struct SpectralEstimate {
  double omega2_max = 0;   ///< λ_max(M⁻¹K) (Ritz value, from below), 1/s².
  double damping_max = 0;  ///< λ_max(M⁻¹C), 1/s (0 unless explicit viscous).
  double dt = 0;           ///< 4/(c + √(c² + 4ω²)), unscaled, s (∞: nothing moves).
  int iterations = 0;      ///< Operator applications (force evaluations).
};

/// Lanczos estimate of the true stable step at state.x. Uses the state's
/// lanczos_* and element_force scratch; allocation-free. `iterations` ≤ 128.
template <typename T>
SpectralEstimate EstimateStableStep(const Model<T>& model, State<T>& state, bool explicit_viscous,
                                    int iterations = 30, int num_threads = 0);

/// Refreshes the per-element bound and the ratio state.dt_ratio =
/// clamp(Lanczos dt / bound, 1, kMaxSpectralRatio).
template <typename T>
void RefreshSpectralRatio(const Model<T>& model, State<T>& state, bool explicit_viscous,
                          int iterations = 30, int num_threads = 0);

/// The current estimate of the true limit: bound × ratio (unscaled), s.
template <typename T>
double EffectiveStableStep(const State<T>& state) {
  return static_cast<double>(state.dt_tree[1]) * state.dt_ratio;
}

/// The element that currently limits the step, or −1.
template <typename T>
int32_t StableStepLimitingElement(const State<T>& state);

}  // namespace cutsim::fem
