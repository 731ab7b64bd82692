// What a trainee feels across the haptic link, against the link's delay and
// loss: the same scripted strokes on the ligament, the block and the skin
// pad, with the station and the server joined by a simulated link
// (tests/support/teleop_link.h: a deterministic clock, the fault injector's
// delay, ±20 % jitter and loss in both directions). Cutting is off, so every
// run meets the same tissue.
//
// Per scene, stroke, one-way delay, loss and stiffness term (the server's K,
// none = zero-order hold of f0, K from the static contact patch only):
// * with the device on the stroke exactly: the force commanded to the device
//   against an in-process run at the same tool positions (1 kHz frames, no
//   link), RMS and peak error relative to the reference's peak force, and
//   the passivity observer's sum;
// * with a virtual hand (mass–spring–damper) holding the handle through the
//   press-and-hold stroke: the tool's peak-to-peak excursion over the end of
//   the hold (a sustained oscillation keeps it large), the hold force, the
//   observer's sum and what the passivity controller and the watchdog did.
//
// Prints one JSON document; --trace FILE writes the force over time of the
// block's fast press at 0, 25 and 100 ms beside its reference, and the
// block's hold under the hand (for bench/plot.py). Exits 1 when a target is
// missed ("missed": net energy into the hand, a tool that is not still, an
// RMS force error above 10 % at 25 ms or 20 % at 50 ms, a buffer model not
// within half the zero-order hold's error on a stiff stroke); a force that
// is not steady under the hand is reported in "goals_missed" only.
//
//   link_fidelity_bench [--scene-dir scenes] [--trace FILE]
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <string>
#include <vector>

#include <CLI/CLI.hpp>

#include "bench/json_text.h"
#include "common/core/log.h"
#include "common/haptics/haptic_renderer.h"
#include "common/haptics/tool_path.h"
#include "common/sim/scene_loader.h"
#include "tests/support/teleop_link.h"

