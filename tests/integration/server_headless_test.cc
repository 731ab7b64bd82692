// The headless server as a user runs it: real process, real scene files.
#include <sys/stat.h>

#include <filesystem>
#include <fstream>
#include <iterator>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "common/mesh/mesh_io.h"
#include "tests/integration/subprocess.h"

namespace cutsim {
namespace {

using testing::BinPath;
using testing::RunProcess;
using testing::JsonNumber;
using testing::TempDir;
using namespace std::chrono_literals;

std::string Write(const TempDir& dir, const std::string& name, const std::string& text) {
  const std::string path = dir.path() + "/" + name;
  std::ofstream(path) << text;
  return path;
}

const char* kSmallBeam = R"pb(
name: "small-beam"
mesh { box { min { x: 0 y: 0 z: 0 } max { x: 0.05 y: 0.01 z: 0.01 } nx: 10 ny: 2 nz: 2 } }
materials { young_poisson { youngs_modulus: 200000 poisson_ratio: 0.3 } density: 1000 damping_psi: 50 }
boundary { plane { point { x: 0 y: 0 z: 0 } normal { x: 1 y: 0 z: 0 } } }
gravity { z: -9.81 }
)pb";

TEST(ServerHeadlessTest, RunsForDurationAndWritesVtu) {
  TempDir dir;
  const std::string scene = Write(dir, "beam.pbtxt", kSmallBeam);
  const std::string out = dir.path() + "/beam.vtu";
  const auto r = RunProcess({BinPath("cutsim-server"), "--headless", "--scene", scene, "--duration",
                      "0.05", "--out", out, "--no-progress"},
                     120s);
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_NEAR(JsonNumber(r.out, "sim_time"), 0.05, 1e-9) << r.out;
  EXPECT_GT(JsonNumber(r.out, "steps"), 0);
  EXPECT_GT(JsonNumber(r.out, "max_displacement"), 0.0);
  EXPECT_GT(JsonNumber(r.out, "tet_steps_per_s"), 0.0);
  EXPECT_EQ(JsonNumber(r.out, "tets"), 10 * 2 * 2 * 6);
  ASSERT_TRUE(std::filesystem::exists(out));
  const mesh::TetMesh m = mesh::ReadMesh(out);
  EXPECT_EQ(m.num_tets(), 10 * 2 * 2 * 6);
}

// The shipped ligament, cut by its scripted path, scored against its planned
// incision: the summary carries the score, --session-report writes the same
// score with its series as JSON and their plot as SVG.
TEST(ServerHeadlessTest, SessionReportScoresTheLigamentCut) {
  TempDir dir;
  const std::string report = dir.path() + "/report.json";
  const auto r = RunProcess({BinPath("cutsim-server"), "--headless", "--scene",
                             std::string(CUTSIM_SOURCE_DIR) + "/scenes/ligament.pbtxt", "--session-report", report,
                             "--no-progress", "--threads", "1"},
                            300s);
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_GE(JsonNumber(r.out, "cuts"), 1) << r.out;
  EXPECT_GE(JsonNumber(r.out, "cut_points"), 1) << r.out;
  // On the planned line (x = 15 mm; the path cuts at 15.1 mm), through the
  // full 8 mm.
  EXPECT_LT(JsonNumber(r.out, "mean_deviation"), 0.001) << r.out;
  EXPECT_NEAR(JsonNumber(r.out, "depth_error"), 0.0, 0.001) << r.out;
  // The blade crosses the 8 mm in one cut step and severs it: the whole
  // planned cut surface is opened.
  EXPECT_GE(JsonNumber(r.out, "coverage"), 0.9) << r.out;
  std::ifstream in(report);
  const std::string json((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  EXPECT_EQ(JsonNumber(json, "mean_deviation"), JsonNumber(r.out, "mean_deviation")) << json;
  EXPECT_NE(json.find("\"force_t\":["), std::string::npos) << json.substr(0, 400);
  EXPECT_NE(json.find("\"cut_deviation\":["), std::string::npos) << json.substr(0, 400);
  std::ifstream svg_in(dir.path() + "/report.svg");
  const std::string svg((std::istreambuf_iterator<char>(svg_in)), std::istreambuf_iterator<char>());
  EXPECT_EQ(svg.rfind("<svg", 0), 0u) << svg.substr(0, 200);
  EXPECT_NE(svg.find("<polyline"), std::string::npos);
  EXPECT_NE(svg.find("<circle"), std::string::npos);
  EXPECT_NE(svg.find("tolerance"), std::string::npos);
  EXPECT_FALSE(std::filesystem::exists(report + ".tmp"));
}

// Outputs never replace what is not theirs, and every one is checked before
// the session starts: a device, a pipe or a directory at an output's path
// (the session report's .svg included) is refused at once, naming the flag
// and the path, and is still there afterwards.
TEST(ServerHeadlessTest, OutputsThatAreNotRegularFilesAreRefusedBeforeTheSession) {
  TempDir dir;
  const std::string scene = Write(dir, "beam.pbtxt", kSmallBeam);
  const std::string fifo = dir.path() + "/pipe";
  ASSERT_EQ(::mkfifo(fifo.c_str(), 0600), 0);
  std::filesystem::create_directory(dir.path() + "/report.svg");
  struct Case {
    std::vector<std::string> flags;
    std::string flag, path, kind;
  };
  const std::vector<Case> cases = {
      {{"--session-report", "/dev/full"}, "--session-report", "/dev/full", "character device"},
      {{"--out", fifo}, "--out", fifo, "pipe"},
      {{"--checkpoint", "/dev/null"}, "--checkpoint", "/dev/null", "character device"},
      {{"--stats-json", fifo}, "--stats-json", fifo, "pipe"},
      {{"--session-report", dir.path() + "/report.json"}, ".svg", dir.path() + "/report.svg", "directory"},
  };
  for (const Case& c : cases) {
    std::vector<std::string> args = {BinPath("cutsim-server"), "--headless", "--scene", scene, "--duration", "30"};
    args.insert(args.end(), c.flags.begin(), c.flags.end());
    const auto r = RunProcess(args, 60s);
    EXPECT_EQ(r.exit_code, 2) << r.err;
    EXPECT_NE(r.err.find(c.flag), std::string::npos) << r.err;
    EXPECT_NE(r.err.find(c.path), std::string::npos) << r.err;
    EXPECT_NE(r.err.find(c.kind), std::string::npos) << r.err;
    EXPECT_EQ(r.out.find("\"sim_time\""), std::string::npos) << "the session ran: " << r.out;
  }
  EXPECT_TRUE(std::filesystem::is_character_file("/dev/full"));
  EXPECT_TRUE(std::filesystem::is_character_file("/dev/null"));
  EXPECT_TRUE(std::filesystem::is_fifo(fifo));
  EXPECT_FALSE(std::filesystem::exists(dir.path() + "/report.json")) << "nothing written when an output is refused";
}

// Headless honours --stats-json: the summary it prints, written to the file.
TEST(ServerHeadlessTest, StatsJsonIsWrittenInHeadlessMode) {
  TempDir dir;
  const std::string scene = Write(dir, "beam.pbtxt", kSmallBeam);
  const std::string stats = dir.path() + "/stats.json";
  const auto r = RunProcess({BinPath("cutsim-server"), "--headless", "--scene", scene, "--duration", "0.05",
                             "--stats-json", stats, "--no-progress"},
                            60s);
  ASSERT_EQ(r.exit_code, 0) << r.err;
  std::ifstream in(stats);
  const std::string json((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  EXPECT_EQ(json, r.out);
}

// An implicit step that stops at its Newton cap above its force tolerance
// is not an answer: the summary's status is "unconverged" with the count
// and the largest residual in newtons, the session report says the same,
// every output is still written, and the run exits 7 (not 0).
TEST(ServerHeadlessTest, UnconvergedImplicitStepsAreNeverReportedOk) {
  TempDir dir;
  // One Newton iteration per step against a 1e-12 N tolerance: the beam
  // falling under gravity cannot meet it.
  const std::string scene = Write(dir, "beam.pbtxt", std::string(kSmallBeam) + R"pb(
time_step { integrator: INTEGRATOR_IMPLICIT implicit { force_tolerance: 1e-12 max_newton_iterations: 1 } }
)pb");
  const std::string report = dir.path() + "/report.json";
  const std::string out = dir.path() + "/beam.vtu";
  const auto r = RunProcess({BinPath("cutsim-server"), "--headless", "--scene", scene, "--duration", "0.05",
                             "--threads", "1", "--session-report", report, "--out", out, "--no-progress"},
                            120s);
  EXPECT_EQ(r.exit_code, 7) << r.err;
  EXPECT_EQ(testing::JsonString(r.out, "status").value_or(""), "unconverged") << r.out;
  const double steps = JsonNumber(r.out, "unconverged_steps");
  EXPECT_GT(steps, 0) << r.out;
  const double residual = JsonNumber(r.out, "max_residual_unconverged");
  EXPECT_GT(residual, 1e-12) << r.out;
  const std::string diagnosis = testing::JsonString(r.out, "diagnosis").value_or("");
  EXPECT_NE(diagnosis.find(std::to_string(static_cast<int64_t>(steps)) + " of "), std::string::npos) << diagnosis;
  EXPECT_NE(diagnosis.find(" N"), std::string::npos) << diagnosis;
  EXPECT_NE(r.err.find("did not converge"), std::string::npos) << r.err;
  // The outputs are written all the same: the state is finite, only not
  // at the tolerance.
  EXPECT_TRUE(std::filesystem::exists(out));
  std::ifstream in(report);
  const std::string json((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  EXPECT_EQ(testing::JsonString(json, "status").value_or(""), "unconverged") << json.substr(0, 400);
  EXPECT_EQ(JsonNumber(json, "unconverged_steps"), steps) << json.substr(0, 400);
  std::ifstream svg_in(dir.path() + "/report.svg");
  const std::string svg((std::istreambuf_iterator<char>(svg_in)), std::istreambuf_iterator<char>());
  EXPECT_NE(svg.find("status unconverged"), std::string::npos) << svg.substr(0, 400);

  // The same beam with Newton free to converge: ok, exit 0.
  const std::string converged = Write(dir, "converged.pbtxt", std::string(kSmallBeam) + R"pb(
time_step { integrator: INTEGRATOR_IMPLICIT }
)pb");
  const auto ok = RunProcess({BinPath("cutsim-server"), "--headless", "--scene", converged, "--duration", "0.05",
                              "--threads", "1", "--no-progress"},
                             120s);
  EXPECT_EQ(ok.exit_code, 0) << ok.err;
  EXPECT_EQ(testing::JsonString(ok.out, "status").value_or(""), "ok") << ok.out;
  EXPECT_EQ(JsonNumber(ok.out, "unconverged_steps"), 0) << ok.out;
}

// A flag that does nothing in the chosen mode is refused before anything
// runs, naming the flag and the mode (exit 2): real-time flags with
// --headless, headless flags in a real-time session, and run flags with
// --replay (which re-runs what the recording holds).
TEST(ServerHeadlessTest, FlagsThatDoNothingInTheModeAreRefused) {
  TempDir dir;
  const std::string scene = Write(dir, "beam.pbtxt", kSmallBeam);
  const std::string headless = "--headless";
  struct Case {
    std::vector<std::string> args;
    std::string flag, mode;
  };
  // --replay needs an existing file; the refusal comes before it is read,
  // so the scene stands in.
  const std::vector<Case> cases = {
      {{headless, "--scene", scene, "--duration", "0.01", "--no-rt"}, "--no-rt", "--headless"},
      {{headless, "--scene", scene, "--duration", "0.01", "--auth-window", "1"}, "--auth-window", "--headless"},
      {{headless, "--scene", scene, "--duration", "0.01", "--viewer-fps", "5"}, "--viewer-fps", "--headless"},
      {{headless, "--scene", scene, "--duration", "0.01", "--frame-rate", "50"}, "--frame-rate", "--headless"},
      {{"--scene", scene, "--duration", "0.01", "--until-rest"}, "--until-rest", "a real-time session"},
      {{"--scene", scene, "--duration", "0.01", "--no-progress"}, "--no-progress", "a real-time session"},
      {{"--scene", scene, "--duration", "0.01", "--max-time", "1"}, "--max-time", "a real-time session"},
      {{headless, "--replay", scene, "--stats-json", dir.path() + "/s.json"}, "--stats-json", "--headless --replay"},
      {{headless, "--replay", scene, "--threads", "1"}, "--threads", "--headless --replay"},
      {{headless, "--replay", scene, "--duration", "1"}, "--duration", "--headless --replay"},
      {{headless, "--replay", scene, "--out", dir.path() + "/o.vtu"}, "--out", "--headless --replay"},
      {{"--replay", scene, "--live", "--threads", "1"}, "--threads", "--replay --live"},
      {{"--replay", scene, "--live", "--record", dir.path() + "/r.lcm"}, "--record", "--replay --live"},
      {{"--replay", scene, "--live", "--session-report", dir.path() + "/r.json"}, "--session-report",
       "--replay --live"},
  };
  for (const Case& c : cases) {
    std::vector<std::string> args = {BinPath("cutsim-server")};
    args.insert(args.end(), c.args.begin(), c.args.end());
    const auto r = RunProcess(args, 30s);
    EXPECT_EQ(r.exit_code, 2) << c.flag << ": " << r.err;
    EXPECT_NE(r.err.find(c.flag + ": does nothing in " + c.mode), std::string::npos) << r.err;
    EXPECT_EQ(r.out, "") << c.flag;
  }
  // The same flags in the modes they act in are accepted.
  const auto ok = RunProcess({BinPath("cutsim-server"), headless, "--scene", scene, "--duration", "0.01",
                              "--no-progress", "--max-time", "1", "--threads", "1"},
                             60s);
  EXPECT_EQ(ok.exit_code, 0) << ok.err;
}

TEST(ServerHeadlessTest, BadSceneNamesFileAndLine) {
  TempDir dir;
  const std::string scene = Write(dir, "bad.pbtxt", std::string(kSmallBeam) + "\ngravity { z: oops }\n");
  const auto r = RunProcess({BinPath("cutsim-server"), "--headless", "--scene", scene, "--duration", "0.01"}, 60s);
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_NE(r.err.find("bad.pbtxt:8:"), std::string::npos) << r.err;
}

TEST(ServerHeadlessTest, BadFlagsAreRejected) {
  EXPECT_NE(RunProcess({BinPath("cutsim-server"), "--headless", "--scene", "/nonexistent.pbtxt", "--duration", "1"}, 30s).exit_code, 0);
  TempDir dir;
  const std::string scene = Write(dir, "beam.pbtxt", kSmallBeam);
  EXPECT_NE(RunProcess({BinPath("cutsim-server"), "--headless", "--scene", scene, "--duration", "-1"}, 30s).exit_code, 0);
  EXPECT_NE(RunProcess({BinPath("cutsim-server"), "--headless", "--scene", scene, "--precision", "half", "--duration", "1"}, 30s).exit_code, 0);
}

TEST(ServerHeadlessTest, MissingMeshFileNamesIt) {
  TempDir dir;
  const std::string scene = Write(dir, "m.pbtxt", R"pb(
mesh { file: "nothere.msh" }
materials { lame { lambda: 1 mu: 1 } density: 1 }
)pb");
  const auto r = RunProcess({BinPath("cutsim-server"), "--headless", "--scene", scene, "--duration", "0.01"}, 30s);
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_NE(r.err.find("nothere.msh"), std::string::npos) << r.err;
}

}  // namespace
}  // namespace cutsim
