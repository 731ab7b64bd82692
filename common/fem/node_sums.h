#pragma once
/// @file
/// Sums over nodes that give the same bits for any thread count. An OpenMP
/// `reduction(+)` adds one partial sum per thread, so 1 and 2 threads round
/// differently, and the sums here steer the step (the stable-step estimate,
/// the viscous CG's α, β and stopping test): a run, or a replay of it, on a
/// machine with another number of cores would drift apart.

#include <algorithm>
#include <array>
#include <cstdint>

namespace cutsim::fem {

/// Nodes in fixed blocks (≥ 256 nodes, at most kMaxBlocks of them, sized by
/// the node count alone); each block is summed in node order by one thread,
/// then the blocks in order. Allocation-free (the partial sums live here:
/// declare it outside the parallel region, so the team shares it).
template <int K>
class NodeSums {
 public:
  static constexpr int32_t kMaxBlocks = 256;
  static constexpr int32_t kMinBlock = 256;

  explicit NodeSums(int32_t num_nodes)
      : num_nodes_(num_nodes),
        block_(std::max(kMinBlock, (num_nodes + kMaxBlocks - 1) / kMaxBlocks)),
        num_blocks_((num_nodes + block_ - 1) / block_) {}

  /// Called by every thread of a team (or outside one, serially): visits
  /// every node once, `body(n, acc)` adding node n's terms to acc[0..K).
  /// Ends with the team's barrier (an orphaned `omp for`).
  template <typename Body>
  void Team(Body&& body) {
#pragma omp for schedule(static)
    for (int32_t b = 0; b < num_blocks_; ++b) {
      std::array<double, K> acc{};
      const int32_t end = std::min(num_nodes_, (b + 1) * block_);
      for (int32_t n = b * block_; n < end; ++n) body(n, acc);
      partial_[static_cast<size_t>(b)] = acc;
    }
  }

  /// After Team: sum k, over the blocks in order.
  [[nodiscard]] double Total(int k) const {
    double s = 0;
    for (int32_t b = 0; b < num_blocks_; ++b) s += partial_[static_cast<size_t>(b)][static_cast<size_t>(k)];
    return s;
  }

 private:
  int32_t num_nodes_, block_, num_blocks_;
  std::array<std::array<double, K>, kMaxBlocks> partial_;  // #blocks×K
};

}  // namespace cutsim::fem
