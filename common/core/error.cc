#include "common/core/error.h"

#include <cstdio>
#include <cstdlib>

#include <fmt/format.h>

namespace cutsim {

std::string SourceRef::ToString() const {
  std::string out = file;
  if (line) out += fmt::format("{}{}", out.empty() ? "line " : ":", *line);
  if (column) out += fmt::format(":{}", *column);
  if (!field.empty()) out += fmt::format("{}{}", out.empty() ? "" : ": ", field);
  return out.empty() ? std::string("<input>") : out;
}

InputError::InputError(SourceRef source, std::string_view message)
    : std::runtime_error(fmt::format("{}: {}", source.ToString(), message)),
      source_(std::move(source)),
      message_(message) {}

void ThrowInputError(SourceRef source, std::string_view message) {
  throw InputError(std::move(source), message);
}

void ThrowFileError(std::string_view file, std::string_view message) {
  throw InputError(SourceRef{.file = std::string(file)}, message);
}

void AbortInvariant(const char* condition, const char* file, int line,
                    std::string_view message) {
  std::fprintf(stderr, "%s:%d: invariant failed: %s: %.*s\n", file, line, condition,
               static_cast<int>(message.size()), message.data());
  std::fflush(stderr);
  std::abort();
}

}  // namespace cutsim
