#pragma once
/// @file
/// Prescribed displacements (scene boundary kind KIND_DISPLACEMENT): nodes
/// whose position is set from outside the dynamics, x = X + Σ s_i(t)·u_i,
/// with X the node's rest position, u_i the displacement of each condition
/// that selects it and s_i its ramp (RampFactor). The nodes are fixed nodes
/// of the model, so both integrators keep their x and v through a step; this
/// stage sets them before each frame's dynamics, at the frame's end time
/// (the nodes lead the frame by at most one frame), and before the settle
/// stage at t = 0.
///
/// A cut may copy a prescribed node (cutting::Split); the copy moves with
/// its original, so the stage follows the topology events.

#include <cstdint>
#include <span>
#include <vector>

#include <Eigen/Core>

#include "common/cutting/topology_event.h"
#include "common/fem/model.h"
#include "common/fem/state.h"

namespace cutsim::sim {

/// The ramp's fraction of the full displacement at time `t` (s) for a ramp
/// of `ramp_time` (s): 0 before t = 0, 3τ² − 2τ³ with τ = t/ramp_time on
/// the ramp (zero velocity at both ends, so the ramp starts and ends without
/// a jolt), 1 after it; 1 at every t ≥ 0 when ramp_time is 0.
[[nodiscard]] double RampFactor(double t, double ramp_time);
/// d RampFactor / dt, 1/s (0 off the ramp).
[[nodiscard]] double RampRate(double t, double ramp_time);

template <typename T>
class PrescribedMotion {
 public:
  /// One node's prescribed displacement (m) and its ramp (s).
  struct Entry {
    int32_t node = -1;
    Eigen::Vector3d displacement = Eigen::Vector3d::Zero();
    double ramp_time = 0;
  };

  /// Adds a displacement to `node` (entries on one node add up) and marks
  /// it fixed in `model`.
  void Add(fem::Model<T>& model, int32_t node, const Eigen::Vector3d& displacement, double ramp_time);

  [[nodiscard]] bool empty() const { return entries_.empty(); }
  [[nodiscard]] std::span<const Entry> entries() const { return entries_; }

  /// Takes in the topology events after the ones already seen: a copy of a
  /// prescribed node gets its original's entries. `events` is the whole
  /// list so far, in order (it only grows).
  void Follow(std::span<const cutting::TopologyEvent> events);

  /// Sets x = X + Σ s(t)·u and v = Σ ṡ(t)·u of every prescribed node at
  /// time `t` (s).
  void Apply(const fem::Model<T>& model, fem::State<T>& state, double t) const;

 private:
  std::vector<Entry> entries_;
  size_t events_seen_ = 0;
};

extern template class PrescribedMotion<float>;
extern template class PrescribedMotion<double>;

}  // namespace cutsim::sim
