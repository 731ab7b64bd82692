// The trainee server's own rules on loopback sockets (the refusals it shares
// with the observer server are in web_core_test.cc): a silent trainee loses
// the seat after the idle time, a trainee whose page sends heartbeats keeps
// it, and mesh frames reach the trainee, the newest snapshot first for one
// who joins.
#include <gtest/gtest.h>

#include <chrono>
#include <filesystem>
#include <fstream>
#include <memory>
#include <string>
#include <thread>

#include <boost/asio/ip/tcp.hpp>
#include <boost/beast/core.hpp>
#include <boost/beast/websocket.hpp>

#include "common/web/trainee_server.h"

namespace cutsim::web {
namespace {

namespace net = boost::asio;
namespace beast = boost::beast;
namespace websocket = beast::websocket;
using tcp = net::ip::tcp;
using namespace std::chrono_literals;

constexpr const char* kToken = "trainee-token-0123";

class TraineeServerTest : public ::testing::Test {
 protected:
  TraineeServerTest() : dir_(std::filesystem::temp_directory_path() / ("cutsim_trainee_test_" + std::to_string(::getpid()))) {
    std::filesystem::create_directories(dir_);
    std::ofstream(dir_ / "index.html") << "<html>trainee</html>";
  }
  ~TraineeServerTest() override { std::filesystem::remove_all(dir_); }

  void Start(double idle_s) {
    TraineeServerOptions o;
    o.files = {{"/index.html", dir_ / "index.html"}};
    o.token = kToken;
    o.idle_timeout_s = idle_s;
    TraineeHandlers h;
    h.on_message = [](std::string_view, int64_t) {};
    server_ = std::make_unique<TraineeServer>(o, h);
  }

  /// Opens a trainee's WebSocket; false when refused.
  bool Open(websocket::stream<tcp::socket>* ws) {
    ws->next_layer().connect(tcp::endpoint(net::ip::make_address("127.0.0.1"), server_->port()));
    beast::error_code ec;
    ws->handshake("127.0.0.1:" + std::to_string(server_->port()), std::string("/ws?token=") + kToken, ec);
    return !ec;
  }

  template <typename P>
  static bool Eventually(P pred) {
    const auto deadline = std::chrono::steady_clock::now() + 10s;
    while (std::chrono::steady_clock::now() < deadline) {
      if (pred()) return true;
      std::this_thread::sleep_for(5ms);
    }
    return pred();
  }

  std::filesystem::path dir_;
  net::io_context ioc_;
  std::unique_ptr<TraineeServer> server_;
};

TEST_F(TraineeServerTest, ASilentTraineeLosesTheSeatAHeartbeatKeepsIt) {
  Start(0.5);
  websocket::stream<tcp::socket> silent(ioc_);
  ASSERT_TRUE(Open(&silent));
  // Nothing sent: the server closes the socket and frees the seat.
  beast::flat_buffer buffer;
  beast::error_code ec;
  while (!ec) silent.read(buffer, ec);
  EXPECT_TRUE(Eventually([&] { return !server_->stats().connected && server_->stats().web.ws_clients == 0; }));
  EXPECT_EQ(server_->stats().closed_idle, 1u);

  websocket::stream<tcp::socket> beating(ioc_);
  ASSERT_TRUE(Open(&beating));
  beating.text(true);
  // Heartbeats at ten times the idle rate, for three idle times.
  for (int i = 0; i < 30; ++i) {
    beating.write(net::buffer(std::string("h")));
    std::this_thread::sleep_for(50ms);
  }
  EXPECT_TRUE(server_->stats().connected);
  EXPECT_EQ(server_->stats().closed_idle, 1u);
  websocket::stream<tcp::socket> second(ioc_);
  EXPECT_FALSE(Open(&second));  // the seat is still taken
}

TEST_F(TraineeServerTest, MeshFramesReachTheTraineeTheNewestSnapshotFirstOnJoining) {
  Start(10.0);
  server_->SendMesh(std::make_shared<const std::string>("S0"), true);
  websocket::stream<tcp::socket> ws(ioc_);
  ASSERT_TRUE(Open(&ws));
  beast::flat_buffer buffer;
  ws.read(buffer);
  EXPECT_TRUE(ws.got_binary());
  EXPECT_EQ(beast::buffers_to_string(buffer.data()), "S0");
  buffer.clear();
  server_->SendMesh(std::make_shared<const std::string>("S1"), true);
  ws.read(buffer);
  EXPECT_EQ(beast::buffers_to_string(buffer.data()), "S1");
  buffer.clear();
  server_->SendMesh(std::make_shared<const std::string>("U1"), false);
  ws.read(buffer);
  EXPECT_EQ(beast::buffers_to_string(buffer.data()), "U1");
}

}  // namespace
}  // namespace cutsim::web
