#pragma once
/// @file
/// The HTTP/WebSocket core that the observer and the trainee servers share:
/// one listening socket on one I/O thread of its own (Boost.Beast), the
/// page's fixed set of files, and every check a request passes before a
/// server sees it. The checks live here, once:
///  - connections are capped at `accept`, HTTP and WebSocket alike, in total
///    and per peer address; the total cap also stays `reserved_descriptors`
///    below the process's descriptor limit, and when `accept` still fails
///    for lack of descriptors (EMFILE, ENFILE) the core waits before it
///    accepts again instead of spinning;
///  - an idle HTTP connection is closed after `http_idle_s`;
///  - the `Host` header must name this server (ServedHosts): its listening
///    address, `localhost` and the loopback literals when it listens on
///    loopback or on every address, any IP literal when it listens on every
///    address, or a configured name; and the port must be this server's. A
///    page fetched through another name (DNS rebinding) is refused;
///  - a WebSocket upgrade's `Origin`, when present, must be `http://` and a
///    host and port this server serves, by the same rule;
///  - a WebSocket upgrade carries `?token=<token>` when a token is set, asks
///    for the WebSocket path, and its `Sec-WebSocket-Key` is 16 bytes in
///    base64 (RFC 6455, 4.1);
///  - the WebSocket client cap is taken when the upgrade is granted, on the
///    I/O thread, and released when the client's connection ends: upgrades
///    that arrive together cannot pass it together;
///  - request headers are capped in size, and a request may carry no body.

#include <cstdint>
#include <filesystem>
#include <functional>
#include <map>
#include <memory>
#include <string>
#include <string_view>
#include <utility>
#include <vector>

#include <boost/asio/io_context.hpp>
#include <boost/beast/core/tcp_stream.hpp>
#include <boost/beast/http/empty_body.hpp>
#include <boost/beast/http/message.hpp>

namespace cutsim::web {

/// What the core enforces (see the file comment).
struct WebCoreOptions {
  std::string address = "127.0.0.1";  ///< Listening address (IPv4 or IPv6 literal, or "localhost").
  uint16_t port = 0;                  ///< 0: any free port.
  /// Required on every WebSocket upgrade when non-empty.
  std::string token;
  /// Further names browsers may use for this server (`Host`, `Origin`).
  std::vector<std::string> host_names;
  /// URL path → file served at it (read once). "/" serves "/index.html".
  std::map<std::string, std::filesystem::path> files;
  std::string files_what = "the page's files";  ///< Names the files in errors.
  std::string ws_path = "/ws";                  ///< The WebSocket endpoint.
  int max_connections = 512;           ///< Open connections at once (HTTP and WebSocket).
  int max_connections_per_peer = 64;   ///< Of them, from one peer address.
  int max_ws_clients = 32;             ///< WebSocket clients at once.
  int reserved_descriptors = 64;       ///< Descriptors left to the rest of the process.
  double http_idle_s = 10.0;           ///< An HTTP connection idle this long is closed.
  double accept_backoff_s = 0.1;       ///< Wait after `accept` runs out of descriptors.
  size_t max_request_header_bytes = 8192;  ///< HTTP request header limit.
};

/// The core's options from a server's own options, which name the shared
/// fields (address, port, token, host names, files, connection caps,
/// header limit) as WebCoreOptions does: one place copies them.
template <typename ServerOptions>
[[nodiscard]] WebCoreOptions CoreOptionsOf(const ServerOptions& o, std::string files_what, int max_ws_clients) {
  WebCoreOptions co;
  co.address = o.address;
  co.port = o.port;
  co.token = o.token;
  co.host_names = o.host_names;
  co.files = o.files;
  co.files_what = std::move(files_what);
  co.max_connections = o.max_connections;
  co.max_connections_per_peer = o.max_connections_per_peer;
  co.max_ws_clients = max_ws_clients;
  co.max_request_header_bytes = o.max_request_header_bytes;
  return co;
}

/// The core's counters (a consistent copy from WebCore::stats()).
struct WebCoreStats {
  int connections = 0;                ///< Open connections now (HTTP and WebSocket).
  int ws_clients = 0;                 ///< WebSocket clients now (granted upgrades).
  uint64_t refused_connections = 0;   ///< Closed at accept: a connection cap was reached.
  uint64_t accept_backoffs = 0;       ///< Waits after accept ran out of descriptors.
  uint64_t refused_cap = 0;           ///< Upgrades refused: WebSocket client cap reached.
  uint64_t refused_origin = 0;        ///< Upgrades refused: foreign Origin.
  uint64_t refused_host = 0;          ///< Requests refused: a Host this server does not serve.
  uint64_t refused_token = 0;         ///< Upgrades refused: missing or wrong token.
  uint64_t refused_key = 0;           ///< Upgrades refused: malformed Sec-WebSocket-Key.
  uint64_t bad_requests = 0;          ///< Malformed or oversized HTTP requests, unknown paths.
  uint64_t pages_served = 0;          ///< HTTP files served.
};

/// Why a request is refused (kOk: it is not).
enum class RequestVerdict { kOk, kBadRequest, kHost, kOrigin, kToken, kNotFound, kKey };

/// The hosts a server serves, for `Host` and `Origin`.
struct ServedHosts {
  std::string address;             ///< The listening address.
  uint16_t port = 0;               ///< The bound port.
  std::vector<std::string> names;  ///< Configured names.

