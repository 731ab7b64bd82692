#pragma once
/// @file
/// The `--device-arg` string of the shipped plugins: comma-separated
/// `key=value` items. Parsed once in `open` (never in the loop); every error
/// names the plugin, the key and the value.

#include <cstdint>
#include <map>
#include <optional>
#include <stdexcept>
#include <string>
#include <vector>

namespace cutsim::device_plugins {

/// A bad `--device-arg`; `what()` names the plugin and the key.
class ConfigError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

class PluginConfig {
 public:
  /// Parses `text`; throws `ConfigError` for an item without '=' or a
  /// repeated key. `plugin` prefixes every message.
  PluginConfig(const std::string& plugin, const std::string& text);

  /// The value of `key` or `fallback`; throws for a non-number.
  [[nodiscard]] double Number(const std::string& key, double fallback);
  /// The same, also checking lo ≤ value ≤ hi.
  [[nodiscard]] double Number(const std::string& key, double fallback, double lo, double hi);
  [[nodiscard]] std::string String(const std::string& key, const std::string& fallback);
  /// A ':'-separated list of integers (e.g. "288:289"), or `fallback`.
  [[nodiscard]] std::vector<int> Integers(const std::string& key, const std::vector<int>& fallback);
  /// Throws naming any key no `Number`/`String`/`Integers` call asked for.
  void RejectUnknown(const std::string& known) const;

 private:
  std::string plugin_;
  std::map<std::string, std::string> values_;
  std::map<std::string, bool> used_;
};

}  // namespace cutsim::device_plugins
