// Skip table, session level: what each piece of work a scene or a
// session may not need costs per physics frame, each measured against the
// same scene with that work forced on, in the same process, in alternating
// rounds (the machine is noisy: ratios from one run, medians of rounds).
//
//   tool        no tool in the scene  vs  a tool hovering 5 mm above the
//               surface (contact query every frame, cutting enabled; at 1–3 mm
//               the ligament's slanted facet beside the top counted as a
//               touch, see tool_contact.cc case 2, so the row checks it)
//   contact     no tool               vs  the tool pressing 0.5 mm into the
//               surface (penalty force every substep, the stress criterion
//               evaluated every frame; K_I out of reach so nothing cuts)
//   criterion   tool pressing, cutting disabled  vs  enabled (the stress
//               eigen-solves and cut-attempt bookkeeping alone)
//   haptic      tool pressing, no client  vs  a local model built per frame
//               as the real-time server does (tool report, contact
//               stiffness, BuildLocalModel, protobuf encode)
//   viewer      no reader matched  vs  one viewer matched over DDS
//               (loopback, in-process reader), a mesh frame at the server's
//               default 10 Hz: fill + diff + encode + write
//
// Force-pass skips (damping, gravity, fixed nodes) are kernel-level and live
// in fem_bench's BM_Skip. Times are the server thread's CPU time
// (CLOCK_THREAD_CPUTIME_ID: time descheduled by other load is not counted;
// these scenes step on one thread below 20k tets), and the substeps per
// frame are reported beside them because a variant can change the step.
//
// Each forced-on variant states the state it measures ("tool_touching",
// "viewer_frames_received"): a pressing tool that does not touch, a hovering
// one that does, or a viewer row whose viewer received nothing makes the
// row's numbers meaningless, and the exit code 1.
//
//   skip_bench [--scene-dir scenes] [--rounds 7] [--frames 100] [--filter TEXT] [--json FILE]
#include <time.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <functional>
#include <memory>
#include <string>
#include <vector>

#include <CLI/CLI.hpp>
#include <fmt/format.h>

#include "bench/json_text.h"
#include "common/core/clock.h"
#include "common/core/log.h"
#include "common/haptics/local_model.h"
#include "common/sim/scene_loader.h"
#include "common/sim/simulation.h"
#include "common/transport/dds.h"
#include "common/transport/haptic_link.h"
#include "common/transport/mesh_stream.h"
#include "cutsim/v1/wire.pb.h"

namespace {

using cutsim::MonotonicNs;
using cutsim::sim::Simulation;
using cutsim::sim::ToolPose;
using Eigen::Vector3d;

int64_t ThreadCpuNs() {
  timespec ts{};
  clock_gettime(CLOCK_THREAD_CPUTIME_ID, &ts);
  return int64_t{ts.tv_sec} * 1'000'000'000 + ts.tv_nsec;
}

double Median(std::vector<double> v) {
  std::sort(v.begin(), v.end());
  const size_t n = v.size();
  return n == 0 ? 0.0 : (n % 2 ? v[n / 2] : 0.5 * (v[n / 2 - 1] + v[n / 2]));
}

/// Where the tool sits in a variant: none (the scene's tool removed), above
/// the surface, or pressed into it.
enum class ToolUse { kNone, kHover, kPress };
constexpr double kHoverHeight = 5e-3;  // m above the top point

struct Variant {
  ToolUse tool = ToolUse::kNone;
  bool cutting = true;
  bool haptic_model = false;
  bool viewer = false;
};

struct Scene {
  std::string name;
  cutsim::sim::LoadedScene loaded;
  Vector3d top_point;  ///< m, a point on the top surface the tool goes to
};

/// One simulation set up for a variant, and the per-frame work around it.
class Runner {
 public:
  Runner(const Scene& scene, const Variant& v, cutsim::transport::DdsParticipant* participant,
         const std::string& session)
      : v_(v) {
    cutsim::sim::LoadedScene loaded = scene.loaded;
    auto& s = loaded.scene;
    if (v.tool == ToolUse::kNone) {
      s.clear_tool();
      s.clear_cutting();
    } else {
      s.mutable_tool()->clear_path_file();
      s.mutable_tool()->clear_keyframes();
      s.mutable_cutting()->set_enabled(v.cutting);
      // Out of reach: the criterion is evaluated, nothing cuts, every frame
      // is the same work.
      s.mutable_cutting()->set_critical_stress(1e30);
    }
    sim_ = Simulation::Create(loaded);
    if (v.tool != ToolUse::kNone) {
      ToolPose pose;
      pose.tip = scene.top_point + Vector3d(0, 0, v.tool == ToolUse::kHover ? kHoverHeight : -0.5e-3);
      sim_->SetToolPose(pose);
    }
    if (v.viewer) {
      publisher_ = std::make_unique<cutsim::transport::MeshStreamPublisher>(
          *participant, session, cutsim::transport::MeshStreamOptions{.keyframe_interval_s = 0});
      subscriber_ = std::make_unique<cutsim::transport::MeshStreamSubscriber>(*participant, session);
      const int64_t deadline = MonotonicNs() + 10'000'000'000LL;
      while (!publisher_->HasReaders() && MonotonicNs() < deadline) {
        subscriber_->Poll(std::chrono::milliseconds(10));
      }
      if (!publisher_->HasReaders()) throw std::runtime_error("skip_bench: the DDS reader never matched");
    }
    viewer_every_ = std::max(1, static_cast<int>(std::lround(0.1 / sim_->frame_dt())));  // 10 Hz
  }

