#pragma once
/// @file
/// Logging through spdlog. Every process calls `InitLogging` once in main;
/// libraries log through `cutsim::Log()`. Logs go to stderr so that stdout
/// stays free for machine-readable output (JSON summaries).

#include <string_view>

#include <spdlog/spdlog.h>

namespace cutsim {

/// Sets the process-wide logger: stderr, "[time] [name] [level] msg".
/// `level` is one of trace, debug, info, warn, error, critical, off; an
/// unknown level throws `InputError` naming the flag.
void InitLogging(std::string_view process_name, std::string_view level = "info");

/// The process-wide logger (a default stderr logger if InitLogging was not called).
spdlog::logger& Log();

}  // namespace cutsim
