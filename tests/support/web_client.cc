#include "tests/support/web_client.h"

#include <boost/asio/ip/tcp.hpp>
#include <boost/beast/core.hpp>
#include <boost/beast/http.hpp>
#include <boost/beast/websocket.hpp>

namespace cutsim::test {

namespace net = boost::asio;
namespace beast = boost::beast;
namespace http = beast::http;
namespace websocket = beast::websocket;
using tcp = net::ip::tcp;

namespace {

tcp::endpoint Loopback(uint16_t port) { return {net::ip::make_address("127.0.0.1"), port}; }

std::string HostOf(uint16_t port) { return "127.0.0.1:" + std::to_string(port); }

}  // namespace

struct WebSocketClient::Impl {
  net::io_context ioc;
  websocket::stream<tcp::socket> ws{ioc};
};

WebSocketClient::WebSocketClient() : impl_(std::make_unique<Impl>()) {}

WebSocketClient::~WebSocketClient() = default;

bool WebSocketClient::Open(uint16_t port, const std::string& target, const std::string& origin) {
  // A failed connect throws: only a refused upgrade is an answer.
  impl_->ws.next_layer().connect(Loopback(port));
  impl_->ws.set_option(websocket::stream_base::decorator([origin](websocket::request_type& req) {
    if (!origin.empty()) req.set(http::field::origin, origin);
  }));
  beast::error_code ec;
  impl_->ws.handshake(HostOf(port), target, ec);
  return !ec;
}

std::optional<std::pair<std::string, bool>> WebSocketClient::Read() {
  beast::flat_buffer buffer;
  beast::error_code ec;
  impl_->ws.read(buffer, ec);
  if (ec) return std::nullopt;
  return std::make_pair(beast::buffers_to_string(buffer.data()), impl_->ws.got_binary());
}

std::optional<std::string> WebSocketClient::ReadData() {
  auto message = Read();
  if (!message) return std::nullopt;
  return std::move(message->first);
}

bool WebSocketClient::Write(std::string_view bytes, bool binary) {
  impl_->ws.binary(binary);
  beast::error_code ec;
  impl_->ws.write(net::buffer(bytes.data(), bytes.size()), ec);
  return !ec;
}

std::pair<int, std::string> WebSocketClient::CloseReason() const {
  const websocket::close_reason& r = impl_->ws.reason();
  return {static_cast<int>(r.code), std::string(r.reason.c_str())};
}

bool WebSocketClient::Close() {
  beast::error_code ec;
  impl_->ws.close(websocket::close_code::normal, ec);
  return !ec;
}

void WebSocketClient::Shutdown() {
  beast::error_code ec;
  impl_->ws.next_layer().shutdown(tcp::socket::shutdown_both, ec);
}

std::pair<int, std::string> HttpGet(uint16_t port, const std::string& target) {
  net::io_context ioc;
  beast::tcp_stream stream(ioc);
  stream.connect(Loopback(port));
  http::request<http::empty_body> req(http::verb::get, target, 11);
  req.set(http::field::host, HostOf(port));
  http::write(stream, req);
  beast::flat_buffer buffer;
  http::response<http::string_body> res;
  http::read(stream, buffer, res);
  return {static_cast<int>(res.result_int()), res.body()};
}

}  // namespace cutsim::test
