#pragma once
// A randomized stroke suite: a trainee's strokes are not the shipped path.
// From a fixed seed, strokes of the blade on a shipped scene: random entry
// on the top of the tissue, direction, depth, blade tilt (up to 30°) and
// speed (1–10 cm/s), of three kinds (a straight draw, sawing back and
// forth, a plunge). One simulation takes them all in turn, as a session
// would. After every frame that cut, the run must still be ok, every
// position finite, no face shared by more than two tets and the mass
// unchanged.

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <random>
#include <string>
#include <vector>

#include <Eigen/Geometry>

#include "common/core/clock.h"
#include "common/mesh/mesh_validation.h"
#include "common/sim/scene_loader.h"
#include "common/sim/simulation.h"

namespace cutsim::support::strokes {

struct SuiteResult {
  std::string scene;
  int strokes = 0;          ///< Strokes run (all of them unless one stopped the run).
  int stopped = 0;          ///< Strokes during which the run stopped (status not ok).
  int invalid_meshes = 0;   ///< Cut frames after which the mesh was invalid.
  int mass_changes = 0;     ///< Cut frames after which the total mass had moved.
  int64_t frames = 0;
  int64_t cut_frames = 0;
  uint64_t cuts = 0;
  double sim_time = 0;      ///< s
  double wall = 0;          ///< s
  int64_t recovered_steps = 0;  ///< implicit steps redone in substeps
  std::string first_failure;    ///< what stopped or broke first, if anything
  [[nodiscard]] bool ok() const { return stopped == 0 && invalid_meshes == 0 && mass_changes == 0; }
};

/// The mesh checks run after a cut frame: finite positions, indices in
/// range, no face shared by more than two tets.
inline std::string MeshProblem(const sim::Simulation& simulation) {
  const mesh::TetMesh m = simulation.WorldMesh();
  if (!m.nodes.allFinite()) return "a non-finite position";
  if (m.tets.size() > 0 && (m.tets.minCoeff() < 0 || m.tets.maxCoeff() >= m.num_nodes())) return "a tet index out of range";
  if (const int64_t f = mesh::FindOvershardFace(m.tets); f >= 0) {
    return "face " + std::to_string(f) + " shared by more than two tets";
  }
  return {};
}

/// Runs `strokes` random strokes on the scene at `scene_path` with seed
/// `seed`, frames of the scene's frame_dt, `threads` threads (0: the
/// scene's default).
inline SuiteResult RunStrokes(const std::string& scene_path, int strokes, uint32_t seed, int threads = 0) {
  SuiteResult out;
  out.scene = scene_path;
  const sim::LoadedScene scene = sim::LoadScene(scene_path);
  auto simulation = sim::Simulation::Create(scene, {.threads = threads});
  const double frame = simulation->frame_dt();
  sim::MeshView view;
  simulation->FillMeshView(view);
  const Eigen::Vector3d lo = view.world.colwise().minCoeff().transpose();
  const Eigen::Vector3d hi = view.world.colwise().maxCoeff().transpose();
  const Eigen::Vector3d extent = hi - lo;
  const double mass0 = simulation->Summary().total_mass;
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> u(0, 1);
  Stopwatch watch;
  const Eigen::Vector3d clear(0.5 * (lo.x() + hi.x()), 0.5 * (lo.y() + hi.y()), hi.z() + 0.03);
  uint64_t cuts = simulation->Tool().cuts;
  bool running = true;
  // Moves the tool from `a` to `b` at `speed` (m/s) with blade `dir`, a
  // frame at a time, checking after each frame that cut.
  const auto move = [&](const Eigen::Vector3d& a, const Eigen::Vector3d& b, double speed, const Eigen::Vector3d& dir) {
    const int frames = std::max(1, static_cast<int>(std::ceil((b - a).norm() / (speed * frame))));
    for (int f = 1; f <= frames && running; ++f) {
      simulation->SetToolPose({a + (b - a) * (static_cast<double>(f) / frames), dir});
      ++out.frames;
      if (simulation->AdvanceFrame(frame) != sim::SimStatus::kOk) {
        running = false;
        ++out.stopped;
        if (out.first_failure.empty()) out.first_failure = "stopped: " + simulation->QuickSummary().diagnosis;
        return;
      }
      const uint64_t now = simulation->Tool().cuts;
      if (now == cuts) continue;
      cuts = now;
      ++out.cut_frames;
      if (const std::string problem = MeshProblem(*simulation); !problem.empty()) {
        ++out.invalid_meshes;
        if (out.first_failure.empty()) out.first_failure = "frame " + std::to_string(out.frames) + ": " + problem;
      }
      const double mass = simulation->Summary().total_mass;
      if (std::abs(mass - mass0) > 1e-9 * mass0) {
        ++out.mass_changes;
        if (out.first_failure.empty()) out.first_failure = "mass moved by " + std::to_string(mass - mass0) + " kg";
      }
    }
  };
  for (int k = 0; k < strokes && running; ++k) {
    const Eigen::Vector3d entry(lo.x() + (0.15 + 0.7 * u(rng)) * extent.x(), lo.y() + (0.15 + 0.7 * u(rng)) * extent.y(),
                                hi.z());
    const double heading = 2 * M_PI * u(rng);
    const Eigen::Vector3d along(std::cos(heading), std::sin(heading), 0);
    const double tilt = (M_PI / 6) * u(rng);
    const Eigen::Vector3d tilt_axis = Eigen::Vector3d(-std::sin(heading + u(rng)), std::cos(heading), 0).normalized();
    const Eigen::Vector3d dir = Eigen::AngleAxisd(tilt, tilt_axis) * Eigen::Vector3d::UnitZ();
    const double depth = (0.1 + 0.5 * u(rng)) * extent.z();
    const double speed = 0.01 + 0.09 * u(rng);
    const double length = (0.2 + 0.4 * u(rng)) * std::min(extent.x(), extent.y());
    const Eigen::Vector3d above = entry + Eigen::Vector3d(0, 0, 0.02);
    const Eigen::Vector3d start = entry - Eigen::Vector3d(0, 0, depth);
    const int kind = k % 3;  // straight, sawing, plunge
    move(clear, above, 0.1, dir);
    move(above, start, speed, dir);
    if (kind == 0) {
      move(start, start + length * along, speed, dir);
    } else if (kind == 1) {
      for (int pass = 0; pass < 4 && running; ++pass) {
        const Eigen::Vector3d a = start + (pass % 2 == 0 ? 0.0 : 0.3) * length * along;
        move(a, start + (pass % 2 == 0 ? 0.3 : 0.0) * length * along, speed, dir);
      }
    } else {
      move(start, start - Eigen::Vector3d(0, 0, 0.3 * depth), speed, dir);
    }
    move(simulation->Tool().pose.tip, above + (kind == 0 ? length : 0.0) * along, 0.1, dir);
    out.strokes = k + 1;
  }
  const sim::SimulationSummary s = simulation->QuickSummary();
  out.cuts = s.cuts;
  out.sim_time = s.sim_time;
  out.recovered_steps = s.implicit.recovered_steps;
  out.wall = watch.ElapsedSeconds();
  return out;
}

}  // namespace cutsim::support::strokes
