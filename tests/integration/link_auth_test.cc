// The haptic link's authentication and flood resistance with real
// processes over udpm: cutsim-haptic (scripted device, keyed) against
// cutsim-fake-haptic-server (keyed: checks tool tags, signs models), with
// this test or cutsim-lcm-flood as the attacker. ctest runs each case in its
// own private network namespace (deploy/netns-run.sh).
#include <unistd.h>

#include <chrono>
#include <cmath>
#include <csignal>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include <gtest/gtest.h>

#include "common/core/clock.h"
#include "common/transport/channels.h"
#include "common/transport/codec.h"
#include "common/transport/haptic_link.h"
#include "common/transport/lcm_bus.h"
#include "common/transport/stream_auth.h"
#include "cutsim/v1/wire.pb.h"
#include "tests/integration/subprocess.h"

namespace cutsim {
namespace {

using testing::BinPath;
using testing::JsonNumber;
using testing::Subprocess;
using testing::TempDir;
using testing::WaitForStderr;
using namespace std::chrono_literals;

constexpr char kKeyHex[] = "8f1c2e3d4a5b6c7d8e9fa0b1c2d3e4f5061728394a5b6c7d8e9fa0b1c2d3e4f5";
constexpr char kWrongKeyHex[] = "00112233445566778899aabbccddeeff00112233445566778899aabbccddeeff";
constexpr auto kReadyTimeout = 30s;
// The plane's stiffness and the tool's depth below it: a 0.26 N baseline.
constexpr double kStiffness = 1000.0;
constexpr double kDepth = 0.00026;

std::string JsonLine(const std::string& out, const std::string& kind) {
  std::istringstream lines(out);
  std::string line, found;
  while (std::getline(lines, line)) {
    if (testing::JsonString(line, "kind") == kind) found = line;
  }
  return found;
}

/// The number of `key` inside the object after `"outer":`.
double Json(const std::string& json, const std::string& outer, const std::string& key) {
  const auto at = json.find("\"" + outer + "\":");
  if (at == std::string::npos) return NAN;
  return JsonNumber(json.substr(at), key);
}

/// Force magnitudes (column 8, "f") of the client's CSV rows after `t_min`.
std::vector<double> Forces(const std::string& csv, double t_min) {
  std::ifstream in(csv);
  std::string line;
  std::getline(in, line);
  std::vector<double> f;
  while (std::getline(in, line)) {
    std::vector<double> v;
    std::stringstream ss(line);
    std::string cell;
    while (std::getline(ss, cell, ',')) v.push_back(std::stod(cell));
    if (v.size() > 7 && v[0] >= t_min) f.push_back(v[7]);
  }
  return f;
}

class LinkAuthTest : public ::testing::Test {
 protected:
  void SetUp() override {
    const int k = testing::UniqueTestIndex();
    url_ = "udpm://239.255.76.67:" + std::to_string(7950 + k % 40) + "?ttl=0";
    session_ = "la_" + std::to_string(getpid());
    key_file_ = dir_.path() + "/session.key";
    std::ofstream(key_file_) << kKeyHex << "\n";
    std::filesystem::permissions(key_file_, std::filesystem::perms::owner_read);
    const std::string path = dir_.path() + "/tool.path";
    std::ofstream(path) << "0.0  0 0 0.005  0 0 1\n0.3  0 0 " << -kDepth << "  0 0 1\n6.0  0 0 " << -kDepth
                        << "  0 0 1\n";
    path_ = path;
  }

  std::unique_ptr<Subprocess> StartServer() {
    return std::make_unique<Subprocess>(std::vector<std::string>{
        BinPath("cutsim-fake-haptic-server"), "--lcm-url", url_, "--session", session_, "--rate", "200",
        "--stiffness", std::to_string(kStiffness), "--key-file", key_file_});
  }
  std::unique_ptr<Subprocess> StartClient(const std::string& csv) {
    return std::make_unique<Subprocess>(std::vector<std::string>{
        BinPath("cutsim-haptic"), "--lcm-url", url_, "--session", session_, "--csv", csv, "--no-rt",
        "--device", "scripted", "--path", path_, "--key-file", key_file_});
  }

