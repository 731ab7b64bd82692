// The browser device: strict validation of the page's messages, the mapping
// of normalised samples to the workspace box, the interpolation the 1 kHz
// loop reads, the page token, and the device behind its real server on
// loopback (token, Origin, one trainee, size and rate caps) while a valid
// trainee's samples reach Read and the force frames reach the page.
#include <gtest/gtest.h>
#include <unistd.h>

#include <chrono>
#include <filesystem>
#include <fstream>
#include <cmath>
#include <string>
#include <thread>

#include <fmt/format.h>

#include "common/core/clock.h"
#include "common/transport/tool_auth.h"
#include "common/web/trainee_server.h"
#include "haptic_client/browser_device.h"
#include "tests/support/web_client.h"

namespace cutsim::haptic_client {
namespace {

using test::WebSocketClient;
using namespace std::chrono_literals;

DeviceInfo Box() {
  DeviceInfo info;
  info.workspace_min = {-0.01, -0.02, -0.03};
  info.workspace_max = {0.03, 0.02, 0.01};
  return info;
}

SampleError Parse(const std::string& text, double previous_ms = -1.0, BrowserSample* out = nullptr) {
  BrowserSample s;
  return ParseBrowserSample(text, Box(), previous_ms, out != nullptr ? out : &s);
}

TEST(BrowserSampleTest, MapsTheUnitCubeOntoTheWorkspaceBox) {
  BrowserSample s;
  ASSERT_EQ(Parse("p 12.5 0 0 0 0 0 1 0", -1.0, &s), SampleError::kNone);
  EXPECT_TRUE(s.pose.tip.isApprox(Box().workspace_min));
  ASSERT_EQ(Parse("p 13 1 1 1 0 0 1 3", -1.0, &s), SampleError::kNone);
  EXPECT_TRUE(s.pose.tip.isApprox(Box().workspace_max));
  EXPECT_EQ(s.buttons, 3U);
  ASSERT_EQ(Parse("p 14 0.25 0.5 0.75 0 1.05 0 1", -1.0, &s), SampleError::kNone);
  EXPECT_NEAR(s.pose.tip.x(), 0.0, 1e-12);
  EXPECT_NEAR(s.pose.tip.y(), 0.0, 1e-12);
  EXPECT_NEAR(s.pose.tip.z(), 0.0, 1e-12);
  EXPECT_NEAR(s.pose.blade_dir.norm(), 1.0, 1e-12);  // renormalised
  EXPECT_DOUBLE_EQ(s.page_ms, 14.0);
}

TEST(BrowserSampleTest, RefusesEveryMalformedMessageByReason) {
  EXPECT_EQ(Parse(""), SampleError::kFormat);
  EXPECT_EQ(Parse("q 1 0 0 0 0 0 1 0"), SampleError::kFormat);
  EXPECT_EQ(Parse("p 1 0 0 0 0 0 1"), SampleError::kFormat);       // a field short
  EXPECT_EQ(Parse("p 1 0 0 0 0 0 1 0 7"), SampleError::kFormat);   // one too many
  EXPECT_EQ(Parse("p 1 0 0 0x1 0 0 1 0"), SampleError::kFormat);   // not a whole number
  EXPECT_EQ(Parse("p 1 0 0 0 0 0 1 0\n"), SampleError::kFormat);
  EXPECT_EQ(Parse("{\"x\":1}"), SampleError::kFormat);
  EXPECT_EQ(Parse("p nan 0 0 0 0 0 1 0"), SampleError::kNotFinite);
  EXPECT_EQ(Parse("p 1 inf 0 0 0 0 1 0"), SampleError::kNotFinite);
  EXPECT_EQ(Parse("p 1 0 0 0 0 0 -inf 0"), SampleError::kNotFinite);
  EXPECT_EQ(Parse("p 1 1.0001 0 0 0 0 1 0"), SampleError::kRange);
  EXPECT_EQ(Parse("p 1 0 -0.1 0 0 0 1 0"), SampleError::kRange);
  EXPECT_EQ(Parse("p -1 0 0 0 0 0 1 0"), SampleError::kRange);
  EXPECT_EQ(Parse("p 1 0 0 0 0 0 0 0"), SampleError::kDirection);
  EXPECT_EQ(Parse("p 1 0 0 0 0 0 1.2 0"), SampleError::kDirection);
  EXPECT_EQ(Parse("p 1 0 0 0 0 0 1 4"), SampleError::kButtons);
  EXPECT_EQ(Parse("p 1 0 0 0 0 0 1 0.5"), SampleError::kButtons);
  EXPECT_EQ(Parse("p 1 0 0 0 0 0 1 0", 2.0), SampleError::kTimeBackwards);
  EXPECT_EQ(Parse("p 2 0 0 0 0 0 1 0", 2.0), SampleError::kNone);  // equal times are fine
}

SamplePair TwoSamples() {
  SamplePair p;
  p.older.page_ms = 100.0;
  p.older.pose.tip = {0.0, 0.0, 0.0};
  p.older.pose.blade_dir = {0.0, 0.0, 1.0};
  p.older.buttons = 0;
  p.newer.page_ms = 110.0;
  p.newer.pose.tip = {0.01, 0.0, -0.002};
  p.newer.pose.blade_dir = {1.0, 0.0, 0.0};
  p.newer.buttons = 1;
  p.count = 2;
  p.offset_ns = 5'000'000;  // monotonic = page + 5 ms
  p.delay_ns = 10'000'000;
  return p;
}

TEST(BrowserInterpolationTest, RendersOneInputPeriodBehindBetweenTheTwoNewestSamples) {
  const SamplePair p = TwoSamples();
  DeviceState s;
  double used = -1.0;
  // Render time = now − delay − offset (page ms). Halfway: page 105 ms.
  InterpolatePose(p, 120'000'000, &s, &used);
  EXPECT_NEAR(s.pose.tip.x(), 0.005, 1e-12);
  EXPECT_NEAR(s.pose.tip.z(), -0.001, 1e-12);
  EXPECT_NEAR(s.pose.blade_dir.norm(), 1.0, 1e-12);
  EXPECT_NEAR(s.pose.blade_dir.x(), std::sqrt(0.5), 1e-12);
  EXPECT_NEAR(s.velocity.x(), 1.0, 1e-9);  // 10 mm in 10 ms
  EXPECT_EQ(s.buttons, 0U);                // the newer sample's buttons are not due yet
  EXPECT_DOUBLE_EQ(used, 110.0);
  // Before the older sample: hold it (the newer one has no weight yet).
  InterpolatePose(p, 110'000'000, &s, &used);
  EXPECT_TRUE(s.pose.tip.isApprox(p.older.pose.tip));
  EXPECT_DOUBLE_EQ(used, 100.0);
  EXPECT_TRUE(s.velocity.isZero());
  // Past the newer sample: hold it, at rest, with its buttons.
  InterpolatePose(p, 200'000'000, &s, &used);
  EXPECT_TRUE(s.pose.tip.isApprox(p.newer.pose.tip));
  EXPECT_TRUE(s.velocity.isZero());
  EXPECT_EQ(s.buttons, 1U);
}

TEST(BrowserInterpolationTest, IsContinuousAndMonotoneAcrossThePeriod) {
  const SamplePair p = TwoSamples();
  DeviceState s;
  double used = 0.0;
  double last_x = -1.0;
  for (int64_t now = 110'000'000; now <= 130'000'000; now += 250'000) {
    InterpolatePose(p, now, &s, &used);
    EXPECT_GE(s.pose.tip.x(), last_x);
    if (last_x >= 0.0) {
      EXPECT_LE(s.pose.tip.x() - last_x, 0.01 * 0.25 / 10.0 + 1e-12);
    }
    last_x = s.pose.tip.x();
  }
  EXPECT_NEAR(last_x, 0.01, 1e-12);
}

TEST(TraineeTokenTest, IsAKeyedDigestThatHidesTheKey) {
  const transport::SessionKey a = transport::ParseSessionKey("00112233445566778899aabbccddeeff", "test");
  const transport::SessionKey b = transport::ParseSessionKey("00112233445566778899aabbccddeefe", "test");
  const std::string ta = TraineeToken(a);
  EXPECT_EQ(ta.size(), 64U);
  EXPECT_EQ(ta, TraineeToken(a));
  EXPECT_NE(ta, TraineeToken(b));
  EXPECT_EQ(ta.find("00112233445566778899aabbccddeeff"), std::string::npos);
}

// ---------------------------------------------------------------------------
// The device behind its server.

class BrowserDeviceServerTest : public ::testing::Test {
 protected:
  BrowserDeviceServerTest() {
    // three.js stand-ins: the page's own files come from the source tree.
    for (const char* f : {"build/three.module.js", "build/three.core.js", "examples/jsm/controls/OrbitControls.js"}) {
      std::filesystem::create_directories((three_ / f).parent_path());
      std::ofstream(three_ / f) << "// stand-in\n";
    }
    BrowserDeviceOptions o;
    o.token = "abc123";
    o.page_dir = CUTSIM_SOURCE_DIR "/web/trainee";
    o.three_dir = three_.string();
    device_ = std::make_unique<BrowserDevice>(o, BrowserDevice::DefaultInfo());
  }
  ~BrowserDeviceServerTest() override {
    device_.reset();
    std::filesystem::remove_all(three_);
  }

