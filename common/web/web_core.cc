#include "common/web/web_core.h"

#include <sys/resource.h>

#include <algorithm>
#include <cctype>
#include <charconv>
#include <chrono>
#include <future>
#include <mutex>
#include <optional>
#include <thread>
#include <utility>

#include <boost/asio/ip/tcp.hpp>
#include <boost/asio/post.hpp>
#include <boost/asio/steady_timer.hpp>
#include <boost/beast/core.hpp>
#include <boost/beast/http.hpp>
#include <boost/beast/websocket.hpp>
#include <fmt/format.h>

#include "common/core/error.h"
#include "common/web/http_util.h"

namespace cutsim::web {

namespace net = boost::asio;
namespace beast = boost::beast;
namespace http = beast::http;
namespace websocket = beast::websocket;
using tcp = net::ip::tcp;

namespace {

std::string Lower(std::string_view s) {
  std::string out(s);
  std::transform(out.begin(), out.end(), out.begin(), [](unsigned char c) { return std::tolower(c); });
  return out;
}

std::optional<net::ip::address> ParseIp(std::string_view text) {
  boost::system::error_code ec;
  const net::ip::address a = net::ip::make_address(std::string(text), ec);
  if (ec) return std::nullopt;
  return a;
}

/// The listening address as an IP ("localhost" is 127.0.0.1).
std::optional<net::ip::address> BindIp(const std::string& address) {
  return ParseIp(address == "localhost" ? "127.0.0.1" : address);
}

std::string_view View(boost::beast::string_view s) { return {s.data(), s.size()}; }

}  // namespace

bool ServedHosts::Serves(std::string_view host) const {
  // Split "name[:port]" or "[v6][:port]".
  std::string_view name = host;
  std::string_view port_text;
  if (!host.empty() && host.front() == '[') {
    const size_t close = host.find(']');
    if (close == std::string_view::npos) return false;
    name = host.substr(1, close - 1);
    const std::string_view rest = host.substr(close + 1);
    if (!rest.empty()) {
      if (rest.front() != ':') return false;
      port_text = rest.substr(1);
      if (port_text.empty()) return false;
    }
  } else {
    const size_t colon = host.find(':');
    if (colon != std::string_view::npos) {
      name = host.substr(0, colon);
      port_text = host.substr(colon + 1);
      if (port_text.empty()) return false;
    }
  }
  if (name.empty()) return false;
  unsigned p = 80;  // no port: the scheme's default
  if (!port_text.empty()) {
    const auto [end, ec] = std::from_chars(port_text.data(), port_text.data() + port_text.size(), p);
    if (ec != std::errc() || end != port_text.data() + port_text.size()) return false;
  }
  if (p != port) return false;
  const std::string lname = Lower(name);
  for (const std::string& n : names) {
    if (Lower(n) == lname) return true;
  }
  const std::optional<net::ip::address> bind = BindIp(address);
  if (!bind) return false;
  const bool any = bind->is_unspecified();
  const bool local = any || bind->is_loopback();
  if (lname == "localhost") return local;
  const std::optional<net::ip::address> ip = ParseIp(lname);
  if (!ip) return false;  // a name nobody configured: maybe rebound to us
  if (*ip == *bind || any) return true;
  return local && ip->is_loopback();
}

bool ServedHosts::AllowsOrigin(std::string_view origin) const {
  constexpr std::string_view kScheme = "http://";
  if (origin.size() <= kScheme.size() || Lower(origin.substr(0, kScheme.size())) != kScheme) return false;
  const std::string_view rest = origin.substr(kScheme.size());
  if (rest.find_first_of("/?#@") != std::string_view::npos) return false;
  return Serves(rest);
}

bool IsValidWebSocketKey(std::string_view key) {
  // 16 bytes in base64: 22 characters, the last of them carrying 2 bits, then "==".
  if (key.size() != 24 || key.substr(22) != "==") return false;
  for (size_t i = 0; i < 22; ++i) {
    const unsigned char c = static_cast<unsigned char>(key[i]);
    if (std::isalnum(c) == 0 && c != '+' && c != '/') return false;
  }
  return std::string_view("AQgw").find(key[21]) != std::string_view::npos;
}

RequestVerdict CheckRequest(const http::request<http::empty_body>& req, const ServedHosts& hosts,
                            const std::string& token, const std::string& ws_path) {
  const auto host = req.find(http::field::host);
  if (host == req.end() || !hosts.Serves(View(host->value()))) return RequestVerdict::kHost;
  if (!websocket::is_upgrade(req)) return RequestVerdict::kOk;
  const auto [path, given] = SplitTarget(View(req.target()));
  if (!token.empty() && !SameSecret(given, token)) return RequestVerdict::kToken;
  const auto origin = req.find(http::field::origin);
  if (origin != req.end() && !hosts.AllowsOrigin(View(origin->value()))) return RequestVerdict::kOrigin;
  if (path != ws_path) return RequestVerdict::kNotFound;
  if (!IsValidWebSocketKey(View(req[http::field::sec_websocket_key]))) return RequestVerdict::kKey;
  return RequestVerdict::kOk;
}

bool ParseRequest(std::string_view bytes, size_t max_header_bytes, http::request<http::empty_body>* out) {
  http::request_parser<http::empty_body> parser;
  parser.header_limit(static_cast<uint32_t>(std::min<size_t>(max_header_bytes, UINT32_MAX)));
  parser.body_limit(1024);
  parser.eager(true);
  beast::error_code ec;
  size_t at = 0;
  while (at < bytes.size() && !parser.is_done()) {
    const size_t n = parser.put(net::buffer(bytes.data() + at, bytes.size() - at), ec);
    if (ec == http::error::need_more) break;
    if (ec) return false;
    if (n == 0) break;
    at += n;
  }
  if (!parser.is_done()) return false;
  *out = parser.release();
  return true;
}

/// The I/O thread's state.
struct WebCoreImpl {
  WebCoreImpl(WebCoreOptions o, UpgradeHandler h)
      : options(std::move(o)), on_upgrade(std::move(h)), acceptor(ioc), backoff(ioc) {}

