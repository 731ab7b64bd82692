#include "common/sim/contact_stiffness.h"

#include <algorithm>
#include <cmath>
#include <unordered_map>

#include <Eigen/SparseCholesky>

#include "common/fem/element.h"
#include "common/fem/nodal_pressure.h"
#include "common/fem/tangent.h"

namespace cutsim::sim {
namespace {

template <typename T>
Eigen::Vector3d NodeX(const T* x, int32_t n) {
  const size_t i = 3 * static_cast<size_t>(n);
  return {static_cast<double>(x[i]), static_cast<double>(x[i + 1]), static_cast<double>(x[i + 2])};
}

/// Fills `scratch.unknown` (and `column`) with the free nodes of `nodes`
/// and of the kStiffnessRings rings of elements around them.
template <typename T>
void CollectPatch(const fem::Model<T>& model, const std::array<int32_t, 3>& nodes, PatchScratch& scratch) {
  std::vector<int32_t>& column = scratch.column;
  if (column.size() < static_cast<size_t>(model.node_capacity())) {
    column.assign(static_cast<size_t>(model.node_capacity()), -1);
  }
  std::vector<int32_t>& unknown = scratch.unknown;
  unknown.clear();
  auto visit = [&](int32_t node) {
    if (column[static_cast<size_t>(node)] >= 0 || model.fixed(node)) return;
    column[static_cast<size_t>(node)] = static_cast<int32_t>(unknown.size());
    unknown.push_back(node);
  };
  for (const int32_t node : nodes) visit(node);
  const int32_t* slots = model.incidence_slots();
  size_t ring_begin = 0;
  for (int ring = 0; ring < kStiffnessRings; ++ring) {
    const size_t ring_end = unknown.size();
    for (size_t k = ring_begin; k < ring_end; ++k) {
      const int32_t node = unknown[k];
      for (int32_t s = model.incidence_begin(node); s < model.incidence_end(node); ++s) {
        for (int c = 0; c < 4; ++c) visit(model.tet_node(slots[s] / 12, c));
      }
    }
    ring_begin = ring_end;
  }
}

/// Appends the lower triangle of element `t`'s tangent, on the unknowns
/// among its corners, to `scratch.entries` (SimplicialLDLT reads the lower
/// part; the element tangents are symmetric).
template <typename T>
void AddElementEntries(const fem::Model<T>& model, const T* x, int32_t t, PatchScratch& scratch) {
  std::array<int32_t, 4> local{};  // unknown index of each corner, −1 if held
  for (int c = 0; c < 4; ++c) {
    local[static_cast<size_t>(c)] = scratch.column[static_cast<size_t>(model.tet_node(t, c))];
  }
  const Eigen::Matrix<double, 12, 12> Ke = ElementStiffness(model, x, t);
  for (int cj = 0; cj < 4; ++cj) {
    const int32_t col = local[static_cast<size_t>(cj)];
    if (col < 0) continue;
    for (int ci = 0; ci < 4; ++ci) {
      const int32_t row = local[static_cast<size_t>(ci)];
      if (row < col) continue;  // held (−1) or above the diagonal
      for (int a = 0; a < 3; ++a) {
        for (int b = row == col ? a : 0; b < 3; ++b) {
          scratch.entries.emplace_back(3 * row + b, 3 * col + a, Ke(3 * ci + b, 3 * cj + a));
        }
      }
    }
  }
}

// ---- the nodal-pressure element's volumetric tangent ----------------------
// K_vol = Σ_a (U''(J_a)/V_a)·∇v_a ∇v_aᵀ + Σ_e p̄_e·∂²v_e/∂x² (nodal_pressure.h):
// the first term couples the nodes of a patch, so it has no element matrix.

/// Element t's current F and volume gradient ∂v_e/∂x (3×4, m²).
template <typename T>
fem::Mat34<double> ElementVolumeGradient(const fem::Model<T>& model, const T* x, int32_t t, fem::Mat3<double>* F) {
  fem::Mat34<double> xe;
  for (int c = 0; c < 4; ++c) xe.col(c) = NodeX(x, model.tet_node(t, c));
  const fem::Mat3<double> dm_inv = model.DmInv(t).template cast<double>();
  *F = fem::EdgeMatrix(xe) * dm_inv;
  return fem::VolumeGradient(*F, fem::ShapeGradients(dm_inv), static_cast<double>(model.rest_volume(t)));
}

/// Node a's pressure U'(J_a) (Pa) and patch curvature U''(J_a)/V_a (Pa/m³).
template <typename T>
std::pair<double, double> NodePressure(const fem::Model<T>& model, const T* x, int32_t a) {
  const double rest = static_cast<double>(model.node_rest_volume(a));
  if (!(rest > 0)) return {0.0, 0.0};
  const int32_t* slots = model.incidence_slots();
  double now = 0;
  for (int32_t s = model.incidence_begin(a); s < model.incidence_end(a); ++s) {
    fem::Mat34<double> xe;
    const int32_t t = slots[s] / 12;
    for (int c = 0; c < 4; ++c) xe.col(c) = NodeX(x, model.tet_node(t, c));
    now += 0.25 * static_cast<double>(model.rest_volume(t)) *
           (fem::EdgeMatrix(xe) * model.DmInv(t).template cast<double>()).determinant();
  }
  const double j = now / rest, kappa = static_cast<double>(model.node_kappa(a));
  return {fem::VolumetricPressure(j, kappa), fem::VolumetricModulus(j, kappa) / rest};
}

/// ∇_n v_a = ¼ Σ_{e ∋ a, n} ∂v_e/∂x_n: how node n's motion changes node a's
/// patch volume, m².
template <typename T>
Eigen::Vector3d PatchVolumeGradient(const fem::Model<T>& model, const T* x, int32_t a, int32_t n) {
  const int32_t* slots = model.incidence_slots();
  Eigen::Vector3d g = Eigen::Vector3d::Zero();
  for (int32_t s = model.incidence_begin(a); s < model.incidence_end(a); ++s) {
    const int32_t t = slots[s] / 12;
    for (int c = 0; c < 4; ++c) {
      if (model.tet_node(t, c) != n) continue;
      fem::Mat3<double> F;
      g += 0.25 * ElementVolumeGradient(model, x, t, &F).col(c);
    }
  }
  return g;
}

/// Appends the volumetric tangent's lower triangle on the patch's unknowns
/// to `scratch.entries`: the pressure term of each element in
/// `scratch.tets`, and the patch term of every node of those elements
/// (elements outside them have no unknown corner, so they add nothing).
template <typename T>
void AddNodalPressureEntries(const fem::Model<T>& model, const T* x, PatchScratch& scratch) {
  std::vector<int32_t> corners;
  for (const int32_t t : scratch.tets) {
    for (int c = 0; c < 4; ++c) corners.push_back(model.tet_node(t, c));
  }
  std::sort(corners.begin(), corners.end());
  corners.erase(std::unique(corners.begin(), corners.end()), corners.end());
  std::vector<std::pair<double, double>> pressure(corners.size());
  for (size_t i = 0; i < corners.size(); ++i) pressure[i] = NodePressure(model, x, corners[i]);
  const auto index = [&](int32_t node) {
    return static_cast<size_t>(std::lower_bound(corners.begin(), corners.end(), node) - corners.begin());
  };
  const auto column = [&](int32_t node) { return scratch.column[static_cast<size_t>(node)]; };
  const auto add_block = [&](int32_t row, int32_t col, const Eigen::Matrix3d& b) {
    if (row < col) return;
    for (int r = 0; r < 3; ++r) {
      for (int c = 0; c < 3; ++c) {
        if (row == col && r < c) continue;
        scratch.entries.emplace_back(3 * row + r, 3 * col + c, b(r, c));
      }
    }
  };
  // Each element's volume gradient, once: the patch terms below read it for
  // every node of the element.
  std::unordered_map<int32_t, fem::Mat34<double>> volume_gradient;
  volume_gradient.reserve(scratch.tets.size());
  for (const int32_t t : scratch.tets) {
    double p_bar = 0;
    for (int c = 0; c < 4; ++c) p_bar += 0.25 * pressure[index(model.tet_node(t, c))].first;
    fem::Mat34<double> xe;
    for (int c = 0; c < 4; ++c) xe.col(c) = NodeX(x, model.tet_node(t, c));
    const fem::Mat3<double> dm_inv = model.DmInv(t).template cast<double>();
    const fem::Mat34<double> g = fem::ShapeGradients(dm_inv);
    const fem::Mat3<double> F = fem::EdgeMatrix(xe) * dm_inv;
    volume_gradient.emplace(t, fem::VolumeGradient(F, g, static_cast<double>(model.rest_volume(t))));
    for (int a = 0; a < 4; ++a) {
      for (int b = 0; b < 4; ++b) {
        if (a == b) continue;
        const int32_t ra = column(model.tet_node(t, a)), cb = column(model.tet_node(t, b));
        if (ra < 0 || cb < 0) continue;
        add_block(ra, cb, p_bar * fem::VolumeHessianBlock(F, g.col(a), g.col(b), static_cast<double>(model.rest_volume(t))));
      }
    }
  }
  // Patch terms: ∇v_a on the unknowns, then its outer product.
  const int32_t* slots = model.incidence_slots();
  std::vector<std::pair<int32_t, Eigen::Vector3d>> grad;  // (unknown, ∇v_a block)
  for (size_t i = 0; i < corners.size(); ++i) {
    const double curvature = pressure[i].second;
    if (!(curvature > 0)) continue;
    const int32_t a = corners[i];
    grad.clear();
    for (int32_t s = model.incidence_begin(a); s < model.incidence_end(a); ++s) {
      const int32_t t = slots[s] / 12;
      const auto it = volume_gradient.find(t);
      if (it == volume_gradient.end()) continue;  // no unknown corner: adds nothing
      const fem::Mat34<double>& ge = it->second;
      for (int c = 0; c < 4; ++c) {
        const int32_t col = column(model.tet_node(t, c));
        if (col >= 0) grad.emplace_back(col, 0.25 * ge.col(c));
      }
    }
    // One ∇v_a per unknown (a node of several of a's elements appears once
    // per element above): the outer product then has as many blocks as the
    // patch has node pairs, not element-corner pairs.
    std::sort(grad.begin(), grad.end(), [](const auto& l, const auto& r) { return l.first < r.first; });
    size_t merged = 0;
    for (size_t k = 0; k < grad.size(); ++k) {
      if (merged > 0 && grad[merged - 1].first == grad[k].first) {
        grad[merged - 1].second += grad[k].second;
      } else {
        grad[merged++] = grad[k];
      }
    }
    grad.resize(merged);
    for (const auto& [ci, gi] : grad) {
      for (const auto& [cj, gj] : grad) add_block(ci, cj, curvature * gi * gj.transpose());
    }
  }
}

}  // namespace

template <typename T>
Eigen::Matrix<double, 12, 12> ElementStiffness(const fem::Model<T>& model, const T* x, int32_t t) {
  fem::Mat34<double> xe;
  for (int c = 0; c < 4; ++c) xe.col(c) = NodeX(x, model.tet_node(t, c));
  return fem::StvkElementStiffness<double>(xe, model.DmInv(t).template cast<double>(),
                                           static_cast<double>(model.rest_volume(t)),
                                           static_cast<double>(model.element_lambdas()[t]),
                                           static_cast<double>(model.mus()[t]));
}

template <typename T>
double NodeNormalStiffness(const fem::Model<T>& model, const T* x, int32_t node, const Eigen::Vector3d& n) {
  const int32_t* slots = model.incidence_slots();
  double k = 0;
  for (int32_t s = model.incidence_begin(node); s < model.incidence_end(node); ++s) {
    const int corner = (slots[s] % 12) / 3;
    k += n.dot(ElementStiffness(model, x, slots[s] / 12).template block<3, 3>(3 * corner, 3 * corner) * n);
  }
  if (model.element() == fem::ElementKind::kNodalPressure) {
    // Σ_a (U''(J_a)/V_a)·(n·∇_node v_a)² over the nodes sharing an element
    // with `node` (the pressure term's diagonal blocks vanish).
    std::vector<int32_t> neighbours;
    for (int32_t s = model.incidence_begin(node); s < model.incidence_end(node); ++s) {
      for (int c = 0; c < 4; ++c) neighbours.push_back(model.tet_node(slots[s] / 12, c));
    }
    std::sort(neighbours.begin(), neighbours.end());
    neighbours.erase(std::unique(neighbours.begin(), neighbours.end()), neighbours.end());
    for (const int32_t a : neighbours) {
      const double along = n.dot(PatchVolumeGradient(model, x, a, node));
      k += NodePressure(model, x, a).second * along * along;
    }
  }
  return k;
}

template <typename T>
double SolvePatchCompliance(const fem::Model<T>& model, const T* x, const std::array<int32_t, 3>& nodes,
                            const Eigen::Vector3d& w, const Eigen::Vector3d& u, PatchScratch& scratch) {
  model.IncidentTets(scratch.unknown, scratch.tets);
  scratch.entries.clear();
  for (const int32_t t : scratch.tets) AddElementEntries(model, x, t, scratch);
  if (model.element() == fem::ElementKind::kNodalPressure) AddNodalPressureEntries(model, x, scratch);
  const int n = 3 * static_cast<int>(scratch.unknown.size());
  Eigen::SparseMatrix<double> K(n, n);
  K.setFromTriplets(scratch.entries.begin(), scratch.entries.end());
  Eigen::VectorXd f = Eigen::VectorXd::Zero(n);
  for (int i = 0; i < 3; ++i) {
    const int32_t col = scratch.column[static_cast<size_t>(nodes[static_cast<size_t>(i)])];
    if (col >= 0) f.segment<3>(3 * col) = w[i] * u;
  }
  Eigen::SimplicialLDLT<Eigen::SparseMatrix<double>> solver(K);
  if (solver.info() != Eigen::Success) return 0.0;
  const double compliance = f.dot(solver.solve(f));
  return solver.info() == Eigen::Success && std::isfinite(compliance) && compliance > 0 ? 1.0 / compliance : 0.0;
}

template <typename T>
double PatchStiffness(const fem::Model<T>& model, const T* x, const std::array<int32_t, 3>& nodes,
                      const Eigen::Vector3d& w, const Eigen::Vector3d& u, PatchScratch& scratch) {
  CollectPatch(model, nodes, scratch);
  const double k_tissue = scratch.unknown.empty() ? 0.0 : SolvePatchCompliance(model, x, nodes, w, u, scratch);
  for (const int32_t node : scratch.unknown) scratch.column[static_cast<size_t>(node)] = -1;
  if (k_tissue > 0) return k_tissue;
  double k_diagonal = 0;
  for (int i = 0; i < 3; ++i) k_diagonal += w[i] * NodeNormalStiffness(model, x, nodes[static_cast<size_t>(i)], u);
  return std::max(k_diagonal, 0.0);
}

double SeriesStiffness(double k_contact, double k_tissue) {
  return (k_contact + k_tissue) > 0 ? k_contact * k_tissue / (k_contact + k_tissue) : 0.0;
}

#define CUTSIM_SIM_STIFFNESS_INSTANTIATE(T)                                                                       \
  template Eigen::Matrix<double, 12, 12> ElementStiffness<T>(const fem::Model<T>&, const T*, int32_t);            \
  template double NodeNormalStiffness<T>(const fem::Model<T>&, const T*, int32_t, const Eigen::Vector3d&);        \
  template double SolvePatchCompliance<T>(const fem::Model<T>&, const T*, const std::array<int32_t, 3>&,          \
                                          const Eigen::Vector3d&, const Eigen::Vector3d&, PatchScratch&);         \
  template double PatchStiffness<T>(const fem::Model<T>&, const T*, const std::array<int32_t, 3>&,                \
                                    const Eigen::Vector3d&, const Eigen::Vector3d&, PatchScratch&);

CUTSIM_SIM_STIFFNESS_INSTANTIATE(float)
CUTSIM_SIM_STIFFNESS_INSTANTIATE(double)

}  // namespace cutsim::sim
