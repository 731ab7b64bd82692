#pragma once
/// @file
/// The browser observers' wire format: what the bridge (`cutsim-viewer
/// --serve`) sends each browser for a frame of the mesh stream. The page
/// (web/observer/observer.js) decodes it.
///
/// Binary frames, little-endian, a 32-byte header then a body:
///
///   byte 0      u8  kind: 1 = surface snapshot, 2 = positions update
///   byte 1      u8  version = 1;  bytes 2–3 reserved (0)
///   bytes 4–7   u32 V: surface vertices
///   bytes 8–11  u32 F: triangles (0 in an update)
///   bytes 12–15 u32 O: opened triangles (0 in an update)
///   bytes 16–23 f64 simulated time, s
///   bytes 24–31 f64 sequence number of the mesh stream's frame
///
///   kind 1: f32 positions[3V] (m, world), then u32 triangles[3F] over those
///           vertices, the last O of them opened by a cut;
///   kind 2: f32 positions[3V] in the order of the last snapshot.
///
/// Only vertices of the surface travel (the tets' interior nodes are not
/// drawn), renumbered compactly when the topology changes. Each mesh frame
/// is followed by a text frame, JSON:
///   {"type":"session","seq":S,"observed":<ObserverSession, protobuf JSON>,
///    "link":{"frame_age_ms":A,"bridge_gaps":G,"clients":C}}
/// and a browser's first message is {"type":"hello","protocol":1,"session":…}.

#include <cstdint>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "common/transport/mesh_replica.h"
#include "cutsim/v1/wire.pb.h"

namespace cutsim::web {

inline constexpr uint8_t kSurfaceSnapshot = 1;
inline constexpr uint8_t kPositionsUpdate = 2;
inline constexpr uint8_t kBrowserFrameVersion = 1;
inline constexpr size_t kBrowserFrameHeaderBytes = 32;

/// Link health the bridge reports with each frame.
struct LinkHealth {
  double frame_age_ms = 0;  ///< Since the bridge received the frame it sends, ms.
  uint64_t bridge_gaps = 0;  ///< Sequence gaps the bridge's DDS subscriber saw.
  int clients = 0;           ///< Browsers connected.
};

/// Encodes replica states for browsers. Keeps the compact numbering of the
/// surface vertices between frames; not thread-safe.
class BrowserFrameEncoder {
 public:
  /// The mesh frame for browsers already in sync: a snapshot when the
  /// topology or surface changed since the last call (or on the first),
  /// else a positions update.
  [[nodiscard]] std::shared_ptr<const std::string> Frame(const transport::MeshReplica& mesh);
  /// A snapshot of the replica now (for a browser that joins).
  [[nodiscard]] std::shared_ptr<const std::string> Snapshot(const transport::MeshReplica& mesh);
  /// The session text frame of `seq`.
  [[nodiscard]] static std::shared_ptr<const std::string> Session(uint64_t seq,
                                                                 const std::optional<v1::ObserverSession>& observed,
                                                                 const LinkHealth& link);
  /// A browser's first message.
  [[nodiscard]] static std::shared_ptr<const std::string> Hello(const std::string& session);

 private:
  void Renumber(const transport::MeshReplica& mesh);
  [[nodiscard]] std::string Header(uint8_t kind, const transport::MeshReplica& mesh, uint32_t triangles,
                                   uint32_t opened) const;
  void AppendPositions(const transport::MeshReplica& mesh, std::string& out) const;

  bool have_topology_ = false;
  uint64_t topology_version_ = 0;
  int64_t surface_rows_ = -1;
  std::vector<int32_t> vertex_of_node_;  // #N: compact index or −1
  std::vector<int32_t> node_of_vertex_;  // #V
  std::vector<uint32_t> triangles_;      // #F×3 compact, intact first
  uint32_t opened_count_ = 0;
};

}  // namespace cutsim::web
