// Checkpoints: a cut tissue saved and restored in a fresh Simulation is the
// same tissue (positions, topology, surface, mass), keeps evolving the same
// way, and corrupted or foreign checkpoints are refused before anything is
// applied.
#include "common/sim/checkpoint.h"

#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <iterator>
#include <string>

#include <gtest/gtest.h>

#include "common/core/error.h"
#include "common/core/hash.h"
#include "common/sim/scene_loader.h"
#include "common/sim/simulation.h"
#include "tests/support/block_scene.h"

namespace cutsim::sim {
namespace {

// The cut block (tests/support/block_scene.h), named for these tests.
std::string BlockScene(const std::string& name = "checkpoint-block", int nx = 10) {
  return support::BlockScene(name, nx);
}

std::unique_ptr<Simulation> Make(const std::string& text) {
  return Simulation::Create(ParseScene(text, "checkpoint-test.pbtxt", std::filesystem::temp_directory_path()));
}

class CheckpointTest : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = std::filesystem::temp_directory_path() /
           ("cutsim-checkpoint-test-" + std::to_string(::getpid()) + "-" +
            ::testing::UnitTest::GetInstance()->current_test_info()->name());
    std::filesystem::create_directories(dir_);
  }
  void TearDown() override { std::filesystem::remove_all(dir_); }

  /// A simulation that has made at least two cut steps, computed once for
  /// the suite (the slow part) and never advanced by a test.
  static void SetUpTestSuite() {
    cut_sim_ = Make(BlockScene());
    while (cut_sim_->QuickSummary().cuts < 2 && cut_sim_->sim_time() < 0.8) {
      ASSERT_EQ(cut_sim_->AdvanceFrame(), SimStatus::kOk);
    }
  }
  static void TearDownTestSuite() { cut_sim_.reset(); }
  static const Simulation& CutSim() { return *cut_sim_; }

  static inline std::unique_ptr<Simulation> cut_sim_;
  std::filesystem::path dir_;
};

void ExpectSameTissue(const Simulation& a, const Simulation& b) {
  MeshView va, vb;
  a.FillMeshView(va);
  b.FillMeshView(vb);
  ASSERT_EQ(va.world.rows(), vb.world.rows());
  EXPECT_TRUE(va.world == vb.world) << "world positions differ";
  EXPECT_TRUE(va.rest == vb.rest) << "rest positions differ";
  EXPECT_TRUE(va.tets == vb.tets) << "tets differ";
  ASSERT_EQ(va.surface.rows(), vb.surface.rows());
  EXPECT_TRUE(va.surface == vb.surface) << "surface differs";
  EXPECT_EQ(va.opened, vb.opened);
  const SimulationSummary sa = a.Summary(), sb = b.Summary();
  EXPECT_EQ(a.topology_version(), b.topology_version());
  EXPECT_EQ(sa.total_mass, sb.total_mass);
  EXPECT_EQ(sa.cuts, sb.cuts);
  EXPECT_EQ(sa.sim_time, sb.sim_time);
  EXPECT_EQ(sa.components, sb.components);
  EXPECT_EQ(sa.opened_faces, sb.opened_faces);
  EXPECT_EQ(sa.kinetic_energy, sb.kinetic_energy);
}

TEST_F(CheckpointTest, RoundTripRestoresTheCutTissueAndItsFuture) {
  const Simulation& original = CutSim();
  ASSERT_GE(original.Summary().cuts, 2u) << "the scalpel should have cut by now";
  ASSERT_GT(original.topology_version(), 0u);
  const auto file = dir_ / "block.ckpt";
  SaveCheckpoint(original, file);
  EXPECT_FALSE(std::filesystem::exists(file.string() + ".tmp"));

  auto restored = Make(BlockScene());
  ASSERT_EQ(restored->topology_version(), 0u);
  RestoreCheckpoint(*restored, file);
  ExpectSameTissue(original, *restored);
  EXPECT_GT(restored->Summary().opened_faces, 0);
  // The session's measures carry on from where they were.
  const SessionMetrics& m0 = original.Metrics();
  const SessionMetrics& m1 = restored->Metrics();
  EXPECT_GT(m0.path_length(), 0.0);
  EXPECT_GT(m0.opened_area(), 0.0);
  EXPECT_EQ(m1.path_length(), m0.path_length());
  EXPECT_EQ(m1.peak_force(), m0.peak_force());
  EXPECT_EQ(m1.contact_time(), m0.contact_time());
  EXPECT_EQ(m1.opened_area(), m0.opened_area());
  EXPECT_EQ(m1.max_stress_outside(), m0.max_stress_outside());
  EXPECT_EQ(m1.stress_samples(), m0.stress_samples());

  // The restored tissue goes on (the tool keeps cutting); that it goes on
  // exactly as the original does is ResumedMidCutContinuesExactly...'s.
  const uint64_t version = restored->topology_version();
  for (int i = 0; i < 30; ++i) ASSERT_EQ(restored->AdvanceFrame(), SimStatus::kOk);
  EXPECT_GE(restored->topology_version(), version);
  EXPECT_GE(restored->QuickSummary().cuts, original.QuickSummary().cuts);
  EXPECT_GT(restored->Metrics().path_length(), m0.path_length());
  EXPECT_GE(restored->Metrics().max_stress_outside(), m0.max_stress_outside());

  // A checkpoint of the restored simulation carries every event again.
  SaveCheckpoint(*restored, dir_ / "again.ckpt");
  const v1::CheckpointBody a = ReadCheckpointFile(dir_ / "again.ckpt");
  EXPECT_GE(a.events_size(), original.CheckpointState().events_size());
}

