/* example_spring: the worked example of the cutsim device plugin ABI
 * (haptic_client/plugin/cutsim_device.h, docs/devices.md), in plain C.
 *
 * A simulated hand holds the stylus through a spring: the hand starts at
 * (x, y, z) and moves at the constant velocity (vx, vy, vz); the tip sits
 * where the spring balances the commanded force,
 *     tip = hand + F / hand_stiffness
 * (rigid, tip = hand, when hand_stiffness is 0). So the force the client
 * renders pushes the tip back, as it pushes a real user's hand.
 *
 * --device-arg is a comma-separated list of key=value (all optional):
 *   x, y, z          m, the hand's start (0)
 *   vx, vy, vz       m/s, the hand's velocity (0)
 *   hand_stiffness   N/m (0 = rigid)
 *   buttons          button bits reported (1 = cutting)
 *   unplug_after     reads before the device reports itself unplugged (0 = never)
 *   half_extent      m, workspace = +-half_extent on each axis (0.1)
 *   max_force, max_stiffness, max_damping, rate_hz   capabilities (4, 1000, 5, 1000)
 *   fail_open        1 = open fails (for tests)
 *   read_delay_ms    ms each read sleeps: a driver that blocks (for the
 *                    benchmark of the station's device deadline; 0)
 *
 * For tests it also exports cutsim_example_spring_force(): the last force
 * written and the number of writes.
 */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "haptic_client/plugin/cutsim_device.h"

struct cutsim_device {
  double hand0[3];
  double velocity[3];
  double hand_stiffness;
  unsigned buttons;
  long unplug_after;
  double read_delay_ms;
  cutsim_device_caps caps;
  long reads;
  long writes;
  int started;
  int64_t t0_ns;
  double force[3];
  char error[256];
};

/* Parses "key=value,key=value" into `d`; 0 on success, else -1 with a
 * message in `error`. */
static int parse_config(cutsim_device* d, const char* config, int* fail_open, char* error, size_t error_size) {
  char* copy = strdup(config);
  char* save = NULL;
  int rc = 0;
  if (copy == NULL) {
    snprintf(error, error_size, "example_spring: out of memory");
    return -1;
  }
  for (char* item = strtok_r(copy, ",", &save); item != NULL; item = strtok_r(NULL, ",", &save)) {
    char* eq = strchr(item, '=');
    char* end = NULL;
    double v;
    if (eq == NULL) {
      snprintf(error, error_size, "example_spring: --device-arg item \"%s\" is not key=value", item);
      rc = -1;
      break;
    }
    *eq = '\0';
    v = strtod(eq + 1, &end);
    if (end == eq + 1 || *end != '\0') {
      snprintf(error, error_size, "example_spring: --device-arg %s=\"%s\" is not a number", item, eq + 1);
      rc = -1;
      break;
    }
    if (strcmp(item, "x") == 0) d->hand0[0] = v;
    else if (strcmp(item, "y") == 0) d->hand0[1] = v;
    else if (strcmp(item, "z") == 0) d->hand0[2] = v;
    else if (strcmp(item, "vx") == 0) d->velocity[0] = v;
    else if (strcmp(item, "vy") == 0) d->velocity[1] = v;
    else if (strcmp(item, "vz") == 0) d->velocity[2] = v;
    else if (strcmp(item, "hand_stiffness") == 0) d->hand_stiffness = v;
    else if (strcmp(item, "buttons") == 0) d->buttons = (unsigned)v;
    else if (strcmp(item, "unplug_after") == 0) d->unplug_after = (long)v;
    else if (strcmp(item, "half_extent") == 0) {
      for (int i = 0; i < 3; ++i) {
        d->caps.workspace_min[i] = -v;
        d->caps.workspace_max[i] = v;
      }
    } else if (strcmp(item, "max_force") == 0) d->caps.max_force = v;
    else if (strcmp(item, "max_stiffness") == 0) d->caps.max_stiffness = v;
    else if (strcmp(item, "max_damping") == 0) d->caps.max_damping = v;
    else if (strcmp(item, "rate_hz") == 0) d->caps.rate_hz = v;
    else if (strcmp(item, "fail_open") == 0) *fail_open = v != 0.0;
    else if (strcmp(item, "read_delay_ms") == 0) d->read_delay_ms = v;
    else {
      snprintf(error, error_size, "example_spring: unknown --device-arg key \"%s\"", item);
      rc = -1;
      break;
    }
  }
  free(copy);
  return rc;
}

