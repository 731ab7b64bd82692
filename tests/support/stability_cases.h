#pragma once
/// @file
/// The numerical stability stress cases, shared by
/// bench/stability_bench.cc (full size) and tests/unit/sim/stability_test.cc
/// (short size, also under ASan). Each case drives common/fem (or, for
/// cutting and the tool, common/sim Simulation) through an extreme load and
/// reports whether it held and how the guards reacted:
///   * inversion guard: elements on the invertible-StVK path (det F below
///     the model's threshold) — peak count and smallest det F seen;
///   * stable step: Lanczos (spectral) refreshes, fraction of frames in the
///     transient mode (ratio not trusted, step = 0.5 × per-element bound),
///     smallest and largest step;
///   * step guard: the first failing StepStatus (non-finite force, runaway
///     speed = the energy-runaway guard, bad dt), state left unwritten;
///   * cutting: executed and rejected cut steps;
///   * invariants: every coordinate finite, total mass unchanged.

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <functional>
#include <limits>
#include <memory>
#include <random>
#include <span>
#include <string>
#include <vector>

#include <Eigen/Core>
#include <Eigen/LU>

#include "common/core/clock.h"
#include "common/fem/forces.h"
#include "common/fem/implicit.h"
#include "common/fem/integrator.h"
#include "common/fem/model.h"
#include "common/fem/stable_dt.h"
#include "common/fem/state.h"
#include "common/mesh/generators.h"
#include "common/sim/scene_loader.h"
#include "common/sim/simulation.h"

namespace cutsim::support::stability {

/// How big each case is: the bench runs the full size, the unit test the short one.
struct Size {
  int cells = 5;                  ///< Cube side in cells (6·cells³ tets).
  double duration = 0.3;          ///< Simulated seconds of a loading case.
  int64_t long_steps = 1000000;   ///< Steps of the long run (tiny mesh).
  int64_t dt_steps = 20000;       ///< Steps of each fixed-dt case.
  int strokes = 100;              ///< Random cut strokes.
  double jam_time = 0.5;          ///< Seconds the tool stays jammed.

  static Size Bench() { return {}; }
  static Size Test() {
    return {.cells = 3, .duration = 0.05, .long_steps = 10000, .dt_steps = 2000, .strokes = 6, .jam_time = 0.05};
  }
};

struct Result {
  std::string name;
  std::string expectation = "holds";  ///< "holds", or what a correct run does (e.g. the guard stops it).
  bool holds = false;
  std::string reason;                 ///< Why not, or what held.
  int tets = 0;
  int64_t steps = 0;
  double sim_time = 0;   ///< s
  double wall = 0;       ///< s
  bool finite = true;    ///< No NaN/Inf in x or v at the end.
  double mass_rel_change = 0;
  int max_inverted = 0;  ///< Peak number of elements with det F < threshold (invertible path).
  int final_inverted = 0;  ///< Elements with det F < 0 at the end (a tangled, non-physical state).
  /// `holds` and no element inverted at the end. `holds` alone means the
  /// guards kept the run finite, bounded and mass-conserving.
  bool physical = false;
  double min_det_f = 1;
  int64_t spectral_refreshes = 0;
  double transient_fraction = 0;
  double min_dt = 0, max_dt = 0;  ///< s
  std::string step_status = "ok";
  double energy_drift = -1;       ///< max |E − E₀|/E₀ where measured, else −1.
  uint64_t cuts = 0, rejected_cuts = 0;
  bool expected_ok = true;        ///< Whether `holds` matched the expectation.
};

inline const char* StatusName(fem::StepStatus s) {
  switch (s) {
    case fem::StepStatus::kOk: return "ok";
    case fem::StepStatus::kNonFiniteForce: return "non-finite force";
    case fem::StepStatus::kRunaway: return "runaway (speed guard)";
    case fem::StepStatus::kBadTimeStep: return "bad dt";
    case fem::StepStatus::kNoAdmissibleIterate: return "no admissible iterate (implicit)";
  }
  return "?";
}

/// Guard and invariant bookkeeping for the fem-level cases.
class Monitor {
 public:
  Monitor(const fem::Model<double>& model, Result& r) : model_(model), r_(r), mass0_(model.TotalMass()) {
    r_.tets = model.num_tets();
    r_.min_dt = std::numeric_limits<double>::infinity();
  }

  void Sample(const fem::State<double>& s, const fem::StepResult& step) {
    int inverted = 0;
    const double thr = model_.inversion_det_threshold();
    for (int32_t t = 0; t < model_.num_tets(); ++t) {
      const double det = fem::DeformationGradient(model_, s.x.data(), t).determinant();
      r_.min_det_f = std::min(r_.min_det_f, det);
      inverted += det < thr ? 1 : 0;
    }
    r_.max_inverted = std::max(r_.max_inverted, inverted);
    if (s.dt_spectral_step != last_spectral_) {
      ++r_.spectral_refreshes;
      last_spectral_ = s.dt_spectral_step;
    }
    ++frames_;
    transient_ += s.dt_trusted ? 0 : 1;
    if (step.dt > 0) {
      r_.min_dt = std::min(r_.min_dt, step.dt);
      r_.max_dt = std::max(r_.max_dt, step.dt);
    }
  }

