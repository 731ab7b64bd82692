#pragma once
/// @file
/// Scalpel–tissue contact: where the blade touches the surface, how hard the
/// tissue is pushed, and the force and stiffness the haptic side renders.
///
/// Contact model (penalty on the contact facet):
/// - The scalpel is a segment from its tip to the handle end, tip + L·d
///   (d = blade direction, tip → handle; L = blade length). Each physics
///   frame the surface BVH is refitted and the contact facet is where the
///   blade enters the tissue: the crossing of the segment handle → tip with
///   a surface triangle whose outward normal faces the handle (n·d > 0.2),
///   the one nearest the handle. Side walls opened by a cut (n ⟂ d) and the
///   far side of the body are therefore never taken for the touched face.
///   Without a crossing the tip may still be just under a facet (the blade
///   pressed flat): the facing facet nearest to the tip within one mean
///   edge length counts too, if the tip lies straight under it (its
///   closest point on the facet is its projection along the normal; a tip
///   behind the plane of a slanted facet beside a ridge is outside).
/// - Only tissue the blade can push counts: facets flagged in `ignored`
///   (the sim flags those of debris, pieces cut loose with less than 1% of
///   the body's mass and fewer than 64 tets) are passed through. A penalty
///   force sized for the body (k·δ with δ capped at the indentation limit,
///   reached at once when the blade is already inside) would accelerate
///   such a crumb of a few milligrams to metres per second.
/// - Indentation δ = (C_p − tip)·n, capped at `indent_limit` (one mean edge
///   length): a blade pushed deeper is inside the tissue (in its own cut),
///   where the cut, not the surface layer, carries it.
/// - One contact per tool: the normal n is not the facet's own but the
///   barycentric blend at C_p of the angle-weighted vertex normals of the
///   surface, so it is continuous across edges and vertices (the blade on
///   an edge or corner gets the same push whichever facet was taken).
/// - During the frame's substeps the facet, the barycentrics b of C_p and
///   the normal n stay fixed; C_p = Σ bᵢxᵢ follows the facet's nodes and
///   the tip is interpolated over the frame. The tissue receives fᵢ = bᵢ·F
///   with F = −(k δ + c·max(0, −v·n)) n (a spring along the normal and a
///   damper that only resists approach, so the contact never pulls); the
///   tool receives −F. Updating the depth every substep keeps the penalty
///   stable at any frame rate. With n fixed the spring is conservative,
///   ½k((C_p − tip)·n)², and its stiffness is exactly k·(b bᵀ)⊗(n nᵀ), the
///   term the contact-limited substep adds (Simulation); a normal that
///   followed the deformed facet was a follower force, with geometric
///   stiffness k·δ/ℓ that no step estimate saw, and it blew up a block
///   pushed on its corner edge (bench/README.md, stability suite).
/// - Edge coupling of a blade inside the tissue. The penalty above is the
///   tip pressing on a face. Once the contact point is more than the
///   indentation limit up the blade from the tip ((C_p − tip)·d > limit:
///   the tip went through the surface, or the blade stands in its own
///   cut), the blade is *inside* and what loads the tissue is its edge
///   drawn sideways, not its tip: (C_p − tip)·n then measured the slant of
///   the crossed facet, flipped between 0 and the cap from frame to frame
///   and pushed along the facet normal whatever way the blade moved.
///   Inside, the blade grips the tissue where it crosses the surface
///   (EdgeGrip: a material point Σbᵢxᵢ of the facet plus a world offset)
///   with a spring of the same k acting only across the blade,
///   e = (I − d dᵀ)(tip − A): the blade slides freely along itself, and
///   the tissue is pushed along the blade's sideways motion. The stretch
///   is capped at one mean edge (twice the indentation limit, so a coarse
///   mesh still reaches its critical stress): beyond it the gripped point
///   slides after the blade (the offset takes up the excess), so the force
///   stays k·limit along the motion while the blade is drawn through
///   uncut tissue (a steady cutting resistance) and falls back as the
///   blade returns. A cut releases the grip (the tissue gave way: the
///   force drops and the haptic side renders the decay); the grip is
///   re-taken at the new crossing. When the offset exceeds half the cap
///   the grip moves to the current crossing, keeping its world point, so
///   the force stays continuous and acts on the facet at the blade.
/// - In its own cut (a cut executed since the blade last lost contact).
///   The cut opens a slit around the blade, which may then cross no facing
///   facet: the in-cut test takes the facing facet nearest to the blade
///   segment within one mean edge (`in_slit`), so the contact, C_p and
///   v_c, and with them the cut's t0, persist while the blade stands in
///   its slit. In the slit the blade's faces lie along the walls and the
///   lips close up behind it: a real blade there feels at most friction
///   (not modelled); only tissue not yet cut resists its edge. Gripping
///   whatever the contact found instead dragged the cut's own lips after
///   the blade: a severed ligament's stump was pulled along at ≈ k·limit
///   until the blade was lifted out, and a blade drawn back along its slit
///   was held at k·limit. So, in its own cut, a contact facet is *on the
///   cut* (`on_cut`), touched but never gripped and never pushed by the
///   tip (any grip is released), when
///   * it is a wall or lip of a cut: two of its nodes (an edge) lie on
///     faces a cut opened, while the tissue ahead of a cut front shares
///     only the front vertex with them; or
///   * C_p lies behind the cut front: in the area the blade swept in this
///     contact's cut steps (CutSweep: tip at t0 → tip at the cut, along
///     the blade), within the indentation limit across it. The separation
///     follows element faces, up to an element off the blade's plane, so
///     an element the cut left whole can still straddle the blade there;
///     the blade has cut through it all the same.
///   A new grip is taken only where the blade crosses (or the tip lies
///   under) tissue that is not on the cut, which is where the blade drawn
///   forward meets the tissue ahead of the front: there the steady
///   resistance and the stress that reaches K_I are unchanged. An in-slit
///   contact keeps a grip the blade still holds but never takes one: the
///   last bridge of a cut can deform past the edge (the blade's line
///   leaves the body through its end face while the tissue is still
///   hooked on it, as at the block's far end), whereas what lies near a
///   blade that has cut through is the side of a severed part, not tissue
///   at its edge. A cut releases every grip, so after the step that severs
///   a part nothing is held. At the mesh's resolution a lip is the whole
///   facet along the slit: a blade turned out of its slit into the lip's
///   tissue is gripped a facet further on.
/// - The haptic stiffness is derived from the FEM, not a constant (see
///   Simulation::ContactStiffness): the tissue's local stiffness at the
///   contact k_t = 1/(fᵀK⁻¹f), the point stiffness for the load f = b ⊗ n
///   of the tangent K (current state) of the free nodes within two rings
///   of the facet, in series with the contact spring:
///   K = k·k_t/(k + k_t) · n nᵀ (across the blade, (I − d dᵀ), for the
///   edge grip). It stiffens with deformation, as StVK does.

