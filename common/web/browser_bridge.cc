#include "common/web/browser_bridge.h"

#include <algorithm>
#include <cctype>
#include <charconv>
#include <fstream>

#include <fmt/format.h>

#include "common/core/clock.h"
#include "common/core/error.h"

namespace cutsim::web {

std::map<std::string, std::filesystem::path> ObserverPageFiles(const std::filesystem::path& web_root) {
  return {
      {"/index.html", web_root / "index.html"},
      {"/observer.js", web_root / "observer.js"},
      {"/observer.css", web_root / "observer.css"},
      {"/debrief.js", web_root / "debrief.js"},
      {"/common/mesh_frames.js", web_root / ".." / "common" / "mesh_frames.js"},
      {"/common/scalpel.js", web_root / ".." / "common" / "scalpel.js"},
      {"/common/plan_line.js", web_root / ".." / "common" / "plan_line.js"},
      {"/vendor/three.module.js", web_root / "node_modules/three/build/three.module.js"},
      {"/vendor/three.core.js", web_root / "node_modules/three/build/three.core.js"},
      {"/vendor/OrbitControls.js", web_root / "node_modules/three/examples/jsm/controls/OrbitControls.js"},
  };
}

std::string LoadObserverToken(const std::filesystem::path& file) {
  std::error_code ec;
  if (!std::filesystem::is_regular_file(file, ec)) ThrowFileError(file.string(), "not a regular file (--token-file)");
  if (std::filesystem::file_size(file, ec) > 4096) ThrowFileError(file.string(), "too large for a token (--token-file)");
  std::ifstream in(file);
  std::string token;
  in >> token;
  const bool ok = token.size() >= 16 && token.size() <= 128 &&
                  std::all_of(token.begin(), token.end(), [](char c) {
                    return std::isalnum(static_cast<unsigned char>(c)) != 0 || c == '-' || c == '_';
                  });
  if (!ok) {
    ThrowFileError(file.string(), "the token must be 16 to 128 characters of A-Z, a-z, 0-9, '-' and '_' (--token-file)");
  }
  return token;
}

std::pair<std::string, uint16_t> ParseHostPort(const std::string& text, const std::string& field) {
  const size_t colon = text.rfind(':');
  if (colon == std::string::npos || colon == 0) {
    ThrowInputError({.field = field}, fmt::format("'{}' is not HOST:PORT", text));
  }
  std::string host = text.substr(0, colon);
  if (host.size() >= 2 && host.front() == '[' && host.back() == ']') host = host.substr(1, host.size() - 2);
  const std::string port_text = text.substr(colon + 1);
  unsigned port = 0;
  const auto [end, ec] = std::from_chars(port_text.data(), port_text.data() + port_text.size(), port);
  if (ec != std::errc() || end != port_text.data() + port_text.size() || port > 65535) {
    ThrowInputError({.field = field}, fmt::format("'{}' is not a port (0 to 65535)", port_text));
  }
  return {host, static_cast<uint16_t>(port)};
}

BrowserBridge::BrowserBridge(ObserverServerOptions options, std::string session)
    : session_(session), server_(std::make_unique<ObserverServer>(std::move(options))), relay_(std::move(session)) {
  server_->SetJoinMessages({{BrowserFrameEncoder::Hello(session_), false}});
}

void BrowserBridge::Relay(const transport::MeshStreamSubscriber& sub) {
  (void)relay_.Relay(sub, *server_, "", server_->stats().clients);
}

bool SessionRelay::Relay(const transport::MeshStreamSubscriber& sub, ObserverServer& server,
                         const std::string& channel, int clients) {
  if (sub.state_version() == last_state_version_ || !sub.current()) return false;
  last_state_version_ = sub.state_version();
  const transport::MeshReplica& mesh = sub.replica();
  LinkHealth link;
  link.frame_age_ms = sub.last_sample_ns() > 0 ? 1e-6 * static_cast<double>(MonotonicNs() - sub.last_sample_ns()) : 0;
  link.bridge_gaps = sub.stats().gaps;
  link.clients = clients;
  const auto session = BrowserFrameEncoder::Session(mesh.seq(), sub.observed(), link);
  const auto hello = BrowserFrameEncoder::Hello(session_);
  // A browser that joins gets the hello and this frame as a snapshot. Set
  // before the broadcast: one that joins in between then sees this frame
  // twice rather than an update of a topology it never had.
  const auto frame = encoder_.Frame(mesh);
  const bool frame_is_snapshot = !frame->empty() && static_cast<uint8_t>((*frame)[0]) == kSurfaceSnapshot;
  const auto snapshot = frame_is_snapshot ? frame : encoder_.Snapshot(mesh);
  server.SetJoinMessages(channel, {{hello, false}, {snapshot, true}, {session, false}});
  server.Broadcast(channel, {{frame, true}, {session, false}});
  ++frames_relayed_;
  return true;
}

}  // namespace cutsim::web