namespace {

using cutsim::bench::Appendf;
using cutsim::test_support::StiffnessTerm;
namespace ts = cutsim::test_support;

/// Where the strokes touch a scene: a point on its top surface (m) and the
/// indentation (m), less than the scene's contact indentation limit.
struct Spot {
  std::string name;
  Eigen::Vector3d top;
  double depth;
};

/// A scripted stroke and the ticks of its hold (for the hand's stability).
struct Stroke {
  std::string name;
  cutsim::haptics::ToolPath path;
  double hold_begin = 0;  ///< s, the press has arrived
  double hold_end = 0;    ///< s, the lift starts
};

constexpr double kApproach = 0.002;  // m above the surface where strokes start

/// Press straight down at `speed` (m/s), hold `hold` s, lift at `speed`.
Stroke Press(const std::string& name, const Spot& s, double speed, double hold) {
  const Eigen::Vector3d up = Eigen::Vector3d::UnitZ();
  const Eigen::Vector3d above = s.top + kApproach * up, in = s.top - s.depth * up;
  const double travel = (kApproach + s.depth) / speed, rest = 0.05;
  Stroke k{name,
           cutsim::haptics::ToolPath({{0.0, {above, up}},
                                      {rest, {above, up}},
                                      {rest + travel, {in, up}},
                                      {rest + travel + hold, {in, up}},
                                      {2 * rest + 2 * travel + hold, {above, up}}},
                                     name),
           rest + travel, rest + travel + hold};
  return k;
}

/// Press at 2 cm/s, then saw along x ±4 mm at 2 Hz for two strokes, lift.
Stroke Saw(const Spot& s) {
  const Eigen::Vector3d up = Eigen::Vector3d::UnitZ(), ex = Eigen::Vector3d::UnitX();
  const Eigen::Vector3d above = s.top + kApproach * up, in = s.top - s.depth * up;
  const double travel = (kApproach + s.depth) / 0.02, quarter = 0.125, amplitude = 0.004;
  std::vector<cutsim::haptics::ToolKeyframe> k{{0.0, {above, up}}, {0.05, {above, up}}, {0.05 + travel, {in, up}}};
  double t = 0.05 + travel;
  const double offsets[] = {1, 0, -1, 0, 1, 0, -1, 0};
  for (const double o : offsets) {
    t += quarter;
    k.push_back({t, {in + o * amplitude * ex, up}});
  }
  const double hold_end = t;
  k.push_back({t + travel, {above, up}});
  return {"saw", cutsim::haptics::ToolPath(std::move(k), "saw"), 0.05 + travel, hold_end};
}

/// The three strokes on one spot: the stiff contact held (the hand's
/// stability stroke), a fast press at 10 cm/s, sawing.
std::vector<Stroke> StrokesFor(const Spot& s) {
  return {Press("press_hold", s, 0.02, 0.6), Press("fast_press", s, 0.10, 0.3), Saw(s)};
}

struct ErrorStats {
  double rms = 0, peak = 0;  // relative to the reference's peak |F|
  double onset_share = 0;    // share of the squared error in ticks the station renders no force, the reference does
};

ErrorStats Compare(const std::vector<Eigen::Vector3d>& f, const std::vector<Eigen::Vector3d>& ref, double peak) {
  ErrorStats e;
  const size_t n = std::min(f.size(), ref.size());
  double sum = 0, unfelt = 0;
  for (size_t i = 0; i < n; ++i) {
    const double d = (f[i] - ref[i]).norm();
    sum += d * d;
    if (f[i].isZero() && ref[i].norm() > 0.01 * peak) unfelt += d * d;
    e.peak = std::max(e.peak, d);
  }
  e.onset_share = sum > 0 ? unfelt / sum : 0.0;
  const double scale = std::max(peak, 1e-12);
  e.rms = std::sqrt(sum / std::max<size_t>(n, 1)) / scale;
  e.peak /= scale;
  return e;
}

double PeakForce(const std::vector<Eigen::Vector3d>& f) {
  double p = 0;
  for (const auto& v : f) p = std::max(p, v.norm());
  return p;
}

/// Ticks with the watchdog's gain below 1 (the force was being faded).
int FadedTicks(const ts::StationTrace& s) {
  return static_cast<int>(std::count_if(s.watchdog_gain.begin(), s.watchdog_gain.end(),
                                        [](double g) { return g < 1.0; }));
}

std::string StatsJson(const ts::StationTrace& s) {
  std::string o;
  Appendf(o,
          "\"energy_j\": %.6g, \"min_energy_j\": %.6g, \"pc_dissipated_j\": %.6g, \"watchdog_trips\": %llu, "
          "\"faded_ticks\": %d, \"models_stale\": %llu, \"max_force_n\": %.6g",
          s.stats.observed_energy, s.stats.min_observed_energy, s.stats.passivity_dissipated,
          static_cast<unsigned long long>(s.stats.watchdog_trips), FadedTicks(s),
          static_cast<unsigned long long>(s.stats.models_stale), s.stats.max_force);
  return o;
}

/// Force along +z (the strokes' outward normal) per tick, as a JSON array.
std::string NormalForces(const std::vector<Eigen::Vector3d>& f) {
  std::string o = "[";
  for (size_t i = 0; i < f.size(); ++i) Appendf(o, "%s%.5g", i ? ", " : "", f[i].z());
  return o + "]";
}

cutsim::haptics::RendererConfig RendererFor(const cutsim::sim::LoadedScene& scene) {
  const auto& h = scene.scene.haptics();
  return cutsim::haptics::MakeRendererConfig(
      {h.decay_per_second(), h.watchdog(), h.max_force(), h.max_stiffness()}, scene.path.string() + ": haptics");
}

/// The scene with cutting off and no scripted path (the station drives the tool).
cutsim::sim::LoadedScene BenchScene(const std::string& dir, const std::string& name) {
  cutsim::sim::LoadedScene scene = cutsim::sim::LoadScene(dir + "/" + name + ".pbtxt");
  scene.scene.mutable_cutting()->set_enabled(false);
  scene.scene.mutable_tool()->clear_path_file();
  scene.scene.mutable_tool()->clear_keyframes();
  return scene;
}

/// Targets or goals of the summary; every missed one is named.
struct Targets {
  std::vector<std::string> missed;
  void Check(bool ok, const std::string& what) {
    if (!ok) missed.push_back(what);
  }
};
using Goals = Targets;

constexpr double kOscillationLimit = 50e-6;  // m, tool peak-to-peak over the end of the hold
constexpr double kForceRippleLimit = 0.2;    // force peak-to-peak over the end of the hold / its mean
constexpr double kWindow = 0.3;              // s, the end of the hold that is judged

/// The stations every run renders: the three stiffness terms with the
/// passivity controller, and the server's K without it.
const std::vector<ts::Station>& Stations() {
  static const std::vector<ts::Station> stations{{StiffnessTerm::kServer, true},
                                                 {StiffnessTerm::kNone, true},
                                                 {StiffnessTerm::kPatch, true},
                                                 {StiffnessTerm::kServer, false}};
  return stations;
}

bool Shipped(const ts::Station& s) { return s.term == StiffnessTerm::kServer && s.passivity; }

/// Strokes whose force is set by the stiffness (the comparison of terms).
bool Stiff(const Spot& spot, const Stroke& stroke) {
  return (spot.name == "block" && stroke.name == "fast_press") ||
         (spot.name == "ligament" && stroke.name == "press_hold") || stroke.name == "saw";
}

std::string JsonList(const std::vector<std::string>& items) {
  std::string o = "[";
  for (size_t i = 0; i < items.size(); ++i) Appendf(o, "%s\"%s\"", i ? ", " : "", items[i].c_str());
  return o + "]";
}

/// The sweep's settings and what it has written so far.
struct Sweep {
  std::vector<double> delays, losses;
  bool trace = false;
  ts::HandModel hand;
  std::string rows, hand_rows, trace_runs, hand_trace;
  Targets targets;  // gate the exit code
  Goals goals;      // reported only
};

/// The scripted stroke through one link: one row per station.
void ScriptedRows(const cutsim::sim::LoadedScene& scene, const Spot& spot, const Stroke& stroke,
                  const ts::TeleopOptions& o, const std::vector<Eigen::Vector3d>& ref, Sweep& sweep) {
  const double peak = PeakForce(ref), delay = o.link.one_way_ms, loss = o.link.loss;
  const ts::TeleopResult r = ts::RunTeleop(scene, stroke.path, o);
  double shipped_rms = 0, hold_rms = 0;
  const std::string where = spot.name + "/" + stroke.name + " at " + std::to_string(static_cast<int>(delay)) +
                            " ms, loss " + std::to_string(static_cast<int>(100 * loss)) + " %";
  for (const ts::StationTrace& s : r.stations) {
    const ErrorStats e = Compare(s.force, ref, peak);
    Appendf(sweep.rows,
            "%s    {\"scene\": \"%s\", \"stroke\": \"%s\", \"one_way_ms\": %g, \"loss\": %g, \"term\": \"%s\", "
            "\"peak_force_n\": %.6g, \"rms_error\": %.6g, \"peak_error\": %.6g, \"unfelt_share\": %.4g, %s, "
            "\"models_lost\": %llu}",
            sweep.rows.empty() ? "" : ",\n", spot.name.c_str(), stroke.name.c_str(), delay, loss,
            Name(s.station).c_str(), peak, e.rms, e.peak, e.onset_share, StatsJson(s).c_str(),
            static_cast<unsigned long long>(r.downlink.dropped));
    if (Shipped(s.station)) {
      shipped_rms = e.rms;
      sweep.targets.Check(s.stats.observed_energy >= 0.0, "net energy into the hand, " + where);
      if (delay == 25) sweep.targets.Check(e.rms <= 0.10, "rms error <= 10 %, " + where);
      if (delay == 50) sweep.targets.Check(e.rms <= 0.20, "rms error <= 20 %, " + where);
    }
    if (s.station.term == StiffnessTerm::kNone) hold_rms = e.rms;
    const bool traced = sweep.trace && spot.name == "block" && stroke.name == "fast_press" && loss == 0 &&
                        (delay == 0 || delay == 25 || delay == 100);
    if (traced)
      Appendf(sweep.trace_runs, "%s{\"one_way_ms\": %g, \"term\": \"%s\", \"force\": %s}",
              sweep.trace_runs.back() == '[' ? "" : ", ", delay, Name(s.station).c_str(),
              NormalForces(s.force).c_str());
  }
  if (Stiff(spot, stroke) && delay >= 10)
    sweep.targets.Check(shipped_rms <= 0.5 * hold_rms, "buffer model <= half the zero-order hold, " + where);
}

/// The press-and-hold with a virtual hand on the handle: one row per station.
void HandRows(const cutsim::sim::LoadedScene& scene, const Spot& spot, const Stroke& stroke, ts::TeleopOptions o,
              Sweep& sweep) {
  const double delay = o.link.one_way_ms, loss = o.link.loss;
  o.hand = sweep.hand;
  const ts::TeleopResult h = ts::RunTeleop(scene, stroke.path, o);
  const size_t end = static_cast<size_t>(std::lround(stroke.hold_end * 1e3));
  const size_t from = end - static_cast<size_t>(std::lround(kWindow * 1e3));
  const std::string where = spot.name + " at " + std::to_string(static_cast<int>(delay)) + " ms, loss " +
                            std::to_string(static_cast<int>(100 * loss)) + " %";
  for (const ts::StationTrace& s : h.stations) {
    const double p2p = ts::PeakToPeak(s.position, Eigen::Vector3d::UnitZ(), from, end);
    const double force_p2p = ts::PeakToPeak(s.force, Eigen::Vector3d::UnitZ(), from, end);
    double hold_force = 0;
    for (size_t i = from; i < end; ++i) hold_force += s.force[i].z() / static_cast<double>(end - from);
    const bool still = p2p <= kOscillationLimit;
    const bool steady = force_p2p <= kForceRippleLimit * std::abs(hold_force);
    Appendf(sweep.hand_rows,
            "%s    {\"scene\": \"%s\", \"one_way_ms\": %g, \"loss\": %g, \"term\": \"%s\", "
            "\"oscillation_p2p_m\": %.6g, \"tool_still\": %s, \"force_p2p_n\": %.6g, \"force_steady\": %s, "
            "\"hold_force_n\": %.6g, %s}",
            sweep.hand_rows.empty() ? "" : ",\n", spot.name.c_str(), delay, loss, Name(s.station).c_str(), p2p,
            still ? "true" : "false", force_p2p, steady ? "true" : "false", hold_force, StatsJson(s).c_str());
    if (Shipped(s.station)) {
      sweep.targets.Check(still, "tool still under the hand, " + where);
      sweep.targets.Check(s.stats.observed_energy >= 0.0, "net energy into the hand (hand), " + where);
      sweep.goals.Check(steady, "steady force under the hand, " + where);
    }
    if (sweep.trace && spot.name == "block" && loss == 0 && (delay == 0 || delay == 25 || delay == 100)) {
      std::vector<Eigen::Vector3d> z(s.position.size(), Eigen::Vector3d::Zero());
      for (size_t i = 0; i < z.size(); ++i) z[i].z() = s.position[i].z() - spot.top.z();
      Appendf(sweep.hand_trace, "%s{\"one_way_ms\": %g, \"term\": \"%s\", \"depth\": %s, \"force\": %s}",
              sweep.hand_trace.empty() ? "" : ", ", delay, Name(s.station).c_str(), NormalForces(z).c_str(),
              NormalForces(s.force).c_str());
    }
  }
}

/// One stroke on one scene over every link of the sweep.
void RunStroke(const cutsim::sim::LoadedScene& scene, const Spot& spot, const Stroke& stroke, Sweep& sweep) {
  const std::vector<Eigen::Vector3d> ref = ts::ReferenceForces(scene, stroke.path);
  if (sweep.trace && spot.name == "block" && stroke.name == "fast_press")
    sweep.trace_runs = "{\"scene\": \"block\", \"stroke\": \"fast_press\", \"dt\": 0.001, \"reference\": " +
                       NormalForces(ref) + ", \"runs\": [";
  for (const double loss : sweep.losses) {
    for (const double delay : sweep.delays) {
      ts::TeleopOptions o;
      o.link = {delay, 0.2, loss, 1};
      o.stations = Stations();
      o.renderer = RendererFor(scene);
      ScriptedRows(scene, spot, stroke, o, ref, sweep);
      if (stroke.name == "press_hold") HandRows(scene, spot, stroke, o, sweep);
    }
  }
}

/// Writes `stroke` as a tool path file (scenes/README.md format) for the
/// scripted device of a real station, after a lead-in of `lead_in` s at its
/// start pose (the station's first models arrive while the tool waits).
void WritePath(const Stroke& stroke, const std::string& file, double lead_in) {
  std::ofstream out(file);
  out << "# " << stroke.name << ": t tip_x tip_y tip_z dir_x dir_y dir_z\n";
  for (const auto& k : stroke.path.keyframes()) {
    std::string line;
    Appendf(line, "%.4f %.6f %.6f %.6f %g %g %g\n", k.t + (k.t > 0 ? lead_in : 0), k.pose.tip.x(), k.pose.tip.y(), k.pose.tip.z(),
            k.pose.blade_dir.x(), k.pose.blade_dir.y(), k.pose.blade_dir.z());
    out << line;
  }
}

/// A real station's run (cutsim-haptic --csv) against the in-process
/// reference at the positions it logged: one JSON line.
int CompareCsv(const cutsim::sim::LoadedScene& scene, const std::string& csv, const std::string& label) {
  std::ifstream in(csv);
  std::string line;
  std::getline(in, line);  // header: t_s,x_m,y_m,z_m,fx_n,fy_n,fz_n,f_n,...,energy_j,dissipated_j,...
  std::vector<double> t;
  std::vector<Eigen::Vector3d> x, f;
  double energy = 0, dissipated = 0, min_energy = 0, faded = 0;
  while (std::getline(in, line)) {
    double v[17] = {};
    if (std::sscanf(line.c_str(), "%lf,%lf,%lf,%lf,%lf,%lf,%lf,%lf,%lf,%lf,%lf,%lf,%lf,%lf,%lf,%lf,%lf", &v[0],
                    &v[1], &v[2], &v[3], &v[4], &v[5], &v[6], &v[7], &v[8], &v[9], &v[10], &v[11], &v[12], &v[13],
                    &v[14], &v[15], &v[16]) != 17)
      continue;
    t.push_back(v[0]);
    x.emplace_back(v[1], v[2], v[3]);
    f.emplace_back(v[4], v[5], v[6]);
    faded += v[11] < 1.0 ? 1 : 0;
    energy = v[15];
    min_energy = std::min(min_energy, energy);
    dissipated = v[16];
  }
  if (t.size() < 2) {
    std::fprintf(stderr, "%s: no rows\n", csv.c_str());
    return 1;
  }
  auto sim = cutsim::sim::Simulation::Create(scene);
  std::vector<Eigen::Vector3d> ref(t.size(), Eigen::Vector3d::Zero());
  for (size_t i = 1; i < t.size(); ++i) {
    sim->SetToolPose({x[i], Eigen::Vector3d::UnitZ()});
    sim->AdvanceFrame(std::clamp(t[i] - t[i - 1], 1e-4, 1e-2));
    ref[i] = sim->Tool().force_on_tool;
  }
  const double peak = PeakForce(ref);
  const ErrorStats e = Compare(f, ref, peak);
  std::string out;
  Appendf(out,
          "{\"kind\": \"link_fidelity_station\", \"run\": \"%s\", \"ticks\": %zu, \"peak_force_n\": %.6g, "
          "\"rms_error\": %.6g, \"peak_error\": %.6g, \"energy_j\": %.6g, \"min_energy_j\": %.6g, "
          "\"pc_dissipated_j\": %.6g, \"faded_ticks\": %.0f}\n",
          label.c_str(), t.size(), peak, e.rms, e.peak, energy, min_energy, dissipated, faded);
  std::fputs(cutsim::bench::NullNonFinite(out).c_str(), stdout);
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  std::string scene_dir = "scenes", trace_path;
  std::vector<double> delays{0, 5, 10, 25, 50, 100}, losses{0, 0.01, 0.05};
  CLI::App app{"haptic fidelity against the link's delay and loss"};
  app.add_option("--scene-dir", scene_dir, "Folder of ligament, block and skin_pad .pbtxt");
  app.add_option("--trace", trace_path, "JSON file for the force over time of the block's fast press");
  app.add_option("--delays", delays, "One-way delays, ms")->capture_default_str();
  app.add_option("--losses", losses, "Datagram loss probabilities")->capture_default_str();
  std::vector<std::string> only;
  app.add_option("--scenes", only, "Only these scenes (default: ligament, block, skin_pad)");
  std::string path_out, compare_csv, compare_scene = "block", label;
  app.add_option("--path-out", path_out, "Write the --compare-scene's fast press as a tool path file and exit");
  app.add_option("--compare-csv", compare_csv, "A station's CSV (cutsim-haptic --csv) to compare with the reference");
  app.add_option("--compare-scene", compare_scene, "Scene of --path-out / --compare-csv")->capture_default_str();
  app.add_option("--label", label, "Name of the --compare-csv run in its JSON line");
  CLI11_PARSE(app, argc, argv);
  cutsim::InitLogging("link_fidelity_bench", "warn");

  const std::vector<Spot> spots{{"ligament", {0.015, 0.0, 0.004}, 0.001},
                                {"block", {0.02, 0.01, 0.01}, 0.001},
                                {"skin_pad", {0.0015, 0.0015, 0.0}, 0.001}};

  if (!path_out.empty() || !compare_csv.empty()) {
    const auto spot = std::find_if(spots.begin(), spots.end(), [&](const Spot& s) { return s.name == compare_scene; });
    if (spot == spots.end()) {
      std::fprintf(stderr, "--compare-scene: unknown scene %s\n", compare_scene.c_str());
      return 2;
    }
    if (!path_out.empty()) {
      WritePath(StrokesFor(*spot)[1], path_out, 0.5);
      return 0;
    }
    return CompareCsv(BenchScene(scene_dir, spot->name), compare_csv, label);
  }

  Sweep sweep;
  sweep.delays = delays;
  sweep.losses = losses;
  sweep.trace = !trace_path.empty();
  for (const Spot& spot : spots) {
    if (!only.empty() && std::find(only.begin(), only.end(), spot.name) == only.end()) continue;
    const cutsim::sim::LoadedScene scene = BenchScene(scene_dir, spot.name);
    for (const Stroke& stroke : StrokesFor(spot)) RunStroke(scene, spot, stroke, sweep);
  }
  std::string out = "{\"kind\": \"link_fidelity\", \"link\": \"simulated: fault injector on a simulated clock\", ";
  Appendf(out,
          "\"jitter_fraction\": 0.2, \"hand\": {\"mass_kg\": %g, \"stiffness_n_per_m\": %g, \"damping_ns_per_m\": %g}, "
          "\"oscillation_limit_m\": %g, \"force_ripple_limit\": %g, \"window_s\": %g,\n  \"rows\": [\n",
          sweep.hand.mass, sweep.hand.stiffness, sweep.hand.damping, kOscillationLimit, kForceRippleLimit, kWindow);
  out += sweep.rows + "\n  ],\n  \"hand_rows\": [\n" + sweep.hand_rows + "\n  ],\n  \"missed\": " +
         JsonList(sweep.targets.missed) + ",\n  \"goals_missed\": " + JsonList(sweep.goals.missed) + "}\n";
  std::fputs(cutsim::bench::NullNonFinite(out).c_str(), stdout);
  if (!trace_path.empty() && !sweep.trace_runs.empty())
    std::ofstream(trace_path) << cutsim::bench::NullNonFinite(sweep.trace_runs + "], \"hand_runs\": [" +
                                                              sweep.hand_trace + "]}\n");
  return sweep.targets.missed.empty() ? 0 : 1;
}
