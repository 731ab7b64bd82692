#pragma once
/// @file
/// Forward and back substitution with a supernodal Cholesky factor
/// P·A·Pᵀ = L·Lᵀ made by CHOLMOD, in single or double precision, over
/// CHOLMOD's own supernodal layout (a copy of `super`, `pi`, `px`, `s`,
/// `Perm` and the values, converted to the solve's scalar type).
///
/// Supernode k holds the columns [super[k], super[k+1]) of L; its rows are
/// s[pi[k] .. pi[k+1]) (the first ncols are the columns themselves) and its
/// values a column-major nrows×ncols block at x[px[k]] whose top ncols×ncols
/// square is lower triangular. The forward solve walks the supernodes in
/// order, a triangular solve on the diagonal block (BLAS trsv) and a
/// product (gemv) that updates the rows below; the back solve walks them in
/// reverse with the transposes.
///
/// Why single precision: the solves read every value of L once and do two
/// flops per value, so their time is the time to stream L from memory.
/// Floats halve that stream, and at the organ's size the float factor fits
/// the last-level cache. The solve is a preconditioner inside a PCG that
/// stays in double, so its relative error of ~1e-7 (a float's round-off
/// times the growth of the triangular solves) only moves the iteration
/// count, never the accuracy of the result.
///
/// `SolveSparse` runs the forward solve with a right-hand side of a few
/// nonzeros and a block of them at once (BLAS trsm/gemm): only the
/// supernodes on the elimination-tree paths from those rows to the root are
/// touched, which is what a low-rank correction of the factor needs.

#include <cstdint>
#include <span>
#include <vector>

namespace cutsim::fem {

template <typename T>
class SupernodalSolver {
 public:
  SupernodalSolver() = default;

  /// Copies the layout and the values of a CHOLMOD supernodal LLᵀ factor
  /// (`cholmod_factor*`, passed untyped to keep CHOLMOD out of this
  /// header). Allocates; meant for the thread that made the factor.
  /// Returns false (and stays empty) when the factor is not supernodal LLᵀ
  /// with int indices and double values.
  bool Assign(const void* cholmod_factor);

  [[nodiscard]] bool empty() const { return n_ == 0; }
  /// Order of the factor (DOFs).
  [[nodiscard]] int32_t size() const { return n_; }
  /// Stored values of L (the supernodes' blocks, upper parts included).
  [[nodiscard]] int64_t stored_values() const { return static_cast<int64_t>(x_.size()); }
  [[nodiscard]] int32_t num_supernodes() const { return nsuper_; }

  /// Scalars of scratch a Solve needs (size() plus the most rows below the
  /// diagonal block of any supernode).
  [[nodiscard]] int64_t work_size() const { return n_ + max_below_; }
  /// Scalars of scratch a ForwardBlock of m columns needs.
  [[nodiscard]] int64_t block_work_size(int32_t m) const { return static_cast<int64_t>(max_below_) * m; }

  /// z = A⁻¹ r with A = Pᵀ L Lᵀ P; r and z hold size() doubles and may
  /// alias. `work` holds work_size() scalars (no allocation).
  void Solve(const double* r, double* z, T* work) const;

  /// Forward solve in place, y ← L⁻¹ y, on the factor's (permuted) order;
  /// `tmp` holds work_size() − size() scalars.
  void Forward(T* y, T* tmp) const;
  /// Back solve in place, y ← L⁻ᵀ y, on the factor's order.
  void Backward(T* y, T* tmp) const;

  /// Original row of factor row k (CHOLMOD's Perm).
  [[nodiscard]] int32_t PermutedRow(int32_t k) const { return perm_[static_cast<size_t>(k)]; }
  /// Position in the factor's order of original row i (the inverse of Perm).
  [[nodiscard]] int32_t PermutedIndex(int32_t i) const { return iperm_[static_cast<size_t>(i)]; }

  /// The supernodes a forward solve from a few rows reaches (the union of
  /// their elimination-tree paths to the root, ascending: a child before
  /// its parent) and a compact numbering of their columns.
  struct Reach {
    std::vector<int32_t> supernodes;
    std::vector<int32_t> offset;  // #nsuper: compact index of a supernode's first column, −1 outside
    int32_t rows = 0;             // columns covered = rows of a compact vector
  };
  /// The reach of the factor-order rows `rows`. Allocates.
  [[nodiscard]] Reach ReachOf(std::span<const int32_t> rows) const;
  /// Compact index (in `reach`) of factor-order row r, −1 outside the reach.
  [[nodiscard]] int32_t CompactRow(const Reach& reach, int32_t r) const {
    const int32_t k = col_super_[static_cast<size_t>(r)];
    const int32_t o = reach.offset[static_cast<size_t>(k)];
    return o < 0 ? -1 : o + r - super_[static_cast<size_t>(k)];
  }
  /// Forward solve of m right-hand sides at once, Y ← L⁻¹ Y, for a Y that
  /// is zero outside the reach's rows: Y is compact (reach.rows × m,
  /// column-major, leading dimension reach.rows). `tmp` holds
  /// block_work_size(m) scalars. Touches only the reach's supernodes.
  void ForwardBlock(const Reach& reach, T* y, int32_t m, T* tmp) const;

 private:
  int32_t n_ = 0;
  int32_t nsuper_ = 0;
  std::vector<int32_t> super_;  // #nsuper+1: first column of each supernode
  std::vector<int32_t> pi_;     // #nsuper+1: start of its rows in s_
  std::vector<int64_t> px_;     // #nsuper+1: start of its values in x_
  std::vector<int32_t> s_;      // row indices of the supernodes
  std::vector<int32_t> perm_;   // #n: factor row k is original row perm_[k]
  std::vector<int32_t> iperm_;  // #n: inverse of perm_
  std::vector<int32_t> parent_;  // #nsuper: supernodal elimination tree (−1: root)
  std::vector<int32_t> col_super_;  // #n: the supernode of each column
  std::vector<T> x_;            // values
  int32_t max_below_ = 0;       // most rows below a diagonal block
};

extern template class SupernodalSolver<float>;
extern template class SupernodalSolver<double>;

}  // namespace cutsim::fem
