#include "common/core/log.h"

#include <memory>
#include <string>

#include <spdlog/sinks/stdout_color_sinks.h>

#include "common/core/error.h"

namespace cutsim {

void InitLogging(std::string_view process_name, std::string_view level) {
  const auto parsed = spdlog::level::from_str(std::string(level));
  // from_str maps unknown strings to "off"; only accept "off" when asked for.
  if (parsed == spdlog::level::off && level != "off") {
    ThrowInputError({.field = "--log-level"},
                    "unknown log level '" + std::string(level) +
                        "' (trace, debug, info, warn, error, critical, off)");
  }
  auto logger = spdlog::stderr_color_mt(std::string(process_name));
  logger->set_pattern("[%H:%M:%S.%e] [%n] [%^%l%$] %v");
  logger->set_level(parsed);
  spdlog::set_default_logger(std::move(logger));
}

spdlog::logger& Log() { return *spdlog::default_logger_raw(); }

}  // namespace cutsim