  /// Runs `frames` frames; returns the server thread's CPU time per frame,
  /// s (the in-process viewer's receive is not counted).
  double Run(int frames) {
    int64_t busy_ns = 0;
    const int64_t steps0 = sim_->QuickSummary().steps;
    for (int i = 0; i < frames; ++i) {
      const int64_t t0 = ThreadCpuNs();
      if (sim_->AdvanceFrame() != cutsim::sim::SimStatus::kOk) {
        throw std::runtime_error("skip_bench: simulation stopped: " + sim_->Summary().diagnosis);
      }
      if (v_.haptic_model) BuildModel();
      if (v_.viewer && ++frame_ % viewer_every_ == 0) Publish();
      busy_ns += ThreadCpuNs() - t0;
      if (subscriber_) subscriber_->Poll(std::chrono::nanoseconds(0));
    }
    steps_per_frame_ = static_cast<double>(sim_->QuickSummary().steps - steps0) / frames;
    return 1e-9 * static_cast<double>(busy_ns) / frames;
  }

  [[nodiscard]] double steps_per_frame() const { return steps_per_frame_; }
  [[nodiscard]] bool touching() const { return sim_->Tool().touching; }
  [[nodiscard]] uint64_t viewer_frames() const {
    return subscriber_ ? subscriber_->stats().deltas + subscriber_->stats().snapshots : 0;
  }

 private:
  // As server/realtime_session.cc does for a present client.
  void BuildModel() {
    const cutsim::sim::ToolReport tool = sim_->Tool();
    cutsim::haptics::ModelHeader header;
    header.stamp_ns = MonotonicNs();
    header.sim_time = sim_->sim_time();
    header.valid_for = 2.0 * sim_->frame_dt();
    header.topology_version = sim_->topology_version();
    cutsim::haptics::ContactLinearisation contact;
    contact.contact = tool.touching;
    if (tool.touching) {
      contact.x0 = tool.pose.tip;
      contact.normal = tool.normal;
      contact.f0 = tool.force_on_tool;
      contact.stiffness = sim_->ContactStiffness();
    }
    cutsim::transport::ToProto(cutsim::haptics::BuildLocalModel(header, contact), &model_msg_);
    const size_t n = model_msg_.ByteSizeLong();
    bytes_.resize(n);
    model_msg_.SerializeToArray(bytes_.data(), static_cast<int>(n));
  }

  void Publish() {
    publisher_->PublishFrame([&](cutsim::transport::MeshFrame& frame) {
      sim_->FillMeshView(view_);
      frame.frame = frame_;
      frame.sim_time = sim_->sim_time();
      frame.topology_version = sim_->topology_version();
      frame.world.swap(view_.world);
      frame.rest.swap(view_.rest);
      frame.tets.swap(view_.tets);
      frame.surface.swap(view_.surface);
      frame.opened.swap(view_.opened);
      frame.stress.clear();
    });
  }

