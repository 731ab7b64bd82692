// LCM's udpm packet format as cutsim parses it (lcm_packet.h): every kind
// of datagram, truncated headers and fragments, against packets built the
// way LCM builds them.
#include "common/transport/lcm_packet.h"

#include <array>
#include <cstdint>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "cutsim/v1/report.pb.h"

namespace cutsim::transport {
namespace {

std::vector<uint8_t> Bytes(std::string_view s) { return {s.begin(), s.end()}; }

std::vector<uint8_t> Packet(std::string_view channel, std::string_view payload, uint32_t seqno = 7) {
  std::vector<uint8_t> out(2048);
  const auto p = Bytes(payload);
  out.resize(WriteLcmPacket(seqno, channel, p, out));
  return out;
}

TEST(LcmPacketTest, ShortMessageRoundTripsChannelSeqnoAndPayload) {
  const auto d = Packet("CUTSIM_a_TOOL", "hello", 0x01020304);
  // The layout LCM sends: "LC02", big-endian seqno, channel, NUL, payload.
  ASSERT_EQ(d.size(), 8U + 13U + 1U + 5U);
  EXPECT_EQ(d[0], 'L');
  EXPECT_EQ(d[1], 'C');
  EXPECT_EQ(d[2], '0');
  EXPECT_EQ(d[3], '2');
  EXPECT_EQ(d[4], 0x01);
  EXPECT_EQ(d[7], 0x04);
  const LcmPacket p = ParseLcmPacket(d);
  ASSERT_EQ(p.kind, LcmPacketKind::kMessage);
  EXPECT_EQ(p.seqno, 0x01020304U);
  EXPECT_EQ(p.channel, "CUTSIM_a_TOOL");
  EXPECT_EQ(std::string(p.payload.begin(), p.payload.end()), "hello");
}

TEST(LcmPacketTest, EmptyPayloadIsAMessage) {
  const auto d = Packet("CH", "");
  const LcmPacket p = ParseLcmPacket(d);
  ASSERT_EQ(p.kind, LcmPacketKind::kMessage);
  EXPECT_EQ(p.channel, "CH");
  EXPECT_TRUE(p.payload.empty());
}

TEST(LcmPacketTest, EveryTruncationOfTheHeaderIsNotLcm) {
  const auto d = Packet("CUTSIM_a_TOOL", "xyz");
  // Any cut before the channel's NUL leaves no complete header.
  const size_t header = 8 + 13 + 1;
  for (size_t n = 0; n < header; ++n) {
    const LcmPacket p = ParseLcmPacket(std::span<const uint8_t>(d.data(), n));
    EXPECT_EQ(p.kind, LcmPacketKind::kNotLcm) << n << " bytes";
  }
  EXPECT_EQ(ParseLcmPacket(std::span<const uint8_t>(d.data(), header)).kind, LcmPacketKind::kMessage);
}

TEST(LcmPacketTest, OtherMagicsAndBadChannelsAreNotLcm) {
  auto d = Packet("CH", "x");
  d[3] = '1';  // "LC01"
  EXPECT_EQ(ParseLcmPacket(d).kind, LcmPacketKind::kNotLcm);
  // Empty channel (NUL right after the header).
  const std::vector<uint8_t> empty = {'L', 'C', '0', '2', 0, 0, 0, 1, 0, 'x'};
  EXPECT_EQ(ParseLcmPacket(empty).kind, LcmPacketKind::kNotLcm);
  // A channel of 64 characters (LCM's limit is 63): its NUL is too far.
  std::vector<uint8_t> longer = {'L', 'C', '0', '2', 0, 0, 0, 1};
  longer.insert(longer.end(), 64, 'A');
  longer.push_back(0);
  EXPECT_EQ(ParseLcmPacket(longer).kind, LcmPacketKind::kNotLcm);
  longer.erase(longer.begin() + 8);  // 63 characters: fine
  EXPECT_EQ(ParseLcmPacket(longer).kind, LcmPacketKind::kMessage);
  // Random bytes.
  const std::vector<uint8_t> junk = {0xde, 0xad, 0xbe, 0xef, 1, 2, 3, 4, 5, 6, 7, 8};
  EXPECT_EQ(ParseLcmPacket(junk).kind, LcmPacketKind::kNotLcm);
  EXPECT_EQ(WriteLcmPacket(1, std::string(64, 'A'), {}, std::span<uint8_t>()), 0U);
}

TEST(LcmPacketTest, FragmentsAreRecognisedWhateverTheirLength) {
  std::vector<uint8_t> out(2048);
  const auto data = Bytes("part of a large message");
  out.resize(WriteLcmFragment(9, "CUTSIM_a_TOOL", 5000, 0, 0, 4, data, out));
  ASSERT_EQ(out.size(), 20U + 14U + data.size());
  const LcmPacket p = ParseLcmPacket(out);
  EXPECT_EQ(p.kind, LcmPacketKind::kFragment);
  EXPECT_EQ(p.seqno, 9U);
  // A truncated fragment header is still a fragment (the magic says so).
  for (size_t n = 4; n < out.size(); n += 3) {
    EXPECT_EQ(ParseLcmPacket(std::span<const uint8_t>(out.data(), n)).kind, LcmPacketKind::kFragment) << n;
  }
  // Fragments after the first carry no channel.
  std::vector<uint8_t> second(2048);
  second.resize(WriteLcmFragment(9, "CUTSIM_a_TOOL", 5000, 1400, 1, 4, data, second));
  EXPECT_EQ(second.size(), 20U + data.size());
  EXPECT_EQ(ParseLcmPacket(second).kind, LcmPacketKind::kFragment);
}

TEST(LcmPacketTest, WriterRefusesABufferTooSmall) {
  std::array<uint8_t, 12> small{};
  const auto payload = Bytes("abc");
  EXPECT_EQ(WriteLcmPacket(1, "CHANNEL", payload, small), 0U);
  EXPECT_EQ(WriteLcmFragment(1, "CHANNEL", 9, 0, 0, 2, payload, small), 0U);
}

TEST(PacketCountersTest, ReasonsHaveDistinctNamesAndTheReportCarriesEach) {
  PacketCounters counters;
  for (size_t i = 0; i < kPacketReasonCount; ++i) counters.Add(static_cast<PacketReason>(i), i + 1);
  PacketCounts counts;
  for (size_t i = 0; i < kPacketReasonCount; ++i) counts.n[i] = counters.get(static_cast<PacketReason>(i));
  EXPECT_EQ(counts.total(), kPacketReasonCount * (kPacketReasonCount + 1) / 2);
  v1::LinkPacketReport report;
  ToReport(counts, &report);
  // Each reason lands in the report field of its own name, with its count.
  const auto* d = v1::LinkPacketReport::descriptor();
  const auto* refl = v1::LinkPacketReport::GetReflection();
  for (size_t i = 0; i < kPacketReasonCount; ++i) {
    const char* name = ToString(static_cast<PacketReason>(i));
    const auto* field = d->FindFieldByName(name);
    ASSERT_NE(field, nullptr) << name;
    EXPECT_EQ(refl->GetUInt32(report, field), i + 1) << name;
  }
  EXPECT_EQ(report.total(), static_cast<double>(counts.total()));
  EXPECT_EQ(counters.unauthentic(), 9U + 10 + 11 + 12 + 13 + 14);
}

TEST(PacketCountersTest, EveryRefusingVerdictHasItsReason) {
  EXPECT_EQ(ReasonOf(AuthVerdict::kOk), PacketReason::kAccepted);
  EXPECT_EQ(ReasonOf(AuthVerdict::kNewEpoch), PacketReason::kAccepted);
  EXPECT_EQ(ReasonOf(AuthVerdict::kUnsigned), PacketReason::kUnsigned);
  EXPECT_EQ(ReasonOf(AuthVerdict::kForged), PacketReason::kForged);
  EXPECT_EQ(ReasonOf(AuthVerdict::kReplayed), PacketReason::kReplayed);
  EXPECT_EQ(ReasonOf(AuthVerdict::kOutsideWindow), PacketReason::kOutsideWindow);
  EXPECT_EQ(ReasonOf(AuthVerdict::kInvalidEpoch), PacketReason::kInvalidEpoch);
  EXPECT_EQ(ReasonOf(AuthVerdict::kOtherSender), PacketReason::kOtherSender);
}

}  // namespace
}  // namespace cutsim::transport
