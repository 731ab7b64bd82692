#pragma once
/// @file
/// `fem::Model<T>`: the rest state of a tetrahedral StVK body in flat
/// structure-of-arrays form (MuJoCo's mjModel role). Positions, velocities,
/// forces and scratch live in `fem::State<T>` (state.h).
///
/// Mass (docs/DESIGN.md): each element's mass ρ·vol is frozen at load; a node's
/// mass is the sum of a quarter of each incident element's mass. Cutting moves
/// rest coordinates and recomputes Dm⁻¹ and volume (stiffness) but never mass,
/// and split nodes share their elements' masses, so total mass is exact.
///
/// Topology edits (cutting) go through AddNodeCopy / RetargetTet /
/// SetRestPosition, then RecomputeElements / RecomputeNodeMasses, then
/// CommitTopology (which bumps topology_version()).

#include <cstdint>
#include <span>
#include <string>
#include <vector>

#include <Eigen/Core>

#include "common/fem/element.h"
#include "common/mesh/tet_mesh.h"

namespace cutsim::fem {

/// An isotropic StVK material with O'Brien–Hodgins strain-rate damping.
struct Material {
  double lambda = 0;        ///< First Lamé parameter λ, Pa.
  double mu = 0;            ///< Shear modulus μ, Pa.
  double psi = 0;           ///< Viscous shear coefficient ψ, Pa·s.
  double phi = 0;           ///< Viscous dilatation coefficient φ, Pa·s.
  double density = 1000.0;  ///< ρ, kg/m³.

  /// From Young's modulus E (Pa) and Poisson's ratio ν.
  static Material FromYoungPoisson(double youngs_modulus, double poisson_ratio, double density,
                                   double psi = 0, double phi = 0);
};

/// The element formulation.
enum class ElementKind : uint8_t {
  /// Linear tet, StVK per element. Locks as ν → ½.
  kLinear,
  /// Average nodal pressure (nodal_pressure.h): μ|dev E|² per element (the
  /// StVK kernel with λ = −2μ/3) and the volumetric energy on the nodes, from
  /// each node patch's volume ratio. Nearly incompressible tissue without
  /// locking. Both integrators: the explicit force kernel (forces.h) and the
  /// implicit step (implicit.h).
  kNodalPressure,
};

struct ModelOptions {
  ElementKind element = ElementKind::kLinear;
  /// Nodes reserved for cutting (AddNodeCopy); 0 means exactly the mesh's.
  int32_t node_capacity = 0;
  /// Gravity, m/s².
  Eigen::Vector3d gravity = Eigen::Vector3d::Zero();
  /// det F below which an element switches to the invertible StVK of Irving
  /// et al. (element.h). Above it the force is plain StVK, bit for bit.
  double inversion_det_threshold = 0.3;
  /// Singular-value clamp of the invertible path.
  double min_singular_value = 0.3;
  /// Source name used in input errors (the mesh file, if any).
  std::string source = "mesh";
};

template <typename T>
struct State;

template <typename T>
class Model {
 public:
  /// Elements are processed in SIMD blocks of this many; element arrays are
  /// padded to a multiple of it with inert elements (zero volume).
  static constexpr int kBlock = 8;

  /// Builds the model. `materials` holds one entry (whole body), one per tet,
  /// or one per region (when `mesh.regions` is set). Throws `InputError`
  /// naming the tet or material for NaN coordinates, bad indices, non-positive
  /// volume or an invalid material.
  Model(const mesh::TetMesh& mesh, std::span<const Material> materials,
        const ModelOptions& options = {});

  // ---- sizes ---------------------------------------------------------------
  [[nodiscard]] int32_t num_nodes() const { return num_nodes_; }
  [[nodiscard]] int32_t node_capacity() const { return node_capacity_; }
  [[nodiscard]] int32_t num_tets() const { return num_tets_; }
  /// num_tets() rounded up to kBlock; the length of every per-tet array.
  [[nodiscard]] int32_t padded_tets() const { return padded_tets_; }

