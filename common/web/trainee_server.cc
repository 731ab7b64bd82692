#include "common/web/trainee_server.h"

#include <algorithm>
#include <chrono>
#include <mutex>
#include <optional>
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

namespace cutsim::web {

namespace net = boost::asio;
namespace beast = boost::beast;
namespace http = beast::http;
namespace websocket = beast::websocket;
using tcp = net::ip::tcp;

class TraineeSession;

struct TraineeServerImpl {
  TraineeServerImpl(TraineeServerOptions o, TraineeHandlers h) : options(std::move(o)), handlers(std::move(h)) {}

  void OnUpgrade(beast::tcp_stream&& stream, http::request<http::empty_body>&& req, std::shared_ptr<void> hold);
  void ScheduleFrame();
  template <typename F>
  void Count(F&& f) {
    const std::lock_guard lock(stats_mu);
    f(stats);
  }

  TraineeServerOptions options;
  TraineeHandlers handlers;
  std::weak_ptr<TraineeSession> trainee;          // I/O thread
  std::shared_ptr<const std::string> snapshot;    // I/O thread: the newest mesh snapshot
  mutable std::mutex stats_mu;
  TraineeServerStats stats;
  std::chrono::nanoseconds frame_period{16666667};
  std::chrono::nanoseconds poll_period{2000000};
  std::chrono::steady_clock::time_point last_frame;  // when the last frame went
  std::optional<net::steady_timer> frame_timer;  // on the core's I/O context
  std::unique_ptr<WebCore> core;                 // last: destroyed first, with the sessions it holds
};

/// The trainee's WebSocket: reads messages through the size, rate and idle
/// caps; writes one message at a time, the newest force frame first, then
/// the newest mesh frames (older ones waiting are replaced: only the newest
/// force and shape matter).
class TraineeSession : public std::enable_shared_from_this<TraineeSession> {
 public:
  TraineeSession(TraineeServerImpl& server, beast::tcp_stream&& stream, std::shared_ptr<void> hold)
      : server_(server), ws_(std::move(stream)), hold_(std::move(hold)), idle_(ws_.get_executor()) {}
  ~TraineeSession() {
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
      if (self->server_.snapshot) self->SendMesh(self->server_.snapshot, true);
      self->ArmIdle();
      self->Read();
    });
  }

  void Send(std::string text) {
    if (closing_ || text.empty()) return;
    text_ = std::move(text);
    if (!writing_) WriteNext();
  }

  void SendMesh(std::shared_ptr<const std::string> frame, bool snapshot) {
    if (closing_ || !opened_) return;
    if (snapshot) {
      snapshot_ = std::move(frame);
      update_.reset();
    } else {
      update_ = std::move(frame);
    }
    if (!writing_) WriteNext();
  }

  void Abort() {
    closing_ = true;
    idle_.cancel();
    beast::error_code ec;
    beast::get_lowest_layer(ws_).socket().close(ec);
  }

 private:
  /// Writes the next waiting message: the force frame, then the mesh.
  void WriteNext() {
    if (text_) {
      out_text_ = std::move(*text_);
      text_.reset();
      ws_.text(true);
      return Write(net::buffer(out_text_), true);
    }
    std::shared_ptr<const std::string>& next = snapshot_ ? snapshot_ : update_;
    if (!next) return;
    out_mesh_ = std::move(next);
    next.reset();
    ws_.binary(true);
    Write(net::buffer(*out_mesh_), false);
  }

  void Write(net::const_buffer buffer, bool text) {
    writing_ = true;
    ws_.async_write(buffer, [self = shared_from_this(), text](beast::error_code ec, size_t) {
      self->writing_ = false;
      self->out_mesh_.reset();
      if (ec) return self->Abort();
      if (text) self->server_.Count([](TraineeServerStats& s) { ++s.frames_sent; });
      if (!self->closing_) self->WriteNext();
    });
  }

  /// Closes the session when nothing arrives for idle_timeout_s.
  void ArmIdle() {
    idle_.expires_after(std::chrono::nanoseconds(static_cast<int64_t>(server_.options.idle_timeout_s * 1e9)));
    idle_.async_wait([weak = weak_from_this()](beast::error_code ec) {
      auto self = weak.lock();
      if (ec || !self || self->closing_) return;
      self->server_.Count([](TraineeServerStats& s) { ++s.closed_idle; });
      self->Abort();
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
        self->ArmIdle();  // any message within the caps keeps the seat
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
  std::shared_ptr<void> hold_;  // the core's connection and seat
  net::steady_timer idle_;
  beast::flat_buffer buffer_;
  std::optional<std::string> text_;                 // the force frame waiting
  std::shared_ptr<const std::string> snapshot_;     // mesh frames waiting
  std::shared_ptr<const std::string> update_;
  std::string out_text_;                            // in flight
  std::shared_ptr<const std::string> out_mesh_;
  bool writing_ = false;
  bool closing_ = false;
  bool opened_ = false;
  double tokens_ = 0.0;
  int64_t refill_ns_ = 0;
};

void TraineeServerImpl::OnUpgrade(beast::tcp_stream&& stream, http::request<http::empty_body>&& req,
                                  std::shared_ptr<void> hold) {
  // Small frames, one per input: send each at once rather than wait for an ACK.
  beast::error_code ignored;
  stream.socket().set_option(tcp::no_delay(true), ignored);
  std::make_shared<TraineeSession>(*this, std::move(stream), std::move(hold))->Run(std::move(req));
}

void TraineeServerImpl::ScheduleFrame() {
  // The fast poll only while a trainee is there to take the frames.
  frame_timer->expires_after(trainee.expired() ? frame_period : poll_period);
  frame_timer->async_wait([this](beast::error_code ec) {
    if (ec) return;
    const auto now = std::chrono::steady_clock::now();
    auto s = trainee.lock();
    if (s && handlers.frame && (now - last_frame >= frame_period || (handlers.urgent && handlers.urgent()))) {
      s->Send(handlers.frame());
      last_frame = now;
    }
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
  if (!(o.idle_timeout_s >= 0.05 && o.idle_timeout_s <= 3600.0)) {
    ThrowInputError({.field = "idle_timeout_s"}, fmt::format("{} s is out of range [0.05, 3600]", o.idle_timeout_s));
  }
  if (!(o.poll_hz >= o.frame_hz && o.poll_hz <= 2000.0)) {
    ThrowInputError({.field = "poll_hz"}, fmt::format("{} Hz is out of range [frame_hz, 2000]", o.poll_hz));
  }
  impl_->frame_period = std::chrono::nanoseconds(static_cast<int64_t>(1e9 / o.frame_hz));
  impl_->poll_period = std::chrono::nanoseconds(static_cast<int64_t>(1e9 / o.poll_hz));
  // One trainee holds the tool: one WebSocket client.
  WebCoreOptions co = CoreOptionsOf(o, "the trainee page's files", 1);
  TraineeServerImpl* impl = impl_.get();
  impl_->core = std::make_unique<WebCore>(
      std::move(co), [impl](beast::tcp_stream&& stream, http::request<http::empty_body>&& req,
                            std::shared_ptr<void> hold) { impl->OnUpgrade(std::move(stream), std::move(req), std::move(hold)); });
  port_ = impl_->core->port();
  impl_->frame_timer.emplace(impl_->core->ioc());
  impl_->ScheduleFrame();
  impl_->core->Start();
}

TraineeServer::~TraineeServer() {
  impl_->core->Stop([this] {
    impl_->frame_timer->cancel();
    if (auto s = impl_->trainee.lock()) s->Abort();
  });
  impl_->frame_timer.reset();
}

std::string TraineeServer::BaseUrl() const { return impl_->core->BaseUrl(); }

void TraineeServer::SendMesh(std::shared_ptr<const std::string> frame, bool snapshot) {
  if (!frame || frame->empty()) return;
  net::post(impl_->core->ioc(), [this, f = std::move(frame), snapshot]() mutable {
    if (snapshot) impl_->snapshot = f;
    if (auto s = impl_->trainee.lock()) s->SendMesh(std::move(f), snapshot);
  });
}

TraineeServerStats TraineeServer::stats() const {
  TraineeServerStats s;
  {
    const std::lock_guard lock(impl_->stats_mu);
    s = impl_->stats;
  }
  s.web = impl_->core->stats();
  return s;
}

}  // namespace cutsim::web
