/* A device plugin whose read sleeps for as long as the test says: the
 * stand-in for a driver that blocks (a USB read that does not return). The
 * test drives it through three exported functions:
 *   cutsim_test_slow_block(1)   makes every read sleep until ...
 *   cutsim_test_slow_block(0)   ... lets them return again
 *   cutsim_test_slow_sleeping() 1 while a read is sleeping
 *   cutsim_test_slow_closed()   1 once close has run
 * Otherwise it is a device at rest at the origin that records the force.
 * Built with CRASH_IN_CLOSE, its close then raises SIGSEGV: the stand-in for
 * a driver whose teardown faults. */
#include <signal.h>
#include <stddef.h>
#include <stdlib.h>
#include <time.h>

#include "haptic_client/plugin/cutsim_device.h"

struct cutsim_device {
  long reads;
};

static int g_block;
static int g_sleeping;
static int g_closed;

int cutsim_test_slow_block(int block);
int cutsim_test_slow_sleeping(void);
int cutsim_test_slow_closed(void);

int cutsim_test_slow_block(int block) {
  __atomic_store_n(&g_block, block, __ATOMIC_SEQ_CST);
  return 0;
}
int cutsim_test_slow_sleeping(void) { return __atomic_load_n(&g_sleeping, __ATOMIC_SEQ_CST); }
int cutsim_test_slow_closed(void) { return __atomic_load_n(&g_closed, __ATOMIC_SEQ_CST); }

static cutsim_device* slow_open(const char* config, char* error, size_t error_size) {
  (void)config;
  (void)error;
  (void)error_size;
  __atomic_store_n(&g_closed, 0, __ATOMIC_SEQ_CST);
  return calloc(1, sizeof(cutsim_device));
}

static int slow_capabilities(cutsim_device* d, cutsim_device_caps* caps) {
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

static int slow_read(cutsim_device* d, int64_t now_ns, cutsim_device_pose* pose) {
  (void)now_ns;
  if (__atomic_load_n(&g_block, __ATOMIC_SEQ_CST)) {
    __atomic_store_n(&g_sleeping, 1, __ATOMIC_SEQ_CST);
    const struct timespec nap = {0, 100000};
    while (__atomic_load_n(&g_block, __ATOMIC_SEQ_CST)) nanosleep(&nap, NULL);
    __atomic_store_n(&g_sleeping, 0, __ATOMIC_SEQ_CST);
  }
  ++d->reads;
  for (int i = 0; i < 3; ++i) {
    pose->position[i] = 0.0;
    pose->velocity[i] = 0.0;
    pose->blade_dir[i] = i == 2 ? 1.0 : 0.0;
  }
  pose->buttons = CUTSIM_BUTTON_CUT;
  return CUTSIM_DEVICE_OK;
}

static int slow_write(cutsim_device* d, int64_t now_ns, const double force[3]) {
  (void)d;
  (void)now_ns;
  (void)force;
  return CUTSIM_DEVICE_OK;
}

static void slow_close(cutsim_device* d) {
  free(d);
  __atomic_store_n(&g_closed, 1, __ATOMIC_SEQ_CST);
#ifdef CRASH_IN_CLOSE
  raise(SIGSEGV);
#endif
}

static const char* slow_last_error(cutsim_device* d) {
  (void)d;
  return "";
}

static const cutsim_device_api kApi = {
    .abi_version = CUTSIM_DEVICE_ABI_VERSION,
    .struct_size = sizeof(cutsim_device_api),
    .name = "slow",
    .open = slow_open,
    .capabilities = slow_capabilities,
    .read = slow_read,
    .write_force = slow_write,
    .close = slow_close,
    .last_error = slow_last_error,
};

const cutsim_device_api* cutsim_device_entry(void) { return &kApi; }
