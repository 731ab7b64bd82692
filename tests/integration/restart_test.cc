// A server restart mid-session: the real server on the ligament
// with checkpoints, the scripted haptic client cutting it and a viewer. The
// server is killed with SIGKILL after it has cut and checkpointed, then
// started again with --resume: the haptic client fades its force and resumes,
// the viewer resyncs, and the tissue keeps its cuts. And a server killed
// right after a cut, long before its first checkpoint, comes back with the
// cut from its event journal. Runs inside its own network namespace
// (deploy/netns-run.sh).
#include <chrono>
#include <cmath>
#include <cstdio>
#include <csignal>
#include <filesystem>
#include <fstream>
#include <memory>
#include <optional>
#include <string>
#include <thread>
#include <vector>

#include <gtest/gtest.h>

#include "common/sim/checkpoint.h"
#include "tests/integration/subprocess.h"

namespace cutsim {
namespace {

using namespace std::chrono_literals;
using testing::BinPath;
using testing::JsonNumber;
using testing::ReadTextFile;
using testing::Subprocess;
using testing::TempDir;
using testing::UniqueTestIndex;
using testing::WaitUntil;

// scenes/ligament-cut.path's stroke (it cuts at ~1.5 s in most runs), then
// back across and across again (more chances if a sweep does not reach K_I
// on a loaded machine), lifted at 7 s: the server is killed once a cut is
// checkpointed, and the client is still running when the new server comes
// up. (A single 5 s stroke, at 3.2 mm/s, cut late or never.)
constexpr const char* kPath = R"(# t  tip x y z  blade dir
0.00    0.0151 -0.0080 0.0100       0 0 1
0.50    0.0151 -0.0080 -0.0060      0 0 1
2.50    0.0151 0.0080 -0.0060       0 0 1
4.50    0.0151 -0.0080 -0.0060      0 0 1
6.50    0.0151 0.0080 -0.0060       0 0 1
7.00    0.0151 0.0080 0.0100        0 0 1
)";

/// The checkpoint's topology version, or nullopt while there is none.
std::optional<uint64_t> CheckpointVersion(const std::string& path) {
  if (!std::filesystem::exists(path)) return std::nullopt;
  try {
    return sim::ReadCheckpointFile(path).topology_version();
  } catch (const std::exception&) {
    return std::nullopt;
  }
}

/// Mesh frames the server had published to a matched viewer at its latest
/// "stats:" log line, and asks for the next one (SIGUSR1; the physics loop
/// answers within a frame, so polling reads the answer to the previous ask).
double ViewerFramesWithReader(Subprocess& server) {
  server.Signal(SIGUSR1);
  const std::string err = server.Stderr();
  const auto at = err.rfind("stats: ");
  if (at == std::string::npos) return 0;
  const std::string line = err.substr(at, err.find('\n', at) - at);
  const double frames = JsonNumber(line, "viewer_frames") - JsonNumber(line, "viewer_frames_without_reader");
  return std::isfinite(frames) ? frames : 0;
}

TEST(RestartTest, KilledServerResumesTheCutTissue) {
  TempDir dir("cutsim-restart");
  const int k = UniqueTestIndex();
  const std::string session = "r" + std::to_string(k);
  const std::string lcm = "udpm://239.255.76.67:" + std::to_string(7950 + k) + "?ttl=0";
  const std::string domain = std::to_string(1 + k % 200);  // Cyclone accepts 0..230
  const std::string scene = std::string(CUTSIM_SOURCE_DIR) + "/scenes/ligament.pbtxt";
  const std::string d = dir.path();
  const std::string ckpt = d + "/ligament.ckpt";
  { std::ofstream(d + "/cut.path") << kPath; }

  auto server_argv = [&](const std::string& stats) {
    return std::vector<std::string>{BinPath("cutsim-server"), "--scene", scene, "--session", session,
                                    "--lcm-url", lcm, "--dds-domain", domain, "--checkpoint", ckpt,
                                    "--checkpoint-every", "0.2", "--resume", "--stats-json", d + "/" + stats,
                                    "--no-rt"};
  };
  auto server = std::make_unique<Subprocess>(server_argv("first.json"));
  Subprocess viewer({BinPath("cutsim-viewer"), "--session", session, "--dds-domain", domain, "--frames",
                     d + "/frames", "--exit-when-idle", "5", "--summary", d + "/viewer.json", "--fps", "5"});
  Subprocess haptic({BinPath("cutsim-haptic"), "--device", "scripted", "--path", d + "/cut.path", "--session",
                     session, "--lcm-url", lcm, "--csv", d + "/haptic.csv", "--no-rt"});

  // Kill once a checkpoint holds a cut (generous deadline: slower under ASan).
  uint64_t version_before = 0;
  (void)WaitUntil(
      [&] {
        version_before = CheckpointVersion(ckpt).value_or(0);
        return version_before >= 1;
      },
      30s, 50ms);
  ASSERT_GE(version_before, 1u) << "no cut was checkpointed before the kill\nserver:\n"
                               << server->Stderr() << "\nhaptic client:\n" << haptic.Stderr();
  server->Kill();  // SIGKILL: no final checkpoint, no goodbye
  ASSERT_TRUE(server->Wait(10s).has_value());
  const auto at_kill = CheckpointVersion(ckpt);
  ASSERT_TRUE(at_kill.has_value()) << "the checkpoint must survive a kill (atomic replace)";
  version_before = *at_kill;
  server.reset();
  // The outage itself, part of the scenario: longer than the client's
  // watchdog (100 ms), so it fades, and than the viewer's liveliness.
  std::this_thread::sleep_for(600ms);

  Subprocess restarted(server_argv("second.json"));
  ASSERT_EQ(haptic.Wait(60s), std::optional<int>(0)) << haptic.Stderr();
  // A few viewer frames from the restarted server before it stops.
  ASSERT_TRUE(WaitUntil([&] { return ViewerFramesWithReader(restarted) >= 5; }, 30s, 100ms))
      << restarted.Stderr();
  restarted.Signal(SIGTERM);        // clean exit: final checkpoint and stats
  ASSERT_EQ(restarted.Wait(30s), std::optional<int>(0)) << restarted.Stderr();
  ASSERT_EQ(viewer.Wait(30s), std::optional<int>(0)) << viewer.Stderr();

  // The restarted server resumed the cut tissue.
  EXPECT_NE(restarted.Stderr().find("resumed from checkpoint"), std::string::npos) << restarted.Stderr();
  const std::string s = ReadTextFile(d + "/second.json");
  EXPECT_GE(JsonNumber(s, "topology_version"), static_cast<double>(version_before)) << s;
  EXPECT_GT(JsonNumber(s, "tool_messages"), 5) << s;
  EXPECT_GE(CheckpointVersion(ckpt).value_or(0), version_before) << "final checkpoint at SIGTERM";

  // The haptic client noticed the restart, faded (watchdog) and resumed.
  const std::string h = haptic.Stdout();
  EXPECT_GE(JsonNumber(h, "restarts"), 1) << h;
  EXPECT_GE(JsonNumber(h, "watchdog_trips"), 1) << h;
  EXPECT_GT(JsonNumber(h, "models_accepted"), 10) << h;

  // The viewer lost the old server and resynced on the new one's snapshot,
  // every frame hash-verified.
  const std::string v = ReadTextFile(d + "/viewer.json");
  EXPECT_EQ(JsonNumber(v, "hash_mismatches"), 0) << v;
  EXPECT_GE(JsonNumber(v, "snapshots"), 2) << v;
  EXPECT_GT(JsonNumber(v, "verified_frames"), 5) << v;
  std::printf("restart_test: topology version %llu at the kill; after restart %s\nviewer %s\n",
              static_cast<unsigned long long>(version_before), s.c_str(), v.c_str());
}

/// The topology version of the server's latest "stats:" log line (0 while
/// there is none), and asks for the next one (SIGUSR1).
double ReportedTopologyVersion(Subprocess& server) {
  server.Signal(SIGUSR1);
  const std::string err = server.Stderr();
  const auto at = err.rfind("stats: ");
  if (at == std::string::npos) return 0;
  const double v = JsonNumber(err.substr(at, err.find('\n', at) - at), "topology_version");
  return std::isfinite(v) ? v : 0;
}

TEST(RestartTest, KilledRightAfterACutComesBackWithTheCut) {
  TempDir dir("cutsim-journal-restart");
  const int k = UniqueTestIndex();
  const std::string session = "j" + std::to_string(k);
  const std::string lcm = "udpm://239.255.76.67:" + std::to_string(7960 + k) + "?ttl=0";
  const std::string domain = std::to_string(1 + (k + 100) % 200);
  const std::string scene = std::string(CUTSIM_SOURCE_DIR) + "/scenes/ligament.pbtxt";
  const std::string d = dir.path();
  const std::string ckpt = d + "/ligament.ckpt";
  { std::ofstream(d + "/cut.path") << kPath; }
  // A checkpoint only every 60 s: the kill comes long before the first.
  auto server_argv = [&](std::vector<std::string> more) {
    std::vector<std::string> argv{BinPath("cutsim-server"), "--scene", scene, "--session", session,
                                  "--lcm-url", lcm, "--dds-domain", domain, "--checkpoint", ckpt,
                                  "--checkpoint-every", "60", "--resume", "--no-rt"};
    argv.insert(argv.end(), more.begin(), more.end());
    return argv;
  };
  auto server = std::make_unique<Subprocess>(server_argv({}));
  auto haptic = std::make_unique<Subprocess>(
      std::vector<std::string>{BinPath("cutsim-haptic"), "--device", "scripted", "--path", d + "/cut.path",
                               "--session", session, "--lcm-url", lcm, "--no-rt"});

  // SIGKILL as soon as the server reports a cut (asked once it handles
  // SIGUSR1: its session is up).
  ASSERT_TRUE(WaitUntil([&] { return server->Stderr().find("session '") != std::string::npos; }, 30s, 20ms))
      << server->Stderr();
  double reported = 0;
  (void)WaitUntil([&] { return (reported = ReportedTopologyVersion(*server)) >= 1; }, 30s, 20ms);
  server->Kill();
  ASSERT_GE(reported, 1) << "the server never reported a cut\nserver:\n"
                         << server->Stderr() << "\nhaptic client:\n" << haptic->Stderr();
  ASSERT_TRUE(server->Wait(10s).has_value());
  const std::string killed_log = server->Stderr();
  server.reset();
  haptic.reset();  // no more cuts: what comes back is what the killed server had
  ASSERT_FALSE(std::filesystem::exists(ckpt)) << "a checkpoint was written: the journal is not what is tested";
  ASSERT_TRUE(std::filesystem::exists(ckpt + ".journal")) << killed_log;

  Subprocess restarted(server_argv({"--duration", "0.3", "--stats-json", d + "/second.json"}));
  ASSERT_EQ(restarted.Wait(60s), std::optional<int>(0)) << restarted.Stderr();
  EXPECT_NE(restarted.Stderr().find("resumed from event journal"), std::string::npos) << restarted.Stderr();
  const std::string s = ReadTextFile(d + "/second.json");
  EXPECT_GE(JsonNumber(s, "topology_version"), reported) << s << "\n" << restarted.Stderr();
  EXPECT_GE(JsonNumber(s, "cuts"), 1) << s;
  EXPECT_EQ(JsonNumber(s, "failures"), 0) << s;  // the journal's
  std::printf("journal restart: topology version %g reported before SIGKILL; after --resume %s\n", reported,
              s.c_str());
}

}  // namespace
}  // namespace cutsim
