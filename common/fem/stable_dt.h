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

/// The element that currently limits the step, or −1.
template <typename T>
int32_t StableStepLimitingElement(const State<T>& state);

}  // namespace cutsim::fem
