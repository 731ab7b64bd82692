#pragma once
/// @file
/// Protobuf codecs for everything cutsim puts on a wire (LCM channels, DDS
/// envelope payloads). Decoding untrusted bytes never throws and never
/// crashes: a bad payload yields a `DecodeError` that names the channel or
/// topic, the message type and what was wrong, and the caller drops it and
/// counts it. Each message type has a size limit (`MaxPayloadBytes`), checked
/// before parsing so that a hostile length cannot make us allocate.
///
/// Hot-path use: keep one message object and one `Encoder` per stream and
/// call `DecodeInto` / `Encoder::Encode` on them; protobuf reuses the
/// message's storage after the first few messages, and the encoder reuses its
/// buffer, so the steady state does not allocate.

#include <cstddef>
#include <cstdint>
#include <optional>
#include <span>
#include <string>
#include <string_view>
#include <type_traits>
#include <vector>

#include <google/protobuf/message_lite.h>

#include "common/transport/stream_auth.h"
#include "cutsim/v1/wire.pb.h"

namespace cutsim::transport {

/// Largest serialised size we accept for a message type, bytes. The haptic
/// link (LCM) must fit one UDP datagram with the LCM header and channel name,
/// see `kLcmMaxPayloadBytes`; mesh snapshots and deltas are bounded by what a
/// viewer can sensibly hold in memory.
template <class Msg>
constexpr size_t MaxPayloadBytes() {
  if constexpr (std::is_same_v<Msg, ::cutsim::v1::ToolState> ||
                std::is_same_v<Msg, ::cutsim::v1::HapticModel> ||
                std::is_same_v<Msg, ::cutsim::v1::ServerPresence> ||
                std::is_same_v<Msg, ::cutsim::v1::DebriefControl>) {
    return 1400;
  } else if constexpr (std::is_same_v<Msg, ::cutsim::v1::SessionStatus>) {
    return 4 * 1024;
  } else if constexpr (std::is_same_v<Msg, ::cutsim::v1::MeshSnapshot>) {
    return size_t{512} << 20;  // 512 MiB: ~5 M tets with positions.
  } else if constexpr (std::is_same_v<Msg, ::cutsim::v1::MeshDelta>) {
    return size_t{128} << 20;
  } else {
    return size_t{16} << 20;
  }
}

/// Largest payload published on an LCM control channel, bytes. LCM fragments
/// anything that does not fit a datagram and silently drops the whole
/// message when one fragment is lost, so the haptic link refuses larger ones.
inline constexpr size_t kLcmMaxPayloadBytes = 1400;

/// What was wrong with a payload.
enum class DecodeStatus : uint8_t {
  kOk = 0,
  kTooLarge,   ///< Larger than `MaxPayloadBytes` for the type.
  kMalformed,  ///< Not a valid protobuf encoding of the type (garbage, truncated).
};

/// Why `Decode` rejected a payload. Holds only views and numbers so that
/// filling it does not allocate; `source` must outlive the error (it is the
/// channel or topic name owned by the subscription or reader).
struct DecodeError {
  DecodeStatus status = DecodeStatus::kOk;
  std::string_view source;     ///< Channel or topic name.
  std::string_view type_name;  ///< Full protobuf type name, e.g. "cutsim.v1.ToolState".
  size_t size = 0;             ///< Payload size, bytes.
  size_t limit = 0;            ///< Size limit for the type, bytes.

  /// One line for a log or an exception, e.g.
  /// "CUTSIM_a_TOOL: cutsim.v1.ToolState: malformed payload (17 bytes): ...".
  /// Allocates; call it off the hot path.
  [[nodiscard]] std::string Message() const;
};

namespace detail {
/// Non-template core of `DecodeInto`: checks the size, parses, fills `err`.
bool DecodeInto(std::span<const uint8_t> bytes, google::protobuf::MessageLite& out,
                std::string_view type_name, size_t limit, std::string_view source,
                DecodeError* err) noexcept;
}  // namespace detail

/// Parses `bytes` into `out` (cleared first). Returns false and fills `err`
/// (if given) on a payload that is too large or not a valid `Msg`; `out` is
/// then unspecified. Never throws. `source` names the channel or topic.
///
/// Note on truncation: protobuf has no end marker, so a payload cut exactly
/// at a field boundary parses as a message with fewer fields. LCM and DDS both
/// deliver whole messages with their exact length, so that case only arises
/// from a buggy sender; any cut inside a field is rejected here.
template <class Msg>
bool DecodeInto(std::span<const uint8_t> bytes, Msg& out, std::string_view source,
                DecodeError* err = nullptr) noexcept {
  return detail::DecodeInto(bytes, out, Msg::descriptor()->full_name(), MaxPayloadBytes<Msg>(),
                            source, err);
}

/// Convenience form of `DecodeInto` that returns a fresh message (allocates).
template <class Msg>
std::optional<Msg> Decode(std::span<const uint8_t> bytes, std::string_view source,
                          DecodeError* err = nullptr) {
  Msg msg;
  if (!DecodeInto(bytes, msg, source, err)) return std::nullopt;
  return msg;
}

/// Serialises messages into one reusable buffer. Not thread-safe.
class Encoder {
 public:
  /// Serialises `msg`; returns a view of the bytes valid until the next call,
  /// or an empty optional if the encoding exceeds `limit` bytes or fails
  /// (protobuf cannot encode messages above 2 GiB, or signing failed). With
  /// a `signer` the bytes end with its signed trailer (stream_auth.h), which
  /// counts towards `limit`. `size` (if given) receives the encoded size
  /// even when it exceeds the limit.
  std::optional<std::span<const uint8_t>> Encode(const google::protobuf::MessageLite& msg,
                                                 size_t limit, size_t* size = nullptr,
                                                 PayloadAuthenticator* signer = nullptr);

  /// Typed form using `MaxPayloadBytes<Msg>()` as the limit.
  template <class Msg>
  std::optional<std::span<const uint8_t>> Encode(const Msg& msg, size_t* size = nullptr,
                                                 PayloadAuthenticator* signer = nullptr) {
    return Encode(static_cast<const google::protobuf::MessageLite&>(msg),
                  MaxPayloadBytes<Msg>(), size, signer);
  }

 private:
  std::vector<uint8_t> buffer_;  // grows to the largest message seen, never shrinks
};

}  // namespace cutsim::transport
