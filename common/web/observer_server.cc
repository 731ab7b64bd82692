#include "common/web/observer_server.h"

#include <algorithm>
#include <cctype>
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

#include "common/core/clock.h"
#include "common/core/error.h"
#include "common/core/log.h"
#include "common/web/http_util.h"
#include "common/web/web_core.h"

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
  explicit ObserverServerImpl(ObserverServerOptions o) : options(std::move(o)) {}

  // Called on the I/O thread only (no lock), except the stats.
  void OnUpgrade(beast::tcp_stream&& stream, http::request<http::empty_body>&& req, std::shared_ptr<void> hold);
  void OnWsOpen(const std::shared_ptr<WsSession>& s);
  void OnWsClosed(WsSession* s);
  template <typename F>
  void Count(F&& f) {
    const std::lock_guard lock(stats_mu);
    f(stats);
  }

  ObserverServerOptions options;
  std::map<WsSession*, std::weak_ptr<WsSession>> sessions;  // I/O thread
  std::map<std::string, std::vector<Outgoing>> join;        // I/O thread, by channel
  mutable std::mutex stats_mu;
  ObserverServerStats stats;
  std::unique_ptr<WebCore> core;  // last: destroyed first, with the sessions its I/O context holds
};

/// One WebSocket client: a queue of shared messages, written one at a time;
/// a read that only ever ends the session.
class WsSession : public std::enable_shared_from_this<WsSession> {
 public:
  WsSession(ObserverServerImpl& server, beast::tcp_stream&& stream, std::shared_ptr<void> hold, std::string channel,
            bool instructor)
      : server_(server),
        ws_(std::move(stream)),
        hold_(std::move(hold)),
        channel_(std::move(channel)),
        instructor_(instructor),
        bucket_(server.options.max_control_per_s),
        bucket_ns_(MonotonicNs()) {}

  [[nodiscard]] const std::string& channel() const { return channel_; }
  [[nodiscard]] bool instructor() const { return instructor_; }
  ~WsSession() {
    if (opened_) server_.OnWsClosed(this);
  }

  void Run(http::request<http::empty_body> req) {
    ws_.set_option(websocket::stream_base::timeout::suggested(beast::role_type::server));
    ws_.read_message_max(server_.options.max_incoming_bytes);
    ws_.async_accept(req, [self = shared_from_this()](beast::error_code ec) {
      if (ec) return;
      self->opened_ = true;
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
      self->server_.Count([n, &self](ObserverServerStats& s) {
        ++s.messages_sent;
        s.bytes_sent += n;
        if (self->server_.options.channels) s.channel_bytes[self->channel_] += n;
      });
      self->queued_bytes_ -= self->queue_.front().payload->size();
      self->queue_.pop_front();
      if (!self->queue_.empty() && !self->closing_) self->Write();
    });
  }

  void Read() {
    ws_.async_read(read_buffer_, [self = shared_from_this()](beast::error_code ec, size_t) {
      // A message above the cap (Beast fails the connection with 1009
      // itself) ends the session, and so does any message from an
      // observer: it has nothing to say. Other errors are a browser leaving
      // (a close frame, a reset, end of stream).
      const bool too_big = ec == websocket::error::message_too_big;
      if (ec && !too_big) return self->Abort();
      if (!too_big && self->instructor_) return self->OnControl();
      self->server_.Count([&self](ObserverServerStats& s) {
        ++s.closed_incoming;
        if (!self->instructor_) ++s.control_not_instructor;
      });
      if (too_big) return self->Abort();
      self->closing_ = true;
      self->ws_.async_close(websocket::close_reason(websocket::close_code::policy_error,
                                                    "read-only: control needs the instructor token"),
                            [self](beast::error_code) { self->Abort(); });
    });
  }

  /// An instructor's message: within the rate cap, handed to on_control and
  /// answered; then the next read.
  void OnControl() {
    const int64_t now = MonotonicNs();
    const double rate = server_.options.max_control_per_s;
    bucket_ = std::min(rate, bucket_ + rate * 1e-9 * static_cast<double>(now - bucket_ns_));
    bucket_ns_ = now;
    std::string reply;
    if (!ws_.got_text()) {
      reply = R"({"type":"control","ok":false,"field":"command","error":"commands are text frames"})";
    } else if (bucket_ < 1.0) {
      server_.Count([](ObserverServerStats& s) { ++s.control_rate_limited; });
      reply = fmt::format(
          R"({{"type":"control","ok":false,"field":"rate","error":"more than {:g} commands a second"}})", rate);
    } else {
      bucket_ -= 1.0;
      server_.Count([](ObserverServerStats& s) { ++s.control_messages; });
      const auto data = read_buffer_.cdata();
      const std::string_view text(static_cast<const char*>(data.data()), data.size());
      reply = server_.options.on_control
                  ? server_.options.on_control(text)
                  : std::string(R"({"type":"control","ok":false,"field":"command","error":"no control here"})");
    }
    read_buffer_.consume(read_buffer_.size());
    Send(Outgoing{.payload = std::make_shared<const std::string>(std::move(reply)), .binary = false});
    if (!closing_) Read();
  }

  ObserverServerImpl& server_;
  websocket::stream<beast::tcp_stream> ws_;
  std::shared_ptr<void> hold_;  // the core's connection and client slot
  bool opened_ = false;
  beast::flat_buffer read_buffer_;
  std::deque<Outgoing> queue_;
  size_t queued_bytes_ = 0;
  bool closing_ = false;
  std::string channel_;
  bool instructor_ = false;
  double bucket_;       // instructor messages that may be sent now (token bucket)
  int64_t bucket_ns_;   // when the bucket was last filled
};

