/* A device plugin that works until it is closed and then crashes in its
 * close (SIGSEGV): the stand-in for a driver whose teardown faults. A
 * device at rest at the origin otherwise. */
#include <signal.h>
#include <stddef.h>
#include <stdlib.h>

#include "haptic_client/plugin/cutsim_device.h"

struct cutsim_device {
  long reads;
};

static cutsim_device* crash_open(const char* config, char* error, size_t error_size) {
  (void)config;
  (void)error;
  (void)error_size;
  return calloc(1, sizeof(cutsim_device));
}

static int crash_capabilities(cutsim_device* d, cutsim_device_caps* caps) {
  (void)d;
  for (int i = 0; i < 3; ++i) {
    caps->workspace_min[i] = -0.1;
    caps->workspace_max[i] = 0.1;
  }
  caps->max_force = 4.0;
  caps->max_stiffness = 1000.0;
  caps->max_damping = 5.0;
  caps->rate_hz = 1000.0;
  return CUTSIM_DEVICE_OK;
}

static int crash_read(cutsim_device* d, int64_t now_ns, cutsim_device_pose* pose) {
  (void)now_ns;
  ++d->reads;
  for (int i = 0; i < 3; ++i) {
    pose->position[i] = 0.0;
    pose->velocity[i] = 0.0;
    pose->blade_dir[i] = i == 2 ? 1.0 : 0.0;
  }
  pose->buttons = 0;
  return CUTSIM_DEVICE_OK;
}

static int crash_write(cutsim_device* d, int64_t now_ns, const double force[3]) {
  (void)d;
  (void)now_ns;
  (void)force;
  return CUTSIM_DEVICE_OK;
}

static void crash_close(cutsim_device* d) {
  free(d);
  raise(SIGSEGV);
}

static const char* crash_last_error(cutsim_device* d) {
  (void)d;
  return "";
}

static const cutsim_device_api kApi = {
    .abi_version = CUTSIM_DEVICE_ABI_VERSION,
    .struct_size = sizeof(cutsim_device_api),
    .name = "crash_close",
    .open = crash_open,
    .capabilities = crash_capabilities,
    .read = crash_read,
    .write_force = crash_write,
    .close = crash_close,
    .last_error = crash_last_error,
};

const cutsim_device_api* cutsim_device_entry(void) { return &kApi; }
