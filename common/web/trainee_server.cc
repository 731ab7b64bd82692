#include "common/web/trainee_server.h"

#include <algorithm>
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

#include "common/core/clock.h"
#include "common/core/error.h"
#include "common/web/http_util.h"

namespace cutsim::web {

namespace net = boost::asio;
namespace beast = boost::beast;
namespace http = beast::http;
namespace websocket = beast::websocket;
using tcp = net::ip::tcp;

class TraineeSession;

struct TraineeServerImpl {
  TraineeServerImpl(TraineeServerOptions o, TraineeHandlers h)
      : options(std::move(o)), handlers(std::move(h)), acceptor(ioc), frame_timer(ioc) {}

  void Accept();
  void ScheduleFrame();
  template <typename F>
  void Count(F&& f) {
    const std::lock_guard lock(stats_mu);
    f(stats);
  }

  TraineeServerOptions options;
  TraineeHandlers handlers;
  std::map<std::string, PageFile> files;
  std::weak_ptr<TraineeSession> trainee;  // I/O thread
  bool busy = false;                      // I/O thread: a trainee holds (or is opening) the socket
  mutable std::mutex stats_mu;
  TraineeServerStats stats;
  net::io_context ioc;
  tcp::acceptor acceptor;
  net::steady_timer frame_timer;
  std::chrono::nanoseconds frame_period{16666667};
  std::thread thread;
};

/// The trainee's WebSocket: reads messages through the size and rate caps;
/// writes the newest frame, one at a time (a frame that finds a write in
/// flight replaces the one waiting: only the newest force matters).
class TraineeSession : public std::enable_shared_from_this<TraineeSession> {
 public:
  TraineeSession(TraineeServerImpl& server, beast::tcp_stream&& stream) : server_(server), ws_(std::move(stream)) {}
  ~TraineeSession() {
    server_.busy = false;
    if (opened_) {
      server_.Count([](TraineeServerStats& s) { s.connected = false; });
      if (server_.handlers.on_close) server_.handlers.on_close();
    }
  }

  void Run(http::request<http::empty_body> req) {
    ws_.set_option(websocket::stream_base::timeout::suggested(beast::role_type::server));
    ws_.read_message_max(server_.options.max_incoming_bytes);
    ws_.async_accept(req, [self = shared_from_this()](beast::error_code ec) {
      if (ec) return;
      self->opened_ = true;
      self->server_.trainee = self;
      self->server_.Count([](TraineeServerStats& s) {
        ++s.accepted;
        s.connected = true;
      });
      self->tokens_ = self->server_.options.burst_messages;
      self->refill_ns_ = MonotonicNs();
      if (self->server_.handlers.on_open) self->Send(self->server_.handlers.on_open());
      self->Read();
    });
  }

  void Send(std::string text) {
    if (closing_ || text.empty()) return;
    if (writing_) {
      pending_ = std::move(text);
      return;
    }
    out_ = std::move(text);
    Write();
  }

  void Abort() {
    closing_ = true;
    beast::error_code ec;
    beast::get_lowest_layer(ws_).socket().close(ec);
  }

 private:
  void Write() {
    writing_ = true;
    ws_.text(true);
    ws_.async_write(net::buffer(out_), [self = shared_from_this()](beast::error_code ec, size_t) {
      self->writing_ = false;
      if (ec) return self->Abort();
      self->server_.Count([](TraineeServerStats& s) { ++s.frames_sent; });
      if (self->pending_ && !self->closing_) {
        self->out_ = std::move(*self->pending_);
        self->pending_.reset();
        self->Write();
      }
    });
  }

  /// Token bucket: true if one more message fits the rate cap now.
  bool TakeToken(int64_t now_ns) {
    const TraineeServerOptions& o = server_.options;
    tokens_ = std::min(o.burst_messages, tokens_ + 1e-9 * static_cast<double>(now_ns - refill_ns_) * o.max_messages_per_s);
    refill_ns_ = now_ns;
    if (tokens_ < 1.0) return false;
    tokens_ -= 1.0;
    return true;
  }

  void Read() {
    ws_.async_read(buffer_, [self = shared_from_this()](beast::error_code ec, size_t) {
      if (ec == websocket::error::message_too_big) {
        // Beast fails the connection with 1009 itself.
        self->server_.Count([](TraineeServerStats& s) { ++s.closed_oversized; });
        return self->Abort();
      }
      if (ec) return self->Abort();  // a close frame, a reset, end of stream
      const int64_t now = MonotonicNs();
      if (self->TakeToken(now)) {
        self->server_.Count([](TraineeServerStats& s) { ++s.messages_received; });
        const auto data = self->buffer_.cdata();
        self->server_.handlers.on_message(
            std::string_view(static_cast<const char*>(data.data()), data.size()), now);
      } else {
        self->server_.Count([](TraineeServerStats& s) { ++s.rate_limited; });
      }
      self->buffer_.consume(self->buffer_.size());
      self->Read();
    });
  }

  TraineeServerImpl& server_;
  websocket::stream<beast::tcp_stream> ws_;
  beast::flat_buffer buffer_;
  std::string out_;
  std::optional<std::string> pending_;
  bool writing_ = false;
  bool closing_ = false;
  bool opened_ = false;
  double tokens_ = 0.0;
  int64_t refill_ns_ = 0;
};

/// One HTTP connection: reads a request, serves a file or upgrades.
class TraineeHttp : public std::enable_shared_from_this<TraineeHttp> {
 public:
  TraineeHttp(TraineeServerImpl& server, tcp::socket&& socket) : server_(server), stream_(std::move(socket)) {}