#include <array>
#include <cstdint>
#include <vector>

#include <Eigen/Core>

#include "common/mesh/bvh.h"
#include "common/mesh/tet_mesh.h"

namespace cutsim::sim {

/// The facet the tool touches this frame.
struct ContactFacet {
  bool touching = false;
  int32_t surface_tri = -1;               ///< Row in the surface triangle list.
  std::array<int32_t, 3> nodes{-1, -1, -1};
  Eigen::Vector3d bary = Eigen::Vector3d::Zero();
  Eigen::Vector3d point = Eigen::Vector3d::Zero();   ///< C_p, m
  Eigen::Vector3d normal = Eigen::Vector3d::UnitZ(); ///< outward, unit
  double depth = 0.0;                                 ///< δ ≥ 0, m
  int32_t closest_node = -1;                          ///< v_c: facet node nearest to C_p
  bool in_slit = false;  ///< Found by the in-cut test: the blade crosses no facet (file comment).
  /// On the blade's own cut, touched but not gripped (file comment): a wall
  /// or lip (set here with in_cut) or behind the cut front (InSweptArea,
  /// set by the caller).
  bool on_cut = false;
};

/// The blade's grip on the tissue it is inside (file comment, edge coupling).
struct EdgeGrip {
  bool active = false;
  std::array<int32_t, 3> nodes{-1, -1, -1};           ///< Gripped facet's nodes.
  Eigen::Vector3d bary = Eigen::Vector3d::Zero();     ///< Material point on the facet.
  Eigen::Vector3d offset = Eigen::Vector3d::Zero();   ///< Spring's tissue end − Σbᵢxᵢ, world, m.
  Eigen::Vector3d stretch = Eigen::Vector3d::Zero();  ///< Last capped e (⟂ blade), m.
  uint64_t topology_version = 0;                      ///< Mesh version the nodes belong to.
};

/// The area one cut step's blade swept: the blade from the tip at t0 to the
/// tip at the cut. Tissue there is cut, whatever element faces the
/// separation followed (file comment, in its own cut).
struct CutSweep {
  Eigen::Vector3d from = Eigen::Vector3d::Zero();       ///< Tip at t0, m.
  Eigen::Vector3d to = Eigen::Vector3d::Zero();         ///< Tip at the cut, m.
  Eigen::Vector3d blade_dir = Eigen::Vector3d::UnitZ(); ///< Unit, tip → handle.
};

/// `point` lies behind a cut front: in the area one of `sweeps` covers
/// along the cut, within `tolerance` (m) across it.
bool InSweptArea(const std::vector<CutSweep>& sweeps, const Eigen::Vector3d& point, double tolerance);

/// Grips `facet` (its nodes, barycentrics and current point C_p) so that
/// the spring's tissue end is at `hold` (world, m): hold = C_p starts
/// unloaded, hold = the previous grip's end keeps the force continuous.
EdgeGrip MakeGrip(const ContactFacet& facet, const Eigen::Vector3d& hold, uint64_t topology_version);

/// World position of the grip's tissue end for the current node positions.
Eigen::Vector3d GripPoint(const EdgeGrip& grip, const Eigen::Vector3d& x0, const Eigen::Vector3d& x1,
                          const Eigen::Vector3d& x2);

/// Edge-coupling force on the tissue (N, to be split as bᵢF) for the blade
/// line through `tip` along unit `blade_dir`: k·e with e the stretch across
/// the blade capped at `limit`; an uncapped stretch beyond it slides the
/// tissue end (grip.offset) so that |e| = limit. Updates `grip.stretch`.
Eigen::Vector3d EdgeGripForce(EdgeGrip& grip, const Eigen::Vector3d& x0, const Eigen::Vector3d& x1,
                              const Eigen::Vector3d& x2, const Eigen::Vector3d& tip,
                              const Eigen::Vector3d& blade_dir, double stiffness, double limit);

/// Finds the contact facet of the blade (tip, unit direction tip → handle,
/// length) on a surface (see file comment). `near_radius` is the reach of
/// the tip-only test and of the in-cut test; `hits` and `boxes` are
/// scratch; `ignored` (empty, or one flag per surface triangle) marks facets
/// never taken; `in_cut` enables the in-cut test and the `on_cut` flag,
/// read from `wall_nodes` (empty, or one flag per node: on a face a cut
/// opened) (file comment).
ContactFacet FindContactFacet(const mesh::TriangleBvh& bvh, const mesh::Positions& world,
                              const mesh::Triangles& surface, const Eigen::Vector3d& tip,
                              const Eigen::Vector3d& blade_dir, double blade_length,
                              double near_radius, std::vector<mesh::SegmentHit>& hits,
                              std::vector<int32_t>& boxes, const std::vector<uint8_t>& ignored = {},
                              bool in_cut = false, const std::vector<uint8_t>& wall_nodes = {});

/// Penalty force on the tissue at the facet for the current facet node
/// positions: returns F (the force on the tissue, N, to be split as bᵢF) and
/// updates `facet.point` and `facet.depth`; `facet.normal` (set by
/// FindContactFacet for the frame) is not changed.
Eigen::Vector3d PenaltyForce(ContactFacet& facet, const Eigen::Vector3d& x0, const Eigen::Vector3d& x1,
                             const Eigen::Vector3d& x2, const Eigen::Vector3d& tip,
                             const Eigen::Vector3d& approach_velocity, double stiffness, double damping,
                             double indent_limit);

}  // namespace cutsim::sim
