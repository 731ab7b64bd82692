#include "common/web/observer_server.h"

#include <algorithm>
#include <deque>
#include <future>
#include <mutex>
#include <optional>
#include <utility>
#include <vector>

#include <boost/asio/ip/tcp.hpp>
#include <boost/asio/post.hpp>
#include <boost/beast/core.hpp>
#include <boost/beast/http.hpp>
#include <boost/beast/websocket.hpp>
#include <fmt/format.h>

#include "common/core/error.h"
#include "common/core/log.h"
#include "common/web/http_util.h"

namespace cutsim::web {

namespace net = boost::asio;
namespace beast = boost::beast;
namespace http = beast::http;
namespace websocket = beast::websocket;
using tcp = net::ip::tcp;

bool IsLoopbackAddress(const std::string& address) {
  if (address == "localhost") return true;
  boost::system::error_code ec;
  const net::ip::address a = net::ip::make_address(address, ec);
  return !ec && a.is_loopback();
}

class WsSession;

struct ObserverServerImpl {
  explicit ObserverServerImpl(ObserverServerOptions o) : options(std::move(o)), acceptor(ioc) {}

  // Called on the I/O thread only (no lock), except the stats.
  void Accept();
  void OnWsOpen(const std::shared_ptr<WsSession>& s);
  void OnWsClosed(WsSession* s);
  template <typename F>
  void Count(F&& f) {
    const std::lock_guard lock(stats_mu);
    f(stats);
  }

  ObserverServerOptions options;
  std::map<std::string, PageFile> files;
  std::map<WsSession*, std::weak_ptr<WsSession>> sessions;  // I/O thread
  std::vector<Outgoing> join;                               // I/O thread
  mutable std::mutex stats_mu;
  ObserverServerStats stats;
  net::io_context ioc;  // after the registry: destroyed first, with the sessions it holds
  tcp::acceptor acceptor;
  std::thread thread;
};

/// One WebSocket client: a queue of shared messages, written one at a time;
/// a read that only ever ends the session.
class WsSession : public std::enable_shared_from_this<WsSession> {
 public:
  WsSession(ObserverServerImpl& server, beast::tcp_stream&& stream) : server_(server), ws_(std::move(stream)) {}
  ~WsSession() { server_.OnWsClosed(this); }

  void Run(http::request<http::empty_body> req) {
    ws_.set_option(websocket::stream_base::timeout::suggested(beast::role_type::server));
    ws_.read_message_max(server_.options.max_incoming_bytes);
    ws_.async_accept(req, [self = shared_from_this()](beast::error_code ec) {
      if (ec) return;
      self->server_.OnWsOpen(self);
      self->Read();
    });
  }

  void Send(const Outgoing& m) {
    if (closing_) return;
    if (queued_bytes_ + m.payload->size() > server_.options.max_queued_bytes) {
      // Too far behind: close rather than buffer without bound.
      server_.Count([](ObserverServerStats& s) { ++s.closed_slow; });
      Abort();
      return;
    }
    queued_bytes_ += m.payload->size();
    queue_.push_back(m);
    if (queue_.size() == 1) Write();
  }

  void Abort() {
    closing_ = true;
    beast::error_code ec;
    beast::get_lowest_layer(ws_).socket().close(ec);
  }

 private:
  void Write() {
    const Outgoing& m = queue_.front();
    ws_.binary(m.binary);
    ws_.async_write(net::buffer(*m.payload), [self = shared_from_this()](beast::error_code ec, size_t n) {
      if (ec) return self->Abort();
      self->server_.Count([n](ObserverServerStats& s) {
        ++s.messages_sent;
        s.bytes_sent += n;
      });
      self->queued_bytes_ -= self->queue_.front().payload->size();
      self->queue_.pop_front();
      if (!self->queue_.empty() && !self->closing_) self->Write();
    });
  }