  TempDir dir_{"cutsim-link-auth"};
  std::string url_, session_, key_file_, path_;
};

// Forged models (another key, unsigned, replayed, and correctly signed by a
// second, older "server") sent to a running station: its force stays at the
// genuine 0.26 N and every refusal is counted. When the genuine server is
// gone and only forgeries arrive, the force fades and the station says why.
TEST_F(LinkAuthTest, ForgedModelsNeverReachTheDevice) {
  auto server = StartServer();
  ASSERT_TRUE(WaitForStderr(*server, "ready:", kReadyTimeout)) << server->Stderr();
  const std::string csv = dir_.path() + "/haptic.csv";
  auto client = StartClient(csv);
  ASSERT_TRUE(WaitForStderr(*server, "in contact for 0.5 s", kReadyTimeout)) << server->Stderr();

  transport::LcmBus bus(url_);
  const std::string channel = transport::LcmChannelName(session_, transport::LcmChannel::kModel);
  std::vector<std::vector<uint8_t>> genuine;
  auto capture = bus.SubscribeRaw(channel, 4096, [&](std::span<const uint8_t> b) {
    if (genuine.size() < 50) genuine.emplace_back(b.begin(), b.end());
  });
  const int64_t until = MonotonicNs() + 10'000'000'000;
  while (genuine.size() < 50 && MonotonicNs() < until) bus.HandleTimeout(10);
  ASSERT_EQ(genuine.size(), 50U);
  v1::HapticModel followed;
  ASSERT_TRUE(transport::DecodeInto(transport::SplitTrailer(genuine[0]).body, followed, "test"));
  ASSERT_GT(followed.epoch(), 0U);

  // The forgeries: an 8 N push with a stiff spring, 30× the baseline.
  v1::HapticModel push = followed;
  push.set_seq(followed.seq() + 100'000);
  push.mutable_f0()->set_z(8.0);
  push.set_valid_for(1.0);
  transport::PayloadAuthenticator right(transport::ParseSessionKey(kKeyHex, "t"), transport::kHapticModelDomain,
                                        session_);
  transport::PayloadAuthenticator wrong(transport::ParseSessionKey(kWrongKeyHex, "t"),
                                        transport::kHapticModelDomain, session_);
  transport::Encoder encoder;
  auto sign = [&](v1::HapticModel m, transport::PayloadAuthenticator* auth) {
    m.set_wall_ns(transport::RealtimeNowNs());
    const auto body = encoder.Encode(m);
    std::vector<uint8_t> out(body->begin(), body->end());
    if (auth != nullptr) {
      out.resize(out.size() + transport::kTrailerBytes);
      EXPECT_TRUE(auth->MakeTrailer(std::span<const uint8_t>(out.data(), body->size()),
                                    std::span<uint8_t, transport::kTrailerBytes>(out.data() + body->size(),
                                                                                 transport::kTrailerBytes)));
    }
    return out;
  };
  v1::HapticModel older = push;
  older.set_epoch(followed.epoch() - 1'000'000'000);  // a server started a second earlier
  // `with_older`: also the older server's models. Only while the genuine
  // server is alive: once it has been quiet for 0.5 s, another holder of the
  // key may take over (EpochGate), which is the protocol, not an attack.
  const auto attack_for = [&](std::chrono::milliseconds how_long, bool with_older) {
    const int64_t end = MonotonicNs() + std::chrono::nanoseconds(how_long).count();
    for (int i = 0; MonotonicNs() < end; ++i) {
      push.set_seq(push.seq() + 1);
      older.set_seq(older.seq() + 1);
      switch (i % (with_older ? 4 : 3)) {
        case 0: bus.PublishBytes(channel, sign(push, &wrong)); break;
        case 1: bus.PublishBytes(channel, sign(push, nullptr)); break;
        case 2: bus.PublishBytes(channel, genuine[static_cast<size_t>(i) % genuine.size()]); break;
        default: bus.PublishBytes(channel, sign(older, &right)); break;
      }
      std::this_thread::sleep_for(1ms);
    }
  };
  attack_for(1500ms, /*with_older=*/true);
  // The genuine server goes away; only forgeries arrive from now on.
  server->Signal(SIGTERM);
  ASSERT_EQ(server->Wait(10s), 0) << server->Stderr();
  attack_for(1500ms, /*with_older=*/false);
  const auto code = client->Wait(30s);
  ASSERT_EQ(code, 0) << client->Stderr();
  const std::string stats = JsonLine(client->Stdout(), "haptic_stats");
  ASSERT_FALSE(stats.empty()) << client->Stdout();

  // The device felt the plane, never the forgeries.
  const std::vector<double> f = Forces(csv, 0.5);
  ASSERT_GT(f.size(), 1000U);
  double max_f = 0.0;
  for (const double v : f) max_f = std::max(max_f, v);
  EXPECT_LE(max_f, kStiffness * kDepth + 0.01) << "a forged model reached the device";
  EXPECT_GE(max_f, kStiffness * kDepth - 0.01) << "the genuine model never did";
  // Every kind refused and counted.
  EXPECT_GT(Json(stats, "model_packets", "forged"), 100.0) << stats;
  EXPECT_GT(Json(stats, "model_packets", "unsigned"), 100.0) << stats;
  EXPECT_GT(Json(stats, "model_packets", "replayed"), 100.0) << stats;
  EXPECT_GT(Json(stats, "model_packets", "other_sender") + Json(stats, "model_packets", "replayed"), 200.0)
      << stats;
  EXPECT_GT(Json(stats, "model_packets", "other_sender"), 10.0) << stats;
  EXPECT_GT(Json(stats, "model_packets", "accepted"), 100.0) << stats;
  EXPECT_EQ(testing::JsonBool(stats, "models_authenticated"), true) << stats;
  EXPECT_GE(JsonNumber(stats, "watchdog_trips"), 1.0) << stats;
  const std::string err = client->Stderr();
  EXPECT_NE(err.find("are not authentic"), std::string::npos) << err;
  EXPECT_NE(err.find("two servers publish session"), std::string::npos) << err;
}

// A flood of unsigned tool messages, forged ones, garbage and fragments on
// the tool channel beside a genuine station: the station's poses keep
// reaching the server, and every flood datagram is counted under its reason.
TEST_F(LinkAuthTest, ToolFloodIsCountedAndDoesNotStarveTheStation) {
  auto server = StartServer();
  ASSERT_TRUE(WaitForStderr(*server, "ready:", kReadyTimeout)) << server->Stderr();
  auto client = StartClient(dir_.path() + "/haptic.csv");
  ASSERT_TRUE(WaitForStderr(*server, "in contact for 0.5 s", kReadyTimeout)) << server->Stderr();
  const auto flood = [&](const std::string& kind) {
    return testing::RunProcess({BinPath("cutsim-lcm-flood"), "--lcm-url", url_, "--session", session_, "--channel",
                                "tool", "--kind", kind, "--rate", "10000", "--duration", "0.8"},
                               30s);
  };
  double sent = 0.0;
  std::vector<std::string> floods;
  for (const char* kind : {"unsigned", "forged", "garbage", "fragment"}) {
    const auto r = flood(kind);
    ASSERT_EQ(r.exit_code, 0) << r.err;
    floods.push_back(JsonLine(r.out, "flood_stats"));
    sent += JsonNumber(floods.back(), "sent");
  }
  const auto code = client->Wait(30s);
  ASSERT_EQ(code, 0) << client->Stderr();
  server->Signal(SIGTERM);
  ASSERT_EQ(server->Wait(10s), 0) << server->Stderr();
  const std::string s = JsonLine(server->Stdout(), "fake_server_stats");
  ASSERT_FALSE(s.empty()) << server->Stdout();
  const auto n = [&](const char* reason) { return Json(s, "tool_packets", reason); };
  const double kernel = n("kernel_dropped");
  EXPECT_EQ(testing::JsonBool(s, "packet_level"), true) << s;
  // Each flood is under its own reason (or dropped by the kernel on a full
  // buffer, and counted there); nothing else refused anything.
  const double flood_counted = n("unsigned") + n("forged") + n("not_lcm") + n("fragment");
  EXPECT_LE(flood_counted, sent) << s;
  EXPECT_GE(flood_counted + kernel, sent) << s;
  EXPECT_GT(n("unsigned"), 0.5 * JsonNumber(floods[0], "sent")) << s;
  EXPECT_GT(n("forged"), 0.5 * JsonNumber(floods[1], "sent")) << s;
  EXPECT_GT(n("not_lcm"), 0.5 * JsonNumber(floods[2], "sent")) << s;
  EXPECT_GT(n("fragment"), 0.5 * JsonNumber(floods[3], "sent")) << s;
  EXPECT_EQ(n("decode_error") + n("foreign_session") + n("replayed") + n("invalid"), 0.0) << s;
  // The station's poses kept arriving (its 6 s path at 1 kHz).
  EXPECT_GT(n("accepted"), 1000.0) << s;
  // The client's models: the server's own, all taken or superseded.
  const std::string c = JsonLine(client->Stdout(), "haptic_stats");
  EXPECT_GT(Json(c, "model_packets", "accepted"), 100.0) << c;
  EXPECT_EQ(Json(c, "model_packets", "forged") + Json(c, "model_packets", "unsigned"), 0.0) << c;
}

}  // namespace
}  // namespace cutsim
