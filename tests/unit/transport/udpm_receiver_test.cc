// The packet-level udpm receiver (udpm_receiver.h) and the haptic link on
// it, with real multicast datagrams. ctest runs this inside a private
// network namespace (deploy/netns-run.sh), so nothing leaves its loopback.
#include "common/transport/udpm_receiver.h"

#include <arpa/inet.h>
#include <poll.h>
#include <sys/socket.h>
#include <unistd.h>

#include <string>
#include <thread>
#include <vector>

#include <gtest/gtest.h>

#include "common/core/clock.h"
#include "common/transport/channels.h"
#include "common/transport/codec.h"
#include "common/transport/haptic_link.h"
#include "common/transport/lcm_bus.h"
#include "common/transport/tool_auth.h"

namespace cutsim::transport {
namespace {

std::string Url(int port) { return "udpm://239.255.76.67:" + std::to_string(port) + "?ttl=0"; }

/// Sends raw datagrams to the group, as any host on it could.
class RawSender {
 public:
  explicit RawSender(int port) : fd_(::socket(AF_INET, SOCK_DGRAM, 0)) {
    const unsigned char ttl = 0, loop = 1;
    ::setsockopt(fd_, IPPROTO_IP, IP_MULTICAST_TTL, &ttl, sizeof(ttl));
    ::setsockopt(fd_, IPPROTO_IP, IP_MULTICAST_LOOP, &loop, sizeof(loop));
    to_.sin_family = AF_INET;
    inet_aton("239.255.76.67", &to_.sin_addr);
    to_.sin_port = htons(static_cast<uint16_t>(port));
  }
  ~RawSender() { ::close(fd_); }
  void Send(std::span<const uint8_t> d) {
    ASSERT_EQ(::sendto(fd_, d.data(), d.size(), 0, reinterpret_cast<const sockaddr*>(&to_), sizeof(to_)),
              static_cast<ssize_t>(d.size()));
  }
  void SendMessage(std::string_view channel, std::span<const uint8_t> payload) {
    std::vector<uint8_t> d(65000);
    d.resize(WriteLcmPacket(seq_++, channel, payload, d));
    Send(d);
  }

