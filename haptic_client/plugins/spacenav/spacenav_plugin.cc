// libcutsim_device_spacenav.so: the 3D mouse (spacenav_device.h) behind the
// device plugin C ABI.
#include <cstdio>
#include <exception>

#include "haptic_client/plugin/cutsim_device.h"
#include "haptic_client/plugins/spacenav/spacenav_device.h"

using cutsim::device_plugins::SpacenavDevice;

struct cutsim_device {
  SpacenavDevice spacenav;
};

namespace {

cutsim_device* Open(const char* config, char* error, size_t error_size) {
  try {
    return new cutsim_device{SpacenavDevice(cutsim::device_plugins::ParseSpacenavOptions(config))};
  } catch (const std::exception& e) {
    std::snprintf(error, error_size, "%s", e.what());
  }
  return nullptr;
}

int Capabilities(cutsim_device* d, cutsim_device_caps* caps) {
  *caps = d->spacenav.Capabilities();
  return CUTSIM_DEVICE_OK;
}
int Read(cutsim_device* d, int64_t now_ns, cutsim_device_pose* pose) { return d->spacenav.Read(now_ns, pose); }
int WriteForce(cutsim_device* /*d*/, int64_t /*now_ns*/, const double* /*force*/) { return CUTSIM_DEVICE_OK; }
void Close(cutsim_device* d) { delete d; }
const char* LastError(cutsim_device* d) { return d->spacenav.last_error(); }

const cutsim_device_api kApi{CUTSIM_DEVICE_ABI_VERSION,
                             sizeof(cutsim_device_api),
                             "spacenav",
                             Open,
                             Capabilities,
                             Read,
                             WriteForce,
                             Close,
                             LastError};

}  // namespace

extern "C" const cutsim_device_api* cutsim_device_entry(void) { return &kApi; }
