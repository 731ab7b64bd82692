#pragma once
// Shared helpers for the cutting tests: a Kuhn-split box, a world that is
// the rest mesh, a brute-force "tool contact", and the invariant checks run
// after every cut.

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <random>
#include <set>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "common/cutting/cut_mesh.h"
#include "common/cutting/world_access.h"
#include "common/mesh/mesh_validation.h"
#include "common/mesh/surface.h"
#include "common/mesh/tet_mesh.h"

namespace cutsim::cutting::testing {

/// Box [lo, hi] with nx·ny·nz cubes, 6 Kuhn tets each (conforming), every
/// tet positively oriented. `jitter` moves interior nodes by up to that
/// fraction of the cell size (deterministic from `seed`).
inline mesh::TetMesh KuhnBox(const Eigen::Vector3d& lo, const Eigen::Vector3d& hi, int nx, int ny, int nz,
                             double jitter = 0.0, uint32_t seed = 1) {
  mesh::TetMesh m;
  const int NX = nx + 1, NY = ny + 1, NZ = nz + 1;
  m.nodes.resize(NX * NY * NZ, 3);
  const Eigen::Vector3d cell = (hi - lo).cwiseQuotient(Eigen::Vector3d(nx, ny, nz));
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  auto id = [&](int i, int j, int k) { return i + NX * (j + NY * k); };
  for (int k = 0; k < NZ; ++k)
    for (int j = 0; j < NY; ++j)
      for (int i = 0; i < NX; ++i) {
        Eigen::Vector3d p = lo + Eigen::Vector3d(i * cell.x(), j * cell.y(), k * cell.z());
        const bool interior = i > 0 && i < nx && j > 0 && j < ny && k > 0 && k < nz;
        if (jitter > 0.0 && interior) p += jitter * cell.cwiseProduct(Eigen::Vector3d(u(rng), u(rng), u(rng)));
        m.nodes.row(id(i, j, k)) = p.transpose();
      }
  const std::array<std::array<int, 3>, 6> perms = {
      {{0, 1, 2}, {0, 2, 1}, {1, 0, 2}, {1, 2, 0}, {2, 0, 1}, {2, 1, 0}}};
  m.tets.resize(6 * nx * ny * nz, 4);
  int row = 0;
  for (int k = 0; k < nz; ++k)
    for (int j = 0; j < ny; ++j)
      for (int i = 0; i < nx; ++i)
        for (const auto& p : perms) {
          std::array<int, 3> c{i, j, k};
          std::array<int32_t, 4> t{};
          t[0] = id(c[0], c[1], c[2]);
          for (int s = 0; s < 3; ++s) {
            c[static_cast<size_t>(p[static_cast<size_t>(s)])] += 1;
            t[static_cast<size_t>(s + 1)] = id(c[0], c[1], c[2]);
          }
          m.tets.row(row) << t[0], t[1], t[2], t[3];
          if (mesh::SignedVolume(m, row) < 0) std::swap(m.tets(row, 1), m.tets(row, 2));
          ++row;
        }
  return m;
}

inline VectorWorld WorldFromRest(const mesh::TetMesh& m) {
  std::vector<Eigen::Vector3d> x;
  for (int32_t i = 0; i < m.num_nodes(); ++i) x.emplace_back(m.nodes.row(i).transpose());
  return VectorWorld(std::move(x));
}

using FaceSet = std::set<std::array<int32_t, 3>>;

inline std::array<int32_t, 3> Sorted(int32_t a, int32_t b, int32_t c) {
  std::array<int32_t, 3> k{a, b, c};
  std::sort(k.begin(), k.end());
  return k;
}

/// Oriented triangles as a set of rotations starting at the smallest index.
inline std::set<std::array<int32_t, 3>> OrientedSet(const mesh::Triangles& tris) {
  std::set<std::array<int32_t, 3>> s;
  for (int r = 0; r < tris.rows(); ++r) {
    std::array<int32_t, 3> t{tris(r, 0), tris(r, 1), tris(r, 2)};
    while (t[0] != std::min({t[0], t[1], t[2]})) std::rotate(t.begin(), t.begin() + 1, t.end());
    s.insert(t);
  }
  return s;
}

/// What the uncut mesh looked like, for the invariant checks.
struct Reference {
  FaceSet surface_keys;             // sorted keys of the uncut surface
  std::vector<double> tet_mass;     // #T frozen element masses, kg (ρ = 1000)
  double total_mass = 0.0;
  explicit Reference(const mesh::TetMesh& m) {
    const mesh::Surface s = mesh::ExtractSurface(m.tets);
    for (int r = 0; r < s.tris.rows(); ++r) surface_keys.insert(Sorted(s.tris(r, 0), s.tris(r, 1), s.tris(r, 2)));
    for (int32_t t = 0; t < m.num_tets(); ++t) {
      tet_mass.push_back(1000.0 * mesh::SignedVolume(m, t));
      total_mass += tet_mass.back();
    }
  }
};

/// Every invariant a cut must keep; `what` names the step in failures.
inline void ExpectInvariants(const CutMesh& cm, const WorldAccess& world, const Reference& ref,
                             const std::string& what) {
  SCOPED_TRACE(what);
  const mesh::TetMesh rest = cm.RestMesh();
  ASSERT_EQ(cm.num_tets(), static_cast<int32_t>(ref.tet_mass.size())) << "element count changed";
  // Positive volume, rest and world.
  for (int32_t t = 0; t < cm.num_tets(); ++t) {
    const auto& n = cm.tet(t);
    ASSERT_GT(mesh::SignedVolume(rest, t), 0.0) << "rest volume of tet " << t;
    ASSERT_GT(mesh::SignedVolume(world.Get(n[0]), world.Get(n[1]), world.Get(n[2]), world.Get(n[3])), 0.0)
        << "world volume of tet " << t;
  }
  // Incidence consistent; mass from incident tets equals the uncut mass.
  double node_mass_total = 0.0;
  std::vector<int> uses(static_cast<size_t>(cm.num_tets()), 0);
  for (int32_t v = 0; v < cm.num_nodes(); ++v) {
    ASSERT_FALSE(cm.node_tets(v).empty()) << "node " << v << " has no tet";
    double mv = 0.0;
    for (const int32_t t : cm.node_tets(v)) {
      const auto& n = cm.tet(t);
      ASSERT_NE(std::find(n.begin(), n.end(), v), n.end());
      mv += ref.tet_mass[static_cast<size_t>(t)] / 4.0;
      ++uses[static_cast<size_t>(t)];
    }
    node_mass_total += mv;
  }
  for (const int u : uses) ASSERT_EQ(u, 4);
  EXPECT_NEAR(node_mass_total, ref.total_mass, 1e-12 * ref.total_mass);
  // Faces: at most two tets each; the incremental surface equals a fresh
  // extraction; closed 2-manifold; opened flags exactly on once-interior faces.
  EXPECT_EQ(mesh::FindOvershardFace(rest.tets), -1);
  std::vector<uint8_t> opened;
  const mesh::Triangles tris = cm.SurfaceTriangles(&opened);
  const mesh::Surface fresh = mesh::ExtractSurface(rest.tets);
  ASSERT_EQ(OrientedSet(tris), OrientedSet(fresh.tris)) << "incremental surface differs from extraction";
  const mesh::ManifoldCheck mc = mesh::CheckClosedManifold(tris);
  ASSERT_TRUE(mc.ok) << mc.problem;
  for (int r = 0; r < tris.rows(); ++r) {
    const auto key = Sorted(cm.origin(tris(r, 0)), cm.origin(tris(r, 1)), cm.origin(tris(r, 2)));
    const bool was_surface = ref.surface_keys.contains(key);
    ASSERT_EQ(opened[static_cast<size_t>(r)] != 0, !was_surface) << "opened flag of surface triangle " << r;
  }
}

}  // namespace cutsim::cutting::testing
