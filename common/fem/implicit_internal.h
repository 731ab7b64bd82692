#pragma once
/// @file
/// Helpers shared by the implicit integrator's translation units
/// (implicit.cc, implicit_volumetric.cc); not part of the library's API.

#include <cstdint>

#include "common/fem/model.h"
#include "common/fem/sparse_system.h"
#include "common/fem/tangent.h"

namespace cutsim::fem::internal {

/// Calls body(t) for every tet, colour by colour (sparse_system.h), each
/// colour's chunks split over the team (an orphaned `omp for` per colour,
/// with its barrier) and each chunk's tets in order: chunks of one colour
/// share no node, so their scatters never collide.
template <typename Body>
void ForEachTetByColor(const SparseSystem& system, Body&& body) {
  const int32_t* cp = system.color_ptr();
  const int32_t* chunks = system.color_chunks();
  for (int32_t c = 0; c < system.num_colors(); ++c) {
#pragma omp for schedule(dynamic, 1)
    for (int32_t k = cp[c]; k < cp[c + 1]; ++k) {
      for (int32_t t = system.chunk_begin(chunks[k]); t < system.chunk_end(chunks[k]); ++t) body(t);
    }
  }
}

/// Adds scale·blocks of tet t into `values`; pairs with an inactive node
/// are skipped when `active` is given (their rows and columns stay identity).
inline void ScatterBlocks(const SparseSystem& system, const Model<double>& model, int32_t t,
                   const ElementBlocks& blocks, double scale, const uint8_t* active, double* values) {
  const int32_t* off = system.tet_blocks(t);
  for (int i = 0; i < 4; ++i) {
    const int32_t a = model.tet_node(t, i);
    if (active != nullptr && active[a] == 0) continue;
    for (int j = 0; j < 4; ++j) {
      const int32_t b = model.tet_node(t, j);
      if (active != nullptr && active[b] == 0) continue;
      system.AddBlock(values, off[4 * i + j], b, scale * blocks[4 * i + j]);
    }
  }
}

inline Mat34<double> TetPositions(const Model<double>& model, const double* x, int32_t t) {
  Mat34<double> xs;
  for (int c = 0; c < 4; ++c) {
    const int32_t n = model.tet_node(t, c);
    xs.col(c) = Vec3<double>(x[3 * n], x[3 * n + 1], x[3 * n + 2]);
  }
  return xs;
}

}  // namespace cutsim::fem::internal
