// The browser observers' server against real sockets on loopback: pages and
// unknown paths, the token off loopback, the Origin check, the client cap,
// broadcast order with the join messages first, and the read-only rules (a
// client that sends anything, or too much, is closed; one that stops reading
// is closed instead of buffered for) while the others keep receiving.
#include <gtest/gtest.h>
#include <unistd.h>

#include <atomic>
#include <chrono>
#include <filesystem>
#include <fstream>
#include <memory>
#include <optional>
#include <string>
#include <thread>
#include <vector>

#include "common/core/error.h"
#include "common/web/observer_server.h"
#include "tests/support/web_client.h"
#include "tests/support/web_test_util.h"

namespace cutsim::web {
namespace {

using test::Binary;
using test::Eventually;
using test::TempPage;
using test::Text;

using namespace std::chrono_literals;
using Client = test::WebSocketClient;

ObserverServerOptions Options(const TempPage& page) {
  ObserverServerOptions o;
  o.files = page.files();
  return o;
}

TEST(ObserverServerTest, ServesThePageAndNothingElse) {
  TempPage page("web_test", "<html>observer</html>");
  ObserverServer server(Options(page));
  EXPECT_EQ(test::HttpGet(server.port(), "/"), std::make_pair(200, std::string("<html>observer</html>")));
  EXPECT_EQ(test::HttpGet(server.port(), "/index.html").first, 200);
  EXPECT_EQ(test::HttpGet(server.port(), "/../index.html").first, 404);
  EXPECT_EQ(test::HttpGet(server.port(), "/etc/passwd").first, 404);
  EXPECT_EQ(server.stats().web.pages_served, 2u);
  EXPECT_EQ(server.Url(), "http://127.0.0.1:" + std::to_string(server.port()) + "/");
}

TEST(ObserverServerTest, OffLoopbackNeedsATokenAndTheStreamChecksIt) {
  TempPage page("web_test", "<html>observer</html>");
  ObserverServerOptions open = Options(page);
  open.address = "0.0.0.0";
  try {
    ObserverServer refused(open);
    FAIL() << "listening off loopback without a token was accepted";
  } catch (const InputError& e) {
    EXPECT_EQ(e.source().field, "--serve");
  }
  ObserverServerOptions o = Options(page);
  o.token = "0123456789abcdef0123";
  ObserverServer server(o);
  // The page's files carry no session data; the stream needs the token.
  EXPECT_EQ(test::HttpGet(server.port(), "/").first, 200);
  Client without, wrong, with;
  EXPECT_FALSE(without.Open(server.port()));
  EXPECT_FALSE(wrong.Open(server.port(), "/ws?token=0123456789abcdef0124"));
  EXPECT_TRUE(with.Open(server.port(), "/ws?token=" + o.token));
  EXPECT_EQ(server.stats().web.refused_token, 2u);
}

TEST(ObserverServerTest, ForeignOriginIsRefusedOwnOriginAccepted) {
  TempPage page("web_test", "<html>observer</html>");
  ObserverServer server(Options(page));
  Client evil, own;
  EXPECT_FALSE(evil.Open(server.port(), "/ws", "http://evil.example"));
  EXPECT_TRUE(own.Open(server.port(), "/ws", "http://127.0.0.1:" + std::to_string(server.port())));
  EXPECT_EQ(server.stats().web.refused_origin, 1u);
}

TEST(ObserverServerTest, ClientCapRefusesTheNextClient) {
  TempPage page("web_test", "<html>observer</html>");
  ObserverServerOptions o = Options(page);
  o.max_clients = 2;
  ObserverServer server(o);
  Client a, b, c;
  ASSERT_TRUE(a.Open(server.port()));
  ASSERT_TRUE(b.Open(server.port()));
  ASSERT_TRUE(Eventually([&] { return server.stats().clients == 2; }));
  EXPECT_FALSE(c.Open(server.port()));
  EXPECT_EQ(server.stats().web.refused_cap, 1u);
}

TEST(ObserverServerTest, JoinMessagesComeFirstThenEveryBroadcastInOrder) {
  TempPage page("web_test", "<html>observer</html>");
  ObserverServer server(Options(page));
  server.SetJoinMessages({Text("hello"), Binary(std::string("\x01snap", 5))});
  std::vector<std::unique_ptr<Client>> clients;
  for (int i = 0; i < 3; ++i) {
    clients.push_back(std::make_unique<Client>());
    ASSERT_TRUE(clients.back()->Open(server.port()));
  }
  ASSERT_TRUE(Eventually([&] { return server.stats().clients == 3; }));
  server.Broadcast({Binary("frame1"), Text("session1")});
  server.Broadcast({Binary("frame2")});
  for (auto& c : clients) {
    EXPECT_EQ(c->Read(), std::make_optional(std::make_pair(std::string("hello"), false)));
    EXPECT_EQ(c->Read(), std::make_optional(std::make_pair(std::string("\x01snap", 5), true)));
    EXPECT_EQ(c->Read(), std::make_optional(std::make_pair(std::string("frame1"), true)));
    EXPECT_EQ(c->Read(), std::make_optional(std::make_pair(std::string("session1"), false)));
    EXPECT_EQ(c->Read(), std::make_optional(std::make_pair(std::string("frame2"), true)));
  }
}

TEST(ObserverServerTest, AClientThatSendsIsClosedAndTheOthersGoOn) {
  TempPage page("web_test", "<html>observer</html>");
  ObserverServerOptions o = Options(page);
  o.max_incoming_bytes = 1024;
  ObserverServer server(o);
  Client talker, flooder, watcher;
  ASSERT_TRUE(talker.Open(server.port()));
  ASSERT_TRUE(flooder.Open(server.port()));
  ASSERT_TRUE(watcher.Open(server.port()));
  ASSERT_TRUE(Eventually([&] { return server.stats().clients == 3; }));
  ASSERT_TRUE(talker.Write("{\"type\":\"cut\"}"));
  flooder.Write(std::string(2u << 20, 'x'), true);  // may fail midway: the server closes
  EXPECT_EQ(talker.Read(), std::nullopt);
  EXPECT_EQ(flooder.Read(), std::nullopt);
  EXPECT_TRUE(Eventually([&] { return server.stats().clients == 1; }));
  EXPECT_EQ(server.stats().closed_incoming, 2u);
  server.Broadcast({Text("still here")});
  EXPECT_EQ(watcher.Read(), std::make_optional(std::make_pair(std::string("still here"), false)));
}

TEST(ObserverServerTest, OnlyTheInstructorControlsAndEveryMessageIsAnswered) {
  TempPage page("web_test", "<html>observer</html>");
  ObserverServerOptions o = Options(page);
  o.instructor_token = "instructor-token-0123456789";
  o.max_control_per_s = 5.0;
  std::vector<std::string> handed;  // on the I/O thread; read after the replies arrived
  o.on_control = [&handed](std::string_view m) {
    handed.emplace_back(m);
    return std::string(R"({"type":"control","ok":true})");
  };
  ObserverServer server(o);
  // A wrong instructor token is refused at the upgrade.
  Client wrong;
  EXPECT_FALSE(wrong.Open(server.port(), "/ws?instructor=instructor-token-XXXXXXXXXX"));
  EXPECT_TRUE(Eventually([&] { return server.stats().refused_instructor == 1; }));
  // An observer that sends is closed with 1008 and its reason; nothing is handed on.
  Client observer;
  ASSERT_TRUE(observer.Open(server.port()));
  observer.Write("pause");
  EXPECT_EQ(observer.Read(), std::nullopt);
  EXPECT_EQ(observer.CloseReason().first, 1008);  // policy violation
  EXPECT_NE(observer.CloseReason().second.find("instructor"), std::string::npos);
  // The instructor's messages are handed on and answered, a binary frame is
  // refused by field, and beyond the rate cap messages are refused.
  Client instructor;
  ASSERT_TRUE(instructor.Open(server.port(), "/ws?instructor=instructor-token-0123456789"));
  ASSERT_TRUE(Eventually([&] { return server.stats().instructors == 1; }));
  instructor.Write("seek 1.5");
  EXPECT_EQ(instructor.Read()->first, R"({"type":"control","ok":true})");
  instructor.Write("\x01\x02", true);
  EXPECT_NE(instructor.Read()->first.find(R"("field":"command")"), std::string::npos);
  int refused = 0;
  for (int i = 0; i < 10; ++i) {
    instructor.Write("next");
    if (instructor.Read()->first.find(R"("field":"rate")") != std::string::npos) ++refused;
  }
  EXPECT_GT(refused, 0) << "10 messages at once against 5 a second";
  EXPECT_EQ(server.stats().control_not_instructor, 1u);
  EXPECT_EQ(handed.front(), "seek 1.5");
  EXPECT_EQ(static_cast<int>(handed.size()), 1 + 10 - refused);
}

TEST(ObserverServerTest, AClientThatStopsReadingIsClosedNotBufferedFor) {
  TempPage page("web_test", "<html>observer</html>");
  ObserverServerOptions o = Options(page);
  o.max_queued_bytes = 1u << 20;
  ObserverServer server(o);
  Client stalled, reader;
  ASSERT_TRUE(stalled.Open(server.port()));
  ASSERT_TRUE(reader.Open(server.port()));
  ASSERT_TRUE(Eventually([&] { return server.stats().clients == 2; }));
  std::atomic<int> received{0};
  std::thread drain([&] {
    while (reader.Read()) ++received;
  });
  const std::string chunk(256u << 10, 'm');
  constexpr int kMessages = 160;  // 40 MiB: far beyond what the kernel buffers for the stalled client
  for (int i = 0; i < kMessages; ++i) {
    // In step with the reader (at most two messages ahead of it, well under
    // the cap), so only the stalled client falls behind.
    ASSERT_TRUE(Eventually([&] { return received.load() >= i - 2; })) << i;
    server.Broadcast({Binary(chunk)});
  }
  EXPECT_TRUE(Eventually([&] { return server.stats().closed_slow == 1; }));
  EXPECT_TRUE(Eventually([&] { return received.load() == kMessages; })) << received.load();
  EXPECT_EQ(server.stats().clients, 1);
  // Shutdown (not close) wakes the drain thread's blocking read.
  reader.Shutdown();
  drain.join();
}

}  // namespace
}  // namespace cutsim::web
