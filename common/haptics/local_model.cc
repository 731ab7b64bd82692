#include "common/haptics/local_model.h"

#include <algorithm>
#include <cmath>

#include <Eigen/Eigenvalues>

namespace cutsim::haptics {
namespace {

bool AllFinite(const LocalModel& m) {
  return std::isfinite(m.sim_time) && m.x0.allFinite() && m.normal.allFinite() && m.f0.allFinite() &&
         m.stiffness.allFinite() && std::isfinite(m.damping) && std::isfinite(m.valid_for) &&
         std::isfinite(m.cut.decay_per_second);
}

// Eigenvalues of a symmetric 3×3 in closed form (fixed size: no allocation).
Eigen::Vector3d SymmetricEigenvalues(const Eigen::Matrix3d& symmetric) {
  Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> solver;
  solver.computeDirect(symmetric, Eigen::EigenvaluesOnly);
  return solver.eigenvalues();  // ascending
}

}  // namespace

std::string_view ToString(ModelIssue issue) noexcept {
  switch (issue) {
    case ModelIssue::kOk: return "ok";
    case ModelIssue::kNonFinite: return "non_finite";
    case ModelIssue::kNonUnitNormal: return "non_unit_normal";
    case ModelIssue::kAsymmetricStiffness: return "asymmetric_stiffness";
    case ModelIssue::kNegativeStiffness: return "negative_stiffness";
    case ModelIssue::kAbsurdMagnitude: return "absurd_magnitude";
    case ModelIssue::kNegativeParameter: return "negative_parameter";
  }
  return "unknown";
}

ModelIssue Validate(const LocalModel& m, const ValidationLimits& limits) noexcept {
  if (!AllFinite(m)) return ModelIssue::kNonFinite;
  if (m.damping < 0.0 || m.valid_for < 0.0 || m.cut.decay_per_second < 0.0) {
    return ModelIssue::kNegativeParameter;
  }
  const double k_norm = m.stiffness.norm();  // Frobenius, N/m
  if (m.x0.norm() > limits.max_position || m.f0.norm() > limits.max_force ||
      k_norm > limits.max_stiffness || m.damping > limits.max_damping ||
      m.valid_for > limits.max_valid_for || m.cut.decay_per_second > limits.max_decay_per_second) {
    return ModelIssue::kAbsurdMagnitude;
  }
  if (m.contact && std::abs(m.normal.norm() - 1.0) > limits.normal_tolerance) {
    return ModelIssue::kNonUnitNormal;
  }
  // Tolerances relative to the stiffness scale (at least 1 N/m) so that a
  // model serialised through float-precision arithmetic still passes.
  const double scale = std::max(k_norm, 1.0);
  if ((m.stiffness - m.stiffness.transpose()).norm() > limits.symmetry_tolerance * scale) {
    return ModelIssue::kAsymmetricStiffness;
  }
  const Eigen::Matrix3d sym = 0.5 * (m.stiffness + m.stiffness.transpose());
  if (SymmetricEigenvalues(sym)(0) < -limits.eigenvalue_tolerance * scale) {
    return ModelIssue::kNegativeStiffness;
  }
  return ModelIssue::kOk;
}

Eigen::Matrix3d SymmetricPsdPart(const Eigen::Matrix3d& k) noexcept {
  if (!k.allFinite()) return Eigen::Matrix3d::Zero();
  const Eigen::Matrix3d sym = 0.5 * (k + k.transpose());
  Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> solver;
  solver.computeDirect(sym, Eigen::ComputeEigenvectors);
  const Eigen::Vector3d lambda = solver.eigenvalues().cwiseMax(0.0);
  const Eigen::Matrix3d& q = solver.eigenvectors();
  Eigen::Matrix3d psd = q * lambda.asDiagonal() * q.transpose();
  // Reconstruction leaves round-off asymmetry of order ε‖K‖; remove it exactly.
  psd = 0.5 * (psd + psd.transpose()).eval();
  return psd.allFinite() ? psd : Eigen::Matrix3d::Zero();
}

double LargestEigenvalue(const Eigen::Matrix3d& symmetric) noexcept {
  if (!symmetric.allFinite()) return 0.0;
  return SymmetricEigenvalues(symmetric)(2);
}

LocalModel BuildLocalModel(const ModelHeader& header, const ContactLinearisation& contact) noexcept {
  LocalModel m;
  m.seq = header.seq;
  m.stamp_ns = header.stamp_ns;
  m.sim_time = std::isfinite(header.sim_time) ? header.sim_time : 0.0;
  m.valid_for = std::isfinite(header.valid_for) ? std::max(header.valid_for, 0.0) : 0.0;
  m.cut = header.cut;
  if (!std::isfinite(m.cut.decay_per_second) || m.cut.decay_per_second < 0.0) {
    m.cut.decay_per_second = 0.0;  // renderer default
  }
  m.topology_version = header.topology_version;
  if (!contact.contact) return m;

  const double n_norm = contact.normal.norm();
  if (!contact.x0.allFinite() || !contact.f0.allFinite() || !contact.stiffness.allFinite() ||
      !std::isfinite(n_norm) || n_norm < 1e-12 || !std::isfinite(contact.damping)) {
    return m;  // degenerate contact: render nothing rather than garbage
  }
  m.contact = true;
  m.x0 = contact.x0;
  m.normal = contact.normal / n_norm;
  m.f0 = contact.f0;
  m.stiffness = SymmetricPsdPart(contact.stiffness);
  m.damping = std::max(contact.damping, 0.0);
  if (Validate(m) != ModelIssue::kOk) {
    LocalModel none;  // e.g. an absurd magnitude: still safe to send
    none.seq = m.seq;
    none.stamp_ns = m.stamp_ns;
    none.sim_time = m.sim_time;
    none.valid_for = m.valid_for;
    none.cut = m.cut;
    none.topology_version = m.topology_version;
    return none;
  }
  return m;
}

}  // namespace cutsim::haptics