  /// True when `host` ("name", "name:port", "[v6]:port") names this server.
  [[nodiscard]] bool Serves(std::string_view host) const;
  /// True when `origin` is `http://` and a host Serves() accepts.
  [[nodiscard]] bool AllowsOrigin(std::string_view origin) const;
};

/// True for a `Sec-WebSocket-Key` of 16 bytes in base64 (24 characters).
[[nodiscard]] bool IsValidWebSocketKey(std::string_view key);

/// The checks every request passes (Host, and for an upgrade the token,
/// Origin, path and key), without I/O: what the core applies and what the
/// fuzz target drives.
[[nodiscard]] RequestVerdict CheckRequest(const boost::beast::http::request<boost::beast::http::empty_body>& req,
                                          const ServedHosts& hosts, const std::string& token,
                                          const std::string& ws_path);

/// Parses one HTTP request header from `bytes` with the core's limits;
/// false when it is malformed, incomplete or too large.
bool ParseRequest(std::string_view bytes, size_t max_header_bytes,
                  boost::beast::http::request<boost::beast::http::empty_body>* out);

/// Granted upgrades call this on the I/O thread with the connection, the
/// request and a hold that keeps the connection and its client slot counted
/// until it is destroyed (keep it as long as the WebSocket lives).
using UpgradeHandler = std::function<void(boost::beast::tcp_stream&& stream,
                                          boost::beast::http::request<boost::beast::http::empty_body>&& req,
                                          std::shared_ptr<void> hold)>;

struct WebCoreImpl;

/// The listening core. Construction binds; Start() starts the I/O thread;
/// destruction stops it after `before_stop` (run on the I/O thread) closed
/// the server's own connections.
class WebCore {
 public:
  /// Throws InputError naming `--serve` (or FileError naming the file) for a
  /// bad address, a port that cannot be bound, or a missing file.
  WebCore(WebCoreOptions options, UpgradeHandler on_upgrade);
  ~WebCore();
  WebCore(const WebCore&) = delete;
  WebCore& operator=(const WebCore&) = delete;

  /// Starts accepting on the I/O thread.
  void Start();
  /// Runs `f` on the I/O thread, closes the acceptor, and stops the thread.
  void Stop(const std::function<void()>& f);

  [[nodiscard]] boost::asio::io_context& ioc();
  [[nodiscard]] uint16_t port() const;
  /// "http://address:port/".
  [[nodiscard]] std::string BaseUrl() const;
  [[nodiscard]] const WebCoreOptions& options() const;
  [[nodiscard]] WebCoreStats stats() const;

 private:
  std::unique_ptr<WebCoreImpl> impl_;
};

}  // namespace cutsim::web
