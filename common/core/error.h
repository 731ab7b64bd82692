#pragma once
/// @file
/// Errors that name their source. Bad input (a scene, a mesh, a message, a
/// command line) is reported by throwing `cutsim::InputError` at construction
/// time, with the file, line and field that caused it, so a user can fix the
/// input without reading code. Broken invariants are programming errors and
/// abort through `CUTSIM_CHECK`.

#include <cstdint>
#include <optional>
#include <stdexcept>
#include <string>
#include <string_view>

namespace cutsim {

/// Where a piece of input came from: any subset of file, line, column, field.
struct SourceRef {
  std::string file;               ///< Path or channel name; empty if unknown.
  std::optional<int64_t> line;    ///< 1-based line (or element/record index).
  std::optional<int64_t> column;  ///< 1-based column.
  std::string field;              ///< Field or element name, e.g. "material.youngs_modulus".

  /// "file:line:column: field" with the missing parts left out.
  [[nodiscard]] std::string ToString() const;
};

/// Thrown for bad input. `what()` is "<source>: <message>".
class InputError : public std::runtime_error {
 public:
  InputError(SourceRef source, std::string_view message);

  [[nodiscard]] const SourceRef& source() const { return source_; }
  [[nodiscard]] const std::string& message() const { return message_; }

 private:
  SourceRef source_;
  std::string message_;
};

/// Convenience constructors.
[[noreturn]] void ThrowInputError(SourceRef source, std::string_view message);
[[noreturn]] void ThrowFileError(std::string_view file, std::string_view message);

/// Aborts with file/line and a message; for invariants that only a bug breaks.
[[noreturn]] void AbortInvariant(const char* condition, const char* file, int line,
                                 std::string_view message);

}  // namespace cutsim

/// Checks an internal invariant in every build type (not an input check).
#define CUTSIM_CHECK(cond, msg)                                   \
  do {                                                            \
    if (!(cond)) [[unlikely]] {                                   \
      ::cutsim::AbortInvariant(#cond, __FILE__, __LINE__, (msg)); \
    }                                                             \
  } while (false)