  /// Closes the result: invariants, and `holds` = no failure and invariants kept.
  void Finish(const fem::State<double>& s, const fem::StepResult& last, double wall) {
    r_.steps = s.step;
    r_.sim_time = s.time;
    r_.wall = wall;
    r_.finite = true;
    for (int32_t i = 0; i < 3 * model_.num_nodes(); ++i) {
      r_.finite = r_.finite && std::isfinite(s.x[static_cast<size_t>(i)]) && std::isfinite(s.v[static_cast<size_t>(i)]);
    }
    r_.mass_rel_change = std::abs(model_.TotalMass() - mass0_) / mass0_;
    for (int32_t t = 0; t < model_.num_tets(); ++t) {
      r_.final_inverted += fem::DeformationGradient(model_, s.x.data(), t).determinant() <= 0 ? 1 : 0;
    }
    r_.transient_fraction = frames_ > 0 ? static_cast<double>(transient_) / frames_ : 0.0;
    if (!std::isfinite(r_.min_dt)) r_.min_dt = 0;
    r_.step_status = StatusName(last.status);
    r_.holds = last.ok() && r_.finite && r_.mass_rel_change < 1e-12;
    r_.physical = r_.holds && r_.final_inverted == 0;
    if (!last.ok()) {
      r_.reason = std::string("step ") + std::to_string(last.step) + ": " + StatusName(last.status) + " (" +
                  last.quantity + " = " + std::to_string(last.value) + ")";
    } else if (!r_.finite) {
      r_.reason = "non-finite state";
    }
  }