/// FNV-1a 64 of the observable mesh: world and rest positions, tets,
/// surface and opened flags, bit for bit.
uint64_t ViewHash(const Simulation& sim) {
  MeshView v;
  sim.FillMeshView(v);
  uint64_t h = Fnv1a64(v.world.data(), static_cast<size_t>(v.world.size()) * sizeof(v.world(0, 0)));
  h = Fnv1a64(v.rest.data(), static_cast<size_t>(v.rest.size()) * sizeof(v.rest(0, 0)), h);
  h = Fnv1a64(v.tets.data(), static_cast<size_t>(v.tets.size()) * sizeof(v.tets(0, 0)), h);
  h = Fnv1a64(v.surface.data(), static_cast<size_t>(v.surface.size()) * sizeof(v.surface(0, 0)), h);
  return Fnv1a64(v.opened.data(), v.opened.size() * sizeof(v.opened[0]), h);
}

// A server stopped mid-cut (the blade in the tissue, gripping it, its cut
// tracker anchored) and resumed from its checkpoint file continues exactly
// as the one that was not stopped: every stage's state is in the file.
TEST_F(CheckpointTest, ResumedMidCutContinuesExactlyAsTheUnstoppedRun) {
  auto unstopped = Make(BlockScene());
  while (unstopped->QuickSummary().cuts < 2 && unstopped->sim_time() < 0.8) {
    ASSERT_EQ(unstopped->AdvanceFrame(), SimStatus::kOk);
  }
  // Two frames past a cut step: the blade is inside its own cut.
  for (int i = 0; i < 2; ++i) ASSERT_EQ(unstopped->AdvanceFrame(), SimStatus::kOk);
  ASSERT_GE(unstopped->QuickSummary().cuts, 2u);
  ASSERT_TRUE(unstopped->Tool().touching) << "the blade should be in the tissue";
  const auto file = dir_ / "mid-cut.ckpt";
  SaveCheckpoint(*unstopped, file);

  auto resumed = Make(BlockScene());
  RestoreCheckpoint(*resumed, file);
  ASSERT_EQ(ViewHash(*resumed), ViewHash(*unstopped));
  const uint64_t cuts_at_stop = unstopped->QuickSummary().cuts;
  for (int frame = 1; frame <= 30; ++frame) {
    ASSERT_EQ(unstopped->AdvanceFrame(), SimStatus::kOk);
    ASSERT_EQ(resumed->AdvanceFrame(), SimStatus::kOk);
    ASSERT_EQ(ViewHash(*resumed), ViewHash(*unstopped)) << "the runs part at frame " << frame << " after the stop";
    ASSERT_EQ(resumed->QuickSummary().cuts, unstopped->QuickSummary().cuts) << "frame " << frame;
    ASSERT_EQ(resumed->Tool().force_on_tool, unstopped->Tool().force_on_tool) << "frame " << frame;
  }
  EXPECT_GT(unstopped->QuickSummary().cuts, cuts_at_stop) << "the comparison should span further cut steps";
  EXPECT_EQ(resumed->Metrics().path_length(), unstopped->Metrics().path_length());
}

TEST_F(CheckpointTest, UncutSceneRoundTrips) {
  auto sim = Make(BlockScene());
  for (int i = 0; i < 3; ++i) ASSERT_EQ(sim->AdvanceFrame(), SimStatus::kOk);
  SaveCheckpoint(*sim, dir_ / "uncut.ckpt");
  auto restored = Make(BlockScene());
  RestoreCheckpoint(*restored, dir_ / "uncut.ckpt");
  ExpectSameTissue(*sim, *restored);
}

