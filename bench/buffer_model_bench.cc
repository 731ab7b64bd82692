// Buffer-model accuracy (method paper §3.4): the force a haptic client renders at
// 1 kHz from local models the server builds at a physics frame rate f,
// against a reference that runs the full FEM with 1 ms frames on the same
// scripted tool path. Prints one JSON line per frame rate: the RMS force
// error relative to the peak reference force, for the buffer model
// F = f0 − K(x − x0) and for a zero-order hold of f0 (what a client without
// the stiffness term would render).
//
//   buffer_model_bench [--scene scenes/ligament.pbtxt]
#include <cmath>
#include <cstdio>
#include <string>
#include <vector>

#include <CLI/CLI.hpp>

#include "bench/json_text.h"
#include "common/core/log.h"
#include "common/haptics/force_shaping.h"
#include "common/haptics/local_model.h"
#include "common/haptics/tool_path.h"
#include "common/sim/scene_loader.h"
#include "common/sim/simulation.h"

namespace {

// Press 2 mm into the ligament's top, slide 6 mm across it, lift: contact
// throughout the middle second, no cut (cutting is disabled for this study).
cutsim::haptics::ToolPath PressAndSlide() {
  const Eigen::Vector3d up(0, 0, 1);
  return cutsim::haptics::ToolPath({{0.0, {{0.015, -0.003, 0.0065}, up}},
                                    {0.4, {{0.015, -0.003, 0.0020}, up}},
                                    {1.4, {{0.015, 0.003, 0.0020}, up}},
                                    {1.8, {{0.015, 0.003, 0.0065}, up}}},
                                   "press-and-slide");
}

}  // namespace

int main(int argc, char** argv) {
  std::string scene_path = "scenes/ligament.pbtxt";
  CLI::App app{"buffer-model accuracy against a 1 kHz FEM reference"};
  app.add_option("--scene", scene_path, "Scene with a tool (cutting is turned off)");
  CLI11_PARSE(app, argc, argv);
  cutsim::InitLogging("buffer_model_bench", "warn");

  cutsim::sim::LoadedScene scene = cutsim::sim::LoadScene(scene_path);
  scene.scene.mutable_cutting()->set_enabled(false);
  scene.scene.mutable_tool()->clear_path_file();
  scene.scene.mutable_tool()->clear_keyframes();
  const cutsim::haptics::ToolPath path = PressAndSlide();
  const double end = path.end_time();
  const int ticks = static_cast<int>(std::lround(end * 1000.0));

  auto make = [&] {
    auto sim = cutsim::sim::Simulation::Create(scene);
    return sim;
  };
  // Reference: the FEM itself at 1 kHz; the tool follows the path.
  std::vector<Eigen::Vector3d> reference(static_cast<size_t>(ticks));
  {
    auto sim = make();
    for (int i = 0; i < ticks; ++i) {
      sim->SetToolPose(path.Sample(1e-3 * (i + 1)));
      sim->AdvanceFrame(1e-3);
      reference[static_cast<size_t>(i)] = sim->Tool().force_on_tool;
    }
  }
  double peak = 0;
  for (const auto& f : reference) peak = std::max(peak, f.norm());

  cutsim::haptics::DeviceLimits limits;
  limits.max_force = 1e3;
  limits.max_stiffness = 1e6;
  for (const double rate : {50.0, 100.0, 200.0, 500.0}) {
    auto sim = make();
    const int per_frame = static_cast<int>(std::lround(1000.0 / rate));
    double err_buffer = 0, err_hold = 0;
    cutsim::haptics::BoundedModel model;
    int i = 0;
    for (int frame = 0; i < ticks; ++frame) {
      // Ticks of this frame render the model of the previous frame (one frame of latency, as on the wire).
      for (int k = 0; k < per_frame && i < ticks; ++k, ++i) {
        const Eigen::Vector3d x = path.Sample(1e-3 * (i + 1)).tip;
        const Eigen::Vector3d f = cutsim::haptics::EvaluateBufferModel(model, x, Eigen::Vector3d::Zero(),
                                                                       limits.max_force, 1.0);
        const Eigen::Vector3d hold = model.contact ? model.f0 : Eigen::Vector3d::Zero();
        err_buffer += (f - reference[static_cast<size_t>(i)]).squaredNorm();
        err_hold += (hold - reference[static_cast<size_t>(i)]).squaredNorm();
      }
      sim->SetToolPose(path.Sample(std::min(end, (frame + 1) / rate)));
      sim->AdvanceFrame(1.0 / rate);
      const cutsim::sim::ToolReport tool = sim->Tool();
      cutsim::haptics::ModelHeader header;
      cutsim::haptics::ContactLinearisation contact;
      contact.contact = tool.touching;
      contact.x0 = tool.pose.tip;
      contact.normal = tool.normal;
      contact.f0 = tool.force_on_tool;
      contact.stiffness = sim->ContactStiffness();
      model = cutsim::haptics::BoundModel(cutsim::haptics::BuildLocalModel(header, contact), limits);
    }
    const double rms_buffer = std::sqrt(err_buffer / ticks) / std::max(peak, 1e-12);
    const double rms_hold = std::sqrt(err_hold / ticks) / std::max(peak, 1e-12);
    std::string line;
    cutsim::bench::Appendf(
        line, "{\"frame_rate_hz\": %.0f, \"peak_force_n\": %.6g, \"rms_error_buffer_model\": %.6g, "
        "\"rms_error_zero_order_hold\": %.6g}\n",
        rate, peak, rms_buffer, rms_hold);
    std::fputs(cutsim::bench::NullNonFinite(line).c_str(), stdout);
  }
  return 0;
}
