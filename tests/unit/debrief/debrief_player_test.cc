// The debrief's player: the recording played again looks the same however a
// frame is reached (straight through, after a seek back or forward, after a
// step to a cut), bit for bit, on the ligament cut by its scripted path;
// and it plays at once, while its checkpoints are still being made.
#include "common/debrief/debrief_player.h"

#include <cmath>
#include <condition_variable>
#include <mutex>
#include <string>
#include <thread>
#include <vector>

#include <gtest/gtest.h>

#include "common/core/error.h"
#include "common/core/hash.h"
#include "common/sim/scene_loader.h"

namespace cutsim::debrief {
namespace {

const std::string kScene = std::string(CUTSIM_SOURCE_DIR) + "/scenes/ligament.pbtxt";

/// The exact state: every world position's bits, the tets and the version.
uint64_t StateHash(const sim::Simulation& s) {
  sim::MeshView view;
  s.FillMeshView(view);
  uint64_t h = Fnv1a64(view.world.data(), sizeof(double) * static_cast<size_t>(view.world.size()));
  h = Fnv1a64(view.tets.data(), sizeof(int32_t) * static_cast<size_t>(view.tets.size()), h);
  const uint64_t v = s.topology_version();
  return Fnv1a64(&v, sizeof v, h);
}

/// The ligament's recording as its scene's tool path drives it: frames of
/// the scene's frame time, no external pose (the path moves the blade).
struct Fixture {
  sim::LoadedScene scene = sim::LoadScene(kScene);
  std::vector<uint64_t> hashes;  // after each frame of the pre-pass
  DebriefPlayer player;

  explicit Fixture(double seconds, double checkpoint_every)
      : player([this] { return sim::Simulation::Create(scene); }, Frames(seconds),
               {.checkpoint_every = checkpoint_every, .timeline_samples = 100},
               [this](size_t, const sim::Simulation& s) {
                 hashes.push_back(StateHash(s));
                 return true;
               }) {
    player.WaitProduced();
  }

