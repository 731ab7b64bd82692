#pragma once
/// @file
/// The trainee page's server: HTTP for the page's fixed set of files and one
/// two-way WebSocket (`/ws`) over which a single browser drives the scalpel
/// (pose samples in) and sees the force and the cut (frames out). Boost.Beast
/// on one I/O thread of its own; the handlers run on that thread.
///
/// The shared core (web_core.h) enforces the connection caps and the
/// `Host`, `Origin`, token and key checks; this server adds:
///  - a token on every WebSocket upgrade (`?token=<token>`), always: the
///    page drives a tool that cuts, so nobody without the session's token
///    may connect, on loopback or not (the page's files hold no session data
///    and are served to anyone who can connect);
///  - one trainee at a time: the core's client cap is 1, so an upgrade while
///    a trainee holds the seat is refused (503);
///  - a cap on the size of incoming WebSocket messages (a message above it
///    closes the client with 1009);
///  - a rate cap on incoming messages (a token bucket): messages above it
///    are dropped and counted, not handed on;
///  - an idle limit: a trainee that sends nothing for `idle_timeout_s` is
///    closed and the seat freed (the page sends a heartbeat while the
///    trainee pauses, so a connected page keeps the seat).
/// What a message says is the handler's to validate (browser_device.h).

#include <cstdint>
#include <filesystem>
#include <functional>
#include <map>
#include <memory>
#include <string>
#include <string_view>
#include <vector>

#include "common/web/web_core.h"

namespace cutsim::web {

/// The server's settings.
struct TraineeServerOptions {
  std::string address = "127.0.0.1";  ///< Listening address (IPv4 or IPv6 literal).
  uint16_t port = 0;                  ///< 0: any free port (see TraineeServer::port()).
  std::string token;                  ///< Required on every WebSocket upgrade; must not be empty.
  /// URL path → file served at it (read once, at construction). "/" serves
  /// the entry mapped to "/index.html".
  std::map<std::string, std::filesystem::path> files;
  /// Further names browsers may use for this server (Host and Origin).
  std::vector<std::string> host_names;
  int max_connections = 64;               ///< Connections at once (HTTP and WebSocket).
  int max_connections_per_peer = 32;      ///< Of them, from one peer address.
  double idle_timeout_s = 10.0;           ///< A trainee silent this long loses the seat.
  size_t max_incoming_bytes = 256;        ///< Largest WebSocket message the trainee may send.
  double max_messages_per_s = 400.0;      ///< Sustained incoming rate; above it messages are dropped.
  double burst_messages = 40.0;           ///< Token-bucket depth (messages).
  double frame_hz = 60.0;                 ///< Least rate of the outgoing frames while a trainee is connected.
  /// How often the server asks TraineeHandlers::urgent whether a frame
  /// should go before its `frame_hz` tick (one that answers a new input).
  double poll_hz = 500.0;
  size_t max_request_header_bytes = 8192; ///< HTTP request header limit.
};

/// What the server calls, on its I/O thread.
struct TraineeHandlers {
  /// A trainee connected; returns the first message sent to it.
  std::function<std::string()> on_open;
  /// A message within the size and rate caps (text or binary), with the
  /// CLOCK_MONOTONIC time it was read.
  std::function<void(std::string_view message, int64_t receive_ns)> on_message;
  /// At `frame_hz` while a trainee is connected, and whenever `urgent`
  /// says so: the frame to send ("" = none).
  std::function<std::string()> frame;
  /// At `poll_hz` while a trainee is connected: whether a frame should go
  /// now rather than at the next `frame_hz` tick. Empty: never.
  std::function<bool()> urgent;
  /// The trainee left (or was closed).
  std::function<void()> on_close;
};

/// Counters, read with TraineeServer::stats() (a consistent copy).
struct TraineeServerStats {
  WebCoreStats web;              ///< The shared core's counters (web.refused_cap: seat taken).
  bool connected = false;        ///< A trainee is connected now.
  uint64_t accepted = 0;         ///< Trainees accepted in all.
  uint64_t closed_idle = 0;      ///< Trainees closed for sending nothing for idle_timeout_s.
  uint64_t closed_oversized = 0; ///< Trainees closed for a message above the size cap.
  uint64_t rate_limited = 0;     ///< Messages dropped above the rate cap.
  uint64_t messages_received = 0;///< Messages handed to `on_message`.
  uint64_t frames_sent = 0;      ///< Messages written to the trainee.
};

struct TraineeServerImpl;  // the I/O thread's state (trainee_server.cc)

/// The HTTP + WebSocket server. Construction binds and starts the I/O
/// thread; destruction closes the trainee's connection and joins it.
class TraineeServer {
 public:
  /// Throws InputError naming `--serve` (or the file) for a bad address, an
  /// empty token, a missing file, or a port that cannot be bound.
  TraineeServer(TraineeServerOptions options, TraineeHandlers handlers);
  ~TraineeServer();
  TraineeServer(const TraineeServer&) = delete;
  TraineeServer& operator=(const TraineeServer&) = delete;

  /// The bound port (the chosen one when options.port was 0).
  [[nodiscard]] uint16_t port() const { return port_; }
  /// "http://address:port/" without the token.
  [[nodiscard]] std::string BaseUrl() const;
  /// Queues a binary mesh frame (browser_frames.h) for the trainee.
  /// Thread-safe, never blocks. Only the newest frames wait: a snapshot
  /// replaces every frame waiting, an update replaces the update waiting.
  /// The newest snapshot is also what a trainee who connects gets first.
  void SendMesh(std::shared_ptr<const std::string> frame, bool snapshot);
  [[nodiscard]] TraineeServerStats stats() const;

 private:
  std::unique_ptr<TraineeServerImpl> impl_;
  uint16_t port_ = 0;
};

}  // namespace cutsim::web
