#include "common/fem/supernodal_solve.h"

#include <cblas.h>
#include <suitesparse/cholmod.h>

#include <algorithm>

namespace cutsim::fem {

namespace {

// BLAS by scalar type (column-major, lower-triangular, non-unit diagonal).
inline void Trsv(CBLAS_TRANSPOSE t, int n, const float* a, int lda, float* x) {
  cblas_strsv(CblasColMajor, CblasLower, t, CblasNonUnit, n, a, lda, x, 1);
}
inline void Trsv(CBLAS_TRANSPOSE t, int n, const double* a, int lda, double* x) {
  cblas_dtrsv(CblasColMajor, CblasLower, t, CblasNonUnit, n, a, lda, x, 1);
}
inline void Gemv(CBLAS_TRANSPOSE t, int m, int n, float alpha, const float* a, int lda, const float* x,
                 float beta, float* y) {
  cblas_sgemv(CblasColMajor, t, m, n, alpha, a, lda, x, 1, beta, y, 1);
}
inline void Gemv(CBLAS_TRANSPOSE t, int m, int n, double alpha, const double* a, int lda, const double* x,
                 double beta, double* y) {
  cblas_dgemv(CblasColMajor, t, m, n, alpha, a, lda, x, 1, beta, y, 1);
}
inline void Trsm(int n, int m, const float* a, int lda, float* b, int ldb) {
  cblas_strsm(CblasColMajor, CblasLeft, CblasLower, CblasNoTrans, CblasNonUnit, n, m, 1.0f, a, lda, b, ldb);
}
inline void Trsm(int n, int m, const double* a, int lda, double* b, int ldb) {
  cblas_dtrsm(CblasColMajor, CblasLeft, CblasLower, CblasNoTrans, CblasNonUnit, n, m, 1.0, a, lda, b, ldb);
}
inline void Gemm(int m, int n, int k, const float* a, int lda, const float* b, int ldb, float* c, int ldc) {
  cblas_sgemm(CblasColMajor, CblasNoTrans, CblasNoTrans, m, n, k, 1.0f, a, lda, b, ldb, 0.0f, c, ldc);
}
inline void Gemm(int m, int n, int k, const double* a, int lda, const double* b, int ldb, double* c, int ldc) {
  cblas_dgemm(CblasColMajor, CblasNoTrans, CblasNoTrans, m, n, k, 1.0, a, lda, b, ldb, 0.0, c, ldc);
}

}  // namespace

template <typename T>
bool SupernodalSolver<T>::Assign(const void* factor) {
  const auto* L = static_cast<const cholmod_factor*>(factor);
  n_ = 0;
  nsuper_ = 0;
  if (L == nullptr || !L->is_super || !L->is_ll || L->itype != CHOLMOD_INT || L->xtype != CHOLMOD_REAL ||
      L->dtype != CHOLMOD_DOUBLE || L->x == nullptr) {
    return false;
  }
  const auto n = static_cast<int32_t>(L->n);
  const auto ns = static_cast<int32_t>(L->nsuper);
  const auto* super = static_cast<const int*>(L->super);
  const auto* pi = static_cast<const int*>(L->pi);
  const auto* px = static_cast<const int*>(L->px);
  const auto* s = static_cast<const int*>(L->s);
  const auto* perm = static_cast<const int*>(L->Perm);
  const auto* x = static_cast<const double*>(L->x);
  super_.assign(super, super + ns + 1);
  pi_.assign(pi, pi + ns + 1);
  px_.assign(px, px + ns + 1);
  s_.assign(s, s + pi[ns]);
  perm_.resize(static_cast<size_t>(n));
  iperm_.resize(static_cast<size_t>(n));
  for (int32_t k = 0; k < n; ++k) {
    perm_[static_cast<size_t>(k)] = perm != nullptr ? perm[k] : k;
    iperm_[static_cast<size_t>(perm_[static_cast<size_t>(k)])] = k;
  }
  x_.resize(static_cast<size_t>(px[ns]));
  std::transform(x, x + px[ns], x_.begin(), [](double v) { return static_cast<T>(v); });
  col_super_.resize(static_cast<size_t>(n));
  parent_.assign(static_cast<size_t>(ns), -1);
  max_below_ = 0;
  for (int32_t k = 0; k < ns; ++k) {
    const int32_t ncols = super[k + 1] - super[k];
    const int32_t nrows = pi[k + 1] - pi[k];
    for (int32_t c = super[k]; c < super[k + 1]; ++c) col_super_[static_cast<size_t>(c)] = k;
    max_below_ = std::max(max_below_, nrows - ncols);
  }
  for (int32_t k = 0; k < ns; ++k) {
    const int32_t ncols = super[k + 1] - super[k];
    if (pi[k + 1] - pi[k] > ncols) parent_[static_cast<size_t>(k)] = col_super_[static_cast<size_t>(s[pi[k] + ncols])];
  }
  n_ = n;
  nsuper_ = ns;
  return true;
}

template <typename T>
void SupernodalSolver<T>::Forward(T* y, T* tmp) const {
  for (int32_t k = 0; k < nsuper_; ++k) {
    const int32_t c0 = super_[static_cast<size_t>(k)];
    const int32_t ncols = super_[static_cast<size_t>(k) + 1] - c0;
    const int32_t nrows = pi_[static_cast<size_t>(k) + 1] - pi_[static_cast<size_t>(k)];
    const int32_t below = nrows - ncols;
    const T* lk = x_.data() + px_[static_cast<size_t>(k)];
    Trsv(CblasNoTrans, ncols, lk, nrows, y + c0);
    if (below == 0) continue;
    Gemv(CblasNoTrans, below, ncols, T(1), lk + ncols, nrows, y + c0, T(0), tmp);
    const int32_t* rows = s_.data() + pi_[static_cast<size_t>(k)] + ncols;
    for (int32_t i = 0; i < below; ++i) y[rows[i]] -= tmp[i];
  }
}

template <typename T>
void SupernodalSolver<T>::Backward(T* y, T* tmp) const {
  for (int32_t k = nsuper_ - 1; k >= 0; --k) {
    const int32_t c0 = super_[static_cast<size_t>(k)];
    const int32_t ncols = super_[static_cast<size_t>(k) + 1] - c0;
    const int32_t nrows = pi_[static_cast<size_t>(k) + 1] - pi_[static_cast<size_t>(k)];
    const int32_t below = nrows - ncols;
    const T* lk = x_.data() + px_[static_cast<size_t>(k)];
    if (below > 0) {
      const int32_t* rows = s_.data() + pi_[static_cast<size_t>(k)] + ncols;
      for (int32_t i = 0; i < below; ++i) tmp[i] = y[rows[i]];
      Gemv(CblasTrans, below, ncols, T(-1), lk + ncols, nrows, tmp, T(1), y + c0);
    }
    Trsv(CblasTrans, ncols, lk, nrows, y + c0);
  }
}

template <typename T>
void SupernodalSolver<T>::Solve(const double* r, double* z, T* work) const {
  T* y = work;
  T* tmp = work + n_;
  for (int32_t k = 0; k < n_; ++k) y[k] = static_cast<T>(r[perm_[static_cast<size_t>(k)]]);
  Forward(y, tmp);
  Backward(y, tmp);
  for (int32_t k = 0; k < n_; ++k) z[perm_[static_cast<size_t>(k)]] = static_cast<double>(y[k]);
}

template <typename T>
typename SupernodalSolver<T>::Reach SupernodalSolver<T>::ReachOf(std::span<const int32_t> rows) const {
  Reach reach;
  reach.offset.assign(static_cast<size_t>(nsuper_), -1);
  for (const int32_t r : rows) {
    if (r < 0 || r >= n_) continue;
    for (int32_t k = col_super_[static_cast<size_t>(r)]; k >= 0 && reach.offset[static_cast<size_t>(k)] < 0;
         k = parent_[static_cast<size_t>(k)]) {
      reach.offset[static_cast<size_t>(k)] = 0;
      reach.supernodes.push_back(k);
    }
  }
  std::sort(reach.supernodes.begin(), reach.supernodes.end());  // a child precedes its parent
  for (const int32_t k : reach.supernodes) {
    reach.offset[static_cast<size_t>(k)] = reach.rows;
    reach.rows += super_[static_cast<size_t>(k) + 1] - super_[static_cast<size_t>(k)];
  }
  return reach;
}

template <typename T>
void SupernodalSolver<T>::ForwardBlock(const Reach& reach, T* y, int32_t m, T* tmp) const {
  const int32_t ld = reach.rows;
  for (const int32_t k : reach.supernodes) {
    const int32_t c0 = super_[static_cast<size_t>(k)];
    const int32_t ncols = super_[static_cast<size_t>(k) + 1] - c0;
    const int32_t nrows = pi_[static_cast<size_t>(k) + 1] - pi_[static_cast<size_t>(k)];
    const int32_t below = nrows - ncols;
    const T* lk = x_.data() + px_[static_cast<size_t>(k)];
    T* yk = y + reach.offset[static_cast<size_t>(k)];
    Trsm(ncols, m, lk, nrows, yk, ld);
    if (below == 0) continue;
    Gemm(below, m, ncols, lk + ncols, nrows, yk, ld, tmp, below);
    const int32_t* rows = s_.data() + pi_[static_cast<size_t>(k)] + ncols;
    for (int32_t i = 0; i < below; ++i) {
      const int32_t c = CompactRow(reach, rows[i]);  // an ancestor's column: inside the reach
      for (int32_t j = 0; j < m; ++j) y[static_cast<int64_t>(j) * ld + c] -= tmp[static_cast<int64_t>(j) * below + i];
    }
  }
}

template class SupernodalSolver<float>;
template class SupernodalSolver<double>;

}  // namespace cutsim::fem
