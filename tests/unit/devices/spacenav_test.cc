// The spacenav plugin against a fake spacenavd: an AF_UNIX socket in a temp
// folder speaking the daemon's protocol (32-byte events of eight int32:
// type 0 = motion x y z rx ry rz period, 1 = button press, 2 = release,
// button number in the second word), with and without answering libspnav's
// protocol-version request.
#include <sys/socket.h>
#include <sys/un.h>
#include <unistd.h>

#include <array>
#include <cmath>
#include <cstdint>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <stdexcept>
#include <string>
#include <thread>

#include <gtest/gtest.h>

#include "haptic_client/plugins/common/plugin_config.h"
#include "haptic_client/plugins/spacenav/spacenav_device.h"

namespace cutsim::device_plugins {
namespace {

constexpr int64_t kMs = 1'000'000;

class FakeDaemon {
 public:
  /// Listens on a fresh socket; a thread accepts the client and, with
  /// `answer_protocol`, replies to its version request (protocol v1).
  explicit FakeDaemon(bool answer_protocol) {
    char tmpl[] = "/tmp/cutsim_spnav_XXXXXX";
    dir_ = mkdtemp(tmpl);
    path_ = dir_ + "/spnav.sock";
    listener_ = socket(AF_UNIX, SOCK_STREAM, 0);
    sockaddr_un addr{};
    addr.sun_family = AF_UNIX;
    std::strncpy(addr.sun_path, path_.c_str(), sizeof addr.sun_path - 1);
    if (bind(listener_, reinterpret_cast<sockaddr*>(&addr), sizeof addr) != 0 || listen(listener_, 1) != 0) {
      throw std::runtime_error("fake spacenavd: cannot listen on " + path_);
    }
    acceptor_ = std::thread([this, answer_protocol] {
      client_ = accept(listener_, nullptr, nullptr);
      if (client_ >= 0 && answer_protocol) {
        int32_t request = 0;
        if (read(client_, &request, sizeof request) == sizeof request) {
          (void)write(client_, &request, sizeof request);  // "yes, that version"
        }
      }
    });
  }
  ~FakeDaemon() {
    if (acceptor_.joinable()) acceptor_.join();
    if (client_ >= 0) close(client_);
    close(listener_);
    std::filesystem::remove_all(dir_);
  }
  FakeDaemon(const FakeDaemon&) = delete;
  FakeDaemon& operator=(const FakeDaemon&) = delete;

  [[nodiscard]] const std::string& path() const { return path_; }

  void Send(std::array<int32_t, 8> event) {
    if (acceptor_.joinable()) acceptor_.join();
    ASSERT_EQ(write(client_, event.data(), sizeof event), static_cast<ssize_t>(sizeof event));
  }
  void Motion(int32_t x, int32_t y, int32_t z, int32_t rx = 0, int32_t ry = 0, int32_t rz = 0) {
    Send({0, x, y, z, rx, ry, rz, 16});
  }
  void Button(int32_t number, bool press) { Send({press ? 1 : 2, number, 0, 0, 0, 0, 0, 0}); }
  void Hangup() {
    if (acceptor_.joinable()) acceptor_.join();
    close(client_);
    client_ = -1;
  }

