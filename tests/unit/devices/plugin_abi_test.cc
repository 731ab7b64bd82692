// The device plugin ABI: loading the example plugin through PluginDevice,
// the loader's refusals (missing file, no entry, other ABI version, missing
// function), capability checks, and a pose and force through the boundary.
#include <dlfcn.h>

#include <array>
#include <cmath>
#include <memory>
#include <string>

#include <gtest/gtest.h>

#include "common/core/error.h"
#include "haptic_client/plugin_device.h"
#include "haptic_client/plugin_loader.h"

namespace cutsim::haptic_client {
namespace {

std::unique_ptr<PluginDevice> Open(const std::string& arg) {
  return std::make_unique<PluginDevice>(PluginLibrary::Load(CUTSIM_EXAMPLE_PLUGIN), arg);
}

/// The InputError message `f` throws ("" if none).
template <typename F>
std::string ErrorOf(F&& f) {
  try {
    f();
  } catch (const InputError& e) {
    return e.what();
  }
  return "";
}

TEST(PluginAbi, ResolvesNamesInTheDirectoryAndPathsAsGiven) {
  EXPECT_EQ(ResolvePluginPath("evdev", "/opt/x"), std::filesystem::path("/opt/x/libcutsim_device_evdev.so"));
  EXPECT_EQ(ResolvePluginPath("./mine.so", "/opt/x"), std::filesystem::path("./mine.so"));
  EXPECT_EQ(ResolvePluginPath("/a/b", "/opt/x"), std::filesystem::path("/a/b"));
}

TEST(PluginAbi, ExamplePluginLoadsWithItsCapabilities) {
  auto device = Open("half_extent=0.07,max_force=3,max_stiffness=800,rate_hz=500");
  const DeviceInfo& info = device->info();
  EXPECT_EQ(info.name, "example_spring");
  EXPECT_DOUBLE_EQ(info.max_force, 3.0);
  EXPECT_DOUBLE_EQ(info.max_stiffness, 800.0);
  EXPECT_DOUBLE_EQ(info.rate_hz, 500.0);
  EXPECT_DOUBLE_EQ(info.workspace_min.x(), -0.07);
  EXPECT_DOUBLE_EQ(info.workspace_max.z(), 0.07);
}

TEST(PluginAbi, PoseAndForceCrossTheBoundary) {
  auto device = Open("x=0.01,y=0.02,z=0.03,vx=0.1,hand_stiffness=1000,buttons=3");
  device->Start(0);
  DeviceState s;
  device->Read(1'000'000'000, &s);  // first read: the hand at its start
  EXPECT_NEAR(s.pose.tip.x(), 0.01, 1e-12);
  EXPECT_NEAR(s.pose.tip.y(), 0.02, 1e-12);
  EXPECT_NEAR(s.velocity.x(), 0.1, 1e-12);
  EXPECT_EQ(s.buttons, 3U);
  EXPECT_NEAR(s.pose.blade_dir.norm(), 1.0, 1e-12);
  device->Read(1'100'000'000, &s);  // 0.1 s later at 0.1 m/s
  EXPECT_NEAR(s.pose.tip.x(), 0.02, 1e-9);
  // A force pushes the tip through the hand's spring: +1 N in z → +1 mm.
  device->SetForce(Eigen::Vector3d(0.0, 0.0, 1.0));
  device->Read(1'100'000'000, &s);
  EXPECT_NEAR(s.pose.tip.z(), 0.031, 1e-9);
  EXPECT_EQ(device->stats().read_errors, 0U);
}

TEST(PluginAbi, ForceReachesThePluginThroughItsWriteFunction) {
  void* handle = dlopen(CUTSIM_EXAMPLE_PLUGIN, RTLD_NOW | RTLD_LOCAL);
  ASSERT_NE(handle, nullptr) << dlerror();
  using Hook = long (*)(const void*, double*);
  const auto hook = reinterpret_cast<Hook>(dlsym(handle, "cutsim_example_spring_force"));
  ASSERT_NE(hook, nullptr);
  const auto entry = reinterpret_cast<cutsim_device_entry_fn>(dlsym(handle, CUTSIM_DEVICE_ENTRY_SYMBOL));
  const cutsim_device_api* api = entry();
  std::array<char, 128> error{};
  cutsim_device* d = api->open("", error.data(), error.size());
  ASSERT_NE(d, nullptr) << error.data();
  const double f[3] = {0.5, -1.0, 2.0};
  EXPECT_EQ(api->write_force(d, 0, f), CUTSIM_DEVICE_OK);
  std::array<double, 3> got{};
  EXPECT_EQ(hook(d, got.data()), 1);
  EXPECT_EQ(got[1], -1.0);
  const double bad[3] = {NAN, 0.0, 0.0};
  EXPECT_EQ(api->write_force(d, 0, bad), CUTSIM_DEVICE_ERROR);
  EXPECT_NE(std::string(api->last_error(d)).find("non-finite"), std::string::npos);
  api->close(d);
  dlclose(handle);
}

TEST(PluginAbi, UnpluggedDeviceHoldsItsLastPoseAndTakesNoMoreForce) {
  auto device = Open("vx=0.1,unplug_after=3");
  device->Start(0);
  DeviceState s;
  for (int i = 0; i < 3; ++i) device->Read(int64_t{i} * 10'000'000, &s);
  const Eigen::Vector3d last = s.pose.tip;
  EXPECT_FALSE(s.lost);
  device->Read(40'000'000, &s);
  EXPECT_TRUE(s.lost);
  EXPECT_EQ(s.pose.tip, last);
  EXPECT_EQ(s.buttons, 0U);
  EXPECT_TRUE(device->stats().unplugged);
  EXPECT_NE(device->last_error().find("unplugged"), std::string::npos);
  device->SetForce(Eigen::Vector3d(1.0, 0.0, 0.0));  // no call reaches a lost device
  EXPECT_EQ(device->stats().write_errors, 0U);
}

TEST(PluginAbi, RefusesAMissingFileNamingIt) {
  const std::string e = ErrorOf([] { (void)PluginLibrary::Load("/nonexistent/libcutsim_device_x.so"); });
  EXPECT_NE(e.find("/nonexistent/libcutsim_device_x.so"), std::string::npos) << e;
}

TEST(PluginAbi, RefusesALibraryWithoutTheEntryFunction) {
  const std::string e = ErrorOf([] { (void)PluginLibrary::Load(CUTSIM_NO_ENTRY_PLUGIN); });
  EXPECT_NE(e.find(CUTSIM_DEVICE_ENTRY_SYMBOL), std::string::npos) << e;
  EXPECT_NE(e.find(CUTSIM_NO_ENTRY_PLUGIN), std::string::npos) << e;
}

TEST(PluginAbi, RefusesAnotherAbiVersion) {
  const std::string e = ErrorOf([] { (void)PluginLibrary::Load(CUTSIM_BAD_VERSION_PLUGIN); });
  EXPECT_NE(e.find("abi_version"), std::string::npos) << e;
  EXPECT_NE(e.find(std::to_string(CUTSIM_DEVICE_ABI_VERSION + 1)), std::string::npos) << e;
}

TEST(PluginAbi, RefusesAMissingFunction) {
  const std::string e = ErrorOf([] { (void)PluginLibrary::Load(CUTSIM_NULL_READ_PLUGIN); });
  EXPECT_NE(e.find("read"), std::string::npos) << e;
  EXPECT_NE(e.find("NULL"), std::string::npos) << e;
}

TEST(PluginAbi, OpenFailureCarriesThePluginsMessage) {
  const std::string e = ErrorOf([] { (void)Open("fail_open=1"); });
  EXPECT_NE(e.find("fail_open"), std::string::npos) << e;
  EXPECT_NE(e.find("--device-arg"), std::string::npos) << e;
  const std::string unknown = ErrorOf([] { (void)Open("colour=red"); });
  EXPECT_NE(unknown.find("colour"), std::string::npos) << unknown;
}

TEST(PluginAbi, RefusesInsaneCapabilitiesNamingTheField) {
  struct Case {
    const char* arg;
    const char* field;
  };
  for (const Case& c : {Case{"max_force=nan", "capabilities.max_force"},
                        Case{"max_force=-1", "capabilities.max_force"},
                        Case{"max_force=5000", "capabilities.max_force"},
                        Case{"max_stiffness=0", "capabilities.max_stiffness"},
                        Case{"max_damping=inf", "capabilities.max_damping"},
                        Case{"rate_hz=0", "capabilities.rate_hz"},
                        Case{"half_extent=-0.1", "capabilities.workspace_max[0]"},
                        Case{"half_extent=100", "capabilities.workspace_min[0]"}}) {
    const std::string e = ErrorOf([&] { (void)Open(c.arg); });
    EXPECT_NE(e.find(c.field), std::string::npos) << c.arg << ": " << e;
    EXPECT_NE(e.find(CUTSIM_EXAMPLE_PLUGIN), std::string::npos) << e;
  }
}

TEST(PluginAbi, InputOnlyDeviceIsAccepted) {
  auto device = Open("max_force=0");
  EXPECT_EQ(device->info().max_force, 0.0);
}

}  // namespace
}  // namespace cutsim::haptic_client