  // ---- rest geometry -------------------------------------------------------
  [[nodiscard]] const T* rest_positions() const { return rest_.data(); }  // #N×3
  [[nodiscard]] Vec3<T> rest_position(int32_t n) const {
    return {rest_[3 * n], rest_[3 * n + 1], rest_[3 * n + 2]};
  }
  [[nodiscard]] const int32_t* tets() const { return tets_.data(); }  // #T_pad×4
  [[nodiscard]] int32_t tet_node(int32_t t, int corner) const { return tets_[4 * t + corner]; }
  /// Component k = 3·row + col of Dm⁻¹ for all tets.  // #T_pad
  [[nodiscard]] const T* dm_inv(int k) const { return dm_inv_.data() + k * padded_tets_; }
  [[nodiscard]] Mat3<T> DmInv(int32_t t) const;
  [[nodiscard]] const T* rest_volumes() const { return volume_.data(); }  // #T_pad, m³
  [[nodiscard]] T rest_volume(int32_t t) const { return volume_[t]; }
  /// λ_max(GᵀG), G = [−1ᵀDm⁻¹; Dm⁻¹] the shape-function gradients, 1/m²;
  /// enters the stable-time-step bound.
  [[nodiscard]] T grad_sq_max(int32_t t) const { return grad_sq_max_[t]; }

  // ---- material ------------------------------------------------------------
  [[nodiscard]] const T* lambdas() const { return lambda_.data(); }  // #T_pad, Pa
  [[nodiscard]] ElementKind element() const { return element_; }
  /// The λ the element kernels use: the material's for kLinear, −2μ/3 for
  /// kNodalPressure (the element then carries μ|dev E|² only). The
  /// material's λ (lambdas()) still sets wave speeds and the stable step.
  [[nodiscard]] const T* element_lambdas() const { return element_lambda_.data(); }  // #T_pad, Pa
  /// Bulk modulus κ = λ + 2μ/3 per tet, Pa.  // #T_pad
  [[nodiscard]] const T* kappas() const { return kappa_.data(); }
  /// kNodalPressure: a node's patch rest volume V_a = Σ_{e∋a} V_e/4 (m³) and
  /// volume-weighted bulk modulus κ_a (Pa), kept current through cuts
  /// (RecomputeElements, RecomputeNodeMasses); zero for kLinear.
  [[nodiscard]] T node_rest_volume(int32_t n) const { return node_volume_[n]; }
  [[nodiscard]] T node_kappa(int32_t n) const { return node_kappa_[n]; }
  [[nodiscard]] const T* mus() const { return mu_.data(); }          // #T_pad, Pa
  [[nodiscard]] const T* psis() const { return psi_.data(); }        // #T_pad, Pa·s
  [[nodiscard]] const T* phis() const { return phi_.data(); }        // #T_pad, Pa·s
  /// True if any element has ψ ≠ 0 or φ ≠ 0; otherwise no damping work is done.
  [[nodiscard]] bool damped() const { return damped_; }
  [[nodiscard]] T inversion_det_threshold() const { return inversion_det_threshold_; }
  [[nodiscard]] T min_singular_value() const { return min_singular_value_; }

  // ---- mass ----------------------------------------------------------------
  /// ρ·vol at load time, frozen, kg.  // #T_pad
  [[nodiscard]] T element_mass(int32_t t) const { return element_mass_[t]; }
  [[nodiscard]] const T* node_masses() const { return node_mass_.data(); }  // #N, kg
  [[nodiscard]] T node_mass(int32_t n) const { return node_mass_[n]; }
  [[nodiscard]] double TotalMass() const;

  // ---- loads and boundary conditions --------------------------------------
  void SetFixed(int32_t node, bool fixed);
  [[nodiscard]] bool fixed(int32_t node) const { return fixed_[node] != 0; }
  [[nodiscard]] const uint8_t* fixed_mask() const { return fixed_.data(); }  // #N
  void SetGravity(const Vec3<T>& g) { gravity_ = g; }
  [[nodiscard]] const Vec3<T>& gravity() const { return gravity_; }
  /// A constant nodal force (N), e.g. a traction load of a scene.
  void SetPrescribedForce(int32_t node, const Vec3<T>& f);
  [[nodiscard]] const T* prescribed_forces() const { return prescribed_force_.data(); }  // #N×3

  // ---- node → element incidence ------------------------------------------
  /// Entries of node n are slots [ranges[2n], ranges[2n+1]) of
  /// incidence_slots(); a slot is 12·t + 3·corner, the node's place in the
  /// #T×12 element-force buffer. Built compact (CSR order, ascending tets);
  /// cutting edits it locally: RetargetTet removes the slot from the old
  /// node's range in place and moves the new node's range to an append
  /// region at the end of the slot array (O(degree)). When that region is
  /// full the whole array is compacted again (O(T), amortised over ≥ T/2
  /// retargets).
  [[nodiscard]] const int32_t* incidence_ranges() const { return inc_range_.data(); }  // #N_cap×2
  [[nodiscard]] const int32_t* incidence_slots() const { return inc_slots_.data(); }   // 4·#T + slack
  [[nodiscard]] int32_t incidence_begin(int32_t n) const { return inc_range_[2 * n]; }
  [[nodiscard]] int32_t incidence_end(int32_t n) const { return inc_range_[2 * n + 1]; }
  /// Every element with a corner in `nodes`, once, ascending, into `out`
  /// (cleared first; no allocation once `out` is large enough).
  void IncidentTets(std::span<const int32_t> nodes, std::vector<int32_t>& out) const;
  /// How many times the incidence was compacted since construction.
  [[nodiscard]] int64_t incidence_compactions() const { return inc_compactions_; }
  [[nodiscard]] bool topology_dirty() const { return topology_dirty_; }
  [[nodiscard]] uint64_t topology_version() const { return topology_version_; }

