#include "common/fem/model.h"

#include <algorithm>
#include <cmath>
#include <string>

#include "common/core/error.h"
#include "common/fem/state.h"

namespace cutsim::fem {

Material Material::FromYoungPoisson(double youngs_modulus, double poisson_ratio, double density,
                                    double psi, double phi) {
  const double nu = poisson_ratio;
  Material m;
  m.lambda = youngs_modulus * nu / ((1.0 + nu) * (1.0 - 2.0 * nu));
  m.mu = youngs_modulus / (2.0 * (1.0 + nu));
  m.psi = psi;
  m.phi = phi;
  m.density = density;
  return m;
}

namespace {

void ValidateMaterial(const Material& m, const std::string& source, int64_t index) {
  const SourceRef ref{.file = source, .field = "materials[" + std::to_string(index) + "]"};
  const bool finite = std::isfinite(m.lambda) && std::isfinite(m.mu) && std::isfinite(m.psi) &&
                      std::isfinite(m.phi) && std::isfinite(m.density);
  if (!finite) ThrowInputError(ref, "material has a non-finite parameter");
  if (!(m.mu > 0)) ThrowInputError(ref, "shear modulus mu must be > 0 Pa");
  // Strong ellipticity of the linearised material: 3λ + 2μ > 0 (ν > −1).
  if (!(3 * m.lambda + 2 * m.mu > 0)) ThrowInputError(ref, "need 3*lambda + 2*mu > 0");
  if (m.psi < 0 || m.phi < 0 || !(3 * m.phi + 2 * m.psi >= 0)) {
    ThrowInputError(ref, "damping psi, phi must be >= 0 Pa*s");
  }
  if (!(m.density > 0)) ThrowInputError(ref, "density must be > 0 kg/m^3");
}

}  // namespace

template <typename T>
Model<T>::Model(const mesh::TetMesh& mesh, std::span<const Material> materials,
                const ModelOptions& options) {
  const std::string& src = options.source;
  num_nodes_ = mesh.num_nodes();
  num_tets_ = mesh.num_tets();
  if (num_tets_ <= 0) ThrowInputError({.file = src, .field = "tets"}, "mesh has no tetrahedra");
  node_capacity_ = std::max(num_nodes_, options.node_capacity);
  padded_tets_ = (num_tets_ + kBlock - 1) / kBlock * kBlock;
  for (int32_t n = 0; n < num_nodes_; ++n) {
    if (!mesh.nodes.row(n).allFinite()) {
      ThrowInputError({.file = src, .field = "node " + std::to_string(n + 1)},
                      "node coordinate is NaN or infinite (after mesh.scale and mesh.translate)");
    }
  }
  // Material per tet.
  const bool per_region = !mesh.regions.empty() && materials.size() != 1 &&
                          std::ssize(materials) != num_tets_;
  if (materials.empty()) ThrowInputError({.file = src, .field = "materials"}, "no material given");
  if (!mesh.regions.empty() && std::ssize(mesh.regions) != num_tets_) {
    ThrowInputError({.file = src, .field = "regions"}, "regions must have one entry per tet");
  }
  if (!per_region && materials.size() != 1 && std::ssize(materials) != num_tets_) {
    ThrowInputError({.file = src, .field = "materials"},
                    "need 1 material, one per tet, or one per region (" +
                        std::to_string(materials.size()) + " given for " +
                        std::to_string(num_tets_) + " tets)");
  }
  for (size_t i = 0; i < materials.size(); ++i) {
    ValidateMaterial(materials[i], src, static_cast<int64_t>(i));
  }

  const auto P = static_cast<size_t>(padded_tets_);
  const auto NC = static_cast<size_t>(node_capacity_);
  rest_.assign(3 * NC, T(0));
  tets_.assign(4 * P, 0);
  dm_inv_.assign(9 * P, T(0));
  volume_.assign(P, T(0));
  grad_sq_max_.assign(P, T(0));
  lambda_.assign(P, T(0));
  mu_.assign(P, T(0));
  element_lambda_.assign(P, T(0));
  kappa_.assign(P, T(0));
  node_volume_.assign(NC, T(0));
  node_kappa_.assign(NC, T(0));
  element_ = options.element;
  psi_.assign(P, T(0));
  phi_.assign(P, T(0));
  element_mass_.assign(P, T(0));
  node_mass_.assign(NC, T(0));
  fixed_.assign(NC, 0);
  prescribed_force_.assign(3 * NC, T(0));
  inc_range_.assign(2 * NC, 0);
  // Append region for cut edits: half the compact size again (≥ 1024), so a
  // compaction is paid for by at least 2·T retargeted corners.
  inc_slots_.assign(4 * static_cast<size_t>(num_tets_) + std::max<size_t>(1024, 2 * static_cast<size_t>(num_tets_)), 0);
  gravity_ = options.gravity.cast<T>();
  inversion_det_threshold_ = static_cast<T>(options.inversion_det_threshold);
  min_singular_value_ = static_cast<T>(options.min_singular_value);

  for (int32_t n = 0; n < num_nodes_; ++n) {
    for (int d = 0; d < 3; ++d) rest_[3 * n + d] = static_cast<T>(mesh.nodes(n, d));
  }
  for (int32_t t = 0; t < num_tets_; ++t) {
    for (int c = 0; c < 4; ++c) {
      const int32_t node = mesh.tets(t, c);
      if (node < 0 || node >= num_nodes_) {
        ThrowInputError({.file = src, .field = "tet " + std::to_string(t + 1)},
                        "node index " + std::to_string(node) + " out of range [0, " +
                            std::to_string(num_nodes_) + ")");
      }
      tets_[4 * t + c] = node;
    }
    const Material& m = materials.size() == 1            ? materials[0]
                        : per_region                     ? Material{}
                                                         : materials[static_cast<size_t>(t)];
    Material mat = m;
    if (per_region) {
      const int32_t r = mesh.regions[static_cast<size_t>(t)];
      if (r < 0 || r >= std::ssize(materials)) {
        ThrowInputError({.file = src, .field = "region of tet " + std::to_string(t + 1)},
                        "region " + std::to_string(r) + " has no material");
      }
      mat = materials[static_cast<size_t>(r)];
    }
    lambda_[t] = static_cast<T>(mat.lambda);
    mu_[t] = static_cast<T>(mat.mu);
    kappa_[t] = static_cast<T>(mat.lambda + 2.0 / 3.0 * mat.mu);
    element_lambda_[t] = element_ == ElementKind::kNodalPressure ? static_cast<T>(-2.0 / 3.0 * mat.mu)
                                                                 : static_cast<T>(mat.lambda);
    psi_[t] = static_cast<T>(mat.psi);
    phi_[t] = static_cast<T>(mat.phi);
    damped_ = damped_ || mat.psi != 0 || mat.phi != 0;
    bool degenerate = false;
    ComputeElement(t, &degenerate);
    if (degenerate) {
      ThrowInputError({.file = src, .field = "tet " + std::to_string(t + 1)},
                      "tetrahedron has non-positive volume (inverted or degenerate), or a volume outside floating "
                      "point range (check mesh.scale)");
    }
    // Mass frozen at load: ρ·vol (docs/DESIGN.md), computed in double.
    element_mass_[t] = static_cast<T>(mat.density * mesh::SignedVolume(mesh, t));
  }
  RebuildIncidence();
  inc_compactions_ = 0;
  std::vector<int32_t> all(static_cast<size_t>(num_nodes_));
  for (int32_t n = 0; n < num_nodes_; ++n) all[static_cast<size_t>(n)] = n;
  RecomputeNodeMasses(all);
  topology_version_ = 0;
}

template <typename T>
Mat3<T> Model<T>::DmInv(int32_t t) const {
  Mat3<T> m;
  for (int k = 0; k < 9; ++k) m(k / 3, k % 3) = dm_inv_[static_cast<size_t>(k * padded_tets_ + t)];
  return m;
}

template <typename T>
void Model<T>::ComputeElement(int32_t t, bool* degenerate) {
  // In double: Dm⁻¹ of a thin element loses digits fast in float.
  Eigen::Matrix3d Dm;
  const Eigen::Vector3d u0 = rest_position(tets_[4 * t]).template cast<double>();
  for (int c = 0; c < 3; ++c) {
    Dm.col(c) = rest_position(tets_[4 * t + c + 1]).template cast<double>() - u0;
  }
  const double vol = Dm.determinant() / 6.0;
  // Relative degeneracy test: volume against the cube of the longest edge.
  const double h = Dm.colwise().norm().maxCoeff();
  *degenerate = !(vol > 1e-12 * h * h * h) || !std::isfinite(vol);
  Eigen::Matrix3d inv = Eigen::Matrix3d::Zero();
  double g = 0;
  if (!*degenerate) {
    inv = Dm.inverse();
    // GᵀG = Dm⁻ᵀ(I + 11ᵀ)Dm⁻¹ for G = [−1ᵀDm⁻¹; Dm⁻¹] (4×3).
    const Eigen::Matrix3d GtG =
        inv.transpose() * (Eigen::Matrix3d::Identity() + Eigen::Matrix3d::Ones()) * inv;
    Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> es;
    es.computeDirect(GtG, Eigen::EigenvaluesOnly);
    g = es.eigenvalues()(2);
  }
  for (int k = 0; k < 9; ++k) {
    dm_inv_[static_cast<size_t>(k * padded_tets_ + t)] = static_cast<T>(inv(k / 3, k % 3));
  }
  volume_[t] = *degenerate ? T(0) : static_cast<T>(vol);
  grad_sq_max_[t] = static_cast<T>(g);
}

template <typename T>
double Model<T>::TotalMass() const {
  double m = 0;
  for (int32_t n = 0; n < num_nodes_; ++n) m += static_cast<double>(node_mass_[n]);
  return m;
}

template <typename T>
void Model<T>::SetFixed(int32_t node, bool fixed) {
  CUTSIM_CHECK(node >= 0 && node < num_nodes_, "SetFixed: node out of range");
  fixed_[node] = fixed ? 1 : 0;
}

template <typename T>
void Model<T>::SetPrescribedForce(int32_t node, const Vec3<T>& f) {
  CUTSIM_CHECK(node >= 0 && node < num_nodes_, "SetPrescribedForce: node out of range");
  for (int d = 0; d < 3; ++d) prescribed_force_[3 * node + d] = f(d);
}

template <typename T>
void Model<T>::reserve_nodes(int32_t capacity) {
  if (capacity <= node_capacity_) return;
  node_capacity_ = capacity;
  const auto NC = static_cast<size_t>(capacity);
  rest_.resize(3 * NC, T(0));
  node_mass_.resize(NC, T(0));
  node_volume_.resize(NC, T(0));
  node_kappa_.resize(NC, T(0));
  fixed_.resize(NC, 0);
  prescribed_force_.resize(3 * NC, T(0));
  inc_range_.resize(2 * NC, inc_tail_);
}

template <typename T>
int32_t Model<T>::AddNodeCopy(int32_t node, State<T>& state) {
  CUTSIM_CHECK(node >= 0 && node < num_nodes_, "AddNodeCopy: node out of range");
  CUTSIM_CHECK(num_nodes_ < node_capacity_, "AddNodeCopy: node capacity exhausted (reserve_nodes)");
  CUTSIM_CHECK(std::ssize(state.x) >= 3 * static_cast<int64_t>(node_capacity_),
               "AddNodeCopy: state was created before reserve_nodes");
  const int32_t n = num_nodes_++;
  for (int d = 0; d < 3; ++d) {
    rest_[3 * n + d] = rest_[3 * node + d];
    prescribed_force_[3 * n + d] = T(0);  // a load is not duplicated (it would double)
    state.x[3 * n + d] = state.x[3 * node + d];
    state.v[3 * n + d] = state.v[3 * node + d];
    state.f[3 * n + d] = T(0);
    state.f_ext[3 * n + d] = T(0);
  }
  fixed_[n] = fixed_[node];
  node_mass_[n] = T(0);
  node_volume_[n] = node_kappa_[n] = T(0);
  inc_range_[2 * n] = inc_range_[2 * n + 1] = inc_tail_;  // empty range
  topology_dirty_ = true;
  return n;
}

template <typename T>
void Model<T>::RetargetTet(int32_t t, int corner, int32_t new_node) {
  CUTSIM_CHECK(t >= 0 && t < num_tets_ && corner >= 0 && corner < 4, "RetargetTet: bad tet/corner");
  CUTSIM_CHECK(new_node >= 0 && new_node < num_nodes_, "RetargetTet: node out of range");
  const int32_t old_node = tets_[4 * t + corner];
  tets_[4 * t + corner] = new_node;
  topology_dirty_ = true;
  if (old_node == new_node) return;
  const int32_t slot = 12 * t + 3 * corner;
  RemoveIncidence(old_node, slot);
  AddIncidence(new_node, slot);
}

template <typename T>
void Model<T>::SetRestPosition(int32_t node, const Vec3<T>& p) {
  CUTSIM_CHECK(node >= 0 && node < num_nodes_, "SetRestPosition: node out of range");
  for (int d = 0; d < 3; ++d) rest_[3 * node + d] = p(d);
}

template <typename T>
int Model<T>::RecomputeElements(std::span<const int32_t> tets) {
  int degenerate_count = 0;
  for (const int32_t t : tets) {
    CUTSIM_CHECK(t >= 0 && t < num_tets_, "RecomputeElements: tet out of range");
    bool degenerate = false;
    ComputeElement(t, &degenerate);
    degenerate_count += degenerate ? 1 : 0;
  }
  if (element_ == ElementKind::kNodalPressure) {
    for (const int32_t t : tets) {
      for (int c = 0; c < 4; ++c) RecomputeNodeVolume(tets_[4 * t + c]);
    }
  }
  return degenerate_count;
}

template <typename T>
void Model<T>::IncidentTets(std::span<const int32_t> nodes, std::vector<int32_t>& out) const {
  out.clear();
  for (const int32_t n : nodes) {
    for (int32_t k = inc_range_[2 * n]; k < inc_range_[2 * n + 1]; ++k) out.push_back(inc_slots_[k] / 12);
  }
  std::sort(out.begin(), out.end());
  out.erase(std::unique(out.begin(), out.end()), out.end());
}

template <typename T>
void Model<T>::RecomputeNodeMasses(std::span<const int32_t> nodes) {
  if (topology_dirty_) CommitTopology();  // O(1): the incidence is already current
  for (const int32_t n : nodes) {
    CUTSIM_CHECK(n >= 0 && n < num_nodes_, "RecomputeNodeMasses: node out of range");
    // Sum in double so repeated splits keep Σ node mass = Σ element mass.
    double m = 0;
    for (int32_t k = inc_range_[2 * n]; k < inc_range_[2 * n + 1]; ++k) {
      m += static_cast<double>(element_mass_[inc_slots_[k] / 12]) / 4.0;
    }
    node_mass_[n] = static_cast<T>(m);
    if (element_ == ElementKind::kNodalPressure) RecomputeNodeVolume(n);
  }
}

template <typename T>
void Model<T>::RecomputeNodeVolume(int32_t n) {
  double volume = 0, kappa_volume = 0;
  for (int32_t k = inc_range_[2 * n]; k < inc_range_[2 * n + 1]; ++k) {
    const int32_t t = inc_slots_[k] / 12;
    const double v = 0.25 * static_cast<double>(volume_[t]);
    volume += v;
    kappa_volume += v * static_cast<double>(kappa_[t]);
  }
  node_volume_[n] = static_cast<T>(volume);
  node_kappa_[n] = volume > 0 ? static_cast<T>(kappa_volume / volume) : T(0);
}

template <typename T>
void Model<T>::CommitTopology() {
  topology_dirty_ = false;
  ++topology_version_;
}

template <typename T>
void Model<T>::RemoveIncidence(int32_t node, int32_t slot) {
  // In place, keeping the range ascending: O(degree).
  int32_t* begin = inc_slots_.data() + inc_range_[2 * node];
  int32_t* end = inc_slots_.data() + inc_range_[2 * node + 1];
  int32_t* at = std::find(begin, end, slot);
  CUTSIM_CHECK(at != end, "incidence: slot missing from its node");
  std::copy(at + 1, end, at);
  --inc_range_[2 * node + 1];
}

template <typename T>
void Model<T>::AddIncidence(int32_t node, int32_t slot) {
  const int32_t begin = inc_range_[2 * node], end = inc_range_[2 * node + 1];
  const int32_t degree = end - begin;
  const auto capacity = static_cast<int32_t>(inc_slots_.size());
  if (end != inc_tail_) {
    // Not at the tail: move the range there so it can grow.
    if (inc_tail_ + degree + 1 > capacity) {
      RebuildIncidence();  // tets_ already holds the new corner
      return;
    }
    std::copy(inc_slots_.begin() + begin, inc_slots_.begin() + end, inc_slots_.begin() + inc_tail_);
    inc_range_[2 * node] = inc_tail_;
    inc_range_[2 * node + 1] = inc_tail_ + degree;
    inc_tail_ += degree;
  } else if (inc_tail_ + 1 > capacity) {
    RebuildIncidence();
    return;
  }
  // Insert sorted (ascending slots: the gather reads element forces in order).
  int32_t* first = inc_slots_.data() + inc_range_[2 * node];
  int32_t* last = inc_slots_.data() + inc_range_[2 * node + 1];
  int32_t* at = std::upper_bound(first, last, slot);
  std::copy_backward(at, last, last + 1);
  *at = slot;
  ++inc_range_[2 * node + 1];
  ++inc_tail_;
}

template <typename T>
void Model<T>::RebuildIncidence() {
  // Counting sort of the 4·T (tet, corner) slots by node: no allocation,
  // and each node's slots come out in increasing tet order (cache friendly).
  // Ends are counted in the end entries, then turned into begins.
  for (int32_t n = 0; n < num_nodes_; ++n) inc_range_[2 * n + 1] = 0;
  for (int32_t t = 0; t < num_tets_; ++t) {
    for (int c = 0; c < 4; ++c) ++inc_range_[2 * tets_[4 * t + c] + 1];
  }
  int32_t running = 0;
  for (int32_t n = 0; n < num_nodes_; ++n) {
    const int32_t degree = inc_range_[2 * n + 1];
    inc_range_[2 * n] = inc_range_[2 * n + 1] = running;  // end advances as slots are placed
    running += degree;
  }
  for (int32_t t = 0; t < num_tets_; ++t) {
    for (int c = 0; c < 4; ++c) {
      const int32_t n = tets_[4 * t + c];
      inc_slots_[static_cast<size_t>(inc_range_[2 * n + 1]++)] = 12 * t + 3 * c;
    }
  }
  inc_tail_ = running;
  for (int32_t n = num_nodes_; n < node_capacity_; ++n) inc_range_[2 * n] = inc_range_[2 * n + 1] = inc_tail_;
  ++inc_compactions_;
}

template <typename T>
State<T>::State(const Model<T>& model) {
  const auto NC = 3 * static_cast<size_t>(model.node_capacity());
  x.assign(NC, T(0));
  for (int32_t n = 0; n < model.num_nodes(); ++n) {
    for (int d = 0; d < 3; ++d) x[static_cast<size_t>(3 * n + d)] = model.rest_positions()[3 * n + d];
  }
  v.assign(NC, T(0));
  f.assign(NC, T(0));
  f_ext.assign(NC, T(0));
  v_star.assign(NC, T(0));
  cg_r.assign(NC, T(0));
  cg_p.assign(NC, T(0));
  cg_q.assign(NC, T(0));
  cg_precond.assign(2 * NC, T(0));
  viscous_dv.assign(NC, T(0));
  lanczos_prev.assign(NC, T(0));
  lanczos_q.assign(NC, T(0));
  lanczos_w.assign(NC, T(0));
  lanczos_x.assign(NC, T(0));
  lanczos_f0.assign(NC, T(0));
  element_force.assign(12 * static_cast<size_t>(model.padded_tets()), T(0));
  node_pressure.assign(static_cast<size_t>(model.node_capacity()), T(0));
  element_dt.assign(static_cast<size_t>(model.padded_tets()), std::numeric_limits<T>::infinity());
  element_dt_at_spectral.assign(static_cast<size_t>(model.padded_tets()), std::numeric_limits<T>::infinity());
  dt_leaves = 1;
  while (dt_leaves < model.padded_tets()) dt_leaves *= 2;
  dt_tree.assign(2 * static_cast<size_t>(dt_leaves), std::numeric_limits<T>::infinity());
}

template class Model<float>;
template class Model<double>;
template struct State<float>;
template struct State<double>;

}  // namespace cutsim::fem