  void Read() {
    parser_.emplace();
    parser_->header_limit(static_cast<uint32_t>(server_.options.max_request_header_bytes));
    parser_->body_limit(1024);
    stream_.expires_after(std::chrono::seconds(10));
    http::async_read(stream_, buffer_, *parser_, [self = shared_from_this()](beast::error_code ec, size_t) {
      if (ec) {
        if (ec != http::error::end_of_stream) self->server_.Count([](TraineeServerStats& s) { ++s.bad_requests; });
        return;
      }
      self->Handle(self->parser_->release());
    });
  }

 private:
  void Handle(http::request<http::empty_body> req) {
    const auto [path, token] = SplitTarget(std::string_view(req.target().data(), req.target().size()));
    if (websocket::is_upgrade(req)) return Upgrade(std::move(req), path, token);
    const auto it = server_.files.find(path == "/" ? "/index.html" : path);
    if (req.method() != http::verb::get || it == server_.files.end()) {
      server_.Count([](TraineeServerStats& s) { ++s.bad_requests; });
      return Reply(req, http::status::not_found, "not found\n", "text/plain");
    }
    server_.Count([](TraineeServerStats& s) { ++s.pages_served; });
    Reply(req, http::status::ok, it->second.body, it->second.content_type);
  }

  void Upgrade(http::request<http::empty_body> req, const std::string& path, const std::string& token) {
    if (!SameSecret(token, server_.options.token)) {
      server_.Count([](TraineeServerStats& s) { ++s.refused_token; });
      return Reply(req, http::status::forbidden, "token required\n", "text/plain");
    }
    const auto origin = req[http::field::origin];
    const auto host = req[http::field::host];
    const std::string own = fmt::format("http://{}", std::string_view(host.data(), host.size()));
    if (!origin.empty() && std::string_view(origin.data(), origin.size()) != own) {
      server_.Count([](TraineeServerStats& s) { ++s.refused_origin; });
      return Reply(req, http::status::forbidden, "foreign origin\n", "text/plain");
    }
    if (path != "/ws") {
      server_.Count([](TraineeServerStats& s) { ++s.bad_requests; });
      return Reply(req, http::status::not_found, "no such endpoint\n", "text/plain");
    }
    if (server_.busy) {
      server_.Count([](TraineeServerStats& s) { ++s.refused_busy; });
      return Reply(req, http::status::service_unavailable, "a trainee is already connected\n", "text/plain");
    }
    server_.busy = true;
    stream_.expires_never();
    // Small frames at 60 Hz: send each at once rather than wait for an ACK.
    beast::error_code ignored;
    stream_.socket().set_option(tcp::no_delay(true), ignored);
    std::make_shared<TraineeSession>(server_, std::move(stream_))->Run(std::move(req));
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

  TraineeServerImpl& server_;
  beast::tcp_stream stream_;
  beast::flat_buffer buffer_;
  std::optional<http::request_parser<http::empty_body>> parser_;
};

void TraineeServerImpl::Accept() {
  acceptor.async_accept([this](beast::error_code ec, tcp::socket socket) {
    if (ec == net::error::operation_aborted) return;
    if (!ec) std::make_shared<TraineeHttp>(*this, std::move(socket))->Read();
    Accept();
  });
}

void TraineeServerImpl::ScheduleFrame() {
  frame_timer.expires_after(frame_period);
  frame_timer.async_wait([this](beast::error_code ec) {
    if (ec) return;
    if (auto s = trainee.lock(); s && handlers.frame) s->Send(handlers.frame());
    ScheduleFrame();
  });
}

TraineeServer::TraineeServer(TraineeServerOptions options, TraineeHandlers handlers)
    : impl_(std::make_unique<TraineeServerImpl>(std::move(options), std::move(handlers))) {
  const TraineeServerOptions& o = impl_->options;
  if (o.token.empty()) ThrowInputError({.field = "--serve"}, "the trainee page needs a token (the session key)");
  if (!impl_->handlers.on_message) ThrowInputError({.field = "--serve"}, "no message handler");
  if (!(o.frame_hz >= 1.0 && o.frame_hz <= 1000.0)) {
    ThrowInputError({.field = "frame_hz"}, fmt::format("{} Hz is out of range [1, 1000]", o.frame_hz));
  }
  if (!(o.max_messages_per_s > 0.0 && o.burst_messages >= 1.0)) {
    ThrowInputError({.field = "max_messages_per_s"}, "the rate cap needs a positive rate and a burst of at least 1");
  }
  impl_->frame_period = std::chrono::nanoseconds(static_cast<int64_t>(1e9 / o.frame_hz));
  impl_->files = ReadPageFiles(o.files, "the trainee page's files");
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
  impl_->ScheduleFrame();
  impl_->thread = std::thread([this] { impl_->ioc.run(); });
}

TraineeServer::~TraineeServer() {
  std::promise<void> closed;
  net::post(impl_->ioc, [this, &closed] {
    beast::error_code ec;
    impl_->acceptor.close(ec);
    impl_->frame_timer.cancel();
    if (auto s = impl_->trainee.lock()) s->Abort();
    closed.set_value();
  });
  closed.get_future().wait();
  impl_->ioc.stop();
  if (impl_->thread.joinable()) impl_->thread.join();
}

std::string TraineeServer::BaseUrl() const {
  const std::string& a = impl_->options.address;
  const std::string host = a.find(':') != std::string::npos ? "[" + a + "]" : a;
  return fmt::format("http://{}:{}/", host, port_);
}

TraineeServerStats TraineeServer::stats() const {
  const std::lock_guard lock(impl_->stats_mu);
  return impl_->stats;
}

}  // namespace cutsim::web
