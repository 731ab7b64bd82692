#pragma once
/// @file
/// `sim::ToolStage`, the tool and its contact with the tissue, frame by
/// frame (the wire's `v1::ToolState` is the pose a station sends): the tool's
/// set-up from the scene (scripted path or external pose, blade, contact
/// spring sized to the tissue), the contact facet and the blade's grip
/// (tool_contact.h has the contact model), the penalty or grip force on the
/// facet nodes, the substep bound the contact spring adds, and what the
/// haptic side reads (ToolReport, ContactStiffness).

#include <array>
#include <cstdint>
#include <optional>
#include <vector>

#include <Eigen/Core>

#include "common/fem/implicit.h"
#include "common/fem/model.h"
#include "common/fem/state.h"
#include "common/haptics/tool_path.h"
#include "common/mesh/bvh.h"
#include "common/mesh/tet_mesh.h"
#include "common/sim/contact_stiffness.h"
#include "common/sim/scene_loader.h"
#include "common/sim/stage.h"
#include "common/sim/surface_tracker.h"
#include "common/sim/tool_contact.h"
#include "common/sim/types.h"

namespace cutsim::sim {

template <typename T>
class ToolStage final : public CheckpointedStage {
 public:
  /// The scene's tool over the uncut `mesh`, its contact spring as stiff as
  /// one element of the model's first material (E·h̄) unless the scene
  /// sets it. Throws InputError for an unreadable path file.
  ToolStage(const LoadedScene& scene, const mesh::TetMesh& mesh, const fem::Model<T>& model);

  // ---- pose -------------------------------------------------------------
  /// Drives the tool from outside (haptic link) from the next frame on.
  void SetExternalPose(const ToolPose& pose) { external_pose_ = pose; }
  /// The frame's pose: the external one if set, else the path's at `time`.
  void MoveTo(double time) { pose_ = external_pose_ ? *external_pose_ : Sample(time); }
  /// The path's pose at `time` (after a restore).
  void MoveToPath(double time) { pose_ = Sample(time); }
  [[nodiscard]] const ToolPose& pose() const { return pose_; }
  [[nodiscard]] double path_end_time() const { return path_.empty() ? 0.0 : path_.end_time(); }
  [[nodiscard]] double blade_length() const { return blade_length_; }
  [[nodiscard]] double contact_stiffness() const { return contact_stiffness_; }
  [[nodiscard]] double indent_limit() const { return indent_limit_; }

  // ---- contact ----------------------------------------------------------
  /// Finds the contact facet of the blade at its pose on `surface` (its
  /// world copy refreshed), and takes, keeps or releases the grip.
  void FindContact(const SurfaceTracker& surface, const fem::Model<T>& model, const T* x);
  /// The blade loads the tissue this frame: it touches it, not only a wall
  /// or lip of its own cut, and in its slit it still holds a grip. Other
  /// in-cut contacts keep the cut's t0 but take no load (tool_contact.h).
  [[nodiscard]] bool Loaded() const {
    return facet_.touching && !facet_.on_cut && (!facet_.in_slit || grip_.active);
  }
  /// `dt_max` lowered for the contact spring and damper (see .cc), s.
  [[nodiscard]] double ContactLimitedStep(double dt_max, const fem::Model<T>& model, double safety_factor) const;
  /// Puts the contact force for the blade tip at `tip` moving at
  /// `tool_velocity` (m/s) on the loaded nodes' f_ext.
  void ApplyContactForce(const Eigen::Vector3d& tip, const Eigen::Vector3d& tool_velocity, fem::State<T>& state);
  /// Takes the contact force off f_ext again (end of the frame's substeps).
  void ClearContactForce(fem::State<T>& state);
  /// The contact as a spring inside an implicit step: the force on the
  /// loaded nodes for the blade tip at `tip` moving at `tool_velocity`, at
  /// positions `x` (#N·3), and its stiffness −∂F/∂p in the contact point p
  /// (k·n nᵀ for the tip penalty, k·(I − d dᵀ) for the edge grip; zero where
  /// the force is capped). Updates the report as ApplyContactForce does.
  [[nodiscard]] fem::PenaltyTerm ContactPenalty(const Eigen::Vector3d& tip, const Eigen::Vector3d& tool_velocity,
                                                const T* x);
  /// K = −∂f_tool/∂x_tool at the current contact, N/m (tool_contact.h);
  /// zero without load. The tissue's part: PatchStiffness.
  [[nodiscard]] Eigen::Matrix3d ContactStiffness(const fem::Model<T>& model, const T* x) const;
  /// The same with the tissue's point stiffness `tissue` (3×3, N/m, symmetric
  /// positive definite) at the loaded nodes, e.g. the implicit step's own
  /// linearisation (fem::ImplicitIntegrator::EffectiveStiffness).
  [[nodiscard]] Eigen::Matrix3d ContactStiffness(const Eigen::Matrix3d& tissue) const;
  /// Nodes and barycentric weights the contact force goes to this frame.
  [[nodiscard]] const std::array<int32_t, 3>& force_nodes() const { return ForceNodes(); }
  [[nodiscard]] const Eigen::Vector3d& force_weights() const { return ForceWeights(); }
  /// A cut step executed and swept `sweep`: the blade is in its own cut.
  void EnterCut(const CutSweep& sweep);

