// The trainee server's own rules on loopback sockets (the refusals it shares
// with the observer server are in web_core_test.cc): a silent trainee loses
// the seat after the idle time, a trainee whose page sends heartbeats keeps
// it, and mesh frames reach the trainee, the newest snapshot first for one
// who joins.
#include <gtest/gtest.h>
#include <unistd.h>

#include <chrono>
#include <filesystem>
#include <fstream>
#include <memory>
#include <string>
#include <thread>

#include "common/web/trainee_server.h"
#include "tests/support/web_client.h"

namespace cutsim::web {
namespace {

using test::WebSocketClient;
using namespace std::chrono_literals;

constexpr const char* kTraineeToken = "trainee-token-0123";

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
    o.token = kTraineeToken;
    o.idle_timeout_s = idle_s;
    TraineeHandlers h;
    h.on_message = [](std::string_view, int64_t) {};
    server_ = std::make_unique<TraineeServer>(o, h);
  }

  /// Opens a trainee's WebSocket; false when refused.
  bool Open(WebSocketClient* ws) { return ws->Open(server_->port(), std::string("/ws?token=") + kTraineeToken); }

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
  std::unique_ptr<TraineeServer> server_;
};

TEST_F(TraineeServerTest, ASilentTraineeLosesTheSeatAHeartbeatKeepsIt) {
  Start(0.5);
  WebSocketClient silent;
  ASSERT_TRUE(Open(&silent));
  // Nothing sent: the server closes the socket and frees the seat.
  while (silent.Read()) {
  }
  EXPECT_TRUE(Eventually([&] { return !server_->stats().connected && server_->stats().web.ws_clients == 0; }));
  EXPECT_EQ(server_->stats().closed_idle, 1u);

  WebSocketClient beating;
  ASSERT_TRUE(Open(&beating));
  // Heartbeats at ten times the idle rate, for three idle times.
  for (int i = 0; i < 30; ++i) {
    ASSERT_TRUE(beating.Write("h"));
    std::this_thread::sleep_for(50ms);
  }
  EXPECT_TRUE(server_->stats().connected);
  EXPECT_EQ(server_->stats().closed_idle, 1u);
  WebSocketClient second;
  EXPECT_FALSE(Open(&second));  // the seat is still taken
}

TEST_F(TraineeServerTest, MeshFramesReachTheTraineeTheNewestSnapshotFirstOnJoining) {
  Start(10.0);
  server_->SendMesh(std::make_shared<const std::string>("S0"), true);
  WebSocketClient ws;
  ASSERT_TRUE(Open(&ws));
  const auto s0 = ws.Read();
  ASSERT_TRUE(s0);
  EXPECT_TRUE(s0->second);
  EXPECT_EQ(s0->first, "S0");
  server_->SendMesh(std::make_shared<const std::string>("S1"), true);
  EXPECT_EQ(ws.ReadData(), "S1");
  server_->SendMesh(std::make_shared<const std::string>("U1"), false);
  EXPECT_EQ(ws.ReadData(), "U1");
}

}  // namespace
}  // namespace cutsim::web
