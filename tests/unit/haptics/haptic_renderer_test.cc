#include "common/haptics/haptic_renderer.h"

#include <cmath>
#include <limits>
#include <numbers>

#include <gtest/gtest.h>

#include "common/core/error.h"
#include "tests/unit/haptics/test_models.h"

namespace cutsim::haptics {
namespace {

using testing::ContactModel;
using testing::kNsPerMs;

constexpr double kNotANumber = std::numeric_limits<double>::quiet_NaN();

// Drives a renderer at a fixed rate with the tool held still.
struct Loop {
  HapticRenderer& renderer;
  int64_t period_ns;
  int64_t now_ns = 0;
  Eigen::Vector3d x = Eigen::Vector3d::Zero();
  Eigen::Vector3d v = Eigen::Vector3d::Zero();

  double dt() const { return 1e-9 * static_cast<double>(period_ns); }
  Eigen::Vector3d Tick() {
    now_ns += period_ns;
    return renderer.Tick(x, v, now_ns, dt());
  }
  // Ticks until `until_ns`; returns the last force.
  Eigen::Vector3d RunUntil(int64_t until_ns) {
    Eigen::Vector3d f = renderer.last_force();
    while (now_ns < until_ns) f = Tick();
    return f;
  }
};

TEST(HapticRendererTest, RendersTheBufferModelOnceFadedIn) {
  HapticRenderer r;
  Loop loop{r, kNsPerMs};
  EXPECT_EQ(loop.Tick(), Eigen::Vector3d::Zero());  // nothing before the first model
  r.SetModel(ContactModel(1, Eigen::Vector3d::Zero(), Eigen::Vector3d(0, 0, 2.0), 1000.0), loop.now_ns);
  // Fades in over `fade` (no jump), then renders f0 − K(x − x0).
  double max_step = 0.0;
  Eigen::Vector3d previous = Eigen::Vector3d::Zero();
  for (int i = 0; i < 49; ++i) {
    const Eigen::Vector3d f = loop.Tick();
    max_step = std::max(max_step, (f - previous).norm());
    previous = f;
  }
  EXPECT_LE(max_step, 0.5 * std::numbers::pi * 2.0 / 0.05 * 1e-3 + 1e-12);
  r.SetModel(ContactModel(2, Eigen::Vector3d::Zero(), Eigen::Vector3d(0, 0, 2.0), 1000.0), loop.now_ns);
  loop.x = Eigen::Vector3d(0, 0, -1e-3);
  const Eigen::Vector3d f = loop.Tick();
  EXPECT_NEAR(f.z(), 3.0, 1e-12);
  EXPECT_EQ(r.stats().models_accepted, 2u);
}

// Runs a cut at time 0 and samples the force at the given times after the
// switch, for a loop at `rate_hz`.
std::vector<double> DecaySamples(int rate_hz, const std::vector<double>& sample_times) {
  RendererConfig config;
  config.default_decay_per_second = 40.0;
  HapticRenderer r(config);
  const int64_t period = 1'000'000'000 / rate_hz;
  Loop loop{r, period};
  uint64_t seq = 0;
  const Eigen::Vector3d f_push(0, 0, 5.0);
  // Steady contact, models at 100 Hz.
  while (loop.now_ns < 200 * kNsPerMs) {
    if (loop.now_ns % (10 * kNsPerMs) == 0) {
      r.SetModel(ContactModel(++seq, Eigen::Vector3d::Zero(), f_push), loop.now_ns);
    }
    loop.Tick();
  }
  EXPECT_NEAR(r.last_force().z(), 5.0, 1e-12);
  // The cut: counter goes up; the tool falls through (no contact afterwards).
  LocalModel cut = ContactModel(++seq, Eigen::Vector3d::Zero(), f_push);
  cut.cut.cuts = 1;
  cut.cut.cutting = true;
  r.SetModel(cut, loop.now_ns);
  std::vector<double> samples;
  size_t next = 0;
  for (int i = 0; next < sample_times.size(); ++i) {
    if (i > 0 && loop.now_ns % (10 * kNsPerMs) == 0) {
      LocalModel free;
      free.seq = ++seq;
      free.cut.cuts = 1;
      r.SetModel(free, loop.now_ns);
    }
    const Eigen::Vector3d f = loop.Tick();
    const double t = i / static_cast<double>(rate_hz);  // time since the switch
    if (std::abs(t - sample_times[next]) < 1e-12) {
      samples.push_back(f.z());
      ++next;
    }
  }
  EXPECT_EQ(r.stats().cut_decays_started, 1u);
  return samples;
}

TEST(HapticRendererTest, CutDecayIsIndependentOfLoopRate) {
  const std::vector<double> times = {0.0, 0.005, 0.010, 0.025, 0.050, 0.080};
  const std::vector<double> at_1khz = DecaySamples(1000, times);
  const std::vector<double> at_2khz = DecaySamples(2000, times);
  ASSERT_EQ(at_1khz.size(), times.size());
  ASSERT_EQ(at_2khz.size(), times.size());
  for (size_t i = 0; i < times.size(); ++i) {
    const double expected = 5.0 * std::exp(-40.0 * times[i]);  // method paper eq. (13), ξ = 40/s
    EXPECT_NEAR(at_1khz[i], expected, 1e-9) << "t = " << times[i];
    EXPECT_NEAR(at_2khz[i], expected, 1e-9) << "t = " << times[i];
  }
}

TEST(HapticRendererTest, CutDecayBlendsBackToTheBufferModelWithoutAJump) {
  RendererConfig config;
  config.default_decay_per_second = 40.0;
  HapticRenderer r(config);
  Loop loop{r, kNsPerMs};
  uint64_t seq = 0;
  auto send = [&](const Eigen::Vector3d& f0, uint64_t cuts) {
    LocalModel m = ContactModel(++seq, Eigen::Vector3d::Zero(), f0);
    m.cut.cuts = cuts;
    r.SetModel(m, loop.now_ns);
  };
  for (int frame = 0; frame < 11; ++frame) {
    send(Eigen::Vector3d(0, 0, 5.0), 0);
    loop.RunUntil((frame + 1) * 10 * kNsPerMs);
  }
  ASSERT_NEAR(r.last_force().z(), 5.0, 1e-12);

  send(Eigen::Vector3d(0, 0, 5.0), 1);  // the cut
  loop.Tick();
  EXPECT_EQ(r.phase(), RenderPhase::kCutDecay);
  // No newer model yet: the decay goes on even below the buffer force.
  loop.RunUntil(140 * kNsPerMs);
  EXPECT_EQ(r.phase(), RenderPhase::kCutDecay);
  EXPECT_LT(r.last_force().z(), 2.0);
  // The next frame's model (new surface touched, 2 N) ends the decay: the
  // decayed force (≈1.4 N) is already below it, so the force blends up to 2 N.
  double max_step = 0.0;
  Eigen::Vector3d previous = r.last_force();
  send(Eigen::Vector3d(0, 0, 2.0), 1);
  for (int i = 0; i < 40; ++i) {
    const Eigen::Vector3d f = loop.Tick();
    max_step = std::max(max_step, (f - previous).norm());
    previous = f;
    if (i == 0) {
      EXPECT_EQ(r.phase(), RenderPhase::kBlendBack);
    }
    if (i % 10 == 9) send(Eigen::Vector3d(0, 0, 2.0), 1);
  }
  EXPECT_EQ(r.phase(), RenderPhase::kBufferModel);
  EXPECT_NEAR(r.last_force().z(), 2.0, 1e-12);
  // Decay slope ξ·F ≈ 40/s · 1.6 N plus the blend weight slope (π/2)/0.02 s
  // times the ≤ 0.6 N gap, per 1 ms tick: well below the 2 N rate-limit step.
  EXPECT_LT(max_step, 0.1);
  EXPECT_EQ(r.stats().cut_decays_started, 1u);
}

TEST(HapticRendererTest, SecondCutRestartsDecayFromTheCurrentForce) {
  RendererConfig config;
  config.default_decay_per_second = 40.0;
  HapticRenderer r(config);
  Loop loop{r, kNsPerMs};
  LocalModel m = ContactModel(1, Eigen::Vector3d::Zero(), Eigen::Vector3d(0, 0, 5.0));
  r.SetModel(m, loop.now_ns);
  loop.RunUntil(40 * kNsPerMs);
  m.seq = 10;
  r.SetModel(m, loop.now_ns);
  loop.RunUntil(60 * kNsPerMs);
  ASSERT_NEAR(r.last_force().z(), 5.0, 1e-12);
  m.seq = 2 + 10;
  m.cut.cuts = 1;
  r.SetModel(m, loop.now_ns);
  loop.RunUntil(80 * kNsPerMs);  // 20 ticks of decay: F = 5 e^(−40·0.019)
  const double before = r.last_force().z();
  m.seq = 13;
  m.cut.cuts = 2;
  m.cut.decay_per_second = 100.0;  // model-supplied ξ
  r.SetModel(m, loop.now_ns);
  const double at_switch = loop.Tick().z();
  EXPECT_NEAR(at_switch, before, 1e-12);  // F_c = the force rendered at the switch
  const double later = loop.RunUntil(90 * kNsPerMs).z();
  EXPECT_NEAR(later, at_switch * std::exp(-100.0 * 9e-3), 1e-9);
  EXPECT_EQ(r.stats().cut_decays_started, 2u);
}

TEST(HapticRendererTest, FirstModelSetsTheCutBaselineWithoutDecay) {
  HapticRenderer r;
  LocalModel m = ContactModel(1, Eigen::Vector3d::Zero(), Eigen::Vector3d(0, 0, 1.0));
  m.cut.cuts = 17;  // joined a session with cuts already made
  r.SetModel(m, 0);
  r.Tick(Eigen::Vector3d::Zero(), Eigen::Vector3d::Zero(), kNsPerMs, 1e-3);
  EXPECT_EQ(r.phase(), RenderPhase::kBufferModel);
  EXPECT_EQ(r.stats().cut_decays_started, 0u);
}

TEST(WatchdogTest, FadesToZeroWithin100MsAndResumesWithoutAJump) {
  HapticRenderer r;  // watchdog 50 ms, fade 50 ms
  Loop loop{r, kNsPerMs};
  const double force = 6.0;
  uint64_t seq = 0;
  while (loop.now_ns < 200 * kNsPerMs) {
    if (loop.now_ns % (10 * kNsPerMs) == 0) {
      r.SetModel(ContactModel(++seq, Eigen::Vector3d::Zero(), Eigen::Vector3d(0, 0, force)), loop.now_ns);
    }
    loop.Tick();
  }
  ASSERT_NEAR(r.last_force().z(), force, 1e-12);
  const int64_t last_model_ns = 190 * kNsPerMs;
  // Server silent. Full force up to the watchdog, zero by 100 ms, smooth between.
  const double rate_step = r.config().device.max_force_rate * loop.dt();
  const double fade_step = 0.5 * std::numbers::pi * force / r.config().fade * loop.dt();
  double max_step = 0.0;
  Eigen::Vector3d previous = r.last_force();
  while (loop.now_ns < last_model_ns + 100 * kNsPerMs) {
    const Eigen::Vector3d f = loop.Tick();
    ASSERT_TRUE(f.allFinite());
    max_step = std::max(max_step, (f - previous).norm());
    previous = f;
    if (loop.now_ns == last_model_ns + 50 * kNsPerMs) {
      EXPECT_NEAR(f.z(), force, 1e-12);
    }
  }
  EXPECT_LT(r.last_force().norm(), 1e-9);
  EXPECT_LE(max_step, rate_step);
  EXPECT_LE(max_step, fade_step + 1e-12);
  EXPECT_EQ(r.stats().watchdog_trips, 1u);
  loop.RunUntil(400 * kNsPerMs);
  EXPECT_EQ(r.last_force(), Eigen::Vector3d::Zero());

  // Models resume with a different force: the gain ramps back up.
  max_step = 0.0;
  previous = r.last_force();
  while (loop.now_ns < 500 * kNsPerMs) {
    if (loop.now_ns % (10 * kNsPerMs) == 0) {
      r.SetModel(ContactModel(++seq, Eigen::Vector3d::Zero(), Eigen::Vector3d(0, 0, 4.0)), loop.now_ns);
    }
    const Eigen::Vector3d f = loop.Tick();
    max_step = std::max(max_step, (f - previous).norm());
    previous = f;
  }
  EXPECT_NEAR(r.last_force().z(), 4.0, 1e-12);
  EXPECT_LE(max_step, 0.5 * std::numbers::pi * 4.0 / r.config().fade * loop.dt() + 1e-12);
}

TEST(WatchdogTest, ModelReturningMidFadeReversesSmoothly) {
  HapticRenderer r;
  Loop loop{r, kNsPerMs};
  r.SetModel(ContactModel(1, Eigen::Vector3d::Zero(), Eigen::Vector3d(0, 0, 6.0)), 0);
  loop.RunUntil(49 * kNsPerMs);
  r.SetModel(ContactModel(2, Eigen::Vector3d::Zero(), Eigen::Vector3d(0, 0, 6.0)), loop.now_ns);
  loop.RunUntil(49 * kNsPerMs + 75 * kNsPerMs);  // half way through the fade
  const double mid = r.last_force().z();
  EXPECT_GT(mid, 1.0);
  EXPECT_LT(mid, 5.0);
  r.SetModel(ContactModel(3, Eigen::Vector3d::Zero(), Eigen::Vector3d(0, 0, 6.0)), loop.now_ns);
  double max_step = 0.0;
  double previous = mid;
  for (int i = 0; i < 40; ++i) {
    const double f = loop.Tick().z();
    max_step = std::max(max_step, std::abs(f - previous));
    previous = f;
  }
  EXPECT_LE(max_step, 0.5 * std::numbers::pi * 6.0 / 0.05 * 1e-3 + 1e-12);
  EXPECT_GT(previous, mid);
}

TEST(SafetyTest, GarbageModelsAreRejectedCountedAndNeverRendered) {
  HapticRenderer r;
  Loop loop{r, kNsPerMs};
  uint64_t seq = 0;
  const LocalModel good = ContactModel(++seq, Eigen::Vector3d::Zero(), Eigen::Vector3d(0, 0, 3.0), 500.0);
  r.SetModel(good, 0);
  loop.RunUntil(40 * kNsPerMs);
  LocalModel again = good;
  again.seq = ++seq;
  r.SetModel(again, loop.now_ns);
  loop.RunUntil(55 * kNsPerMs);
  ASSERT_NEAR(r.last_force().z(), 3.0, 1e-12);

  std::vector<LocalModel> garbage;
  LocalModel m = good;
  m.f0.x() = kNotANumber;
  garbage.push_back(m);
  m = good;
  m.stiffness(0, 0) = std::numeric_limits<double>::infinity();
  garbage.push_back(m);
  m = good;
  m.normal = Eigen::Vector3d(0, 0, 3);
  garbage.push_back(m);
  m = good;
  m.stiffness(0, 2) = 300.0;
  garbage.push_back(m);
  m = good;
  m.stiffness(1, 1) = -300.0;
  garbage.push_back(m);
  m = good;
  m.f0 = Eigen::Vector3d(0, 0, 1e8);
  garbage.push_back(m);
  m = good;
  m.damping = -3.0;
  garbage.push_back(m);
  for (LocalModel& g : garbage) {
    g.seq = ++seq;
    EXPECT_EQ(r.SetModel(g, loop.now_ns), ModelUpdate::kRejected);
    const Eigen::Vector3d f = loop.Tick();
    EXPECT_TRUE(f.allFinite());
    EXPECT_NEAR(f.z(), 3.0, 1e-12);  // still the last good model
  }
  const RendererStats& s = r.stats();
  EXPECT_EQ(s.models_rejected, garbage.size());
  EXPECT_EQ(s.models_accepted, 2u);
  EXPECT_EQ(s.rejected_by_issue[static_cast<size_t>(ModelIssue::kNonFinite)], 2u);
  EXPECT_EQ(s.rejected_by_issue[static_cast<size_t>(ModelIssue::kNonUnitNormal)], 1u);
  EXPECT_EQ(s.rejected_by_issue[static_cast<size_t>(ModelIssue::kAsymmetricStiffness)], 1u);
  EXPECT_EQ(s.rejected_by_issue[static_cast<size_t>(ModelIssue::kNegativeStiffness)], 1u);
  EXPECT_EQ(s.rejected_by_issue[static_cast<size_t>(ModelIssue::kAbsurdMagnitude)], 1u);
  EXPECT_EQ(s.rejected_by_issue[static_cast<size_t>(ModelIssue::kNegativeParameter)], 1u);
  // Garbage is not a heartbeat: the watchdog still fades the force out.
  loop.RunUntil(40 * kNsPerMs + 100 * kNsPerMs);
  EXPECT_EQ(r.last_force(), Eigen::Vector3d::Zero());
}

TEST(SafetyTest, NonFiniteDeviceInputNeverReachesTheOutput) {
  HapticRenderer r;
  Loop loop{r, kNsPerMs};
  r.SetModel(ContactModel(1, Eigen::Vector3d::Zero(), Eigen::Vector3d(0, 0, 3.0), 500.0), 0);
  loop.RunUntil(50 * kNsPerMs);
  const Eigen::Vector3d before = r.last_force();
  loop.x = Eigen::Vector3d(kNotANumber, 0, 0);
  const Eigen::Vector3d f = loop.Tick();
  EXPECT_TRUE(f.allFinite());
  EXPECT_LE((f - before).norm(), r.config().device.max_force_rate * 1e-3 + 1e-12);  // ramps, no step
  EXPECT_TRUE(r.Tick(Eigen::Vector3d::Zero(), Eigen::Vector3d::Zero(), loop.now_ns, kNotANumber).allFinite());
  EXPECT_EQ(r.stats().non_finite_inputs, 2u);
  loop.v = Eigen::Vector3d(0, std::numeric_limits<double>::infinity(), 0);
  EXPECT_TRUE(loop.Tick().allFinite());
  EXPECT_TRUE(std::isfinite(r.stats().observed_energy));
}

TEST(SafetyTest, OutputNeverStepsMoreThanTheRateLimit) {
  RendererConfig config;
  config.device.max_force_rate = 500.0;  // N/s: 0.5 N per 1 ms tick
  config.device.max_force = 8.0;
  HapticRenderer r(config);
  Loop loop{r, kNsPerMs};
  uint64_t seq = 0;
  testing::Lcg rng(7);
  Eigen::Vector3d previous = Eigen::Vector3d::Zero();
  for (int i = 0; i < 3000; ++i) {
    if (i % 10 == 0) {  // wildly different models every frame
      const Eigen::Vector3d f0(8 * rng.Next() - 4, 8 * rng.Next() - 4, 10 * rng.Next());
      r.SetModel(ContactModel(++seq, Eigen::Vector3d::Zero(), f0, 5000.0 * rng.Next()), loop.now_ns);
    }
    loop.x = Eigen::Vector3d(0, 0, -0.01 * rng.Next());
    const Eigen::Vector3d f = loop.Tick();
    EXPECT_LE((f - previous).norm(), 0.5 + 1e-12);
    EXPECT_LE(f.norm(), 8.0 + 1e-12);
    previous = f;
  }
  EXPECT_LE(r.stats().max_force_step, 0.5 + 1e-12);
  EXPECT_LE(r.stats().max_force, 8.0 + 1e-12);
}

TEST(SequenceTest, StaleAndOutOfOrderModelsAreIgnored) {
  HapticRenderer r;
  Loop loop{r, kNsPerMs};
  EXPECT_EQ(r.SetModel(ContactModel(5, Eigen::Vector3d::Zero(), Eigen::Vector3d(0, 0, 1.0)), 0),
            ModelUpdate::kAccepted);
  EXPECT_EQ(r.SetModel(ContactModel(3, Eigen::Vector3d::Zero(), Eigen::Vector3d(0, 0, 7.0)), 0),
            ModelUpdate::kStale);
  EXPECT_EQ(r.SetModel(ContactModel(5, Eigen::Vector3d::Zero(), Eigen::Vector3d(0, 0, 7.0)), 0),
            ModelUpdate::kStale);
  loop.RunUntil(50 * kNsPerMs);
  EXPECT_NEAR(r.last_force().z(), 1.0, 1e-12);  // seq 5 still rules
  // A stale model is no heartbeat either.
  EXPECT_EQ(r.SetModel(ContactModel(4, Eigen::Vector3d::Zero(), Eigen::Vector3d(0, 0, 7.0)), loop.now_ns),
            ModelUpdate::kStale);
  EXPECT_EQ(r.SetModel(ContactModel(6, Eigen::Vector3d::Zero(), Eigen::Vector3d(0, 0, 2.0)), loop.now_ns),
            ModelUpdate::kAccepted);
  loop.RunUntil(80 * kNsPerMs);
  EXPECT_NEAR(r.last_force().z(), 2.0, 1e-12);
  EXPECT_EQ(r.stats().models_stale, 3u);
  EXPECT_EQ(r.stats().models_accepted, 2u);
  // After Reset (server restarted) a low seq is accepted again.
  r.Reset();
  EXPECT_EQ(r.SetModel(ContactModel(1, Eigen::Vector3d::Zero(), Eigen::Vector3d(0, 0, 2.0)), loop.now_ns),
            ModelUpdate::kAccepted);
}

TEST(ConfigTest, OutOfRangeSettingsNameTheirField) {
  auto field_of = [](const RendererConfig& c) -> std::string {
    try {
      ValidateConfig(c);
    } catch (const InputError& e) {
      return e.source().field;
    }
    return "";
  };
  RendererConfig c;
  EXPECT_EQ(field_of(c), "");
  c.device.max_force = -1.0;
  EXPECT_EQ(field_of(c), "haptics.max_force");
  c = RendererConfig{};
  c.watchdog = 0.08;  // + 0.05 fade > 100 ms
  EXPECT_EQ(field_of(c), "haptics.watchdog");
  c = RendererConfig{};
  c.device.max_force_rate = 10.0;  // cannot fade 8 N in 50 ms
  EXPECT_EQ(field_of(c), "haptics.max_force_rate");
  c = RendererConfig{};
  c.decay_floor = 1.5;
  EXPECT_EQ(field_of(c), "haptics.decay_floor");
  EXPECT_THROW(HapticRenderer{c}, InputError);
}

TEST(ConfigTest, SceneParametersWithZeroMeaningDefault) {
  const RendererConfig defaults = MakeRendererConfig({});
  EXPECT_EQ(defaults.watchdog, 0.05);
  EXPECT_EQ(defaults.fade, 0.05);
  const RendererConfig c = MakeRendererConfig(
      {.decay_per_second = 80.0, .watchdog = 0.08, .max_force = 12.0, .max_stiffness = 3000.0});
  EXPECT_EQ(c.default_decay_per_second, 80.0);
  EXPECT_EQ(c.watchdog, 0.08);
  EXPECT_NEAR(c.fade, 0.02, 1e-15);  // watchdog + fade ≤ 100 ms
  EXPECT_EQ(c.device.max_force, 12.0);
  EXPECT_EQ(c.device.max_stiffness, 3000.0);
  EXPECT_GE(c.device.max_force_rate * c.fade, 0.5 * std::numbers::pi * 12.0);
  EXPECT_THROW((void)MakeRendererConfig({.watchdog = 0.2}, "scene.haptics"), InputError);
  try {
    (void)MakeRendererConfig({.max_force = -2.0}, "scene.haptics");
    FAIL();
  } catch (const InputError& e) {
    EXPECT_EQ(e.source().field, "scene.haptics.max_force");
  }
}

}  // namespace
}  // namespace cutsim::haptics
