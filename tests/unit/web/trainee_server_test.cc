// The trainee server's own rules on loopback sockets (the refusals it shares
// with the observer server are in web_core_test.cc): a silent trainee loses
// the seat after the idle time, a trainee whose page sends heartbeats keeps
// it, mesh frames reach the trainee, the newest snapshot first for one
// who joins, and a frame the device marks urgent goes before its tick.
#include <gtest/gtest.h>

#include <atomic>
#include <chrono>
#include <memory>
#include <string>
#include <thread>

#include "common/core/error.h"
#include "common/web/trainee_server.h"
#include "tests/support/web_client.h"
#include "tests/support/web_test_util.h"

namespace cutsim::web {
namespace {

using test::Eventually;
using test::TempPage;
using test::WebSocketClient;
using namespace std::chrono_literals;

constexpr const char* kTraineeToken = "trainee-token-0123";

class TraineeServerTest : public ::testing::Test {
 protected:
  void Start(double idle_s, TraineeHandlers h = {}, double frame_hz = 60.0) {
    TraineeServerOptions o;
    o.files = page_.files();
    o.token = kTraineeToken;
    o.idle_timeout_s = idle_s;
    o.frame_hz = frame_hz;
    h.on_message = [](std::string_view, int64_t) {};
    server_ = std::make_unique<TraineeServer>(o, h);
  }

  /// Opens a trainee's WebSocket; false when refused.
  bool Open(WebSocketClient* ws) { return ws->Open(server_->port(), std::string("/ws?token=") + kTraineeToken); }

  const TempPage page_{"trainee_test", "<html>trainee</html>"};
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

TEST_F(TraineeServerTest, AnUrgentFrameGoesBeforeItsTick) {
  // Frames at 1 Hz at least ("t"); `urgent` asks for one more ("u") when armed.
  std::atomic<int> armed{0};
  std::atomic<bool> taken{false};
  TraineeHandlers h;
  h.frame = [&] { return taken.exchange(false) ? std::string("u") : std::string("t"); };
  h.urgent = [&] {
    if (armed.load() == 0) return false;
    armed = 0;
    taken = true;
    return true;
  };
  Start(10.0, h, 1.0);
  WebSocketClient ws;
  ASSERT_TRUE(Open(&ws));
  EXPECT_EQ(ws.ReadData(), "t");  // the first tick is due at once
  // Five urgent frames, each armed after the last arrived: with only the
  // 1 Hz tick they would take four seconds more.
  const auto start = std::chrono::steady_clock::now();
  int urgent = 0, ticks = 1;
  while (urgent < 5) {
    armed = 1;
    const auto frame = ws.ReadData();
    ASSERT_TRUE(frame);
    (*frame == "u" ? urgent : ticks) += 1;
  }
  EXPECT_LT(std::chrono::steady_clock::now() - start, 3s);
  EXPECT_LE(ticks, 4);
  EXPECT_TRUE(Eventually([&] { return server_->stats().frames_sent == static_cast<uint64_t>(urgent + ticks); }));
}

TEST(TraineeServerOptionsTest, APollSlowerThanTheFramesIsRefused) {
  TraineeServerOptions o;
  o.token = "t";
  o.frame_hz = 60.0;
  o.poll_hz = 30.0;
  TraineeHandlers h;
  h.on_message = [](std::string_view, int64_t) {};
  try {
    TraineeServer server(o, h);
    FAIL() << "a 30 Hz poll under 60 Hz frames was taken";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("poll_hz"), std::string::npos) << e.what();
  }
}

}  // namespace
}  // namespace cutsim::web
