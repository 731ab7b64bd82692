#include "common/transport/channels.h"

#include <fmt/format.h>

#include "common/core/error.h"

namespace cutsim::transport {

bool IsValidSessionName(std::string_view session) noexcept {
  if (session.empty() || session.size() > kMaxSessionLength) return false;
  for (const char c : session) {
    const bool ok = (c >= 'a' && c <= 'z') || (c >= 'A' && c <= 'Z') || (c >= '0' && c <= '9') ||
                    c == '_' || c == '-';
    if (!ok) return false;
  }
  return true;
}

void ValidateSessionName(std::string_view session, std::string_view field) {
  if (!IsValidSessionName(session)) {
    ThrowInputError(SourceRef{.field = std::string(field)},
                    fmt::format("invalid session name \"{}\": use 1 to {} characters of "
                                "A-Z, a-z, 0-9, '_' and '-'",
                                session, kMaxSessionLength));
  }
}

std::string LcmChannelName(std::string_view session, LcmChannel channel) {
  ValidateSessionName(session);
  switch (channel) {
    case LcmChannel::kTool:
      return fmt::format("CUTSIM_{}_TOOL", session);
    case LcmChannel::kModel:
      return fmt::format("CUTSIM_{}_MODEL", session);
    case LcmChannel::kServer:
      return fmt::format("CUTSIM_{}_SERVER", session);
  }
  CUTSIM_CHECK(false, "unknown LcmChannel");
}

}  // namespace cutsim::transport