  void Accept();
  bool Admit(const std::string& peer);
  void Release(const std::string& peer);
  template <typename F>
  void Count(F&& f) {
    const std::lock_guard lock(mu);
    f(stats);
  }

  WebCoreOptions options;
  UpgradeHandler on_upgrade;
  ServedHosts hosts;
  std::map<std::string, PageFile> files;
  int total_cap = 0;
  std::map<std::string, int> per_peer;  // I/O thread
  mutable std::mutex mu;                // guards stats (read by other threads)
  WebCoreStats stats;
  net::io_context ioc;  // destroyed before the counters its handlers release
  tcp::acceptor acceptor;
  net::steady_timer backoff;
  std::thread thread;
};

namespace {

/// Counts one connection from accept to its socket's end.
struct ConnectionHold {
  ConnectionHold(WebCoreImpl& c, std::string p) : core(c), peer(std::move(p)) {}
  ~ConnectionHold() { core.Release(peer); }
  ConnectionHold(const ConnectionHold&) = delete;
  ConnectionHold& operator=(const ConnectionHold&) = delete;
  WebCoreImpl& core;
  std::string peer;
};

/// A granted WebSocket client slot, with its connection.
struct ClientHold {
  ClientHold(WebCoreImpl& c, std::shared_ptr<ConnectionHold> h) : core(c), connection(std::move(h)) {}
  ~ClientHold() {
    core.Count([](WebCoreStats& s) { --s.ws_clients; });
  }
  ClientHold(const ClientHold&) = delete;
  ClientHold& operator=(const ClientHold&) = delete;
  WebCoreImpl& core;
  std::shared_ptr<ConnectionHold> connection;
};

/// One HTTP connection: reads requests, serves files, grants upgrades.
class HttpConnection : public std::enable_shared_from_this<HttpConnection> {
 public:
  HttpConnection(WebCoreImpl& core, tcp::socket&& socket, std::shared_ptr<ConnectionHold> hold)
      : core_(core), stream_(std::move(socket)), hold_(std::move(hold)) {}

  void Read() {
    parser_.emplace();
    parser_->header_limit(static_cast<uint32_t>(core_.options.max_request_header_bytes));
    parser_->body_limit(1024);
    stream_.expires_after(std::chrono::nanoseconds(static_cast<int64_t>(core_.options.http_idle_s * 1e9)));
    http::async_read(stream_, buffer_, *parser_, [self = shared_from_this()](beast::error_code ec, size_t) {
      if (ec) {
        if (ec != http::error::end_of_stream && ec != beast::error::timeout) {
          self->core_.Count([](WebCoreStats& s) { ++s.bad_requests; });
        }
        return;
      }
      self->Handle(self->parser_->release());
    });
  }

