// Backward Euler step time at organ scale (JSON on stdout).
//
// A box from mesh::MakeBox (≈22k tets, the organ's size, and ≈100k tets),
// E = 3 kPa or 30 kPa, ν = 0.45, ρ = 1000 kg/m³, gravity −z, light
// strain-rate damping, one face clamped: the bottom (z = 0, an organ lying
// on a tray) or, for organ_cantilever, the end x = 0 (a 12 cm cantilever
// released from rest: large deformation). For h = 10 ms and 20 ms, from rest:
// the median wall time of a step, Newton and PCG iterations per step, the
// factorisation and symbolic-analysis times, and the real-time factor
// h / step time. Then, for 10 ms steps, a cut-like topology change (a slit:
// the nodes on the mid plane x = L/2 above mid height are split, tets on the
// +x side move to the copies) and the PCG iterations of each step before
// and after it, with the DOFs the factor in use covers, in the same run
// with the low-rank correction of the old factor and without it (the old
// factor on the old DOFs, block Jacobi on the new ones), and the wall time
// of the first step after the slit. Then the preconditioner's solves on
// the case's system matrix (M + h²K, h = 10 ms) in the same run: CHOLMOD's
// double solve, the own supernodal solve in double and in float (median
// time of a solve, relative difference to CHOLMOD's). Then the tangent's
// product on a deformed state of the case: assembling the tangent (with the
// forces, as a Newton iteration does) and one sparse product with it,
// against recording the elements' F and S and one matrix-free product
// (tangent_product.h), with the force pass alone for scale, on the bench's
// threads, and the time to build the sparse pattern (what a cut frame pays
// before its first assembly). Exits 1 when a step does not converge.
//
//   implicit_bench [--cases organ,organ_soft,large] [--steps 20]
//                  [--relative-tolerance 1e-6] [--linear-tolerance 1e-4]
//                  [--refactor-iterations 12] [--tangent 0|1|2] [--no-async] [--bdf2]
//                  [--verbose]
#include <algorithm>
#include <chrono>
#include <cstdio>
#include <sstream>
#include <string>
#include <vector>

#include <CLI/CLI.hpp>
#include <omp.h>

#include "common/fem/implicit.h"
#include "common/fem/tangent_product.h"
#include "common/mesh/generators.h"

