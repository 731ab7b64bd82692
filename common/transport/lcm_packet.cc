#include "common/transport/lcm_packet.h"

#include <cstring>

#include "common/transport/report_json.h"
#include "cutsim/v1/report.pb.h"

namespace cutsim::transport {
namespace {

uint32_t ReadU32(const uint8_t* p) {
  return static_cast<uint32_t>(p[0]) << 24 | static_cast<uint32_t>(p[1]) << 16 |
         static_cast<uint32_t>(p[2]) << 8 | static_cast<uint32_t>(p[3]);
}

void WriteU32(uint32_t v, uint8_t* p) {
  p[0] = static_cast<uint8_t>(v >> 24);
  p[1] = static_cast<uint8_t>(v >> 16);
  p[2] = static_cast<uint8_t>(v >> 8);
  p[3] = static_cast<uint8_t>(v);
}

void WriteU16(uint16_t v, uint8_t* p) {
  p[0] = static_cast<uint8_t>(v >> 8);
  p[1] = static_cast<uint8_t>(v);
}

}  // namespace

LcmPacket ParseLcmPacket(std::span<const uint8_t> d) noexcept {
  LcmPacket p;
  if (d.size() < 4) return p;
  const uint32_t magic = ReadU32(d.data());
  if (magic == kLcmMagicLong) {
    p.kind = LcmPacketKind::kFragment;
    if (d.size() >= 8) p.seqno = ReadU32(d.data() + 4);
    return p;
  }
  if (magic != kLcmMagicShort || d.size() < kLcmShortHeaderBytes + 1) return p;
  const uint8_t* name = d.data() + kLcmShortHeaderBytes;
  const size_t room = std::min(d.size() - kLcmShortHeaderBytes, kLcmMaxChannelChars + 1);
  const void* nul = std::memchr(name, '\0', room);
  if (nul == nullptr) return p;  // unterminated, or longer than 63 characters
  const size_t length = static_cast<size_t>(static_cast<const uint8_t*>(nul) - name);
  if (length == 0) return p;
  p.kind = LcmPacketKind::kMessage;
  p.seqno = ReadU32(d.data() + 4);
  p.channel = std::string_view(reinterpret_cast<const char*>(name), length);
  p.payload = d.subspan(kLcmShortHeaderBytes + length + 1);
  return p;
}

size_t WriteLcmPacket(uint32_t seqno, std::string_view channel, std::span<const uint8_t> payload,
                      std::span<uint8_t> out) noexcept {
  if (channel.empty() || channel.size() > kLcmMaxChannelChars) return 0;
  const size_t size = kLcmShortHeaderBytes + channel.size() + 1 + payload.size();
  if (out.size() < size) return 0;
  WriteU32(kLcmMagicShort, out.data());
  WriteU32(seqno, out.data() + 4);
  std::memcpy(out.data() + kLcmShortHeaderBytes, channel.data(), channel.size());
  out[kLcmShortHeaderBytes + channel.size()] = 0;
  if (!payload.empty()) std::memcpy(out.data() + size - payload.size(), payload.data(), payload.size());
  return size;
}

size_t WriteLcmFragment(uint32_t seqno, std::string_view channel, uint32_t message_size, uint32_t offset,
                        uint16_t number, uint16_t count, std::span<const uint8_t> data,
                        std::span<uint8_t> out) noexcept {
  if (channel.empty() || channel.size() > kLcmMaxChannelChars) return 0;
  const size_t name = number == 0 ? channel.size() + 1 : 0;
  const size_t size = kLcmLongHeaderBytes + name + data.size();
  if (out.size() < size) return 0;
  WriteU32(kLcmMagicLong, out.data());
  WriteU32(seqno, out.data() + 4);
  WriteU32(message_size, out.data() + 8);
  WriteU32(offset, out.data() + 12);
  WriteU16(number, out.data() + 16);
  WriteU16(count, out.data() + 18);
  if (name > 0) {
    std::memcpy(out.data() + kLcmLongHeaderBytes, channel.data(), channel.size());
    out[kLcmLongHeaderBytes + channel.size()] = 0;
  }
  if (!data.empty()) std::memcpy(out.data() + kLcmLongHeaderBytes + name, data.data(), data.size());
  return size;
}

const char* ToString(PacketReason reason) {
  switch (reason) {
    case PacketReason::kAccepted: return "accepted";
    case PacketReason::kSuperseded: return "superseded";
    case PacketReason::kNotLcm: return "not_lcm";
    case PacketReason::kFragment: return "fragment";
    case PacketReason::kOtherChannel: return "other_channel";
    case PacketReason::kOversized: return "oversized";
    case PacketReason::kDecodeError: return "decode_error";
    case PacketReason::kForeignSession: return "foreign_session";
    case PacketReason::kUnsigned: return "unsigned";
    case PacketReason::kForged: return "forged";
    case PacketReason::kReplayed: return "replayed";
    case PacketReason::kOutsideWindow: return "outside_window";
    case PacketReason::kInvalidEpoch: return "invalid_epoch";
    case PacketReason::kOtherSender: return "other_sender";
    case PacketReason::kInvalid: return "invalid";
    case PacketReason::kStale: return "stale";
    case PacketReason::kCount: break;
  }
  return "?";
}

PacketReason ReasonOf(AuthVerdict verdict) noexcept {
  switch (verdict) {
    case AuthVerdict::kOk:
    case AuthVerdict::kNewEpoch: return PacketReason::kAccepted;
    case AuthVerdict::kUnsigned: return PacketReason::kUnsigned;
    case AuthVerdict::kForged: return PacketReason::kForged;
    case AuthVerdict::kReplayed: return PacketReason::kReplayed;
    case AuthVerdict::kOutsideWindow: return PacketReason::kOutsideWindow;
    case AuthVerdict::kInvalidEpoch: return PacketReason::kInvalidEpoch;
    case AuthVerdict::kOtherSender: return PacketReason::kOtherSender;
  }
  return PacketReason::kForged;
}

uint64_t PacketCounters::unauthentic() const noexcept {
  uint64_t n = 0;
  for (auto r : {PacketReason::kUnsigned, PacketReason::kForged, PacketReason::kReplayed,
                 PacketReason::kOutsideWindow, PacketReason::kInvalidEpoch, PacketReason::kOtherSender}) {
    n += get(r);
  }
  return n;
}

uint64_t PacketCounts::total() const {
  uint64_t t = 0;
  for (const uint64_t v : n) t += v;
  return t;
}

void ToReport(const PacketCounts& c, v1::LinkPacketReport* r) {
  using R = PacketReason;
  r->set_accepted(ReportCount(c[R::kAccepted]));
  r->set_superseded(ReportCount(c[R::kSuperseded]));
  r->set_not_lcm(ReportCount(c[R::kNotLcm]));
  r->set_fragment(ReportCount(c[R::kFragment]));
  r->set_other_channel(ReportCount(c[R::kOtherChannel]));
  r->set_oversized(ReportCount(c[R::kOversized]));
  r->set_decode_error(ReportCount(c[R::kDecodeError]));
  r->set_foreign_session(ReportCount(c[R::kForeignSession]));
  r->set_unsigned_(ReportCount(c[R::kUnsigned]));
  r->set_forged(ReportCount(c[R::kForged]));
  r->set_replayed(ReportCount(c[R::kReplayed]));
  r->set_outside_window(ReportCount(c[R::kOutsideWindow]));
  r->set_invalid_epoch(ReportCount(c[R::kInvalidEpoch]));
  r->set_other_sender(ReportCount(c[R::kOtherSender]));
  r->set_invalid(ReportCount(c[R::kInvalid]));
  r->set_stale(ReportCount(c[R::kStale]));
  r->set_total(static_cast<double>(c.total()));
  r->set_kernel_dropped(ReportCount(c.kernel_dropped));
  r->set_packet_level(c.packet_level);
}

}  // namespace cutsim::transport