static cutsim_device* spring_open(const char* config, char* error, size_t error_size) {
  cutsim_device* d = calloc(1, sizeof *d);
  int fail_open = 0;
  if (d == NULL) {
    snprintf(error, error_size, "example_spring: out of memory");
    return NULL;
  }
  d->buttons = CUTSIM_BUTTON_CUT;
  for (int i = 0; i < 3; ++i) {
    d->caps.workspace_min[i] = -0.1;
    d->caps.workspace_max[i] = 0.1;
  }
  d->caps.max_force = 4.0;
  d->caps.max_stiffness = 1000.0;
  d->caps.max_damping = 5.0;
  d->caps.rate_hz = 1000.0;
  if (parse_config(d, config, &fail_open, error, error_size) != 0) {
    free(d);
    return NULL;
  }
  if (fail_open) {
    snprintf(error, error_size, "example_spring: fail_open=1 was asked for");
    free(d);
    return NULL;
  }
  if (!(d->read_delay_ms >= 0.0 && d->read_delay_ms <= 10000.0)) {
    snprintf(error, error_size, "example_spring: read_delay_ms %g must lie in [0, 10000]", d->read_delay_ms);
    free(d);
    return NULL;
  }
  if (!(d->hand_stiffness >= 0.0)) {
    snprintf(error, error_size, "example_spring: hand_stiffness %g N/m must be >= 0", d->hand_stiffness);
    free(d);
    return NULL;
  }
  return d;
}

static int spring_capabilities(cutsim_device* d, cutsim_device_caps* caps) {
  *caps = d->caps;
  return CUTSIM_DEVICE_OK;
}

static int spring_read(cutsim_device* d, int64_t now_ns, cutsim_device_pose* pose) {
  double t;
  if (d->unplug_after > 0 && d->reads >= d->unplug_after) {
    snprintf(d->error, sizeof d->error, "example_spring: unplugged after %ld reads (unplug_after)", d->reads);
    return CUTSIM_DEVICE_UNPLUGGED;
  }
  ++d->reads;
  if (d->read_delay_ms > 0.0) {
    const double s = 1e-3 * d->read_delay_ms;
    const struct timespec nap = {(time_t)s, (long)((s - (double)(time_t)s) * 1e9)};
    nanosleep(&nap, NULL);
  }
  if (!d->started) {
    d->started = 1;
    d->t0_ns = now_ns;
  }
  t = 1e-9 * (double)(now_ns - d->t0_ns);
  for (int i = 0; i < 3; ++i) {
    const double hand = d->hand0[i] + d->velocity[i] * t;
    pose->position[i] = d->hand_stiffness > 0.0 ? hand + d->force[i] / d->hand_stiffness : hand;
    pose->velocity[i] = d->velocity[i];
    pose->blade_dir[i] = i == 2 ? 1.0 : 0.0;
  }
  pose->buttons = d->buttons;
  return CUTSIM_DEVICE_OK;
}

static int spring_write_force(cutsim_device* d, int64_t now_ns, const double force[3]) {
  (void)now_ns;
  for (int i = 0; i < 3; ++i) {
    if (!isfinite(force[i])) {
      snprintf(d->error, sizeof d->error, "example_spring: non-finite force[%d]", i);
      return CUTSIM_DEVICE_ERROR;
    }
  }
  memcpy(d->force, force, sizeof d->force);
  ++d->writes;
  return CUTSIM_DEVICE_OK;
}

static void spring_close(cutsim_device* d) { free(d); }

static const char* spring_last_error(cutsim_device* d) { return d->error; }

static const cutsim_device_api kApi = {
    .abi_version = CUTSIM_DEVICE_ABI_VERSION,
    .struct_size = sizeof(cutsim_device_api),
    .name = "example_spring",
    .open = spring_open,
    .capabilities = spring_capabilities,
    .read = spring_read,
    .write_force = spring_write_force,
    .close = spring_close,
    .last_error = spring_last_error,
};

const cutsim_device_api* cutsim_device_entry(void) { return &kApi; }

/* Test hook: the last force written (N) and the number of writes. */
long cutsim_example_spring_force(const cutsim_device* d, double force[3]);
long cutsim_example_spring_force(const cutsim_device* d, double force[3]) {
  memcpy(force, d->force, sizeof d->force);
  return d->writes;
}
