#include "common/sim/tool_stage.h"

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <limits>
#include <utility>

#include <fmt/format.h>

#include "common/core/units.h"
#include "common/sim/checkpoint_part.h"
#include "cutsim/v1/checkpoint.pb.h"
#include "common/mesh/surface.h"

namespace cutsim::sim {
namespace {

Eigen::Vector3d ToEigen(const v1::Vec3& v) { return {v.x(), v.y(), v.z()}; }

template <typename T>
Eigen::Vector3d NodeX(const T* x, int32_t n) {
  const size_t i = 3 * static_cast<size_t>(n);
  return {static_cast<double>(x[i]), static_cast<double>(x[i + 1]), static_cast<double>(x[i + 2])};
}

haptics::ToolPath ReadPath(const LoadedScene& scene) {
  const auto& tool = scene.scene.tool();
  if (!tool.path_file().empty()) {
    const std::filesystem::path p(tool.path_file());
    return haptics::ToolPath::Read(p.is_absolute() ? p : scene.base_dir / p);
  }
  if (tool.keyframes_size() == 0) return {};
  std::vector<haptics::ToolKeyframe> frames;
  for (const auto& k : tool.keyframes()) frames.push_back({k.t(), {ToEigen(k.tip()), ToEigen(k.blade_dir())}});
  return haptics::ToolPath(std::move(frames), scene.path.string() + ": tool.keyframes");
}

double MeanSurfaceEdge(const mesh::TetMesh& mesh) {
  const mesh::Surface surf = mesh::ExtractSurface(mesh.tets);
  double sum = 0;
  int64_t count = 0;
  for (int32_t f = 0; f < surf.tris.rows(); ++f) {
    for (int k = 0; k < 3; ++k) {
      sum += (mesh.nodes.row(surf.tris(f, k)) - mesh.nodes.row(surf.tris(f, (k + 1) % 3))).norm();
      ++count;
    }
  }
  return count > 0 ? sum / static_cast<double>(count) : 1e-3;
}

/// Where the tool waits without a path until a client sets a pose: clear
/// of the tissue, blade vertical with its tip one blade length above the
/// top of the body (the default pose, tip at the origin, would lie on the
/// body of any scene built from the origin, e.g. along a box's edge).
ToolPose ParkedPose(const mesh::TetMesh& mesh, double blade_length) {
  if (mesh.num_nodes() == 0) return {};
  Eigen::Vector3d lo = Eigen::Vector3d::Constant(std::numeric_limits<double>::infinity());
  Eigen::Vector3d hi = -lo;
  for (int32_t n = 0; n < mesh.num_nodes(); ++n) {
    lo = lo.cwiseMin(mesh.nodes.row(n).transpose());
    hi = hi.cwiseMax(mesh.nodes.row(n).transpose());
  }
  return {Eigen::Vector3d(0.5 * (lo.x() + hi.x()), 0.5 * (lo.y() + hi.y()), hi.z() + blade_length),
          Eigen::Vector3d::UnitZ()};
}

}  // namespace

template <typename T>
ToolStage<T>::ToolStage(const LoadedScene& scene, const mesh::TetMesh& mesh, const fem::Model<T>& model)
    : path_(ReadPath(scene)) {
  const auto& tool = scene.scene.tool();
  blade_length_ = tool.blade_length();
  // Defaults tied to the tissue: a penalty spring as stiff as one element
  // of the first material (E·h̄), an indentation limit of one mean edge.
  mean_edge_ = MeanSurfaceEdge(mesh);
  const double E = units::YoungFromLame({static_cast<double>(model.lambdas()[0]), static_cast<double>(model.mus()[0])});
  contact_stiffness_ = tool.contact_stiffness() > 0 ? tool.contact_stiffness() : E * mean_edge_;
  contact_damping_ = tool.contact_damping();
  indent_limit_ = 0.5 * mean_edge_;
  grip_limit_ = mean_edge_;
  if (blade_length_ <= 0) blade_length_ = 2.0 * mean_edge_;
  report_.present = true;
  report_.blade_length = blade_length_;
  if (path_.empty()) pose_ = ParkedPose(mesh, blade_length_);
  pose_ = Sample(0.0);
  report_.pose = pose_;
}

template <typename T>
ToolPose ToolStage<T>::Sample(double t) const {
  if (path_.empty()) return pose_;
  return path_.Sample(t);
}

template <typename T>
void ToolStage<T>::FindContact(const SurfaceTracker& surface, const fem::Model<T>& model, const T* x) {
  facet_ = FindContactFacet(surface.bvh(), surface.world(), surface.triangles(), pose_.tip, pose_.blade_dir,
                            blade_length_, mean_edge_, hits_scratch_, box_scratch_, surface.debris_facets(), in_cut_,
                            surface.wall_nodes());
  if (!facet_.touching) {
    in_cut_ = false;  // the blade left the tissue (see tool_contact.h)
    sweeps_.clear();
  }
  // Behind its own cut front the tissue is cut (tool_contact.h, in its own cut).
  if (in_cut_ && facet_.touching && !facet_.on_cut) {
    facet_.on_cut = InSweptArea(sweeps_, facet_.point, indent_limit_);
  }
  // Capped at the indentation limit; none in its own cut, where the tip
  // never pushes (tool_contact.h, in its own cut).
  if (facet_.touching) {
    facet_.depth = facet_.on_cut || facet_.in_slit ? 0.0 : std::min(facet_.depth, indent_limit_);
  }
  UpdateGrip(model, x);
  report_.touching = facet_.touching;
  report_.pose = pose_;
  report_.point = facet_.point;
  report_.normal = facet_.normal;
  report_.depth = facet_.depth;
  if (!Loaded()) report_.force_on_tool.setZero();
}

/// Edge coupling (tool_contact.h): the blade is inside once the contact
/// point is more than the indentation limit up the blade from its tip.
/// A grip from an older topology is released (a cut: the tissue gave
/// way, the spring restarts unloaded at the new crossing); one whose
/// tissue end drifted more than half the limit from its material point
/// moves to the current crossing, keeping its world point. In its own
/// cut a facet on the cut releases the grip, and an in-slit contact keeps
/// one but never takes one (tool_contact.h, in its own cut).
template <typename T>
void ToolStage<T>::UpdateGrip(const fem::Model<T>& model, const T* x) {
  const bool inside =
      facet_.touching && !facet_.on_cut && (facet_.point - pose_.tip).dot(pose_.blade_dir) > indent_limit_;
  if (!inside) {
    grip_.active = false;
    return;
  }
  const uint64_t version = model.topology_version();
  if (!grip_.active || grip_.topology_version != version) {
    // A new grip only where the edge crosses uncut tissue; in the slit it
    // may only keep the one it holds (tool_contact.h, in-cut rule).
    if (facet_.in_slit) {
      grip_.active = false;
      return;
    }
    grip_ = MakeGrip(facet_, facet_.point, version);
  } else if (grip_.offset.norm() > 0.5 * grip_limit_) {
    const auto& nd = grip_.nodes;
    grip_ = MakeGrip(facet_, GripPoint(grip_, NodeX(x, nd[0]), NodeX(x, nd[1]), NodeX(x, nd[2])), version);
  }
  facet_.depth = 0.0;  // no tip penalty inside: the edge carries the load
}

/// The penalty spring is stiffness the FEM's stable-step estimate does not
/// see: K_c = k·(b ⊗ b)·n nᵀ on the facet nodes. Its largest frequency is
/// ω_c² ≤ k·Σ bᵢ²/mᵢ; with the elastic one, ω² ≤ ω_e² + ω_c² (Weyl: both
/// parts are positive semi-definite), ω_e taken as 2·safety/dt_max
/// (conservative: dt_max is at most safety × the limit). The approach
/// damper c adds dt ≤ min mᵢ/(c·bᵢ). On a finely cut body the facet nodes
/// are split copies of a few milligrams, where a spring sized for the body
/// (E·h̄) would otherwise set the limit.
template <typename T>
double ToolStage<T>::ContactLimitedStep(double dt_max, const fem::Model<T>& model, double safety_factor) const {
  double w2 = 0;
  double damper_limit = std::numeric_limits<double>::infinity();
  for (int i = 0; i < 3; ++i) {
    const double b = ForceWeights()[i];
    const double m = static_cast<double>(model.node_mass(ForceNodes()[static_cast<size_t>(i)]));
    if (!(m > 0) || b <= 0) continue;
    w2 += contact_stiffness_ * b * b / m;
    if (contact_damping_ > 0) damper_limit = std::min(damper_limit, m / (contact_damping_ * b));
  }
  const double safety = std::min(1.0, safety_factor);
  const double we = 2.0 * safety / dt_max;
  const double limited = 2.0 * safety / std::sqrt(we * we + w2);
  return std::min({dt_max, limited, safety * damper_limit});
}

template <typename T>
Eigen::Vector3d ToolStage<T>::ContactForce(const Eigen::Vector3d& tip, const Eigen::Vector3d& tool_velocity,
                                           const T* x) {
  const auto& nd = ForceNodes();
  const Eigen::Vector3d x0 = NodeX(x, nd[0]), x1 = NodeX(x, nd[1]), x2 = NodeX(x, nd[2]);
  Eigen::Vector3d F;
  if (grip_.active) {
    F = EdgeGripForce(grip_, x0, x1, x2, tip, pose_.blade_dir, contact_stiffness_, grip_limit_);
    facet_.point = facet_.bary[0] * NodeX(x, facet_.nodes[0]) + facet_.bary[1] * NodeX(x, facet_.nodes[1]) +
                   facet_.bary[2] * NodeX(x, facet_.nodes[2]);
  } else {
    F = PenaltyForce(facet_, x0, x1, x2, tip, tool_velocity, contact_stiffness_, contact_damping_, indent_limit_);
  }
  report_.force_on_tool = -F;
  report_.depth = grip_.active ? grip_.stretch.norm() : facet_.depth;
  report_.point = facet_.point;
  // The haptic side renders unilaterally along this direction: the push
  // on the tool (against the blade's sideways motion when gripping).
  const double f = F.norm();
  report_.normal = grip_.active && f > 0 ? Eigen::Vector3d(-F / f) : facet_.normal;
  return F;
}

template <typename T>
void ToolStage<T>::ApplyContactForce(const Eigen::Vector3d& tip, const Eigen::Vector3d& tool_velocity,
                                     fem::State<T>& state) {
  const Eigen::Vector3d F = ContactForce(tip, tool_velocity, state.x.data());
  const auto& nd = ForceNodes();
  const Eigen::Vector3d& w = ForceWeights();
  for (int i = 0; i < 3; ++i) {
    const size_t b = 3 * static_cast<size_t>(nd[static_cast<size_t>(i)]);
    for (int k = 0; k < 3; ++k) state.f_ext[b + static_cast<size_t>(k)] = static_cast<T>(w[i] * F[k]);
  }
  applied_nodes_ = nd;
}

/// The force is linear in p below its caps: the tip penalty
/// −k·((p − tip)·n)·n has −∂F/∂p = k·n nᵀ while 0 < depth < the
/// indentation limit, the grip k·(tip − p)⊥ has k·(I − d dᵀ) while its
/// stretch is below the grip limit. At a cap the force is constant in p.
template <typename T>
fem::PenaltyTerm ToolStage<T>::ContactPenalty(const Eigen::Vector3d& tip, const Eigen::Vector3d& tool_velocity,
                                              const T* x) {
  fem::PenaltyTerm term;
  term.force = ContactForce(tip, tool_velocity, x);
  const Eigen::Vector3d& w = ForceWeights();
  for (size_t i = 0; i < 3; ++i) {
    term.nodes[i] = ForceNodes()[i];
    term.weights[i] = w[static_cast<Eigen::Index>(i)];
  }
  if (grip_.active) {
    if (grip_.stretch.norm() < grip_limit_) {
      const Eigen::Vector3d& d = pose_.blade_dir;
      term.stiffness = contact_stiffness_ * (Eigen::Matrix3d::Identity() - d * d.transpose());
    }
  } else if (facet_.depth > 0.0 && facet_.depth < indent_limit_) {
    term.stiffness = contact_stiffness_ * facet_.normal * facet_.normal.transpose();
  }
  return term;
}

template <typename T>
void ToolStage<T>::ClearContactForce(fem::State<T>& state) {
  for (const int32_t n : applied_nodes_) {
    if (n < 0) continue;
    for (int k = 0; k < 3; ++k) state.f_ext[3 * static_cast<size_t>(n) + static_cast<size_t>(k)] = T(0);
  }
  applied_nodes_ = {-1, -1, -1};
}

/// The contact spring k in series with the tissue's point stiffness along
/// the direction it pushes. The tip penalty acts along n: K = k_eff·n nᵀ.
/// The edge grip acts across the blade, K = k_eff·(I − d dᵀ), with the
/// tissue taken along the stretch (or, unloaded, along the facet normal's
/// part across the blade).
template <typename T>
bool ToolStage<T>::StiffnessShape(Eigen::Vector3d& u, Eigen::Matrix3d& shape) const {
  if (!Loaded()) return false;
  u = facet_.normal;
  shape = u * u.transpose();
  if (!grip_.active) return true;
  const Eigen::Vector3d d = pose_.blade_dir;
  u = grip_.stretch;
  if (u.norm() <= 1e-12 * (1.0 + indent_limit_)) u = facet_.normal - facet_.normal.dot(d) * d;
  const double u_len = u.norm();
  if (!(u_len > 0)) return false;
  u /= u_len;
  shape = Eigen::Matrix3d::Identity() - d * d.transpose();
  return true;
}

template <typename T>
Eigen::Matrix3d ToolStage<T>::ContactStiffness(const fem::Model<T>& model, const T* x) const {
  Eigen::Vector3d u;
  Eigen::Matrix3d shape;
  if (!StiffnessShape(u, shape)) return Eigen::Matrix3d::Zero();
  const double k_tissue = PatchStiffness(model, x, ForceNodes(), ForceWeights(), u, patch_);
  return SeriesStiffness(contact_stiffness_, k_tissue) * shape;
}

/// The tissue's stiffness along u for a load along u: 1/(uᵀ K⁻¹ u).
template <typename T>
Eigen::Matrix3d ToolStage<T>::ContactStiffness(const Eigen::Matrix3d& tissue) const {
  Eigen::Vector3d u;
  Eigen::Matrix3d shape;
  if (!StiffnessShape(u, shape)) return Eigen::Matrix3d::Zero();
  const double compliance = u.dot(tissue.ldlt().solve(u));
  const double k_tissue = compliance > 0 && std::isfinite(compliance) ? 1.0 / compliance : 0.0;
  return SeriesStiffness(contact_stiffness_, k_tissue) * shape;
}

template <typename T>
void ToolStage<T>::EnterCut(const CutSweep& sweep) {
  in_cut_ = true;  // the blade is in its own slit now (tool_contact.h, in-cut test)
  sweeps_.push_back(sweep);
}


namespace {

void PoseToProto(const ToolPose& pose, v1::CheckpointToolPose* out) {
  Vec3ToProto(pose.tip, out->mutable_tip());
  Vec3ToProto(pose.blade_dir, out->mutable_blade_dir());
}

ToolPose PoseFromPart(const v1::CheckpointToolPose& p, const std::string& source, const std::string& field) {
  return {Vec3FromPart(p.tip(), source, field + ".tip"), Vec3FromPart(p.blade_dir(), source, field + ".blade_dir")};
}

void NodesToProto(const std::array<int32_t, 3>& nodes, google::protobuf::RepeatedField<int32_t>* out) {
  out->Add(nodes.begin(), nodes.end());
}

std::array<int32_t, 3> NodesFromPart(const google::protobuf::RepeatedField<int32_t>& in) {
  return {in[0], in[1], in[2]};
}

void CheckNodes(const google::protobuf::RepeatedField<int32_t>& nodes, int32_t num_nodes, const std::string& source,
                const std::string& field) {
  if (nodes.size() != 3) FailPart(source, field, fmt::format("{} nodes, expected 3", nodes.size()));
  for (int k = 0; k < 3; ++k) CheckNodeOrNone(nodes[k], num_nodes, source, fmt::format("{}[{}]", field, k));
}

}  // namespace

template <typename T>
void ToolStage<T>::Save(v1::CheckpointBody& body) const {
  v1::ToolPart& p = *body.mutable_tool();
  PoseToProto(pose_, p.mutable_pose());
  if (external_pose_) PoseToProto(*external_pose_, p.mutable_external_pose());
  p.set_touching(facet_.touching);
  p.set_surface_tri(facet_.surface_tri);
  NodesToProto(facet_.nodes, p.mutable_facet_nodes());
  Vec3ToProto(facet_.bary, p.mutable_facet_bary());
  Vec3ToProto(facet_.point, p.mutable_facet_point());
  Vec3ToProto(facet_.normal, p.mutable_facet_normal());
  p.set_facet_depth(facet_.depth);
  p.set_closest_node(facet_.closest_node);
  p.set_in_slit(facet_.in_slit);
  p.set_on_cut(facet_.on_cut);
  p.set_grip_active(grip_.active);
  NodesToProto(grip_.nodes, p.mutable_grip_nodes());
  Vec3ToProto(grip_.bary, p.mutable_grip_bary());
  Vec3ToProto(grip_.offset, p.mutable_grip_offset());
  Vec3ToProto(grip_.stretch, p.mutable_grip_stretch());
  p.set_grip_topology_version(grip_.topology_version);
  p.set_in_cut(in_cut_);
  for (const CutSweep& s : sweeps_) {
    v1::ToolPart::Sweep* out = p.add_sweeps();
    Vec3ToProto(s.from, out->mutable_from());
    Vec3ToProto(s.to, out->mutable_to());
    Vec3ToProto(s.blade_dir, out->mutable_blade_dir());
  }
}

template <typename T>
void ToolStage<T>::Check(const v1::CheckpointBody& body, const PartCheck& check) const {
  const std::string& src = check.source;
  if (!body.has_tool()) FailPart(src, "tool", "missing: the checkpoint does not hold the tool's state");
  const v1::ToolPart& p = body.tool();
  (void)PoseFromPart(p.pose(), src, "tool.pose");
  if (p.has_external_pose()) (void)PoseFromPart(p.external_pose(), src, "tool.external_pose");
  CheckNodes(p.facet_nodes(), check.num_nodes, src, "tool.facet_nodes");
  CheckNodes(p.grip_nodes(), check.num_nodes, src, "tool.grip_nodes");
  CheckNodeOrNone(p.closest_node(), check.num_nodes, src, "tool.closest_node");
  if (p.surface_tri() < -1) FailPart(src, "tool.surface_tri", fmt::format("{} is negative", p.surface_tri()));
  for (const auto& [v, field] : {std::pair{&p.facet_bary(), "tool.facet_bary"}, {&p.facet_point(), "tool.facet_point"},
                                 {&p.facet_normal(), "tool.facet_normal"}, {&p.grip_bary(), "tool.grip_bary"},
                                 {&p.grip_offset(), "tool.grip_offset"}, {&p.grip_stretch(), "tool.grip_stretch"}}) {
    (void)Vec3FromPart(*v, src, field);
  }
  if (!std::isfinite(p.facet_depth())) FailPart(src, "tool.facet_depth", "not finite");
  // grip_topology_version counts the FEM model's topology changes, not the
  // cut mesh's versions the body carries, so it has no bound to check here:
  // a grip whose version differs from the restored model's is made anew at
  // the next contact, as after any topology change.
  // One swept area per cut step since the blade entered the tissue.
  if (static_cast<uint64_t>(p.sweeps_size()) > body.cuts()) {
    FailPart(src, "tool.sweeps", fmt::format("{} swept areas, more than the {} cut steps", p.sweeps_size(), body.cuts()));
  }
  for (int i = 0; i < p.sweeps_size(); ++i) {
    const std::string field = fmt::format("tool.sweeps[{}]", i);
    (void)Vec3FromPart(p.sweeps(i).from(), src, field + ".from");
    (void)Vec3FromPart(p.sweeps(i).to(), src, field + ".to");
    (void)Vec3FromPart(p.sweeps(i).blade_dir(), src, field + ".blade_dir");
  }
}

template <typename T>
void ToolStage<T>::Restore(const v1::CheckpointBody& body) {
  const v1::ToolPart& p = body.tool();
  const std::string none;  // checked before: nothing throws here
  pose_ = PoseFromPart(p.pose(), none, "");
  external_pose_.reset();
  if (p.has_external_pose()) external_pose_ = PoseFromPart(p.external_pose(), none, "");
  facet_.touching = p.touching();
  facet_.surface_tri = p.surface_tri();
  facet_.nodes = NodesFromPart(p.facet_nodes());
  facet_.bary = Vec3FromPart(p.facet_bary(), none, "");
  facet_.point = Vec3FromPart(p.facet_point(), none, "");
  facet_.normal = Vec3FromPart(p.facet_normal(), none, "");
  facet_.depth = p.facet_depth();
  facet_.closest_node = p.closest_node();
  facet_.in_slit = p.in_slit();
  facet_.on_cut = p.on_cut();
  grip_.active = p.grip_active();
  grip_.nodes = NodesFromPart(p.grip_nodes());
  grip_.bary = Vec3FromPart(p.grip_bary(), none, "");
  grip_.offset = Vec3FromPart(p.grip_offset(), none, "");
  grip_.stretch = Vec3FromPart(p.grip_stretch(), none, "");
  grip_.topology_version = p.grip_topology_version();
  in_cut_ = p.in_cut();
  sweeps_.clear();
  for (const v1::ToolPart::Sweep& s : p.sweeps()) {
    sweeps_.push_back({Vec3FromPart(s.from(), none, ""), Vec3FromPart(s.to(), none, ""),
                       Vec3FromPart(s.blade_dir(), none, "")});
  }
  applied_nodes_ = {-1, -1, -1};  // no contact force is on f_ext between frames
}

template class ToolStage<float>;
template class ToolStage<double>;

}  // namespace cutsim::sim
