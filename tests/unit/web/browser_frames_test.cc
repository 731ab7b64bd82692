// The browsers' frames decoded as the page decodes them: a snapshot carries
// only the surface's vertices, its triangles draw the same positions as the
// replica's, the opened ones last; an update keeps the snapshot's vertex
// order; a topology change sends a new snapshot; the session frame is JSON
// with the observed session in protobuf's JSON mapping.
#include <gtest/gtest.h>

#include <cstring>
#include <string>
#include <vector>

#include "common/transport/mesh_hash.h"
#include "common/transport/mesh_replica.h"
#include "common/web/browser_frames.h"

namespace cutsim::web {
namespace {

constexpr double kQuantum = 1e-5;

/// Header and body of a browser frame, decoded.
struct Decoded {
  uint8_t kind = 0, version = 0;
  uint32_t vertices = 0, triangles = 0, opened = 0;
  double sim_time = 0, seq = 0;
  std::vector<float> positions;       // #V×3
  std::vector<uint32_t> indices;      // #F×3
};

template <typename V>
V At(const std::string& bytes, size_t offset) {
  V v;
  std::memcpy(&v, bytes.data() + offset, sizeof(V));
  return v;
}

Decoded Decode(const std::string& b) {
  Decoded d;
  EXPECT_GE(b.size(), kBrowserFrameHeaderBytes);
  d.kind = At<uint8_t>(b, 0);
  d.version = At<uint8_t>(b, 1);
  d.vertices = At<uint32_t>(b, 4);
  d.triangles = At<uint32_t>(b, 8);
  d.opened = At<uint32_t>(b, 12);
  d.sim_time = At<double>(b, 16);
  d.seq = At<double>(b, 24);
  const size_t want = kBrowserFrameHeaderBytes + 12 * size_t{d.vertices} + 12 * size_t{d.triangles};
  EXPECT_EQ(b.size(), want);
  if (b.size() != want) return d;
  size_t off = kBrowserFrameHeaderBytes;
  for (uint32_t i = 0; i < 3 * d.vertices; ++i, off += 4) d.positions.push_back(At<float>(b, off));
  for (uint32_t i = 0; i < 3 * d.triangles; ++i, off += 4) d.indices.push_back(At<uint32_t>(b, off));
  return d;
}

/// A replica holding six nodes: a surface of three triangles over five of
/// them (node 5 is interior), the middle one opened.
struct Fixture {
  transport::MeshReplica replica;
  v1::MeshSnapshot snapshot;

