#pragma once
/// @file
/// The element part of the implicit step's tangent applied without
/// assembling it. Linearize records, per element, the deformation gradient
/// F and the second Piola stress S (S⁺ when clamped, tangent.h) at a state;
/// AddProduct then forms, element by element, the directional derivative of
/// the force kernel:
///
///   dF = Σ_a p_a g_aᵀ,   dE = sym(Fᵀ dF),   dS = λ tr(dE) I + 2μ dE,
///   dP = dF·S + F·dS,    q_a += V·dP·g_a            (K·p = −Df[p]),
///
/// and, for the nodal-pressure element, the element-local volumetric term
/// p̄_e·∂²v_e/∂x² · p = p̄_e·V·Dcof(F)[dF]·g_a (nodal_pressure.h). The
/// patch term Σ_a c_a ∇v_a ∇v_aᵀ is already matrix-free (the integrator's
/// PatchTerm). The result equals the product with ImplicitIntegrator's
/// assembled stiffness (tests/unit/fem/tangent_product_test.cc) and reads
/// 19 numbers per element instead of the tangent's ~20 nonzeros per DOF.

#include <cstdint>
#include <vector>

#include "common/fem/model.h"
#include "common/fem/sparse_system.h"

namespace cutsim::fem {

class TangentProduct {
 public:
  /// Records F, S (S⁺ when `clamped`) and, for a nodal-pressure model
  /// without clamping, the element pressures p̄_e at positions `x` (#N×3).
  /// `system` supplies the element colouring that makes the threaded
  /// scatter collision-free; it must match `model`.
  void Linearize(const Model<double>& model, const SparseSystem& system, const double* x, bool clamped,
                 int num_threads);

  /// q += scale·K·p (#N×3), K the element tangent recorded by Linearize.
  /// Pairs with a node whose `active` flag is 0 are left out, as the
  /// assembled matrix leaves them (`active` may be null: every node).
  /// Opens its own OpenMP team; deterministic for any thread count.
  void AddProduct(const double* p, double scale, const uint8_t* active, double* q) const;

  [[nodiscard]] bool linearized() const { return model_ != nullptr; }

 private:
  const Model<double>* model_ = nullptr;
  const SparseSystem* system_ = nullptr;
  int num_threads_ = 1;
  std::vector<double> f_;      // #T×9, column-major F
  std::vector<double> s_;      // #T×9, column-major S or S⁺
  std::vector<double> p_bar_;  // #T, Pa (0: no volumetric term)
  std::vector<double> node_volume_;  // #N, m³ (scratch of the nodal pressures)
};

}  // namespace cutsim::fem
