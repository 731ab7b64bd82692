// The trainee page's messages as the browser device reads them
// (haptic_client/browser_device.h): newline-separated messages, each with a
// receive time 0 to 255 ms after the one before (its first byte), pushed
// through one SampleStream; the pose the 1 kHz loop would render is
// interpolated after each and must stay finite and inside the workspace.
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <cstdlib>
#include <string_view>

#include "haptic_client/browser_device.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  using namespace cutsim::haptic_client;
  static const DeviceInfo kInfo = BrowserDevice::DefaultInfo();
  SampleStream stream(kInfo);
  std::string_view rest(reinterpret_cast<const char*>(data), size);
  int64_t now = 1'000'000'000;
  while (!rest.empty()) {
    now += int64_t{static_cast<uint8_t>(rest.front())} * 1'000'000;
    rest.remove_prefix(1);
    const size_t nl = rest.find('\n');
    const std::string_view message = rest.substr(0, nl);
    rest.remove_prefix(nl == std::string_view::npos ? rest.size() : nl + 1);
    bool heartbeat = false;
    bool reanchored = false;
    (void)stream.Push(message, now, &heartbeat, &reanchored);
    DeviceState state;
    double used = -1.0;
    InterpolatePose(stream.pair(), now, &state, &used);
    const Eigen::Vector3d& p = state.pose.tip;
    if (stream.pair().count > 0 &&
        (!p.allFinite() || (p - kInfo.workspace_min).minCoeff() < -1e-9 || (kInfo.workspace_max - p).minCoeff() < -1e-9)) {
      std::abort();  // a pose outside the workspace is a finding
    }
  }
  return 0;
}
