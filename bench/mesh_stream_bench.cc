// The observers' mesh stream on an in-process loopback DDS domain (JSON on
// stdout, and --json FILE):
//
//  (a) "bytes": payload of the joining snapshot of a 24 576-tet box (16³
//      cells, 10 cm), of the delta after a local poke (2 cm wide, 3 mm
//      deep), after a plane cut half-way down, and of an unchanged frame;
//  (b) "late_join": seconds from a subscriber's creation to a verified
//      current mesh, 20 ms frames, the retained keyframe 20 frames old;
//  (c) "encode": PublishFrame time per frame (fill included) and the
//      diff + encode + write part, with 0, 1 and 4 readers.
//
// Targets (in "targets", exit code 1 when one is missed): a poke delta at
// most 10 % of a snapshot, an unchanged frame under 64 bytes, a late join
// under 2 s.
//
//   mesh_stream_bench [--json FILE] [--dds-domain N] [--frames 30]
#include <unistd.h>

#include <chrono>
#include <cstdio>
#include <fstream>
#include <limits>
#include <memory>
#include <string>
#include <vector>

#include <CLI/CLI.hpp>
#include <fmt/format.h>

#include "bench/json_text.h"
#include "common/core/clock.h"
#include "common/core/log.h"
#include "common/transport/dds.h"
#include "common/transport/mesh_stream.h"
#include "tests/support/fake_mesh.h"