  void Read() {
    ws_.async_read(read_buffer_, [self = shared_from_this()](beast::error_code ec, size_t) {
      // Any message, or one above the cap (Beast fails the connection with
      // 1009 itself), ends the session: a browser has nothing to say. Other
      // errors are a browser leaving (a close frame, a reset, end of stream).
      const bool too_big = ec == websocket::error::message_too_big;
      if (ec && !too_big) return self->Abort();
      self->server_.Count([](ObserverServerStats& s) { ++s.closed_incoming; });
      if (too_big) return self->Abort();
      self->closing_ = true;
      self->ws_.async_close(websocket::close_code::policy_error,
                            [self](beast::error_code) { self->Abort(); });
    });
  }

  ObserverServerImpl& server_;
  websocket::stream<beast::tcp_stream> ws_;
  beast::flat_buffer read_buffer_;
  std::deque<Outgoing> queue_;
  size_t queued_bytes_ = 0;
  bool closing_ = false;
};

/// One HTTP connection: reads a request, serves a file or upgrades.
class HttpSession : public std::enable_shared_from_this<HttpSession> {
 public:
  HttpSession(ObserverServerImpl& server, tcp::socket&& socket) : server_(server), stream_(std::move(socket)) {}

  void Read() {
    parser_.emplace();
    parser_->header_limit(static_cast<uint32_t>(server_.options.max_request_header_bytes));
    parser_->body_limit(1024);
    stream_.expires_after(std::chrono::seconds(10));
    http::async_read(stream_, buffer_, *parser_, [self = shared_from_this()](beast::error_code ec, size_t) {
      if (ec) {
        if (ec != http::error::end_of_stream) self->server_.Count([](ObserverServerStats& s) { ++s.bad_requests; });
        return;
      }
      self->Handle(self->parser_->release());
    });
  }

 private:
  void Handle(http::request<http::empty_body> req) {
    const auto [path, token] = SplitTarget(std::string_view(req.target().data(), req.target().size()));
    const ObserverServerOptions& o = server_.options;
    if (websocket::is_upgrade(req)) {
      if (!o.token.empty() && !SameSecret(token, o.token)) {
        server_.Count([](ObserverServerStats& s) { ++s.refused_token; });
        return Reply(req, http::status::forbidden, "token required\n", "text/plain");
      }
      const auto origin = req[http::field::origin];
      const std::string own = fmt::format("http://{}", std::string_view(req[http::field::host].data(),
                                                                        req[http::field::host].size()));
      if (!origin.empty() && std::string_view(origin.data(), origin.size()) != own) {
        server_.Count([](ObserverServerStats& s) { ++s.refused_origin; });
        return Reply(req, http::status::forbidden, "foreign origin\n", "text/plain");
      }
      if (path != "/ws") {
        server_.Count([](ObserverServerStats& s) { ++s.bad_requests; });
        return Reply(req, http::status::not_found, "no such endpoint\n", "text/plain");
      }
      if (static_cast<int>(server_.sessions.size()) >= o.max_clients) {
        server_.Count([](ObserverServerStats& s) { ++s.refused_cap; });
        return Reply(req, http::status::service_unavailable, "too many observers\n", "text/plain");
      }
      stream_.expires_never();
      std::make_shared<WsSession>(server_, std::move(stream_))->Run(std::move(req));
      return;
    }
    const auto it = server_.files.find(path == "/" ? "/index.html" : path);
    if (req.method() != http::verb::get || it == server_.files.end()) {
      server_.Count([](ObserverServerStats& s) { ++s.bad_requests; });
      return Reply(req, http::status::not_found, "not found\n", "text/plain");
    }
    server_.Count([](ObserverServerStats& s) { ++s.pages_served; });
    Reply(req, http::status::ok, it->second.body, it->second.content_type);
  }

