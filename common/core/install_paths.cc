#include "common/core/install_paths.h"

#include <system_error>

// Set by common/core/CMakeLists.txt from the install layout (GNUInstallDirs).
#ifndef CUTSIM_SOURCE_DIR
#error "CUTSIM_SOURCE_DIR must name the source tree"
#endif
#ifndef CUTSIM_DATA_DIR_FROM_BIN
#error "CUTSIM_DATA_DIR_FROM_BIN must name the data folder relative to the executables' folder"
#endif
#ifndef CUTSIM_PLUGIN_DIR_FROM_BIN
#error "CUTSIM_PLUGIN_DIR_FROM_BIN must name the plugin folder relative to the executables' folder"
#endif

namespace cutsim {
namespace fs = std::filesystem;

fs::path ExecutableDir() {
  std::error_code ec;
  const fs::path exe = fs::read_symlink("/proc/self/exe", ec);
  return ec ? fs::current_path() : exe.parent_path();
}

fs::path ResolveInstallDir(const fs::path& exe_dir, std::string_view relative, const fs::path& fallback) {
  std::error_code ec;
  const fs::path installed = (exe_dir / relative).lexically_normal();
  return fs::is_directory(installed, ec) ? installed : fallback;
}

fs::path DataDir() { return ResolveInstallDir(ExecutableDir(), CUTSIM_DATA_DIR_FROM_BIN, CUTSIM_SOURCE_DIR); }

fs::path PluginDir() {
  const fs::path exe_dir = ExecutableDir();
  return ResolveInstallDir(exe_dir, CUTSIM_PLUGIN_DIR_FROM_BIN, exe_dir);
}

}  // namespace cutsim