namespace cutsim::bench {
namespace {

using namespace std::chrono_literals;
using support::FakeMesh;
using transport::DdsParticipant;
using transport::MeshFrame;
using transport::MeshStreamPublisher;
using transport::MeshStreamSubscriber;

constexpr int64_t kReaderWaitNs = 5'000'000'000LL;

std::string SessionName(const char* part) { return fmt::format("msb{}_{}", ::getpid(), part); }

/// Polls `sub` until `pub` sees a matched reader (or 5 s pass).
void WaitForReader(const MeshStreamPublisher& pub, MeshStreamSubscriber& sub) {
  const int64_t deadline = MonotonicNs() + kReaderWaitNs;
  while (!pub.HasReaders() && MonotonicNs() < deadline) sub.Poll(10ms);
}

struct Bytes {
  uint64_t snapshot = 0, poke = 0, cut = 0, unchanged = 0;
  int64_t nodes = 0, tets = 0;
};

Bytes MeasureBytes(DdsParticipant& participant) {
  const std::string session = SessionName("bytes");
  MeshStreamPublisher pub(participant, session, {.keyframe_interval_s = 0});
  MeshStreamSubscriber sub(participant, session);
  WaitForReader(pub, sub);
  FakeMesh m(16);
  const auto publish = [&] {
    pub.PublishFrame([&](MeshFrame& f) { m.Fill(f); });
    sub.Poll(5ms);
  };
  Bytes b;
  b.tets = m.tets.rows();
  publish();
  b.snapshot = pub.stats().last_snapshot_bytes;
  m.Poke({0.05, 0.05, 0.1}, 0.02, 0.003);
  publish();
  b.poke = pub.stats().last_delta_bytes;
  m.Cut(0.05, 0.05);
  publish();
  b.cut = pub.stats().last_delta_bytes;
  m.frame += 1;
  publish();
  b.unchanged = pub.stats().last_delta_bytes;
  b.nodes = m.rest.rows();
  return b;
}

/// Seconds from a late subscriber's creation to a verified current mesh
/// (negative if it never became current within the deadline).
double MeasureLateJoin(DdsParticipant& participant) {
  const std::string session = SessionName("late");
  MeshStreamPublisher pub(participant, session, {.keyframe_interval_s = 60});
  FakeMesh m(6);
  MeshStreamSubscriber first(participant, session);
  int i = 0;
  const auto step = [&] {
    ++i;
    m.frame = static_cast<uint64_t>(i);
    m.Poke({0.05, 0.05, 0.1}, 0.04, 0.001 * (i % 7));
    pub.PublishFrame([&](MeshFrame& f) { m.Fill(f); });
  };
  const int64_t first_deadline = MonotonicNs() + kReaderWaitNs;
  while (!first.current() && MonotonicNs() < first_deadline) {
    step();
    first.Poll(20ms);
  }
  if (!first.current()) return -1.0;
  for (int k = 0; k < 20; ++k) step();  // the retained keyframe is now 20 frames old
  const int64_t join_ns = MonotonicNs();
  MeshStreamSubscriber late(participant, session);
  const int64_t deadline = join_ns + 2 * kReaderWaitNs;
  while (MonotonicNs() < deadline) {
    step();
    first.Poll(0ns);
    late.Poll(20ms);
    if (late.current()) return 1e-9 * static_cast<double>(MonotonicNs() - join_ns);
  }
  return -1.0;
}

struct EncodeCost {
  int readers = 0;
  double publish_ms = 0;  ///< PublishFrame per frame, fill included.
  double encode_ms = 0;   ///< Diff + encode + write per frame.
};

EncodeCost MeasureEncode(DdsParticipant& participant, int readers, int frames) {
  FakeMesh m(16);
  const std::string session = SessionName(("encode" + std::to_string(readers)).c_str());
  MeshStreamPublisher pub(participant, session, {.keyframe_interval_s = 0});
  std::vector<std::unique_ptr<MeshStreamSubscriber>> subs;
  for (int r = 0; r < readers; ++r) subs.push_back(std::make_unique<MeshStreamSubscriber>(participant, session));
  if (readers > 0) WaitForReader(pub, *subs[0]);
  int64_t total_ns = 0;
  for (int i = 0; i < frames + 1; ++i) {
    m.Poke({0.05, 0.05, 0.1}, 0.03, 0.0001 * i);
    const int64_t t0 = MonotonicNs();
    pub.PublishFrame([&](MeshFrame& f) { m.Fill(f); });
    if (i > 0) total_ns += MonotonicNs() - t0;  // frame 0 is the joining snapshot
    for (auto& s : subs) s->Poll(0ns);
  }
  return {readers, 1e-6 * static_cast<double>(total_ns) / frames,
          1e-6 * static_cast<double>(pub.stats().encode_ns) / (frames + 1)};
}

int Main(int argc, char** argv) {
  std::string json_path;
  uint32_t domain = 1 + static_cast<uint32_t>(::getpid()) % 200;
  int frames = 30;
  CLI::App app{"mesh stream: delta vs snapshot bytes, late join, encode cost"};
  app.add_option("--json", json_path, "Also write the JSON here");
  app.add_option("--dds-domain", domain, "DDS domain id (default: from the pid)")
      ->check(CLI::Range(0u, transport::kMaxDdsDomainId));
  app.add_option("--frames", frames, "Frames per encode-cost run")->check(CLI::Range(1, 100000));
  CLI11_PARSE(app, argc, argv);
  InitLogging("mesh_stream_bench", "warn");

  DdsParticipant participant(domain);
  const Bytes b = MeasureBytes(participant);
  const double late_join_s = MeasureLateJoin(participant);
  std::vector<EncodeCost> encode;
  for (const int readers : {0, 1, 4}) encode.push_back(MeasureEncode(participant, readers, frames));

  const double poke_fraction = static_cast<double>(b.poke) / static_cast<double>(b.snapshot);
  const double cut_fraction = static_cast<double>(b.cut) / static_cast<double>(b.snapshot);
  std::vector<std::string> missed;
  if (!(poke_fraction <= 0.10)) missed.push_back(fmt::format("poke delta {:.2f} % of a snapshot > 10 %", 100 * poke_fraction));
  if (!(b.unchanged < 64)) missed.push_back(fmt::format("unchanged frame {} bytes >= 64", b.unchanged));
  if (!(late_join_s >= 0 && late_join_s < 2.0)) missed.push_back(fmt::format("late join {:.3f} s, not in [0, 2)", late_join_s));

  std::string json = fmt::format(
      "{{\n  \"bytes\": {{\"nodes\": {}, \"tets\": {}, \"snapshot\": {}, \"poke_delta\": {}, \"poke_fraction\": {:.4g}, "
      "\"cut_delta\": {}, \"cut_fraction\": {:.4g}, \"unchanged_frame\": {}}},\n"
      "  \"late_join\": {{\"frame_interval_s\": 0.02, \"seconds\": {:.4g}}},\n  \"encode\": [",
      b.nodes, b.tets, b.snapshot, b.poke, poke_fraction, b.cut, cut_fraction, b.unchanged,
      late_join_s >= 0 ? late_join_s : std::numeric_limits<double>::quiet_NaN());
  for (size_t i = 0; i < encode.size(); ++i) {
    json += fmt::format("{}\n    {{\"readers\": {}, \"frames\": {}, \"publish_ms_per_frame\": {:.4g}, "
                        "\"encode_ms_per_frame\": {:.4g}}}",
                        i == 0 ? "" : ",", encode[i].readers, frames, encode[i].publish_ms, encode[i].encode_ms);
  }
  json += fmt::format(
      "\n  ],\n  \"targets\": {{\"poke_fraction_max\": 0.1, \"unchanged_frame_bytes_max\": 63, "
      "\"late_join_s_max\": 2.0, \"pass\": {}}}\n}}\n",
      missed.empty() ? "true" : "false");
  json = NullNonFinite(json);
  std::fputs(json.c_str(), stdout);
  if (!json_path.empty()) std::ofstream(json_path) << json;
  return ExitCodeForTargets("mesh_stream_bench", missed);
}

}  // namespace
}  // namespace cutsim::bench

int main(int argc, char** argv) { return cutsim::bench::Main(argc, argv); }
