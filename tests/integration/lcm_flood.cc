// cutsim-lcm-flood: a test and benchmark tool that floods one channel of the
// haptic link with hostile datagrams on an LCM udpm group (inside a private
// network namespace: tests and bench/flood_session.sh run it there).
//
// Kinds (--kind): `unsigned` (well-formed messages of the session with no
// tag: a cutting pose on the tool channel, an 8 N push on the model
// channel), `forged` (the same, signed with a random key), `garbage`
// (random bytes), `fragment` (LCM fragments of a message on the channel),
// `junk` (garbage and fragments in turn) and `mixed` (the four in turn). The packets are built once (256 of them) and
// sent in batches with sendmmsg every millisecond, at --rate packets per
// second. Prints one JSON line on exit: {"kind":"flood_stats","sent":…}.
#include <arpa/inet.h>
#include <netinet/in.h>
#include <sys/socket.h>
#include <unistd.h>

#include <atomic>
#include <cerrno>
#include <csignal>
#include <cstdio>
#include <cstring>
#include <random>
#include <string>
#include <vector>

#include <CLI/CLI.hpp>
#include <fmt/format.h>

#include "common/core/clock.h"
#include "common/core/log.h"
#include "common/transport/channels.h"
#include "common/transport/codec.h"
#include "common/transport/haptic_link.h"
#include "common/transport/lcm_packet.h"
#include "common/transport/stream_auth.h"
#include "common/transport/tool_auth.h"
#include "common/transport/udpm_receiver.h"

namespace {

using namespace cutsim;
std::atomic<bool> g_stop{false};
extern "C" void OnSignal(int /*sig*/) { g_stop.store(true); }

constexpr size_t kPackets = 256;

transport::SessionKey RandomKey(std::mt19937_64& rng) {
  transport::SessionKey k;
  k.size = 32;
  for (size_t i = 0; i < k.size; ++i) k.bytes[i] = static_cast<uint8_t>(rng());
  return k;
}

/// The payload of packet `i` of a message kind on `channel_kind`.
std::vector<uint8_t> Message(const std::string& session, bool tool, bool sign, uint64_t i,
                             transport::HmacToolAuthenticator& tool_signer,
                             transport::PayloadAuthenticator& model_signer) {
  transport::Encoder encoder;
  if (tool) {
    v1::ToolState t;
    t.set_session(session);
    t.set_seq(1'000'000 + i);
    t.set_stamp_ns(MonotonicNs());
    t.mutable_tip()->set_x(0.0151);  // through the ligament
    t.mutable_tip()->set_y(-0.008 + 0.016 * static_cast<double>(i) / kPackets);
    t.mutable_tip()->set_z(-0.006);
    t.mutable_blade_dir()->set_z(1.0);
    t.set_buttons(1);
    if (sign) tool_signer.Sign(&t);
    const auto bytes = encoder.Encode(t);
    return {bytes->begin(), bytes->end()};
  }
  v1::HapticModel m;
  m.set_session(session);
  m.set_seq(1'000'000 + i);
  m.set_stamp_ns(MonotonicNs());
  m.set_contact(true);
  m.mutable_normal()->set_z(1.0);
  m.mutable_f0()->set_z(8.0);  // 8 N
  m.set_valid_for(1.0);
  m.set_epoch(static_cast<uint64_t>(transport::RealtimeNowNs()));
  m.set_wall_ns(transport::RealtimeNowNs());
  const auto bytes = encoder.Encode(m);
  std::vector<uint8_t> out(bytes->begin(), bytes->end());
  if (sign) {
    out.resize(out.size() + transport::kTrailerBytes);
    (void)model_signer.MakeTrailer(std::span<const uint8_t>(out.data(), out.size() - transport::kTrailerBytes),
                                   std::span<uint8_t, transport::kTrailerBytes>(
                                       out.data() + out.size() - transport::kTrailerBytes, transport::kTrailerBytes));
  }
  return out;
}

}  // namespace

