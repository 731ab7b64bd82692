#pragma once
/// @file
/// Geometric criterion (method paper §3.1, Fig. 1, eq. 4): decides, frame by frame,
/// whether the tool's motion on the surface is a cut attempt.
///
/// Choices the method paper leaves open, made here:
/// - Neighbourhood N: the ball of radius r = α·d_v centred on v_c(t) (the
///   current closest vertex, as the method paper's figure draws it), with
///   d_v = |x(v_c(t)) − x(v_c(t0))| in world coordinates at time t.
/// - t0 (the anchor: C_p(t0), v_c(t0)) is set by the first contact and
///   reset (a) when contact is lost, (b) after each executed cut, to the
///   contact of that frame (t0 := t), so the cut progresses vertex by vertex
///   and v0 of the next step is this step's v1, and (c) after
///   `CutParams::t0_timeout_frames` consecutive frames in which v_c(t) ≠
///   v_c(t0) but C_p(t) stays outside N (the tool wandered off without
///   cutting), to the contact of that frame.
/// - A small motion in the middle of a facet can flip the closest vertex
///   (condition 1) while C_p(t) is still about half an edge from every
///   vertex; with α < 0.5 it is outside N, so it is not an attempt (the case
///   N exists for). The tool must come close to the new vertex.
/// - Twin vertices (copies made by earlier cuts, coincident) give d_v = 0,
///   hence r = 0: switching between twins is never an attempt.

#include <cstdint>

#include <Eigen/Core>

#include "common/cutting/cut_params.h"
#include "common/cutting/world_access.h"

namespace cutsim::cutting {

/// Tool–surface contact of one physics frame, from the sim's contact query.
struct Contact {
  bool touching = false;
  Eigen::Vector3d point = Eigen::Vector3d::Zero();   ///< C_p(t), world, m.
  Eigen::Vector3d normal = Eigen::Vector3d::UnitZ(); ///< Outward unit normal of the facet, world.
  int32_t closest_node = -1;                         ///< v_c(t).
  int32_t facet_tet = -1;                            ///< Tet owning the contact facet (optional).
};

/// A cut attempt: the cut line starts at v0 = v_c(t0) and goes to v1 = v_c(t).
struct CutAttempt {
  bool attempt = false;
  int32_t v0 = -1;
  int32_t v1 = -1;
  Eigen::Vector3d cp0 = Eigen::Vector3d::Zero();     ///< C_p(t0), m.
  Eigen::Vector3d cp = Eigen::Vector3d::Zero();      ///< C_p(t), m.
  Eigen::Vector3d normal = Eigen::Vector3d::UnitZ(); ///< Facet normal at t.
  int32_t facet_tet = -1;
  double radius = 0.0;                               ///< r = α·d_v, m.
};

class CutAttemptTracker {
 public:
  explicit CutAttemptTracker(const CutParams& params) : params_(params) {}

  /// Feeds one frame's contact; returns whether it is a cut attempt. Reads
  /// the world positions of v_c(t) and v_c(t0). Never throws or allocates.
  CutAttempt Update(const Contact& contact, const WorldAccess& world);

  /// The last attempt was executed as a cut: t0 := t.
  void OnCutExecuted();

  /// Forgets t0 (as on contact loss).
  void Reset();

  [[nodiscard]] bool has_anchor() const { return anchor_node_ >= 0; }
  [[nodiscard]] int32_t anchor_node() const { return anchor_node_; }              ///< v_c(t0)
  [[nodiscard]] const Eigen::Vector3d& anchor_point() const { return anchor_point_; } ///< C_p(t0)
  [[nodiscard]] int32_t frames_outside() const { return frames_outside_; }

  /// What the tracker carries from frame to frame (a checkpoint keeps it).
  struct Memory {
    int32_t anchor_node = -1;  ///< v_c(t0), −1: none
    Eigen::Vector3d anchor_point = Eigen::Vector3d::Zero();
    int32_t last_node = -1;
    Eigen::Vector3d last_point = Eigen::Vector3d::Zero();
    int32_t frames_outside = 0;
  };
  [[nodiscard]] Memory memory() const {
    return {anchor_node_, anchor_point_, last_node_, last_point_, frames_outside_};
  }
  void set_memory(const Memory& m) {
    anchor_node_ = m.anchor_node;
    anchor_point_ = m.anchor_point;
    last_node_ = m.last_node;
    last_point_ = m.last_point;
    frames_outside_ = m.frames_outside;
  }

 private:
  CutParams params_;
  int32_t anchor_node_ = -1;
  Eigen::Vector3d anchor_point_ = Eigen::Vector3d::Zero();
  int32_t last_node_ = -1;
  Eigen::Vector3d last_point_ = Eigen::Vector3d::Zero();
  int32_t frames_outside_ = 0;
};

}  // namespace cutsim::cutting
