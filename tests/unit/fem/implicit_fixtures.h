#pragma once
/// @file
/// Shared set-ups of the implicit-step tests: a cantilever box clamped at
/// x = 0, deformed states of it, and a vertex split as a cut makes one.

#include <algorithm>
#include <cmath>
#include <vector>

#include "common/fem/implicit.h"
#include "common/fem/model.h"
#include "common/fem/state.h"
#include "tests/unit/fem/test_meshes.h"

namespace cutsim::fem::testing {

/// nx×2×2 cells over lx × 0.02 × 0.02 m, E (Pa), ν = 0.45, ρ = 1000,
/// the x = 0 face fixed, gravity −z unless `gravity` is false.
inline Model<double> MakeCantilever(int nx, double lx, double youngs, bool gravity = true,
                                    double psi = 0, double phi = 0, int extra_nodes = 0) {
  const mesh::TetMesh mesh = MakeBoxMesh(nx, 2, 2, lx, 0.02, 0.02);
  const Material mat = Material::FromYoungPoisson(youngs, 0.45, 1000.0, psi, phi);
  ModelOptions opt;
  opt.node_capacity = mesh.num_nodes() + extra_nodes;
  if (gravity) opt.gravity = Eigen::Vector3d(0, 0, -9.81);
  Model<double> model(mesh, std::span(&mat, 1), opt);
  for (int32_t n = 0; n < model.num_nodes(); ++n) {
    if (model.rest_position(n)(0) < 1e-9) model.SetFixed(n, true);
  }
  return model;
}

/// Rest positions with free nodes moved by a smooth pseudo-random field of
/// amplitude `amp` (m) and the whole body scaled along x by `sx` about x = 0.
inline std::vector<double> DeformedPositions(const Model<double>& model, double amp, double sx,
                                             double seed = 1.0) {
  std::vector<double> x(static_cast<size_t>(3 * model.node_capacity()), 0.0);
  for (int32_t n = 0; n < model.num_nodes(); ++n) {
    const Vec3<double> p = model.rest_position(n);
    for (int d = 0; d < 3; ++d) {
      const double r = std::sin(seed * (1.3 + d) * (3 * n + d) + 0.7 * seed);
      x[static_cast<size_t>(3 * n + d)] = p(d) * (d == 0 ? sx : 1.0) + (model.fixed(n) ? 0.0 : amp * r);
    }
  }
  return x;
}

/// Splits node `mid` as a cut does: every tet whose rest centroid c
/// satisfies `moves(c)` takes a copy of the node in its place; elements,
/// node masses and the topology are then brought up to date. Returns the
/// number of tets moved (0: nothing changed but the copy).
template <typename Moves>
int32_t SplitNodeAsACut(Model<double>& model, State<double>& state, int32_t mid, Moves moves) {
  const int32_t copy = model.AddNodeCopy(mid, state);
  std::vector<int32_t> touched;
  for (int32_t t = 0; t < model.num_tets(); ++t) {
    Vec3<double> centroid = Vec3<double>::Zero();
    for (int k = 0; k < 4; ++k) centroid += model.rest_position(model.tet_node(t, k)) / 4;
    for (int c = 0; c < 4; ++c) {
      if (model.tet_node(t, c) == mid && moves(centroid)) {
        model.RetargetTet(t, c, copy);
        touched.push_back(t);
      }
    }
  }
  if (touched.empty()) return 0;
  model.RecomputeElements(touched);
  const std::vector<int32_t> split = {mid, copy};
  model.RecomputeNodeMasses(split);
  model.CommitTopology();
  return static_cast<int32_t>(touched.size());
}

/// Whether some Newton iteration of `r` shows quadratic convergence: with
/// residuals scaled by `scale` (N), e₀ < 1e-2 followed by e₁ ≤ 100·e₀².
inline bool HasQuadraticStep(const ImplicitResult& r, double scale) {
  const int kept = std::min(r.newton_iterations, ImplicitResult::kHistory);
  for (int k = 0; k < kept; ++k) {
    const bool last = k + 1 == r.newton_iterations;
    if (!last && k + 1 >= kept) break;  // the next residual was not kept
    const double e0 = r.residual_history[static_cast<size_t>(k)] / scale;
    const double e1 = (last ? r.residual : r.residual_history[static_cast<size_t>(k + 1)]) / scale;
    if (e0 < 1e-2 && e1 <= 100 * e0 * e0) return true;
  }
  return false;
}

/// ‖a − b‖ / ‖b‖ of two vectors of one length.
inline double RelativeDifference(const std::vector<double>& a, const std::vector<double>& b) {
  double d = 0, n = 0;
  for (size_t i = 0; i < a.size(); ++i) {
    d += (a[i] - b[i]) * (a[i] - b[i]);
    n += b[i] * b[i];
  }
  return std::sqrt(d / n);
}

/// The node whose rest position is (x, y, z) to 1 nm, or −1.
inline int32_t FindNode(const Model<double>& model, double x, double y, double z) {
  for (int32_t n = 0; n < model.num_nodes(); ++n) {
    const Vec3<double> r = model.rest_position(n);
    if (std::abs(r(0) - x) < 1e-9 && std::abs(r(1) - y) < 1e-9 && std::abs(r(2) - z) < 1e-9) return n;
  }
  return -1;
}

}  // namespace cutsim::fem::testing
