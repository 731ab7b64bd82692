#pragma once
/// @file
/// The seam between the evdev plugin and the kernel: the five calls it makes
/// on /dev/input/event*, as a function table, so tests drive the plugin's
/// logic against a fake device. Each function follows its POSIX namesake:
/// -1 with errno set on failure.

#include <sys/types.h>

namespace cutsim::device_plugins {

struct EvdevSys {
  int (*open)(void* ctx, const char* path, int flags);
  int (*ioctl)(void* ctx, int fd, unsigned long request, void* arg);
  ssize_t (*read)(void* ctx, int fd, void* buffer, size_t size);
  ssize_t (*write)(void* ctx, int fd, const void* buffer, size_t size);
  int (*close)(void* ctx, int fd);
  void* ctx = nullptr;  ///< Passed to every call (the fake's state; null for the kernel).
};

/// The real calls (open(2), ioctl(2), read(2), write(2), close(2)).
[[nodiscard]] const EvdevSys& KernelEvdevSys();

}  // namespace cutsim::device_plugins