int main(int argc, char** argv) {
  std::string url = std::string(transport::kDefaultLcmUrl);
  std::string session = "default";
  std::string channel_kind = "tool";
  std::string kind = "unsigned";
  double rate = 50'000.0;
  double duration = 0.0;
  CLI::App app{"Floods one haptic-link channel with hostile datagrams (tests and benchmarks only)"};
  app.add_option("--lcm-url", url)->capture_default_str();
  app.add_option("--session", session)->capture_default_str();
  app.add_option("--channel", channel_kind, "tool | model")->capture_default_str();
  app.add_option("--kind", kind, "unsigned | forged | garbage | fragment | junk | mixed")->capture_default_str();
  app.add_option("--rate", rate, "Packets per second")->capture_default_str();
  app.add_option("--duration", duration, "Seconds (0 = until SIGTERM)")->capture_default_str();
  CLI11_PARSE(app, argc, argv);
  InitLogging("lcm-flood", "info");
  std::signal(SIGTERM, OnSignal);
  std::signal(SIGINT, OnSignal);
  if (channel_kind != "tool" && channel_kind != "model") {
    Log().error("--channel: \"{}\": use tool or model", channel_kind);
    return 2;
  }
  if (kind != "unsigned" && kind != "forged" && kind != "garbage" && kind != "fragment" && kind != "junk" &&
      kind != "mixed") {
    Log().error("--kind: \"{}\": use unsigned, forged, garbage, fragment, junk or mixed", kind);
    return 2;
  }
  const auto address = transport::ParseUdpmAddress(url);
  if (!address || !(rate > 0.0)) {
    Log().error("--lcm-url must be udpm://GROUP:PORT and --rate > 0");
    return 2;
  }
  const bool tool = channel_kind == "tool";
  const std::string channel =
      transport::LcmChannelName(session, tool ? transport::LcmChannel::kTool : transport::LcmChannel::kModel);

  std::mt19937_64 rng(0x5eed);
  const transport::SessionKey wrong = RandomKey(rng);
  transport::HmacToolAuthenticator tool_signer(wrong, session);
  transport::PayloadAuthenticator model_signer(wrong, transport::kHapticModelDomain, session);
  std::vector<std::vector<uint8_t>> packets(kPackets);
  for (size_t i = 0; i < kPackets; ++i) {
    std::string k = kind;
    if (k == "junk") k = i % 2 == 0 ? "garbage" : "fragment";
    if (k == "mixed") k = (i % 4 == 0) ? "unsigned" : (i % 4 == 1) ? "forged" : (i % 4 == 2) ? "garbage" : "fragment";
    std::vector<uint8_t>& p = packets[i];
    p.resize(1500);
    if (k == "garbage") {
      p.resize(16 + rng() % 600);
      for (auto& b : p) b = static_cast<uint8_t>(rng());
      p[0] = 0x00;  // never an LCM magic
    } else if (k == "fragment") {
      const auto msg = Message(session, tool, false, i, tool_signer, model_signer);
      const size_t half = msg.size() / 2;
      const auto n = transport::WriteLcmFragment(static_cast<uint32_t>(i), channel, static_cast<uint32_t>(msg.size()),
                                                 0, 0, 2, std::span<const uint8_t>(msg.data(), half), p);
      p.resize(n);
    } else {
      const auto msg = Message(session, tool, k == "forged", i, tool_signer, model_signer);
      p.resize(transport::WriteLcmPacket(static_cast<uint32_t>(i), channel, msg, p));
    }
  }

  const int fd = ::socket(AF_INET, SOCK_DGRAM | SOCK_CLOEXEC, 0);
  if (fd < 0) {
    Log().error("socket: {}", std::strerror(errno));
    return 1;
  }
  const unsigned char ttl = 0, loop = 1;
  (void)::setsockopt(fd, IPPROTO_IP, IP_MULTICAST_TTL, &ttl, sizeof(ttl));
  (void)::setsockopt(fd, IPPROTO_IP, IP_MULTICAST_LOOP, &loop, sizeof(loop));
  const int sndbuf = 4 << 20;
  (void)::setsockopt(fd, SOL_SOCKET, SO_SNDBUF, &sndbuf, sizeof(sndbuf));
  sockaddr_in to{};
  to.sin_family = AF_INET;
  to.sin_addr = address->group;
  to.sin_port = htons(address->port);

  constexpr size_t kMaxBatch = 256;
  std::vector<iovec> iov(kMaxBatch);
  std::vector<mmsghdr> msgs(kMaxBatch);
  const int64_t start = MonotonicNs();
  const int64_t end = duration > 0.0 ? start + static_cast<int64_t>(duration * 1e9) : INT64_MAX;
  uint64_t sent = 0, errors = 0, skipped = 0, next = 0;
  Log().info("flooding {} with {} packets at {:.0f}/s", channel, kind, rate);
  // Batches of what is due; the thread sleeps only when it is on schedule.
  // When sending takes longer (the kernel delivers each datagram to every
  // socket on the group in this thread), the rate is what the machine
  // allows: the JSON reports it, and what fell more than a second behind.
  const auto budget = static_cast<uint64_t>(rate);
  while (!g_stop.load() && MonotonicNs() < end) {
    const int64_t now = MonotonicNs();
    const auto due = static_cast<uint64_t>(1e-9 * static_cast<double>(now - start) * rate);
    const uint64_t done = sent + errors + skipped;
    if (done >= due) {
      SleepUntilNs(now + 200'000);
      continue;
    }
    if (due - done > budget) skipped += due - done - budget;
    size_t n = static_cast<size_t>(std::min<uint64_t>(due - (sent + errors + skipped), kMaxBatch));
    for (size_t i = 0; i < n; ++i) {
      std::vector<uint8_t>& p = packets[(next + i) % kPackets];
      iov[i] = {.iov_base = p.data(), .iov_len = p.size()};
      msgs[i] = mmsghdr{};
      msgs[i].msg_hdr.msg_name = &to;
      msgs[i].msg_hdr.msg_namelen = sizeof(to);
      msgs[i].msg_hdr.msg_iov = &iov[i];
      msgs[i].msg_hdr.msg_iovlen = 1;
    }
    while (n > 0) {
      const int k = ::sendmmsg(fd, msgs.data(), static_cast<unsigned>(n), 0);
      if (k <= 0) {
        errors += n;
        break;
      }
      sent += static_cast<uint64_t>(k);
      next += static_cast<uint64_t>(k);
      std::memmove(msgs.data(), msgs.data() + k, (n - static_cast<size_t>(k)) * sizeof(mmsghdr));
      n -= static_cast<size_t>(k);
    }
  }
  ::close(fd);
  const double seconds = 1e-9 * static_cast<double>(MonotonicNs() - start);
  std::printf("%s\n", fmt::format(R"({{"kind":"flood_stats","channel":"{}","flood":"{}","sent":{},"errors":{},"skipped":{},)"
                                  R"("seconds":{:.3f},"rate":{:.0f}}})",
                                  channel_kind, kind, sent, errors, skipped, seconds, sent / std::max(seconds, 1e-9))
                      .c_str());
  return 0;
}