/// The error of `fn`, or "" if it did not throw InputError.
template <typename Fn>
InputError ErrorOf(Fn fn) {
  try {
    fn();
  } catch (const InputError& e) {
    return e;
  }
  ADD_FAILURE() << "no InputError";
  return InputError({}, "none");
}

TEST_F(CheckpointTest, CorruptedFilesAreRefusedNamingFileAndField) {
  const Simulation& original = CutSim();
  const auto good = dir_ / "good.ckpt";
  SaveCheckpoint(original, good);
  std::ifstream in(good, std::ios::binary);
  const std::string bytes((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  ASSERT_GT(bytes.size(), 100u);

  auto fresh = Make(BlockScene());
  const auto flipped = dir_ / "flipped.ckpt";
  std::string f = bytes;
  f[f.size() / 2] = static_cast<char>(f[f.size() / 2] ^ 0x10);
  std::ofstream(flipped, std::ios::binary) << f;
  InputError e = ErrorOf([&] { RestoreCheckpoint(*fresh, flipped); });
  EXPECT_EQ(e.source().file, flipped.string());
  EXPECT_EQ(e.source().field, "body_fnv1a64") << e.what();

  const auto truncated = dir_ / "truncated.ckpt";
  std::ofstream(truncated, std::ios::binary) << bytes.substr(0, bytes.size() - 40);
  e = ErrorOf([&] { RestoreCheckpoint(*fresh, truncated); });
  EXPECT_EQ(e.source().file, truncated.string());
  EXPECT_NE(std::string(e.what()).find("truncated.ckpt"), std::string::npos) << e.what();

  const auto text = dir_ / "text.ckpt";
  std::ofstream(text) << "name: \"not a checkpoint\"\n";
  e = ErrorOf([&] { RestoreCheckpoint(*fresh, text); });
  EXPECT_EQ(e.source().file, text.string());

  EXPECT_EQ(fresh->topology_version(), 0u) << "nothing applied";
  EXPECT_EQ(fresh->sim_time(), 0.0);
  RestoreCheckpoint(*fresh, good);  // still usable
  ExpectSameTissue(original, *fresh);
}

TEST_F(CheckpointTest, BadEventsAreRefusedBeforeAnythingIsApplied) {
  const Simulation& original = CutSim();
  v1::CheckpointBody body = original.CheckpointState();
  ASSERT_GE(body.events_size(), 2);
  // The last event retargets a tet that does not use the split node: the
  // earlier, valid events must not be applied either.
  v1::CheckpointBody bad = body;
  auto* last = bad.mutable_events(bad.events_size() - 1);
  bool tampered = false;
  for (auto& split : *last->mutable_splits()) {
    if (split.tets_size() > 0) {
      split.set_tets(0, bad.initial_tets() + 5);
      tampered = true;
      break;
    }
  }
  ASSERT_TRUE(tampered);
  WriteCheckpointFile(dir_ / "bad-event.ckpt", bad);
  auto fresh = Make(BlockScene());
  InputError e = ErrorOf([&] { RestoreCheckpoint(*fresh, dir_ / "bad-event.ckpt"); });
  EXPECT_EQ(e.source().file, (dir_ / "bad-event.ckpt").string());
  EXPECT_EQ(e.source().field.rfind("events[" + std::to_string(bad.events_size() - 1) + "].", 0), 0u)
      << e.source().field;
  EXPECT_EQ(fresh->topology_version(), 0u);
  EXPECT_EQ(fresh->Summary().opened_faces, 0);

  v1::CheckpointBody short_state = body;
  short_state.mutable_positions()->RemoveLast();
  WriteCheckpointFile(dir_ / "short.ckpt", short_state);
  e = ErrorOf([&] { RestoreCheckpoint(*fresh, dir_ / "short.ckpt"); });
  EXPECT_EQ(e.source().field, "positions") << e.what();
  EXPECT_EQ(fresh->topology_version(), 0u);
  RestoreCheckpoint(*fresh, [&] {
    WriteCheckpointFile(dir_ / "ok.ckpt", body);
    return dir_ / "ok.ckpt";
  }());
  ExpectSameTissue(original, *fresh);
}

TEST_F(CheckpointTest, BadStagePartsAndOldVersionsAreRefusedNamingTheField) {
  const v1::CheckpointBody body = CutSim().CheckpointState();
  ASSERT_TRUE(body.has_tool() && body.has_cut_attempt() && body.has_fem_step());
  auto fresh = Make(BlockScene());
  v1::CheckpointBody bad = body;
  bad.mutable_tool()->set_grip_nodes(0, bad.initial_nodes() * 100);
  WriteCheckpointFile(dir_ / "bad-grip.ckpt", bad);
  InputError e = ErrorOf([&] { RestoreCheckpoint(*fresh, dir_ / "bad-grip.ckpt"); });
  EXPECT_EQ(e.source().field, "tool.grip_nodes[0]") << e.what();
  EXPECT_EQ(fresh->topology_version(), 0u) << "nothing applied";

  bad = body;
  bad.clear_cut_attempt();
  WriteCheckpointFile(dir_ / "no-anchor.ckpt", bad);
  e = ErrorOf([&] { RestoreCheckpoint(*fresh, dir_ / "no-anchor.ckpt"); });
  EXPECT_EQ(e.source().field, "cut_attempt") << e.what();

  bad = body;
  bad.mutable_fem_step()->mutable_element_dt()->RemoveLast();
  WriteCheckpointFile(dir_ / "short-dt.ckpt", bad);
  e = ErrorOf([&] { RestoreCheckpoint(*fresh, dir_ / "short-dt.ckpt"); });
  EXPECT_EQ(e.source().field, "fem_step.element_dt") << e.what();
  EXPECT_EQ(fresh->topology_version(), 0u);
  EXPECT_EQ(fresh->sim_time(), 0.0);

  // A file of format version 1 (before the stages' parts) is refused with
  // both versions named.
  v1::CheckpointFile old;
  old.set_magic("cutsim-checkpoint");
  old.set_format_version(1);
  ASSERT_TRUE(body.SerializeToString(old.mutable_body()));
  old.set_body_fnv1a64(Fnv1a64(old.body().data(), old.body().size()));
  const auto old_path = dir_ / "v1.ckpt";
  std::ofstream(old_path, std::ios::binary) << old.SerializeAsString();
  e = ErrorOf([&] { RestoreCheckpoint(*fresh, old_path); });
  EXPECT_EQ(e.source().file, old_path.string());
  EXPECT_EQ(e.source().field, "format_version") << e.what();
  EXPECT_NE(std::string(e.what()).find("version 1"), std::string::npos) << e.what();
  EXPECT_NE(std::string(e.what()).find("version 2"), std::string::npos) << e.what();
}

TEST_F(CheckpointTest, HugeVersionsAndTimesAreRefusedWithoutReplayingThem) {
  const v1::CheckpointBody body = CutSim().CheckpointState();
  ASSERT_GE(body.events_size(), 1);
  // A valid checksum over an event version of 2^62: the empty versions in
  // between would be replayed one by one for ever.
  v1::CheckpointBody bad = body;
  bad.mutable_events(bad.events_size() - 1)->set_version(uint64_t{1} << 62);
  bad.set_topology_version(uint64_t{1} << 62);
  WriteCheckpointFile(dir_ / "huge-version.ckpt", bad);
  auto fresh = Make(BlockScene());
  InputError e = ErrorOf([&] { RestoreCheckpoint(*fresh, dir_ / "huge-version.ckpt"); });
  EXPECT_NE(e.source().field.find(".version"), std::string::npos) << e.what();
  EXPECT_NE(std::string(e.what()).find("limit"), std::string::npos) << e.what();
  bad = body;
  bad.set_sim_time(1e300);
  WriteCheckpointFile(dir_ / "huge-time.ckpt", bad);
  e = ErrorOf([&] { RestoreCheckpoint(*fresh, dir_ / "huge-time.ckpt"); });
  EXPECT_EQ(e.source().field, "sim_time") << e.what();
  e = ErrorOf([&] { RestoreCheckpoint(*fresh, "/dev/zero"); });
  EXPECT_NE(std::string(e.what()).find("only regular files"), std::string::npos) << e.what();
  EXPECT_EQ(fresh->topology_version(), 0u);
}

TEST_F(CheckpointTest, ForeignScenesAreRefused) {
  const Simulation& original = CutSim();
  const auto file = dir_ / "block.ckpt";
  SaveCheckpoint(original, file);

  auto renamed = Make(BlockScene("another-scene"));
  InputError e = ErrorOf([&] { RestoreCheckpoint(*renamed, file); });
  EXPECT_EQ(e.source().field, "scene_name") << e.what();
  EXPECT_NE(std::string(e.what()).find("checkpoint-block"), std::string::npos) << e.what();

  auto other_mesh = Make(BlockScene("checkpoint-block", 9));
  e = ErrorOf([&] { RestoreCheckpoint(*other_mesh, file); });
  EXPECT_EQ(e.source().field, "scene_fingerprint") << e.what();
  EXPECT_EQ(other_mesh->topology_version(), 0u);
}

}  // namespace
}  // namespace cutsim::sim
