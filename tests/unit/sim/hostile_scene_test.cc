// Valid-looking but hostile scenes: every value that bounds the work a scene
// asks for is checked against a stated limit, with the field named, and the
// physics loop answers a stop request within a sub-step.

#include <filesystem>
#include <fstream>
#include <string>
#include <utility>
#include <vector>

#include <gtest/gtest.h>

#include "common/core/error.h"
#include "common/core/stop.h"
#include "common/sim/scene_loader.h"
#include "common/sim/simulation.h"

namespace cutsim::sim {
namespace {

const std::string kMesh =
    "mesh { box { min { x: 0 y: 0 z: 0 } max { x: 0.02 y: 0.01 z: 0.01 } nx: 2 ny: 1 nz: 1 } }\n";
const std::string kFixed = "boundary { plane { point { x: 0 y: 0 z: 0 } normal { x: 1 y: 0 z: 0 } } }\n";

std::string Material(const std::string& e, const std::string& nu) {
  return "materials { young_poisson { youngs_modulus: " + e + " poisson_ratio: " + nu + " } density: 1000 }\n";
}

template <typename Fn>
InputError ErrorOf(Fn&& fn) {
  try {
    fn();
  } catch (const InputError& e) {
    return e;
  }
  ADD_FAILURE() << "no InputError";
  return InputError({}, "none");
}

InputError ParseError(const std::string& text) {
  return ErrorOf([&] { (void)ParseScene(text, "scene.pbtxt", "."); });
}

TEST(HostileScene, OutOfRangeValuesNameTheFieldAndTheLimit) {
  const std::string base = kMesh + Material("20000", "0.4");
  const struct {
    std::string text;
    std::string field;
  } cases[] = {
      {base + "time_step { threads: 70000 }", "time_step.threads"},
      {base + "time_step { threads: 2147483647 }", "time_step.threads"},
      {base + "time_step { frame_dt: 1e-300 }", "time_step.frame_dt"},
      {base + "time_step { frame_dt: 1e300 }", "time_step.frame_dt"},
      {base + "time_step { fixed_dt: 1e-300 }", "time_step.fixed_dt"},
      {base + "time_step { safety_factor: 1e-300 }", "time_step.safety_factor"},
      {base + "time_step { integrator: 99 }", "time_step.integrator"},
      {base + "boundary { plane { point { x: 0 } normal { x: 1 } } kind: 99 }", "boundary[0].kind"},
      {"mesh { box { min { x: 0 y: 0 z: 0 } max { x: 1 y: 1 z: 1 } nx: 2147483647 ny: 1 nz: 1 } }\n" +
           Material("20000", "0.4"),
       "mesh.box.nx/ny/nz"},
      {"mesh { box { min { x: 0 y: 0 z: 0 } max { x: 1 y: 1 z: 1 } nx: 300 ny: 300 nz: 300 } }\n" +
           Material("20000", "0.4"),
       "mesh.box.nx/ny/nz"},
      {"mesh { organ { semi_axes { x: 1 y: 1 z: 1 } edge_length: 0.0001 } }\n" + Material("20000", "0.4"),
       "mesh.organ.edge_length"},
      {"mesh { box { min { x: 0 y: 0 z: 0 } max { x: 1 y: 1 z: 1 } nx: 1 ny: 1 nz: 1 } scale: 1e300 }\n" +
           Material("20000", "0.4"),
       "mesh.scale"},
      {base + "tool { keyframes { t: 0 tip { x: 0 } blade_dir { z: 1 } } keyframes { t: 1e300 tip { x: 0 } "
              "blade_dir { z: 1 } } }",
       "tool.keyframes[1].t"},
  };
  for (const auto& c : cases) {
    const InputError e = ParseError(c.text);
    EXPECT_EQ(e.source().field, c.field) << c.text << "\n" << e.what();
    EXPECT_EQ(e.source().file, "scene.pbtxt");
  }
}

TEST(HostileScene, FieldsNoProgramReadsAreRefusedNotIgnored) {
  const std::string base = kMesh + Material("20000", "0.4");
  for (const auto& [text, field] : {std::pair{std::string("haptics { max_force: 2 }"), "haptics.max_force"},
                                    std::pair{std::string("haptics { max_stiffness: 500 }"), "haptics.max_stiffness"},
                                    std::pair{std::string("haptics { watchdog: 0.02 }"), "haptics.watchdog"},
                                    std::pair{std::string("outputs { vtu: \"x.vtu\" }"), "outputs"},
                                    std::pair{std::string("camera { fov_deg: 30 }"), "camera"}}) {
    const InputError e = ParseError(base + text);
    EXPECT_EQ(e.source().field, field) << e.what();
    EXPECT_NE(std::string(e.what()).find("not read"), std::string::npos) << e.what();
  }
  // decay_per_second reaches the haptic station in every model: accepted.
  EXPECT_NO_THROW((void)ParseScene(base + "haptics { decay_per_second: 20 }", "scene.pbtxt", "."));
}

TEST(HostileScene, StiffnessOutOfRangeForExplicitIntegrationIsRefusedWithAnEstimate) {
  for (const auto& material : {Material("20000", "0.4999999999999")}) {
    const LoadedScene scene = ParseScene(kMesh + material + kFixed, "stiff.pbtxt", ".");
    const InputError e = ErrorOf([&] { (void)Simulation::Create(scene, {.threads = 1}); });
    const std::string what = e.what();
    EXPECT_NE(what.find("steps per second of simulation"), std::string::npos) << what;
    EXPECT_NE(what.find("out of range for explicit integration"), std::string::npos) << what;
    EXPECT_EQ(e.source().file, "stiff.pbtxt");
  }
  // The same scene within the budget loads.
  const LoadedScene ok = ParseScene(kMesh + Material("20000", "0.4") + kFixed, "ok.pbtxt", ".");
  EXPECT_NO_THROW((void)Simulation::Create(ok, {.threads = 1}));
}

TEST(HostileScene, EveryMagnitudeOutsideItsStatedRangeIsRefusedByName) {
  const std::string base = kMesh + Material("20000", "0.4") + kFixed;
  const std::string plan = "planned_incision { points { x: 0 y: 0 z: 0.01 } points { x: 0.02 y: 0 z: 0.01 } depth: 0.005 }\n";
  const std::vector<std::pair<std::string, std::string>> cases = {
      {kMesh + Material("1e30", "0.3") + kFixed, "materials[0].young_poisson.youngs_modulus"},
      {kMesh + Material("1e-30", "0.3") + kFixed, "materials[0].young_poisson.youngs_modulus"},
      {kMesh + "materials { lame { lambda: 1e20 mu: 1000 } density: 1000 }\n" + kFixed, "materials[0].lame.lambda"},
      {kMesh + "materials { lame { lambda: 0 mu: 1000 } density: 1e9 }\n" + kFixed, "materials[0].density"},
      {kMesh + "materials { lame { lambda: 0 mu: 1000 } density: 1000 damping_psi: 1e300 }\n" + kFixed,
       "materials[0].damping_psi"},
      {base + "gravity { z: -1e6 }", "gravity.z"},
      {base + "mass_damping: 1e300", "mass_damping"},
      {base + "boundary { box { min { x: -1e300 } max { x: 1 y: 1 z: 1 } } }", "boundary[1].box.min.x"},
      {base + "boundary { plane { point { x: 0 } normal { x: 1e300 } } }", "boundary[1].plane.normal.x"},
      {base + "boundary { plane { point { x: 0 } normal { x: 1 } tolerance: 1e300 } }", "boundary[1].plane.tolerance"},
      {base + "boundary { nodes { ids: 0 } kind: KIND_FORCE force { z: 1e300 } }", "boundary[1].force.z"},
      {base + "planned_incision { points { x: 1e300 y: 0 z: 0 } points { x: -1e300 y: 0 z: 0 } depth: 0.005 }",
       "planned_incision.points[0].x"},
      {base + plan.substr(0, plan.size() - 2) + " tolerance: 1e300 }", "planned_incision.tolerance"},
      {base + "tool { blade_length: 1e300 }", "tool.blade_length"},
      {base + "tool { contact_stiffness: 1e300 }", "tool.contact_stiffness"},
      {base + "tool { keyframes { t: 0 tip { x: 1e300 } } }", "tool.keyframes[0].tip.x"},
      {base + "haptics { decay_per_second: 1e300 }", "haptics.decay_per_second"},
      {base + "haptics { device_offset { y: 1e300 } }", "haptics.device_offset.y"},
      {base + "rest { kinetic_energy: 1e300 }", "rest.kinetic_energy"},
      {"mesh { box { min { x: 0 y: 0 z: 0 } max { x: 0.02 y: 0.01 z: 0.01 } nx: 2 ny: 1 nz: 1 } translate { x: 1e300 } }\n" +
           Material("20000", "0.4") + kFixed,
       "mesh.translate.x"},
  };
  for (const auto& [text, field] : cases) {
    const InputError e = ParseError(text);
    EXPECT_EQ(e.source().field, field) << e.what();
  }
  EXPECT_NO_THROW((void)ParseScene(base + plan, "scene.pbtxt", "."));
}

TEST(HostileScene, ThreadsFromTheCommandLineOrARecordingAreCapped) {
  const LoadedScene scene = ParseScene(kMesh + Material("20000", "0.4") + kFixed, "t.pbtxt", ".");
  for (const int threads : {65536, 257, -1}) {
    const InputError e = ErrorOf([&] { (void)Simulation::Create(scene, {.threads = threads}); });
    EXPECT_EQ(e.source().field, "threads") << e.what();
  }
  EXPECT_NO_THROW((void)Simulation::Create(scene, {.threads = static_cast<int>(kMaxThreads)}));
}

TEST(HostileScene, NonRegularScenesAndPathFilesAreRefusedAsSuch) {
  EXPECT_NE(std::string(ErrorOf([] { (void)LoadScene("/dev/zero"); }).what()).find("character device"),
            std::string::npos);
  const auto dir = std::filesystem::temp_directory_path() / ("cutsim_hostile_scene_" + std::to_string(::getpid()));
  std::filesystem::create_directories(dir / "path.txt");
  const LoadedScene scene = ParseScene(kMesh + Material("20000", "0.4") + "tool { path_file: \"path.txt\" }",
                                       (dir / "s.pbtxt").string(), dir);
  const std::string what = ErrorOf([&] { (void)Simulation::Create(scene, {.threads = 1}); }).what();
  EXPECT_NE(what.find("directory"), std::string::npos) << what;
  EXPECT_EQ(what.find("no keyframes"), std::string::npos) << what;
  std::filesystem::remove_all(dir);
}

TEST(HostileScene, AStopRequestEndsAFrameWithinASubStep) {
  // A stiff (but allowed) tissue and a 1 s frame: thousands of sub-steps.
  const LoadedScene scene = ParseScene(
      kMesh + Material("1e8", "0.45") + kFixed + "time_step { frame_dt: 1 }", "long-frame.pbtxt", ".");
  auto sim = Simulation::Create(scene, {.threads = 1});
  RequestStop();
  (void)sim->AdvanceFrame();
  internal::g_stop_requested.store(false);
  const int64_t steps_after_stop = sim->QuickSummary().steps;
  EXPECT_LE(steps_after_stop, 2) << "the frame ran on after the stop request";
  // Without a stop request the same frame takes thousands of sub-steps.
  (void)sim->AdvanceFrame();
  EXPECT_GT(sim->QuickSummary().steps - steps_after_stop, 1000);
}

}  // namespace
}  // namespace cutsim::sim
