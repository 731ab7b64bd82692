// The nodal-pressure element inside the implicit step (implicit.h): its
// volumetric pass, the matrix-free patch term of the PCG product, and the
// patch term's approximation in the factored matrix.
#include <omp.h>

#include <algorithm>
#include <cmath>
#include <vector>
#include <cstring>
#include <limits>

#include "common/fem/implicit.h"
#include "common/fem/implicit_internal.h"
#include "common/fem/nodal_pressure.h"

namespace cutsim::fem {

namespace {

using internal::ForEachTetByColor;
using internal::ScatterBlocks;
using internal::TetPositions;

}  // namespace

void ImplicitIntegrator::VolumetricPass(const Model<double>& model, const double* x, double tangent_scale,
                                        bool clamped, const uint8_t* active, double* values) {
  const int nt = NumThreads();
  const int32_t nn = system_.num_nodes();
  const bool tangent = tangent_scale > 0;
  std::fill(node_volume_now_.begin(), node_volume_now_.end(), 0.0);
#pragma omp parallel num_threads(nt)
  ForEachTetByColor(system_, [&](int32_t t) {
    const double vol = model.rest_volume(t);
    if (!(vol > 0)) return;
    const Mat3<double> F = EdgeMatrix(TetPositions(model, x, t)) * model.DmInv(t);
    const double v = vol * F.determinant();
    for (int c = 0; c < 4; ++c) node_volume_now_[static_cast<size_t>(model.tet_node(t, c))] += 0.25 * v;
  });
  // Nodal ratios, energy (summed in node order: deterministic), pressures.
  double energy = 0;
  for (int32_t n = 0; n < nn; ++n) {
    const auto i = static_cast<size_t>(n);
    const double rest = model.node_rest_volume(n);
    node_pressure_[i] = 0;
    if (tangent) patch_curvature_[i] = 0;
    if (!(rest > 0)) continue;
    const double j = node_volume_now_[i] / rest;
    const double kappa = model.node_kappa(n);
    energy += rest * VolumetricEnergyDensity(j, kappa);
    node_pressure_[i] = VolumetricPressure(j, kappa);
    if (tangent) patch_curvature_[i] = VolumetricModulus(j, kappa) / rest;
  }
  volumetric_energy_ = energy;
  double* force = node_force_.data();
#pragma omp parallel num_threads(nt)
  ForEachTetByColor(system_, [&](int32_t t) {
    const double vol = model.rest_volume(t);
    if (!(vol > 0)) return;
    const Mat3<double> dm_inv = model.DmInv(t);
    const Mat34<double> g = ShapeGradients(dm_inv);
    const Mat3<double> F = EdgeMatrix(TetPositions(model, x, t)) * dm_inv;
    const Mat34<double> grad = VolumeGradient(F, g, vol);
    const double p_bar = ElementMean(model, t, node_pressure_);
    for (int c = 0; c < 4; ++c) {
      Eigen::Map<Eigen::Vector3d>(force + 3 * model.tet_node(t, c)) -= p_bar * grad.col(c);
    }
    if (!tangent) return;
    std::memcpy(volume_grad_.data() + 12 * static_cast<size_t>(t), grad.data(), 12 * sizeof(double));
    if (clamped) return;
    ElementBlocks blocks;
    for (int a = 0; a < 4; ++a) {
      blocks[4 * a + a].setZero();
      for (int b = a + 1; b < 4; ++b) {
        blocks[4 * a + b] = p_bar * VolumeHessianBlock(F, g.col(a), g.col(b), vol);
        blocks[4 * b + a] = blocks[4 * a + b].transpose();
      }
    }
    ScatterBlocks(system_, model, t, blocks, tangent_scale, active, values);
  });
}

void ImplicitIntegrator::PatchTerm::AddProduct(const double* p, double* q) const {
  const ImplicitIntegrator& o = owner_;
  const Model<double>& model = *o.model_;
  double* slope = o.patch_slope_.data();
  const double* curvature = o.patch_curvature_.data();
  const double* grads = o.volume_grad_.data();
  const auto nn = static_cast<int32_t>(o.patch_slope_.size());
  // Colour by colour, so the scatters of one colour never collide and every
  // node sums in the same order for any thread count.
#pragma omp parallel num_threads(o.NumThreads())
  {
#pragma omp for schedule(static)
    for (int32_t n = 0; n < nn; ++n) slope[n] = 0;
    // ∇v_a·p = ¼ Σ_{e∋a} ∇v_e·p.
    ForEachTetByColor(o.system_, [&](int32_t t) {
      if (!(model.rest_volume(t) > 0)) return;
      const double* g = grads + 12 * static_cast<size_t>(t);
      double d = 0;
      for (int c = 0; c < 4; ++c) {
        const int32_t n = model.tet_node(t, c);
        d += g[3 * c] * p[3 * n] + g[3 * c + 1] * p[3 * n + 1] + g[3 * c + 2] * p[3 * n + 2];
      }
      for (int c = 0; c < 4; ++c) slope[model.tet_node(t, c)] += 0.25 * d;
    });
    // w_a = c_a·(∇v_a·p).
#pragma omp for schedule(static)
    for (int32_t n = 0; n < nn; ++n) slope[n] *= curvature[n];
    // q_c += h²·Σ_{e∋c} w̄_e ∇v_e|_c.
    ForEachTetByColor(o.system_, [&](int32_t t) {
      if (!(model.rest_volume(t) > 0)) return;
      const double* g = grads + 12 * static_cast<size_t>(t);
      double w = 0;
      for (int c = 0; c < 4; ++c) w += slope[model.tet_node(t, c)];
      w *= 0.25 * o.patch_scale_;
      for (int c = 0; c < 4; ++c) {
        const int32_t n = model.tet_node(t, c);
        for (int d = 0; d < 3; ++d) q[3 * n + d] += w * g[3 * c + d];
      }
    });
  }
}

void ImplicitIntegrator::LumpPatchTerm(const Model<double>& model) {
  const auto nn = static_cast<size_t>(system_.num_nodes());
  std::vector<double> sum(nn, 0.0), sum2(nn, 0.0);  // Σ_e V_e and Σ_e V_e² over each node's tets
  for (int32_t t = 0; t < model.num_tets(); ++t) {
    const double vol = model.rest_volume(t);
    if (!(vol > 0)) continue;
    for (int c = 0; c < 4; ++c) {
      const auto n = static_cast<size_t>(model.tet_node(t, c));
      sum[n] += vol;
      sum2[n] += vol * vol;
    }
  }
  patch_lump_.assign(nn, 1.0);
  for (size_t n = 0; n < nn; ++n) {
    if (sum2[n] > 0) patch_lump_[n] = std::pow(sum[n] * sum[n] / sum2[n], options_.patch_lumping);
  }
}

const double* ImplicitIntegrator::FactorValues() {
  // A factor request and a correction in one solve share one computation.
  if (factor_values_version_ == a_values_version_) return factor_values_.data();
  factor_values_version_ = a_values_version_;
  std::copy(a_values_.begin(), a_values_.end(), factor_values_.begin());
  AddPenaltyBlocks(jacobian_penalties_, -patch_scale_, factor_values_.data(), nullptr);
  if (!nodal_pressure_) return factor_values_.data();
  const Model<double>& model = *model_;
  const double scale = patch_scale_;
#pragma omp parallel num_threads(NumThreads())
  ForEachTetByColor(system_, [&](int32_t t) {
    if (!(model.rest_volume(t) > 0)) return;
    const Eigen::Map<const Mat34<double>> g(volume_grad_.data() + 12 * static_cast<size_t>(t));
    double coef = 0;
    for (int c = 0; c < 4; ++c) {
      const auto n = static_cast<size_t>(model.tet_node(t, c));
      coef += patch_curvature_[n] * patch_lump_[n];
    }
    coef /= 16.0;
    ElementBlocks blocks;
    for (int a = 0; a < 4; ++a) {
      for (int b = 0; b < 4; ++b) blocks[4 * a + b] = coef * g.col(a) * g.col(b).transpose();
    }
    ScatterBlocks(system_, model, t, blocks, scale, active_.data(), factor_values_.data());
  });
  return factor_values_.data();
}

}  // namespace cutsim::fem
