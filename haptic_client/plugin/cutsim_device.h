/* cutsim device plugin ABI (plain C).
 *
 * A device plugin is a shared library (libcutsim_device_<name>.so) that
 * exports one function, `cutsim_device_entry`, returning a table of function
 * pointers. `cutsim-haptic --device <name>` loads it with dlopen, checks
 * `abi_version` and `struct_size`, opens the device with the string of
 * `--device-arg`, checks its capabilities and then calls `read` and
 * `write_force` once per servo tick (1 kHz by default) from the servo thread.
 *
 * Rules for a plugin:
 *  - `open` and `close` run outside the servo loop: they may block, allocate
 *    and talk to the hardware for as long as they need.
 *  - `read` and `write_force` run inside the loop: no allocation, no blocking
 *    (file descriptors O_NONBLOCK), no sleeping, no exceptions across the
 *    boundary. A call should return within a few microseconds.
 *  - All calls on one device come from one thread; a plugin needs no locks.
 *  - Units are SI (metres, seconds, newtons) in the device's own frame; the
 *    haptic client maps that frame to the tissue (scale, offset, clutch).
 *  - Every function returns CUTSIM_DEVICE_OK (0) on success or a negative
 *    CUTSIM_DEVICE_* code; `last_error` then says why, naming the device.
 *
 * docs/devices.md documents the ABI with a worked example
 * (haptic_client/plugins/example_spring/example_spring.c).
 */
#ifndef CUTSIM_DEVICE_H_
#define CUTSIM_DEVICE_H_

#include <stddef.h>
#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

/* Bumped on any incompatible change of the structs or functions below. */
#define CUTSIM_DEVICE_ABI_VERSION 1u

/* The name of the function every plugin exports. */
#define CUTSIM_DEVICE_ENTRY_SYMBOL "cutsim_device_entry"

/* Return codes. */
#define CUTSIM_DEVICE_OK 0           /* success */
#define CUTSIM_DEVICE_ERROR (-1)     /* a failure; the device may recover */
#define CUTSIM_DEVICE_UNPLUGGED (-2) /* the device is gone (ENODEV, EOF); it does not come back */

/* Button bits of cutsim_device_pose.buttons (the client's defaults; a
 * plugin sets whatever its hardware has, the user picks the clutch bit). */
#define CUTSIM_BUTTON_CUT 0x1u    /* cutting enabled */
#define CUTSIM_BUTTON_CLUTCH 0x2u /* clutch: move the device, not the tool */

/* Opaque per-device state, allocated by `open`, freed by `close`. */
typedef struct cutsim_device cutsim_device;

/* What the device can do. Filled by `capabilities` after `open`. */
typedef struct cutsim_device_caps {
  double workspace_min[3]; /* m, device frame: the box the tip can reach */
  double workspace_max[3]; /* m, each > workspace_min */
  double max_force;        /* N, continuous; 0 = no force output (input-only device) */
  double max_stiffness;    /* N/m, stiffest spring it renders stably (> 0) */
  double max_damping;      /* N*s/m (>= 0) */
  double rate_hz;          /* highest rate at which read/write_force make sense (> 0) */
} cutsim_device_caps;

/* One reading of the device. */
typedef struct cutsim_device_pose {
  double position[3];  /* m, tip in the device frame */
  double blade_dir[3]; /* unit vector along the blade edge (any length > 0; normalised by the client) */
  double velocity[3];  /* m/s, of the tip */
  uint32_t buttons;    /* CUTSIM_BUTTON_* bits */
} cutsim_device_pose;

typedef struct cutsim_device_api {
  uint32_t abi_version; /* CUTSIM_DEVICE_ABI_VERSION */
  uint32_t struct_size; /* sizeof(cutsim_device_api) */
  const char* name;     /* short name for logs, e.g. "evdev" */

  /* Opens the device described by `config` (the --device-arg string, never
   * NULL, may be empty). On failure returns NULL and writes a NUL-terminated
   * message of at most `error_size` bytes into `error`. */
  cutsim_device* (*open)(const char* config, char* error, size_t error_size);

  /* Fills `caps`. */
  int (*capabilities)(cutsim_device* device, cutsim_device_caps* caps);

  /* The state at `now_ns` (CLOCK_MONOTONIC ns). When no new data has
   * arrived, returns the last state and CUTSIM_DEVICE_OK. */
  int (*read)(cutsim_device* device, int64_t now_ns, cutsim_device_pose* pose);

  /* The force to exert on the user's hand, N, device frame, at `now_ns`.
   * Already clamped by the client to caps.max_force. */
  int (*write_force)(cutsim_device* device, int64_t now_ns, const double force[3]);

  /* Zeroes the force and releases the device and `device`. */
  void (*close)(cutsim_device* device);

  /* The reason for the last failure (never NULL; "" when none). The string
   * lives until the next call on `device`. */
  const char* (*last_error)(cutsim_device* device);
} cutsim_device_api;

/* The one exported function. */
typedef const cutsim_device_api* (*cutsim_device_entry_fn)(void);
const cutsim_device_api* cutsim_device_entry(void);

#ifdef __cplusplus
}
#endif

#endif /* CUTSIM_DEVICE_H_ */
