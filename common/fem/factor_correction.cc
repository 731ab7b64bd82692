#include "common/fem/factor_correction.h"

#include <cblas.h>

#include <algorithm>
#include <chrono>
#include <cmath>

#include <Eigen/Dense>

namespace cutsim::fem {

namespace {

/// Appends `sign`·M[J,J] of a full symmetric CSC matrix to `out` as
/// triplets (k×k), with `pos` mapping a DOF to its index in J (−1 outside).
/// Only columns of J below `m.n` are read.
void AddBlockOnJ(const CscView& m, std::span<const int32_t> j, const std::vector<int32_t>& pos, double sign,
                 std::vector<Eigen::Triplet<double>>& out) {
  for (size_t b = 0; b < j.size(); ++b) {
    const int32_t col = j[b];
    if (col >= m.n) continue;
    for (int32_t p = m.col_ptr[col]; p < m.col_ptr[col + 1]; ++p) {
      const int32_t row = m.row_index[p];
      if (row >= static_cast<int32_t>(pos.size())) continue;
      const int32_t a = pos[static_cast<size_t>(row)];
      if (a >= 0) out.emplace_back(a, static_cast<int32_t>(b), sign * m.values[p]);
    }
  }
}

}  // namespace

void FactorCorrection::Clear() {
  n_ = n0_ = k_old_ = 0;
  j_.clear();
  g_.clear();
  stats_ = {};
}

bool FactorCorrection::Build(const SupernodalSolver<float>& factor, const CscView& a0, const CscView& b,
                             std::span<const int32_t> changed_nodes, int32_t max_rank) {
  const auto t0 = std::chrono::steady_clock::now();
  Clear();
  const int32_t n = b.n;
  const int32_t n0 = a0.n;
  if (factor.size() != n0 || n < n0 || n0 % 3 != 0) return false;
  std::vector<int32_t> j;
  for (const int32_t node : changed_nodes) {
    if (node < 0 || 3 * node >= n0) continue;
    for (int d = 0; d < 3; ++d) j.push_back(3 * node + d);
  }
  const auto k_old = static_cast<int32_t>(j.size());
  for (int32_t i = n0; i < n; ++i) j.push_back(i);
  const auto k = static_cast<int32_t>(j.size());
  if (k == 0 || k > max_rank) return false;

  // G = L⁻¹·P·E_Jo on the reach of the changed rows.
  std::vector<int32_t> rows(static_cast<size_t>(k_old));
  for (int32_t c = 0; c < k_old; ++c) rows[static_cast<size_t>(c)] = factor.PermutedIndex(j[static_cast<size_t>(c)]);
  reach_ = factor.ReachOf(rows);
  const int32_t nr = reach_.rows;
  g_.assign(static_cast<size_t>(nr) * static_cast<size_t>(k_old), 0.0f);
  for (int32_t c = 0; c < k_old; ++c) {
    g_[static_cast<size_t>(c) * static_cast<size_t>(nr) +
       static_cast<size_t>(factor.CompactRow(reach_, rows[static_cast<size_t>(c)]))] = 1.0f;
  }
  std::vector<float> tmp(static_cast<size_t>(std::max<int64_t>(1, factor.block_work_size(k_old))));
  if (k_old > 0) factor.ForwardBlock(reach_, g_.data(), k_old, tmp.data());
  reach_rows_.assign(static_cast<size_t>(nr), 0);
  for (int32_t r = 0; r < n0; ++r) {
    const int32_t c = factor.CompactRow(reach_, r);
    if (c >= 0) reach_rows_[static_cast<size_t>(c)] = r;
  }

  // C = blockdiag(GᵀG, D⁻¹); Δ = B[J,J] − P0[J,J], sparse: J couples only
  // through the elements of its nodes.
  Eigen::MatrixXf gtg = Eigen::MatrixXf::Zero(k_old, k_old);
  if (k_old > 0) {
    cblas_ssyrk(CblasColMajor, CblasLower, CblasTrans, k_old, nr, 1.0f, g_.data(), nr, 0.0f, gtg.data(), k_old);
  }
  std::vector<int32_t> pos(static_cast<size_t>(n), -1);
  for (int32_t a = 0; a < k; ++a) pos[static_cast<size_t>(j[static_cast<size_t>(a)])] = a;
  std::vector<Eigen::Triplet<double>> entries;
  AddBlockOnJ(b, j, pos, 1.0, entries);
  AddBlockOnJ(a0, std::span(j).first(static_cast<size_t>(k_old)), pos, -1.0, entries);
  // P0 = blockdiag(A0, D): Δ has no diagonal block on N, where B's is D.
  const int32_t new_nodes = (n - n0) / 3;
  std::vector<double> d_blocks(9 * static_cast<size_t>(new_nodes), 0.0);  // #(n−n0)×3, column-major per node
  std::erase_if(entries, [&](const Eigen::Triplet<double>& e) {
    if (e.row() < k_old || e.col() < k_old) return false;
    const int32_t r = e.row() - k_old, c = e.col() - k_old;  // on N
    if (r / 3 != c / 3) return false;
    d_blocks[9 * static_cast<size_t>(r / 3) + 3 * static_cast<size_t>(c % 3) + static_cast<size_t>(r % 3)] +=
        e.value();
    return true;
  });
  delta_.resize(k, k);
  delta_.setFromTriplets(entries.begin(), entries.end());
  d_inv_.assign(9 * static_cast<size_t>(new_nodes), 0.0);
  Eigen::MatrixXd c = Eigen::MatrixXd::Zero(k, k);
  for (int32_t a = 0; a < k_old; ++a) {
    for (int32_t bb = 0; bb <= a; ++bb) c(a, bb) = c(bb, a) = gtg(a, bb);
  }
  for (int32_t m = 0; m < new_nodes; ++m) {
    const Eigen::Map<const Eigen::Matrix3d> d(d_blocks.data() + 9 * m);
    Eigen::Matrix3d inv;
    bool invertible = false;
    d.computeInverseWithCheck(inv, invertible);
    if (!invertible) inv = Eigen::Matrix3d::Identity() / std::max(1e-300, d.diagonal().cwiseAbs().maxCoeff());
    Eigen::Map<Eigen::Matrix3d>(d_inv_.data() + 9 * m) = inv;
    c.block<3, 3>(k_old + 3 * m, k_old + 3 * m) = inv;
  }
  // I + CΔ: C dense times Δ sparse, k·nnz(Δ) work.
  Eigen::MatrixXd i_plus_c_delta = c * delta_;
  i_plus_c_delta.diagonal().array() += 1.0;
  lu_.compute(i_plus_c_delta);
  const double det = lu_.determinant();
  if (!std::isfinite(det) || det == 0 || !lu_.matrixLU().allFinite()) {
    Clear();
    return false;
  }
  j_ = std::move(j);
  k_old_ = k_old;
  n_ = n;
  n0_ = n0;
  y_.assign(static_cast<size_t>(n0), 0.0f);
  yc_.assign(static_cast<size_t>(nr), 0.0f);
  tmp_.assign(static_cast<size_t>(std::max<int64_t>(1, factor.work_size() - n0)), 0.0f);
  wf_.assign(static_cast<size_t>(std::max(1, k_old)), 0.0f);
  w_.resize(k);
  u_.resize(k);
  v_.resize(k);
  stats_.rank = k;
  stats_.reach_rows = nr;
  stats_.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  return true;
}

void FactorCorrection::Apply(const SupernodalSolver<float>& factor, const double* r, double* z) const {
  const int32_t nr = reach_.rows;
  float* y = y_.data();
  for (int32_t i = 0; i < n0_; ++i) y[i] = static_cast<float>(r[factor.PermutedRow(i)]);
  factor.Forward(y, tmp_.data());
  // w = [Gᵀ y; D⁻¹ r_N].
  for (int32_t c = 0; c < nr; ++c) yc_[static_cast<size_t>(c)] = y[reach_rows_[static_cast<size_t>(c)]];
  if (k_old_ > 0) {
    cblas_sgemv(CblasColMajor, CblasTrans, nr, k_old_, 1.0f, g_.data(), nr, yc_.data(), 1, 0.0f, wf_.data(), 1);
  }
  for (int32_t a = 0; a < k_old_; ++a) w_(a) = wf_[static_cast<size_t>(a)];
  const int32_t new_nodes = (n_ - n0_) / 3;
  for (int32_t m = 0; m < new_nodes; ++m) {
    w_.segment<3>(k_old_ + 3 * m) = Eigen::Map<const Eigen::Matrix3d>(d_inv_.data() + 9 * m) *
                                    Eigen::Map<const Eigen::Vector3d>(r + n0_ + 3 * m);
  }
  u_ = lu_.solve(w_);
  v_.noalias() = delta_ * u_;
  // y ← y − G·v_o, then the back solve.
  if (k_old_ > 0) {
    for (int32_t a = 0; a < k_old_; ++a) wf_[static_cast<size_t>(a)] = static_cast<float>(v_(a));
    cblas_sgemv(CblasColMajor, CblasNoTrans, nr, k_old_, -1.0f, g_.data(), nr, wf_.data(), 1, 1.0f, yc_.data(), 1);
    for (int32_t c = 0; c < nr; ++c) y[reach_rows_[static_cast<size_t>(c)]] = yc_[static_cast<size_t>(c)];
  }
  factor.Backward(y, tmp_.data());
  for (int32_t i = 0; i < n0_; ++i) z[factor.PermutedRow(i)] = static_cast<double>(y[i]);
  for (int32_t m = 0; m < new_nodes; ++m) {
    Eigen::Map<Eigen::Vector3d>(z + n0_ + 3 * m) =
        Eigen::Map<const Eigen::Matrix3d>(d_inv_.data() + 9 * m) *
        (Eigen::Map<const Eigen::Vector3d>(r + n0_ + 3 * m) - v_.segment<3>(k_old_ + 3 * m));
  }
}

}  // namespace cutsim::fem
