#include "haptic_client/plugins/common/plugin_config.h"

#include <cerrno>
#include <cmath>
#include <cstdlib>
#include <sstream>

namespace cutsim::device_plugins {

PluginConfig::PluginConfig(const std::string& plugin, const std::string& text) : plugin_(plugin) {
  std::stringstream ss(text);
  std::string item;
  while (std::getline(ss, item, ',')) {
    if (item.empty()) continue;
    const size_t eq = item.find('=');
    if (eq == std::string::npos || eq == 0) {
      throw ConfigError(plugin_ + ": --device-arg item \"" + item + "\" is not key=value");
    }
    const std::string key = item.substr(0, eq);
    if (values_.contains(key)) throw ConfigError(plugin_ + ": --device-arg key \"" + key + "\" is given twice");
    values_[key] = item.substr(eq + 1);
  }
}

double PluginConfig::Number(const std::string& key, double fallback) {
  used_[key] = true;
  const auto it = values_.find(key);
  if (it == values_.end()) return fallback;
  const char* s = it->second.c_str();
  char* end = nullptr;
  errno = 0;
  const double v = std::strtod(s, &end);
  if (end == s || *end != '\0' || errno != 0 || !std::isfinite(v)) {
    throw ConfigError(plugin_ + ": --device-arg " + key + "=\"" + it->second + "\" is not a finite number");
  }
  return v;
}

double PluginConfig::Number(const std::string& key, double fallback, double lo, double hi) {
  const double v = Number(key, fallback);
  if (!(v >= lo && v <= hi)) {
    std::ostringstream m;
    m << plugin_ << ": --device-arg " << key << "=" << v << " is out of range [" << lo << ", " << hi << "]";
    throw ConfigError(m.str());
  }
  return v;
}

std::string PluginConfig::String(const std::string& key, const std::string& fallback) {
  used_[key] = true;
  const auto it = values_.find(key);
  return it == values_.end() ? fallback : it->second;
}

std::vector<int> PluginConfig::Integers(const std::string& key, const std::vector<int>& fallback) {
  used_[key] = true;
  const auto it = values_.find(key);
  if (it == values_.end()) return fallback;
  std::vector<int> out;
  std::stringstream ss(it->second);
  std::string item;
  while (std::getline(ss, item, ':')) {
    char* end = nullptr;
    const long v = std::strtol(item.c_str(), &end, 0);
    if (item.empty() || *end != '\0' || v < 0 || v > 0xffff) {
      throw ConfigError(plugin_ + ": --device-arg " + key + "=\"" + it->second +
                        "\" is not a ':'-separated list of codes 0..65535");
    }
    out.push_back(static_cast<int>(v));
  }
  return out;
}

void PluginConfig::RejectUnknown(const std::string& known) const {
  for (const auto& [key, value] : values_) {
    if (!used_.contains(key)) {
      throw ConfigError(plugin_ + ": unknown --device-arg key \"" + key + "\" (known: " + known + ")");
    }
  }
}

}  // namespace cutsim::device_plugins