  void Reply(const http::request<http::empty_body>& req, http::status status, const std::string& body,
             const std::string& type) {
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

  ObserverServerImpl& server_;
  beast::tcp_stream stream_;
  beast::flat_buffer buffer_;
  std::optional<http::request_parser<http::empty_body>> parser_;
};

void ObserverServerImpl::Accept() {
  acceptor.async_accept([this](beast::error_code ec, tcp::socket socket) {
    if (ec == net::error::operation_aborted) return;
    if (!ec) std::make_shared<HttpSession>(*this, std::move(socket))->Read();
    Accept();
  });
}

void ObserverServerImpl::OnWsOpen(const std::shared_ptr<WsSession>& s) {
  sessions[s.get()] = s;
  Count([this](ObserverServerStats& st) {
    ++st.accepted;
    st.clients = static_cast<int>(sessions.size());
  });
  for (const Outgoing& m : join) s->Send(m);
}

void ObserverServerImpl::OnWsClosed(WsSession* s) {
  sessions.erase(s);
  Count([this](ObserverServerStats& st) { st.clients = static_cast<int>(sessions.size()); });
}

ObserverServer::ObserverServer(ObserverServerOptions options) : impl_(std::make_unique<ObserverServerImpl>(std::move(options))) {
  const ObserverServerOptions& o = impl_->options;
  if (!IsLoopbackAddress(o.address) && o.token.empty()) {
    ThrowInputError({.field = "--serve"},
                    fmt::format("{} is not a loopback address: observers from other machines need a token "
                                "(--token-file)",
                                o.address));
  }
  impl_->files = ReadPageFiles(o.files, "the observer page's files");
  boost::system::error_code ec;
  const net::ip::address address = net::ip::make_address(o.address == "localhost" ? "127.0.0.1" : o.address, ec);
  if (ec) ThrowInputError({.field = "--serve"}, fmt::format("'{}' is not an IP address", o.address));
  const tcp::endpoint endpoint(address, o.port);
  tcp::acceptor& acc = impl_->acceptor;
  acc.open(endpoint.protocol(), ec);
  if (!ec) acc.set_option(net::socket_base::reuse_address(true), ec);
  if (!ec) acc.bind(endpoint, ec);
  if (!ec) acc.listen(net::socket_base::max_listen_connections, ec);
  if (ec) ThrowInputError({.field = "--serve"}, fmt::format("cannot listen on {}:{}: {}", o.address, o.port, ec.message()));
  port_ = acc.local_endpoint().port();
  impl_->Accept();
  impl_->thread = std::thread([this] { impl_->ioc.run(); });
}

ObserverServer::~ObserverServer() {
  // Close the acceptor and every client on the I/O thread, then stop it;
  // handlers still pending are destroyed with the io_context.
  std::promise<void> closed;
  net::post(impl_->ioc, [this, &closed] {
    beast::error_code ec;
    impl_->acceptor.close(ec);
    for (auto& [ptr, weak] : impl_->sessions) {
      if (auto s = weak.lock()) s->Abort();
    }
    closed.set_value();
  });
  closed.get_future().wait();
  impl_->ioc.stop();
  if (impl_->thread.joinable()) impl_->thread.join();
}

std::string ObserverServer::Url() const {
  const std::string& a = impl_->options.address;
  const std::string host = a.find(':') != std::string::npos ? "[" + a + "]" : a;
  std::string url = fmt::format("http://{}:{}/", host, port_);
  if (!impl_->options.token.empty()) url += "?token=" + impl_->options.token;
  return url;
}

void ObserverServer::Broadcast(std::vector<Outgoing> messages) {
  net::post(impl_->ioc, [this, m = std::move(messages)] {
    for (auto& [ptr, weak] : impl_->sessions) {
      if (auto s = weak.lock()) {
        for (const Outgoing& o : m) s->Send(o);
      }
    }
  });
}

void ObserverServer::SetJoinMessages(std::vector<Outgoing> messages) {
  net::post(impl_->ioc, [this, m = std::move(messages)]() mutable { impl_->join = std::move(m); });
}

ObserverServerStats ObserverServer::stats() const {
  const std::lock_guard lock(impl_->stats_mu);
  return impl_->stats;
}

}  // namespace cutsim::web