  explicit Fixture(uint64_t seq, double shift = 0.0, bool fourth_triangle = false) {
    const double p[6][3] = {{0, 0, 0}, {0.01, 0, 0}, {0, 0.01, 0}, {0, 0, 0.01}, {0.01, 0.01, 0.01}, {0.003, 0.003, 0.003}};
    transport::QuantisedPositions q(6, 3);
    for (int n = 0; n < 6; ++n) {
      for (int c = 0; c < 3; ++c) {
        q(n, c) = static_cast<int32_t>(std::lround((p[n][c] + (c == 2 ? shift : 0.0)) / kQuantum));
        snapshot.add_world(static_cast<float>(q(n, c) * kQuantum));
        snapshot.add_rest(static_cast<float>(std::lround(p[n][c] / kQuantum) * kQuantum));
      }
    }
    mesh::Tets tets(3, 4);
    tets << 0, 1, 2, 5, 1, 2, 4, 5, 0, 2, 3, 5;
    mesh::Triangles surface(fourth_triangle ? 4 : 3, 3);
    if (fourth_triangle) {
      surface << 0, 1, 2, 1, 2, 4, 0, 2, 3, 0, 1, 3;
    } else {
      surface << 0, 1, 2, 1, 2, 4, 0, 2, 3;
    }
    std::vector<uint8_t> opened(static_cast<size_t>(surface.rows()), 0);
    opened[1] = 1;
    for (int i = 0; i < tets.size(); ++i) snapshot.add_tets(static_cast<uint32_t>(tets(i / 4, i % 4)));
    for (Eigen::Index f = 0; f < surface.rows(); ++f) {
      for (int k = 0; k < 3; ++k) snapshot.add_surface(static_cast<uint32_t>(surface(f, k)));
      snapshot.add_opened(opened[static_cast<size_t>(f)] != 0);
    }
    const uint64_t version = fourth_triangle ? 2 : 1;
    snapshot.set_seq(seq);
    snapshot.set_frame(seq);
    snapshot.set_sim_time(0.01 * static_cast<double>(seq));
    snapshot.set_topology_version(version);
    snapshot.set_quantum(kQuantum);
    snapshot.set_hash(transport::MeshHash(version, q, tets, surface, opened));
    EXPECT_EQ(replica.ApplySnapshot(snapshot), transport::MeshReplica::SnapshotResult::kApplied);
  }
};

TEST(BrowserFramesTest, SnapshotCarriesTheSurfaceVerticesAndOpenedFacesLast) {
  const Fixture f(7);
  BrowserFrameEncoder enc;
  const Decoded d = Decode(*enc.Frame(f.replica));
  EXPECT_EQ(d.kind, kSurfaceSnapshot);
  EXPECT_EQ(d.version, kBrowserFrameVersion);
  EXPECT_EQ(d.vertices, 5u) << "node 5 is interior and not sent";
  EXPECT_EQ(d.triangles, 3u);
  EXPECT_EQ(d.opened, 1u);
  EXPECT_DOUBLE_EQ(d.seq, 7.0);
  EXPECT_DOUBLE_EQ(d.sim_time, 0.07);
  // Every triangle draws the replica's positions of its nodes; the opened
  // (1, 2, 4) comes last.
  const mesh::Triangles& s = f.replica.surface();
  const int order[3] = {0, 2, 1};
  for (int t = 0; t < 3; ++t) {
    for (int k = 0; k < 3; ++k) {
      const uint32_t v = d.indices[static_cast<size_t>(3 * t + k)];
      ASSERT_LT(v, d.vertices);
      for (int c = 0; c < 3; ++c) {
        EXPECT_FLOAT_EQ(d.positions[3 * v + static_cast<size_t>(c)],
                        static_cast<float>(f.replica.world()(s(order[t], k), c)));
      }
    }
  }
}

TEST(BrowserFramesTest, UpdateKeepsTheOrderAndATopologyChangeSendsASnapshot) {
  BrowserFrameEncoder enc;
  const Decoded first = Decode(*enc.Frame(Fixture(1).replica));
  const Fixture moved(2, 0.002);
  const Decoded update = Decode(*enc.Frame(moved.replica));
  EXPECT_EQ(update.kind, kPositionsUpdate);
  EXPECT_EQ(update.vertices, first.vertices);
  EXPECT_EQ(update.triangles, 0u);
  for (size_t v = 0; v < first.vertices; ++v) {
    EXPECT_FLOAT_EQ(update.positions[3 * v], first.positions[3 * v]);
    EXPECT_NEAR(static_cast<double>(update.positions[3 * v + 2]), static_cast<double>(first.positions[3 * v + 2]) + 0.002, 1e-6);
  }
  const Decoded cut = Decode(*enc.Frame(Fixture(3, 0.0, true).replica));
  EXPECT_EQ(cut.kind, kSurfaceSnapshot);
  EXPECT_EQ(cut.triangles, 4u);
  // A joining browser's snapshot equals the frame state without changing the
  // encoder's numbering.
  const Decoded join = Decode(*enc.Snapshot(Fixture(3, 0.0, true).replica));
  EXPECT_EQ(join.indices, cut.indices);
}

TEST(BrowserFramesTest, SessionFrameIsJsonWithTheObservedSession) {
  v1::ObserverSession o;
  o.set_sim_time(1.5);
  o.set_cuts(3);
  o.add_tools()->mutable_tip()->set_x(0.25);
  const std::string json = *BrowserFrameEncoder::Session(42, o, {.frame_age_ms = 1.5, .bridge_gaps = 2, .clients = 3});
  EXPECT_EQ(json.rfind(R"({"type":"session","seq":42,"observed":{)", 0), 0u) << json;
  EXPECT_NE(json.find(R"("simTime":1.5)"), std::string::npos) << json;
  EXPECT_NE(json.find(R"("cuts":"3")"), std::string::npos) << json;
  EXPECT_NE(json.find(R"("tip":{"x":0.25})"), std::string::npos) << json;
  EXPECT_NE(json.find(R"("link":{"frame_age_ms":1.500,"bridge_gaps":2,"clients":3})"), std::string::npos) << json;
  EXPECT_EQ(*BrowserFrameEncoder::Hello("lab-1"), R"({"type":"hello","protocol":1,"session":"lab-1"})");
  EXPECT_NE(BrowserFrameEncoder::Session(1, std::nullopt, {})->find(R"("observed":{})"), std::string::npos);
}

}  // namespace
}  // namespace cutsim::web
