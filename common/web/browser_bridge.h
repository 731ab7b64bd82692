#pragma once
/// @file
/// The bridge between the observers' DDS stream and browsers: once per
/// frame the viewer's subscriber applies, it encodes the frame for browsers
/// (browser_frames.h) and hands it to the ObserverServer, which relays it to
/// every connected browser. The simulation server sees one DDS reader
/// however many browsers watch.

#include <cstdint>
#include <filesystem>
#include <memory>
#include <string>

#include "common/transport/mesh_subscriber.h"
#include "common/web/browser_frames.h"
#include "common/web/observer_server.h"

namespace cutsim::web {

/// The page's files under `web_root` (web/observer, with its npm packages
/// installed, and the modules both pages share in web/common beside it), by
/// the URL path each is served at.
[[nodiscard]] std::map<std::string, std::filesystem::path> ObserverPageFiles(const std::filesystem::path& web_root);

/// The observers' token from a text file (surrounding whitespace ignored):
/// 16 to 128 characters of A-Z, a-z, 0-9, '-' and '_'. Throws InputError
/// naming the file otherwise.
[[nodiscard]] std::string LoadObserverToken(const std::filesystem::path& file);

/// Parses "HOST:PORT" (IPv6 as "[::1]:PORT"); throws InputError naming `field`.
[[nodiscard]] std::pair<std::string, uint16_t> ParseHostPort(const std::string& text, const std::string& field);

/// Encodes one session's frames for browsers and hands them to a server's
/// channel: the hello, the newest frame as a snapshot and its session frame
/// for browsers that join, each new frame and its session frame for those
/// connected. Used by BrowserBridge (one session, channel "") and by the
/// lab bridge (a channel per session).
class SessionRelay {
 public:
  explicit SessionRelay(std::string session) : session_(std::move(session)) {}
  /// Call after the subscriber polled: when it applied a new frame, encodes
  /// it and queues it on `channel`. Cheap when nothing changed; true when a
  /// frame went out.
  bool Relay(const transport::MeshStreamSubscriber& sub, ObserverServer& server, const std::string& channel,
             int clients);
  [[nodiscard]] uint64_t frames_relayed() const { return frames_relayed_; }

 private:
  std::string session_;
  BrowserFrameEncoder encoder_;
  uint64_t last_state_version_ = 0;
  uint64_t frames_relayed_ = 0;
};

/// Relays a MeshStreamSubscriber's frames to browsers.
class BrowserBridge {
 public:
  /// Starts the server (throws as ObserverServer does).
  BrowserBridge(ObserverServerOptions options, std::string session);

  /// Call after the subscriber polled: when it applied a new frame, encodes
  /// it and queues it for every browser, and refreshes what a joining browser
  /// gets first. Cheap when nothing changed.
  void Relay(const transport::MeshStreamSubscriber& sub);

  [[nodiscard]] const ObserverServer& server() const { return *server_; }
  [[nodiscard]] uint64_t frames_relayed() const { return relay_.frames_relayed(); }

 private:
  std::string session_;
  std::unique_ptr<ObserverServer> server_;
  SessionRelay relay_;
};

}  // namespace cutsim::web
