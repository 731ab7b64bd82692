// Cut benchmarks. JSON on stdout (and --json FILE):
//
//  (a) "step": wall time per executed cut step at ~1k, 10k and 100k tets,
//      median and p90, split into criterion / topology / FEM update /
//      surface+BVH (Simulation::CutTimings). Boxes from mesh::MakeBox with
//      the same element size (2 mm cells), so a cut step meets the same
//      number of elements at every size and only the mesh size changes; a
//      blade 5 mm deep (2.5 cells) is drawn straight across the top, 0.1 mm
//      beside a row of nodes, at 1.25 m/s with one cut attempt every few
//      frames. critical_stress is 1 Pa: every geometric attempt passes the
//      stress test, so the steps measured are real cuts.
//  (b) "block": scenes/block.pbtxt (K_I = 1 Pa) cut by parallel half-depth passes until
//      100 cut steps executed (or the 7 passes end), then the blade lifted
//      out and parked clear; the stable time step (fem estimate, before
//      the safety factor) as a ratio of the uncut mesh's, and the smallest
//      mean-ratio quality of the world mesh.
//  (c) "throughput": tet-steps/s of that cut block vs an uncut copy in the
//      same process, tool lifted clear, alternating rounds (median ratio).
//
//   cut_bench [--json FILE] [--scene-dir scenes] [--max-tets 100000] [--cuts 100]
//             [--min-tets 0] [--step-only] [--precision double|float] [--evict-mb 0]
//   (--min-tets/--step-only: one size alone, and no (b)/(c), for callgrind:
//   valgrind stops at an AVX-512 instruction in (b)'s quality check.)
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <string>
#include <vector>

#include <CLI/CLI.hpp>
#include <omp.h>
#include <fmt/format.h>

#include "bench/json_text.h"
#include "common/core/clock.h"
#include "common/core/hash.h"
#include "common/core/log.h"
#include "common/mesh/quality.h"
#include "common/sim/scene_loader.h"
#include "common/sim/simulation.h"

namespace {

using cutsim::Stopwatch;
using cutsim::sim::CutStepTiming;
using cutsim::sim::Simulation;
using cutsim::sim::ToolPose;
using Eigen::Vector3d;

double Quantile(std::vector<double> v, double q) {
  if (v.empty()) return 0.0;
  std::sort(v.begin(), v.end());
  const double at = q * static_cast<double>(v.size() - 1);
  const auto lo = static_cast<size_t>(std::floor(at));
  const size_t hi = std::min(lo + 1, v.size() - 1);
  return v[lo] + (at - static_cast<double>(lo)) * (v[hi] - v[lo]);
}

std::string Stats(const std::vector<double>& seconds) {
  return fmt::format("{{\"median_us\": {:.2f}, \"p90_us\": {:.2f}, \"max_us\": {:.2f}}}", 1e6 * Quantile(seconds, 0.5),
                     1e6 * Quantile(seconds, 0.9), 1e6 * Quantile(seconds, 1.0));
}

// A box of nx × ny × nz 2 mm cells on a fixed base with a tool and cutting;
// `precision`: "double" or "float".
std::string BoxScene(int nx, int ny, int nz, int threads, const std::string& precision) {
  const double h = 0.002;
  const char* precision_enum = precision == "float" ? "FLOAT" : "DOUBLE";
  return fmt::format(R"pb(
name: "cut-bench-box"
mesh {{ box {{ min {{ x: 0 y: 0 z: 0 }} max {{ x: {} y: {} z: {} }} nx: {} ny: {} nz: {} }} }}
materials {{ name: "tissue" young_poisson {{ youngs_modulus: 50000 poisson_ratio: 0.4 }} density: 1000 damping_psi: 0.05 }}
boundary {{ plane {{ point {{ x: 0 y: 0 z: 0 }} normal {{ x: 0 y: 0 z: 1 }} }} kind: KIND_FIXED }}
time_step {{ frame_dt: 0.0002 threads: {} precision: PRECISION_{} }}
tool {{ blade_length: 0.025 keyframes {{ t: 0 tip {{ x: -0.003 y: 0 z: 0.1 }} blade_dir {{ z: 1 }} }} }}
cutting {{ enabled: true alpha: 0.4 kappa: 1.0 zeta: 1.0 critical_stress: 1 }}
)pb",
                     nx * h, ny * h, nz * h, nx, ny, nz, threads, precision_enum);
}

