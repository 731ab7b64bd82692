#pragma once
// Small model builders shared by the haptics tests.

#include <cstdint>

#include <Eigen/Core>

#include "common/haptics/local_model.h"

namespace cutsim::haptics::testing {

inline constexpr int64_t kNsPerMs = 1'000'000;

/// A contact model with force `f0` at `x0`, outward normal `normal` and an
/// isotropic-in-normal stiffness k·n·nᵀ.
inline LocalModel ContactModel(uint64_t seq, const Eigen::Vector3d& x0, const Eigen::Vector3d& f0,
                               double k = 0.0, const Eigen::Vector3d& normal = Eigen::Vector3d::UnitZ()) {
  LocalModel m;
  m.seq = seq;
  m.contact = true;
  m.x0 = x0;
  m.normal = normal;
  m.f0 = f0;
  m.stiffness = k * normal * normal.transpose();
  return m;
}

/// A model of a flat wall z ≤ 0 of stiffness `k_wall` linearised at tool
/// position `p`, with the stiffness sent to the client scaled by `k_fraction`
/// (1 = exact local model, < 1 = the client partly renders a held force).
inline LocalModel WallModel(uint64_t seq, const Eigen::Vector3d& p, double k_wall, double k_fraction) {
  LocalModel m;
  m.seq = seq;
  if (p.z() >= 0.0) return m;  // no contact
  m.contact = true;
  m.x0 = p;
  m.normal = Eigen::Vector3d::UnitZ();
  m.f0 = Eigen::Vector3d(0.0, 0.0, -k_wall * p.z());
  m.stiffness = k_fraction * k_wall * m.normal * m.normal.transpose();
  return m;
}

/// Deterministic uniform numbers in [0, 1) (a 64-bit LCG; same on every platform).
class Lcg {
 public:
  explicit Lcg(uint64_t seed) : state_(seed) {}
  double Next() {
    state_ = state_ * 6364136223846793005ULL + 1442695040888963407ULL;
    return static_cast<double>(state_ >> 11) * 0x1.0p-53;
  }

 private:
  uint64_t state_;
};

}  // namespace cutsim::haptics::testing
