#pragma once
/// @file
/// The local haptic model (the in-memory form of the wire's `HapticModel`):
/// what the server linearises around the tool contact each physics frame and
/// the 1 kHz client renders until the next one arrives (the method paper's "buffer
/// model", §3.4). Validation here is what stops a malformed or hostile model
/// from ever reaching the device; the builder is the server-side half.
///
/// Everything here is allocation-free and never throws, so it may run in the
/// haptic loop and in transport callbacks.

#include <cstdint>
#include <string_view>

#include <Eigen/Core>

namespace cutsim::haptics {

/// Cut state carried with every model (wire `CutState`).
struct CutState {
  uint64_t cuts = 0;              ///< Cut steps so far; an increase means a cut happened.
  bool cutting = false;           ///< A cut happened in the frame this model comes from.
  double decay_per_second = 0.0;  ///< ξ of method paper eq. (13), 1/s; 0 = use the renderer's default.
};

/// One local model: `F(x, v) = f0 − K (x − x0) − damping · v` around the contact
/// (K = −∂f/∂x, so the sign makes pushing in raise the outward force).
struct LocalModel {
  uint64_t seq = 0;                           ///< Server sequence number; higher is newer.
  int64_t stamp_ns = 0;                       ///< Server CLOCK_MONOTONIC at publish, ns (not our clock).
  double sim_time = 0.0;                      ///< Simulation time of the frame, s.
  bool contact = false;                       ///< Tool touches tissue; false = render no force.
  Eigen::Vector3d x0 = Eigen::Vector3d::Zero();      ///< Contact point (tool tip at linearisation), m.
  Eigen::Vector3d normal = Eigen::Vector3d::UnitZ(); ///< Unit outward surface normal at x0.
  Eigen::Vector3d f0 = Eigen::Vector3d::Zero();      ///< Force on the tool at x0, N.
  Eigen::Matrix3d stiffness = Eigen::Matrix3d::Zero();  ///< K = −∂f/∂x at x0, N/m (symmetric PSD).
  double damping = 0.0;                       ///< Viscous damping along the tool velocity, N·s/m.
  double valid_for = 0.0;                     ///< Server's validity horizon, s (0 = unspecified).
  CutState cut;                               ///< Cut counter, flag and decay rate.
  uint64_t topology_version = 0;              ///< Mesh topology version the model was built on.
};

/// Why a model was rejected. `kOk` means it may be rendered.
enum class ModelIssue : uint8_t {
  kOk = 0,
  kNonFinite,           ///< NaN or Inf in any field.
  kNonUnitNormal,       ///< |normal| differs from 1 beyond tolerance (checked when in contact).
  kAsymmetricStiffness, ///< ‖K − Kᵀ‖ beyond tolerance.
  kNegativeStiffness,   ///< An eigenvalue of K below −tolerance (the model would pull the tool in).
  kAbsurdMagnitude,     ///< A position, force, stiffness, damping or time beyond any physical device.
  kNegativeParameter,   ///< damping, valid_for or ξ negative.
};
inline constexpr int kModelIssueCount = 7;

/// Static name of an issue ("non_finite", ...); never allocates.
[[nodiscard]] std::string_view ToString(ModelIssue issue) noexcept;

/// Plausibility limits for `Validate`. These reject garbage; they are not the
/// device limits (those clamp legitimate but strong models when rendering).
struct ValidationLimits {
  double normal_tolerance = 1e-6;        ///< Allowed | |n| − 1 |.
  double symmetry_tolerance = 1e-6;      ///< Allowed ‖K − Kᵀ‖_F / max(‖K‖_F, 1 N/m).
  double eigenvalue_tolerance = 1e-6;    ///< Allowed −λ_min / max(‖K‖_F, 1 N/m).
  double max_position = 100.0;           ///< m; |x0| beyond this is not a tool in a workspace.
  double max_force = 1e4;                ///< N.
  double max_stiffness = 1e7;            ///< N/m (Frobenius norm of K).
  double max_damping = 1e5;              ///< N·s/m.
  double max_valid_for = 60.0;           ///< s.
  double max_decay_per_second = 1e6;     ///< 1/s.
};

/// Checks a model before it is rendered. Fields that matter only in contact
/// (normal) are checked only when `contact` is set; finiteness is checked
/// everywhere. Allocation-free, never throws.
[[nodiscard]] ModelIssue Validate(const LocalModel& model, const ValidationLimits& limits = {}) noexcept;

/// Symmetric positive-semidefinite part of a stiffness: ½(K + Kᵀ) with
/// negative eigenvalues clamped to zero (a linearised FEM stiffness may be
/// indefinite under compression or buckling; rendering a negative stiffness
/// pulls the tool into the tissue and is active). Non-finite input → zero.
[[nodiscard]] Eigen::Matrix3d SymmetricPsdPart(const Eigen::Matrix3d& k) noexcept;

/// Largest eigenvalue of a symmetric 3×3 matrix (0 for non-finite input).
[[nodiscard]] double LargestEigenvalue(const Eigen::Matrix3d& symmetric) noexcept;

/// What the server knows about a contact in one physics frame.
struct ContactLinearisation {
  bool contact = false;                              ///< Tool in contact with the tissue.
  Eigen::Vector3d x0 = Eigen::Vector3d::Zero();      ///< Contact point, m.
  Eigen::Vector3d normal = Eigen::Vector3d::UnitZ(); ///< Outward normal (normalised by the builder).
  Eigen::Vector3d f0 = Eigen::Vector3d::Zero();      ///< Force on the tool at x0, N.
  Eigen::Matrix3d stiffness = Eigen::Matrix3d::Zero();  ///< FEM-derived −∂f/∂x, N/m (any 3×3).
  double damping = 0.0;                              ///< N·s/m.
};

/// Frame metadata the builder copies into the model.
struct ModelHeader {
  uint64_t seq = 0;
  int64_t stamp_ns = 0;
  double sim_time = 0.0;
  double valid_for = 0.0;
  CutState cut;
  uint64_t topology_version = 0;
};

/// Server side: builds a model that passes `Validate` with default limits.
/// Normalises the normal, symmetrises K and clamps its negative eigenvalues,
/// clamps negative damping to 0. A degenerate contact (non-finite values,
/// zero normal, or anything `Validate` would still reject) becomes a
/// no-contact model, because sending no force is always safe. Never throws.
[[nodiscard]] LocalModel BuildLocalModel(const ModelHeader& header,
                                         const ContactLinearisation& contact) noexcept;

}  // namespace cutsim::haptics
