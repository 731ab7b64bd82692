#pragma once
/// @file
/// LCM's UDP multicast packet format, parsed by cutsim itself so that the
/// haptic link can judge every datagram before anything queues it
/// (udpm_receiver.h), and the per-reason counters every packet of the link
/// lands in.
///
/// LCM (lcm_udpm.c, udpm_util.h) sends two kinds of datagram, big-endian:
///
/// * short message, magic "LC02" (0x4c433032): magic (4), sequence number
///   (4), the channel name NUL-terminated (at most 63 characters), payload;
/// * fragment, magic "LC03" (0x4c433033): magic, sequence number, message
///   size (4), fragment offset (4), fragment number (2), fragment count (2),
///   then (in fragment 0 only) the channel, then data.
///
/// The tool and model channels' messages fit one datagram
/// (`kLcmMaxPayloadBytes`), so cutsim never sends a fragment on them: the
/// receiver counts and drops every fragment without reassembling it.

#include <array>
#include <atomic>
#include <cstddef>
#include <cstdint>
#include <span>
#include <string_view>

#include "common/transport/stream_auth.h"

namespace cutsim::v1 {
class LinkPacketReport;
}  // namespace cutsim::v1

namespace cutsim::transport {

inline constexpr uint32_t kLcmMagicShort = 0x4c433032;  ///< "LC02"
inline constexpr uint32_t kLcmMagicLong = 0x4c433033;   ///< "LC03"
inline constexpr size_t kLcmShortHeaderBytes = 8;       ///< magic + sequence number
inline constexpr size_t kLcmLongHeaderBytes = 20;       ///< + size, offset, fragment no., count
inline constexpr size_t kLcmMaxChannelChars = 63;       ///< LCM_MAX_CHANNEL_NAME_LENGTH

/// What a datagram is.
enum class LcmPacketKind : uint8_t {
  kMessage,   ///< A whole short message: `channel` and `payload` are set.
  kFragment,  ///< A fragment of a large message (LC03), whatever its length.
  kNotLcm,    ///< Too short for a header, another magic, or a channel that is
              ///< not NUL-terminated within 64 bytes of the header.
};

/// A parsed datagram; views into the datagram's bytes.
struct LcmPacket {
  LcmPacketKind kind = LcmPacketKind::kNotLcm;
  uint32_t seqno = 0;
  std::string_view channel;
  std::span<const uint8_t> payload;
};

/// Parses one datagram (never reads past it; never throws or allocates).
[[nodiscard]] LcmPacket ParseLcmPacket(std::span<const uint8_t> datagram) noexcept;

/// Writes a short message as LCM sends it into `out`; returns its size, or 0
/// if `out` is too small or the channel is empty or over 63 characters
/// (tests and the flood tool).
size_t WriteLcmPacket(uint32_t seqno, std::string_view channel, std::span<const uint8_t> payload,
                      std::span<uint8_t> out) noexcept;

/// Writes fragment `number` of `count` of a message of `message_size` bytes
/// (the channel in fragment 0), with `data` as its part; returns the size or 0.
size_t WriteLcmFragment(uint32_t seqno, std::string_view channel, uint32_t message_size,
                        uint32_t offset, uint16_t number, uint16_t count,
                        std::span<const uint8_t> data, std::span<uint8_t> out) noexcept;

/// Why one received packet of the haptic link went where it went. Every
/// datagram that reaches the link's socket is counted under exactly one.
enum class PacketReason : uint8_t {
  kAccepted,       ///< Taken by its consumer (the physics, the servo loop).
  kSuperseded,     ///< Passed every check, but a newer one replaced it before it was taken.
  kNotLcm,         ///< Garbage: not an LCM packet.
  kFragment,       ///< An LCM fragment (never legitimate on the link's channels).
  kOtherChannel,   ///< An LCM message on another channel (not a drop: not ours).
  kOversized,      ///< Larger than the message type's limit, or than the receive buffer.
  kDecodeError,    ///< Not a valid protobuf of the channel's type.
  kForeignSession, ///< Its `session` field is not ours.
  kUnsigned,       ///< No tag while the session has a key.
  kForged,         ///< A tag that does not verify.
  kReplayed,       ///< Authentic, not newer than one already accepted from its sender.
  kOutsideWindow,  ///< Authentic, signed too far from our clock.
  kInvalidEpoch,   ///< Authentic, its epoch after its own signing time.
  kOtherSender,    ///< Authentic, from an older sender while the followed one is alive.
  kInvalid,        ///< A non-finite or absurd pose; a model whose stiffness is not 3×3.
  kStale,          ///< A duplicate or older sequence number.
  kCount,
};
inline constexpr size_t kPacketReasonCount = static_cast<size_t>(PacketReason::kCount);

/// Name of a reason (snake case, as in the reports).
[[nodiscard]] const char* ToString(PacketReason reason);

/// The reason for a refused authentication verdict (kOk/kNewEpoch: kAccepted).
[[nodiscard]] PacketReason ReasonOf(AuthVerdict verdict) noexcept;

/// Per-reason packet counts, written by one thread and read by any.
class PacketCounters {
 public:
  void Add(PacketReason reason, uint64_t n = 1) noexcept {
    counts_[static_cast<size_t>(reason)].fetch_add(n, std::memory_order_relaxed);
  }
  [[nodiscard]] uint64_t get(PacketReason reason) const noexcept {
    return counts_[static_cast<size_t>(reason)].load(std::memory_order_relaxed);
  }
  /// Refusals by the authentication (unsigned through other-sender).
  [[nodiscard]] uint64_t unauthentic() const noexcept;

 private:
  std::array<std::atomic<uint64_t>, kPacketReasonCount> counts_{};
};

/// A copy of the counters (for stats and reports).
struct PacketCounts {
  std::array<uint64_t, kPacketReasonCount> n{};
  uint64_t kernel_dropped = 0;  ///< Dropped by the kernel on a full socket buffer (SO_RXQ_OVFL).
  bool packet_level = false;    ///< Counted per datagram (udpm receiver); else per LCM delivery.
  [[nodiscard]] uint64_t operator[](PacketReason r) const { return n[static_cast<size_t>(r)]; }
  /// Every datagram counted (the sum over all reasons).
  [[nodiscard]] uint64_t total() const;
};

/// The counts as their report (report.proto), counts saturated to uint32.
void ToReport(const PacketCounts& counts, v1::LinkPacketReport* report);

}  // namespace cutsim::transport