  Variant v_;
  std::unique_ptr<Simulation> sim_;
  std::unique_ptr<cutsim::transport::MeshStreamPublisher> publisher_;
  std::unique_ptr<cutsim::transport::MeshStreamSubscriber> subscriber_;
  cutsim::sim::MeshView view_;
  cutsim::v1::HapticModel model_msg_;
  std::vector<uint8_t> bytes_;
  uint64_t frame_ = 0;
  int viewer_every_ = 1;
  double steps_per_frame_ = 0.0;
};

struct Row {
  std::string skip, scene, skipped_label, forced_label;
  Variant skipped, forced;
};

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"skip table at the session level: each skip against the same scene with the work forced on"};
  std::string scene_dir = "scenes";
  std::string json_path;
  int rounds = 7;
  int frames = 100;
  uint32_t domain = 0;
  app.add_option("--scene-dir", scene_dir, "Folder with block.pbtxt and ligament.pbtxt")->check(CLI::ExistingDirectory);
  app.add_option("--rounds", rounds, "Alternating rounds per row (median)")->check(CLI::Range(1, 1000));
  app.add_option("--frames", frames, "Physics frames per round")->check(CLI::Range(1, 100000));
  app.add_option("--dds-domain", domain, "DDS domain for the viewer row (0: one derived from the pid)")
      ->check(CLI::Range(0, 230));
  app.add_option("--json", json_path, "Also write the JSON here");
  std::string filter;
  app.add_option("--filter", filter, "Only rows whose \"skip/scene\" contains this (e.g. ligament, \"no viewer\")");
  CLI11_PARSE(app, argc, argv);
  cutsim::InitLogging("skip_bench", "warn");
  if (domain == 0) domain = 100 + static_cast<uint32_t>(getpid() % 100);

  try {
    std::vector<Scene> scenes;
    scenes.push_back({"block", cutsim::sim::LoadScene(scene_dir + "/block.pbtxt"), Vector3d(0.02, 0.01, 0.01)});
    scenes.push_back({"ligament", cutsim::sim::LoadScene(scene_dir + "/ligament.pbtxt"), Vector3d(0.015, 0, 0.004)});
    cutsim::transport::DdsParticipant participant(domain);

    const Variant none{};
    const Variant hover{.tool = ToolUse::kHover};
    const Variant press{.tool = ToolUse::kPress};
    const Variant press_nocut{.tool = ToolUse::kPress, .cutting = false};
    const Variant press_model{.tool = ToolUse::kPress, .haptic_model = true};
    const Variant viewer{.viewer = true};
    std::vector<Row> rows;
    for (const Scene& s : scenes) {
      rows.push_back({"no cutting tool", s.name, "no tool", "tool hovering 5 mm above", none, hover});
      rows.push_back({"no cutting tool", s.name, "no tool", "tool pressing 0.5 mm", none, press});
      rows.push_back({"cutting disabled", s.name, "pressing, cutting off", "pressing, cutting on", press_nocut, press});
      rows.push_back({"no haptic client", s.name, "no local model", "local model every frame", press, press_model});
      rows.push_back({"no viewer", s.name, "no reader matched", "one viewer at 10 Hz", none, viewer});
    }
    std::erase_if(rows, [&](const Row& row) { return (row.skip + "/" + row.scene).find(filter) == std::string::npos; });

    std::vector<std::string> missed;
    std::string out = "{\n  \"rows\": [\n";
    for (size_t r = 0; r < rows.size(); ++r) {
      const Row& row = rows[r];
      const Scene& scene = *std::find_if(scenes.begin(), scenes.end(), [&](const Scene& s) { return s.name == row.scene; });
      const std::string session = fmt::format("skip{}_{}", getpid(), r);
      Runner skipped(scene, row.skipped, &participant, session + "a");
      Runner forced(scene, row.forced, &participant, session + "b");
      (void)skipped.Run(std::max(1, frames / 5));  // warm-up: caches, allocations, the first snapshot
      (void)forced.Run(std::max(1, frames / 5));
      std::vector<double> a, b;
      for (int k = 0; k < rounds; ++k) {
        a.push_back(skipped.Run(frames));
        b.push_back(forced.Run(frames));
      }
      const double ma = Median(a), mb = Median(b);
      const bool touching = forced.touching();
      std::fprintf(stderr,
                   "%-17s %-9s %-22s %9.1f us/frame (%5.1f steps) | %-25s %9.1f us/frame (%5.1f steps) | "
                   "saving %5.1f %%%s\n",
                   row.skip.c_str(), row.scene.c_str(), row.skipped_label.c_str(), 1e6 * ma,
                   skipped.steps_per_frame(), row.forced_label.c_str(), 1e6 * mb, forced.steps_per_frame(),
                   100.0 * (mb - ma) / mb,
                   row.forced.tool == ToolUse::kPress && !touching   ? " (tool NOT touching!)"
                   : row.forced.tool == ToolUse::kHover && touching ? " (hovering tool TOUCHES!)"
                                                                    : "");
      const std::string what = row.skip + "/" + row.scene + ", " + row.forced_label;
      if (row.forced.tool == ToolUse::kPress && !touching) missed.push_back(what + ": tool not touching");
      if (row.forced.tool == ToolUse::kHover && touching) missed.push_back(what + ": hovering tool touches");
      if (row.forced.viewer && forced.viewer_frames() == 0) missed.push_back(what + ": viewer received no frame");
      out += fmt::format(
          "    {{\"skip\": \"{}\", \"scene\": \"{}\", \"skipped\": \"{}\", \"forced_on\": \"{}\", "
          "\"skipped_us_per_frame\": {:.2f}, \"forced_on_us_per_frame\": {:.2f}, \"saving\": {:.4f}, "
          "\"skipped_steps_per_frame\": {:.2f}, \"forced_on_steps_per_frame\": {:.2f}, "
          "\"tool_touching\": {}, \"viewer_frames_received\": {}}}{}\n",
          row.skip, row.scene, row.skipped_label, row.forced_label, 1e6 * ma, 1e6 * mb, (mb - ma) / mb,
          skipped.steps_per_frame(), forced.steps_per_frame(), touching ? "true" : "false", forced.viewer_frames(), r + 1 < rows.size() ? "," : "");
    }
    out += fmt::format("  ],\n  \"rounds\": {}, \"frames_per_round\": {}\n}}\n", rounds, frames);
    out = cutsim::bench::NullNonFinite(out);
    std::fputs(out.c_str(), stdout);
    if (!json_path.empty() && !cutsim::bench::WriteTextFile("skip_bench", json_path, out)) return 1;
    return cutsim::bench::ExitCodeForTargets("skip_bench", missed);
  } catch (const std::exception& e) {
    std::fprintf(stderr, "skip_bench: %s\n", e.what());
    return 1;
  }
}
