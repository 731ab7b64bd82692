#include "common/cutting/cut_attempt.h"

namespace cutsim::cutting {

CutAttempt CutAttemptTracker::Update(const Contact& contact, const WorldAccess& world) {
  CutAttempt out;
  if (!contact.touching || contact.closest_node < 0 || !contact.point.allFinite()) {
    Reset();  // (a) contact lost: the next touch is a new t0
    return out;
  }
  last_node_ = contact.closest_node;
  last_point_ = contact.point;
  if (anchor_node_ < 0) {  // first contact: t0
    anchor_node_ = contact.closest_node;
    anchor_point_ = contact.point;
    frames_outside_ = 0;
    return out;
  }
  if (contact.closest_node == anchor_node_) {  // condition 1 fails
    frames_outside_ = 0;
    return out;
  }
  const Eigen::Vector3d xc = world.Get(contact.closest_node);
  const double d_v = (xc - world.Get(anchor_node_)).norm();
  const double r = params_.alpha * d_v;  // eq. (4)
  if ((contact.point - xc).norm() <= r && d_v > 0.0) {  // condition 2: C_p(t) ∈ N(v_c(t))
    frames_outside_ = 0;
    out.attempt = true;
    out.v0 = anchor_node_;
    out.v1 = contact.closest_node;
    out.cp0 = anchor_point_;
    out.cp = contact.point;
    out.normal = contact.normal;
    out.facet_tet = contact.facet_tet;
    out.radius = r;
    return out;
  }
  // (c) wandered off without cutting for too long: re-anchor here.
  if (params_.t0_timeout_frames > 0 && ++frames_outside_ >= params_.t0_timeout_frames) {
    anchor_node_ = contact.closest_node;
    anchor_point_ = contact.point;
    frames_outside_ = 0;
  }
  return out;
}

void CutAttemptTracker::OnCutExecuted() {
  // (b) t0 := t, so the next step's v0 is this step's v1.
  if (last_node_ < 0) return;
  anchor_node_ = last_node_;
  anchor_point_ = last_point_;
  frames_outside_ = 0;
}

void CutAttemptTracker::Reset() {
  anchor_node_ = -1;
  last_node_ = -1;
  frames_outside_ = 0;
}

}  // namespace cutsim::cutting
