#pragma once
/// @file
/// A low-rank correction that lets the factor of a matrix before a cut
/// precondition the matrix after it (the augmented-matrix / Woodbury idea
/// of cutting with a fixed factor, Yeung, Crouch & Pothen, ACM TOG 2016).
///
/// A0 (n0 DOFs) is factored, P·A0·Pᵀ = L·Lᵀ. A cut appends DOFs (n ≥ n0,
/// the old ones a prefix) and changes the elements around it, so the new
/// matrix B differs from P0 = blockdiag(A0, D), D the 3×3 diagonal blocks
/// of B on the new DOFs, on a set J of DOFs: the old DOFs Jo of every node
/// of a changed element and all new DOFs N (a new node belongs only to
/// changed elements). The corrected matrix
///
///   T = P0 + E_J Δ E_Jᵀ,  Δ = B[J,J] − P0[J,J]   (k×k, k = |J|)
///
/// equals B on J×J and P0 elsewhere; the couplings between J and the rest
/// come from unchanged elements and match up to the factor's own age. By
/// Woodbury, with G = L⁻¹·P·E_Jo (sparse forward solves of the changed
/// columns, on their elimination-tree reach only) and
/// C = E_Jᵀ P0⁻¹ E_J = blockdiag(GᵀG, D⁻¹):
///
///   T⁻¹ r = P0⁻¹ r − P0⁻¹ E_J Δ (I + C Δ)⁻¹ E_Jᵀ P0⁻¹ r.
///
/// Applied as one forward solve y = L⁻¹Pr, w = [Gᵀy; D⁻¹r_N], u = (I + CΔ)⁻¹w,
/// v = Δu, one back solve of y − G·v_o, and D⁻¹(r_N − v_N) on the new DOFs:
/// the cost of an ordinary solve plus two products with the thin G.

#include <cstdint>
#include <span>
#include <vector>

#include <Eigen/Core>
#include <Eigen/LU>
#include <Eigen/SparseCore>

#include "common/fem/supernodal_solve.h"

namespace cutsim::fem {

/// A full symmetric CSC matrix (both triangles), as SparseSystem stores it.
struct CscView {
  const int32_t* col_ptr = nullptr;    // #n+1
  const int32_t* row_index = nullptr;  // #nnz, ascending within a column
  const double* values = nullptr;      // #nnz
  int32_t n = 0;
};

class FactorCorrection {
 public:
  /// What Build did.
  struct BuildStats {
    int32_t rank = 0;        ///< k = |J|.
    int32_t reach_rows = 0;  ///< Rows of G (the columns its forward solves touch).
    double seconds = 0;      ///< Wall time of Build.
  };

  /// Builds the correction of `factor` (of A0, n0 = a0.n DOFs) toward B
  /// (n = b.n DOFs, n ≥ n0) for the old nodes `changed_nodes` (ascending,
  /// unique, < n0/3) and the new nodes [n0/3, n/3). Refuses (returns false
  /// and stays empty) above `max_rank` DOFs or when I + CΔ is singular.
  /// Allocates. Reads `factor` and both matrices only: several threads may
  /// build corrections of one factor at once.
  bool Build(const SupernodalSolver<float>& factor, const CscView& a0, const CscView& b,
             std::span<const int32_t> changed_nodes, int32_t max_rank);
  void Clear();

  [[nodiscard]] bool empty() const { return n_ == 0; }
  [[nodiscard]] int32_t rank() const { return static_cast<int32_t>(j_.size()); }
  /// DOFs the corrected preconditioner covers (n).
  [[nodiscard]] int32_t size() const { return n_; }
  [[nodiscard]] const BuildStats& stats() const { return stats_; }

  /// z = T⁻¹ r on all n DOFs (r and z must not alias). No allocation.
  void Apply(const SupernodalSolver<float>& factor, const double* r, double* z) const;

 private:
  int32_t n_ = 0, n0_ = 0;
  int32_t k_old_ = 0;              // |Jo|
  std::vector<int32_t> j_;         // #k: the DOFs of J, Jo first (ascending), then N
  SupernodalSolver<float>::Reach reach_;
  std::vector<int32_t> reach_rows_;  // #reach.rows: the factor row of each compact row
  std::vector<float> g_;           // #reach.rows×k_old: G, column-major
  Eigen::SparseMatrix<double> delta_;  // #k×k: Δ, as sparse as the elements that couple J
  Eigen::PartialPivLU<Eigen::MatrixXd> lu_;  // of I + CΔ
  std::vector<double> d_inv_;      // #(n−n0)×3: inverse 3×3 diagonal blocks of B on N, column-major per node
  BuildStats stats_;
  // Apply scratch.
  mutable std::vector<float> y_, yc_, tmp_, wf_;  // #n0, #reach.rows, factor scratch, #k_old
  mutable Eigen::VectorXd w_, u_, v_;              // #k
};

}  // namespace cutsim::fem