 private:
  const fem::Model<double>& model_;
  Result& r_;
  double mass0_;
  int64_t last_spectral_ = -1;
  int64_t frames_ = 0, transient_ = 0;
};

inline mesh::TetMesh Cube(int cells, double side = 0.01) {
  return mesh::MakeBox(Eigen::Vector3d::Zero(), Eigen::Vector3d::Constant(side), cells, cells, cells);
}

/// Soft tissue of the method paper (λ = 140 kPa, μ = 11 kPa) with its damping.
inline fem::Material PaperTissue() {
  return {.lambda = 140000, .mu = 11000, .psi = 10, .phi = 80, .density = 1000};
}

inline double TotalEnergy(const fem::Model<double>& m, const fem::State<double>& s) {
  return fem::StrainEnergy(m, s.x.data()) + fem::KineticEnergy(m, s.v.data()) + fem::GravityPotential(m, s.x.data());
}

/// Prescribed boundary motion: nodes in `moved` follow target(rest, s) with
/// s ramping 0 → 1 over the first half of `duration`, then hold; the rest is
/// dynamics under the default Advance (safety 0.85, adaptive step).
template <typename Target>
Result PrescribedMotion(const std::string& name, const Size& size, const fem::Material& mat,
                        const std::vector<uint8_t>& moved, const std::vector<uint8_t>& clamped, Target&& target) {
  Result r;
  r.name = name;
  const mesh::TetMesh m = Cube(size.cells);
  fem::Model<double> model(m, std::span(&mat, 1));
  for (int32_t n = 0; n < model.num_nodes(); ++n) {
    if (moved[static_cast<size_t>(n)] || clamped[static_cast<size_t>(n)]) model.SetFixed(n, true);
  }
  fem::State<double> s(model);
  Monitor mon(model, r);
  fem::StepOptions opt;
  opt.num_threads = 1;
  opt.viscous = fem::ViscousTreatment::kImplicit;
  constexpr double kFrame = 1e-3;
  const int frames = std::max(2, static_cast<int>(std::lround(size.duration / kFrame)));
  const int ramp = frames / 2;
  fem::StepResult last;
  Stopwatch watch;
  for (int f = 1; f <= frames; ++f) {
    const double a = std::min(1.0, static_cast<double>(f) / ramp);
    const double a_prev = std::min(1.0, static_cast<double>(f - 1) / ramp);
    for (int32_t n = 0; n < model.num_nodes(); ++n) {
      if (!moved[static_cast<size_t>(n)]) continue;
      const Eigen::Vector3d rest = m.nodes.row(n).transpose();
      const Eigen::Vector3d p = target(rest, a), p_prev = target(rest, a_prev);
      for (int k = 0; k < 3; ++k) {
        s.x[3 * static_cast<size_t>(n) + static_cast<size_t>(k)] = p(k);
        s.v[3 * static_cast<size_t>(n) + static_cast<size_t>(k)] = (p(k) - p_prev(k)) / kFrame;
      }
    }
    last = fem::Advance(model, s, kFrame, opt);
    if (!last.ok()) break;
    mon.Sample(s, last);
  }
  mon.Finish(s, last, watch.ElapsedSeconds());
  if (r.physical) r.reason = "reached the target, no element inverted at the end";
  if (r.holds && !r.physical) {
    r.reason = "reached the target stably, but " + std::to_string(r.final_inverted) +
               " elements are inverted at the end (StVK has no valid equilibrium here; see the notes)";
  }
  return r;
}

inline std::vector<uint8_t> NodesWhere(const mesh::TetMesh& m, const std::function<bool(const Eigen::Vector3d&)>& f) {
  std::vector<uint8_t> out(static_cast<size_t>(m.num_nodes()), 0);
  for (int32_t n = 0; n < m.num_nodes(); ++n) out[static_cast<size_t>(n)] = f(m.nodes.row(n).transpose()) ? 1 : 0;
  return out;
}

inline Result StretchX3(const Size& size) {
  const mesh::TetMesh m = Cube(size.cells);
  const double L = 0.01;
  return PrescribedMotion("stretch x3 (uniaxial, prescribed face)", size, PaperTissue(),
                          NodesWhere(m, [&](const Eigen::Vector3d& p) { return p.x() > L - 1e-9; }),
                          NodesWhere(m, [](const Eigen::Vector3d& p) { return p.x() < 1e-9; }),
                          [&](const Eigen::Vector3d& rest, double a) {
                            return Eigen::Vector3d(rest.x() + 2.0 * L * a, rest.y(), rest.z());
                          });
}

inline Result CompressVolume10(const Size& size) {
  const mesh::TetMesh m = Cube(size.cells);
  const double L = 0.01;
  const double s_end = std::cbrt(0.1);  // every boundary node moves towards the centre
  const Eigen::Vector3d c = Eigen::Vector3d::Constant(L / 2);
  return PrescribedMotion("compression to 10% volume (triaxial, whole boundary)", size, PaperTissue(),
                          NodesWhere(m, [&](const Eigen::Vector3d& p) {
                            return (p.array() < 1e-9).any() || (p.array() > L - 1e-9).any();
                          }),
                          std::vector<uint8_t>(static_cast<size_t>(m.num_nodes()), 0),
                          [&](const Eigen::Vector3d& rest, double a) {
                            return Eigen::Vector3d(c + (1.0 + a * (s_end - 1.0)) * (rest - c));
                          });
}

inline Result CompressUniaxial10(const Size& size) {
  const mesh::TetMesh m = Cube(size.cells);
  const double L = 0.01;
  return PrescribedMotion("compression to 10% length (uniaxial, sides free)", size, PaperTissue(),
                          NodesWhere(m, [&](const Eigen::Vector3d& p) { return p.x() > L - 1e-9; }),
                          NodesWhere(m, [](const Eigen::Vector3d& p) { return p.x() < 1e-9; }),
                          [&](const Eigen::Vector3d& rest, double a) {
                            return Eigen::Vector3d(rest.x() - 0.9 * L * a, rest.y(), rest.z());
                          });
}

/// A cube on a fixed base released under gravity from a sheared start.
inline Result Release(const std::string& name, const Size& size, const std::vector<fem::Material>& mats,
                      const std::function<int(const Eigen::Vector3d&)>& region) {
  Result r;
  r.name = name;
  mesh::TetMesh m = Cube(size.cells);
  std::vector<fem::Material> per_tet(static_cast<size_t>(m.num_tets()));
  for (int32_t t = 0; t < m.num_tets(); ++t) {
    Eigen::Vector3d c = Eigen::Vector3d::Zero();
    for (int k = 0; k < 4; ++k) c += m.nodes.row(m.tets(t, k)).transpose() / 4.0;
    per_tet[static_cast<size_t>(t)] = mats[static_cast<size_t>(region(c))];
  }
  fem::ModelOptions mo;
  mo.gravity = Eigen::Vector3d(0, 0, -9.81);
  fem::Model<double> model(m, per_tet, mo);
  for (int32_t n = 0; n < model.num_nodes(); ++n) model.SetFixed(n, m.nodes(n, 2) < 1e-9);
  fem::State<double> s(model);
  for (int32_t n = 0; n < model.num_nodes(); ++n) s.x[3 * static_cast<size_t>(n)] += 0.3 * m.nodes(n, 2);  // shear 30%
  Monitor mon(model, r);
  fem::StepOptions opt;
  opt.num_threads = 1;
  opt.viscous = fem::ViscousTreatment::kImplicit;
  constexpr double kFrame = 1e-3;
  const int frames = std::max(2, static_cast<int>(std::lround(size.duration / kFrame)));
  fem::StepResult last;
  Stopwatch watch;
  for (int f = 0; f < frames; ++f) {
    last = fem::Advance(model, s, kFrame, opt);
    if (!last.ok()) break;
    mon.Sample(s, last);
  }
  mon.Finish(s, last, watch.ElapsedSeconds());
  if (r.holds) {
    r.reason = (r.physical ? "released, settling" : std::to_string(r.final_inverted) + " elements inverted at the end") +
               std::string("; dt ") + std::to_string(r.min_dt * 1e6) + " us min";
  }
  return r;
}

inline Result NearIncompressible(const Size& size, double nu) {
  const fem::Material mat = fem::Material::FromYoungPoisson(50000, nu, 1000, 5, 0);
  return Release("near-incompressible nu = " + std::to_string(nu).substr(0, 5) + " (release under gravity)", size,
                 {mat}, [](const Eigen::Vector3d&) { return 0; });
}

inline Result StiffnessContrast(const Size& size) {
  const fem::Material soft = fem::Material::FromYoungPoisson(10000, 0.4, 1000, 1, 0);
  const fem::Material stiff = fem::Material::FromYoungPoisson(1.0e7, 0.4, 1000, 1, 0);
  return Release("stiffness contrast 1000x (two halves, release)", size, {soft, stiff},
                 [](const Eigen::Vector3d& c) { return c.x() < 0.005 ? 0 : 1; });
}

/// The method paper's tissue without strain-rate damping (the energy cases).
inline fem::Material UndampedTissue() {
  fem::Material mat = PaperTissue();
  mat.psi = mat.phi = 0;
  return mat;
}

/// Moves every free node by up to `amplitude` (m) per axis, the same
/// pseudo-random pattern every call: an excited state to release.
inline void JitterFreeNodes(const fem::Model<double>& model, fem::State<double>& s, double amplitude) {
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> u(-1, 1);
  for (int32_t n = 0; n < model.num_nodes(); ++n) {
    if (model.fixed(n)) continue;
    for (int k = 0; k < 3; ++k) s.x[3 * static_cast<size_t>(n) + static_cast<size_t>(k)] += amplitude * u(rng);
  }
}

/// Symplectic Euler is linearly stable for h·ω < 2, but on a nonlinear
/// system it trades energy between modes at the resonances h·ω = 2 sin(π/n);
/// the fourth-order one, h·ω = √2, lies at 0.707 of the linear limit (Skeel
/// & Srinivas, SIAM J. Numer. Anal. 38, 2000). FixedStep's undamped cube,
/// whose energy starts in its top modes, gains energy below that fraction of
/// the start's Lanczos estimate (the estimate is under ω_max and the motion
/// stiffens the cube); where the growth starts depends on the mesh, and this
/// is where it starts on the bench's 750-tet cube. A user-fixed step above
/// it is in the resonance band, where growth the speed guard stops is an
/// expected end.
inline constexpr double kFixedStepResonanceOnset = 0.65;

/// Undamped, no gravity, bottom face fixed, randomly perturbed start (5% of
/// the cell size). Two ways of choosing the step:
///  * `adaptive` = false: a fixed dt = fraction × the Lanczos estimate of the
///    true limit at the start (the raw integrator against its linear limit);
///  * `adaptive` = true: fem::Advance with safety_factor = fraction (what a
///    scene's time_step.safety_factor does: refreshed bound, Lanczos ratio,
///    transient mode).
/// Energy: E = strain + kinetic at 200 sample points. Symplectic Euler's
/// naive energy oscillates (x and v are staggered), so "drift" is the change
/// of the mean over the last tenth of the samples against the first tenth,
/// relative to E₀, and `holds` needs it below 5%; the largest excursion is
/// printed in the reason.
inline Result FixedStep(const std::string& name, int cells, int64_t steps, double fraction, bool beyond_limit,
                        bool adaptive = false) {
  Result r;
  r.name = name;
  r.expectation = beyond_limit ? "guard stops it, nothing written" : "holds, energy bounded";
  const mesh::TetMesh m = Cube(cells);
  const fem::Material mat = UndampedTissue();
  fem::Model<double> model(m, std::span(&mat, 1));
  for (int32_t n = 0; n < model.num_nodes(); ++n) model.SetFixed(n, m.nodes(n, 2) < 1e-9);
  fem::State<double> s(model);
  JitterFreeNodes(model, s, 0.05 * (0.01 / cells));
  const fem::SpectralEstimate est = fem::EstimateStableStep(model, s, false, 60, 1);
  const double dt = fraction * est.dt;
  Monitor mon(model, r);
  fem::StepOptions opt;
  opt.num_threads = 1;
  opt.safety_factor = fraction;
  const double e0 = TotalEnergy(model, s);
  std::vector<double> energies;
  fem::StepResult last;
  const int64_t sample_every = std::max<int64_t>(1, steps / 200);
  int64_t next_sample = sample_every;
  // A user-fixed step: the Lanczos limit of the states the motion reaches
  // (every 10 steps, while the energy is still within 10% of E₀, i.e.
  // before any divergence), to tell a step beyond a later state's limit.
  const bool track_limit = !adaptive && !beyond_limit && fraction > 0.5;
  double min_limit = est.dt;
  int64_t min_limit_step = 0;
  Stopwatch watch;
  while (s.step < steps) {
    last = adaptive ? fem::Advance(model, s, 20 * est.dt, opt) : fem::Step(model, s, dt, opt);
    if (!last.ok()) break;
    if (track_limit && (s.step <= 100 || s.step % 10 == 0) && std::abs(TotalEnergy(model, s) - e0) <= 0.1 * e0) {
      const double limit = fem::EstimateStableStep(model, s, false, 60, 1).dt;
      if (limit < min_limit) {
        min_limit = limit;
        min_limit_step = s.step;
      }
    }
    if (s.step >= next_sample) {
      next_sample += sample_every;
      energies.push_back(TotalEnergy(model, s));
      mon.Sample(s, last);
    }
  }
  mon.Finish(s, last, watch.ElapsedSeconds());
  double excursion = 0, drift = 0;
  for (const double e : energies) excursion = std::max(excursion, std::abs(e - e0) / e0);
  const size_t tenth = std::max<size_t>(1, energies.size() / 10);
  if (energies.size() >= 2 * tenth) {
    double first = 0, tail = 0;
    for (size_t i = 0; i < tenth; ++i) {
      first += energies[i];
      tail += energies[energies.size() - 1 - i];
    }
    drift = std::abs(tail - first) / (static_cast<double>(tenth) * e0);
  }
  r.energy_drift = drift;
  r.physical = r.physical && r.holds;
  if (!adaptive) r.min_dt = r.max_dt = dt;
  const std::string energy_note = "energy drift " + std::to_string(drift) + ", largest excursion " +
                                  std::to_string(excursion) + " of E0";
  // What the run's own guards said (finite, no runaway) and whether the speed
  // guard ended it cleanly.
  const bool guard_ok = r.holds;
  const bool guard_stop = !last.ok() && r.finite && last.status == fem::StepStatus::kRunaway;
  const std::string guard_note =
      "the speed guard stopped it at step " + std::to_string(last.step) + ", state finite";
  if (beyond_limit) {
    // Correct behaviour: the run diverges and the speed guard stops it
    // without writing the state.
    const bool stopped = !last.ok() && r.finite;
    r.holds = last.ok() && r.finite && drift < 0.05;
    r.expected_ok = stopped;
    r.reason = stopped ? "diverged; guard stopped it at step " + std::to_string(last.step) + " (" +
                             StatusName(last.status) + "), state finite"
                       : (r.holds ? "did not diverge within the run" : "energy grew without a guard stop");
    return r;
  }
  r.holds = guard_ok && drift < 0.05;
  if (track_limit && min_limit <= dt) {
    // The fixed step is beyond the limit of a state the motion reached: a
    // guard stop (state finite, nothing written) is the correct outcome.
    r.expectation = "holds, or (dt beyond a later state's limit) the guard stops it";
    r.expected_ok = r.holds || guard_stop;
    r.reason = (min_limit_step == 0 ? std::string("dt is the start state's own limit (any stiffer state is beyond it); ")
                                    : "the motion reached a state whose Lanczos limit is " +
                                          std::to_string(min_limit / est.dt).substr(0, 5) + " x the start's (step " +
                                          std::to_string(min_limit_step) + "), below this dt; ") +
               (r.holds ? "held anyway, " + energy_note : guard_stop ? guard_note : r.reason);
  } else if (!adaptive && fraction > kFixedStepResonanceOnset) {
    // In the resonance band the energy may grow; what must hold is that the
    // run either stays finite or the speed guard stops it, nothing written.
    r.expectation = "holds, or (in the 4:1 resonance band) the energy grows and the guard stops it";
    r.expected_ok = r.finite && (guard_ok || guard_stop);
    r.reason = std::string("in the leapfrog's 4:1 resonance band; ") +
               (guard_stop ? guard_note : guard_ok ? energy_note : r.reason);
  } else {
    r.expected_ok = r.holds;
    if (guard_ok) r.reason = energy_note;
    if (track_limit) {
      r.reason += "; smallest Lanczos limit of the states sampled before the energy left ±10%: " +
                  std::to_string(min_limit / est.dt).substr(0, 5) + " x the start's (above this dt)";
    }
  }
  return r;
}

/// FixedStep's jittered, undamped cube stepped by backward Euler
/// (fem::ImplicitIntegrator, factor inline) with a step of `multiple` × the
/// start state's Lanczos limit, `steps` steps. No stability limit binds it:
/// it holds when every step converges and the energy never rises above E₀
/// (backward Euler only dissipates).
inline Result ImplicitLargeStep(const std::string& name, int cells, int64_t steps, double multiple) {
  Result r;
  r.name = name;
  r.expectation = "holds, energy non-increasing";
  const mesh::TetMesh m = Cube(cells);
  const fem::Material mat = UndampedTissue();
  fem::Model<double> model(m, std::span(&mat, 1));
  for (int32_t n = 0; n < model.num_nodes(); ++n) model.SetFixed(n, m.nodes(n, 2) < 1e-9);
  fem::State<double> s(model);
  JitterFreeNodes(model, s, 0.05 * (0.01 / cells));
  const double dt = multiple * fem::EstimateStableStep(model, s, false, 60, 1).dt;
  // Without a load the relative tolerance would shrink with the motion as
  // the cube comes to rest: an absolute one, a millionth of the start's
  // largest elastic nodal force.
  std::vector<double> f0(s.x.size(), 0.0);
  fem::ImplicitIntegrator integrator({.num_threads = 1, .asynchronous_factorization = false});
  integrator.InternalForce(model, s.x.data(), f0.data());
  double f_max = 0;
  for (const double f : f0) f_max = std::max(f_max, std::abs(f));
  integrator.mutable_options().force_tolerance = 1e-6 * f_max;
  const double mass0 = model.TotalMass();
  const double e0 = TotalEnergy(model, s);
  double peak = e0;
  int unconverged = 0;
  bool failed = false;
  Stopwatch watch;
  while (s.step < steps) {
    const fem::ImplicitResult step = integrator.Step(model, s, dt);
    if (step.status == fem::ImplicitStatus::kNonFinite) {
      failed = true;
      break;
    }
    unconverged += step.ok() ? 0 : 1;
    peak = std::max(peak, TotalEnergy(model, s));
  }
  r.wall = watch.ElapsedSeconds();
  r.tets = model.num_tets();
  r.steps = s.step;
  r.sim_time = s.time;
  r.min_dt = r.max_dt = dt;
  r.finite = std::all_of(s.x.begin(), s.x.end(), [](double x) { return std::isfinite(x); });
  r.mass_rel_change = std::abs(model.TotalMass() - mass0) / mass0;
  r.energy_drift = std::abs(TotalEnergy(model, s) - e0) / e0;
  r.step_status = failed ? "non-finite (implicit)" : "ok";
  r.holds = !failed && r.finite && unconverged == 0 && peak <= e0 * (1 + 1e-9);
  r.physical = r.holds;
  r.expected_ok = r.holds;
  r.reason = "dt " + std::to_string(multiple).substr(0, 4) + " x Lanczos limit, " + std::to_string(unconverged) +
             " unconverged steps, energy " + std::to_string(TotalEnergy(model, s) / e0) + " of E0 at the end, peak " +
             std::to_string(peak / e0);
  return r;
}

// ---- Simulation-level cases (cutting, tool) ---------------------------------

/// Smallest det F = det(Ds·Dm⁻¹) over the tets of a mesh view, and how many
/// are below `threshold`.
inline void DetStats(const sim::MeshView& v, double threshold, double& min_det, int& below) {
  below = 0;
  for (Eigen::Index t = 0; t < v.tets.rows(); ++t) {
    Eigen::Matrix3d ds, dm;
    for (int k = 0; k < 3; ++k) {
      ds.col(k) = (v.world.row(v.tets(t, k + 1)) - v.world.row(v.tets(t, 0))).transpose();
      dm.col(k) = (v.rest.row(v.tets(t, k + 1)) - v.rest.row(v.tets(t, 0))).transpose();
    }
    const double dm_det = dm.determinant();
    if (!(std::abs(dm_det) > 0)) continue;  // a zero-volume (degenerate-cut) element has no stiffness
    const double det = ds.determinant() / dm_det;
    min_det = std::min(min_det, det);
    below += det < threshold ? 1 : 0;
  }
}

inline sim::LoadedScene BlockScene(const std::string& path, int nx, int ny, int nz, bool cutting) {
  sim::LoadedScene scene = sim::LoadScene(path);
  auto* box = scene.scene.mutable_mesh()->mutable_box();
  box->set_nx(nx);
  box->set_ny(ny);
  box->set_nz(nz);
  scene.scene.mutable_tool()->clear_path_file();
  scene.scene.mutable_tool()->clear_keyframes();
  scene.scene.mutable_cutting()->set_enabled(cutting);
  return scene;
}

/// The tool cases' block at the suite's size (2s × s × max(2, s/2) cells,
/// s = size.cells), no tool path, one thread, stepped by `integrator`
/// ("explicit" or "implicit"; the scene's AUTO would pick by size).
inline std::unique_ptr<sim::Simulation> SmallBlock(const Size& size, const std::string& scene_path, bool cutting,
                                                   const std::string& integrator = "explicit") {
  const int s = size.cells;
  return sim::Simulation::Create(BlockScene(scene_path, 2 * s, s, std::max(2, s / 2), cutting),
                                 {.threads = 1, .integrator = integrator});
}

/// Finishes a Simulation case from its summary and mesh.
inline void FinishSim(const sim::Simulation& simulation, double mass0, Result& r, sim::MeshView& view) {
  const sim::SimulationSummary s = simulation.Summary();
  simulation.FillMeshView(view);
  r.tets = s.num_tets;
  r.steps = s.steps;
  r.sim_time = s.sim_time;
  r.wall = s.wall_time;
  r.cuts = s.cuts;
  r.rejected_cuts = s.cuts_rejected;
  r.step_status = s.status;
  r.finite = view.world.allFinite();
  r.mass_rel_change = std::abs(s.total_mass - mass0) / mass0;
  r.min_dt = r.max_dt = s.dt;
  DetStats(view, 0.3, r.min_det_f, r.max_inverted);
  double final_min = 1;
  DetStats(view, 0.0, final_min, r.final_inverted);
  r.holds = s.status == "ok" && r.finite && r.mass_rel_change < 1e-9;
  r.physical = r.holds && r.final_inverted == 0;
  r.expected_ok = r.holds;
  r.reason = s.status == "ok" ? (r.final_inverted > 0 ? std::to_string(r.final_inverted) + " inverted elements; " : "") +
                                    std::to_string(s.cuts) + " cuts, " + std::to_string(s.components) + " parts" +
                                    ", smallest rest volume " + std::to_string(s.min_rest_volume * 1e9) + " mm^3"
                              : s.status + ": " + s.diagnosis;
}

/// Random straight strokes of the blade across the block (entering from
/// outside, tip under the base as in scenes/block-cut.path), each followed by
/// dynamics; then 0.2 s (bench) of free dynamics.
inline Result RandomCuts(const Size& size, const std::string& scene_path) {
  Result r;
  r.name = "random cuts (" + std::to_string(size.strokes) + " strokes) then dynamics";
  auto simulation = SmallBlock(size, scene_path, true);
  const double mass0 = simulation->Summary().total_mass;
  std::mt19937 rng(11);
  std::uniform_real_distribution<double> u(0, 1);
  const double frame = 0.01;
  sim::MeshView view;
  double min_det = 1;
  int peak_inverted = 0;
  Stopwatch watch;
  bool ok = true;
  // Start with the blade well above the block (without a path the tool sits
  // at the origin, on the block's corner edge: ToolOnEdge).
  simulation->SetToolPose({Eigen::Vector3d(0.02, 0.01, 0.05), Eigen::Vector3d::UnitZ()});
  for (int k = 0; k < size.strokes && ok; ++k) {
    // A chord of the 40 × 20 mm top between two random points on the border (outside by 3 mm).
    const double a = 2 * M_PI * u(rng), b = a + M_PI * (0.5 + u(rng));
    const Eigen::Vector3d c(0.02, 0.01, -0.001);
    const Eigen::Vector3d p0 = c + Eigen::Vector3d(0.025 * std::cos(a), 0.015 * std::sin(a), 0);
    const Eigen::Vector3d p1 = c + Eigen::Vector3d(0.025 * std::cos(b), 0.015 * std::sin(b), 0);
    constexpr int kStrokeFrames = 20;
    for (int f = 0; f <= kStrokeFrames && ok; ++f) {
      simulation->SetToolPose({p0 + (p1 - p0) * (static_cast<double>(f) / kStrokeFrames), Eigen::Vector3d::UnitZ()});
      ok = simulation->AdvanceFrame(frame) == sim::SimStatus::kOk;
    }
    // Lift the blade out and move it away before the next stroke.
    simulation->SetToolPose({Eigen::Vector3d(0.02, 0.01, 0.05), Eigen::Vector3d::UnitZ()});
    for (int f = 0; f < 3 && ok; ++f) ok = simulation->AdvanceFrame(frame) == sim::SimStatus::kOk;
    if (k % 10 == 0) {
      simulation->FillMeshView(view);
      int below = 0;
      DetStats(view, 0.3, min_det, below);
      peak_inverted = std::max(peak_inverted, below);
    }
  }
  const int settle = static_cast<int>(std::lround(std::max(0.05, size.duration) / frame));
  for (int f = 0; f < settle && ok; ++f) ok = simulation->AdvanceFrame(frame) == sim::SimStatus::kOk;
  FinishSim(*simulation, mass0, r, view);
  r.min_det_f = std::min(r.min_det_f, min_det);
  r.max_inverted = std::max(r.max_inverted, peak_inverted);
  r.wall = watch.ElapsedSeconds();
  return r;
}

/// The blade teleported to the block's centre, 8 mm deep in a 10 mm block,
/// and held there (cutting on or off).
inline Result ToolJammed(const Size& size, const std::string& scene_path, bool cutting) {
  Result r;
  r.name = std::string("tool jammed 8 mm deep, cutting ") + (cutting ? "on" : "off");
  auto simulation = SmallBlock(size, scene_path, cutting);
  const double mass0 = simulation->Summary().total_mass;
  const double frame = 0.01;
  Stopwatch watch;
  simulation->SetToolPose({Eigen::Vector3d(0.0201, 0.0101, 0.002), Eigen::Vector3d::UnitZ()});
  const int frames = std::max(2, static_cast<int>(std::lround(size.jam_time / frame)));
  for (int f = 0; f < frames; ++f) {
    if (simulation->AdvanceFrame(frame) != sim::SimStatus::kOk) break;
  }
  sim::MeshView view;
  FinishSim(*simulation, mass0, r, view);
  r.wall = watch.ElapsedSeconds();
  const sim::ToolReport tool = simulation->Tool();
  r.reason += ", tool force " + std::to_string(tool.force_on_tool.norm()) + " N, depth " +
              std::to_string(tool.depth * 1e3) + " mm";
  return r;
}

/// The blade (tip 1 mm under the base) drawn back and forth along x
/// through the block with cutting off: its edge grip drags the tissue at
/// the cap the whole way (the steady resistance of tissue it cannot cut).
inline Result ToolDrawnThrough(const Size& size, const std::string& scene_path) {
  Result r;
  r.name = "tool drawn through the block, cutting off";
  auto simulation = SmallBlock(size, scene_path, false);
  const double mass0 = simulation->Summary().total_mass;
  const double frame = 0.01;
  Stopwatch watch;
  const int frames = std::max(4, static_cast<int>(std::lround(size.jam_time / frame)));
  double peak = 0;
  for (int f = 0; f < frames; ++f) {
    const double phase = static_cast<double>(f) / frames;  // one pass there and back
    const double x = 0.005 + 0.03 * (phase < 0.5 ? 2 * phase : 2 - 2 * phase);
    simulation->SetToolPose({Eigen::Vector3d(x, 0.0101, -0.001), Eigen::Vector3d::UnitZ()});
    if (simulation->AdvanceFrame(frame) != sim::SimStatus::kOk) break;
    peak = std::max(peak, simulation->Tool().force_on_tool.norm());
  }
  sim::MeshView view;
  FinishSim(*simulation, mass0, r, view);
  r.wall = watch.ElapsedSeconds();
  r.reason += ", peak tool force " + std::to_string(peak) + " N";
  return r;
}

/// The blade held pointing +z along the block's corner edge, its tip at
/// height `tip_z` on the edge. At the origin (the worst place a tool could
/// rest) the blade stands along the whole edge: it is inside the
/// tissue and its edge grip holds it (tool_contact.h). At 0.5 mm under the
/// top (under the indentation limit) the tip presses the top corner: the
/// penalty acts on a vertex and the edges shared by the top and side facets.
inline Result ToolOnEdge(const Size& size, const std::string& scene_path, double tip_z = 0.0,
                         const std::string& integrator = "explicit") {
  Result r;
  r.name = tip_z == 0.0 ? "tool resting on the block's corner edge (no path)"
                        : "tool tip pressing the block's top corner, 0.5 mm";
  if (integrator != "explicit") r.name += ", " + integrator;
  auto simulation = SmallBlock(size, scene_path, true, integrator);
  const double mass0 = simulation->Summary().total_mass;
  const double frame = 0.01;
  Stopwatch watch;
  const int frames = std::max(2, static_cast<int>(std::lround(size.jam_time / frame)));
  // A tool without a path is parked clear of the body (ToolParked); put the
  // blade where the old default pose left it: tip at the origin, along +z.
  simulation->SetToolPose({Eigen::Vector3d(0, 0, tip_z), Eigen::Vector3d::UnitZ()});
  int touching = 0;
  for (int f = 0; f < frames; ++f) {
    if (simulation->AdvanceFrame(frame) != sim::SimStatus::kOk) break;
    touching += simulation->Tool().touching ? 1 : 0;
  }
  sim::MeshView view;
  FinishSim(*simulation, mass0, r, view);
  r.wall = watch.ElapsedSeconds();
  r.reason += ", touching in " + std::to_string(touching) + " of " + std::to_string(frames) + " frames";
  return r;
}

/// Every case at `size`. `scene_path` is scenes/block.pbtxt.
/// `on_case` (optional) is called after each case, e.g. for progress lines.
/// Every case in table order; `only` (empty: all) keeps the cases whose
/// name contains it, and the others are not run.
inline std::vector<Result> RunAll(const Size& size, const std::string& scene_path,
                                  const std::function<void(const Result&)>& on_case = {},
                                  const std::string& only = {}) {
  std::vector<Result> out;
  const auto add = [&](const std::string& name, const std::function<Result()>& run) {
    if (!only.empty() && name.find(only) == std::string::npos) return;
    Result r = run();
    if (r.expectation == "holds") r.expected_ok = r.holds;
    if (on_case) on_case(r);
    out.push_back(std::move(r));
  };
  add("stretch x3", [&] { return StretchX3(size); });
  add("compression to 10% volume", [&] { return CompressVolume10(size); });
  add("uniaxial compression to 10% length", [&] { return CompressUniaxial10(size); });
  add("near-incompressible nu 0.45", [&] { return NearIncompressible(size, 0.45); });
  add("near-incompressible nu 0.49", [&] { return NearIncompressible(size, 0.49); });
  add("stiffness contrast 1000x", [&] { return StiffnessContrast(size); });
  for (const double frac : {0.5, kFixedStepResonanceOnset, 0.75, 1.0}) {
    const std::string name = "fixed dt = " + std::to_string(frac).substr(0, 4) + " x initial Lanczos limit";
    add(name, [&] { return FixedStep(name, size.cells, size.dt_steps, frac, false); });
  }
  for (const double frac : {0.5, 0.75, 1.0}) {
    const std::string name = "Advance, safety_factor " + std::to_string(frac).substr(0, 4);
    add(name, [&] { return FixedStep(name, size.cells, size.dt_steps, frac, false, true); });
  }
  const std::string implicit_large = "implicit dt = 20 x initial Lanczos limit";
  add(implicit_large, [&] { return ImplicitLargeStep(implicit_large, size.cells, size.dt_steps / 20, 20.0); });
  add("fixed dt = 1.5 x Lanczos limit (beyond)",
      [&] { return FixedStep("fixed dt = 1.5 x Lanczos limit (beyond)", size.cells, size.dt_steps, 1.5, true); });
  const std::string long_fixed = "long run: " + std::to_string(size.long_steps) + " steps, fixed dt 0.5 x Lanczos, 48 tets";
  add(long_fixed, [&] { return FixedStep(long_fixed, 2, size.long_steps, 0.5, false, false); });
  const std::string long_advance =
      "long run: " + std::to_string(size.long_steps) + " steps, Advance (default 0.85), 48 tets";
  add(long_advance, [&] { return FixedStep(long_advance, 2, size.long_steps, 0.85, false, true); });
  add("tool jammed, cutting off", [&] { return ToolJammed(size, scene_path, false); });
  add("tool jammed, cutting on", [&] { return ToolJammed(size, scene_path, true); });
  add("tool on the corner edge", [&] { return ToolOnEdge(size, scene_path); });
  add("tool tip pressing the corner", [&] { return ToolOnEdge(size, scene_path, 0.0095); });
  add("tool on the corner edge, implicit", [&] { return ToolOnEdge(size, scene_path, 0.0, "implicit"); });
  add("tool drawn through uncut tissue", [&] { return ToolDrawnThrough(size, scene_path); });
  add("random cuts", [&] { return RandomCuts(size, scene_path); });  // last: see the note in stability_test.cc
  return out;
}

}  // namespace cutsim::support::stability
