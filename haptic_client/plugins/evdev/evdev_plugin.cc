// libcutsim_device_evdev.so: the evdev device (evdev_device.h) behind the
// device plugin C ABI, on the kernel's calls (evdev_sys.h).
#include <cstdio>
#include <exception>
#include <new>

#include "haptic_client/plugin/cutsim_device.h"
#include "haptic_client/plugins/evdev/evdev_device.h"

using cutsim::device_plugins::EvdevDevice;

struct cutsim_device {
  EvdevDevice evdev;
};

namespace {

cutsim_device* Open(const char* config, char* error, size_t error_size) {
  try {
    return new cutsim_device{EvdevDevice(cutsim::device_plugins::KernelEvdevSys(),
                                         cutsim::device_plugins::ParseEvdevOptions(config))};
  } catch (const std::exception& e) {
    std::snprintf(error, error_size, "%s", e.what());
  }
  return nullptr;
}

int Capabilities(cutsim_device* d, cutsim_device_caps* caps) {
  *caps = d->evdev.Capabilities();
  return CUTSIM_DEVICE_OK;
}
int Read(cutsim_device* d, int64_t now_ns, cutsim_device_pose* pose) { return d->evdev.Read(now_ns, pose); }
int WriteForce(cutsim_device* d, int64_t now_ns, const double force[3]) { return d->evdev.WriteForce(now_ns, force); }
void Close(cutsim_device* d) { delete d; }
const char* LastError(cutsim_device* d) { return d->evdev.last_error(); }

const cutsim_device_api kApi{CUTSIM_DEVICE_ABI_VERSION,
                             sizeof(cutsim_device_api),
                             "evdev",
                             Open,
                             Capabilities,
                             Read,
                             WriteForce,
                             Close,
                             LastError};

}  // namespace

extern "C" const cutsim_device_api* cutsim_device_entry(void) { return &kApi; }
