#pragma once
/// @file
/// The browser observers' server: HTTP for the page's fixed set of files and
/// a read-only WebSocket (`/ws`) over which every connected browser receives
/// the frames the caller broadcasts. Boost.Beast on one I/O thread of its
/// own; the caller's thread only posts to it, so a slow browser never blocks
/// the caller.
///
/// Read-only by design: nothing an observer sends is passed on. The one
/// exception is an instructor's page in a debrief: with `instructor_token`
/// set, an upgrade whose `?instructor=` equals it (compared in constant
/// time; a wrong one is refused with 403) may send text messages, each
/// handed to `on_control` within the size cap and a rate cap, whose reply
/// goes back to that page. A message from any other client closes it with
/// 1008 and the reason "read-only: control needs the instructor token".
/// The shared core (web_core.h) enforces the connection caps, the `Host`,
/// `Origin`, token and key checks and the client cap; this server adds:
///  - a listening address on loopback unless a token is set; with a token,
///    every WebSocket upgrade must carry `?token=<token>` (the page's files
///    hold no session data and are served to anyone who can connect);
///  - a cap on incoming WebSocket messages (a browser has nothing to send:
///    any data message closes it, one above the cap with 1009, others with
///    1008);
///  - a cap on the bytes queued for one client: a client that falls that far
///    behind is closed instead of buffered for without bound.

#include <cstdint>
#include <filesystem>
#include <functional>
#include <map>
#include <memory>
#include <string>
#include <string_view>
#include <thread>
#include <vector>

#include "common/web/web_core.h"

namespace cutsim::web {

/// The server's settings.
struct ObserverServerOptions {
  std::string address = "127.0.0.1";  ///< Listening address (IPv4 or IPv6 literal).
  uint16_t port = 0;                  ///< 0: any free port (see ObserverServer::port()).
  /// Required on every WebSocket upgrade when non-empty; must be non-empty
  /// when `address` is not a loopback address.
  std::string token;
  /// URL path → file served at it (read once, at construction). "/" serves
  /// the entry mapped to "/index.html".
  std::map<std::string, std::filesystem::path> files;
  /// Further names browsers may use for this server (Host and Origin).
  std::vector<std::string> host_names;
  int max_clients = 32;                       ///< WebSocket clients at once.
  int max_connections = 512;                  ///< Connections at once (HTTP and WebSocket).
  int max_connections_per_peer = 64;          ///< Of them, from one peer address.
  size_t max_incoming_bytes = 1024;           ///< Largest WebSocket message a client may send.
  size_t max_queued_bytes = 16u << 20;        ///< Bytes queued for one client before it is closed.
  size_t max_request_header_bytes = 8192;     ///< HTTP request header limit.
  /// Streams by session: a WebSocket upgrade may ask for `?session=NAME`
  /// and then receives only that channel's messages (the lab bridge);
  /// without it, the default channel "". When false the parameter is
  /// ignored and every client is on "" (one session's bridge).
  bool channels = false;
  /// The instructor's token (16-128 of A-Z a-z 0-9 - _), or empty: every
  /// client is read-only.
  std::string instructor_token;
  /// With `instructor_token`: called on the I/O thread with each text
  /// message an instructor's page sends; returns the reply (a JSON text
  /// frame) for that page. What the message says is the handler's to check.
  std::function<std::string(std::string_view message)> on_control;
  double max_control_per_s = 20.0;  ///< Sustained instructor messages per second; above it they are refused.
};

/// Counters, read with ObserverServer::stats() (a consistent copy).
struct ObserverServerStats {
  WebCoreStats web;                   ///< The shared core's counters (refusals, pages).
  int clients = 0;                    ///< WebSocket clients connected now (handshake done).
  uint64_t accepted = 0;              ///< WebSocket clients accepted in all.
  uint64_t closed_incoming = 0;       ///< Clients closed for sending a message.
  uint64_t closed_slow = 0;           ///< Clients closed for falling behind (queue cap).
  uint64_t messages_sent = 0;         ///< WebSocket messages written.
  uint64_t bytes_sent = 0;            ///< Their payload bytes.
  uint64_t refused_channel = 0;       ///< Upgrades refused: `session` is not a session name.
  uint64_t refused_instructor = 0;    ///< Upgrades refused: a wrong `instructor` token.
  int instructors = 0;                ///< Instructors' pages connected now.
  uint64_t control_messages = 0;      ///< Instructor messages handed to on_control.
  uint64_t control_rate_limited = 0;  ///< Instructor messages refused above the rate cap.
  uint64_t control_not_instructor = 0;  ///< Clients closed for a message without the instructor token.
  /// Payload bytes written per channel (only with `channels`).
  std::map<std::string, uint64_t> channel_bytes;
};

/// One message for every browser: text (JSON) or binary.
struct Outgoing {
  std::shared_ptr<const std::string> payload;
  bool binary = false;
};

struct ObserverServerImpl;  // the I/O thread's state (observer_server.cc)

/// The HTTP + WebSocket server. Construction binds and starts the I/O
/// thread; destruction closes every connection and joins it.
class ObserverServer {
 public:
  /// Throws InputError naming the field (`--serve`, `--token-file`, or the
  /// file) for a bad address, a non-loopback address without a token, a
  /// missing file, or a port that cannot be bound.
  explicit ObserverServer(ObserverServerOptions options);
  ~ObserverServer();
  ObserverServer(const ObserverServer&) = delete;
  ObserverServer& operator=(const ObserverServer&) = delete;

  /// The bound port (the chosen one when options.port was 0).
  [[nodiscard]] uint16_t port() const { return port_; }
  /// "http://address:port/" (with `?token=…` when a token is set).
  [[nodiscard]] std::string Url() const;

  /// Queues `messages` for every connected client, in order. Thread-safe,
  /// never blocks.
  void Broadcast(std::vector<Outgoing> messages) { Broadcast("", std::move(messages)); }
  /// Queues `messages` for every client on `channel` (options.channels).
  void Broadcast(const std::string& channel, std::vector<Outgoing> messages);
  /// What a client that connects from now on receives first, before any
  /// broadcast (the latest snapshot and session frames). Thread-safe.
  void SetJoinMessages(std::vector<Outgoing> messages) { SetJoinMessages("", std::move(messages)); }
  /// The same for clients of `channel`; an empty list forgets the channel.
  void SetJoinMessages(const std::string& channel, std::vector<Outgoing> messages);

  [[nodiscard]] ObserverServerStats stats() const;

 private:
  std::unique_ptr<ObserverServerImpl> impl_;
  uint16_t port_ = 0;
};

/// True for 127.0.0.0/8, ::1 and "localhost".
[[nodiscard]] bool IsLoopbackAddress(const std::string& address);

}  // namespace cutsim::web
