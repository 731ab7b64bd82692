// cutsim-fake-haptic-server: a test-only stand-in for the server's real-time
// mode, speaking the real haptic link (HapticServerLink). The "tissue" is a
// stiff plane z = 0 (outward normal +z). Each frame it polls the newest tool
// pose and publishes the exact local model of the plane around it:
//   tip within 5 mm above or below the plane → contact,
//   x0 = tip (penetrating) or its projection on the plane (above),
//   f0 = k · max(0, −z) · n,  K = k · n nᵀ  (K = −∂f/∂x),
// so the client's buffer model F = f0 − K(x − x0) is exactly k·max(0, −z)·n.
// With --cut-after S, once the tip has been in contact for S seconds the cut
// counter increments (cutting = true in that frame) and the plane drops by
// --cut-drop metres (the tissue parted under the blade), so the client sees
// the cut decay of method paper eq. (13). Publishes nothing until a tool pose arrives
// (like the real server with no haptic client). With --key-file it checks
// the tool messages' tags and signs its models, as the real server does.
// Prints one JSON line of stats on exit (SIGTERM/SIGINT or --duration), with
// the tool packets by reason.
#include <atomic>
#include <cmath>
#include <csignal>
#include <cstdio>
#include <string>

#include <CLI/CLI.hpp>
#include <fmt/format.h>

#include "common/core/clock.h"
#include "common/core/log.h"
#include "common/haptics/local_model.h"
#include "common/transport/fault_flags.h"
#include "common/transport/haptic_link.h"
#include "common/transport/lcm_bus.h"
#include "common/transport/lcm_packet.h"
#include "common/transport/report_json.h"
#include "common/transport/stream_auth.h"
#include "common/transport/tool_auth.h"
#include "cutsim/v1/report.pb.h"

namespace {
std::atomic<bool> g_stop{false};
extern "C" void OnSignal(int /*sig*/) { g_stop.store(true); }
}  // namespace

