#include "common/fem/sparse_system.h"

#include <algorithm>
#include <atomic>
#include <bit>
#include <cstddef>
#include <vector>

#include "common/core/headroom.h"

namespace cutsim::fem {

namespace {

std::atomic<int64_t> g_next_pattern_id{0};

/// Greedy colouring of the chunks: each takes the smallest colour none of
/// its nodes has yet, in chunk order (deterministic). A node's colours are
/// a bit set of `words` 64-bit words; when a chunk finds every colour of
/// the set taken, the colouring restarts with twice the words. Returns
/// per-chunk colours.
std::vector<int32_t> ColorChunks(const Model<double>& model, int32_t chunk, int32_t* num_colors) {
  const int32_t nt = model.num_tets();
  const int32_t num_chunks = (nt + chunk - 1) / chunk;
  std::vector<int32_t> color(static_cast<size_t>(num_chunks), 0);
  for (size_t words = 1;; words *= 2) {
    std::vector<uint64_t> used(words * static_cast<size_t>(model.num_nodes()), 0);
    std::vector<uint64_t> taken(words);
    bool fits = true;
    *num_colors = 0;
    for (int32_t k = 0; k < num_chunks && fits; ++k) {
      const int32_t first = k * chunk, last = std::min(nt, (k + 1) * chunk);
      std::fill(taken.begin(), taken.end(), 0);
      for (int32_t t = first; t < last; ++t) {
        for (int c = 0; c < 4; ++c) {
          const uint64_t* u = used.data() + words * static_cast<size_t>(model.tet_node(t, c));
          for (size_t w = 0; w < words; ++w) taken[w] |= u[w];
        }
      }
      size_t w = 0;
      while (w < words && taken[w] == ~uint64_t{0}) ++w;
      if (w == words) {
        fits = false;
        break;
      }
      const int bit = std::countr_one(taken[w]);
      const int32_t c = static_cast<int32_t>(64 * w) + bit;
      color[static_cast<size_t>(k)] = c;
      *num_colors = std::max(*num_colors, c + 1);
      for (int32_t t = first; t < last; ++t) {
        for (int q = 0; q < 4; ++q) used[words * static_cast<size_t>(model.tet_node(t, q)) + w] |= uint64_t{1} << bit;
      }
    }
    if (fits) return color;
  }
}

}  // namespace

void SparseSystem::Build(const Model<double>& model) {
  const int32_t nn = model.num_nodes();
  const int32_t nt = model.num_tets();
  const int32_t* slots = model.incidence_slots();
  // Node b's column: itself and every corner of its incident tets, found
  // through the model's incidence (slot = 12·t + 3·corner) with a stamp per
  // node, then sorted. A first pass counts each column's blocks.
  std::vector<int32_t> stamp(static_cast<size_t>(nn), -1);
  std::vector<int32_t> column;
  auto gather = [&](int32_t b) {
    column.clear();
    column.push_back(b);
    stamp[static_cast<size_t>(b)] = b;
    for (int32_t k = model.incidence_begin(b); k < model.incidence_end(b); ++k) {
      const int32_t t = slots[k] / 12;
      for (int i = 0; i < 4; ++i) {
        const int32_t a = model.tet_node(t, i);
        if (stamp[static_cast<size_t>(a)] == b) continue;
        stamp[static_cast<size_t>(a)] = b;
        column.push_back(a);
      }
    }
  };
  ResizeWithHeadroom(block_ptr_, static_cast<size_t>(nn) + 1);
  block_ptr_[0] = 0;
  for (int32_t b = 0; b < nn; ++b) {
    gather(b);
    block_ptr_[static_cast<size_t>(b) + 1] = block_ptr_[static_cast<size_t>(b)] + static_cast<int32_t>(column.size());
  }
  ResizeWithHeadroom(block_row_, static_cast<size_t>(block_ptr_.back()));
  ResizeWithHeadroom(col_ptr_, static_cast<size_t>(3 * nn) + 1);
  ResizeWithHeadroom(row_index_, 9 * block_row_.size());
  ResizeWithHeadroom(diag_offset_, static_cast<size_t>(nn));
  ResizeWithHeadroom(tet_block_, 16 * static_cast<size_t>(nt));
  // The second pass writes the sorted column, its scalar rows, and, with
  // each row node's place in the column (`place`), the column's blocks of
  // every incident tet: assembly's offsets without a search.
  std::fill(stamp.begin(), stamp.end(), -1);
  std::vector<int32_t> place(static_cast<size_t>(nn), 0);
  for (int32_t b = 0; b < nn; ++b) {
    gather(b);
    std::sort(column.begin(), column.end());
    const auto deg = static_cast<int32_t>(column.size());
    const int32_t base = 9 * block_ptr_[static_cast<size_t>(b)];
    std::copy(column.begin(), column.end(), block_row_.begin() + block_ptr_[static_cast<size_t>(b)]);
    for (int c = 0; c < 3; ++c) {
      const int32_t col_begin = base + 3 * c * deg;
      col_ptr_[static_cast<size_t>(3 * b + c)] = col_begin;
      for (int32_t k = 0; k < deg; ++k) {
        for (int r = 0; r < 3; ++r) {
          row_index_[static_cast<size_t>(col_begin + 3 * k + r)] = 3 * column[static_cast<size_t>(k)] + r;
        }
      }
    }
    for (int32_t k = 0; k < deg; ++k) place[static_cast<size_t>(column[static_cast<size_t>(k)])] = k;
    diag_offset_[static_cast<size_t>(b)] = base + 3 * place[static_cast<size_t>(b)];
    for (int32_t k = model.incidence_begin(b); k < model.incidence_end(b); ++k) {
      const int32_t t = slots[k] / 12;
      const int32_t j = (slots[k] % 12) / 3;  // b is corner j of t
      for (int i = 0; i < 4; ++i) {
        tet_block_[16 * static_cast<size_t>(t) + static_cast<size_t>(4 * i + j)] =
            base + 3 * place[static_cast<size_t>(model.tet_node(t, i))];
      }
    }
  }
  col_ptr_[static_cast<size_t>(3 * nn)] = static_cast<int32_t>(row_index_.size());
  num_nodes_ = nn;
  num_tets_ = nt;

  int32_t num_colors = 0;
  const std::vector<int32_t> color = ColorChunks(model, kChunk, &num_colors);
  ResizeWithHeadroom(color_ptr_, static_cast<size_t>(num_colors) + 1);
  std::fill(color_ptr_.begin(), color_ptr_.end(), 0);
  for (const int32_t c : color) ++color_ptr_[static_cast<size_t>(c) + 1];
  for (int32_t c = 0; c < num_colors; ++c) color_ptr_[static_cast<size_t>(c) + 1] += color_ptr_[static_cast<size_t>(c)];
  ResizeWithHeadroom(color_chunks_, color.size());
  std::vector<int32_t> next(color_ptr_.begin(), color_ptr_.end() - 1);
  for (size_t k = 0; k < color.size(); ++k) {
    color_chunks_[static_cast<size_t>(next[static_cast<size_t>(color[k])]++)] = static_cast<int32_t>(k);
  }

  topology_version_ = model.topology_version();
  built_ = true;
  ++builds_;
  pattern_id_ = g_next_pattern_id.fetch_add(1);
}

int32_t SparseSystem::FindBlock(int32_t a, int32_t b) const {
  const auto begin = block_row_.begin() + block_ptr_[static_cast<size_t>(b)];
  const auto end = block_row_.begin() + block_ptr_[static_cast<size_t>(b) + 1];
  const auto it = std::lower_bound(begin, end, a);
  if (it == end || *it != a) return -1;
  return 9 * block_ptr_[static_cast<size_t>(b)] + 3 * static_cast<int32_t>(it - begin);
}

void SparseSystem::MultiplyTeam(const double* values, const double* x, double* y) const {
  const int32_t nd = num_dofs();
  const int32_t* cp = col_ptr_.data();
  const int32_t* ri = row_index_.data();
#pragma omp for schedule(static)
  for (int32_t j = 0; j < nd; ++j) {
    double s = 0;
    for (int32_t k = cp[j]; k < cp[j + 1]; ++k) s += values[k] * x[ri[k]];
    y[j] = s;  // the matrix is symmetric: column j is row j
  }
}

Eigen::Matrix3d SparseSystem::GetBlock(const double* values, int32_t offset, int32_t b) const {
  Eigen::Matrix3d m;
  const int32_t stride = col_stride(b);
  for (int c = 0; c < 3; ++c) {
    for (int r = 0; r < 3; ++r) m(r, c) = values[offset + c * stride + r];
  }
  return m;
}

}  // namespace cutsim::fem
