// Observers end to end: cutsim-fake-mesh-server (standing in for the server's
// real-time mode) publishes a poked and cut box over loopback DDS, real
// cutsim-viewer processes join it (one late, one killed and restarted), and
// we check their hashes against the publisher's log and their PNG frames.
// Each test uses its own DDS domain id; the default (loopback) config keeps
// every packet on 127.0.0.1, which the last test checks on the sockets.

#include <dirent.h>
#include <signal.h>
#include <unistd.h>

#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <map>
#include <regex>
#include <set>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include <gtest/gtest.h>

#include "common/core/clock.h"
#include "common/render/image.h"
#include "tests/integration/subprocess.h"

namespace cutsim::testing {
namespace {

using namespace std::chrono_literals;

std::string Domain(int offset = 0) { return std::to_string((UniqueTestIndex() + offset) % 200 + 1); }

std::string ReadFile(const std::string& path) {
  std::ifstream in(path);
  std::stringstream s;
  s << in.rdbuf();
  return s.str();
}

/// A number field of a flat JSON object (our summaries); NaN if missing.
double JsonNumber(const std::string& json, const std::string& key) {
  const std::regex re("\"" + key + "\":\\s*(-?[0-9.eE+-]+)");
  std::smatch m;
  if (!std::regex_search(json, m, re)) return std::nan("");
  return std::stod(m[1]);
}

struct PublishedFrame {
  std::string hash;
  int64_t mono_ns;
  double sim_time;
};
/// The fake server's --hash-log: seq → (hash, when, sim time).
std::map<uint64_t, PublishedFrame> ReadPublisherLog(const std::string& path) {
  std::map<uint64_t, PublishedFrame> out;
  std::ifstream in(path);
  uint64_t seq = 0;
  PublishedFrame f;
  while (in >> seq >> f.hash >> f.mono_ns >> f.sim_time) out[seq] = f;
  return out;
}

struct RenderedFrame {
  int index;
  uint64_t seq;
  std::string hash;
  double sim_time;
  int64_t mono_ns;
};
std::vector<RenderedFrame> ReadFrameLog(const std::string& path) {
  std::vector<RenderedFrame> out;
  std::ifstream in(path);
  RenderedFrame f{};
  while (in >> f.index >> f.seq >> f.hash >> f.sim_time >> f.mono_ns) out.push_back(f);
  return out;
}

/// Simulated time of the latest frame in a viewer's frame log (-1 if none).
double LatestSimTime(const std::string& path) {
  const std::vector<RenderedFrame> frames = ReadFrameLog(path);
  return frames.empty() ? -1.0 : frames.back().sim_time;
}

std::string FramePath(const std::string& dir, int index) {
  char name[32];
  std::snprintf(name, sizeof name, "frame_%06d.png", index);
  return dir + "/" + name;
}

std::vector<std::string> ViewerArgs(const std::string& session, const std::string& domain,
                                    const std::string& dir, const std::string& tag) {
  return {BinPath("cutsim-viewer"), "--session", session, "--dds-domain", domain,
          "--frames", dir + "/" + tag + "_frames", "--frame-log", dir + "/" + tag + ".log",
          "--summary", dir + "/" + tag + ".json", "--exit-when-idle", "2", "--fps", "10",
          "--log-level", "warn"};
}

/// Every frame a viewer rendered is a state the publisher sent (same seq, same hash).
void ExpectFramesMatchPublisher(const std::vector<RenderedFrame>& frames,
                                const std::map<uint64_t, PublishedFrame>& published,
                                const std::string& tag) {
  for (const RenderedFrame& f : frames) {
    const auto it = published.find(f.seq);
    ASSERT_NE(it, published.end()) << tag << " frame " << f.index << " seq " << f.seq << " never published";
    EXPECT_EQ(it->second.hash, f.hash) << tag << " frame " << f.index << " seq " << f.seq;
  }
}

TEST(ViewerStreamTest, TwoViewersOneLateSeeTheServersMeshAndTheCut) {
  TempDir dir("viewer_it");
  const std::string domain = Domain();
  const std::string session = "it_" + std::to_string(getpid());
  const double cut_at = 4.0;
  Subprocess server({BinPath("cutsim-fake-mesh-server"), "--session", session, "--dds-domain", domain,
                     "--duration", "9", "--cut-at", std::to_string(cut_at), "--rate", "20",
                     "--hash-log", dir.path() + "/pub.log", "--log-level", "warn"});
  Subprocess early(ViewerArgs(session, domain, dir.path(), "early"));
  // The late viewer joins once the early one has rendered 2 s of the stream
  // (the publisher's keyframe is then older than its current mesh).
  ASSERT_TRUE(WaitUntil([&] { return LatestSimTime(dir.path() + "/early.log") >= 2.0; }, 60s))
      << early.Stderr() << server.Stderr();
  const int64_t late_start_ns = MonotonicNs();
  Subprocess late(ViewerArgs(session, domain, dir.path(), "late"));

  EXPECT_EQ(server.Wait(60s), 0) << server.Stderr();
  EXPECT_EQ(early.Wait(30s), 0) << early.Stderr();
  EXPECT_EQ(late.Wait(30s), 0) << late.Stderr();

  const auto published = ReadPublisherLog(dir.path() + "/pub.log");
  ASSERT_GT(published.size(), 100U);
  for (const std::string tag : {"early", "late"}) {
    SCOPED_TRACE(tag);
    const std::string json = ReadFile(dir.path() + "/" + tag + ".json");
    ASSERT_FALSE(json.empty()) << "no summary";
    std::printf("viewer_stream_test: %s viewer summary: %s\n", tag.c_str(), json.c_str());
    EXPECT_EQ(JsonNumber(json, "hash_mismatches"), 0);
    EXPECT_EQ(JsonNumber(json, "resyncs"), 0);
    EXPECT_GE(JsonNumber(json, "frames"), tag == std::string("early") ? 50 : 35);
    EXPECT_GT(JsonNumber(json, "bytes_received"), 0);
    const auto frames = ReadFrameLog(dir.path() + "/" + tag + ".log");
    EXPECT_EQ(static_cast<double>(frames.size()), JsonNumber(json, "frames"));
    ExpectFramesMatchPublisher(frames, published, tag);
  }

  // The late joiner's first frame is the publisher's current mesh, not an
  // old keyframe: no older than what the publisher had sent when it started.
  const auto late_frames = ReadFrameLog(dir.path() + "/late.log");
  ASSERT_FALSE(late_frames.empty());
  uint64_t current_at_join = 0;
  for (const auto& [seq, f] : published) {
    if (f.mono_ns <= late_start_ns) current_at_join = seq;
  }
  EXPECT_GE(late_frames.front().seq, current_at_join);
  const double join_s = 1e-9 * static_cast<double>(late_frames.front().mono_ns - late_start_ns);
  std::printf("viewer_stream_test: late join: first verified frame %.3f s after the viewer process started\n", join_s);
  EXPECT_LT(join_s, 3.0);  // process start-up + discovery + first tick (target 0.5 s in release)

  // Pixels: the object covers ≥ 5 %; cut colour only after the cut; frames
  // after the cut differ from those before.
  const auto frames = ReadFrameLog(dir.path() + "/early.log");
  const std::string fdir = dir.path() + "/early_frames";
  int before = 0, after = 0;
  render::Image last_before;
  double max_diff = 0;
  for (const RenderedFrame& f : frames) {
    const render::Image img = render::ReadPng(FramePath(fdir, f.index));
    EXPECT_GE(render::NonBackgroundFraction(img), 0.05) << "frame " << f.index;
    const int64_t cut_pixels = render::CountCutFacePixels(img);
    if (f.sim_time < cut_at) {
      EXPECT_EQ(cut_pixels, 0) << "cut colour before the cut, frame " << f.index;
      last_before = img;
      ++before;
    } else if (f.sim_time > cut_at + 0.6) {  // the cut has opened
      EXPECT_GT(cut_pixels, 100) << "no cut colour after the cut, frame " << f.index;
      if (last_before.valid()) max_diff = std::max(max_diff, render::MeanAbsoluteDifference(last_before, img));
      ++after;
    }
  }
  EXPECT_GE(before, 20);
  EXPECT_GE(after, 20);
  EXPECT_GT(max_diff, 1.0);
}

TEST(ViewerStreamTest, KilledViewerRejoinsAndSigtermWritesTheSummary) {
  TempDir dir("viewer_it");
  const std::string domain = Domain(1);
  const std::string session = "rj_" + std::to_string(getpid());
  Subprocess server({BinPath("cutsim-fake-mesh-server"), "--session", session, "--dds-domain", domain,
                     "--duration", "8", "--cut-at", "2", "--hash-log", dir.path() + "/pub.log",
                     "--log-level", "warn"});
  {
    Subprocess first(ViewerArgs(session, domain, dir.path(), "first"));
    // Killed while watching: after it has rendered a few frames.
    ASSERT_TRUE(WaitUntil([&] { return CountLines(dir.path() + "/first.log") >= 3; }, 60s)) << first.Stderr();
    first.Kill();  // SIGKILL: no goodbye to DDS
  }
  Subprocess again(ViewerArgs(session, domain, dir.path(), "again"));
  // Stopped once it has rendered the frames the check below needs.
  ASSERT_TRUE(WaitUntil([&] { return CountLines(dir.path() + "/again.log") >= 15; }, 60s)) << again.Stderr();
  again.Signal(SIGTERM);
  EXPECT_EQ(again.Wait(20s), 0) << again.Stderr();
  EXPECT_EQ(server.Wait(30s), 0) << server.Stderr();
  const std::string json = ReadFile(dir.path() + "/again.json");
  ASSERT_FALSE(json.empty()) << again.Stderr();
  EXPECT_EQ(testing::JsonString(json, "exit_reason"), "signal") << json;
  EXPECT_EQ(JsonNumber(json, "hash_mismatches"), 0);
  EXPECT_GE(JsonNumber(json, "frames"), 15);
  EXPECT_NE(again.Stderr().find("summary:"), std::string::npos);  // logged on stderr too
  ExpectFramesMatchPublisher(ReadFrameLog(dir.path() + "/again.log"),
                             ReadPublisherLog(dir.path() + "/pub.log"), "again");
}

TEST(ViewerStreamTest, VideoOrAClearErrorAndBadFlags) {
  TempDir dir("viewer_it");
  const bool have_ffmpeg = std::system("command -v ffmpeg > /dev/null 2>&1") == 0;
  const std::string domain = Domain(2);
  const std::string session = "vid_" + std::to_string(getpid());
  if (have_ffmpeg) {
    Subprocess server({BinPath("cutsim-fake-mesh-server"), "--session", session, "--dds-domain",
                       domain, "--duration", "4", "--cut-at", "1", "--log-level", "warn"});
    const auto r = RunProcess({BinPath("cutsim-viewer"), "--session", session, "--dds-domain", domain,
                               "--video", dir.path() + "/out.mp4", "--max-frames", "15",
                               "--width", "320", "--height", "240"},
                              60s);
    EXPECT_EQ(r.exit_code, 0) << r.err;
    EXPECT_GT(std::filesystem::file_size(dir.path() + "/out.mp4"), 1000U);
    server.Kill();
  } else {
    const auto r = RunProcess({BinPath("cutsim-viewer"), "--video", dir.path() + "/out.mp4"}, 20s);
    EXPECT_EQ(r.exit_code, 2);
    EXPECT_NE(r.err.find("ffmpeg"), std::string::npos) << r.err;
  }
  auto bad = RunProcess({BinPath("cutsim-viewer"), "--eye", "1,2"}, 20s);
  EXPECT_EQ(bad.exit_code, 2);
  EXPECT_NE(bad.err.find("--eye"), std::string::npos) << bad.err;
  bad = RunProcess({BinPath("cutsim-viewer"), "--session", "no spaces"}, 20s);
  EXPECT_EQ(bad.exit_code, 2);
  EXPECT_NE(bad.err.find("--session"), std::string::npos) << bad.err;
}

/// Local IPv4 address (hex, as in /proc/net/udp) of every UDP socket `pid` holds.
std::vector<std::string> UdpLocalAddresses(pid_t pid) {
  std::set<std::string> inodes;
  const std::string fd_dir = "/proc/" + std::to_string(pid) + "/fd";
  for (const auto& e : std::filesystem::directory_iterator(fd_dir)) {
    std::error_code ec;
    const auto target = std::filesystem::read_symlink(e.path(), ec).string();
    if (target.rfind("socket:[", 0) == 0) inodes.insert(target.substr(8, target.size() - 9));
  }
  std::vector<std::string> out;
  for (const char* table : {"udp", "udp6"}) {
    std::ifstream in("/proc/" + std::to_string(pid) + "/net/" + table);
    std::string line;
    std::getline(in, line);  // header
    while (std::getline(in, line)) {
      std::istringstream s(line);
      std::string sl, local, remote, st, queues, tr, retr, uid, timeout, inode;
      s >> sl >> local >> remote >> st >> queues >> tr >> retr >> uid >> timeout >> inode;
      if (inodes.count(inode) != 0) out.push_back(local.substr(0, local.find(':')));
    }
  }
  return out;
}

TEST(ViewerStreamTest, DefaultConfigKeepsEveryPacketOnLoopback) {
  const std::string domain = Domain(3);
  const std::string session = "lo_" + std::to_string(getpid());
  Subprocess server({BinPath("cutsim-fake-mesh-server"), "--session", session, "--dds-domain", domain,
                     "--duration", "4", "--log-level", "warn"});
  TempDir dir("viewer_it");
  Subprocess viewer({BinPath("cutsim-viewer"), "--session", session, "--dds-domain", domain,
                     "--duration", "3", "--frame-log", dir.path() + "/lo.log", "--log-level", "warn"});
  // Discovery is done (every socket open) once the viewer has rendered a frame.
  ASSERT_TRUE(WaitUntil([&] { return CountLines(dir.path() + "/lo.log") >= 1; }, 60s)) << viewer.Stderr();
  for (const pid_t pid : {server.pid(), viewer.pid()}) {
    const auto addrs = UdpLocalAddresses(pid);
    EXPECT_FALSE(addrs.empty());
    for (const std::string& a : addrs) {
      // 127.0.0.1 (transmit) or the wildcard (Cyclone 0.10 binds receive
      // sockets to it); never a real interface's address.
      EXPECT_TRUE(a == "0100007F" || a == "00000000" || a == std::string(32, '0'))
          << "pid " << pid << " has a UDP socket on " << a;
    }
    // No multicast group joined on any interface (SPDP would be 239.255.0.1).
    const std::string igmp = ReadFile("/proc/" + std::to_string(pid) + "/net/igmp");
    EXPECT_EQ(igmp.find("0100FFEF"), std::string::npos) << igmp;
  }
  EXPECT_EQ(viewer.Wait(20s), 0) << viewer.Stderr();
  EXPECT_EQ(server.Wait(20s), 0) << server.Stderr();
}

}  // namespace
}  // namespace cutsim::testing