// Hash of the world mesh (tets and positions), printed to stderr so a
// change that claims identical cut results can be checked before/after.
uint64_t MeshHash(const Simulation& sim) {
  const cutsim::mesh::TetMesh m = sim.WorldMesh();
  const uint64_t h = cutsim::Fnv1a64(m.tets.data(), static_cast<size_t>(m.tets.size()) * sizeof(m.tets(0, 0)));
  return cutsim::Fnv1a64(m.nodes.data(), static_cast<size_t>(m.nodes.size()) * sizeof(double), h);
}

struct StepResult {
  int tets = 0;
  std::vector<CutStepTiming> timings;
  int64_t attempts = 0, rejected = 0;
};

// Streams through `buffer` (read and write, a line at a time) so that the
// data of the previous step is in no cache level: the state a cut step meets
// at 100k tets, where the FEM steps in between stream the whole state.
void EvictCaches(std::vector<double>& buffer) {
  double sum = 0;
  for (size_t i = 0; i < buffer.size(); i += 8) {
    sum += buffer[i];
    buffer[i] = sum * 1e-300;
  }
  volatile double sink = sum;
  (void)sink;
}

StepResult RunStepBench(int nx, int ny, int nz, int threads, const std::string& precision, int evict_mb) {
  const cutsim::sim::LoadedScene scene =
      cutsim::sim::ParseScene(BoxScene(nx, ny, nz, threads, precision), "cut_bench box", ".");
  auto sim = Simulation::Create(scene);
  const double h = 0.002;
  const double y = (ny / 2) * h + 0.0001;  // 0.1 mm beside a row of nodes
  const double top = nz * h;
  const double x_end = std::min(nx * h + 0.003, 0.030);  // ≤ 30 mm of path: same work at every size
  const double speed = 0.00025;                          // m per frame
  ToolPose pose;
  pose.blade_dir = Vector3d::UnitZ();
  const double depth = 0.005;
  std::vector<double> evict_buffer(static_cast<size_t>(evict_mb) * (1 << 20) / sizeof(double), 1.0);
  for (double x = -0.003; x <= x_end; x += speed) {
    if (!evict_buffer.empty()) EvictCaches(evict_buffer);
    pose.tip = Vector3d(x, y, top - depth);
    sim->SetToolPose(pose);
    if (sim->AdvanceFrame() != cutsim::sim::SimStatus::kOk) break;
  }
  StepResult r;
  const auto s = sim->QuickSummary();
  std::fprintf(stderr,
               "step bench: %d tets, %d threads, %llu cuts, %lld steps, %.1f s wall, stable dt %.3g s, "
               "mesh hash %016llx\n",
               s.num_tets, threads, static_cast<unsigned long long>(s.cuts), static_cast<long long>(s.steps),
               s.wall_time, s.stable_dt, static_cast<unsigned long long>(MeshHash(*sim)));
  r.tets = s.num_tets;
  r.timings = sim->CutTimings();
  r.attempts = static_cast<int64_t>(s.cut_attempts);
  r.rejected = static_cast<int64_t>(s.cuts_rejected);
  return r;
}

double MinQuality(const Simulation& sim) {
  const cutsim::mesh::TetQuality q = cutsim::mesh::ComputeTetQuality(sim.WorldMesh());
  return *std::min_element(q.mean_ratio.begin(), q.mean_ratio.end());
}

// Frames with the tool lifted clear: wall seconds and tet-steps.
std::pair<double, double> Rounds(Simulation& sim, int frames) {
  const int64_t steps0 = sim.QuickSummary().steps;
  Stopwatch watch;
  for (int i = 0; i < frames; ++i) (void)sim.AdvanceFrame();
  const double wall = watch.ElapsedSeconds();
  const auto s = sim.QuickSummary();
  return {wall, static_cast<double>(s.steps - steps0) * s.num_tets};
}

/// Prints `json` (non-finite numbers as null), writes it to `path` if given,
/// and returns the exit code: 1 if the file cannot be written or a target
/// was missed.
int Emit(const std::string& json, const std::string& path, const std::vector<std::string>& missed) {
  const std::string text = cutsim::bench::NullNonFinite(json);
  std::fputs(text.c_str(), stdout);
  if (!path.empty() && !cutsim::bench::WriteTextFile("cut_bench", path, text)) return 1;
  return cutsim::bench::ExitCodeForTargets("cut_bench", missed);
}

}  // namespace

