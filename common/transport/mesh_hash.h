#pragma once
/// @file
/// The integer form of a mesh as the observer stream sends it: quantised
/// positions, log-scale stress codes and the 64-bit hash both ends compute
/// to verify that a viewer holds exactly the server's mesh.

#include <cstdint>
#include <span>

#include <Eigen/Core>

#include "common/mesh/tet_mesh.h"

namespace cutsim::transport {

/// Quantised coordinates, one row per node.  // #N×3
using QuantisedPositions = Eigen::Matrix<int32_t, Eigen::Dynamic, 3, Eigen::RowMajor>;

/// Largest |k| of a quantised coordinate: k·quantum is exact in a float.
inline constexpr int32_t kMaxQuantised = 1 << 22;

/// round(x / quantum), clamped to ±kMaxQuantised; NaN gives 0.
[[nodiscard]] int32_t Quantise(double x, double quantum);

/// Per-node stress code: sign(s)·round(16·log2(1 + |s|/1 Pa)), clamped to
/// ±65535 (about 6 % resolution, any magnitude up to 10^1230 Pa). NaN → 0.
[[nodiscard]] int32_t StressCode(double s);
/// Inverse of `StressCode` (the centre of the code's interval), Pa.
[[nodiscard]] double StressFromCode(int32_t code);

/// The hash of a mesh state as sent. Both sides compute it with this function.
/// `opened` may be empty (no face opened) — it hashes like all zeros.
[[nodiscard]] uint64_t MeshHash(uint64_t topology_version, const QuantisedPositions& world_q,
                                const mesh::Tets& tets, const mesh::Triangles& surface,
                                std::span<const uint8_t> opened);
/// The two halves `MeshHash` combines, for callers that cache the topology part.
[[nodiscard]] uint64_t TopologyHash(uint64_t topology_version, const mesh::Tets& tets,
                                    const mesh::Triangles& surface, std::span<const uint8_t> opened);
[[nodiscard]] uint64_t PositionsHash(const QuantisedPositions& world_q);
[[nodiscard]] uint64_t CombineHashes(uint64_t topology_hash, uint64_t positions_hash);

}  // namespace cutsim::transport
