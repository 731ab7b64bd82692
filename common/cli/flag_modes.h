#pragma once
/// @file
/// Flags that act only in some of an application's modes. Every option an
/// application adds declares the modes it acts in; after parsing, a flag
/// given in a mode where it does nothing is refused, naming the flag, the
/// mode, and where it does act. An option added without a declaration is a
/// programming error, caught the first time the parser runs, so a new flag
/// cannot forget to say where it acts.

#include <cstdint>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include <CLI/CLI.hpp>

namespace cutsim::cli {

/// A set of modes: bit i is the i-th mode given to FlagModes.
using ModeSet = uint32_t;

class FlagModes {
 public:
  /// `mode_names`: each mode as the error names it, e.g. "a real-time
  /// session" or "--headless --replay" (at most 32).
  explicit FlagModes(std::vector<std::string> mode_names);

  /// Every mode.
  [[nodiscard]] ModeSet all() const;

  /// Declares that `option` acts in `modes`; returns `option` (for
  /// chaining).
  CLI::Option* Declare(CLI::Option* option, ModeSet modes);

  /// Declares that every option of `app` not yet declared acts in `modes`
  /// (for a group of options added by a shared helper).
  void DeclareRest(const CLI::App& app, ModeSet modes);

  /// After `app` parsed the command line, running in mode `mode` (an index
  /// into the names): the message refusing the first flag given that does
  /// nothing in that mode, or nullopt. Aborts (CUTSIM_CHECK) when an option
  /// of `app` other than --help has no declared modes.
  [[nodiscard]] std::optional<std::string> Refusal(const CLI::App& app, int mode) const;

 private:
  std::vector<std::string> mode_names_;
  /// The modes declared for `option` (0: none).
  [[nodiscard]] ModeSet ModesOf(const CLI::Option* option) const;

  std::vector<std::pair<const CLI::Option*, ModeSet>> declared_;
};

}  // namespace cutsim::cli
