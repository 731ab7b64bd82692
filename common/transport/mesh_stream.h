#pragma once
/// @file
/// The observers' mesh stream: the server publishes snapshots and deltas of
/// its mesh over DDS (`MeshStreamPublisher`, mesh_publisher.h), viewers
/// rebuild the exact mesh (`MeshStreamSubscriber` → `MeshReplica`,
/// mesh_subscriber.h and mesh_replica.h) and verify it by hash (mesh_hash.h).
/// This header includes all four.
///
/// Encoding:
///  - World and rest positions are quantised to integers k = round(x/quantum)
///    (default quantum 10 µm), clamped to |k| ≤ 2^22 (±42 m at 10 µm) so a
///    float carries k·quantum exactly. The state *as sent* is these integers.
///  - A snapshot (MeshSnapshot) carries everything: rest and world as floats
///    of k·quantum, tets, surface, opened flags, topology version, stress codes.
///  - A delta (MeshDelta) carries, against the state last sent:
///      * topology diffs when tets, surface, opened flags or the node count
///        changed: new node count (nodes are only appended), the changed tet
///        rows (indices sorted and delta-coded), the nodes whose quantised rest
///        changed (new nodes included, delta-coded against the previous sent
///        value, 0 for a new node), and the whole surface + opened flags when
///        they changed. The publisher sees states, not cut events, so a diff
///        is exact whatever the cut code did.
///      * moved nodes: nodes whose world position is more than
///        `move_tolerance_m` away from the value last sent for them (new nodes
///        always), indices sorted and delta-coded, positions as the zigzag
///        (sint32) change of the quantised value.
///      * stress codes (log scale, see `StressCode`) of nodes whose code changed.
///      * the hash after applying.
///    A node count that shrinks or a tet count that changes cannot be a delta:
///    the publisher sends a snapshot instead.
///  - Sequence numbers: one counter per published frame. The delta chain is
///    unbroken: a frame that publishes a snapshot (new reader, keyframe,
///    topology beyond a delta) also publishes that frame's delta, so viewers
///    already in sync never see a gap. A delta with seq s applies to the state
///    at seq s−1; a snapshot with seq s is the state at seq s.
///  - Hash (`MeshHash`): a 64-bit hash of topology version, quantised world
///    positions, tets, surface and opened flags. Rest positions and stress are
///    display data and are not hashed.

#include "common/transport/mesh_hash.h"        // IWYU pragma: export
#include "common/transport/mesh_publisher.h"   // IWYU pragma: export
#include "common/transport/mesh_replica.h"     // IWYU pragma: export
#include "common/transport/mesh_subscriber.h"  // IWYU pragma: export
