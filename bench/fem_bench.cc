// Force-kernel and full-step throughput of common/fem, with a STREAM-triad
// memory-bandwidth benchmark in the same binary so results can be read as a
// fraction of the roofline. Meshes are Kuhn-split boxes built once and cached.
//
// Counters: tet_steps_per_s (rate), tets, nodes, bytes_per_tet (estimated
// DRAM traffic of one force pass: element data + element-force write and
// re-read + incidence; node arrays assumed cached), and for the triad
// bytes_per_s.
#include <omp.h>

#include <algorithm>
#include <array>
#include <chrono>
#include <cstdio>
#include <map>
#include <memory>
#include <string>
#include <utility>
#include <vector>

#include <benchmark/benchmark.h>

#include "common/fem/forces.h"
#include "common/fem/integrator.h"
#include "common/fem/model.h"
#include "common/fem/stable_dt.h"
#include "common/fem/state.h"
#include "common/mesh/generators.h"
#include "common/mesh/tet_mesh.h"
#include "common/sim/session_metrics.h"

namespace cutsim::fem {
namespace {

mesh::TetMesh MakeBox(int nx, int ny, int nz, double h) {
  return mesh::MakeBox(Eigen::Vector3d::Zero(), Eigen::Vector3d(h * nx, h * ny, h * nz), nx, ny, nz);
}

// ~1k, 10k, 100k, 1M tets.
constexpr std::array<std::array<int, 3>, 4> kSizes = {
    {{6, 6, 5}, {12, 12, 12}, {26, 26, 25}, {55, 55, 55}}};

template <typename T>
struct Fixture {
  std::unique_ptr<Model<T>> model_damped, model_plain;
  std::unique_ptr<State<T>> state;
};

template <typename T>
Fixture<T>& GetFixture(int size_index) {
  static std::map<int, Fixture<T>> cache;
  auto it = cache.find(size_index);
  if (it != cache.end()) return it->second;
  const auto& s = kSizes[static_cast<size_t>(size_index)];
  const mesh::TetMesh mesh = MakeBox(s[0], s[1], s[2], 1e-3);
  const Material damped{.lambda = 140000, .mu = 11000, .psi = 10, .phi = 80, .density = 1000};
  Material plain = damped;
  plain.psi = plain.phi = 0;
  Fixture<T> f;
  const ModelOptions mo{.gravity = Eigen::Vector3d(0, 0, -9.81)};
  f.model_damped = std::make_unique<Model<T>>(mesh, std::span(&damped, 1), mo);
  f.model_plain = std::make_unique<Model<T>>(mesh, std::span(&plain, 1), mo);
  for (int n = 0; n < (s[0] + 1) * (s[1] + 1); ++n) {  // bottom face fixed
    f.model_damped->SetFixed(n, true);
    f.model_plain->SetFixed(n, true);
  }
  f.state = std::make_unique<State<T>>(*f.model_damped);
  // A small deformation so no branch sees the trivial rest state.
  for (size_t i = 0; i < f.state->x.size(); ++i) {
    f.state->x[i] *= T(1) + T(1e-3) * static_cast<T>(i % 7);
    f.state->v[i] = T(1e-3) * static_cast<T>(i % 5);
  }
  return cache.emplace(size_index, std::move(f)).first->second;
}

template <typename T>
double BytesPerTet(bool damped) {
  // Dm⁻¹ (9) + vol + λ + μ (+ ψ + φ) + element force write + read (24),
  // plus 4 tet indices and 4 incidence slots (int32).
  return static_cast<double>(sizeof(T)) * (9 + 3 + (damped ? 2 : 0) + 24) + 8 * 4;
}

template <typename T>
void BM_Force(benchmark::State& st) {
  const int size_index = static_cast<int>(st.range(0));
  const int threads = static_cast<int>(st.range(1));
  const bool damped = st.range(2) != 0;
  Fixture<T>& f = GetFixture<T>(size_index);
  const Model<T>& model = damped ? *f.model_damped : *f.model_plain;
  std::vector<T> out(f.state->x.size());
  const ForceMode mode = damped ? ForceMode::kElasticDamped : ForceMode::kElastic;
  for (auto _ : st) {
    ComputeInternalForces(model, *f.state, mode, out.data(), threads);
    benchmark::DoNotOptimize(out.data());
    benchmark::ClobberMemory();
  }
  const double tets = model.num_tets();
  st.counters["tets"] = tets;
  st.counters["nodes"] = model.num_nodes();
  st.counters["threads"] = threads;
  st.counters["bytes_per_tet"] = BytesPerTet<T>(damped);
  st.counters["tet_steps_per_s"] =
      benchmark::Counter(tets * static_cast<double>(st.iterations()), benchmark::Counter::kIsRate);
}

template <typename T>
void BM_Step(benchmark::State& st) {
  const int size_index = static_cast<int>(st.range(0));
  const int threads = static_cast<int>(st.range(1));
  const bool damped = st.range(2) != 0;
  Fixture<T>& f = GetFixture<T>(size_index);
  const Model<T>& model = damped ? *f.model_damped : *f.model_plain;
  State<T> state(model);  // fresh, allocated outside the timed loop
  state.x = f.state->x;
  StepOptions opt;
  opt.num_threads = threads;
  RefreshStableStep(model, state, true, threads);
  const T dt = T(0.5) * StableStepBound(state);
  for (auto _ : st) {
    const StepResult r = Step(model, state, dt, opt);
    if (!r.ok()) {
      st.SkipWithError("step failed");
      break;
    }
  }
  const double tets = model.num_tets();
  st.counters["tets"] = tets;
  st.counters["nodes"] = model.num_nodes();
  st.counters["threads"] = threads;
  st.counters["tet_steps_per_s"] =
      benchmark::Counter(tets * static_cast<double>(st.iterations()), benchmark::Counter::kIsRate);
}

// The skip table at ~100k tets, 1 thread: each skip against
// the same scene with the work forced on.
//   case 0: damping (ψ = φ = 0): force pass kElastic (skipped) vs kElasticDamped
//           evaluated with zero coefficients (forced on).
//   case 1: gravity off (skipped) vs gravity on, full step.
//   case 2: fixed nodes: bottom layer fixed (not integrated) vs no node fixed,
//           full step (the same force work; the difference is the integration).
void BM_Skip(benchmark::State& st) {
  const int which = static_cast<int>(st.range(0));
  const bool work_on = st.range(1) != 0;
  const auto& s = kSizes[2];
  static const mesh::TetMesh mesh = MakeBox(s[0], s[1], s[2], 1e-3);
  const Material plain{.lambda = 140000, .mu = 11000, .psi = 0, .phi = 0, .density = 1000};
  ModelOptions mo;
  if (which == 1 && work_on) mo.gravity = Eigen::Vector3d(0, 0, -9.81);
  Model<double> model(mesh, std::span(&plain, 1), mo);
  const int fixed_layers = which == 2 ? (work_on ? 0 : s[2] / 2) : 1;
  for (int n = 0; n < (s[0] + 1) * (s[1] + 1) * fixed_layers; ++n) model.SetFixed(n, true);
  State<double> state(model);
  for (size_t i = 0; i < state.x.size(); ++i) state.x[i] *= 1.0 + 1e-3 * static_cast<double>(i % 7);
  std::vector<double> out(state.x.size());
  StepOptions opt;
  opt.num_threads = 1;
  RefreshStableStep(model, state, true, 1);
  const double dt = 0.5 * StableStepBound(state);
  for (auto _ : st) {
    if (which == 0) {
      ComputeInternalForces(model, state, work_on ? ForceMode::kElasticDamped : ForceMode::kElastic, out.data(), 1);
      benchmark::DoNotOptimize(out.data());
    } else {
      const StepResult r = Step(model, state, dt, opt);
      benchmark::DoNotOptimize(r);
    }
    benchmark::ClobberMemory();
  }
  st.counters["tets"] = model.num_tets();
  st.counters["case"] = which;
  st.counters["work_on"] = work_on ? 1 : 0;
  st.counters["tet_steps_per_s"] =
      benchmark::Counter(model.num_tets() * static_cast<double>(st.iterations()), benchmark::Counter::kIsRate);
}

// The nodal-pressure element's force pass against the plain element's on the
// same 100k-tet box, deformation, precision and threads (ν = 0.49,
// undamped). Each iteration times one pass of each, back to back, so both
// see the same machine; the counter `ratio` is the median of the per-pair
// ratios and must stay ≤ kNodalPressureCostTarget.
constexpr double kNodalPressureCostTarget = 1.5;
bool g_nodal_pressure_cost_missed = false;

template <typename T>
void BM_NodalPressureCost(benchmark::State& st) {
  const int threads = static_cast<int>(st.range(0));
  const auto& s = kSizes[2];
  static const mesh::TetMesh mesh = MakeBox(s[0], s[1], s[2], 1e-3);
  const Material mat = Material::FromYoungPoisson(3e4, 0.49, 1000.0);
  ModelOptions linear_options, nodal_options;
  nodal_options.element = ElementKind::kNodalPressure;
  const Model<T> linear(mesh, std::span(&mat, 1), linear_options);
  const Model<T> nodal(mesh, std::span(&mat, 1), nodal_options);
  State<T> state(linear);
  for (size_t i = 0; i < state.x.size(); ++i) state.x[i] *= T(1) + T(1e-3) * static_cast<T>(i % 7);
  std::vector<T> out(state.x.size());
  std::vector<double> ratios, linear_s, nodal_s;
  using Clock = std::chrono::steady_clock;
  for (auto _ : st) {
    const auto t0 = Clock::now();
    ComputeInternalForces(linear, state, ForceMode::kElastic, out.data(), threads);
    benchmark::DoNotOptimize(out.data());
    const auto t1 = Clock::now();
    ComputeInternalForces(nodal, state, ForceMode::kElastic, out.data(), threads);
    benchmark::DoNotOptimize(out.data());
    benchmark::ClobberMemory();
    const auto t2 = Clock::now();
    linear_s.push_back(std::chrono::duration<double>(t1 - t0).count());
    nodal_s.push_back(std::chrono::duration<double>(t2 - t1).count());
    ratios.push_back(nodal_s.back() / linear_s.back());
  }
  const auto median = [](std::vector<double> v) {
    std::nth_element(v.begin(), v.begin() + static_cast<std::ptrdiff_t>(v.size() / 2), v.end());
    return v[v.size() / 2];
  };
  const double ratio = median(ratios);
  st.counters["tets"] = linear.num_tets();
  st.counters["threads"] = threads;
  st.counters["linear_ms"] = 1e3 * median(linear_s);
  st.counters["nodal_pressure_ms"] = 1e3 * median(nodal_s);
  st.counters["ratio"] = ratio;
  st.counters["target"] = kNodalPressureCostTarget;
  if (ratio > kNodalPressureCostTarget) {
    g_nodal_pressure_cost_missed = true;
    st.SetLabel("target missed");
  }
}

// One whole-mesh sample of the session's measures (common/sim/session_metrics.h:
// the incision's rings, von Mises per tet outside it, the largest) against
// one elastic force pass, on the same 100k-tet box, deformation and
// threads. The session samples 10 times per simulated second; at
// ≤ kSessionSampleCostTarget force passes a sample stays a few per cent of
// a real-time frame budget at this size. The counter `ratio` is the median
// of the per-pair ratios.
constexpr double kSessionSampleCostTarget = 4.0;
bool g_session_sample_cost_missed = false;

void BM_SessionSample(benchmark::State& st) {
  const int threads = static_cast<int>(st.range(0));
  const auto& s = kSizes[2];
  static const mesh::TetMesh mesh = MakeBox(s[0], s[1], s[2], 1e-3);
  const Material mat = Material::FromYoungPoisson(3e4, 0.45, 1000.0);
  const Model<double> model(mesh, std::span(&mat, 1));
  State<double> state(model);
  for (size_t i = 0; i < state.x.size(); ++i) state.x[i] *= 1.0 + 1e-3 * static_cast<double>(i % 7);
  std::vector<double> out(state.x.size());
  // An incision along a line of nodes through the middle, as a cut leaves.
  std::vector<uint8_t> walls(static_cast<size_t>(model.num_nodes()), 0);
  for (int32_t n = 0; n < model.num_nodes(); ++n) {
    const Eigen::Vector3d X = mesh.nodes.row(n).transpose();
    if (std::abs(X.x() - 13e-3) < 0.6e-3 && X.z() > 12e-3) walls[static_cast<size_t>(n)] = 1;
  }
  sim::SessionMeter<double> meter({.incision_rings = 1, .threads = threads});
  const sim::IncisionView incision{.wall_nodes = walls};
  std::vector<double> ratios, force_s, sample_s;
  using Clock = std::chrono::steady_clock;
  for (auto _ : st) {
    const auto t0 = Clock::now();
    ComputeInternalForces(model, state, ForceMode::kElastic, out.data(), threads);
    benchmark::DoNotOptimize(out.data());
    const auto t1 = Clock::now();
    meter.Sample(model, state.x.data(), incision, 0.0);
    benchmark::DoNotOptimize(meter.metrics().stress_outside());
    const auto t2 = Clock::now();
    force_s.push_back(std::chrono::duration<double>(t1 - t0).count());
    sample_s.push_back(std::chrono::duration<double>(t2 - t1).count());
    ratios.push_back(sample_s.back() / force_s.back());
  }
  const auto median = [](std::vector<double> v) {
    std::nth_element(v.begin(), v.begin() + static_cast<std::ptrdiff_t>(v.size() / 2), v.end());
    return v[v.size() / 2];
  };
  const double ratio = median(ratios);
  st.counters["tets"] = model.num_tets();
  st.counters["threads"] = threads;
  st.counters["force_ms"] = 1e3 * median(force_s);
  st.counters["sample_ms"] = 1e3 * median(sample_s);
  st.counters["ratio"] = ratio;
  st.counters["target"] = kSessionSampleCostTarget;
  if (ratio > kSessionSampleCostTarget) {
    g_session_sample_cost_missed = true;
    st.SetLabel("target missed");
  }
}

// STREAM triad a = b + s·c, 3 × 32 MiB of doubles (well beyond L3).
void BM_Triad(benchmark::State& st) {
  const int threads = static_cast<int>(st.range(0));
  constexpr size_t kN = size_t{4} << 20;
  static std::vector<double> a(kN, 1.0), b(kN, 2.0), c(kN, 3.0);
  const double s = 1.5;
  const auto n = static_cast<int64_t>(kN);
  for (auto _ : st) {
#pragma omp parallel for schedule(static) num_threads(threads)
    for (int64_t i = 0; i < n; ++i) a[static_cast<size_t>(i)] = b[static_cast<size_t>(i)] + s * c[static_cast<size_t>(i)];
    benchmark::DoNotOptimize(a.data());
    benchmark::ClobberMemory();
  }
  // STREAM counts 24 bytes per element (write-allocate traffic not counted).
  st.counters["bytes_per_s"] = benchmark::Counter(
      24.0 * static_cast<double>(kN) * static_cast<double>(st.iterations()), benchmark::Counter::kIsRate);
  st.counters["threads"] = threads;
}

void RegisterAll() {
  for (int t : {1, 2}) {
    benchmark::RegisterBenchmark("BM_Triad", BM_Triad)->Arg(t)->UseRealTime();
  }
  for (int t : {1, 2}) {
    benchmark::RegisterBenchmark("BM_SessionSample", BM_SessionSample)->Arg(t)->UseRealTime();
  }
  for (int which = 0; which < 3; ++which) {
    for (int on : {0, 1}) {
      benchmark::RegisterBenchmark("BM_Skip", BM_Skip)->Args({which, on})->UseRealTime();
    }
  }
  for (int t : {1, 2}) {
    benchmark::RegisterBenchmark("BM_NodalPressureCost<double>", BM_NodalPressureCost<double>)->Arg(t)->UseRealTime();
    benchmark::RegisterBenchmark("BM_NodalPressureCost<float>", BM_NodalPressureCost<float>)->Arg(t)->UseRealTime();
  }
  for (int size = 0; size < 4; ++size) {
    for (int threads : {1, 2}) {
      for (int damped : {0, 1}) {
        const std::vector<int64_t> args = {size, threads, damped};
        benchmark::RegisterBenchmark("BM_Force<double>", BM_Force<double>)->Args(args)->UseRealTime();
        benchmark::RegisterBenchmark("BM_Force<float>", BM_Force<float>)->Args(args)->UseRealTime();
        benchmark::RegisterBenchmark("BM_Step<double>", BM_Step<double>)->Args(args)->UseRealTime();
        benchmark::RegisterBenchmark("BM_Step<float>", BM_Step<float>)->Args(args)->UseRealTime();
      }
    }
  }
}

}  // namespace
}  // namespace cutsim::fem

int main(int argc, char** argv) {
  cutsim::fem::RegisterAll();
  benchmark::Initialize(&argc, argv);
  if (benchmark::ReportUnrecognizedArguments(argc, argv)) return 1;
  benchmark::RunSpecifiedBenchmarks();
  benchmark::Shutdown();
  if (cutsim::fem::g_nodal_pressure_cost_missed) {
    std::fprintf(stderr, "fem_bench: the nodal-pressure force pass costs more than %.2fx the plain one\n",
                 cutsim::fem::kNodalPressureCostTarget);
    return 1;
  }
  if (cutsim::fem::g_session_sample_cost_missed) {
    std::fprintf(stderr, "fem_bench: a session-measure sample costs more than %.2fx a force pass\n",
                 cutsim::fem::kSessionSampleCostTarget);
    return 1;
  }
  return 0;
}