  /// Opens a WebSocket; false when the upgrade is refused.
  bool Open(WebSocketClient* ws, const std::string& token, const std::string& origin) {
    return ws->Open(device_->server().port(), "/ws?token=" + token, origin);
  }

  std::string Own() const { return "http://127.0.0.1:" + std::to_string(device_->server().port()); }

  DeviceState ReadAt(int64_t now_ns) {
    DeviceState s;
    device_->Read(now_ns, &s);
    return s;
  }

  std::filesystem::path three_ =
      std::filesystem::temp_directory_path() / ("cutsim_three_stub_" + std::to_string(::getpid()));
  std::unique_ptr<BrowserDevice> device_;
};

template <typename Pred>
bool WaitFor(Pred pred) {
  for (int i = 0; i < 300; ++i) {
    if (pred()) return true;
    std::this_thread::sleep_for(10ms);
  }
  return pred();
}

TEST_F(BrowserDeviceServerTest, ATraineeDrivesTheToolAndReceivesTheForce) {
  // Before any page: the tip waits above the workspace's middle.
  const DeviceInfo& info = device_->info();
  EXPECT_NEAR(ReadAt(MonotonicNs()).pose.tip.z(), info.workspace_max.z(), 1e-12);

  WebSocketClient ws;
  ASSERT_TRUE(Open(&ws, "abc123", Own()));
  const auto hello = ws.ReadData();
  ASSERT_TRUE(hello);
  EXPECT_NE(hello->find("\"hello\""), std::string::npos);

  ASSERT_TRUE(ws.Write("p 1000 0.5 0.5 0.25 0 0 1 1"));
  ASSERT_TRUE(ws.Write("p 1010 0.5 0.75 0.25 0 0 1 1"));
  ASSERT_TRUE(ws.Write("p 1020 nan 0.75 0.25 0 0 1 1"));  // refused, harmless
  ASSERT_TRUE(WaitFor([&] { return device_->stats().samples == 2 && device_->stats().refused_total() == 1; }));
  const DeviceState s = ReadAt(MonotonicNs() + 1'000'000'000);  // long after: the newest sample
  EXPECT_NEAR(s.pose.tip.y(), info.workspace_min.y() + 0.75 * (info.workspace_max.y() - info.workspace_min.y()),
              1e-9);
  EXPECT_NEAR(s.pose.tip.z(), info.workspace_min.z() + 0.25 * (info.workspace_max.z() - info.workspace_min.z()),
              1e-9);
  EXPECT_EQ(s.buttons, 1U);
  EXPECT_EQ(device_->stats().refused[static_cast<size_t>(SampleError::kNotFinite)], 1U);

  device_->SetForce(Eigen::Vector3d(0.0, 0.0, 2.5));
  device_->ShowModel(7, true);
  device_->SetForce(Eigen::Vector3d(0.0, 0.0, 2.5));
  bool seen = false;
  for (int i = 0; i < 20 && !seen; ++i) {
    const auto read = ws.ReadData();
    ASSERT_TRUE(read);
    const std::string& frame = *read;
    seen = frame.find("\"force\":[0.00000,0.00000,2.50000]") != std::string::npos &&
           frame.find("\"cuts\":7") != std::string::npos && frame.find("\"used_ms\":1010.000") != std::string::npos;
  }
  EXPECT_TRUE(seen);

  // A second trainee is refused while the first holds the tool.
  WebSocketClient second;
  EXPECT_FALSE(Open(&second, "abc123", Own()));
  EXPECT_EQ(device_->server().stats().web.refused_cap, 1U);

  // The page leaves: cutting stops, the tool holds its place.
  ASSERT_TRUE(ws.Close());
  ASSERT_TRUE(WaitFor([&] { return !device_->server().stats().connected; }));
  const DeviceState after = ReadAt(MonotonicNs() + 2'000'000'000);
  EXPECT_EQ(after.buttons, 0U);
  EXPECT_NEAR(after.pose.tip.y(), s.pose.tip.y(), 1e-12);
}

TEST_F(BrowserDeviceServerTest, RefusesAWrongTokenAForeignOriginAndOversizedMessages) {
  WebSocketClient bad_token;
  EXPECT_FALSE(Open(&bad_token, "abc124", Own()));
  WebSocketClient no_token;
  EXPECT_FALSE(Open(&no_token, "", ""));
  WebSocketClient foreign;
  EXPECT_FALSE(Open(&foreign, "abc123", "http://evil.example"));
  const web::TraineeServerStats st = device_->server().stats();
  EXPECT_EQ(st.web.refused_token, 2U);
  EXPECT_EQ(st.web.refused_origin, 1U);
  EXPECT_EQ(st.accepted, 0U);

  WebSocketClient ws;
  ASSERT_TRUE(Open(&ws, "abc123", ""));
  ASSERT_TRUE(ws.Write(std::string(4096, 'p')));
  bool closed = false;
  for (int i = 0; i < 100 && !closed; ++i) closed = !ws.Read();
  EXPECT_TRUE(closed);
  ASSERT_TRUE(WaitFor([&] { return device_->server().stats().closed_oversized == 1; }));
  EXPECT_EQ(device_->stats().samples, 0U);
  // The slot is free again for the next trainee.
  ASSERT_TRUE(WaitFor([&] { return !device_->server().stats().connected; }));
  WebSocketClient again;
  EXPECT_TRUE(Open(&again, "abc123", Own()));
}

TEST_F(BrowserDeviceServerTest, DropsMessagesAboveTheRateCap) {
  WebSocketClient ws;
  ASSERT_TRUE(Open(&ws, "abc123", Own()));
  // Far more than the burst, as fast as a socket takes them, their times
  // 10 µs apart (all within the stream clock's window however slowly they
  // arrive).
  for (int i = 0; i < 2000; ++i) {
    ASSERT_TRUE(ws.Write("p " + std::to_string(1000.0 + 0.01 * i) + " 0.5 0.5 0.5 0 0 1 0"));
  }
  ASSERT_TRUE(WaitFor([&] {
    const auto st = device_->server().stats();
    return st.messages_received + st.rate_limited == 2000;
  }));
  const auto st = device_->server().stats();
  EXPECT_GT(st.rate_limited, 0U);
  EXPECT_LT(st.messages_received, 2000U);
  EXPECT_EQ(device_->stats().samples, st.messages_received);
}

// A sample's time must lie near the stream's clock: one wild time is
// refused and the tool keeps following the page.
TEST_F(BrowserDeviceServerTest, AWildSampleTimeIsRefusedAndTheToolFollowsOn) {
  const int64_t r0 = MonotonicNs();
  device_->OnMessage("p 1000 0.5 0.5 0.5 0 0 1 1", r0);
  device_->OnMessage("p 1010 0.5 0.5 0.5 0 0 1 1", r0 + 10'000'000);
  device_->OnMessage("p 1e12 0.9 0.5 0.5 0 0 1 1", r0 + 20'000'000);
  device_->OnMessage("p 1030 0.1 0.5 0.5 0 0 1 1", r0 + 30'000'000);
  EXPECT_EQ(device_->stats().refused[static_cast<size_t>(SampleError::kClock)], 1U);
  EXPECT_EQ(device_->stats().samples, 3U);
  const DeviceInfo& info = device_->info();
  const double x = info.workspace_min.x() + 0.1 * (info.workspace_max.x() - info.workspace_min.x());
  EXPECT_NEAR(ReadAt(r0 + 1'000'000'000).pose.tip.x(), x, 1e-9);
  // A time far in the past of the stream's clock is refused too.
  device_->OnMessage("p 1040 0.9 0.5 0.5 0 0 1 1", r0 + 5'000'000'000);
  EXPECT_EQ(device_->stats().refused[static_cast<size_t>(SampleError::kClock)], 2U);
  EXPECT_NEAR(ReadAt(r0 + 6'000'000'000).pose.tip.x(), x, 1e-9);
}

// A wild first sample cannot hold the tool either: once every sample has
// been refused for its time for kReanchorMs, the stream's clock restarts.
TEST_F(BrowserDeviceServerTest, AWildFirstSampleTimeIsOutlivedByTheClockRestart) {
  const int64_t r0 = MonotonicNs();
  device_->OnMessage("p 1e12 0.9 0.5 0.5 0 0 1 1", r0);
  for (int ms = 0; ms <= 1500; ms += 10) {
    device_->OnMessage(fmt::format("p {} 0.2 0.5 0.5 0 0 1 0", 50 + ms), r0 + int64_t{ms} * 1'000'000 + 1'000'000);
  }
  EXPECT_EQ(device_->stats().reanchors, 1U);
  const DeviceInfo& info = device_->info();
  const double x = info.workspace_min.x() + 0.2 * (info.workspace_max.x() - info.workspace_min.x());
  EXPECT_NEAR(ReadAt(r0 + 3'000'000'000).pose.tip.x(), x, 1e-9);
}

TEST_F(BrowserDeviceServerTest, AHeartbeatIsCountedNotRefused) {
  device_->OnMessage("h", MonotonicNs());
  EXPECT_EQ(device_->stats().heartbeats, 1U);
  EXPECT_EQ(device_->stats().refused_total(), 0U);
}

}  // namespace
}  // namespace cutsim::haptic_client
