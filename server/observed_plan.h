#pragma once
/// @file
/// The scene's planned incision as observers' pages draw it (ObserverSession.plan).

#include "common/sim/incision_score.h"
#include "common/transport/proto_vec.h"
#include "cutsim/v1/wire.pb.h"

namespace cutsim::server {

/// Fills `out` with the plan's points (m, world frame, in cutting order) and
/// its band's half-width.
inline void FillPlannedLine(const sim::PlannedIncision& plan, v1::PlannedLine* out) {
  out->Clear();
  for (const Eigen::Vector3d& p : plan.points) transport::SetVec3(p, out->add_points());
  out->set_tolerance(plan.tolerance);
}

}  // namespace cutsim::server