  // ---- mutations for cutting ----------------------------------------------
  /// Raises node capacity. States created before must be re-created (they
  /// are sized by capacity). Allocates; not for the step loop.
  void reserve_nodes(int32_t capacity);
  /// Duplicates `node` (rest position, fixed flag, prescribed force; x and v
  /// in `state`). The copy has zero mass until RecomputeNodeMasses. Returns
  /// the new node's index. Requires capacity.
  int32_t AddNodeCopy(int32_t node, State<T>& state);
  /// Makes corner `corner` of tet `t` refer to `new_node`.
  void RetargetTet(int32_t t, int corner, int32_t new_node);
  void SetRestPosition(int32_t node, const Vec3<T>& p);
  /// Recomputes Dm⁻¹, rest volume and grad_sq_max of `tets` from the current
  /// rest positions. Element masses stay frozen. An element whose rest volume
  /// became non-positive (a degenerate cut) gets zero stiffness (vol = 0,
  /// Dm⁻¹ = 0) so it can never produce NaN; returns how many did. With
  /// kNodalPressure the patch rest volumes of the tets' nodes follow.
  int RecomputeElements(std::span<const int32_t> tets);
  /// node mass = Σ element_mass/4 over the node's incident tets (commits
  /// the topology first if it is dirty); with kNodalPressure also the node's
  /// patch rest volume and bulk modulus.
  void RecomputeNodeMasses(std::span<const int32_t> nodes);
  /// Ends a batch of RetargetTet/AddNodeCopy: bumps topology_version(). The
  /// incidence is already current (kept up to date locally, see above).
  void CommitTopology();

 private:
  void ComputeElement(int32_t t, bool* degenerate);
  void RecomputeNodeVolume(int32_t n);
  void RebuildIncidence();
  void RemoveIncidence(int32_t node, int32_t slot);
  void AddIncidence(int32_t node, int32_t slot);

  int32_t num_nodes_ = 0;
  int32_t node_capacity_ = 0;
  int32_t num_tets_ = 0;
  int32_t padded_tets_ = 0;
  std::vector<T> rest_;            // #N_cap×3, m
  std::vector<int32_t> tets_;      // #T_pad×4
  std::vector<T> dm_inv_;          // 9×#T_pad, component-major (SIMD loads)
  std::vector<T> volume_;          // #T_pad, m³
  std::vector<T> grad_sq_max_;     // #T_pad, 1/m²
  std::vector<T> lambda_, mu_;     // #T_pad, Pa
  std::vector<T> element_lambda_;  // #T_pad, Pa
  std::vector<T> kappa_;           // #T_pad, Pa
  std::vector<T> node_volume_;     // #N_cap, m³ (kNodalPressure)
  std::vector<T> node_kappa_;      // #N_cap, Pa (kNodalPressure)
  ElementKind element_ = ElementKind::kLinear;
  std::vector<T> psi_, phi_;       // #T_pad, Pa·s
  std::vector<T> element_mass_;    // #T_pad, kg
  std::vector<T> node_mass_;       // #N_cap, kg
  std::vector<uint8_t> fixed_;     // #N_cap
  std::vector<T> prescribed_force_;  // #N_cap×3, N
  std::vector<int32_t> inc_range_;    // #N_cap×2: begin, end
  std::vector<int32_t> inc_slots_;    // 4·#T + append region
  int32_t inc_tail_ = 0;              // first unused entry of inc_slots_
  int64_t inc_compactions_ = 0;
  Vec3<T> gravity_ = Vec3<T>::Zero();  // m/s²
  T inversion_det_threshold_ = T(0.3);
  T min_singular_value_ = T(0.3);
  bool damped_ = false;
  bool topology_dirty_ = false;
  uint64_t topology_version_ = 0;
};

extern template class Model<float>;
extern template class Model<double>;

}  // namespace cutsim::fem
