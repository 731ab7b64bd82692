#include "common/fem/sparse_system.h"

#include <algorithm>
#include <atomic>
#include <cstddef>
#include <span>
#include <vector>

namespace cutsim::fem {

namespace {

std::atomic<int64_t> g_next_pattern_id{0};

/// Greedy colouring of the chunks: each takes the smallest colour none of
/// its nodes has yet, in chunk order (deterministic). Returns per-chunk
/// colours.
std::vector<int32_t> ColorChunks(const Model<double>& model, int32_t chunk, int32_t* num_colors) {
  const int32_t nt = model.num_tets();
  const int32_t num_chunks = (nt + chunk - 1) / chunk;
  std::vector<std::vector<int32_t>> node_colors(static_cast<size_t>(model.num_nodes()));
  std::vector<int32_t> color(static_cast<size_t>(num_chunks), 0);
  std::vector<uint8_t> taken;
  std::vector<int32_t> nodes;
  *num_colors = 0;
  for (int32_t k = 0; k < num_chunks; ++k) {
    nodes.clear();
    for (int32_t t = k * chunk; t < std::min(nt, (k + 1) * chunk); ++t) {
      for (int c = 0; c < 4; ++c) nodes.push_back(model.tet_node(t, c));
    }
    std::sort(nodes.begin(), nodes.end());
    nodes.erase(std::unique(nodes.begin(), nodes.end()), nodes.end());
    taken.assign(static_cast<size_t>(*num_colors) + 1, 0);
    for (const int32_t n : nodes) {
      for (const int32_t c : node_colors[static_cast<size_t>(n)]) taken[static_cast<size_t>(c)] = 1;
    }
    int32_t c = 0;
    while (taken[static_cast<size_t>(c)] != 0) ++c;
    color[static_cast<size_t>(k)] = c;
    *num_colors = std::max(*num_colors, c + 1);
    for (const int32_t n : nodes) node_colors[static_cast<size_t>(n)].push_back(c);
  }
  return color;
}

}  // namespace

void SparseSystem::Build(const Model<double>& model) {
  const int32_t nn = model.num_nodes();
  const int32_t nt = model.num_tets();
  // Neighbour lists in one flat array (no list per node): every node is its
  // own neighbour (the diagonal block) and each tet adds its 12 ordered
  // pairs; then each node's list is sorted and made unique in place.
  std::vector<int32_t> start(static_cast<size_t>(nn) + 1, 0);
  for (int32_t n = 0; n < nn; ++n) start[static_cast<size_t>(n) + 1] = 1;
  for (int32_t t = 0; t < nt; ++t) {
    for (int i = 0; i < 4; ++i) start[static_cast<size_t>(model.tet_node(t, i)) + 1] += 3;
  }
  for (int32_t n = 0; n < nn; ++n) start[static_cast<size_t>(n) + 1] += start[static_cast<size_t>(n)];
  std::vector<int32_t> flat(static_cast<size_t>(start.back()));
  std::vector<int32_t> fill(start.begin(), start.end() - 1);
  for (int32_t n = 0; n < nn; ++n) flat[static_cast<size_t>(fill[static_cast<size_t>(n)]++)] = n;
  for (int32_t t = 0; t < nt; ++t) {
    for (int i = 0; i < 4; ++i) {
      for (int j = 0; j < 4; ++j) {
        if (i != j) flat[static_cast<size_t>(fill[static_cast<size_t>(model.tet_node(t, j))]++)] = model.tet_node(t, i);
      }
    }
  }
  block_ptr_.assign(static_cast<size_t>(nn) + 1, 0);
  for (int32_t b = 0; b < nn; ++b) {
    const auto first = flat.begin() + start[static_cast<size_t>(b)];
    const auto last = flat.begin() + start[static_cast<size_t>(b) + 1];
    std::sort(first, last);
    const auto end = std::unique(first, last);
    block_ptr_[static_cast<size_t>(b) + 1] = block_ptr_[static_cast<size_t>(b)] + static_cast<int32_t>(end - first);
  }
  block_row_.resize(static_cast<size_t>(block_ptr_.back()));
  col_ptr_.assign(static_cast<size_t>(3 * nn) + 1, 0);
  row_index_.resize(9 * block_row_.size());
  diag_offset_.resize(static_cast<size_t>(nn));
  for (int32_t b = 0; b < nn; ++b) {
    const int32_t deg = block_ptr_[static_cast<size_t>(b) + 1] - block_ptr_[static_cast<size_t>(b)];
    const std::span<const int32_t> l(flat.data() + start[static_cast<size_t>(b)], static_cast<size_t>(deg));
    const int32_t base = 9 * block_ptr_[static_cast<size_t>(b)];
    std::copy(l.begin(), l.end(), block_row_.begin() + block_ptr_[static_cast<size_t>(b)]);
    for (int c = 0; c < 3; ++c) {
      const int32_t col_begin = base + 3 * c * deg;
      col_ptr_[static_cast<size_t>(3 * b + c)] = col_begin;
      for (int32_t k = 0; k < deg; ++k) {
        for (int r = 0; r < 3; ++r) row_index_[static_cast<size_t>(col_begin + 3 * k + r)] = 3 * l[static_cast<size_t>(k)] + r;
      }
    }
    const auto it = std::lower_bound(l.begin(), l.end(), b);
    diag_offset_[static_cast<size_t>(b)] = base + 3 * static_cast<int32_t>(it - l.begin());
  }
  col_ptr_[static_cast<size_t>(3 * nn)] = static_cast<int32_t>(row_index_.size());
  num_nodes_ = nn;
  num_tets_ = nt;

  tet_block_.resize(16 * static_cast<size_t>(nt));
  for (int32_t t = 0; t < nt; ++t) {
    for (int i = 0; i < 4; ++i) {
      for (int j = 0; j < 4; ++j) {
        tet_block_[16 * static_cast<size_t>(t) + static_cast<size_t>(4 * i + j)] =
            FindBlock(model.tet_node(t, i), model.tet_node(t, j));
      }
    }
  }

  int32_t num_colors = 0;
  const std::vector<int32_t> color = ColorChunks(model, kChunk, &num_colors);
  color_ptr_.assign(static_cast<size_t>(num_colors) + 1, 0);
  for (const int32_t c : color) ++color_ptr_[static_cast<size_t>(c) + 1];
  for (int32_t c = 0; c < num_colors; ++c) color_ptr_[static_cast<size_t>(c) + 1] += color_ptr_[static_cast<size_t>(c)];
  color_chunks_.resize(color.size());
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
