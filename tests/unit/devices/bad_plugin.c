/* Broken device plugins for the loader's tests, one per define:
 *   BAD_VERSION   reports ABI version CUTSIM_DEVICE_ABI_VERSION + 1
 *   NULL_READ     leaves `read` NULL
 *   NO_ENTRY      exports no cutsim_device_entry */
#include <stddef.h>

#include "haptic_client/plugin/cutsim_device.h"

#ifndef NO_ENTRY
static cutsim_device* bad_open(const char* config, char* error, size_t error_size) {
  (void)config;
  (void)error;
  (void)error_size;
  return NULL;
}
static int bad_capabilities(cutsim_device* d, cutsim_device_caps* caps) {
  (void)d;
  (void)caps;
  return CUTSIM_DEVICE_ERROR;
}
#ifndef NULL_READ
static int bad_read(cutsim_device* d, int64_t now_ns, cutsim_device_pose* pose) {
  (void)d;
  (void)now_ns;
  (void)pose;
  return CUTSIM_DEVICE_ERROR;
}
#endif
static int bad_write(cutsim_device* d, int64_t now_ns, const double force[3]) {
  (void)d;
  (void)now_ns;
  (void)force;
  return CUTSIM_DEVICE_ERROR;
}
static void bad_close(cutsim_device* d) { (void)d; }
static const char* bad_last_error(cutsim_device* d) {
  (void)d;
  return "broken";
}

static const cutsim_device_api kApi = {
#ifdef BAD_VERSION
    .abi_version = CUTSIM_DEVICE_ABI_VERSION + 1,
#else
    .abi_version = CUTSIM_DEVICE_ABI_VERSION,
#endif
    .struct_size = sizeof(cutsim_device_api),
    .name = "broken",
    .open = bad_open,
    .capabilities = bad_capabilities,
#ifdef NULL_READ
    .read = NULL,
#else
    .read = bad_read,
#endif
    .write_force = bad_write,
    .close = bad_close,
    .last_error = bad_last_error,
};

const cutsim_device_api* cutsim_device_entry(void) { return &kApi; }
#else
int cutsim_not_a_device_plugin(void);
int cutsim_not_a_device_plugin(void) { return 0; }
#endif
