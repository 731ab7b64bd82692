// Record and replay. The shipped recording scenes/ligament-cut.lcm
// (a real-time session: scripted haptic client cutting the ligament over LCM)
// replays to the recorded cuts and final mesh hash, twice; a tampered
// recording is reported as a mismatch; and LCM's own tools read and write the
// format (lcm-logplayer plays it, lcm-logger records it, the copy replays).
//
// The LCM-tools case uses udpm, so ctest runs it inside a private network
// namespace (deploy/netns-run.sh); the others need no network.
#include <unistd.h>

#include <chrono>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <limits>
#include <optional>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "common/transport/codec.h"
#include "common/transport/lcm_bus.h"
#include "common/transport/lcm_log.h"
#include "cutsim/v1/wire.pb.h"
#include "tests/integration/subprocess.h"

namespace cutsim {
namespace {

using testing::BinPath;
using testing::JsonBool;
using testing::JsonNumber;
using testing::JsonString;
using testing::RunProcess;
using testing::Subprocess;
using testing::MulticastGroupJoined;
using testing::TempDir;
using testing::UdpPortBound;
using testing::WaitUntil;
using namespace std::chrono_literals;

const std::string kRecording = std::string(CUTSIM_SOURCE_DIR) + "/scenes/ligament-cut.lcm";

std::vector<transport::LcmLogEvent> ReadAll(const std::string& path) {
  transport::LcmLogReader reader(path);
  std::vector<transport::LcmLogEvent> events;
  while (auto e = reader.Next()) events.push_back(std::move(*e));
  return events;
}

template <class Msg>
Msg Parse(const transport::LcmLogEvent& e) {
  Msg m;
  EXPECT_TRUE(transport::DecodeInto(std::span<const uint8_t>(e.data), m, e.channel));
  return m;
}

bool EndsWith(const std::string& s, const std::string& suffix) {
  return s.size() >= suffix.size() && s.compare(s.size() - suffix.size(), suffix.size(), suffix) == 0;
}

/// Writes `events` to `path`, letting `edit` change each one first.
template <class Edit>
void WriteEdited(const std::vector<transport::LcmLogEvent>& events, const std::string& path, Edit edit) {
  transport::LcmLogWriter writer(path);
  for (transport::LcmLogEvent e : events) {
    edit(e);
    writer.Write(e.channel, e.data, e.timestamp_us);
  }
}

template <class Msg>
void Reencode(const Msg& m, transport::LcmLogEvent* e) {
  std::string bytes;
  m.SerializeToString(&bytes);
  e->data.assign(bytes.begin(), bytes.end());
}

testing::RunResult Replay(const std::string& path) {
  return RunProcess({BinPath("cutsim-server"), "--headless", "--replay", path, "--scene",
                     std::string(CUTSIM_SOURCE_DIR) + "/scenes/ligament.pbtxt", "--log-level", "warn"},
                    120s);
}

TEST(ReplayTest, ShippedRecordingReplaysToTheRecordedHashTwice) {
  // What the recording itself says, read independently of the server.
  const auto events = ReadAll(kRecording);
  ASSERT_GE(events.size(), 3u);
  ASSERT_TRUE(EndsWith(events.front().channel, "_REC_HEADER"));
  ASSERT_TRUE(EndsWith(events.back().channel, "_REC_END"));
  const auto end = Parse<v1::RecordEnd>(events.back());
  uint64_t cut_frames = 0;
  uint64_t tool_frames = 0;
  for (const auto& e : events) {
    if (!EndsWith(e.channel, "_REC_FRAME")) continue;
    const auto f = Parse<v1::RecordFrame>(e);
    if (f.topology_hash() != 0) ++cut_frames;
    if (f.has_tool()) ++tool_frames;
  }
  ASSERT_GE(cut_frames, 1u) << "the shipped recording should contain a cut";
  ASSERT_GT(tool_frames, 0u);
  char recorded[17];
  std::snprintf(recorded, sizeof(recorded), "%016llx", static_cast<unsigned long long>(end.mesh_hash()));

  std::string first_hash;
  for (int run = 0; run < 2; ++run) {
    const auto r = Replay(kRecording);
    ASSERT_EQ(r.exit_code, 0) << r.out << r.err;
    EXPECT_EQ(JsonBool(r.out, "match"), true) << r.out;
    EXPECT_EQ(JsonString(r.out, "mesh_hash"), std::string(recorded)) << r.out;
    EXPECT_EQ(JsonNumber(r.out, "cut_frames"), static_cast<double>(cut_frames)) << r.out;
    EXPECT_EQ(JsonNumber(r.out, "topology_version"), static_cast<double>(end.topology_version()));
    // The score against the ligament's planned incision is reproduced (the
    // replay compares every field of it and of the measures: `match`).
    ASSERT_TRUE(end.has_score()) << "the shipped recording should end with a score";
    // Read back from the JSON text: equal to 1e-9 relative (`match` holds the
    // replay to the recording's exact fields).
    EXPECT_NEAR(JsonNumber(r.out, "mean_deviation"), end.score().mean_deviation(), 1e-9 * end.score().mean_deviation()) << r.out;
    EXPECT_NEAR(JsonNumber(r.out, "peak_force"), end.metrics().peak_force(), 1e-9 * end.metrics().peak_force()) << r.out;
    EXPECT_GE(end.score().cut_points(), 1.0);
    if (run == 0) first_hash = JsonString(r.out, "mesh_hash").value_or("");
    EXPECT_EQ(JsonString(r.out, "mesh_hash"), first_hash) << "replay is not deterministic run to run";
  }
}

TEST(ReplayTest, TamperedRecordingsAreReportedAsMismatches) {
  const auto events = ReadAll(kRecording);
  TempDir dir("cutsim-replay");

  // (a) A different final hash: the whole replay runs, then the hash differs.
  const std::string bad_hash = dir.path() + "/bad-hash.lcm";
  WriteEdited(events, bad_hash, [](transport::LcmLogEvent& e) {
    if (!EndsWith(e.channel, "_REC_END")) return;
    auto end = Parse<v1::RecordEnd>(e);
    end.set_mesh_hash(end.mesh_hash() ^ 1);
    Reencode(end, &e);
  });
  auto r = Replay(bad_hash);
  EXPECT_EQ(r.exit_code, 4) << r.out << r.err;
  EXPECT_NE(r.err.find("final mesh hash"), std::string::npos) << r.err;
  EXPECT_EQ(JsonBool(r.out, "match"), false) << r.out;

  // (a') A different score: the replay's score differs, field named.
  const std::string bad_score = dir.path() + "/bad-score.lcm";
  WriteEdited(events, bad_score, [](transport::LcmLogEvent& e) {
    if (!EndsWith(e.channel, "_REC_END")) return;
    auto end = Parse<v1::RecordEnd>(e);
    end.mutable_score()->set_max_deviation(end.score().max_deviation() + 1e-3);
    Reencode(end, &e);
  });
  r = Replay(bad_score);
  EXPECT_EQ(r.exit_code, 4) << r.out << r.err;
  EXPECT_NE(r.err.find("score.max_deviation"), std::string::npos) << r.err;

  // (b) The tool kept 5 mm higher: it no longer cuts where the recording did.
  const std::string lifted = dir.path() + "/lifted.lcm";
  WriteEdited(events, lifted, [](transport::LcmLogEvent& e) {
    if (!EndsWith(e.channel, "_REC_FRAME")) return;
    auto f = Parse<v1::RecordFrame>(e);
    if (!f.has_tool()) return;
    f.mutable_tip()->set_z(f.tip().z() + 0.005);
    Reencode(f, &e);
  });
  r = Replay(lifted);
  EXPECT_EQ(r.exit_code, 4) << r.out << r.err;
  EXPECT_NE(r.err.find("a cut decision differs"), std::string::npos) << r.err;

  // (c) A truncated recording (no end event) is bad input, not a mismatch.
  const std::string truncated = dir.path() + "/truncated.lcm";
  {
    transport::LcmLogWriter writer(truncated);
    for (size_t i = 0; i + 1 < events.size() && i < 20; ++i) {
      writer.Write(events[i].channel, events[i].data, events[i].timestamp_us);
    }
  }
  r = Replay(truncated);
  EXPECT_EQ(r.exit_code, 2) << r.out << r.err;
  EXPECT_NE(r.err.find("no end event"), std::string::npos) << r.err;
}

// Hostile recordings are bad input (exit 2, the file and event named), never
// a hang, a crash or a match: absurd frame times, a 2 GB event length, an
// absurd thread count, a scene that is a device.
TEST(ReplayTest, HostileRecordingsAreRefusedNamingTheEvent) {
  const auto events = ReadAll(kRecording);
  TempDir dir("cutsim-replay-hostile");
  for (const double t : {std::numeric_limits<double>::quiet_NaN(), -0.01, 0.0, 1e300}) {
    const std::string path = dir.path() + "/frame-time.lcm";
    bool edited = false;
    WriteEdited(events, path, [&](transport::LcmLogEvent& e) {
      if (edited || !EndsWith(e.channel, "_REC_FRAME")) return;
      auto f = Parse<v1::RecordFrame>(e);
      f.set_frame_time(t);
      Reencode(f, &e);
      edited = true;
    });
    const auto r = Replay(path);
    EXPECT_EQ(r.exit_code, 2) << t << ": " << r.out << r.err;
    EXPECT_NE(r.err.find("RecordFrame.frame_time"), std::string::npos) << t << ": " << r.err;
    EXPECT_EQ(r.out.find("\"match\":true"), std::string::npos) << r.out;
  }
  {
    const std::string path = dir.path() + "/threads.lcm";
    WriteEdited(events, path, [&](transport::LcmLogEvent& e) {
      if (!EndsWith(e.channel, "_REC_HEADER")) return;
      auto h = Parse<v1::RecordHeader>(e);
      h.set_threads(70000);
      Reencode(h, &e);
    });
    const auto r = Replay(path);
    EXPECT_EQ(r.exit_code, 2) << r.out << r.err;
    EXPECT_NE(r.err.find("RecordHeader.threads"), std::string::npos) << r.err;
  }
  {
    // The second event claims 2 GB of data.
    const std::string path = dir.path() + "/huge-event.lcm";
    WriteEdited(events, path, [](transport::LcmLogEvent&) {});
    std::string bytes;
    {
      std::ifstream in(path, std::ios::binary);
      bytes.assign(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
    }
    const size_t second = 28 + events[0].channel.size() + events[0].data.size();
    for (int i = 0; i < 4; ++i) bytes[second + 24 + static_cast<size_t>(i)] = i == 0 ? '\x7f' : '\xff';
    std::ofstream(path, std::ios::binary | std::ios::trunc) << bytes;
    const auto r = Replay(path);
    EXPECT_EQ(r.exit_code, 2) << r.out << r.err;
    EXPECT_NE(r.err.find("event 1"), std::string::npos) << r.err;
    EXPECT_NE(r.err.find("2147483647"), std::string::npos) << r.err;
  }
  {
    const auto r = RunProcess({BinPath("cutsim-server"), "--headless", "--replay", kRecording, "--scene", "/dev/zero",
                               "--log-level", "warn"},
                              60s);
    EXPECT_EQ(r.exit_code, 2) << r.out << r.err;
    EXPECT_NE(r.err.find("only regular files"), std::string::npos) << r.err;
  }
}

// lcm-logplayer (Debian liblcm-bin) plays the recording on udpm; lcm-logger
// records it; the copy has the same events and replays to the same hash.
TEST(ReplayTest, LcmLoggerAndLogplayerReadAndWriteTheFormat) {
  if (std::system("command -v lcm-logger >/dev/null && command -v lcm-logplayer >/dev/null") != 0) {
    GTEST_SKIP() << "lcm-logger/lcm-logplayer not installed (Debian package liblcm-bin)";
  }
  TempDir dir("cutsim-replay-lcm");
  const int port = 7990 + testing::UniqueTestIndex() % 9;
  const std::string url = "udpm://239.255.76.67:" + std::to_string(port) + "?ttl=0";
  const std::string copy = dir.path() + "/copy.lcm";
  // Inside the test's private network namespace only the logger binds the
  // port and joins the group: once it has both, it receives what the player
  // sends.
  ASSERT_FALSE(UdpPortBound(port)) << "port " << port << " already in use";
  Subprocess logger({"/usr/bin/lcm-logger", "--lcm-url=" + url, "-q", "-f", "--flush-interval=10", copy});
  ASSERT_TRUE(WaitUntil([&] { return UdpPortBound(port) && MulticastGroupJoined("239.255.76.67"); }, 30s))
      << logger.Stderr();
  const auto played =
      RunProcess({"/usr/bin/lcm-logplayer", "--lcm-url=" + url, "--speed=4", kRecording}, 60s);
  ASSERT_EQ(played.exit_code, 0) << played.err;
  // Until every event is on disk: the logger flushes when it writes an event
  // after its flush interval, so a marker on a channel of its own, sent every
  // 20 ms, pushes the tail of the recording out (the replay ignores it).
  const auto original = ReadAll(kRecording);
  const std::string marker = "REPLAY_TEST_MARKER";
  const auto recorded = [&] {
    std::vector<transport::LcmLogEvent> events;
    if (!std::filesystem::exists(copy)) return events;
    for (auto& e : ReadAll(copy)) {
      if (e.channel != marker) events.push_back(std::move(e));
    }
    return events;
  };
  transport::LcmBus bus(url);
  const std::vector<uint8_t> nothing = {0};
  ASSERT_TRUE(WaitUntil(
      [&] {
        bus.PublishBytes(marker, nothing);
        return recorded().size() >= original.size();
      },
      30s, 20ms))
      << recorded().size() << " of " << original.size() << " events recorded; logger: " << logger.Stderr();
  logger.Signal(SIGINT);
  ASSERT_TRUE(logger.Wait(10s).has_value());

  const auto copied = recorded();
  ASSERT_EQ(copied.size(), original.size()) << "events lost on loopback";
  for (size_t i = 0; i < original.size(); ++i) {
    EXPECT_EQ(copied[i].channel, original[i].channel) << "event " << i;
    EXPECT_EQ(copied[i].data, original[i].data) << "event " << i;
  }
  const auto r = Replay(copy);
  EXPECT_EQ(r.exit_code, 0) << r.out << r.err;
}

}  // namespace
}  // namespace cutsim
