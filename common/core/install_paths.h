#pragma once
/// @file
/// Where the apps find their read-only files at run time: the web pages they
/// serve and the haptic station's device plugins. An installed tree (a
/// Debian package under /usr, `cmake --install` under any prefix, or a
/// package extracted with `dpkg-deb -x` into any folder) keeps them at fixed
/// paths relative to the executable, so they are found wherever the tree
/// lies; an executable run from its build tree falls back to the source tree
/// it was built from.

#include <filesystem>
#include <string_view>

namespace cutsim {

/// The folder holding the running executable (read from /proc/self/exe);
/// the current directory when that link cannot be read.
[[nodiscard]] std::filesystem::path ExecutableDir();

/// `exe_dir / relative` when that folder exists, else `fallback`. The pure
/// rule behind `DataDir` and `PluginDir`.
[[nodiscard]] std::filesystem::path ResolveInstallDir(const std::filesystem::path& exe_dir,
                                                      std::string_view relative,
                                                      const std::filesystem::path& fallback);

/// cutsim's shared data folder: the installed one beside the executable
/// (`<prefix>/bin/../share/cutsim`) when it exists, else the source tree.
/// Holds `scenes/` and `web/` in both cases.
[[nodiscard]] std::filesystem::path DataDir();

/// The device plugins' folder: the installed one
/// (`<prefix>/bin/../lib/<multiarch>/cutsim/devices`) when it exists, else
/// the executable's own folder, where the build tree puts them.
[[nodiscard]] std::filesystem::path PluginDir();

}  // namespace cutsim
