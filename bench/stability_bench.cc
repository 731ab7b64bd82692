// The numerical stability stress suite of issue #8 (cases in
// bench/stability_cases.h; a short version runs as tests/unit/fem/
// stability_test.cc). Prints a Markdown table on stdout and writes JSON.
//
//   stability_bench [--out stability.json] [--long-steps 1000000] [--strokes 300] [--only TEXT]
//                   [--scene scenes/block.pbtxt]
#include <cstdio>
#include <string>

#include <CLI/CLI.hpp>

#include "bench/stability_cases.h"
#include "common/core/log.h"

namespace cutsim::bench::stability {
namespace {

std::string Escape(const std::string& s) {
  std::string out;
  for (const char c : s) {
    if (c == '"' || c == '\\') out += '\\';
    out += c;
  }
  return out;
}

int Main(int argc, char** argv) {
  std::string out_path, scene_path = "scenes/block.pbtxt";
  Size size = Size::Bench();
  CLI::App app{"numerical stability stress suite (issue #8)"};
  app.add_option("--out", out_path, "JSON output file");
  app.add_option("--scene", scene_path, "The block scene (cutting and tool cases)");
  app.add_option("--long-steps", size.long_steps, "Steps of the long run");
  app.add_option("--strokes", size.strokes, "Random cut strokes");
  app.add_option("--cells", size.cells, "Cube side in cells of the loading cases");
  std::string only;
  app.add_option("--only", only, "Only the cases whose name contains this (e.g. \"long run\", \"corner\")");
  bool fixed_only = false;
  app.add_flag("--fixed-dt-only", fixed_only, "Only the fixed-dt cases at 0.5 / 0.75 / 1.0 of the start's limit");
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
    for (const double frac : {0.5, 0.75, 1.0}) {
      results.push_back(FixedStep("fixed dt = " + std::to_string(frac).substr(0, 4) + " x initial Lanczos limit",
                                  size.cells, size.dt_steps, frac, false));
      print_row(results.back());
    }
  } else {
    results = RunAll(size, scene_path, print_row, only);
  }
  if (!out_path.empty()) {
    std::FILE* out = std::fopen(out_path.c_str(), "w");
    if (!out) {
      std::fprintf(stderr, "stability_bench: cannot write %s\n", out_path.c_str());
      return 1;
    }
    std::fprintf(out, "{\"cases\": [\n");
    for (size_t i = 0; i < results.size(); ++i) {
      const Result& r = results[i];
      std::fprintf(out,
                   "  {\"name\": \"%s\", \"expectation\": \"%s\", \"holds\": %s, \"physical\": %s, \"expected_ok\": %s, "
                   "\"reason\": \"%s\", \"tets\": %d, \"steps\": %lld, \"sim_time_s\": %.6g, \"wall_s\": %.6g, "
                   "\"finite\": %s, \"mass_rel_change\": %.3g, \"max_inverted\": %d, \"final_inverted\": %d, \"min_det_f\": %.6g, "
                   "\"spectral_refreshes\": %lld, \"transient_fraction\": %.4g, \"min_dt_s\": %.6g, "
                   "\"max_dt_s\": %.6g, \"step_status\": \"%s\", \"energy_drift\": %.6g, \"cuts\": %llu, "
                   "\"rejected_cuts\": %llu}%s\n",
                   Escape(r.name).c_str(), Escape(r.expectation).c_str(), r.holds ? "true" : "false", r.physical ? "true" : "false",
                   r.expected_ok ? "true" : "false", Escape(r.reason).c_str(), r.tets,
                   static_cast<long long>(r.steps), r.sim_time, r.wall, r.finite ? "true" : "false",
                   r.mass_rel_change, r.max_inverted, r.final_inverted, r.min_det_f, static_cast<long long>(r.spectral_refreshes),
                   r.transient_fraction, r.min_dt, r.max_dt, Escape(r.step_status).c_str(), r.energy_drift,
                   static_cast<unsigned long long>(r.cuts), static_cast<unsigned long long>(r.rejected_cuts),
                   i + 1 == results.size() ? "" : ",");
    }
    std::fprintf(out, "]}\n");
    std::fclose(out);
  }
  int unexpected = 0;
  for (const Result& r : results) unexpected += r.expected_ok ? 0 : 1;
  std::fprintf(stderr, "stability_bench: %zu cases, %d not as expected\n", results.size(), unexpected);
  return 0;
}

}  // namespace
}  // namespace cutsim::bench::stability

int main(int argc, char** argv) { return cutsim::bench::stability::Main(argc, argv); }