void ObserverServerImpl::OnUpgrade(beast::tcp_stream&& stream, http::request<http::empty_body>&& req,
                                   std::shared_ptr<void> hold) {
  std::string channel;
  if (options.channels) {
    if (auto session = QueryParam(std::string_view(req.target().data(), req.target().size()), "session")) {
      // The lab's channels are session names (1-50 of A-Z a-z 0-9 _ -).
      const bool valid = !session->empty() && session->size() <= 50 &&
                         std::all_of(session->begin(), session->end(), [](char c) {
                           return std::isalnum(static_cast<unsigned char>(c)) != 0 || c == '-' || c == '_';
                         });
      if (!valid) {
        // Refused with a reply that names the parameter; the connection
        // closes once it is written.
        Count([](ObserverServerStats& st) { ++st.refused_channel; });
        auto reply = MakeReply(req, http::status::bad_request,
                               "session: must be 1 to 50 characters of A-Z a-z 0-9 _ -\n", "text/plain");
        auto conn = std::make_shared<beast::tcp_stream>(std::move(stream));
        http::async_write(*conn, *reply, [conn, reply, hold](beast::error_code, size_t) {
          beast::error_code ec;
          conn->socket().shutdown(tcp::socket::shutdown_both, ec);
        });
        return;
      }
      channel = std::move(*session);
    }
  }
  bool instructor = false;
  if (auto given = QueryParam(std::string_view(req.target().data(), req.target().size()), "instructor")) {
    instructor = !options.instructor_token.empty() && SameSecret(*given, options.instructor_token);
    if (!instructor) {
      Count([](ObserverServerStats& st) { ++st.refused_instructor; });
      auto reply = MakeReply(req, http::status::forbidden, "instructor: wrong token\n", "text/plain");
      auto conn = std::make_shared<beast::tcp_stream>(std::move(stream));
      http::async_write(*conn, *reply, [conn, reply, hold](beast::error_code, size_t) {
        beast::error_code ec;
        conn->socket().shutdown(tcp::socket::shutdown_both, ec);
      });
      return;
    }
  }
  std::make_shared<WsSession>(*this, std::move(stream), std::move(hold), std::move(channel), instructor)
      ->Run(std::move(req));
}

void ObserverServerImpl::OnWsOpen(const std::shared_ptr<WsSession>& s) {
  sessions[s.get()] = s;
  Count([this, &s](ObserverServerStats& st) {
    ++st.accepted;
    st.clients = static_cast<int>(sessions.size());
    if (s->instructor()) ++st.instructors;
  });
  if (const auto it = join.find(s->channel()); it != join.end()) {
    for (const Outgoing& m : it->second) s->Send(m);
  }
}

void ObserverServerImpl::OnWsClosed(WsSession* s) {
  sessions.erase(s);
  Count([this, s](ObserverServerStats& st) {
    st.clients = static_cast<int>(sessions.size());
    if (s->instructor()) --st.instructors;
  });
}

ObserverServer::ObserverServer(ObserverServerOptions options) : impl_(std::make_unique<ObserverServerImpl>(std::move(options))) {
  const ObserverServerOptions& o = impl_->options;
  if (!o.instructor_token.empty() && !o.on_control) {
    ThrowInputError({.field = "--instructor-token-file"}, "an instructor token needs a control handler");
  }
  if (!IsLoopbackAddress(o.address) && o.token.empty()) {
    ThrowInputError({.field = "--serve"},
                    fmt::format("{} is not a loopback address: observers from other machines need a token "
                                "(--token-file)",
                                o.address));
  }
  WebCoreOptions co = CoreOptionsOf(o, "the observer page's files", o.max_clients);
  ObserverServerImpl* impl = impl_.get();
  impl_->core = std::make_unique<WebCore>(
      std::move(co), [impl](beast::tcp_stream&& stream, http::request<http::empty_body>&& req,
                            std::shared_ptr<void> hold) { impl->OnUpgrade(std::move(stream), std::move(req), std::move(hold)); });
  port_ = impl_->core->port();
  impl_->core->Start();
}

ObserverServer::~ObserverServer() {
  // Close every client on the I/O thread, then stop it; handlers still
  // pending are destroyed with the core's io_context.
  impl_->core->Stop([this] {
    for (auto& [ptr, weak] : impl_->sessions) {
      if (auto s = weak.lock()) s->Abort();
    }
  });
}

std::string ObserverServer::Url() const {
  const std::string& a = impl_->options.address;
  const std::string host = a.find(':') != std::string::npos ? "[" + a + "]" : a;
  std::string url = fmt::format("http://{}:{}/", host, port_);
  if (!impl_->options.token.empty()) url += "?token=" + impl_->options.token;
  return url;
}

void ObserverServer::Broadcast(const std::string& channel, std::vector<Outgoing> messages) {
  net::post(impl_->core->ioc(), [this, channel, m = std::move(messages)] {
    for (auto& [ptr, weak] : impl_->sessions) {
      if (auto s = weak.lock(); s && s->channel() == channel) {
        for (const Outgoing& o : m) s->Send(o);
      }
    }
  });
}

void ObserverServer::SetJoinMessages(const std::string& channel, std::vector<Outgoing> messages) {
  net::post(impl_->core->ioc(), [this, channel, m = std::move(messages)]() mutable {
    if (m.empty()) {
      impl_->join.erase(channel);
    } else {
      impl_->join[channel] = std::move(m);
    }
  });
}

ObserverServerStats ObserverServer::stats() const {
  ObserverServerStats s;
  {
    const std::lock_guard lock(impl_->stats_mu);
    s = impl_->stats;
  }
  s.web = impl_->core->stats();
  return s;
}

}  // namespace cutsim::web
