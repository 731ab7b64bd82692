#include "common/mesh/bvh.h"

#include <random>

#include <gtest/gtest.h>

#include "common/mesh/generators.h"
#include "common/mesh/surface.h"

namespace cutsim::mesh {
namespace {

using Eigen::Vector3d;

// Random triangle soup plus the surface of a cylinder: both shapes of input.
struct Scene {
  Positions x;
  Triangles tris;
};

Scene RandomSoup(std::mt19937& rng, int n) {
  std::uniform_real_distribution<double> u(-1.0, 1.0), small(-0.2, 0.2);
  Scene s;
  s.x.resize(3 * n, 3);
  s.tris.resize(n, 3);
  for (int f = 0; f < n; ++f) {
    const Vector3d c(u(rng), u(rng), u(rng));
    for (int k = 0; k < 3; ++k) s.x.row(3 * f + k) = (c + Vector3d(small(rng), small(rng), small(rng))).transpose();
    s.tris.row(f) << 3 * f, 3 * f + 1, 3 * f + 2;
  }
  return s;
}

void CheckAgainstBruteForce(const Scene& s, const TriangleBvh& bvh, std::mt19937& rng) {
  std::uniform_real_distribution<double> u(-1.3, 1.3);
  auto corner = [&](Eigen::Index f, int k) -> Vector3d { return s.x.row(s.tris(f, k)).transpose(); };
  std::vector<SegmentHit> hits;
  std::vector<int32_t> boxed;
  for (int q = 0; q < 100; ++q) {
    const Vector3d p(u(rng), u(rng), u(rng));
    const double radius = 0.3;
    double best = radius;
    int32_t best_f = -1;
    for (Eigen::Index f = 0; f < s.tris.rows(); ++f) {
      if (s.tris(f, 0) < 0) continue;  // dead id
      const double d = ClosestPointOnTriangle(p, corner(f, 0), corner(f, 1), corner(f, 2)).distance;
      if (d < best || (d == best && best_f < 0)) {  // ascending ids: ties keep the lowest
        best = d;
        best_f = static_cast<int32_t>(f);
      }
    }
    const auto hit = bvh.ClosestPoint(p, radius);
    ASSERT_EQ(hit.has_value(), best_f >= 0);
    if (hit) {
      EXPECT_EQ(hit->tri, best_f) << "ties go to the lowest id, whatever the tree's shape";
      EXPECT_EQ(hit->distance, best);
      const Vector3d rebuilt = hit->bary[0] * corner(hit->tri, 0) + hit->bary[1] * corner(hit->tri, 1) +
                               hit->bary[2] * corner(hit->tri, 2);
      EXPECT_NEAR((rebuilt - hit->point).norm(), 0.0, 1e-12);
      EXPECT_NEAR(hit->bary.sum(), 1.0, 1e-12);
      EXPECT_GE(hit->bary.minCoeff(), -1e-12);
    }
    // Segments.
    const Vector3d a(u(rng), u(rng), u(rng)), b(u(rng), u(rng), u(rng));
    std::vector<int32_t> brute;
    double first_t = 2.0;
    int32_t first_f = -1;
    for (Eigen::Index f = 0; f < s.tris.rows(); ++f) {
      if (s.tris(f, 0) < 0) continue;
      if (auto h = IntersectSegmentTriangle(a, b, corner(f, 0), corner(f, 1), corner(f, 2))) {
        brute.push_back(static_cast<int32_t>(f));
        if (h->t < first_t) {
          first_t = h->t;
          first_f = static_cast<int32_t>(f);
        }
      }
    }
    bvh.AllHits(a, b, hits);
    std::vector<int32_t> got;
    for (const auto& h : hits) got.push_back(h.tri);
    EXPECT_EQ(got, brute) << "sorted by id";
    const auto first = bvh.FirstHit(a, b);
    ASSERT_EQ(first.has_value(), !brute.empty());
    if (first) {
      EXPECT_EQ(first->t, first_t);
      EXPECT_EQ(first->tri, first_f);
    }
    // Boxes.
    const Vector3d lo = p - Vector3d::Constant(0.2), hi = p + Vector3d::Constant(0.25);
    std::vector<int32_t> brute_box;
    for (Eigen::Index f = 0; f < s.tris.rows(); ++f) {
      if (s.tris(f, 0) < 0) continue;
      const Vector3d tl = corner(f, 0).cwiseMin(corner(f, 1)).cwiseMin(corner(f, 2));
      const Vector3d th = corner(f, 0).cwiseMax(corner(f, 1)).cwiseMax(corner(f, 2));
      if ((tl.array() <= hi.array()).all() && (lo.array() <= th.array()).all()) brute_box.push_back(static_cast<int32_t>(f));
    }
    bvh.QueryBox(lo, hi, boxed);
    EXPECT_EQ(boxed, brute_box) << "sorted by id";
  }
}

TEST(TriangleBvh, MatchesBruteForceOnRandomSoup) {
  std::mt19937 rng(42);
  const Scene s = RandomSoup(rng, 300);
  const TriangleBvh bvh(s.x, s.tris);
  CheckAgainstBruteForce(s, bvh, rng);
}

TEST(TriangleBvh, RefitTracksMovedNodes) {
  std::mt19937 rng(7);
  const TetMesh cyl = MakeCylinder(0.8, 2.0, 16, 2, 6);
  Scene s{cyl.nodes, ExtractSurface(cyl.tets).tris};
  s.x.col(0).array() -= 1.0;
  TriangleBvh bvh(s.x, s.tris);
  CheckAgainstBruteForce(s, bvh, rng);
  // Twist and squash the surface, refit, and compare again.
  for (Eigen::Index i = 0; i < s.x.rows(); ++i) {
    const double a = 0.4 * s.x(i, 0);
    const double y = s.x(i, 1), z = s.x(i, 2);
    s.x(i, 1) = std::cos(a) * y - std::sin(a) * z;
    s.x(i, 2) = 0.7 * (std::sin(a) * y + std::cos(a) * z);
  }
  const int32_t nodes_before = bvh.num_nodes();
  bvh.Refit(s.x);
  EXPECT_EQ(bvh.num_nodes(), nodes_before);
  CheckAgainstBruteForce(s, bvh, rng);
}

// Local edits (what a cut does to the surface): random removals and
// insertions by id, reusing freed ids and growing the id space, enough to
// split full leaves and trigger the amortised rebuild, and re-inserting
// live ids with a moved corner; queries must match
// brute force over the live ids after every batch, with and without a refit.
TEST(TriangleBvh, InsertRemoveMatchBruteForce) {
  std::mt19937 rng(11);
  const Scene all = RandomSoup(rng, 900);
  Scene s = all;
  for (Eigen::Index f = 300; f < s.tris.rows(); ++f) s.tris.row(f).setConstant(-1);  // ids 300+ dead
  const Triangles first = s.tris.topRows(400);  // the tree starts with 400 ids, 300 live
  TriangleBvh bvh(s.x, first);
  EXPECT_EQ(bvh.num_live_triangles(), 300);
  std::uniform_int_distribution<int> pick(0, 899), coin(0, 2);
  for (int batch = 0; batch < 12; ++batch) {
    for (int op = 0; op < 40; ++op) {
      const int f = pick(rng);
      if (s.tris(f, 0) >= 0 && coin(rng) == 0) {
        bvh.Remove(f);
        s.tris.row(f).setConstant(-1);
        EXPECT_FALSE(bvh.alive(f));
      } else if (s.tris(f, 0) < 0) {
        s.tris.row(f) = all.tris.row(f);
        bvh.Insert(f, {s.tris(f, 0), s.tris(f, 1), s.tris(f, 2)}, s.x);
        EXPECT_TRUE(bvh.alive(f));
      } else {
        // Re-insert a live id with a corner moved (soup: no other triangle
        // has it), by a little (stays in its leaf's box) or a lot (leaves).
        const double step = coin(rng) == 0 ? 0.3 : 1e-4;
        s.x(s.tris(f, 0), 0) += step;
        bvh.Insert(f, {s.tris(f, 0), s.tris(f, 1), s.tris(f, 2)}, s.x);
        EXPECT_TRUE(bvh.alive(f));
      }
    }
    if (batch % 3 == 2) {  // move the nodes too, as physics does between cuts
      s.x.array() += 0.01;
      bvh.Refit(s.x);
    }
    int live = 0;
    for (Eigen::Index f = 0; f < s.tris.rows(); ++f) live += s.tris(f, 0) >= 0 ? 1 : 0;
    EXPECT_EQ(bvh.num_live_triangles(), live);
    CheckAgainstBruteForce(s, bvh, rng);
  }
  EXPECT_GT(bvh.rebuilds(), 0) << "enough insertions to rebuild at least once";
}

// A tree edited as cuts edit it (faces removed, re-inserted under other
// ids, leaves split) answers exactly as one built from scratch over the same
// faces: same ids in the same order, same points bit for bit. The queries
// sit just outside surface vertices, where the faces around a vertex tie on
// the closest point (all their closest points are the vertex itself).
TEST(TriangleBvh, EditedTreeAnswersExactlyAsARebuiltOne) {
  std::mt19937 rng(5);
  const TetMesh box = MakeBox(Vector3d::Zero(), Vector3d(1.0, 0.6, 0.4), 10, 6, 4);
  const Triangles surface = ExtractSurface(box.tets).tris;
  const auto num_faces = static_cast<int32_t>(surface.rows());
  // Id space twice the faces: every face lives under id f or f + num_faces.
  Triangles tris = Triangles::Constant(2 * num_faces, 3, -1);
  tris.topRows(num_faces) = surface;
  TriangleBvh edited(box.nodes, tris);
  std::uniform_int_distribution<int32_t> pick(0, num_faces - 1);
  for (int op = 0; op < 3 * num_faces; ++op) {
    const int32_t f = pick(rng);
    const int32_t from = tris(f, 0) >= 0 ? f : f + num_faces;
    const int32_t to = from == f ? f + num_faces : f;
    tris.row(to) = tris.row(from);
    tris.row(from).setConstant(-1);
    edited.Remove(from);
    edited.Insert(to, {tris(to, 0), tris(to, 1), tris(to, 2)}, box.nodes);
  }
  const TriangleBvh rebuilt(box.nodes, tris);
  const Vector3d hi(1.0, 0.6, 0.4), centre = 0.5 * hi;
  std::vector<int32_t> boxes_a, boxes_b;
  std::vector<SegmentHit> hits_a, hits_b;
  int ties = 0;
  for (Eigen::Index v = 0; v < box.nodes.rows(); ++v) {
    const Vector3d x = box.nodes.row(v).transpose();
    // Outward along the box's faces through x: every face around x has its
    // closest point at x.
    Vector3d out = Vector3d::Zero();
    for (int k = 0; k < 3; ++k) out[k] = x[k] == 0.0 ? -1.0 : (x[k] == hi[k] ? 1.0 : 0.0);
    const Vector3d q = x + 1e-3 * out;
    const auto a = edited.ClosestPoint(q, 0.05), b = rebuilt.ClosestPoint(q, 0.05);
    ASSERT_EQ(a.has_value(), b.has_value());
    if (!a) continue;
    EXPECT_EQ(a->tri, b->tri) << "vertex " << v;
    EXPECT_EQ(a->point, b->point);
    if (a->point == x) ++ties;
    const Vector3d r = Vector3d::Constant(1e-3);
    edited.QueryBox(x - r, x + r, boxes_a);
    rebuilt.QueryBox(x - r, x + r, boxes_b);
    EXPECT_EQ(boxes_a, boxes_b) << "vertex " << v;
    edited.AllHits(q, centre, hits_a);
    rebuilt.AllHits(q, centre, hits_b);
    ASSERT_EQ(hits_a.size(), hits_b.size());
    for (size_t k = 0; k < hits_a.size(); ++k) {
      EXPECT_EQ(hits_a[k].tri, hits_b[k].tri);
      EXPECT_EQ(hits_a[k].point, hits_b[k].point);
    }
    const auto fa = edited.FirstHit(q, centre), fb = rebuilt.FirstHit(q, centre);
    ASSERT_EQ(fa.has_value(), fb.has_value());
    if (fa) {
      EXPECT_EQ(fa->tri, fb->tri);
    }
  }
  EXPECT_GT(ties, 100) << "the queries should exercise ties";
}

TEST(ClosestPointOnTriangle, RegionsAndDegenerate) {
  const Vector3d p0(0, 0, 0), p1(1, 0, 0), p2(0, 1, 0);
  auto h = ClosestPointOnTriangle(Vector3d(0.2, 0.2, 1.0), p0, p1, p2);
  EXPECT_NEAR(h.distance, 1.0, 1e-15);
  EXPECT_TRUE(h.bary.isApprox(Vector3d(0.6, 0.2, 0.2)));
  h = ClosestPointOnTriangle(Vector3d(2, -1, 0), p0, p1, p2);
  EXPECT_TRUE(h.point.isApprox(p1));
  h = ClosestPointOnTriangle(Vector3d(1, 1, 0), p0, p1, p2);
  EXPECT_TRUE(h.point.isApprox(Vector3d(0.5, 0.5, 0)));
  // Degenerate (collinear) triangle: finite answer, no NaN.
  h = ClosestPointOnTriangle(Vector3d(0.5, 1, 0), p0, p1, Vector3d(2, 0, 0));
  EXPECT_TRUE(h.point.allFinite());
  EXPECT_NEAR(h.distance, 1.0, 1e-12);
}

}  // namespace
}  // namespace cutsim::mesh