namespace cutsim::fem {
namespace {

struct Case {
  std::string name;
  int nx, ny, nz;
  double lx, ly, lz;  // m
  double youngs;      // Pa
  int clamped_axis;   // the face at coordinate 0 of this axis is fixed
};

bool g_verbose = false;
/// A step that did not converge (or a first step that failed) makes the
/// bench exit 1: the solver failed, whatever its time.
bool g_failed = false;
ImplicitOptions g_options;

const Case kCases[] = {
    {"organ", 28, 12, 11, 0.12, 0.05, 0.045, 3e4, 2},
    {"organ_soft", 28, 12, 11, 0.12, 0.05, 0.045, 3e3, 2},
    {"organ_cantilever", 28, 12, 11, 0.12, 0.05, 0.045, 3e4, 0},
    {"large", 48, 20, 17, 0.2, 0.08, 0.07, 3e4, 2},
};

double Median(std::vector<double> v) {
  if (v.empty()) return 0;
  std::sort(v.begin(), v.end());
  return v[v.size() / 2];
}

double Mean(const std::vector<double>& v) {
  double s = 0;
  for (const double x : v) s += x;
  return v.empty() ? 0 : s / static_cast<double>(v.size());
}

std::string Array(const std::vector<int>& v) {
  std::ostringstream o;
  o << "[";
  for (size_t i = 0; i < v.size(); ++i) o << (i ? ", " : "") << v[i];
  o << "]";
  return o.str();
}

Model<double> MakeModel(const Case& c) {
  const mesh::TetMesh mesh =
      mesh::MakeBox(Eigen::Vector3d::Zero(), Eigen::Vector3d(c.lx, c.ly, c.lz), c.nx, c.ny, c.nz);
  const Material mat = Material::FromYoungPoisson(c.youngs, 0.45, 1000.0, 1.0, 10.0);
  ModelOptions opt;
  opt.gravity = Eigen::Vector3d(0, 0, -9.81);
  opt.node_capacity = mesh.num_nodes() + (c.ny + 1) * (c.nz + 1);
  Model<double> model(mesh, std::span(&mat, 1), opt);
  for (int32_t n = 0; n < model.num_nodes(); ++n) {
    if (model.rest_position(n)(c.clamped_axis) < 1e-9) model.SetFixed(n, true);
  }
  return model;
}

/// Splits every node on the plane x = lx/2 with z > lz/2: tets on its +x
/// side move to a copy (a slit through the upper half).
void Slit(const Case& c, Model<double>& model, State<double>& state) {
  const double xp = 0.5 * c.lx;
  const int32_t nn = model.num_nodes();
  std::vector<int32_t> touched, nodes;
  for (int32_t n = 0; n < nn; ++n) {
    const Vec3<double> p = model.rest_position(n);
    if (std::abs(p(0) - xp) > 1e-9 || p(2) <= 0.5 * c.lz) continue;
    const int32_t copy = model.AddNodeCopy(n, state);
    std::vector<int32_t> incident;
    const int32_t one[1] = {n};
    model.IncidentTets(one, incident);
    for (const int32_t t : incident) {
      Vec3<double> centroid = Vec3<double>::Zero();
      for (int k = 0; k < 4; ++k) centroid += model.rest_position(model.tet_node(t, k)) / 4;
      if (centroid(0) <= xp) continue;
      for (int k = 0; k < 4; ++k) {
        if (model.tet_node(t, k) == n) model.RetargetTet(t, k, copy);
      }
      touched.push_back(t);
    }
    nodes.push_back(n);
    nodes.push_back(copy);
  }
  std::sort(touched.begin(), touched.end());
  touched.erase(std::unique(touched.begin(), touched.end()), touched.end());
  model.RecomputeElements(touched);
  model.RecomputeNodeMasses(nodes);
  model.CommitTopology();
}

struct Phase {
  std::vector<double> seconds;
  std::vector<double> newton, pcg;
  int not_converged = 0;
};

Phase RunSteps(ImplicitIntegrator& integ, const Model<double>& model, State<double>& state, double h,
               int steps, std::vector<int>* pcg_per_step, std::vector<int>* factor_dofs) {
  Phase p;
  for (int s = 0; s < steps; ++s) {
    const auto t0 = std::chrono::steady_clock::now();
    const ImplicitResult r = integ.Step(model, state, h);
    p.seconds.push_back(std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count());
    p.newton.push_back(r.newton_iterations);
    p.pcg.push_back(r.pcg_iterations);
    p.not_converged += r.ok() ? 0 : 1;
    if (g_verbose) {
      std::fprintf(stderr, "h %g step %d: status %d newton %d pcg %d (max %d) halvings %d clamped %d negcurv %d"
                   " residual %.3g tol %.3g factor_dofs %d |", h, s, static_cast<int>(r.status),
                   r.newton_iterations, r.pcg_iterations, r.max_pcg_iterations, r.line_search_halvings,
                   r.clamped, r.negative_curvature, r.residual, r.tolerance, r.factor_dofs);
      for (int k = 0; k < std::min(r.newton_iterations, ImplicitResult::kHistory); ++k) {
        std::fprintf(stderr, " %.2g", r.residual_history[static_cast<size_t>(k)]);
      }
      std::fprintf(stderr, "\n");
    }
    if (pcg_per_step != nullptr) pcg_per_step->push_back(r.pcg_iterations);
    if (factor_dofs != nullptr) factor_dofs->push_back(r.factor_dofs);
  }
  return p;
}

template <typename Body>
double MedianSeconds(int reps, Body&& body) {
  std::vector<double> t;
  for (int rep = 0; rep < reps; ++rep) {
    const auto t0 = std::chrono::steady_clock::now();
    body();
    t.push_back(std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count());
  }
  return Median(t);
}

/// Median time of the preconditioner's solve on M + h²K (h = 10 ms, at
/// rest) with each FactorSolve, and the relative difference to CHOLMOD's.
void PrintSolves(const Model<double>& model) {
  ImplicitIntegrator integ(g_options);
  std::vector<double> a;
  std::vector<double> x(static_cast<size_t>(3 * model.node_capacity()));
  for (int32_t n = 0; n < model.num_nodes(); ++n) {
    for (int d = 0; d < 3; ++d) x[static_cast<size_t>(3 * n + d)] = model.rest_position(n)(d);
  }
  integ.AssembleStiffness(model, x.data(), false, a);
  const SparseSystem& sys = integ.system();
  for (auto& v : a) v *= 1e-4;
  for (int32_t n = 0; n < model.num_nodes(); ++n) {
    sys.AddBlock(a.data(), sys.diagonal_block(n), n, model.node_mass(n) * Eigen::Matrix3d::Identity());
  }
  const std::vector<uint8_t> active(static_cast<size_t>(sys.num_nodes()), 1);
  std::vector<double> r(static_cast<size_t>(sys.num_dofs())), z(r.size()), z_ref(r.size());
  for (size_t i = 0; i < r.size(); ++i) r[i] = std::sin(0.37 * static_cast<double>(i)) + 0.1;
  std::printf("   \"solves\": [");
  const char* names[] = {"cholmod_double", "supernodal_double", "supernodal_float"};
  int k = 0;
  for (const FactorSolve mode : {FactorSolve::kCholmod, FactorSolve::kDouble, FactorSolve::kFloat}) {
    LinearSolver solver(false, mode);
    solver.Resize(sys);
    solver.RequestFactor(sys, a.data());
    const double median_s =
        MedianSeconds(30, [&] { solver.Precondition(sys, a.data(), active.data(), r.data(), z.data()); });
    if (mode == FactorSolve::kCholmod) z_ref = z;
    double d = 0, s = 0;
    for (size_t i = 0; i < z.size(); ++i) {
      d += (z[i] - z_ref[i]) * (z[i] - z_ref[i]);
      s += z_ref[i] * z_ref[i];
    }
    std::printf("%s\n    {\"solve\": \"%s\", \"median_s\": %.6f, \"relative_difference\": %.3g}", k == 0 ? "" : ",",
                names[k], median_s, std::sqrt(d / s));
    ++k;
  }
  std::printf("]");
}

/// K·p assembled against matrix-free at a smoothly deformed state (2 % of
/// the box's height), and the force pass alone.
void PrintProducts(const Model<double>& model, const Case& c) {
  ImplicitIntegrator integ(g_options);
  std::vector<double> x(static_cast<size_t>(3 * model.node_capacity()), 0.0);
  for (int32_t n = 0; n < model.num_nodes(); ++n) {
    const Vec3<double> r = model.rest_position(n);
    const double w = model.fixed(n) ? 0.0 : 0.02 * c.lz * std::sin(3.0 * r(0) / c.lx) * r(2) / c.lz;
    for (int d = 0; d < 3; ++d) x[static_cast<size_t>(3 * n + d)] = r(d) + (d == 2 ? w : 0.3 * w);
  }
  std::vector<double> k, f(x.size());
  const double assemble_s = MedianSeconds(9, [&] { integ.AssembleStiffness(model, x.data(), false, k); });
  const double force_s = MedianSeconds(9, [&] { integ.InternalForce(model, x.data(), f.data()); });
  const SparseSystem& sys = integ.system();
  const int threads = integ.options().num_threads > 0 ? integ.options().num_threads : omp_get_max_threads();
  std::vector<double> p(static_cast<size_t>(sys.num_dofs())), q_sparse(p.size()), q_free(p.size());
  for (size_t i = 0; i < p.size(); ++i) p[i] = std::cos(0.91 * static_cast<double>(i));
  const double spmv_s = MedianSeconds(31, [&] {
#pragma omp parallel num_threads(threads)
    sys.MultiplyTeam(k.data(), p.data(), q_sparse.data());
  });
  TangentProduct op;
  const double linearize_s = MedianSeconds(9, [&] { op.Linearize(model, sys, x.data(), false, threads); });
  const double product_s = MedianSeconds(31, [&] {
    std::fill(q_free.begin(), q_free.end(), 0.0);
    op.AddProduct(p.data(), 1.0, nullptr, q_free.data());
  });
  double d = 0, s = 0;
  for (size_t i = 0; i < p.size(); ++i) {
    d += (q_free[i] - q_sparse[i]) * (q_free[i] - q_sparse[i]);
    s += q_sparse[i] * q_sparse[i];
  }
  SparseSystem rebuilt;
  const double pattern_s = MedianSeconds(9, [&] { rebuilt.Build(model); });
  std::printf(",\n   \"tangent_product\": {\"threads\": %d, \"assemble_with_forces_s\": %.6f, \"forces_only_s\": %.6f,"
              " \"sparse_product_s\": %.6f, \"linearize_s\": %.6f, \"matrix_free_product_s\": %.6f,"
              " \"relative_difference\": %.3g, \"pattern_build_s\": %.6f}",
              threads, assemble_s, force_s, spmv_s, linearize_s, product_s, std::sqrt(d / s), pattern_s);
}

void RunCase(const Case& c, int steps, bool first) {
  Model<double> model = MakeModel(c);
  std::printf("%s  {\"case\": \"%s\", \"tets\": %d, \"nodes\": %d, \"youngs_pa\": %g,"
              " \"clamped_face\": \"%c = 0\", \"omp_threads\": %d,\n",
              first ? "" : ",\n", c.name.c_str(), model.num_tets(), model.num_nodes(), c.youngs,
              "xyz"[c.clamped_axis], omp_get_max_threads());
  std::printf("   \"steps\": [");
  for (const double h : {0.01, 0.02}) {
    State<double> state(model);
    ImplicitIntegrator integ(g_options);
    const auto t0 = std::chrono::steady_clock::now();
    const ImplicitResult first_step = integ.Step(model, state, h);  // waits for the first factor
    const double first_seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    const Phase p = RunSteps(integ, model, state, h, steps, nullptr, nullptr);
    const FactorStats fs = integ.linear_solver().stats();
    const double med = Median(p.seconds);
    if (p.not_converged > 0 || !first_step.ok()) g_failed = true;
    std::printf("%s\n    {\"h_s\": %g, \"median_step_s\": %.6f, \"max_step_s\": %.6f, \"first_step_s\": %.4f,"
                " \"first_step_ok\": %s, \"newton_mean\": %.2f, \"newton_max\": %g, \"pcg_mean\": %.2f,"
                " \"pcg_max\": %g, \"not_converged\": %d, \"factorizations\": %lld,"
                " \"factor_s\": %.4f, \"analyze_s\": %.4f, \"nnz\": %lld, \"realtime_factor\": %.3f}",
                h == 0.01 ? "" : ",", h, med, *std::max_element(p.seconds.begin(), p.seconds.end()),
                first_seconds, first_step.ok() ? "true" : "false", Mean(p.newton),
                *std::max_element(p.newton.begin(), p.newton.end()), Mean(p.pcg),
                *std::max_element(p.pcg.begin(), p.pcg.end()), p.not_converged,
                static_cast<long long>(fs.completed), fs.last_seconds, fs.last_analyze_seconds,
                static_cast<long long>(integ.system().nnz()), h / med);
  }
  std::printf("],\n");
  // Topology change at 10 ms steps, with and without the correction.
  std::printf("   \"cut\": [");
  for (const bool corrected : {true, false}) {
    Model<double> cut_model = MakeModel(c);
    State<double> state(cut_model);
    ImplicitOptions options = g_options;
    if (!corrected) options.max_correction_rank = 0;
    ImplicitIntegrator integ(options);
    std::vector<int> before, after, dofs_before, dofs_after;
    RunSteps(integ, cut_model, state, 0.01, steps / 2 + 1, &before, &dofs_before);
    integ.mutable_linear_solver().WaitForFactor();  // both runs start from a factor of the same step
    Slit(c, cut_model, state);
    const Phase p = RunSteps(integ, cut_model, state, 0.01, steps, &after, &dofs_after);
    if (p.not_converged > 0) g_failed = true;
    const FactorStats fs = integ.linear_solver().stats();
    std::printf("%s\n    {\"correction\": %s, \"nodes_after\": %d, \"dofs_after\": %d, \"pcg_before\": %s,"
                " \"pcg_after\": %s, \"factor_dofs_after\": %s, \"first_step_after_s\": %.6f,"
                " \"median_step_after_s\": %.6f, \"correction_rank\": %d, \"correction_s\": %.4f,"
                " \"not_converged\": %d}",
                corrected ? "" : ",", corrected ? "true" : "false", cut_model.num_nodes(), 3 * cut_model.num_nodes(),
                Array(before).c_str(), Array(after).c_str(), Array(dofs_after).c_str(), p.seconds.front(),
                Median(p.seconds), fs.last_correction_rank, fs.last_correction_seconds, p.not_converged);
  }
  std::printf("],\n");
  PrintSolves(model);
  PrintProducts(model, c);
  std::printf("}");
  std::fflush(stdout);
}

}  // namespace
}  // namespace cutsim::fem

