#pragma once
/// @file
/// `fem::SparseSystem`: the fixed block-sparse pattern of a tetrahedral
/// model's 3N×3N tangent (one 3×3 block per pair of nodes that share a tet),
/// stored as a full symmetric scalar CSC matrix that CHOLMOD reads directly
/// (stype −1: the lower triangle) and that PCG multiplies column by column.
///
/// The pattern is built once per topology version. Each tet keeps, for each
/// of its 16 corner pairs, the offset of its 3×3 block in the value array, so
/// assembly is a scatter without search. Tets are cut into chunks of kChunk
/// consecutive tets and the chunks greedily coloured so that no two chunks
/// of one colour share a node: a scatter that runs colour by colour, each
/// colour's chunks in parallel and each chunk's tets in order, adds into
/// every entry in the same order for any thread count (assembly gives the
/// same bits for 1 and 2 threads), and a chunk's tets touch neighbouring
/// memory (a few colours sweep the value array, not one per tet colour).

#include <algorithm>
#include <cstdint>
#include <span>
#include <vector>

#include <Eigen/Core>

#include "common/fem/model.h"

namespace cutsim::fem {

class SparseSystem {
 public:
  /// An empty system (0 nodes); Build it before use.
  SparseSystem() = default;

  /// Builds the pattern, the per-tet block offsets and the tet colouring
  /// for the model's current nodes and tets, in one pass over the model's
  /// node → tet incidence (no search per tet pair). Allocates when the
  /// model grew beyond the headroom of the last build (core/headroom.h).
  void Build(const Model<double>& model);

  /// True if Build has not run for the model's current topology version and
  /// node count.
  [[nodiscard]] bool Stale(const Model<double>& model) const {
    return !built_ || model.topology_version() != topology_version_ ||
           model.num_nodes() != num_nodes_ || model.num_tets() != num_tets_;
  }

  // ---- sizes ---------------------------------------------------------------
  [[nodiscard]] int32_t num_nodes() const { return num_nodes_; }
  [[nodiscard]] int32_t num_dofs() const { return 3 * num_nodes_; }
  [[nodiscard]] int32_t num_tets() const { return num_tets_; }
  [[nodiscard]] int64_t num_blocks() const { return static_cast<int64_t>(block_row_.size()); }
  /// Scalar nonzeros of the full symmetric matrix (9 per block).
  [[nodiscard]] int64_t nnz() const { return static_cast<int64_t>(row_index_.size()); }
  [[nodiscard]] uint64_t topology_version() const { return topology_version_; }
  /// How many times Build ran on this object.
  [[nodiscard]] int64_t builds() const { return builds_; }
  /// Identifies the pattern of the last Build among all systems of the
  /// process (a factor made from one pattern is recognised by it).
  [[nodiscard]] int64_t pattern_id() const { return pattern_id_; }

  // ---- scalar CSC ----------------------------------------------------------
  [[nodiscard]] const int32_t* col_ptr() const { return col_ptr_.data(); }      // #3N+1
  [[nodiscard]] const int32_t* row_index() const { return row_index_.data(); }  // #nnz

  // ---- blocks --------------------------------------------------------------
  /// Offset of entry (row 3a, col 3b) of block (a, b) in the value array;
  /// entry (3a+r, 3b+c) is at offset + c·col_stride(b) + r. −1 if a and b
  /// share no tet.
  [[nodiscard]] int32_t FindBlock(int32_t a, int32_t b) const;
  /// Distance between consecutive scalar columns of node b's blocks.
  [[nodiscard]] int32_t col_stride(int32_t b) const { return col_ptr_[3 * b + 1] - col_ptr_[3 * b]; }
  /// Offset of node n's diagonal block (as FindBlock(n, n)).
  [[nodiscard]] int32_t diagonal_block(int32_t n) const { return diag_offset_[n]; }
  /// Block offsets of tet t: entry 4·i + j is block (corner i, corner j).  // 16
  [[nodiscard]] const int32_t* tet_blocks(int32_t t) const { return tet_block_.data() + 16 * t; }

  // ---- colouring -----------------------------------------------------------
  /// Consecutive tets per chunk.
  static constexpr int32_t kChunk = 64;
  [[nodiscard]] int32_t num_colors() const { return static_cast<int32_t>(color_ptr_.size()) - 1; }
  /// Chunks of colour c: color_chunks()[color_ptr()[c] .. color_ptr()[c+1]).
  [[nodiscard]] const int32_t* color_ptr() const { return color_ptr_.data(); }  // #colors+1
  [[nodiscard]] const int32_t* color_chunks() const { return color_chunks_.data(); }  // #chunks
  /// Tets of chunk k: [chunk_begin(k), chunk_end(k)).
  [[nodiscard]] int32_t chunk_begin(int32_t k) const { return k * kChunk; }
  [[nodiscard]] int32_t chunk_end(int32_t k) const { return std::min(num_tets_, (k + 1) * kChunk); }

  // ---- products and block access ------------------------------------------
  /// y = A·x for the symmetric matrix with the given values (#nnz); each
  /// output entry is summed by one thread in pattern order (deterministic).
  /// Contains an orphaned `omp for`: call inside a parallel region or alone.
  void MultiplyTeam(const double* values, const double* x, double* y) const;
  /// Adds `scale·m` to block (a, b) of `values` at `offset` (from FindBlock).
  void AddBlock(double* values, int32_t offset, int32_t b, const Eigen::Matrix3d& m) const {
    const int32_t stride = col_stride(b);
    for (int c = 0; c < 3; ++c) {
      for (int r = 0; r < 3; ++r) values[offset + c * stride + r] += m(r, c);
    }
  }
  /// Block (a, b) at `offset` as a 3×3 matrix.
  [[nodiscard]] Eigen::Matrix3d GetBlock(const double* values, int32_t offset, int32_t b) const;

 private:
  bool built_ = false;
  int32_t num_nodes_ = 0;
  int32_t num_tets_ = 0;
  uint64_t topology_version_ = 0;
  int64_t builds_ = 0;
  int64_t pattern_id_ = -1;
  std::vector<int32_t> block_ptr_;    // #N+1: node b's blocks are [block_ptr_[b], block_ptr_[b+1])
  std::vector<int32_t> block_row_;    // #blocks: row node a, ascending within a column node
  std::vector<int32_t> col_ptr_;      // #3N+1
  std::vector<int32_t> row_index_;    // #nnz
  std::vector<int32_t> diag_offset_;  // #N
  std::vector<int32_t> tet_block_;    // #T×16
  std::vector<int32_t> color_ptr_;    // #colors+1
  std::vector<int32_t> color_chunks_; // #chunks
};

}  // namespace cutsim::fem
