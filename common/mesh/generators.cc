#include "common/mesh/generators.h"

#include <array>
#include <cmath>
#include <map>
#include <numbers>
#include <vector>

#include <fmt/format.h>

#include "common/core/error.h"
#include "common/mesh/mesh_validation.h"

namespace cutsim::mesh {

using Eigen::Vector3d;

void CheckGeneratedSize(const SourceRef& where, double nodes, double tets) {
  if (!(nodes <= static_cast<double>(kMaxMeshNodes)) || !(tets <= static_cast<double>(kMaxMeshTets))) {
    ThrowInputError(where,
                    fmt::format("would make {:.3g} nodes and {:.3g} tetrahedra: meshes are limited to {} nodes and {} "
                                "tetrahedra",
                                nodes, tets, kMaxMeshNodes, kMaxMeshTets));
  }
}

TetMesh MakeBox(const Vector3d& lo, const Vector3d& hi, int nx, int ny, int nz) {
  if (nx < 1 || ny < 1 || nz < 1 || !((hi - lo).array() > 0.0).all()) {
    ThrowInputError(SourceRef{.field = "MakeBox"}, fmt::format("needs hi > lo and ≥ 1 cell per axis, got {}×{}×{}", nx, ny, nz));
  }
  // Sizes in double first: (nx + 1)(ny + 1)(nz + 1) overflows any integer
  // type for hostile cell counts.
  CheckGeneratedSize(SourceRef{.field = "MakeBox"}, (nx + 1.0) * (ny + 1.0) * (nz + 1.0), 6.0 * nx * ny * nz);
  auto id = [&](int i, int j, int k) { return static_cast<int32_t>(i + (nx + 1) * (j + (ny + 1) * k)); };
  TetMesh mesh;
  mesh.nodes.resize(static_cast<Eigen::Index>(nx + 1) * (ny + 1) * (nz + 1), 3);
  for (int k = 0; k <= nz; ++k) {
    for (int j = 0; j <= ny; ++j) {
      for (int i = 0; i <= nx; ++i) {
        const Vector3d f(static_cast<double>(i) / nx, static_cast<double>(j) / ny, static_cast<double>(k) / nz);
        mesh.nodes.row(id(i, j, k)) = (lo + f.cwiseProduct(hi - lo)).transpose();
      }
    }
  }
  // Kuhn split: one tet per axis permutation, walking 000 → 111 one axis at a
  // time. Every cell uses the same diagonal direction, so faces conform.
  static constexpr std::array<std::array<int, 3>, 6> kPerms = {
      {{0, 1, 2}, {0, 2, 1}, {1, 0, 2}, {1, 2, 0}, {2, 0, 1}, {2, 1, 0}}};
  mesh.tets.resize(6 * static_cast<Eigen::Index>(nx) * ny * nz, 4);
  Eigen::Index t = 0;
  for (int k = 0; k < nz; ++k) {
    for (int j = 0; j < ny; ++j) {
      for (int i = 0; i < nx; ++i) {
        for (const auto& p : kPerms) {
          std::array<int, 3> c{i, j, k};
          mesh.tets(t, 0) = id(c[0], c[1], c[2]);
          for (int s = 0; s < 3; ++s) {
            ++c[static_cast<size_t>(p[static_cast<size_t>(s)])];
            mesh.tets(t, s + 1) = id(c[0], c[1], c[2]);
          }
          ++t;
        }
      }
    }
  }
  OrientTets(mesh);  // odd permutations come out negative
  ValidateTetMesh(mesh, "MakeBox");
  return mesh;
}

TetMesh MakeCylinder(double radius, double length, int segments, int rings, int slices) {
  if (!(radius > 0.0) || !(length > 0.0) || segments < 3 || rings < 1 || slices < 1) {
    ThrowInputError(SourceRef{.field = "MakeCylinder"},
                    fmt::format("needs radius, length > 0, segments ≥ 3, rings ≥ 1, slices ≥ 1 (got {}, {}, {}, {}, {})",
                                radius, length, segments, rings, slices));
  }
  // About segments·rings/2 nodes and segments·rings triangles per cross-section.
  CheckGeneratedSize(SourceRef{.field = "MakeCylinder"}, (1.0 + 0.5 * segments * (rings + 1.0)) * (slices + 1.0),
                     3.0 * segments * (rings + 1.0) * slices);
  // Cross-section in the (y, z) plane: centre node 0, then ring by ring.
  std::vector<double> y{0.0}, z{0.0};
  std::vector<int32_t> ring_start{0};
  std::vector<int> ring_count{1};
  for (int r = 1; r <= rings; ++r) {
    const int count = std::max(3, static_cast<int>(std::lround(static_cast<double>(segments) * r / rings)));
    ring_start.push_back(static_cast<int32_t>(y.size()));
    ring_count.push_back(count);
    const double rad = radius * r / rings;
    for (int s = 0; s < count; ++s) {
      const double a = 2.0 * std::numbers::pi * s / count;
      y.push_back(rad * std::cos(a));
      z.push_back(rad * std::sin(a));
    }
  }
  std::vector<std::array<int32_t, 3>> tri2d;
  for (int r = 0; r < rings; ++r) {
    // Zipper between ring r (m nodes) and ring r+1 (n nodes): advance on the
    // ring whose next node has the smaller angle; ring 0 is the centre.
    const int m = ring_count[static_cast<size_t>(r)], n = ring_count[static_cast<size_t>(r) + 1];
    const int32_t a0 = ring_start[static_cast<size_t>(r)], b0 = ring_start[static_cast<size_t>(r) + 1];
    if (m == 1) {
      for (int s = 0; s < n; ++s) tri2d.push_back({a0, b0 + s, b0 + (s + 1) % n});
      continue;
    }
    int i = 0, j = 0;
    while (i < m || j < n) {
      const double next_a = static_cast<double>(i + 1) / m, next_b = static_cast<double>(j + 1) / n;
      if (j >= n || (i < m && next_a <= next_b)) {
        tri2d.push_back({a0 + i % m, b0 + j % n, a0 + (i + 1) % m});
        ++i;
      } else {
        tri2d.push_back({a0 + i % m, b0 + j % n, b0 + (j + 1) % n});
        ++j;
      }
    }
  }
  const auto n2d = static_cast<int32_t>(y.size());
  TetMesh mesh;
  mesh.nodes.resize(static_cast<Eigen::Index>(n2d) * (slices + 1), 3);
  for (int l = 0; l <= slices; ++l) {
    for (int32_t v = 0; v < n2d; ++v) {
      mesh.nodes.row(static_cast<Eigen::Index>(l) * n2d + v) << length * l / slices, y[static_cast<size_t>(v)],
          z[static_cast<size_t>(v)];
    }
  }
  // Each prism (a,b,c | a',b',c'), a<b<c by global index, becomes 3 tets;
  // every quad face is cut from its lowest-index bottom node to the other
  // node's top copy, a rule both neighbours share, so faces conform.
  mesh.tets.resize(3 * static_cast<Eigen::Index>(tri2d.size()) * slices, 4);
  Eigen::Index t = 0;
  for (int l = 0; l < slices; ++l) {
    for (auto tri : tri2d) {
      std::sort(tri.begin(), tri.end());
      const int32_t a = l * n2d + tri[0], b = l * n2d + tri[1], c = l * n2d + tri[2];
      const int32_t a1 = a + n2d, b1 = b + n2d, c1 = c + n2d;
      mesh.tets.row(t++) << a, b, c, c1;
      mesh.tets.row(t++) << a, b, b1, c1;
      mesh.tets.row(t++) << a, a1, b1, c1;
    }
  }
  OrientTets(mesh);
  ValidateTetMesh(mesh, "MakeCylinder");
  return mesh;
}

void MakeOrganSurface(const OrganOptions& options, Positions& positions, Triangles& tris) {
  const Vector3d ax = options.semi_axes;
  if (!(ax.array() > 0.0).all() || !(options.edge_length > 0.0)) {
    ThrowInputError(SourceRef{.field = "OrganOptions"}, "semi-axes and edge_length must be positive");
  }
  // Icosahedron, subdivided until the mean edge on the ellipsoid is short enough.
  const double phi = (1.0 + std::sqrt(5.0)) / 2.0;
  std::vector<Vector3d> v = {{-1, phi, 0}, {1, phi, 0}, {-1, -phi, 0}, {1, -phi, 0}, {0, -1, phi}, {0, 1, phi},
                             {0, -1, -phi}, {0, 1, -phi}, {phi, 0, -1}, {phi, 0, 1}, {-phi, 0, -1}, {-phi, 0, 1}};
  for (auto& p : v) p.normalize();
  std::vector<std::array<int32_t, 3>> f = {{0, 11, 5}, {0, 5, 1},  {0, 1, 7},   {0, 7, 10}, {0, 10, 11},
                                           {1, 5, 9},  {5, 11, 4}, {11, 10, 2}, {10, 7, 6}, {7, 1, 8},
                                           {3, 9, 4},  {3, 4, 2},  {3, 2, 6},   {3, 6, 8},  {3, 8, 9},
                                           {4, 9, 5},  {2, 4, 11}, {6, 2, 10},  {8, 6, 7},  {9, 8, 1}};
  // Knud Thomsen's approximation of the ellipsoid's area.
  const double p = 1.6075;
  const double area = 4.0 * std::numbers::pi *
                      std::pow((std::pow(ax.x() * ax.y(), p) + std::pow(ax.x() * ax.z(), p) +
                                std::pow(ax.y() * ax.z(), p)) / 3.0, 1.0 / p);
  auto mean_edge = [&](size_t faces) { return std::sqrt(4.0 * area / (std::sqrt(3.0) * static_cast<double>(faces))); };
  while (mean_edge(f.size()) > options.edge_length && f.size() < 2'000'000) {
    std::map<std::pair<int32_t, int32_t>, int32_t> mid;
    auto midpoint = [&](int32_t a, int32_t b) {
      const auto key = std::minmax(a, b);
      auto [it, inserted] = mid.try_emplace(key, static_cast<int32_t>(v.size()));
      if (inserted) v.push_back((v[static_cast<size_t>(a)] + v[static_cast<size_t>(b)]).normalized());
      return it->second;
    };
    std::vector<std::array<int32_t, 3>> next;
    next.reserve(4 * f.size());
    for (const auto& [a, b, c] : f) {
      const int32_t ab = midpoint(a, b), bc = midpoint(b, c), ca = midpoint(c, a);
      next.push_back({a, ab, ca});
      next.push_back({b, bc, ab});
      next.push_back({c, ca, bc});
      next.push_back({ab, bc, ca});
    }
    f = std::move(next);
  }
  // Smooth map of the unit sphere: ellipsoid, a kidney-like hilum dent on +y
  // near the middle, a gentle bend and a slight lobe asymmetry. All terms are
  // smooth in the direction d, so the surface stays smooth and star-shaped.
  positions.resize(static_cast<Eigen::Index>(v.size()), 3);
  for (size_t i = 0; i < v.size(); ++i) {
    const Vector3d& d = v[i];
    Vector3d q(ax.x() * d.x(), ax.y() * d.y(), ax.z() * d.z());
    const double dent = options.bean_depth * ax.y() * std::exp(-4.0 * d.x() * d.x()) * std::exp(-3.0 * d.z() * d.z());
    q.y() -= dent * (0.5 + 0.5 * d.y()) * (0.5 + 0.5 * d.y());
    q.y() += 0.15 * ax.y() * d.x() * d.x();          // bend
    q.x() *= 1.0 + 0.08 * d.y() * (1.0 - d.x() * d.x());  // asymmetric lobes
    positions.row(static_cast<Eigen::Index>(i)) = q.transpose();
  }
  tris.resize(static_cast<Eigen::Index>(f.size()), 3);
  for (size_t i = 0; i < f.size(); ++i) tris.row(static_cast<Eigen::Index>(i)) << f[i][0], f[i][1], f[i][2];
  // The icosahedron list is counter-clockwise from outside only if its first
  // face's normal points away from the centre; fix the winding globally if not.
  const Vector3d n = (v[static_cast<size_t>(f[0][1])] - v[static_cast<size_t>(f[0][0])])
                         .cross(v[static_cast<size_t>(f[0][2])] - v[static_cast<size_t>(f[0][0])]);
  if (n.dot(v[static_cast<size_t>(f[0][0])]) < 0.0) tris.col(1).swap(tris.col(2));
}

TetMesh MakeOrgan(const OrganOptions& options) {
  Positions positions;
  Triangles tris;
  MakeOrganSurface(options, positions, tris);
  return TetrahedralizeSurface(positions, tris, options.edge_length, "<organ>", options.fill);
}

}  // namespace cutsim::mesh