int main(int argc, char** argv) {
  CLI::App app{"Implicit (backward Euler) step time at organ scale"};
  std::string cases = "organ,organ_soft,organ_cantilever,large";
  int steps = 20;
  app.add_option("--cases", cases, "Comma-separated: organ, organ_soft, organ_cantilever, large");
  app.add_option("--steps", steps, "Timed steps per step size")->check(CLI::PositiveNumber);
  auto& o = cutsim::fem::g_options;
  app.add_option("--relative-tolerance", o.relative_force_tolerance, "Newton force tolerance / load scale");
  app.add_option("--linear-tolerance", o.linear_tolerance, "PCG tolerance relative to the Newton residual");
  app.add_option("--refactor-iterations", o.refactor_pcg_iterations, "PCG iterations that trigger a refactor");
  app.add_flag("--verbose", cutsim::fem::g_verbose, "Per-step results on stderr");
  int tangent = static_cast<int>(o.tangent);
  app.add_option("--tangent", tangent, "0 exact, 1 clamped, 2 auto");
  app.add_flag("!--no-async", o.asynchronous_factorization, "Factor inline (reproducible)");
  app.add_flag("--bdf2", o.bdf2, "BDF2 instead of backward Euler");
  CLI11_PARSE(app, argc, argv);
  o.tangent = static_cast<cutsim::fem::TangentMode>(tangent);
  std::printf("{\"bench\": \"implicit\", \"cases\": [\n");
  bool first = true;
  for (const auto& c : cutsim::fem::kCases) {
    if (("," + cases + ",").find("," + c.name + ",") == std::string::npos) continue;
    cutsim::fem::RunCase(c, steps, first);
    first = false;
  }
  std::printf("\n]}\n");
  return cutsim::fem::g_failed ? 1 : 0;
}
