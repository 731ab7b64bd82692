#pragma once
/// @file
/// World (deformed) positions are owned by the FEM state, in float or double;
/// cutting reads and writes them through this small interface.

#include <cstdint>
#include <vector>

#include <Eigen/Core>

#include "common/cutting/topology_event.h"

namespace cutsim::cutting {

class WorldAccess {
 public:
  virtual ~WorldAccess() = default;
  /// World position of `node`, m.
  [[nodiscard]] virtual Eigen::Vector3d Get(int32_t node) const = 0;
  virtual void Set(int32_t node, const Eigen::Vector3d& x) = 0;
  /// The positions as one packed #N×3 array of doubles, if the world holds
  /// them so (nullptr otherwise), valid until the next Set or resize: a cut
  /// step reads them without a virtual call per node.
  [[nodiscard]] virtual const double* Xyz() const { return nullptr; }
};

/// World positions held in a vector: tests, tools, and replay of events.
class VectorWorld final : public WorldAccess {
 public:
  VectorWorld() = default;
  explicit VectorWorld(std::vector<Eigen::Vector3d> x) : x_(std::move(x)) {}
  [[nodiscard]] Eigen::Vector3d Get(int32_t node) const override {
    return x_[static_cast<size_t>(node)];
  }
  void Set(int32_t node, const Eigen::Vector3d& x) override { x_[static_cast<size_t>(node)] = x; }
  [[nodiscard]] const double* Xyz() const override { return x_.empty() ? nullptr : x_.front().data(); }
  /// Appends a copy of `node`; returns its id.
  int32_t AddNodeCopy(int32_t node) {
    x_.push_back(x_[static_cast<size_t>(node)]);
    return static_cast<int32_t>(x_.size()) - 1;
  }
  /// Node copies and world moves of `event` (what the FEM side does to x).
  void ApplyEvent(const TopologyEvent& event) {
    for (const Split& s : event.splits) AddNodeCopy(s.node);
    for (const Move& m : event.moves) Set(m.node, m.world);
  }
  [[nodiscard]] int32_t size() const { return static_cast<int32_t>(x_.size()); }
  [[nodiscard]] const std::vector<Eigen::Vector3d>& positions() const { return x_; }

 private:
  std::vector<Eigen::Vector3d> x_;  // #N, m
};

}  // namespace cutsim::cutting