int main(int argc, char** argv) {
  std::string json_path;
  std::string scene_dir = "scenes";
  int max_tets = 100000;
  int target_cuts = 100;
  int min_tets = 0;
  bool step_only = false;
  std::string precision = "double";
  int evict_mb = 0;
  CLI::App app{"cut step time, stable step and throughput after cuts"};
  app.add_option("--json", json_path, "Also write the JSON here");
  app.add_option("--scene-dir", scene_dir, "Where block.pbtxt is");
  app.add_option("--max-tets", max_tets, "Skip step sizes above this");
  app.add_option("--cuts", target_cuts, "Cut steps on block for (b) and (c)");
  app.add_option("--min-tets", min_tets, "Skip step sizes below this");
  app.add_flag("--step-only", step_only, "Only (a), the cut step times");
  app.add_option("--precision", precision, "FEM precision of (a)'s boxes")
      ->check(CLI::IsMember({"double", "float"}));
  app.add_option("--evict-mb", evict_mb,
                 "(a): before every frame, stream this many MiB through the caches (0: off), so every size "
                 "meets a cut step with cold caches, as 100k tets does")
      ->check(CLI::Range(0, 4096));
  CLI11_PARSE(app, argc, argv);
  cutsim::InitLogging("cut_bench", "warn");

  std::string json = "{\n  \"step\": [";
  // (a) ~1k, 10k, 100k tets, 2 mm cells, one thread; then 100k again with
  // two where the machine has them (the server's default from 20 000 tets:
  // the criterion then runs beside the slab walk, and the FEM half beside
  // the surface half). "total" is the step's wall time.
  struct Config {
    int nx, ny, nz, threads;
  };
  std::vector<Config> configs = {{8, 5, 4, 1}, {17, 10, 10, 1}, {37, 22, 20, 1}};
  if (omp_get_num_procs() >= 2) configs.push_back({37, 22, 20, 2});
  bool first = true;
  for (const Config& c : configs) {
    const int tets = 6 * c.nx * c.ny * c.nz;
    if (tets > max_tets || tets < min_tets) continue;
    const StepResult r = RunStepBench(c.nx, c.ny, c.nz, c.threads, precision, evict_mb);
    std::vector<double> total, criterion, topology, fem, surface, apply, splits;
    for (const CutStepTiming& t : r.timings) {
      total.push_back(t.wall);
      criterion.push_back(t.criterion);
      topology.push_back(t.topology);
      fem.push_back(t.fem);
      surface.push_back(t.surface);
      apply.push_back(t.apply);
      splits.push_back(t.splits);
    }
    json += fmt::format(
        "{}\n    {{\"tets\": {}, \"threads\": {}, \"evict_mb\": {}, \"cut_steps\": {}, \"attempts\": {}, \"rejected\": {}, "
        "\"median_splits\": {:.1f},\n     \"total\": {},\n     \"criterion\": {},\n     \"topology\": {},\n"
        "     \"fem_update\": {},\n     \"surface_bvh\": {},\n     \"fem_and_surface_wall\": {}}}",
        first ? "" : ",", r.tets, c.threads, evict_mb, r.timings.size(), r.attempts, r.rejected, Quantile(splits, 0.5),
        Stats(total), Stats(criterion), Stats(topology), Stats(fem), Stats(surface), Stats(apply));
    first = false;
    std::fflush(stdout);
  }
  json += "\n  ],\n";
  if (step_only) {
    json += "  \"block\": null,\n  \"throughput\": null\n}\n";
    return Emit(json, json_path, {});
  }

  // (b) block: parallel half-depth passes 0.1 mm beside the node rows (2.5 mm apart).
  // K_I = 1 Pa, as in (a): every geometric attempt cuts, so the passes make
  // many small cut steps (with the scene's K_I the blade's grip loads the
  // tissue until it gives way and one step opens what it swept since the
  // last: 6 steps for the whole line, too few for "after 100 cut steps").
  cutsim::sim::LoadedScene block = cutsim::sim::LoadScene(scene_dir + "/block.pbtxt");
  block.scene.mutable_cutting()->set_critical_stress(1.0);
  auto uncut = Simulation::Create(block);
  auto cut = Simulation::Create(block);
  ToolPose lifted;
  lifted.tip = Vector3d(0.02, 0.01, 0.05);
  uncut->SetToolPose(lifted);
  (void)uncut->AdvanceFrame();
  const double dt_uncut = uncut->Summary().stable_dt;
  const double q_uncut = MinQuality(*uncut);
  ToolPose pose;
  const double speed = 0.0005;  // m per 10 ms frame
  // Moves the tool to `to` in frames of at most `step`; true once
  // target_cuts steps have executed (stops there unless `to_the_end`).
  auto glide = [&](const Vector3d& to, double step, bool to_the_end = false) {
    const Vector3d from = pose.tip;
    const int frames = std::max(1, static_cast<int>(std::ceil((to - from).norm() / step)));
    bool reached = false;
    for (int i = 1; i <= frames; ++i) {
      pose.tip = from + (to - from) * (static_cast<double>(i) / frames);
      cut->SetToolPose(pose);
      (void)cut->AdvanceFrame();
      reached = static_cast<int>(cut->QuickSummary().cuts) >= target_cuts;
      if (reached && !to_the_end) return true;
    }
    return reached;
  };
  pose.tip = Vector3d(-0.003, 0.0026, 0.05);
  bool done = false;
  for (int pass = 0; pass < 7 && !done; ++pass) {
    const double y = 0.0026 + 0.0025 * pass;
    done = glide(Vector3d(-0.003, y, 0.05), 0.002) || glide(Vector3d(-0.003, y, 0.005), 0.002) ||
           glide(Vector3d(0.043, y, 0.005), speed) || glide(Vector3d(0.043, y, 0.05), 0.002);
  }
  // Lift the blade out along itself, then park it clear. Both glides run to
  // the end even once the target is reached: a blade left in the last slit
  // during (b) and (c) keeps the cut copy shaking, which is not the state
  // (b) and (c) compare with the uncut copy.
  (void)glide(Vector3d(pose.tip.x(), pose.tip.y(), 0.05), 0.002, true);
  (void)glide(Vector3d(0.02, 0.01, 0.05), 0.002, true);
  for (int i = 0; i < 20; ++i) (void)cut->AdvanceFrame();  // settle, tool clear
  const auto cs = cut->Summary();
  std::fprintf(stderr, "block: %llu cuts after %lld steps, mesh hash %016llx\n", static_cast<unsigned long long>(cs.cuts),
               static_cast<long long>(cs.steps), static_cast<unsigned long long>(MeshHash(*cut)));
  const double q_cut = MinQuality(*cut);
  json += fmt::format(
      "  \"block\": {{\"cut_steps\": {}, \"attempts\": {}, \"rejected\": {}, \"tets\": {}, \"nodes_uncut\": {}, "
      "\"nodes_cut\": {}, \"components\": {},\n            \"stable_dt_uncut\": {:.4g}, \"stable_dt_cut\": {:.4g}, "
      "\"stable_dt_ratio\": {:.3f}, \"min_quality_uncut\": {:.3f}, \"min_quality_cut\": {:.3f}, \"status\": \"{}\"}},\n",
      cs.cuts, cs.cut_attempts, cs.cuts_rejected, cs.num_tets, uncut->Summary().num_nodes, cs.num_nodes,
      cs.components, dt_uncut, cs.stable_dt, cs.stable_dt / dt_uncut, q_uncut, q_cut, cs.status);

  // (c) throughput, alternating rounds of 10 frames. Also the states
  // compared (kinetic energy, tool contact) and steps per frame: tet-steps/s
  // is the cost per step, the frame rate also pays for a smaller step.
  const double ke_uncut = uncut->QuickSummary().kinetic_energy, ke_cut = cut->QuickSummary().kinetic_energy;
  const bool touching = cut->Tool().touching;
  const int64_t steps_uncut0 = uncut->QuickSummary().steps, steps_cut0 = cut->QuickSummary().steps;
  constexpr int kRounds = 7, kFramesPerRound = 10;
  std::vector<double> ratios, rate_uncut, rate_cut;
  for (int round = 0; round < kRounds; ++round) {
    const auto [wu, su] = Rounds(*uncut, kFramesPerRound);
    const auto [wc, sc] = Rounds(*cut, kFramesPerRound);
    rate_uncut.push_back(su / wu);
    rate_cut.push_back(sc / wc);
    ratios.push_back((sc / wc) / (su / wu));
  }
  const double frames = kRounds * kFramesPerRound;
  json += fmt::format(
      "  \"throughput\": {{\"tet_steps_per_s_uncut\": {:.4g}, \"tet_steps_per_s_cut\": {:.4g}, \"ratio\": {:.3f}, "
      "\"rounds\": {},\n                 \"steps_per_frame_uncut\": {:.1f}, \"steps_per_frame_cut\": {:.1f}, "
      "\"kinetic_energy_uncut\": {:.3g}, \"kinetic_energy_cut\": {:.3g}, \"tool_touching\": {}}}\n}}\n",
      Quantile(rate_uncut, 0.5), Quantile(rate_cut, 0.5), Quantile(ratios, 0.5), ratios.size(),
      static_cast<double>(uncut->QuickSummary().steps - steps_uncut0) / frames,
      static_cast<double>(cut->QuickSummary().steps - steps_cut0) / frames, ke_uncut, ke_cut, touching);
  // The block run states its end status: a guard stop means (b) and (c)
  // measured a broken state.
  std::vector<std::string> missed;
  if (cs.status != "ok") missed.push_back("block run ended with status " + cs.status);
  return Emit(json, json_path, missed);
}