int main(int argc, char** argv) {
  std::string session = "default";
  std::string url = "udpm://239.255.76.67:7667?ttl=0";
  double rate = 200.0;          // Hz, model rate (physics frames)
  double stiffness = 1000.0;    // N/m
  double cut_after = 0.0;       // s of contact before the cut (0 = never)
  double cut_drop = 0.02;       // m
  double decay = 30.0;          // ξ, 1/s, sent in the model's cut state
  double duration = 0.0;        // s, 0 = until a signal
  double margin = 0.005;        // m, contact band above the plane
  std::string key_file;
  cutsim::transport::FaultConfig faults;
  CLI::App app{"Test-only haptic server stand-in: a stiff plane with a scripted cut"};
  app.add_option("--session", session)->capture_default_str();
  app.add_option("--lcm-url", url)->capture_default_str();
  app.add_option("--rate", rate, "Model rate, Hz")->capture_default_str();
  app.add_option("--stiffness", stiffness, "Plane stiffness, N/m")->capture_default_str();
  app.add_option("--cut-after", cut_after, "Seconds of contact before the cut (0 = no cut)")->capture_default_str();
  app.add_option("--cut-drop", cut_drop, "Plane drop at the cut, m")->capture_default_str();
  app.add_option("--decay-per-second", decay, "ξ sent with the cut state, 1/s")->capture_default_str();
  app.add_option("--duration", duration, "Run time, s (0 = until SIGTERM)")->capture_default_str();
  app.add_option("--key-file", key_file, "Session key: check tool tags, sign models");
  cutsim::transport::AddFaultFlags(app, &faults);
  CLI11_PARSE(app, argc, argv);
  cutsim::InitLogging("fake-haptic-server", "info");
  std::signal(SIGTERM, OnSignal);
  std::signal(SIGINT, OnSignal);

  try {
    cutsim::transport::LcmBus bus(url);
    cutsim::transport::HapticLinkOptions options;
    options.publish_faults = faults;
    std::unique_ptr<cutsim::transport::HmacToolAuthenticator> verifier;
    std::unique_ptr<cutsim::transport::PayloadAuthenticator> signer;
    if (!key_file.empty()) {
      const auto key = cutsim::transport::LoadSessionKey(key_file);
      verifier = std::make_unique<cutsim::transport::HmacToolAuthenticator>(*key, session);
      signer = std::make_unique<cutsim::transport::PayloadAuthenticator>(*key, cutsim::transport::kHapticModelDomain,
                                                                         session);
      options.authenticator = verifier.get();
      options.model_auth = signer.get();
    }
    cutsim::transport::HapticServerLink link(bus, session, options);
    // Readiness line the tests wait for: the link is subscribed from here on.
    cutsim::Log().info("ready: session {} on {}", session, url);
    const int64_t period = std::llround(1e9 / rate);
    const int64_t t0 = cutsim::MonotonicNs();
    const int64_t end = duration > 0.0 ? t0 + std::llround(duration * 1e9) : INT64_MAX;
    double plane_z = 0.0;
    uint64_t cuts = 0;
    int64_t contact_since = 0;
    bool reported_contact = false;
    uint64_t frames = 0;
    uint64_t contact_frames = 0;
    int64_t deadline = t0;
    Eigen::Vector3d max_tip = Eigen::Vector3d::Constant(-1e9);
    while (!g_stop.load() && cutsim::MonotonicNs() < end) {
      // Poll the link at 1 kHz so fault-delayed models leave on time, and
      // publish one model per physics frame.
      for (int64_t now = cutsim::MonotonicNs(); now < deadline; now = cutsim::MonotonicNs()) {
        link.PollTool();
        cutsim::SleepUntilNs(std::min(deadline, now + 1'000'000));
      }
      deadline += period;
      link.PollTool();
      const auto& tool = link.latest_tool();
      if (!tool) continue;
      ++frames;
      const int64_t now = cutsim::MonotonicNs();
      const Eigen::Vector3d n = Eigen::Vector3d::UnitZ();
      const double height = tool->pose.tip.z() - plane_z;
      cutsim::haptics::ContactLinearisation c;
      c.contact = height < margin;
      bool cutting = false;
      if (c.contact) {
        ++contact_frames;
        if (height < 0.0 && contact_since == 0) contact_since = now;
        // Once, so a test can act on a client that has been pushing for a while.
        if (!reported_contact && contact_since != 0 && now - contact_since >= 500'000'000) {
          cutsim::Log().info("in contact for 0.5 s");
          reported_contact = true;
        }
        if (cut_after > 0.0 && cuts == 0 && contact_since != 0 &&
            1e-9 * static_cast<double>(now - contact_since) >= cut_after) {
          ++cuts;
          cutting = true;
          plane_z -= cut_drop;
          cutsim::Log().info("cut at t={:.3f} s (tool seq {})", 1e-9 * static_cast<double>(now - t0), tool->seq);
        }
      }
      const double h = tool->pose.tip.z() - plane_z;
      c.contact = h < margin;
      c.normal = n;
      c.x0 = h < 0.0 ? tool->pose.tip : Eigen::Vector3d(tool->pose.tip.x(), tool->pose.tip.y(), plane_z);
      c.f0 = stiffness * std::max(0.0, -h) * n;
      c.stiffness = stiffness * n * n.transpose();
      cutsim::haptics::ModelHeader header;
      header.sim_time = 1e-9 * static_cast<double>(now - t0);
      header.valid_for = 2.0 / rate;
      header.cut = {.cuts = cuts, .cutting = cutting, .decay_per_second = decay};
      header.topology_version = cuts;
      link.PublishModel(cutsim::haptics::BuildLocalModel(header, c), tool->seq);
      max_tip = max_tip.cwiseMax(tool->pose.tip);
    }
    const auto s = link.stats();
    cutsim::v1::LinkPacketReport packets;
    cutsim::transport::ToReport(s.packets, &packets);
    std::printf("%s\n", fmt::format(R"({{"kind":"fake_server_stats","frames":{},"contact_frames":{},"cuts":{},)"
                                    R"("tools_received":{},"tools_superseded":{},"tools_accepted":{},"decode_errors":{},)"
                                    R"("foreign_session":{},"stale":{},"duplicate":{},"invalid":{},"restarts":{},)"
                                    R"("models_published":{},"models_not_sent":{},"tool_packets":{}}})",
                                    frames, contact_frames, cuts, s.received, s.superseded, s.accepted,
                                    s.decode_errors, s.foreign_session, s.stale, s.duplicate, s.invalid, s.restarts,
                                    s.models_published, s.models_not_sent, cutsim::transport::ReportJson(packets))
                            .c_str());
    std::fflush(stdout);
  } catch (const std::exception& e) {
    cutsim::Log().error("{}", e.what());
    return 2;
  }
  return 0;
}
