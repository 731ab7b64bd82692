// The numerical stability stress suite (cases in
// tests/support/stability_cases.h; a short version runs as tests/unit/sim/
// stability_test.cc). Prints a Markdown table on stdout and writes JSON.
// Each case states what it expects (holds, or is stopped cleanly by a
// guard); the exit code is 1 when a case is not as expected.
//
//   stability_bench [--out stability.json] [--long-steps 1000000] [--strokes 300] [--only TEXT]
//                   [--scene scenes/block.pbtxt]
//                   [--suite-scenes scenes/organ.pbtxt,scenes/block.pbtxt] [--suite-strokes 100]
//
// Then the randomized stroke suite (tests/support/stroke_suite.h) on each
// of --suite-scenes (a scene file that does not exist is skipped): a case
// fails when a stroke stops the run, or a cut leaves an invalid mesh or
// moves the mass.
#include <cstdio>
#include <filesystem>
#include <sstream>
#include <string>
#include <vector>

#include <CLI/CLI.hpp>

#include "bench/json_text.h"
#include "common/core/log.h"
#include "tests/support/stability_cases.h"
#include "tests/support/stroke_suite.h"

namespace cutsim::support::stability {
namespace {

using bench::Appendf;
using bench::ExitCodeForTargets;
using bench::JsonEscape;
using bench::NullNonFinite;
using bench::WriteTextFile;

/// The results as one JSON document ({"cases": [...]}); non-finite numbers
/// are written as null.
std::string ResultsJson(const std::vector<Result>& results) {
  std::string json = "{\"cases\": [\n";
  for (size_t i = 0; i < results.size(); ++i) {
    const Result& r = results[i];
    Appendf(json,
            "  {\"name\": \"%s\", \"expectation\": \"%s\", \"holds\": %s, \"physical\": %s, \"expected_ok\": %s, "
            "\"reason\": \"%s\", \"tets\": %d, \"steps\": %lld, \"sim_time_s\": %.6g, \"wall_s\": %.6g, "
            "\"finite\": %s, \"mass_rel_change\": %.3g, \"max_inverted\": %d, \"final_inverted\": %d, \"min_det_f\": %.6g, "
            "\"spectral_refreshes\": %lld, \"transient_fraction\": %.4g, \"min_dt_s\": %.6g, "
            "\"max_dt_s\": %.6g, \"step_status\": \"%s\", \"energy_drift\": %.6g, \"cuts\": %llu, "
            "\"rejected_cuts\": %llu}%s\n",
            JsonEscape(r.name).c_str(), JsonEscape(r.expectation).c_str(), r.holds ? "true" : "false",
            r.physical ? "true" : "false", r.expected_ok ? "true" : "false", JsonEscape(r.reason).c_str(), r.tets,
            static_cast<long long>(r.steps), r.sim_time, r.wall, r.finite ? "true" : "false", r.mass_rel_change,
            r.max_inverted, r.final_inverted, r.min_det_f, static_cast<long long>(r.spectral_refreshes),
            r.transient_fraction, r.min_dt, r.max_dt, JsonEscape(r.step_status).c_str(), r.energy_drift,
            static_cast<unsigned long long>(r.cuts), static_cast<unsigned long long>(r.rejected_cuts),
            i + 1 == results.size() ? "" : ",");
  }
  json += "]}\n";
  return NullNonFinite(json);
}

int Main(int argc, char** argv) {
  std::string out_path, scene_path = "scenes/block.pbtxt";
  Size size = Size::Bench();
  CLI::App app{"numerical stability stress suite"};
  app.add_option("--out", out_path, "JSON output file");
  app.add_option("--scene", scene_path, "The block scene (cutting and tool cases)");
  app.add_option("--long-steps", size.long_steps, "Steps of the long run");
  app.add_option("--strokes", size.strokes, "Random cut strokes");
  app.add_option("--cells", size.cells, "Cube side in cells of the loading cases");
  std::string only;
  app.add_option("--only", only, "Only the cases whose name contains this (e.g. \"long run\", \"corner\")");
  std::string suite_scenes = "scenes/organ.pbtxt,scenes/block.pbtxt,scenes/skin_pad.pbtxt";
  int suite_strokes = 100;
  app.add_option("--suite-scenes", suite_scenes, "Comma-separated scenes of the randomized stroke suite (\"\": none)");
  app.add_option("--suite-strokes", suite_strokes, "Strokes per scene of the randomized stroke suite")
      ->check(CLI::Range(0, 100000));
  bool fixed_only = false;
  std::vector<double> fixed_fractions = {0.5, kFixedStepResonanceOnset, 0.75, 1.0};
  app.add_flag("--fixed-dt-only", fixed_only, "Only the fixed-dt cases (--fixed-fractions of the start's limit)");
  app.add_option("--fixed-fractions", fixed_fractions, "Steps of --fixed-dt-only, as fractions of the start's limit")
      ->delimiter(',')
      ->check(CLI::Range(0.01, 0.999));
  int64_t fixed_steps = 0;
  app.add_option("--fixed-steps", fixed_steps, "Steps of each --fixed-dt-only case (0: the suite's)")
      ->check(CLI::Range(int64_t{0}, int64_t{10'000'000}));
  CLI11_PARSE(app, argc, argv);
  InitLogging("stability_bench", "error");

  std::printf("| case | expected | result | physical | tets | steps | wall s | inversion guard: peak elements (min det F) | "
              "inverted at end | Lanczos refreshes / transient frames | dt min–max µs | step guard | energy drift | cuts (rejected) | "
              "finite, mass | note |\n");
  std::printf("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|\n");
  std::fflush(stdout);
  // Rows are printed as cases finish, so a run cut short still leaves them.
  const auto print_row = [](const Result& r) {
    std::fprintf(stderr, "[stability] %-60s %s in %.2f s (%lld steps): %s\n", r.name.c_str(),
                 r.expected_ok ? (r.holds ? "holds" : "as expected") : "FAILS", r.wall,
                 static_cast<long long>(r.steps), r.reason.c_str());
    std::printf("| %s | %s | %s | %s | %d | %lld | %.2f | %d (%.3g) | %d | %lld / %.0f%% | %.3g–%.3g | %s | %s | %llu (%llu) | "
                "%s, %.1e | %s |\n",
                r.name.c_str(), r.expectation.c_str(),
                r.expected_ok ? (r.holds ? "**holds**" : "**as expected**") : "**FAILS**",
                r.physical ? "yes" : "no", r.tets,
                static_cast<long long>(r.steps), r.wall, r.max_inverted, r.min_det_f,
                r.final_inverted, static_cast<long long>(r.spectral_refreshes), 100 * r.transient_fraction, 1e6 * r.min_dt,
                1e6 * r.max_dt, r.step_status.c_str(),
                r.energy_drift >= 0 ? std::to_string(r.energy_drift).c_str() : "–",
                static_cast<unsigned long long>(r.cuts), static_cast<unsigned long long>(r.rejected_cuts),
                r.finite ? "yes" : "NO", r.mass_rel_change, r.reason.c_str());
    std::fflush(stdout);
  };
  std::vector<Result> results;
  if (fixed_only) {
    for (const double frac : fixed_fractions) {
      results.push_back(FixedStep("fixed dt = " + std::to_string(frac).substr(0, 4) + " x initial Lanczos limit",
                                  size.cells, fixed_steps > 0 ? fixed_steps : size.dt_steps, frac, false));
      print_row(results.back());
    }
  } else {
    results = RunAll(size, scene_path, print_row, only);
  }
  if (!fixed_only && suite_strokes > 0) {
    std::stringstream list(suite_scenes);
    for (std::string path; std::getline(list, path, ',');) {
      if (path.empty() || !std::filesystem::exists(path)) continue;
      if (!only.empty() && ("stroke suite " + path).find(only) == std::string::npos) continue;
      const strokes::SuiteResult sr = strokes::RunStrokes(path, suite_strokes, 39);
      Result r;
      r.name = "stroke suite: " + std::to_string(sr.strokes) + " random strokes on " + path;
      r.holds = sr.ok() && sr.strokes == suite_strokes;
      r.expected_ok = r.holds;
      r.physical = r.holds;
      r.steps = sr.frames;
      r.sim_time = sr.sim_time;
      r.wall = sr.wall;
      r.cuts = sr.cuts;
      r.step_status = sr.stopped == 0 ? "ok" : "stopped";
      r.reason = std::to_string(sr.stopped) + " stopped, " + std::to_string(sr.invalid_meshes) + " invalid meshes, " +
                 std::to_string(sr.mass_changes) + " mass changes after " + std::to_string(sr.cut_frames) +
                 " cut frames (" + std::to_string(sr.cuts) + " cuts); " + std::to_string(sr.recovered_steps) +
                 " implicit steps recovered in substeps" +
                 (sr.first_failure.empty() ? "" : "; first: " + sr.first_failure);
      print_row(r);
      results.push_back(std::move(r));
    }
  }
  if (!out_path.empty() && !WriteTextFile("stability_bench", out_path, ResultsJson(results))) return 1;
  std::vector<std::string> missed;
  for (const Result& r : results) {
    if (!r.expected_ok) missed.push_back(r.name + ": " + r.reason);
  }
  std::fprintf(stderr, "stability_bench: %zu cases, %zu not as expected\n", results.size(), missed.size());
  return ExitCodeForTargets("stability_bench", missed);
}

}  // namespace
}  // namespace cutsim::support::stability

int main(int argc, char** argv) { return cutsim::support::stability::Main(argc, argv); }
