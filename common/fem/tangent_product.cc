#include "common/fem/tangent_product.h"

#include <algorithm>

#include "common/fem/implicit_internal.h"
#include "common/fem/nodal_pressure.h"
#include "common/fem/tangent.h"

namespace cutsim::fem {

namespace {

using internal::ForEachTetByColor;
using internal::TetPositions;

/// Dcof(F)[dF]: the derivative of cof(F) (columns f₂×f₃, f₃×f₁, f₁×f₂) in
/// the direction dF.  // 3×3
Mat3<double> CofactorDerivative(const Mat3<double>& F, const Mat3<double>& dF) {
  Mat3<double> d;
  d.col(0) = dF.col(1).cross(F.col(2)) + F.col(1).cross(dF.col(2));
  d.col(1) = dF.col(2).cross(F.col(0)) + F.col(2).cross(dF.col(0));
  d.col(2) = dF.col(0).cross(F.col(1)) + F.col(0).cross(dF.col(1));
  return d;
}

}  // namespace

void TangentProduct::Linearize(const Model<double>& model, const SparseSystem& system, const double* x,
                               bool clamped, int num_threads) {
  model_ = &model;
  system_ = &system;
  num_threads_ = std::max(1, num_threads);
  const auto nt = static_cast<size_t>(model.num_tets());
  f_.resize(9 * nt);
  s_.resize(9 * nt);
  p_bar_.assign(nt, 0.0);
  const bool volumetric = model.element() == ElementKind::kNodalPressure && !clamped;
  if (volumetric) node_volume_.assign(static_cast<size_t>(model.num_nodes()), 0.0);
#pragma omp parallel num_threads(num_threads_)
  ForEachTetByColor(system, [&](int32_t t) {
    const auto i = static_cast<size_t>(t);
    const double vol = model.rest_volume(t);
    if (!(vol > 0)) {
      std::fill_n(f_.data() + 9 * i, 9, 0.0);
      std::fill_n(s_.data() + 9 * i, 9, 0.0);
      return;
    }
    const Mat3<double> F = EdgeMatrix(TetPositions(model, x, t)) * model.DmInv(t);
    const Mat3<double> S = StvkSecondPiola(GreenStrain(F), model.element_lambdas()[t], model.mus()[t]);
    Eigen::Map<Mat3<double>>(f_.data() + 9 * i) = F;
    Eigen::Map<Mat3<double>>(s_.data() + 9 * i) = clamped ? PositivePart(S) : S;
    if (volumetric) {
      const double v = vol * F.determinant();
      for (int c = 0; c < 4; ++c) node_volume_[static_cast<size_t>(model.tet_node(t, c))] += 0.25 * v;
    }
  });
  if (!volumetric) return;
  // Nodal pressures p_a = U'(J_a) in place of the volumes, then p̄_e.
  for (int32_t n = 0; n < model.num_nodes(); ++n) {
    const auto i = static_cast<size_t>(n);
    const double rest = model.node_rest_volume(n);
    node_volume_[i] = rest > 0 ? VolumetricPressure(node_volume_[i] / rest, model.node_kappa(n)) : 0.0;
  }
  for (int32_t t = 0; t < model.num_tets(); ++t) {
    if (model.rest_volume(t) > 0) p_bar_[static_cast<size_t>(t)] = ElementMean(model, t, node_volume_);
  }
}

void TangentProduct::AddProduct(const double* p, double scale, const uint8_t* active, double* q) const {
  const Model<double>& model = *model_;
#pragma omp parallel num_threads(num_threads_)
  ForEachTetByColor(*system_, [&](int32_t t) {
    const double vol = model.rest_volume(t);
    if (!(vol > 0)) return;
    const auto i = static_cast<size_t>(t);
    const Mat34<double> g = ShapeGradients(model.DmInv(t));
    int32_t nodes[4];
    bool on[4];
    Mat34<double> pe;
    for (int c = 0; c < 4; ++c) {
      nodes[c] = model.tet_node(t, c);
      on[c] = active == nullptr || active[nodes[c]] != 0;
      pe.col(c) = on[c] ? Vec3<double>(p[3 * nodes[c]], p[3 * nodes[c] + 1], p[3 * nodes[c] + 2])
                        : Vec3<double>::Zero();
    }
    const Eigen::Map<const Mat3<double>> F(f_.data() + 9 * i);
    const Eigen::Map<const Mat3<double>> S(s_.data() + 9 * i);
    const Mat3<double> dF = pe * g.transpose();
    const Mat3<double> ftdf = F.transpose() * dF;
    const Mat3<double> dE = 0.5 * (ftdf + ftdf.transpose());
    Mat3<double> dS = (2.0 * model.mus()[t]) * dE;
    dS.diagonal().array() += model.element_lambdas()[t] * dE.trace();
    Mat3<double> dP = dF * S + F * dS;
    if (p_bar_[i] != 0) dP += p_bar_[i] * CofactorDerivative(F, dF);
    const Mat34<double> qe = (scale * vol) * dP * g;
    for (int c = 0; c < 4; ++c) {
      if (on[c]) Eigen::Map<Eigen::Vector3d>(q + 3 * nodes[c]) += qe.col(c);
    }
  });
}

}  // namespace cutsim::fem