 private:
  void Handle(http::request<http::empty_body> req) {
    const WebCoreOptions& o = core_.options;
    switch (CheckRequest(req, core_.hosts, o.token, o.ws_path)) {
      case RequestVerdict::kOk:
        break;
      case RequestVerdict::kHost:
        core_.Count([](WebCoreStats& s) { ++s.refused_host; });
        return Reply(req, http::status::forbidden, "this server does not serve that host\n");
      case RequestVerdict::kToken:
        core_.Count([](WebCoreStats& s) { ++s.refused_token; });
        return Reply(req, http::status::forbidden, "token required\n");
      case RequestVerdict::kOrigin:
        core_.Count([](WebCoreStats& s) { ++s.refused_origin; });
        return Reply(req, http::status::forbidden, "foreign origin\n");
      case RequestVerdict::kKey:
        core_.Count([](WebCoreStats& s) { ++s.refused_key; });
        return Reply(req, http::status::bad_request, "Sec-WebSocket-Key must be 16 bytes in base64\n");
      case RequestVerdict::kNotFound:
      case RequestVerdict::kBadRequest:
        core_.Count([](WebCoreStats& s) { ++s.bad_requests; });
        return Reply(req, http::status::not_found, "no such endpoint\n");
    }
    if (websocket::is_upgrade(req)) return Upgrade(std::move(req));
    const auto [path, token] = SplitTarget(View(req.target()));
    const auto it = core_.files.find(path == "/" ? "/index.html" : path);
    if (req.method() != http::verb::get || it == core_.files.end()) {
      core_.Count([](WebCoreStats& s) { ++s.bad_requests; });
      return Reply(req, http::status::not_found, "not found\n");
    }
    core_.Count([](WebCoreStats& s) { ++s.pages_served; });
    Reply(req, http::status::ok, it->second.body, it->second.content_type);
  }

  void Upgrade(http::request<http::empty_body> req) {
    // The slot is taken here, on the I/O thread, before the handshake.
    bool granted = false;
    core_.Count([&](WebCoreStats& s) {
      if (s.ws_clients < core_.options.max_ws_clients) {
        ++s.ws_clients;
        granted = true;
      } else {
        ++s.refused_cap;
      }
    });
    if (!granted) return Reply(req, http::status::service_unavailable, "too many clients\n");
    stream_.expires_never();
    auto hold = std::make_shared<ClientHold>(core_, std::move(hold_));
    core_.on_upgrade(std::move(stream_), std::move(req), std::move(hold));
  }

  void Reply(const http::request<http::empty_body>& req, http::status status, const std::string& body,
             const std::string& type = "text/plain") {
    auto res = MakeReply(req, status, body, type);
    http::async_write(stream_, *res, [self = shared_from_this(), res](beast::error_code ec, size_t) {
      if (ec || !res->keep_alive()) {
        beast::error_code ignored;
        self->stream_.socket().shutdown(tcp::socket::shutdown_send, ignored);
        return;
      }
      self->Read();
    });
  }

