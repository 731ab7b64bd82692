#include "haptic_client/plugin_loader.h"

#include <dlfcn.h>
#include <unistd.h>

#include <array>
#include <system_error>

#include <fmt/format.h>

#include "common/core/error.h"

namespace cutsim::haptic_client {
namespace fs = std::filesystem;

fs::path ResolvePluginPath(const std::string& name, const fs::path& dir) {
  if (name.find('/') != std::string::npos || name.ends_with(".so")) return fs::path(name);
  return dir / fmt::format("libcutsim_device_{}.so", name);
}

std::unique_ptr<PluginLibrary> PluginLibrary::Load(const fs::path& path) {
  const std::string p = path.string();
  std::error_code ec;
  if (!fs::exists(path, ec)) ThrowFileError(p, "no such device plugin (see --device-dir)");
  dlerror();
  void* handle = dlopen(p.c_str(), RTLD_NOW | RTLD_LOCAL);
  if (handle == nullptr) {
    const char* why = dlerror();
    ThrowFileError(p, fmt::format("cannot load the device plugin: {}", why != nullptr ? why : "unknown dlopen error"));
  }
  auto fail = [&](const std::string& field, const std::string& message) {
    dlclose(handle);
    ThrowInputError(SourceRef{.file = p, .field = field}, message);
  };
  void* sym = dlsym(handle, CUTSIM_DEVICE_ENTRY_SYMBOL);
  if (sym == nullptr) fail(CUTSIM_DEVICE_ENTRY_SYMBOL, "the plugin does not export this function");
  // dlsym returns an object pointer; POSIX guarantees it converts to a function pointer.
  const auto entry = reinterpret_cast<cutsim_device_entry_fn>(sym);
  const cutsim_device_api* api = entry();
  if (api == nullptr) fail(CUTSIM_DEVICE_ENTRY_SYMBOL, "returned NULL");
  if (api->abi_version != CUTSIM_DEVICE_ABI_VERSION) {
    fail("abi_version", fmt::format("the plugin speaks device ABI {}, this cutsim-haptic speaks {}; rebuild the "
                                    "plugin against haptic_client/plugin/cutsim_device.h",
                                    api->abi_version, CUTSIM_DEVICE_ABI_VERSION));
  }
  if (api->struct_size < sizeof(cutsim_device_api)) {
    fail("struct_size", fmt::format("{} bytes, expected at least {}", api->struct_size, sizeof(cutsim_device_api)));
  }
  const std::array<std::pair<const char*, bool>, 6> functions{{{"open", api->open != nullptr},
                                                               {"capabilities", api->capabilities != nullptr},
                                                               {"read", api->read != nullptr},
                                                               {"write_force", api->write_force != nullptr},
                                                               {"close", api->close != nullptr},
                                                               {"last_error", api->last_error != nullptr}}};
  for (const auto& [field, present] : functions) {
    if (!present) fail(field, "the function pointer is NULL");
  }
  std::string name = api->name != nullptr && api->name[0] != '\0' ? api->name : path.stem().string();
  return std::unique_ptr<PluginLibrary>(new PluginLibrary(handle, api, p, std::move(name)));
}

PluginLibrary::~PluginLibrary() { dlclose(handle_); }

}  // namespace cutsim::haptic_client
