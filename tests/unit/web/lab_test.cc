// The lab view's parts without processes: the session directory fed status
// payloads (live, stopped, forgotten, the cap, signatures, stale and
// malformed statuses), the observer server's channels (a client receives
// only its session's messages; a bad session name is refused), and the lab
// list's JSON (escaping, non-finite numbers).
#include <gtest/gtest.h>

#include <array>
#include <chrono>
#include <optional>
#include <string>
#include <vector>

#include "common/transport/dds.h"
#include "common/transport/session_directory.h"
#include "common/transport/stream_auth.h"
#include "common/web/lab_bridge.h"
#include "common/web/observer_server.h"
#include "tests/support/web_client.h"
#include "tests/support/web_test_util.h"

namespace cutsim::web {
namespace {

using test::Eventually;
using test::Text;

using namespace std::chrono_literals;
using transport::SessionDirectory;
using transport::SessionDirectoryOptions;

constexpr int64_t kSecond = 1'000'000'000;

std::vector<uint8_t> Status(const std::string& session, uint64_t frame, uint64_t tool_messages = 0,
                            uint64_t epoch = 7) {
  v1::SessionStatus s;
  s.set_session(session);
  s.set_frame(frame);
  s.set_wall_time(0.01 * static_cast<double>(frame));
  s.set_tool_messages(tool_messages);
  s.set_epoch(epoch);
  s.set_scene("ligament");
  s.set_trainee("ada");
  std::vector<uint8_t> bytes(s.ByteSizeLong());
  s.SerializeToArray(bytes.data(), static_cast<int>(bytes.size()));
  return bytes;
}

TEST(SessionDirectoryTest, ASessionIsLiveWhileHeardThenStoppedThenForgotten) {
  SessionDirectory dir(SessionDirectoryOptions{.live_window = 3000ms, .forget_after = 60000ms});
  ASSERT_TRUE(dir.Process("bay-1", Status("bay-1", 100), 0));
  ASSERT_TRUE(dir.Process("bay-2", Status("bay-2", 100), 0));
  ASSERT_TRUE(dir.Process("bay-2", Status("bay-2", 200), 2 * kSecond));
  auto e = dir.Entries(4 * kSecond);
  ASSERT_EQ(e.size(), 2u);
  EXPECT_EQ(e[0].session, "bay-1");
  EXPECT_FALSE(e[0].live) << "silent for 4 s, more than the live window";
  EXPECT_TRUE(e[1].live);
  EXPECT_EQ(e[1].status.scene(), "ligament");
  EXPECT_EQ(e[1].status.trainee(), "ada");
  e = dir.Entries(64 * kSecond);
  ASSERT_EQ(e.size(), 1u) << "bay-1 stopped more than forget_after ago";
  EXPECT_EQ(e[0].session, "bay-2");
  EXPECT_EQ(dir.stats().forgotten, 1u);
}

TEST(SessionDirectoryTest, TheStationIsConnectedWhileToolMessagesArrive) {
  SessionDirectory dir(SessionDirectoryOptions{});
  ASSERT_TRUE(dir.Process("s", Status("s", 100, 0), 0));
  EXPECT_FALSE(dir.Entries(0)[0].trainee_connected);
  ASSERT_TRUE(dir.Process("s", Status("s", 200, 900), kSecond));
  EXPECT_TRUE(dir.Entries(kSecond)[0].trainee_connected);
  ASSERT_TRUE(dir.Process("s", Status("s", 300, 900), 2 * kSecond));
  EXPECT_FALSE(dir.Entries(2 * kSecond)[0].trainee_connected) << "no tool message in the last second";
}

TEST(SessionDirectoryTest, StaleMalformedAndMismatchedStatusesAreDropped) {
  SessionDirectory dir(SessionDirectoryOptions{});
  ASSERT_TRUE(dir.Process("s", Status("s", 200), 0));
  EXPECT_FALSE(dir.Process("s", Status("s", 100), kSecond)) << "an older frame of the same server";
  EXPECT_EQ(dir.stats().stale, 1u);
  EXPECT_TRUE(dir.Process("s", Status("s", 1, 0, 8), kSecond)) << "a restarted server (new epoch) starts again";
  const std::vector<uint8_t> garbage = {0xff, 0xff, 0xff, 0x01};
  EXPECT_FALSE(dir.Process("s", garbage, kSecond));
  EXPECT_FALSE(dir.Process("t", Status("s", 300), kSecond)) << "the payload names another session than its key";
  EXPECT_EQ(dir.stats().malformed, 2u);
  EXPECT_EQ(dir.Entries(kSecond).size(), 1u);
}

TEST(SessionDirectoryTest, AFullDirectoryRefusesNewSessionsButKeepsItsOwn) {
  SessionDirectory dir(SessionDirectoryOptions{.max_sessions = 3});
  for (int i = 0; i < 10; ++i) {
    const std::string name = "s" + std::to_string(i);
    (void)dir.Process(name, Status(name, 1), 0);
  }
  EXPECT_EQ(dir.Entries(0).size(), 3u);
  EXPECT_EQ(dir.stats().refused_full, 7u);
  EXPECT_TRUE(dir.Process("s0", Status("s0", 2), kSecond)) << "a session it holds still updates";
}

TEST(SessionDirectoryTest, WithAKeyOnlySignedStatusesCount) {
  const transport::SessionKey key = transport::ParseSessionKey(std::string(64, 'a'), "test");
  SessionDirectory dir(SessionDirectoryOptions{.key = key});
  EXPECT_FALSE(dir.Process("s", Status("s", 1), 0));
  EXPECT_EQ(dir.stats().unsigned_samples, 1u);
  std::vector<uint8_t> body = Status("s", 2);
  transport::PayloadAuthenticator signer(key, std::string(transport::ObserverStreamDomain(transport::EnvelopeKind::kStatus)),
                                         "s");
  std::array<uint8_t, transport::kTrailerBytes> trailer{};
  ASSERT_TRUE(signer.MakeTrailer(body, trailer));
  std::vector<uint8_t> signed_bytes = body;
  signed_bytes.insert(signed_bytes.end(), trailer.begin(), trailer.end());
  EXPECT_TRUE(dir.Process("s", signed_bytes, 0));
  signed_bytes[3] ^= 1;  // altered after signing
  EXPECT_FALSE(dir.Process("s", signed_bytes, 0));
  EXPECT_EQ(dir.stats().forged, 1u);
  EXPECT_TRUE(dir.authenticated());
}

TEST(LabListJsonTest, EscapesStringsAndWritesNonFiniteNumbersAsNull) {
  LabSessionView v;
  v.entry.session = "bay-1";
  v.entry.live = true;
  v.entry.status.set_scene("he said \"cut\"\\\n\xc3");
  v.entry.status.set_sim_time(std::numeric_limits<double>::quiet_NaN());
  v.entry.status.set_cuts(12);
  v.entry.status.mutable_score()->set_mean_deviation(0.0015);
  const std::string json = LabListJson({v}, false);
  EXPECT_NE(json.find(R"("scene":"he said \"cut\"\\??")"), std::string::npos) << json;
  EXPECT_NE(json.find(R"("sim_time":null)"), std::string::npos) << json;
  EXPECT_NE(json.find(R"("cuts":12)"), std::string::npos) << json;
  EXPECT_NE(json.find(R"("mean_deviation":0.0015)"), std::string::npos) << json;
  EXPECT_NE(json.find(R"("metrics":null)"), std::string::npos) << json;
  for (const char c : json) EXPECT_TRUE(c >= 0x20 && c < 0x7f) << "not printable ASCII: " << static_cast<int>(c);
  EXPECT_NE(json.find(R"("trend":[])"), std::string::npos) << "no trainee, no trend: " << json;
}

TEST(LabListJsonTest, ASessionCarriesItsTraineesTrendAndNoOneElses) {
  LabSessionView ada, bob;
  ada.entry.session = "bay-1";
  ada.entry.status.set_trainee("ada");
  bob.entry.session = "bay-2";
  bob.entry.status.set_trainee("bob");
  const Trends trends = {{"ada", {{.finished_unix_s = 100, .duration = 30, .mean_deviation = 0.002},
                                  {.finished_unix_s = 200, .duration = 25, .mean_deviation = 0.001}}}};
  const std::string json = LabListJson({ada, bob}, true, trends);
  const size_t bay2 = json.find(R"("session":"bay-2")");
  ASSERT_NE(bay2, std::string::npos);
  const size_t trend = json.find(R"("trend":[{"finished":100,"duration":30,"mean_deviation":0.002)");
  EXPECT_LT(trend, bay2) << json;
  EXPECT_NE(json.find(R"({"finished":200,)"), std::string::npos) << json;
  EXPECT_NE(json.find(R"("trend":[])", bay2), std::string::npos) << "bob has no finished session: " << json;
}

TEST(ObserverChannelsTest, AClientReceivesOnlyItsSessionsMessages) {
  const test::TempPage page("lab_test", "<html>lab</html>");
  ObserverServerOptions o;
  o.files = page.files();
  o.channels = true;
  ObserverServer server(o);
  server.SetJoinMessages("", {Text("list")});
  server.SetJoinMessages("a", {Text("join-a")});
  test::WebSocketClient list, a, b, bad;
  ASSERT_TRUE(list.Open(server.port(), "/ws"));
  ASSERT_TRUE(a.Open(server.port(), "/ws?session=a"));
  ASSERT_TRUE(b.Open(server.port(), "/ws?session=b"));
  EXPECT_FALSE(bad.Open(server.port(), "/ws?session=..%2Fx")) << "not a session name";
  ASSERT_TRUE(Eventually([&] { return server.stats().clients == 3; }));
  EXPECT_EQ(server.stats().refused_channel, 1u);
  server.Broadcast("a", {Text("frame-a")});
  server.Broadcast("b", {Text("frame-b")});
  server.Broadcast("", {Text("list-2")});
  EXPECT_EQ(list.ReadData(), "list");
  EXPECT_EQ(list.ReadData(), "list-2");
  EXPECT_EQ(a.ReadData(), "join-a");
  EXPECT_EQ(a.ReadData(), "frame-a");
  EXPECT_EQ(b.ReadData(), "frame-b") << "b has no join messages and never sees a's";
  ASSERT_TRUE(Eventually([&] { return server.stats().channel_bytes.size() == 3; }));
  const auto bytes = server.stats().channel_bytes;
  EXPECT_EQ(bytes.at("a"), std::string("join-a").size() + std::string("frame-a").size());
  EXPECT_EQ(bytes.at("b"), std::string("frame-b").size());
}

}  // namespace
}  // namespace cutsim::web