  WebCoreImpl& core_;
  beast::tcp_stream stream_;
  std::shared_ptr<ConnectionHold> hold_;
  beast::flat_buffer buffer_;
  std::optional<http::request_parser<http::empty_body>> parser_;
};

}  // namespace

bool WebCoreImpl::Admit(const std::string& peer) {
  int& mine = per_peer[peer];
  bool ok = false;
  Count([&](WebCoreStats& s) {
    ok = s.connections < total_cap && mine < options.max_connections_per_peer;
    if (ok) {
      ++s.connections;
      ++mine;
    } else {
      ++s.refused_connections;
    }
  });
  if (mine == 0) per_peer.erase(peer);
  return ok;
}

void WebCoreImpl::Release(const std::string& peer) {
  const auto it = per_peer.find(peer);
  if (it != per_peer.end() && --it->second <= 0) per_peer.erase(it);
  Count([](WebCoreStats& s) { --s.connections; });
}

void WebCoreImpl::Accept() {
  acceptor.async_accept([this](beast::error_code ec, tcp::socket socket) {
    if (ec == net::error::operation_aborted) return;
    if (ec) {
      // Out of descriptors (or another accept failure): wait, then try
      // again, rather than fail the same accept in a loop.
      Count([](WebCoreStats& s) { ++s.accept_backoffs; });
      backoff.expires_after(std::chrono::nanoseconds(static_cast<int64_t>(options.accept_backoff_s * 1e9)));
      backoff.async_wait([this](beast::error_code wait_ec) {
        if (!wait_ec) Accept();
      });
      return;
    }
    beast::error_code peer_ec;
    const tcp::endpoint remote = socket.remote_endpoint(peer_ec);
    const std::string peer = peer_ec ? std::string("?") : remote.address().to_string();
    if (Admit(peer)) {
      auto hold = std::make_shared<ConnectionHold>(*this, peer);
      std::make_shared<HttpConnection>(*this, std::move(socket), std::move(hold))->Read();
    } else {
      beast::error_code ignored;
      socket.close(ignored);  // over a cap: the descriptor goes back at once
    }
    Accept();
  });
}

WebCore::WebCore(WebCoreOptions options, UpgradeHandler on_upgrade)
    : impl_(std::make_unique<WebCoreImpl>(std::move(options), std::move(on_upgrade))) {
  const WebCoreOptions& o = impl_->options;
  if (o.max_connections < 1 || o.max_connections_per_peer < 1 || o.max_ws_clients < 1 ||
      o.reserved_descriptors < 0) {
    ThrowInputError({.field = "--serve"}, "connection caps must be at least 1 (and the reserve not negative)");
  }
  if (!(o.http_idle_s > 0.0 && o.http_idle_s <= 3600.0 && o.accept_backoff_s > 0.0 && o.accept_backoff_s <= 10.0)) {
    ThrowInputError({.field = "--serve"}, "the idle time must be in (0, 3600] s and the accept backoff in (0, 10] s");
  }
  for (const std::string& name : o.host_names) {
    const bool ok = !name.empty() && name.size() <= 253 && std::all_of(name.begin(), name.end(), [](char c) {
      return std::isalnum(static_cast<unsigned char>(c)) != 0 || c == '-' || c == '.';
    });
    if (!ok) {
      ThrowInputError({.field = "--host-name"},
                      fmt::format("'{}' is not a host name (1 to 253 characters of A-Z, a-z, 0-9, '-' and '.')", name));
    }
  }
  // The total cap leaves the reserve below the descriptor limit.
  int cap = o.max_connections;
  rlimit limit{};
  if (::getrlimit(RLIMIT_NOFILE, &limit) == 0 && limit.rlim_cur != RLIM_INFINITY) {
    const auto room = static_cast<int64_t>(limit.rlim_cur) - o.reserved_descriptors;
    cap = static_cast<int>(std::clamp<int64_t>(room, 1, cap));
  }
  impl_->total_cap = cap;
  impl_->files = ReadPageFiles(o.files, o.files_what);
  const std::optional<net::ip::address> address = BindIp(o.address);
  if (!address) ThrowInputError({.field = "--serve"}, fmt::format("'{}' is not an IP address", o.address));
  const tcp::endpoint endpoint(*address, o.port);
  tcp::acceptor& acc = impl_->acceptor;
  boost::system::error_code ec;
  acc.open(endpoint.protocol(), ec);
  if (!ec) acc.set_option(net::socket_base::reuse_address(true), ec);
  if (!ec) acc.bind(endpoint, ec);
  if (!ec) acc.listen(net::socket_base::max_listen_connections, ec);
  if (ec) ThrowInputError({.field = "--serve"}, fmt::format("cannot listen on {}:{}: {}", o.address, o.port, ec.message()));
  impl_->hosts = {o.address, acc.local_endpoint().port(), o.host_names};
}

WebCore::~WebCore() {
  if (impl_->thread.joinable()) Stop([] {});
}

void WebCore::Start() {
  impl_->Accept();
  impl_->thread = std::thread([this] { impl_->ioc.run(); });
}

void WebCore::Stop(const std::function<void()>& f) {
  if (!impl_->thread.joinable()) return;
  std::promise<void> closed;
  net::post(impl_->ioc, [this, &f, &closed] {
    beast::error_code ec;
    impl_->acceptor.close(ec);
    impl_->backoff.cancel();
    f();
    closed.set_value();
  });
  closed.get_future().wait();
  impl_->ioc.stop();
  impl_->thread.join();
}

net::io_context& WebCore::ioc() { return impl_->ioc; }
uint16_t WebCore::port() const { return impl_->hosts.port; }
const WebCoreOptions& WebCore::options() const { return impl_->options; }

std::string WebCore::BaseUrl() const {
  const std::string& a = impl_->options.address;
  const std::string host = a.find(':') != std::string::npos ? "[" + a + "]" : a;
  return fmt::format("http://{}:{}/", host, port());
}

WebCoreStats WebCore::stats() const {
  const std::lock_guard lock(impl_->mu);
  return impl_->stats;
}

}  // namespace cutsim::web