  [[nodiscard]] const ContactFacet& facet() const { return facet_; }
  /// Pose, contact and force; the cut fields are the cut pipeline's.
  [[nodiscard]] const ToolReport& report() const { return report_; }

  // ---- checkpoint part (stage.h) -------------------------------------------
  /// The pose (and the external one, when driven from outside), the
  /// contact facet, the grip and the in-cut state with its swept areas:
  /// what the next frame's contact starts from.
  void Save(v1::CheckpointBody& body) const override;
  void Check(const v1::CheckpointBody& body, const PartCheck& check) const override;
  void Restore(const v1::CheckpointBody& body) override;

 private:
  [[nodiscard]] ToolPose Sample(double t) const;
  void UpdateGrip(const fem::Model<T>& model, const T* x);
  /// The contact force F on the tissue at positions `x` (grip or tip
  /// penalty), with the report updated for it.
  Eigen::Vector3d ContactForce(const Eigen::Vector3d& tip, const Eigen::Vector3d& tool_velocity, const T* x);
  /// The direction u the tissue is probed along and the shape of the
  /// contact's stiffness (n nᵀ or I − d dᵀ); false without load.
  bool StiffnessShape(Eigen::Vector3d& u, Eigen::Matrix3d& shape) const;
  /// Nodes and weights the contact force goes to this frame.
  [[nodiscard]] const std::array<int32_t, 3>& ForceNodes() const { return grip_.active ? grip_.nodes : facet_.nodes; }
  [[nodiscard]] const Eigen::Vector3d& ForceWeights() const { return grip_.active ? grip_.bary : facet_.bary; }

  haptics::ToolPath path_;
  std::optional<ToolPose> external_pose_;
  ToolPose pose_;
  double blade_length_ = 0;       // m
  double contact_stiffness_ = 0;  // N/m
  double contact_damping_ = 0;    // N·s/m
  double indent_limit_ = 0;       // m, tip penalty cap (and the depth at which the blade is inside)
  double grip_limit_ = 0;         // m, edge-grip stretch cap (tool_contact.h)
  double mean_edge_ = 0;          // m
  ContactFacet facet_;
  EdgeGrip grip_;  // the blade's hold on tissue it is inside
  bool in_cut_ = false;            // a cut executed since the blade last lost contact
  std::vector<CutSweep> sweeps_;   // areas those cuts swept (tool_contact.h)
  std::array<int32_t, 3> applied_nodes_{-1, -1, -1};  // nodes holding a contact force in f_ext
  ToolReport report_;
  std::vector<mesh::SegmentHit> hits_scratch_;
  std::vector<int32_t> box_scratch_;
  mutable PatchScratch patch_;  // ContactStiffness's scratch, reused across frames
};

extern template class ToolStage<float>;
extern template class ToolStage<double>;

}  // namespace cutsim::sim