 private:
  int fd_;
  sockaddr_in to_{};
  uint32_t seq_ = 0;
};

/// Drains `r` until `datagrams` arrived or 5 s passed.
template <class F>
void DrainUntil(UdpmReceiver& r, uint64_t datagrams, F&& on_message) {
  const int64_t deadline = MonotonicNs() + 5'000'000'000;
  while (r.datagrams() < datagrams && MonotonicNs() < deadline) {
    pollfd p{.fd = r.fd(), .events = POLLIN, .revents = 0};
    ::poll(&p, 1, 50);
    r.Drain(on_message);
  }
}

TEST(UdpmReceiverTest, ParsesUdpmUrlsOnly) {
  const auto a = ParseUdpmAddress("udpm://239.255.76.67:7667?ttl=0");
  ASSERT_TRUE(a.has_value());
  EXPECT_EQ(a->port, 7667);
  EXPECT_EQ(ntohl(a->group.s_addr), 0xEFFF4C43U);
  const auto d = ParseUdpmAddress("udpm://");
  ASSERT_TRUE(d.has_value());  // LCM's defaults
  EXPECT_EQ(d->port, 7667);
  EXPECT_FALSE(ParseUdpmAddress("memq://").has_value());
  EXPECT_FALSE(ParseUdpmAddress("udpm://239.1.1.1:0").has_value());
  EXPECT_FALSE(ParseUdpmAddress("udpm://nonsense:7667").has_value());
}

TEST(UdpmReceiverTest, EveryDatagramIsCountedOnceOrHandedOver) {
  const int port = 7600 + getpid() % 50;
  PacketCounters counters;
  UdpmReceiver receiver(Url(port), "CUTSIM_t_TOOL", counters,
                        UdpmReceiver::Options{.max_datagram = 2048, .max_payload = 1400});
  EXPECT_GT(receiver.receive_buffer_bytes(), 0);
  RawSender s(port);
  const std::vector<uint8_t> payload = {1, 2, 3, 4};
  const std::vector<uint8_t> big(1500, 7);    // over the payload limit, within the buffer
  const std::vector<uint8_t> huge(4000, 9);   // over the receive buffer: truncated by the kernel
  s.SendMessage("CUTSIM_t_TOOL", payload);    // ours
  s.SendMessage("CUTSIM_t_MODEL", payload);   // another channel
  s.SendMessage("CUTSIM_t_TOOL", big);        // oversized payload
  s.SendMessage("CUTSIM_t_TOOL", huge);       // oversized datagram
  const std::vector<uint8_t> junk = {0xde, 0xad, 0xbe, 0xef, 0, 1};
  s.Send(junk);                                                   // not LCM
  s.Send(std::span<const uint8_t>(std::vector<uint8_t>{'L', 'C', '0', '2', 0, 0}));  // truncated header
  std::vector<uint8_t> frag(256);
  frag.resize(WriteLcmFragment(1, "CUTSIM_t_TOOL", 3000, 0, 0, 3, payload, frag));
  s.Send(frag);                                                   // a fragment
  s.SendMessage("CUTSIM_t_TOOL", {});                            // ours, empty
  std::vector<std::vector<uint8_t>> got;
  DrainUntil(receiver, 8, [&](std::span<const uint8_t> p, int64_t receive_ns) {
    EXPECT_GT(receive_ns, 0);
    got.emplace_back(p.begin(), p.end());
  });
  ASSERT_EQ(receiver.datagrams(), 8U);
  ASSERT_EQ(got.size(), 2U);
  EXPECT_EQ(got[0], payload);
  EXPECT_TRUE(got[1].empty());
  EXPECT_EQ(counters.get(PacketReason::kOtherChannel), 1U);
  EXPECT_EQ(counters.get(PacketReason::kOversized), 2U);
  EXPECT_EQ(counters.get(PacketReason::kNotLcm), 2U);
  EXPECT_EQ(counters.get(PacketReason::kFragment), 1U);
  EXPECT_EQ(receiver.kernel_dropped(), 0U);
}

TEST(UdpmReceiverTest, CoexistsWithLcmsOwnSubscriberOnTheSamePort) {
  const int port = 7650 + getpid() % 50;
  LcmBus bus(Url(port));
  int lcm_got = 0;
  auto sub = bus.SubscribeRaw("CUTSIM_c_TOOL", 1400, [&](std::span<const uint8_t>) { ++lcm_got; });
  PacketCounters counters;
  UdpmReceiver receiver(Url(port), "CUTSIM_c_TOOL", counters);
  const std::vector<uint8_t> payload = {5, 6};
  ASSERT_EQ(bus.PublishBytes("CUTSIM_c_TOOL", payload), PublishStatus::kOk);  // LCM's own sender
  int ours = 0;
  DrainUntil(receiver, 1, [&](std::span<const uint8_t> p, int64_t) { ours += p.size() == 2 ? 1 : 0; });
  EXPECT_EQ(ours, 1);
  const int64_t deadline = MonotonicNs() + 5'000'000'000;
  while (lcm_got == 0 && MonotonicNs() < deadline) bus.HandleTimeout(50);
  EXPECT_EQ(lcm_got, 1);  // both sockets got the datagram
}

constexpr char kKeyHex[] = "8f1c2e3d4a5b6c7d8e9fa0b1c2d3e4f5061728394a5b6c7d8e9fa0b1c2d3e4f5";

// The server's link on udpm: an unsigned flood on the tool channel is
// judged before the mailbox, so a genuine signed pose still gets through,
// and every datagram lands under exactly one reason.
TEST(UdpmHapticLinkTest, UnsignedFloodIsCountedAndDoesNotDisplaceGenuinePoses) {
  const int port = 7700 + getpid() % 50;
  const std::string session = "flood";
  const auto key = ParseSessionKey(kKeyHex, "test");
  HmacToolAuthenticator verifier(key, session);
  HmacToolAuthenticator station(key, session);
  LcmBus server_bus(Url(port));
  HapticServerLink link(server_bus, session, {.authenticator = &verifier});
  ASSERT_TRUE(link.packet_level());
  link.StartReceiving();
  RawSender s(port);
  Encoder encoder;
  v1::ToolState t;
  t.set_session(session);
  t.mutable_tip()->set_z(0.01);
  t.mutable_blade_dir()->set_z(1.0);
  constexpr int kRounds = 200, kFlood = 50;
  int genuine_taken = 0;
  uint64_t seq = 0;
  for (int round = 0; round < kRounds; ++round) {
    // A burst of unsigned junk, then the station's genuine pose, then more junk.
    v1::ToolState junk = t;
    junk.set_seq(1'000'000 + round);
    junk.clear_hmac();  // unsigned (t carries the previous round's tag)
    const auto junk_bytes = encoder.Encode(junk);
    const std::vector<uint8_t> junk_copy(junk_bytes->begin(), junk_bytes->end());
    for (int i = 0; i < kFlood / 2; ++i) s.SendMessage(LcmChannelName(session, LcmChannel::kTool), junk_copy);
    t.set_seq(++seq);
    t.set_stamp_ns(MonotonicNs());
    station.Sign(&t);
    const auto bytes = encoder.Encode(t);
    s.SendMessage(LcmChannelName(session, LcmChannel::kTool), *bytes);
    for (int i = 0; i < kFlood / 2; ++i) s.SendMessage(LcmChannelName(session, LcmChannel::kTool), junk_copy);
    const int64_t deadline = MonotonicNs() + 2'000'000'000;
    std::optional<ToolSample> got;
    while (MonotonicNs() < deadline) {
      got = link.PollTool();
      if (got && got->seq == seq) break;
      std::this_thread::sleep_for(std::chrono::microseconds(200));
    }
    if (got && got->seq == seq) ++genuine_taken;
  }
  // Wait until the receive thread has read everything sent.
  const uint64_t sent = static_cast<uint64_t>(kRounds) * (kFlood + 1);
  const int64_t deadline = MonotonicNs() + 5'000'000'000;
  while (link.stats().packets.total() < sent && MonotonicNs() < deadline) {
    std::this_thread::sleep_for(std::chrono::milliseconds(5));
  }
  link.StopReceiving();
  const PacketCounts c = link.stats().packets;
  EXPECT_EQ(genuine_taken, kRounds);
  EXPECT_EQ(c[PacketReason::kAccepted], static_cast<uint64_t>(kRounds));
  EXPECT_EQ(c[PacketReason::kUnsigned], static_cast<uint64_t>(kRounds * kFlood));
  EXPECT_EQ(c.total() + c.kernel_dropped, sent) << "every datagram under exactly one reason";
  EXPECT_TRUE(c.packet_level);
}

}  // namespace
}  // namespace cutsim::transport
