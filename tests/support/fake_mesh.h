#pragma once
/// @file
/// A mutable tet-mesh state standing in for the server's simulation, for the
/// mesh stream's test (tests/unit/transport/mesh_stream_test.cc) and
/// benchmark (bench/mesh_stream_bench.cc): a box that can be poked, split at
/// a node and cut along a plane, filling a `transport::MeshFrame`.

#include <cmath>
#include <cstdint>
#include <vector>

#include <Eigen/Core>

#include "common/mesh/generators.h"
#include "common/mesh/surface.h"
#include "common/mesh/tet_mesh.h"
#include "common/transport/mesh_stream.h"

namespace cutsim::support {

/// A mutable mesh state standing in for the server's simulation.
struct FakeMesh {
  uint64_t frame = 0;
  double sim_time = 0.0;
  uint64_t version = 1;
  mesh::Positions rest;
  mesh::Positions world;
  mesh::Tets tets;
  mesh::Triangles surface;
  std::vector<uint8_t> opened;
  std::vector<double> stress;

  explicit FakeMesh(int n, double size = 0.1) {
    const mesh::TetMesh box = mesh::MakeBox({0, 0, 0}, {size, size, size}, n, n, n);
    rest = box.nodes;
    world = box.nodes;
    tets = box.tets;
    Resurface();
  }
  void Resurface() {
    surface = mesh::ExtractSurface(tets).tris;
    opened.assign(static_cast<size_t>(surface.rows()), 0);
  }
  void Fill(transport::MeshFrame& f) const {
    f.frame = frame;
    f.sim_time = sim_time;
    f.topology_version = version;
    f.world = world;
    f.rest = rest;
    f.tets = tets;
    f.surface = surface;
    f.opened = opened;
    f.stress = stress;
  }
  /// Smooth bump of `depth` m pushing nodes within `radius` of `centre` down.
  void Poke(const Eigen::Vector3d& centre, double radius, double depth) {
    for (Eigen::Index i = 0; i < world.rows(); ++i) {
      const double r = (rest.row(i).transpose() - centre).norm();
      if (r < radius) {
        const double w = 0.5 * (1 + std::cos(M_PI * r / radius));
        world(i, 2) = rest(i, 2) - depth * w;
      }
    }
  }
  /// Vertex split of `node`: a duplicate at the same place takes over the
  /// tets on the +x side of it (positive orientation kept).
  void Split(int32_t node, bool resurface = true) {
    const Eigen::Index n = world.rows();
    world.conservativeResize(n + 1, 3);
    rest.conservativeResize(n + 1, 3);
    world.row(n) = world.row(node);
    rest.row(n) = rest.row(node);
    if (!stress.empty()) stress.push_back(stress[static_cast<size_t>(node)]);
    for (Eigen::Index t = 0; t < tets.rows(); ++t) {
      bool uses = false;
      Eigen::Vector3d c = Eigen::Vector3d::Zero();
      for (int k = 0; k < 4; ++k) {
        uses |= tets(t, k) == node;
        c += rest.row(tets(t, k)).transpose() / 4;
      }
      if (!uses || c.x() <= rest(node, 0)) continue;
      for (int k = 0; k < 4; ++k) {
        if (tets(t, k) == node) tets(t, k) = static_cast<int32_t>(n);
      }
    }
    ++version;
    if (resurface) MarkOpened(n);
  }
  /// Recomputes the surface; faces touching nodes ≥ `first_new` are opened.
  void MarkOpened(Eigen::Index first_new) {
    Resurface();
    for (Eigen::Index f = 0; f < surface.rows(); ++f) {
      for (int k = 0; k < 3; ++k) {
        if (surface(f, k) >= first_new) opened[static_cast<size_t>(f)] = 1;
      }
    }
  }
  /// A plane cut at x = `x`, from the top down to `z_min`: every node on the
  /// plane above z_min is split, its duplicate taking the tets on the +x side.
  void Cut(double x, double z_min) {
    const Eigen::Index n = rest.rows();
    std::vector<int32_t> dup(static_cast<size_t>(n), -1);
    Eigen::Index next = n;
    for (Eigen::Index i = 0; i < n; ++i) {
      if (std::abs(rest(i, 0) - x) < 1e-9 && rest(i, 2) > z_min + 1e-9) {
        dup[static_cast<size_t>(i)] = static_cast<int32_t>(next++);
      }
    }
    world.conservativeResize(next, 3);
    rest.conservativeResize(next, 3);
    for (Eigen::Index i = 0; i < n; ++i) {
      if (const int32_t d = dup[static_cast<size_t>(i)]; d >= 0) {
        world.row(d) = world.row(i);
        rest.row(d) = rest.row(i);
        if (!stress.empty()) stress.push_back(stress[static_cast<size_t>(i)]);
      }
    }
    for (Eigen::Index t = 0; t < tets.rows(); ++t) {
      double cx = 0;
      for (int k = 0; k < 4; ++k) cx += rest(tets(t, k), 0) / 4;
      if (cx <= x) continue;
      for (int k = 0; k < 4; ++k) {
        if (const int32_t d = dup[static_cast<size_t>(tets(t, k))]; d >= 0) tets(t, k) = d;
      }
    }
    ++version;
    MarkOpened(n);
  }
};

}  // namespace cutsim::support