  std::vector<PlayerFrame> Frames(double seconds) const {
    const double dt = scene.scene.time_step().frame_dt();
    return std::vector<PlayerFrame>(static_cast<size_t>(std::lround(seconds / dt)), PlayerFrame{.frame_time = dt});
  }
  [[nodiscard]] uint64_t HashAt(size_t frame) const { return hashes.at(frame - 1); }
};

/// One pre-pass for the cases that only seek and step (each costs seconds).
Fixture& Shared() {
  static Fixture* fixture = new Fixture(3.2, 0.5);
  return *fixture;
}

TEST(DebriefPlayerTest, SeekThenPlayEqualsUninterruptedPlay) {
  Fixture& f = Shared();
  DebriefPlayer& p = f.player;
  ASSERT_EQ(p.frames(), 640u);
  EXPECT_EQ(p.checkpoints(), 7u);  // the start and every 0.5 s before the end
  EXPECT_NEAR(p.duration(), 3.2, 1e-9);
  EXPECT_FALSE(p.timeline().step_t.empty()) << "the path cuts the ligament";
  // Back, forward past a checkpoint, back again, to the very end and start.
  for (const double t : {1.37, 0.42, 2.93, 2.0, 0.0, 3.2, 1.0}) {
    const SeekReport r = p.Seek(t);
    EXPECT_NEAR(p.position(), t, 0.0051) << t;
    EXPECT_LE(r.frames_stepped, 101u) << "at most one checkpoint period (0.5 s) simulated";
    if (p.frame() > 0) {
      EXPECT_EQ(StateHash(p.simulation()), f.HashAt(p.frame())) << "after a seek to " << t << " s";
    }
    // Then play on: every frame as the uninterrupted pre-pass had it.
    for (int i = 0; i < 40 && p.StepFrame(); ++i) {
      ASSERT_EQ(StateHash(p.simulation()), f.HashAt(p.frame())) << "frame " << p.frame() << " after seek " << t;
    }
  }
}

TEST(DebriefPlayerTest, PlayAcrossTheCutAfterARestoreEqualsThePrepass) {
  // The cut step depends on state a checkpoint body leaves out (the cut
  // test's anchor, the blade's grip): restored before the cut, the replay
  // must cut on the same frame and the same way.
  Fixture& f = Shared();
  DebriefPlayer& p = f.player;
  const double cut = p.timeline().step_t.at(0);
  p.Seek(3.2);
  const SeekReport r = p.Seek(cut - 0.1);
  ASSERT_TRUE(r.restored);
  EXPECT_LT(r.restore_from, cut);
  while (p.StepFrame()) ASSERT_EQ(StateHash(p.simulation()), f.HashAt(p.frame())) << "frame " << p.frame();
}

TEST(DebriefPlayerTest, PlayFromTheStartEqualsThePrepass) {
  Fixture& f = Shared();
  DebriefPlayer& p = f.player;
  p.Seek(0.0);
  EXPECT_EQ(p.frame(), 0u);
  while (p.StepFrame()) ASSERT_EQ(StateHash(p.simulation()), f.HashAt(p.frame())) << "frame " << p.frame();
  EXPECT_TRUE(p.at_end());
}

TEST(DebriefPlayerTest, StepsGoToTheNextAndPreviousCut) {
  Fixture& f = Shared();
  DebriefPlayer& p = f.player;
  const std::vector<double> steps = p.timeline().step_t;
  ASSERT_GE(steps.size(), 1u) << "the path cuts the ligament";
  p.Seek(0.0);
  ASSERT_TRUE(p.NextStep().has_value());
  EXPECT_DOUBLE_EQ(*p.NextStep(), steps.front());
  EXPECT_FALSE(p.PreviousStep().has_value()) << "nothing cut before the start";
  const uint64_t uncut = p.simulation().topology_version();
  // Forward through every step: each shows the state just after its cut.
  for (const double t : steps) {
    const auto next = p.NextStep();
    ASSERT_TRUE(next.has_value());
    EXPECT_DOUBLE_EQ(*next, t);
    p.Seek(*next);
    EXPECT_NEAR(p.position(), t, 1e-9);
    EXPECT_EQ(StateHash(p.simulation()), f.HashAt(p.frame()));
  }
  EXPECT_GT(p.simulation().topology_version(), uncut) << "the picture shows the cut";
  EXPECT_FALSE(p.NextStep().has_value()) << "no step after the last";
  // Back from the end: the last step, then none before the first.
  p.Seek(p.duration());
  ASSERT_TRUE(p.PreviousStep().has_value());
  EXPECT_DOUBLE_EQ(*p.PreviousStep(), steps.back());
  p.Seek(steps.front());
  EXPECT_FALSE(p.PreviousStep().has_value());
  p.Seek(steps.front() + 0.1);
  ASSERT_TRUE(p.PreviousStep().has_value());
  EXPECT_DOUBLE_EQ(*p.PreviousStep(), steps.front());
}

TEST(DebriefPlayerTest, TimelineHoldsTheForcePeakAndTheScoredCut) {
  const Timeline t = Shared().player.timeline();
  ASSERT_EQ(t.force_t.size(), 100u);
  ASSERT_EQ(t.force_n.size(), 100u);
  double peak = 0.0;
  for (const double n : t.force_n) peak = std::max(peak, n);
  EXPECT_GT(peak, 0.01) << "the blade pressed on the ligament";
  EXPECT_EQ(t.cut_t.size(), t.cut_deviation.size());
  EXPECT_GT(t.tolerance, 0.0) << "the ligament has a planned incision";
}

TEST(DebriefPlayerTest, ASeekAheadOfTheProducedCheckpointsLandsOnTheRightState) {
  // The producer is held after 0.3 s of the recording (one checkpoint past
  // the start) while the player already plays and then seeks to 0.9 s,
  // beyond everything produced: it simulates there itself. Released, the
  // producer's own frame at 0.9 s must be the same state, bit for bit.
  const sim::LoadedScene scene = sim::LoadScene(kScene);
  const double dt = scene.scene.time_step().frame_dt();
  const size_t hold = static_cast<size_t>(std::lround(0.3 / dt));
  std::mutex mu;
  std::condition_variable cv;
  bool released = false;
  std::vector<uint64_t> hashes;
  DebriefPlayer p([&] { return sim::Simulation::Create(scene); },
                  std::vector<PlayerFrame>(static_cast<size_t>(std::lround(1.1 / dt)), PlayerFrame{.frame_time = dt}),
                  {.checkpoint_every = 0.25, .timeline_samples = 100}, [&](size_t i, const sim::Simulation& s) {
                    hashes.push_back(StateHash(s));
                    if (i + 1 == hold) {
                      std::unique_lock lock(mu);
                      cv.wait(lock, [&] { return released; });
                    }
                    return true;
                  });
  EXPECT_EQ(p.frame(), 0u) << "the player stands at the start at once";
  ASSERT_TRUE(p.StepFrame()) << "and plays before the checkpoints are made";
  while (p.produced() < hold) std::this_thread::yield();
  EXPECT_EQ(p.produced(), hold) << "the producer is held";
  EXPECT_EQ(p.checkpoints(), 2u) << "the start and 0.25 s";
  const SeekReport r = p.Seek(0.9);
  EXPECT_NEAR(p.position(), 0.9, 0.0051);
  EXPECT_LE(p.produced(), hold) << "the seek went beyond what was produced";
  EXPECT_TRUE(r.restored);
  EXPECT_NEAR(r.restore_from, 0.25, 0.0051) << "from the latest checkpoint produced";
  const uint64_t seen = StateHash(p.simulation());
  {
    const std::lock_guard lock(mu);
    released = true;
  }
  cv.notify_all();
  p.WaitProduced();
  ASSERT_EQ(hashes.size(), p.frames());
  EXPECT_EQ(seen, hashes.at(p.frame() - 1)) << "the state at 0.9 s as the uninterrupted producer has it";
  EXPECT_EQ(p.checkpoints(), 5u) << "the start, 0.25, 0.5, 0.75 and 1.0 s";
  // And back, behind the position: from the nearest checkpoint (0.5 s).
  const SeekReport back = p.Seek(0.6);
  EXPECT_TRUE(back.restored);
  EXPECT_NEAR(back.restore_from, 0.5, 0.0051);
  EXPECT_EQ(StateHash(p.simulation()), hashes.at(p.frame() - 1));
}

TEST(DebriefPlayerTest, RefusesAnEmptyRecordingAndABadPeriod) {
  const sim::LoadedScene scene = sim::LoadScene(kScene);
  const SimulationFactory make = [&] { return sim::Simulation::Create(scene); };
  EXPECT_THROW(DebriefPlayer(make, {}, {}), InputError);
  EXPECT_THROW(DebriefPlayer(make, {PlayerFrame{.frame_time = 0.005}}, {.checkpoint_every = 0.0}), InputError);
  EXPECT_THROW(DebriefPlayer(make, {PlayerFrame{.frame_time = 0.005}}, {.checkpoint_every = NAN}), InputError);
}

}  // namespace
}  // namespace cutsim::debrief
