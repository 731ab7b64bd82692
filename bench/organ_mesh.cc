// Organ mesh quality study: the generated organ (MakeOrgan) with and without
// the sliver cleanup (common/mesh/cleanup.h), reporting what sets the
// explicit FEM's stable step: min mean ratio, shortest altitudes, and the
// per-element stable-step bound for a tissue material. JSON on stdout.
//
//   organ_mesh [--edge 0.004] [--axes 0.06,0.035,0.03] [--E 20000] [--nu 0.45]
#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <string>
#include <vector>

#include "bench/json_text.h"
#include "common/fem/model.h"
#include "common/fem/stable_dt.h"
#include "common/fem/state.h"
#include "common/mesh/generators.h"
#include "common/mesh/quality.h"

using namespace cutsim;
using cutsim::bench::Appendf;

namespace {

double Median(std::vector<double> v) {
  std::nth_element(v.begin(), v.begin() + static_cast<long>(v.size() / 2), v.end());
  return v[v.size() / 2];
}

void Report(std::string& json, const char* name, const mesh::TetMesh& m, double seconds, double E, double nu, const mesh::CleanupReport* r,
            bool last) {
  const mesh::TetQuality q = mesh::ComputeTetQuality(m);
  const double min_q = *std::min_element(q.mean_ratio.begin(), q.mean_ratio.end());
  int below = 0;
  for (double x : q.mean_ratio) below += x < 0.3 ? 1 : 0;
  const double min_alt = *std::min_element(q.shortest_altitude.begin(), q.shortest_altitude.end());
  const double med_alt = Median(q.shortest_altitude);
  const fem::Material mat = fem::Material::FromYoungPoisson(E, nu, 1000.0);
  const fem::Model<double> model(m, std::span(&mat, 1));
  fem::State<double> state(model);
  fem::RefreshStableStep(model, state, false);
  const double dt = fem::StableStepBound(state);
  double vol = 0;
  for (int32_t t = 0; t < m.num_tets(); ++t) vol += mesh::SignedVolume(m, t);
  Appendf(json,
      "  \"%s\": {\"tets\": %d, \"nodes\": %d, \"seconds\": %.3f, \"volume_m3\": %.6g, \"min_mean_ratio\": %.4f, "
      "\"tets_below_0_3\": %d, \"min_altitude_m\": %.4g, \"median_altitude_m\": %.4g, \"altitude_ratio\": %.2f, "
      "\"stable_dt_bound_s\": %.4g",
      name, m.num_tets(), m.num_nodes(), seconds, vol, min_q, below, min_alt, med_alt, med_alt / min_alt, dt);
  if (r != nullptr) {
    Appendf(json, ", \"removed_tets\": %d, \"removed_nodes\": %d, \"moved_nodes\": %d, \"removed_volume_m3\": %.4g",
                r->removed_tets, r->removed_nodes, r->moved_nodes, r->removed_volume);
  }
  Appendf(json, "}%s\n", last ? "" : ",");
}

}  // namespace

int main(int argc, char** argv) {
  mesh::OrganOptions o;
  double E = 20000, nu = 0.45;
  for (int i = 1; i + 1 < argc; i += 2) {
    const std::string k = argv[i];
    if (k == "--edge") o.edge_length = std::atof(argv[i + 1]);
    if (k == "--E") E = std::atof(argv[i + 1]);
    if (k == "--nu") nu = std::atof(argv[i + 1]);
    if (k == "--sliver") o.fill.cleanup_options.sliver_quality = std::atof(argv[i + 1]);
    if (k == "--smooth") o.fill.cleanup_options.smooth_quality = std::atof(argv[i + 1]);
    if (k == "--gmsh-opt") o.fill.gmsh_optimize_threshold = std::atof(argv[i + 1]);
    if (k == "--axes") std::sscanf(argv[i + 1], "%lf,%lf,%lf", &o.semi_axes.x(), &o.semi_axes.y(), &o.semi_axes.z());
  }
  std::string json;
  Appendf(json, "{\n  \"edge_length\": %g, \"semi_axes\": [%g, %g, %g], \"E\": %g, \"nu\": %g,\n", o.edge_length,
              o.semi_axes.x(), o.semi_axes.y(), o.semi_axes.z(), E, nu);
  using Clock = std::chrono::steady_clock;
  o.fill.cleanup = false;
  auto t0 = Clock::now();
  const mesh::TetMesh raw = mesh::MakeOrgan(o);
  const double s_raw = std::chrono::duration<double>(Clock::now() - t0).count();
  Report(json, "gmsh", raw, s_raw, E, nu, nullptr, false);
  mesh::CleanupReport rep;
  o.fill.cleanup = true;
  o.fill.report = &rep;
  t0 = Clock::now();
  const mesh::TetMesh clean = mesh::MakeOrgan(o);
  const double s_clean = std::chrono::duration<double>(Clock::now() - t0).count();
  Report(json, "cleaned", clean, s_clean, E, nu, &rep, true);
  Appendf(json, "}\n");
  std::fputs(bench::NullNonFinite(json).c_str(), stdout);
  return 0;
}
