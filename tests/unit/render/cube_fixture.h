#pragma once
// A unit cube's boundary surface, shared by the render tests.

#include "common/mesh/tet_mesh.h"

namespace cutsim::render::testing {

/// The 8 corners of [0, 1]³.
inline mesh::Positions CubePositions() {
  mesh::Positions p(8, 3);
  p << 0, 0, 0,  //
      1, 0, 0,   //
      1, 1, 0,   //
      0, 1, 0,   //
      0, 0, 1,   //
      1, 0, 1,   //
      1, 1, 1,   //
      0, 1, 1;
  return p;
}

/// 12 outward counter-clockwise triangles, two per face, in the order
/// −z, +z, −y, +y, −x, +x (so triangles 2 and 3 are the top face).
inline mesh::Triangles CubeTriangles() {
  mesh::Triangles t(12, 3);
  t << 0, 2, 1, 0, 3, 2,  // −z
      4, 5, 6, 4, 6, 7,   // +z
      0, 1, 5, 0, 5, 4,   // −y
      3, 7, 6, 3, 6, 2,   // +y
      0, 4, 7, 0, 7, 3,   // −x
      1, 2, 6, 1, 6, 5;   // +x
  return t;
}

}  // namespace cutsim::render::testing
