#pragma once
/// @file
/// Finds and loads a device plugin (haptic_client/plugin/cutsim_device.h):
/// resolves `--device NAME` to a shared library, dlopens it, looks up
/// `cutsim_device_entry` and checks the table it returns (ABI version, size,
/// every function present). Opening the device and checking its
/// capabilities is `PluginDevice`'s job (plugin_device.h).

#include <filesystem>
#include <memory>
#include <string>

#include "haptic_client/plugin/cutsim_device.h"

namespace cutsim::haptic_client {

/// The library `--device NAME` names: NAME itself when it contains a '/' or
/// ends in ".so", else `<dir>/libcutsim_device_<NAME>.so`.
[[nodiscard]] std::filesystem::path ResolvePluginPath(const std::string& name, const std::filesystem::path& dir);

/// A loaded plugin library; dlcloses on destruction.
class PluginLibrary {
 public:
  /// Loads `path` (RTLD_NOW | RTLD_LOCAL) and checks its entry table. Throws
  /// `InputError` naming the path (and the field of the table) when the file
  /// is missing, does not load, lacks the entry symbol, has another ABI
  /// version or a missing function.
  static std::unique_ptr<PluginLibrary> Load(const std::filesystem::path& path);
  ~PluginLibrary();
  PluginLibrary(const PluginLibrary&) = delete;
  PluginLibrary& operator=(const PluginLibrary&) = delete;

  [[nodiscard]] const cutsim_device_api& api() const { return *api_; }
  [[nodiscard]] const std::string& path() const { return path_; }
  /// The plugin's own name (api().name), or the file name if it gives none.
  [[nodiscard]] const std::string& name() const { return name_; }

 private:
  PluginLibrary(void* handle, const cutsim_device_api* api, std::string path, std::string name)
      : handle_(handle), api_(api), path_(std::move(path)), name_(std::move(name)) {}
  void* handle_;
  const cutsim_device_api* api_;
  std::string path_;
  std::string name_;
};

}  // namespace cutsim::haptic_client
