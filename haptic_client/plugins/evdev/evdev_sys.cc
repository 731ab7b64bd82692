#include "haptic_client/plugins/evdev/evdev_sys.h"

#include <fcntl.h>
#include <sys/ioctl.h>
#include <unistd.h>

namespace cutsim::device_plugins {
namespace {

int SysOpen(void* /*ctx*/, const char* path, int flags) { return ::open(path, flags); }
int SysIoctl(void* /*ctx*/, int fd, unsigned long request, void* arg) { return ::ioctl(fd, request, arg); }
ssize_t SysRead(void* /*ctx*/, int fd, void* buffer, size_t size) { return ::read(fd, buffer, size); }
ssize_t SysWrite(void* /*ctx*/, int fd, const void* buffer, size_t size) { return ::write(fd, buffer, size); }
int SysClose(void* /*ctx*/, int fd) { return ::close(fd); }

}  // namespace

const EvdevSys& KernelEvdevSys() {
  static const EvdevSys sys{SysOpen, SysIoctl, SysRead, SysWrite, SysClose, nullptr};
  return sys;
}

}  // namespace cutsim::device_plugins
