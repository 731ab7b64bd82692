#include "common/transport/mesh_replica.h"

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <utility>

namespace cutsim::transport {
namespace {

/// Decodes sorted delta-coded indices into `out`; false if not strictly
/// increasing, out of [0, limit) or overflowing.
template <class Field>
bool DecodeIndices(const Field& coded, uint32_t limit, std::vector<uint32_t>& out) {
  out.clear();
  out.reserve(static_cast<size_t>(coded.size()));
  uint64_t cur = 0;
  for (int i = 0; i < coded.size(); ++i) {
    const uint64_t d = coded.Get(i);
    if (i > 0 && d == 0) return false;
    cur = (i == 0) ? d : cur + d;
    if (cur >= limit) return false;
    out.push_back(static_cast<uint32_t>(cur));
  }
  return true;
}

bool InQuantisedRange(int64_t k) { return k >= -kMaxQuantised && k <= kMaxQuantised; }

// Largest mesh a replica accepts (consistent with MaxPayloadBytes).
constexpr uint64_t kMaxNodes = uint64_t{1} << 26;
constexpr uint64_t kMaxTets = uint64_t{1} << 27;

/// True when the snapshot's sizes agree with each other and every index
/// names an existing node.
bool SnapshotShapeValid(const v1::MeshSnapshot& s) {
  const double q = s.quantum();
  if (!(std::isfinite(q) && q > 0.0 && q <= 1.0)) return false;
  if (s.world_size() != s.rest_size() || s.world_size() % 3 != 0) return false;
  const uint64_t n = static_cast<uint64_t>(s.world_size()) / 3;
  if (n > kMaxNodes || s.tets_size() % 4 != 0 || static_cast<uint64_t>(s.tets_size()) / 4 > kMaxTets ||
      s.surface_size() % 3 != 0) {
    return false;
  }
  if (s.opened_size() != 0 && s.opened_size() != s.surface_size() / 3) return false;
  if (s.stress_code_size() != 0 && static_cast<uint64_t>(s.stress_code_size()) != n) return false;
  for (const uint32_t i : s.tets()) {
    if (i >= n) return false;
  }
  for (const uint32_t i : s.surface()) {
    if (i >= n) return false;
  }
  return true;
}

}  // namespace

mesh::Positions MeshReplica::Rest() const { return rest_q_.cast<double>() * quantum_; }

uint64_t MeshReplica::ComputeHash() const {
  return MeshHash(version_, world_q_, tets_, surface_, opened_);
}

// ---------------------------------------------------------------------------
// Snapshots

MeshReplica::SnapshotResult MeshReplica::ApplySnapshot(const v1::MeshSnapshot& s) {
  if (!SnapshotShapeValid(s)) return SnapshotResult::kMalformed;
  const double q = s.quantum();
  const auto n = static_cast<Eigen::Index>(s.world_size() / 3);
  const int f = s.surface_size() / 3;
  QuantisedPositions world_q(n, 3);
  QuantisedPositions rest_q(n, 3);
  for (int i = 0; i < s.world_size(); ++i) {
    const double kw = std::nearbyint(static_cast<double>(s.world(i)) / q);
    const double kr = std::nearbyint(static_cast<double>(s.rest(i)) / q);
    if (!(std::fabs(kw) <= kMaxQuantised) || !(std::fabs(kr) <= kMaxQuantised)) {
      return SnapshotResult::kMalformed;
    }
    world_q.data()[i] = static_cast<int32_t>(kw);
    rest_q.data()[i] = static_cast<int32_t>(kr);
  }
  mesh::Tets tets(s.tets_size() / 4, 4);
  for (int i = 0; i < s.tets_size(); ++i) tets.data()[i] = static_cast<int32_t>(s.tets(i));
  mesh::Triangles surface(f, 3);
  for (int i = 0; i < s.surface_size(); ++i) surface.data()[i] = static_cast<int32_t>(s.surface(i));
  std::vector<uint8_t> opened(static_cast<size_t>(f), 0);
  for (int i = 0; i < s.opened_size(); ++i) opened[static_cast<size_t>(i)] = s.opened(i) ? 1 : 0;
  const uint64_t topo = TopologyHash(s.topology_version(), tets, surface, opened);
  const uint64_t hash = CombineHashes(topo, PositionsHash(world_q));
  if (hash != s.hash()) return SnapshotResult::kHashMismatch;

  quantum_ = q;
  world_q_ = std::move(world_q);
  rest_q_ = std::move(rest_q);
  world_ = world_q_.cast<double>() * q;
  tets_ = std::move(tets);
  surface_ = std::move(surface);
  opened_ = std::move(opened);
  stress_code_.assign(s.stress_code().begin(), s.stress_code().end());
  stress_.resize(stress_code_.size());
  for (size_t i = 0; i < stress_code_.size(); ++i) stress_[i] = StressFromCode(stress_code_[i]);
  version_ = s.topology_version();
  topology_hash_ = topo;
  hash_ = hash;
  seq_ = s.seq();
  frame_ = s.frame();
  sim_time_ = s.sim_time();
  synced_ = true;
  return SnapshotResult::kApplied;
}

// ---------------------------------------------------------------------------
// Deltas

MeshReplica::DeltaResult MeshReplica::ApplyDelta(const v1::MeshDelta& d) {
  if (!synced_) return DeltaResult::kNotSynced;
  if (d.seq() <= seq_) return DeltaResult::kStale;
  if (d.seq() != seq_ + 1) {
    synced_ = false;
    return DeltaResult::kGap;
  }
  if (d.base_topology_version() != version_) return DeltaResult::kUnknownTopology;
  // Everything is checked before the state changes.
  if (!DecodeDelta(d) || !DeltaInRange(d)) return DeltaResult::kMalformed;
  const bool topology_changed = !indices_.tets.empty() || d.surface_changed() ||
                                d.topology_version() != version_;
  GrowNodes(d.num_nodes());
  ApplyChangedTets(d);
  ApplyRestChanges(d);
  ApplyMovedNodes(d);
  if (d.surface_changed()) ApplySurface(d);
  ApplyStress(d);
  version_ = d.topology_version();
  if (topology_changed) topology_hash_ = TopologyHash(version_, tets_, surface_, opened_);
  hash_ = CombineHashes(topology_hash_, PositionsHash(world_q_));
  seq_ = d.seq();
  frame_ = d.frame();
  sim_time_ = d.sim_time();
  if (hash_ != d.hash()) {
    synced_ = false;
    return DeltaResult::kHashMismatch;
  }
  return DeltaResult::kApplied;
}

bool MeshReplica::DecodeDelta(const v1::MeshDelta& d) {
  if (d.quantum() != quantum_) return false;
  const auto old_n = static_cast<uint64_t>(world_q_.rows());
  const uint64_t n = d.num_nodes();
  if (n < old_n || n > kMaxNodes || d.num_tets() != static_cast<uint64_t>(tets_.rows())) return false;
  const auto limit = static_cast<uint32_t>(n);
  DeltaIndices& idx = indices_;
  if (!DecodeIndices(d.changed_tets(), static_cast<uint32_t>(tets_.rows()), idx.tets) ||
      static_cast<size_t>(d.changed_tet_nodes_size()) != 4 * idx.tets.size() ||
      !DecodeIndices(d.rest_nodes(), limit, idx.rest) ||
      static_cast<size_t>(d.rest_dq_size()) != 3 * idx.rest.size() ||
      !DecodeIndices(d.moved_nodes(), limit, idx.moved) ||
      static_cast<size_t>(d.moved_dq_size()) != 3 * idx.moved.size() ||
      !DecodeIndices(d.stress_nodes(), limit, idx.stress) ||
      d.stress_code_size() != static_cast<int>(idx.stress.size()) ||
      (!d.has_stress() && d.stress_code_size() != 0)) {
    return false;
  }
  // A node the replica does not hold yet comes with its rest and world
  // positions, so the count a delta claims is backed by bytes it carries
  // (indices are sorted and unique: the added ones are the tail).
  auto covers_added = [&](const std::vector<uint32_t>& nodes) {
    const auto first_added = std::lower_bound(nodes.begin(), nodes.end(), old_n);
    return static_cast<uint64_t>(nodes.end() - first_added) == n - old_n;
  };
  if (!covers_added(idx.rest) || !covers_added(idx.moved)) return false;
  for (const uint32_t v : d.changed_tet_nodes()) {
    if (v >= n) return false;
  }
  if (!d.surface_changed()) return d.surface_size() == 0 && d.opened_size() == 0;
  // Surface indices that stay remain valid: they were < old_n ≤ n.
  if (d.surface_size() % 3 != 0) return false;
  if (d.opened_size() != 0 && d.opened_size() != d.surface_size() / 3) return false;
  for (const uint32_t v : d.surface()) {
    if (v >= n) return false;
  }
  return true;
}

bool MeshReplica::DeltaInRange(const v1::MeshDelta& d) const {
  // Every changed coordinate stays a valid quantised value; nodes not held
  // yet start from 0.
  const auto old_n = static_cast<uint64_t>(world_q_.rows());
  auto in_range = [&](const QuantisedPositions& m, const std::vector<uint32_t>& nodes, auto dq) {
    for (size_t j = 0; j < nodes.size(); ++j) {
      for (int c = 0; c < 3; ++c) {
        const int64_t old = nodes[j] < old_n ? m(nodes[j], c) : 0;
        if (!InQuantisedRange(old + dq(static_cast<int>(3 * j) + c))) return false;
      }
    }
    return true;
  };
  return in_range(rest_q_, indices_.rest, [&](int k) { return d.rest_dq(k); }) &&
         in_range(world_q_, indices_.moved, [&](int k) { return d.moved_dq(k); });
}

void MeshReplica::GrowNodes(uint64_t n) {
  const auto rows = static_cast<Eigen::Index>(n);
  const Eigen::Index old_rows = world_q_.rows();
  if (rows <= old_rows) return;
  world_q_.conservativeResize(rows, 3);
  rest_q_.conservativeResize(rows, 3);
  world_.conservativeResize(rows, 3);
  world_q_.bottomRows(rows - old_rows).setZero();
  rest_q_.bottomRows(rows - old_rows).setZero();
  world_.bottomRows(rows - old_rows).setZero();
}

void MeshReplica::ApplyChangedTets(const v1::MeshDelta& d) {
  const std::vector<uint32_t>& rows = indices_.tets;
  for (size_t j = 0; j < rows.size(); ++j) {
    for (int c = 0; c < 4; ++c) {
      tets_(rows[j], c) = static_cast<int32_t>(d.changed_tet_nodes(static_cast<int>(4 * j) + c));
    }
  }
}

void MeshReplica::ApplyRestChanges(const v1::MeshDelta& d) {
  const std::vector<uint32_t>& nodes = indices_.rest;
  for (size_t j = 0; j < nodes.size(); ++j) {
    for (int c = 0; c < 3; ++c) rest_q_(nodes[j], c) += d.rest_dq(static_cast<int>(3 * j) + c);
  }
}

void MeshReplica::ApplyMovedNodes(const v1::MeshDelta& d) {
  const std::vector<uint32_t>& nodes = indices_.moved;
  for (size_t j = 0; j < nodes.size(); ++j) {
    const uint32_t i = nodes[j];
    for (int c = 0; c < 3; ++c) {
      world_q_(i, c) += d.moved_dq(static_cast<int>(3 * j) + c);
      world_(i, c) = quantum_ * world_q_(i, c);
    }
  }
}

void MeshReplica::ApplySurface(const v1::MeshDelta& d) {
  surface_.resize(d.surface_size() / 3, 3);
  for (int i = 0; i < d.surface_size(); ++i) surface_.data()[i] = static_cast<int32_t>(d.surface(i));
  opened_.assign(static_cast<size_t>(surface_.rows()), 0);
  for (int i = 0; i < d.opened_size(); ++i) opened_[static_cast<size_t>(i)] = d.opened(i) ? 1 : 0;
}

void MeshReplica::ApplyStress(const v1::MeshDelta& d) {
  if (!d.has_stress()) {
    stress_code_.clear();
    stress_.clear();
    return;
  }
  const auto n = static_cast<size_t>(d.num_nodes());
  stress_code_.resize(n, 0);
  stress_.resize(n, 0.0);
  const std::vector<uint32_t>& nodes = indices_.stress;
  for (size_t j = 0; j < nodes.size(); ++j) {
    stress_code_[nodes[j]] = d.stress_code(static_cast<int>(j));
    stress_[nodes[j]] = StressFromCode(stress_code_[nodes[j]]);
  }
}

}  // namespace cutsim::transport
