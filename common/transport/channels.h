#pragma once
/// @file
/// Every name cutsim puts on a bus, in one place: the session name rules, the
/// LCM channels of the haptic link and the DDS topics of the observers, and
/// the default bus addresses (which stay on this host).

#include <cstddef>
#include <string>
#include <string_view>

namespace cutsim::transport {

/// Default LCM URL: UDP multicast with TTL 0, so datagrams never leave the host.
inline constexpr std::string_view kDefaultLcmUrl = "udpm://239.255.76.67:7667?ttl=0";

/// Longest session name. LCM channel names are at most 63 characters and the
/// longest channel is "CUTSIM_<session>_MODEL"; the DDS key is string<64>.
inline constexpr size_t kMaxSessionLength = 50;

/// True if `session` is 1..kMaxSessionLength characters of [A-Za-z0-9_-].
/// LCM treats a subscribed channel as a regular expression, so anything else
/// could subscribe to other sessions' channels. Does not allocate.
[[nodiscard]] bool IsValidSessionName(std::string_view session) noexcept;

/// Throws `InputError` naming `field` (e.g. "--session") if the name is invalid.
void ValidateSessionName(std::string_view session, std::string_view field = "--session");

/// The LCM channels of a session: the haptic link's two, and the servers'
/// presence.
enum class LcmChannel {
  kTool,    ///< Haptic station → server: `cutsim.v1.ToolState`, up to 1 kHz.
  kModel,   ///< Server → haptic station: `cutsim.v1.HapticModel`, one per physics frame.
  kServer,  ///< Server ↔ server: `cutsim.v1.ServerPresence`, once a second (server_presence.h).
};

/// "CUTSIM_<session>_TOOL", "CUTSIM_<session>_MODEL" or
/// "CUTSIM_<session>_SERVER". Throws `InputError` (field "--session") on an
/// invalid session name.
[[nodiscard]] std::string LcmChannelName(std::string_view session, LcmChannel channel);

}  // namespace cutsim::transport
