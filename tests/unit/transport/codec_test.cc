#include "common/transport/codec.h"

#include <cstdint>
#include <random>
#include <string>
#include <vector>

#include <google/protobuf/util/message_differencer.h>
#include <gtest/gtest.h>

#include "cutsim/v1/wire.pb.h"

namespace cutsim::transport {
namespace {

using google::protobuf::util::MessageDifferencer;

v1::ToolState FilledTool() {
  v1::ToolState t;
  t.set_session("s1");
  t.set_seq(42);
  t.set_stamp_ns(123456789);
  t.mutable_tip()->set_x(0.01);
  t.mutable_tip()->set_y(-0.02);
  t.mutable_tip()->set_z(0.03);
  t.mutable_blade_dir()->set_z(1.0);
  t.mutable_velocity()->set_x(0.5);
  t.set_buttons(1);
  t.set_hmac(std::string(32, '\x5a'));  // last field: length-delimited
  return t;
}

std::vector<uint8_t> Bytes(const google::protobuf::MessageLite& m) {
  std::string s = m.SerializeAsString();
  return {s.begin(), s.end()};
}

TEST(CodecTest, EncodeDecodeRoundTrip) {
  Encoder encoder;
  const v1::ToolState tool = FilledTool();
  const auto bytes = encoder.Encode(tool);
  ASSERT_TRUE(bytes.has_value());
  DecodeError err;
  const auto back = Decode<v1::ToolState>(*bytes, "CUTSIM_s1_TOOL", &err);
  ASSERT_TRUE(back.has_value()) << err.Message();
  EXPECT_TRUE(MessageDifferencer::Equals(tool, *back));
  EXPECT_EQ(err.status, DecodeStatus::kOk);
}

TEST(CodecTest, EncoderReusesItsBufferAndReportsSize) {
  Encoder encoder;
  v1::MeshSnapshot big;
  for (int i = 0; i < 3000; ++i) big.add_world(static_cast<float>(i));
  const auto first = encoder.Encode(big);
  ASSERT_TRUE(first.has_value());
  const uint8_t* storage = first->data();
  const auto second = encoder.Encode(FilledTool());
  ASSERT_TRUE(second.has_value());
  EXPECT_EQ(second->data(), storage);  // smaller message: same buffer, no allocation

  size_t size = 0;
  EXPECT_FALSE(encoder.Encode(big, /*limit=*/100, &size).has_value());
  EXPECT_GT(size, 100U);
}

TEST(CodecTest, GarbageIsRejectedWithChannelAndType) {
  const std::vector<uint8_t> garbage = {0xff, 0xff, 0xff, 0xff, 0xff, 0xff, 0xff, 0xff, 0xff, 0xff, 0x01};
  DecodeError err;
  EXPECT_FALSE(Decode<v1::ToolState>(garbage, "CUTSIM_s1_TOOL", &err).has_value());
  EXPECT_EQ(err.status, DecodeStatus::kMalformed);
  const std::string msg = err.Message();
  EXPECT_NE(msg.find("CUTSIM_s1_TOOL"), std::string::npos) << msg;
  EXPECT_NE(msg.find("cutsim.v1.ToolState"), std::string::npos) << msg;
  EXPECT_NE(msg.find("11 bytes"), std::string::npos) << msg;
}

TEST(CodecTest, TruncationInsideAFieldIsRejected) {
  const std::vector<uint8_t> full = Bytes(FilledTool());
  DecodeError err;
  // Cutting into the trailing hmac bytes leaves a length prefix that overruns.
  for (size_t cut = 1; cut <= 31; ++cut) {
    const std::span<const uint8_t> prefix(full.data(), full.size() - cut);
    EXPECT_FALSE(Decode<v1::ToolState>(prefix, "CUTSIM_s1_TOOL", &err).has_value()) << cut;
    EXPECT_EQ(err.status, DecodeStatus::kMalformed);
  }
}

TEST(CodecTest, EveryTruncationIsHandledAndAcceptedOnesAreFieldPrefixes) {
  v1::HapticModel model;
  model.set_session("s");
  model.set_seq(9);
  model.mutable_x0()->set_x(1.5);
  for (int i = 0; i < 9; ++i) model.mutable_stiffness()->add_m(100.0 + i);
  model.mutable_cut()->set_cuts(3);
  model.set_topology_version(77);
  const std::vector<uint8_t> full = Bytes(model);
  int rejected = 0;
  for (size_t n = 0; n < full.size(); ++n) {
    DecodeError err;
    const auto got = Decode<v1::HapticModel>(std::span(full.data(), n), "CUTSIM_s_MODEL", &err);
    if (!got) {
      ++rejected;
      continue;
    }
    // Cut at a field boundary: a valid message with some trailing fields
    // missing, never one with different values.
    EXPECT_FALSE(MessageDifferencer::Equals(*got, model)) << n;
    if (got->seq() != 0) {
      EXPECT_EQ(got->seq(), 9U);
    }
  }
  EXPECT_GT(rejected, static_cast<int>(full.size()) / 2);
}

TEST(CodecTest, OversizedPayloadIsRejectedBeforeParsing) {
  const std::vector<uint8_t> huge(MaxPayloadBytes<v1::ToolState>() + 1, 0);
  DecodeError err;
  EXPECT_FALSE(Decode<v1::ToolState>(huge, "CUTSIM_s1_TOOL", &err).has_value());
  EXPECT_EQ(err.status, DecodeStatus::kTooLarge);
  EXPECT_EQ(err.limit, MaxPayloadBytes<v1::ToolState>());
  EXPECT_NE(err.Message().find("limit"), std::string::npos);
}

TEST(CodecTest, ControlMessagesFitOneDatagram) {
  EXPECT_LE(MaxPayloadBytes<v1::ToolState>(), kLcmMaxPayloadBytes);
  EXPECT_LE(MaxPayloadBytes<v1::HapticModel>(), kLcmMaxPayloadBytes);
  // A fully populated model is far below the limit.
  v1::HapticModel m;
  m.set_session(std::string(50, 's'));
  for (int i = 0; i < 9; ++i) m.mutable_stiffness()->add_m(1.0 + i);
  m.mutable_x0()->set_x(1);
  m.mutable_normal()->set_y(1);
  m.mutable_f0()->set_z(1);
  EXPECT_LT(m.ByteSizeLong(), 300U);
}

template <class Msg>
void FuzzDecode(std::mt19937_64& rng, int iterations) {
  std::uniform_int_distribution<int> len(0, 256);
  std::uniform_int_distribution<int> byte(0, 255);
  Msg msg;
  std::vector<uint8_t> buf;
  int accepted = 0;
  for (int i = 0; i < iterations; ++i) {
    buf.resize(static_cast<size_t>(len(rng)));
    for (auto& b : buf) b = static_cast<uint8_t>(byte(rng));
    DecodeError err;
    if (DecodeInto(buf, msg, "fuzz", &err)) {
      ++accepted;
      // Whatever parsed re-encodes and decodes to the same message.
      const std::string again = msg.SerializeAsString();
      const auto back = Decode<Msg>(std::span(reinterpret_cast<const uint8_t*>(again.data()), again.size()), "fuzz");
      ASSERT_TRUE(back.has_value()) << i;
      ASSERT_TRUE(MessageDifferencer::Equals(*back, msg)) << i;
    } else {
      EXPECT_NE(err.status, DecodeStatus::kOk);
      const std::string what = err.Message();
      EXPECT_NE(what.find("fuzz"), std::string::npos) << what;
      EXPECT_NE(what.find(Msg::descriptor()->full_name()), std::string::npos) << what;
    }
  }
  EXPECT_LT(accepted, iterations);  // random bytes are mostly garbage
}

TEST(CodecTest, RandomBytesNeverCrashAnyWireType) {
  std::mt19937_64 rng(20240917);
  FuzzDecode<v1::ToolState>(rng, 4000);
  FuzzDecode<v1::HapticModel>(rng, 4000);
  FuzzDecode<v1::MeshSnapshot>(rng, 4000);
  FuzzDecode<v1::MeshDelta>(rng, 4000);
  FuzzDecode<v1::SessionStatus>(rng, 4000);
}

// Bit flips in a real message reach deeper parser paths than pure noise.
// Every mutated payload is either refused with an error naming the channel
// and the type, or parses to a message that re-encodes and decodes to itself.
TEST(CodecTest, MutatedValidPayloadsAreRefusedOrParseToValidMessages) {
  v1::MeshDelta delta;
  delta.set_session("s");
  delta.set_seq(5);
  delta.set_topology_version(2);
  delta.set_num_nodes(9);
  delta.add_changed_tets(3);
  for (uint32_t v : {1U, 4U, 7U, 8U}) delta.add_changed_tet_nodes(v);
  delta.set_surface_changed(true);
  for (uint32_t v : {0U, 1U, 2U}) delta.add_surface(v);
  delta.add_opened(true);
  for (int i = 0; i < 12; ++i) delta.add_moved_dq(i - 6);
  const std::vector<uint8_t> good = Bytes(delta);
  v1::MeshDelta out;
  ASSERT_TRUE(DecodeInto(good, out, "cutsim_delta"));
  EXPECT_TRUE(MessageDifferencer::Equals(out, delta));  // the unmutated input round-trips

  std::mt19937_64 rng(7);
  std::uniform_int_distribution<size_t> pos(0, good.size() - 1);
  std::uniform_int_distribution<int> bit(0, 7);
  Encoder encoder;
  int refused = 0, parsed = 0;
  for (int i = 0; i < 5000; ++i) {
    std::vector<uint8_t> m = good;
    for (int k = 0; k < 3; ++k) m[pos(rng)] ^= static_cast<uint8_t>(1U << bit(rng));
    DecodeError err;
    if (!DecodeInto(m, out, "cutsim_delta", &err)) {
      ++refused;
      ASSERT_NE(err.status, DecodeStatus::kOk) << i;
      const std::string msg = err.Message();
      ASSERT_NE(msg.find("cutsim_delta"), std::string::npos) << i << ": " << msg;
      ASSERT_NE(msg.find("cutsim.v1.MeshDelta"), std::string::npos) << i << ": " << msg;
      continue;
    }
    ++parsed;
    ASSERT_EQ(err.status, DecodeStatus::kOk) << i;
    const auto bytes = encoder.Encode(out);
    ASSERT_TRUE(bytes.has_value()) << i;
    DecodeError again_err;
    const auto again = Decode<v1::MeshDelta>(*bytes, "cutsim_delta", &again_err);
    ASSERT_TRUE(again.has_value()) << i << ": " << again_err.Message();
    ASSERT_TRUE(MessageDifferencer::Equals(*again, out)) << i;
  }
  // Both outcomes occur, so both branches above were checked.
  EXPECT_GT(refused, 0);
  EXPECT_GT(parsed, 0);
}

}  // namespace
}  // namespace cutsim::transport
