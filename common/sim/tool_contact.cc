#include "common/sim/tool_contact.h"

#include <algorithm>
#include <cmath>
#include <limits>

namespace cutsim::sim {
namespace {

constexpr double kFacingCosine = 0.2;  // n·d above this: the facet faces the handle

struct Facet {
  Eigen::Vector3d p0, p1, p2, n;
  bool ok = false;
};

Facet LoadFacet(const mesh::Positions& world, const mesh::Triangles& surface, int32_t f) {
  Facet out;
  out.p0 = world.row(surface(f, 0)).transpose();
  out.p1 = world.row(surface(f, 1)).transpose();
  out.p2 = world.row(surface(f, 2)).transpose();
  const Eigen::Vector3d cross = (out.p1 - out.p0).cross(out.p2 - out.p0);
  const double area2 = cross.norm();
  out.ok = area2 > 0.0;
  if (out.ok) out.n = cross / area2;
  return out;
}

void Fill(ContactFacet& c, const mesh::Triangles& surface, int32_t f, const Facet& facet,
          const Eigen::Vector3d& point, const Eigen::Vector3d& bary, const Eigen::Vector3d& tip) {
  c.touching = true;
  c.surface_tri = f;
  c.nodes = {surface(f, 0), surface(f, 1), surface(f, 2)};
  c.bary = bary;
  c.point = point;
  c.normal = facet.n;
  c.depth = std::max(0.0, (point - tip).dot(facet.n));
  int k = 0;
  bary.maxCoeff(&k);  // the vertex nearest C_p has the largest barycentric
  c.closest_node = c.nodes[static_cast<size_t>(k)];
}

/// Angle-weighted unit normal of the surface at `node` (the triangles of
/// `surface` around it, found through the BVH; split copies of a cut are
/// other nodes, so the two lips of a slit never mix). Zero if none.
Eigen::Vector3d VertexNormal(const mesh::TriangleBvh& bvh, const mesh::Positions& world,
                             const mesh::Triangles& surface, int32_t node, std::vector<int32_t>& boxes) {
  const Eigen::Vector3d p = world.row(node).transpose();
  const Eigen::Vector3d r = Eigen::Vector3d::Constant(1e-9 + 1e-9 * p.cwiseAbs().maxCoeff());
  bvh.QueryBox(p - r, p + r, boxes);
  Eigen::Vector3d sum = Eigen::Vector3d::Zero();
  for (const int32_t f : boxes) {
    int corner = -1;
    for (int k = 0; k < 3; ++k) corner = surface(f, k) == node ? k : corner;
    if (corner < 0) continue;
    const Facet facet = LoadFacet(world, surface, f);
    if (!facet.ok) continue;
    const Eigen::Vector3d q[3] = {facet.p0, facet.p1, facet.p2};
    const Eigen::Vector3d e1 = q[(corner + 1) % 3] - q[corner], e2 = q[(corner + 2) % 3] - q[corner];
    const double angle = std::atan2(e1.cross(e2).norm(), e1.dot(e2));  // in [0, π]
    sum += angle * facet.n;
  }
  const double len = sum.norm();
  return len > 0.0 ? Eigen::Vector3d(sum / len) : Eigen::Vector3d::Zero();
}

/// The contact normal of a chosen facet: barycentric blend of the
/// angle-weighted vertex normals (continuous across edges and vertices, so
/// which of the facets sharing an edge was taken does not matter); the
/// facet's own normal if the blend degenerates. Updates the depth with it.
void SmoothNormal(ContactFacet& c, const mesh::TriangleBvh& bvh, const mesh::Positions& world,
                  const mesh::Triangles& surface, const Eigen::Vector3d& tip, std::vector<int32_t>& boxes) {
  Eigen::Vector3d n = Eigen::Vector3d::Zero();
  for (int i = 0; i < 3; ++i) n += c.bary[i] * VertexNormal(bvh, world, surface, c.nodes[static_cast<size_t>(i)], boxes);
  const double len = n.norm();
  if (len > 1e-6) c.normal = n / len;
  c.depth = std::max(0.0, (c.point - tip).dot(c.normal));
}

/// Facet `f` is a wall or a lip of a cut: two of its nodes (an edge: a
/// wall's own, or a lip's edge on the cut line) lie on faces a cut opened.
/// Uncut tissue ahead of a cut front shares only the front vertex with them.
bool OnCut(const mesh::Triangles& surface, const std::vector<uint8_t>& wall_nodes, int32_t f) {
  if (wall_nodes.empty()) return false;
  int on_wall = 0;
  for (int k = 0; k < 3; ++k) on_wall += wall_nodes[static_cast<size_t>(surface(f, k))] != 0 ? 1 : 0;
  return on_wall >= 2;
}

}  // namespace

ContactFacet FindContactFacet(const mesh::TriangleBvh& bvh, const mesh::Positions& world,
                              const mesh::Triangles& surface, const Eigen::Vector3d& tip,
                              const Eigen::Vector3d& blade_dir, double blade_length,
                              double near_radius, std::vector<mesh::SegmentHit>& hits,
                              std::vector<int32_t>& boxes, const std::vector<uint8_t>& ignored, bool in_cut,
                              const std::vector<uint8_t>& wall_nodes) {
  ContactFacet best;
  // In its own cut a wall or lip is touched, not gripped (header, in-cut rule).
  auto finish = [&](ContactFacet& c) {
    if (!c.touching) return;
    SmoothNormal(c, bvh, world, surface, tip, boxes);
    if (in_cut) c.on_cut = OnCut(surface, wall_nodes, c.surface_tri);
  };
  auto skip = [&](int32_t f) { return !ignored.empty() && ignored[static_cast<size_t>(f)] != 0; };
  // 1. Where the blade enters: crossing nearest the handle, facing it.
  const Eigen::Vector3d handle = tip + blade_length * blade_dir;
  bvh.AllHits(handle, tip, hits);
  double best_t = std::numeric_limits<double>::infinity();
  for (const mesh::SegmentHit& h : hits) {
    if (skip(h.tri)) continue;
    const Facet facet = LoadFacet(world, surface, h.tri);
    if (!facet.ok || facet.n.dot(blade_dir) <= kFacingCosine || h.t >= best_t) continue;
    best_t = h.t;
    Fill(best, surface, h.tri, facet, h.point, h.bary, tip);
  }
  if (best.touching) {
    finish(best);
    return best;
  }
  // 2. The tip just under a facing facet (no crossing, e.g. pressed flat).
  const Eigen::Vector3d r = Eigen::Vector3d::Constant(near_radius);
  bvh.QueryBox(tip - r, tip + r, boxes);
  double best_distance = std::numeric_limits<double>::infinity();
  for (const int32_t f : boxes) {
    if (skip(f)) continue;
    const Facet facet = LoadFacet(world, surface, f);
    if (!facet.ok || facet.n.dot(blade_dir) <= kFacingCosine) continue;
    const mesh::ClosestPointHit hit = mesh::ClosestPointOnTriangle(tip, facet.p0, facet.p1, facet.p2);
    if (hit.distance > near_radius || hit.distance >= best_distance) continue;
    const Eigen::Vector3d to_facet = hit.point - tip;
    const double below = to_facet.dot(facet.n);
    if (below <= 0.0) continue;  // tip above this facet
    // Straight under it: the closest point is the projection along n. A tip
    // behind the plane of a slanted facet but outside the body, beside a
    // ridge, has its closest point on the facet's border instead.
    if ((to_facet - below * facet.n).norm() > 1e-6 * near_radius) continue;
    best_distance = hit.distance;
    Fill(best, surface, f, facet, hit.point, hit.bary, tip);
  }
  if (best.touching || !in_cut) {
    finish(best);
    return best;
  }
  // 3. Inside its own cut: the blade lies in the slit it opened and crosses
  // no facing facet. Take the facing facet nearest to the blade segment
  // (the lips of the slit, or the last uncut tissue around the cut front).
  const Eigen::Vector3d lo = tip.cwiseMin(handle) - r, hi = tip.cwiseMax(handle) + r;
  bvh.QueryBox(lo, hi, boxes);
  const Eigen::Vector3d seg = handle - tip;
  const double seg2 = seg.squaredNorm();
  auto on_segment = [&](const Eigen::Vector3d& q) {
    const double s = seg2 > 0.0 ? std::clamp((q - tip).dot(seg) / seg2, 0.0, 1.0) : 0.0;
    return Eigen::Vector3d(tip + s * seg);
  };
  for (const int32_t f : boxes) {
    if (skip(f)) continue;
    const Facet facet = LoadFacet(world, surface, f);
    if (!facet.ok || facet.n.dot(blade_dir) <= kFacingCosine) continue;
    // Closest pair segment–triangle by two alternations from the centroid
    // (exact enough at the scale of near_radius).
    Eigen::Vector3d p = on_segment((facet.p0 + facet.p1 + facet.p2) / 3.0);
    mesh::ClosestPointHit hit = mesh::ClosestPointOnTriangle(p, facet.p0, facet.p1, facet.p2);
    for (int k = 0; k < 2; ++k) {
      p = on_segment(hit.point);
      hit = mesh::ClosestPointOnTriangle(p, facet.p0, facet.p1, facet.p2);
    }
    if (hit.distance > near_radius || hit.distance >= best_distance) continue;
    best_distance = hit.distance;
    Fill(best, surface, f, facet, hit.point, hit.bary, tip);
  }
  finish(best);
  best.in_slit = best.touching;
  return best;
}

Eigen::Vector3d PenaltyForce(ContactFacet& facet, const Eigen::Vector3d& x0, const Eigen::Vector3d& x1,
                             const Eigen::Vector3d& x2, const Eigen::Vector3d& tip,
                             const Eigen::Vector3d& approach_velocity, double stiffness, double damping,
                             double indent_limit) {
  // The normal stays as FindContactFacet set it for the frame (see the header).
  facet.point = facet.bary[0] * x0 + facet.bary[1] * x1 + facet.bary[2] * x2;
  facet.depth = std::clamp((facet.point - tip).dot(facet.normal), 0.0, indent_limit);
  if (facet.depth <= 0.0) return Eigen::Vector3d::Zero();
  const double vn = approach_velocity.dot(facet.normal);  // < 0: tool moving inward
  const double push = stiffness * facet.depth + damping * std::max(0.0, -vn);
  return -push * facet.normal;
}

bool InSweptArea(const std::vector<CutSweep>& sweeps, const Eigen::Vector3d& point, double tolerance) {
  for (const CutSweep& sweep : sweeps) {
    // Along the cut: the sweep's part across the blade (sliding along
    // itself sweeps no area).
    const Eigen::Vector3d& d = sweep.blade_dir;
    Eigen::Vector3d along = sweep.to - sweep.from;
    along -= along.dot(d) * d;
    const double len2 = along.squaredNorm();
    if (!(len2 > 0.0)) continue;
    const Eigen::Vector3d rel = point - sweep.from;
    const double u = rel.dot(along) / len2;  // 0 at t0, 1 at the front
    const Eigen::Vector3d across = along.cross(d).normalized();
    if (u >= 0.0 && u <= 1.0 && std::abs(rel.dot(across)) <= tolerance) return true;
  }
  return false;
}

EdgeGrip MakeGrip(const ContactFacet& facet, const Eigen::Vector3d& hold, uint64_t topology_version) {
  EdgeGrip grip;
  grip.active = true;
  grip.nodes = facet.nodes;
  grip.bary = facet.bary;
  grip.offset = hold - facet.point;
  grip.topology_version = topology_version;
  return grip;
}

Eigen::Vector3d GripPoint(const EdgeGrip& grip, const Eigen::Vector3d& x0, const Eigen::Vector3d& x1,
                          const Eigen::Vector3d& x2) {
  return grip.bary[0] * x0 + grip.bary[1] * x1 + grip.bary[2] * x2 + grip.offset;
}

Eigen::Vector3d EdgeGripForce(EdgeGrip& grip, const Eigen::Vector3d& x0, const Eigen::Vector3d& x1,
                              const Eigen::Vector3d& x2, const Eigen::Vector3d& tip,
                              const Eigen::Vector3d& blade_dir, double stiffness, double limit) {
  const Eigen::Vector3d to_blade = tip - GripPoint(grip, x0, x1, x2);
  Eigen::Vector3d e = to_blade - to_blade.dot(blade_dir) * blade_dir;  // across the blade only
  const double len = e.norm();
  if (len > limit) {
    const Eigen::Vector3d capped = e * (limit / len);
    grip.offset += e - capped;  // the tissue end slides after the blade
    e = capped;
  }
  grip.stretch = e;
  return stiffness * e;  // pulls the gripped tissue toward the blade
}

}  // namespace cutsim::sim