 private:
  std::string dir_;
  std::string path_;
  int listener_ = -1;
  int client_ = -1;
  std::thread acceptor_;
};

SpacenavOptions Options(const FakeDaemon& daemon) {
  return ParseSpacenavOptions("socket=" + daemon.path() + ",speed=0.05,full_scale=350,half_extent=0.04,turn_speed=1");
}

/// One read; the events sent before it are already in the local socket.
int ReadAt(SpacenavDevice& device, int64_t now_ns, cutsim_device_pose* pose) { return device.Read(now_ns, pose); }

TEST(Spacenav, DeflectionMovesTheTipAtTheCommandedSpeed) {
  FakeDaemon daemon(true);
  SpacenavDevice device(Options(daemon));
  cutsim_device_pose p{};
  ASSERT_EQ(ReadAt(device, 0, &p), CUTSIM_DEVICE_OK);
  EXPECT_EQ(p.position[0], 0.0);
  daemon.Motion(350, -175, 0);  // full right, half down
  ASSERT_EQ(ReadAt(device, 100 * kMs, &p), CUTSIM_DEVICE_OK);
  EXPECT_NEAR(p.position[0], 0.005, 1e-12);   // 0.05 m/s · 0.1 s
  EXPECT_NEAR(p.position[1], -0.0025, 1e-12);
  EXPECT_NEAR(p.velocity[0], 0.05, 1e-9);
  daemon.Motion(0, 0, 0);  // let go: the tip stays
  ASSERT_EQ(ReadAt(device, 300 * kMs, &p), CUTSIM_DEVICE_OK);
  EXPECT_NEAR(p.position[0], 0.005, 1e-12);
  EXPECT_EQ(p.velocity[0], 0.0);
}

TEST(Spacenav, TipStaysInsideTheWorkspace) {
  FakeDaemon daemon(true);
  SpacenavDevice device(Options(daemon));
  cutsim_device_pose p{};
  ASSERT_EQ(ReadAt(device, 0, &p), CUTSIM_DEVICE_OK);
  daemon.Motion(0, 0, 5000);  // beyond full scale: clamped to full speed
  ASSERT_EQ(ReadAt(device, 100 * kMs, &p), CUTSIM_DEVICE_OK);
  EXPECT_NEAR(p.position[2], 0.005, 1e-12);
  ASSERT_EQ(ReadAt(device, 10'000 * kMs, &p), CUTSIM_DEVICE_OK);
  EXPECT_NEAR(p.position[2], 0.04, 1e-12);
  EXPECT_EQ(device.Capabilities().max_force, 0.0);  // input only
  EXPECT_EQ(device.Capabilities().workspace_max[2], 0.04);
}

TEST(Spacenav, RotationTurnsTheBlade) {
  FakeDaemon daemon(false);  // an old daemon: libspnav falls back to protocol v0
  SpacenavDevice device(Options(daemon));
  cutsim_device_pose p{};
  ASSERT_EQ(ReadAt(device, 0, &p), CUTSIM_DEVICE_OK);
  EXPECT_NEAR(p.blade_dir[2], 1.0, 1e-12);
  daemon.Motion(0, 0, 0, 0, 350, 0);  // full turn about Y at 1 rad/s
  ASSERT_EQ(ReadAt(device, 500 * kMs, &p), CUTSIM_DEVICE_OK);
  EXPECT_NEAR(p.blade_dir[0], std::sin(0.5), 1e-9);
  EXPECT_NEAR(p.blade_dir[2], std::cos(0.5), 1e-9);
  EXPECT_NEAR(p.position[0], 0.0, 1e-12);
}

TEST(Spacenav, ButtonZeroTogglesCuttingButtonOneIsTheClutch) {
  FakeDaemon daemon(true);
  SpacenavDevice device(Options(daemon));
  cutsim_device_pose p{};
  daemon.Button(0, true);
  daemon.Button(0, false);
  ASSERT_EQ(ReadAt(device, 0, &p), CUTSIM_DEVICE_OK);
  EXPECT_EQ(p.buttons, CUTSIM_BUTTON_CUT);
  daemon.Button(1, true);
  ASSERT_EQ(ReadAt(device, kMs, &p), CUTSIM_DEVICE_OK);
  EXPECT_EQ(p.buttons, CUTSIM_BUTTON_CUT | CUTSIM_BUTTON_CLUTCH);
  daemon.Button(1, false);
  daemon.Button(0, true);
  ASSERT_EQ(ReadAt(device, 2 * kMs, &p), CUTSIM_DEVICE_OK);
  EXPECT_EQ(p.buttons, 0U);
}

TEST(Spacenav, DaemonGoneIsUnplugged) {
  FakeDaemon daemon(true);
  SpacenavDevice device(Options(daemon));
  cutsim_device_pose p{};
  ASSERT_EQ(ReadAt(device, 0, &p), CUTSIM_DEVICE_OK);
  daemon.Hangup();
  EXPECT_EQ(ReadAt(device, kMs, &p), CUTSIM_DEVICE_UNPLUGGED);
  EXPECT_NE(std::string(device.last_error()).find(daemon.path()), std::string::npos) << device.last_error();
}

TEST(Spacenav, NoDaemonIsAClearError) {
  const std::string path = "/tmp/cutsim_no_such_spnav.sock";
  try {
    SpacenavDevice device(ParseSpacenavOptions("socket=" + path));
    FAIL() << "connected to nothing";
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find(path), std::string::npos) << e.what();
  }
}

TEST(Spacenav, OneDevicePerProcess) {
  FakeDaemon daemon(true);
  SpacenavDevice device(Options(daemon));
  EXPECT_THROW(SpacenavDevice second(Options(daemon)), std::runtime_error);
}

TEST(Spacenav, DeviceArgErrorsNameTheKey) {
  try {
    (void)ParseSpacenavOptions("speed=fast");
    FAIL();
  } catch (const ConfigError& e) {
    EXPECT_NE(std::string(e.what()).find("speed"), std::string::npos);
  }
  EXPECT_THROW((void)ParseSpacenavOptions("wobble=1"), ConfigError);
}

}  // namespace
}  // namespace cutsim::device_plugins
