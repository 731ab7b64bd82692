#include "common/fem/nodal_pressure.h"

#include <algorithm>
#include <limits>

#include "common/fem/tangent.h"

namespace cutsim::fem {

namespace {

/// One element's deformation gradient and shape-function gradients at x.
struct ElementFrame {
  Mat3<double> F;
  Mat34<double> g;
  double rest_volume = 0;
};

ElementFrame FrameOf(const Model<double>& model, const double* x, int32_t t) {
  ElementFrame e;
  e.rest_volume = model.rest_volume(t);
  const Mat3<double> dm_inv = model.DmInv(t);
  Mat34<double> xe;
  for (int c = 0; c < 4; ++c) xe.col(c) = Eigen::Map<const Eigen::Vector3d>(x + 3 * model.tet_node(t, c));
  e.F = EdgeMatrix(xe) * dm_inv;
  e.g = ShapeGradients(dm_inv);
  return e;
}

/// The nodal volume ratios J_a at x (#N; 1 for a node without volume).
void NodalVolumeRatios(const Model<double>& model, const double* x, const std::vector<double>& node_volume,
                       std::vector<double>& node_j) {
  const int32_t nn = model.num_nodes();
  std::vector<double> current(static_cast<size_t>(nn), 0.0);
  for (int32_t t = 0; t < model.num_tets(); ++t) {
    if (!(model.rest_volume(t) > 0)) continue;
    const ElementFrame e = FrameOf(model, x, t);
    const double v = e.rest_volume * e.F.determinant();
    for (int c = 0; c < 4; ++c) current[static_cast<size_t>(model.tet_node(t, c))] += 0.25 * v;
  }
  node_j.assign(static_cast<size_t>(nn), 1.0);
  for (int32_t n = 0; n < nn; ++n) {
    const auto i = static_cast<size_t>(n);
    if (node_volume[i] > 0) node_j[i] = current[i] / node_volume[i];
  }
}

}  // namespace

void NodalRestVolumes(const Model<double>& model, std::span<const double> kappa,
                      std::vector<double>& node_kappa, std::vector<double>& node_volume) {
  const auto nn = static_cast<size_t>(model.num_nodes());
  node_kappa.assign(nn, 0.0);
  node_volume.assign(nn, 0.0);
  for (int32_t t = 0; t < model.num_tets(); ++t) {
    const double vol = model.rest_volume(t);
    if (!(vol > 0)) continue;
    for (int c = 0; c < 4; ++c) {
      const auto a = static_cast<size_t>(model.tet_node(t, c));
      node_volume[a] += 0.25 * vol;
      node_kappa[a] += 0.25 * vol * kappa[static_cast<size_t>(t)];
    }
  }
  for (size_t a = 0; a < nn; ++a) {
    if (node_volume[a] > 0) node_kappa[a] /= node_volume[a];
  }
}

double NodalPressureEnergyAndForce(const Model<double>& model, std::span<const double> kappa, const double* x,
                                   double* force, double* node_j) {
  std::vector<double> node_kappa, node_volume, j;
  NodalRestVolumes(model, kappa, node_kappa, node_volume);
  NodalVolumeRatios(model, x, node_volume, j);
  const int32_t nn = model.num_nodes();
  double energy = 0;
  std::vector<double> pressure(static_cast<size_t>(nn), 0.0);
  for (int32_t n = 0; n < nn; ++n) {
    const auto i = static_cast<size_t>(n);
    if (node_j != nullptr) node_j[n] = j[i];
    if (!(node_volume[i] > 0)) continue;
    energy += node_volume[i] * VolumetricEnergyDensity(j[i], node_kappa[i]);
    pressure[i] = VolumetricPressure(j[i], node_kappa[i]);
  }
  if (force == nullptr || !std::isfinite(energy)) return energy;
  for (int32_t t = 0; t < model.num_tets(); ++t) {
    if (!(model.rest_volume(t) > 0)) continue;
    const ElementFrame e = FrameOf(model, x, t);
    const Mat34<double> grad = VolumeGradient(e.F, e.g, e.rest_volume);
    const double p_bar = ElementMean(model, t, pressure);
    for (int c = 0; c < 4; ++c) {
      Eigen::Map<Eigen::Vector3d>(force + 3 * model.tet_node(t, c)) -= p_bar * grad.col(c);
    }
  }
  return energy;
}

void NodalPressureHessianProduct(const Model<double>& model, std::span<const double> kappa, const double* x,
                                 const double* p, double* out) {
  std::vector<double> node_kappa, node_volume, j;
  NodalRestVolumes(model, kappa, node_kappa, node_volume);
  NodalVolumeRatios(model, x, node_volume, j);
  const auto nn = static_cast<size_t>(model.num_nodes());
  std::vector<double> pressure(nn, 0.0), slope(nn, 0.0);  // p_a, then ∇v_a·p
  for (size_t a = 0; a < nn; ++a) {
    if (node_volume[a] > 0) pressure[a] = VolumetricPressure(j[a], node_kappa[a]);
  }
  // ∇v_a·p = ¼ Σ_{e∋a} ∇v_e·p.
  for (int32_t t = 0; t < model.num_tets(); ++t) {
    if (!(model.rest_volume(t) > 0)) continue;
    const ElementFrame e = FrameOf(model, x, t);
    const Mat34<double> grad = VolumeGradient(e.F, e.g, e.rest_volume);
    double d = 0;
    for (int c = 0; c < 4; ++c) d += grad.col(c).dot(Eigen::Map<const Eigen::Vector3d>(p + 3 * model.tet_node(t, c)));
    for (int c = 0; c < 4; ++c) slope[static_cast<size_t>(model.tet_node(t, c))] += 0.25 * d;
  }
  // w_a = U''(J_a)/V_a·(∇v_a·p), then out_c += Σ_e w̄_e ∇v_e|_c + p̄_e Σ_b ∂²v_e/∂x_c∂x_b p_b.
  std::vector<double> weight(nn, 0.0);
  for (size_t a = 0; a < nn; ++a) {
    if (node_volume[a] > 0) weight[a] = VolumetricModulus(j[a], node_kappa[a]) / node_volume[a] * slope[a];
  }
  for (int32_t t = 0; t < model.num_tets(); ++t) {
    if (!(model.rest_volume(t) > 0)) continue;
    const ElementFrame e = FrameOf(model, x, t);
    const Mat34<double> grad = VolumeGradient(e.F, e.g, e.rest_volume);
    const double w_bar = ElementMean(model, t, weight);
    const double p_bar = ElementMean(model, t, pressure);
    for (int c = 0; c < 4; ++c) {
      Eigen::Vector3d q = w_bar * grad.col(c);
      for (int b = 0; b < 4; ++b) {
        if (b == c) continue;
        q += p_bar * VolumeHessianBlock(e.F, e.g.col(c), e.g.col(b), e.rest_volume) *
             Eigen::Map<const Eigen::Vector3d>(p + 3 * model.tet_node(t, b));
      }
      Eigen::Map<Eigen::Vector3d>(out + 3 * model.tet_node(t, c)) += q;
    }
  }
}

}  // namespace cutsim::fem
