#include "common/debrief/debrief_command.h"

#include <charconv>
#include <cmath>
#include <vector>

#include <fmt/format.h>

namespace cutsim::debrief {
namespace {

CommandParse Refuse(std::string field, std::string error) {
  return {.command = std::nullopt, .field = std::move(field), .error = std::move(error)};
}

/// A decimal number: digits, one '.', an optional sign and exponent; no
/// "nan", "inf" or hex (from_chars would take them).
std::optional<double> ParseNumber(std::string_view text) {
  if (text.empty() || text.size() > 24) return std::nullopt;
  for (const char c : text) {
    if (!((c >= '0' && c <= '9') || c == '.' || c == '-' || c == '+' || c == 'e' || c == 'E')) return std::nullopt;
  }
  double value = 0.0;
  const auto [end, ec] = std::from_chars(text.data(), text.data() + text.size(), value);
  if (ec != std::errc() || end != text.data() + text.size() || !std::isfinite(value)) return std::nullopt;
  return value;
}

}  // namespace

const char* ActionName(DebriefAction action) {
  switch (action) {
    case DebriefAction::kPlay:
      return "play";
    case DebriefAction::kPause:
      return "pause";
    case DebriefAction::kSeek:
      return "seek";
    case DebriefAction::kNextStep:
      return "next";
    case DebriefAction::kPreviousStep:
      return "prev";
    case DebriefAction::kSpeed:
      return "speed";
  }
  return "?";
}

CommandParse ParseDebriefCommand(std::string_view line) {
  if (line.size() > kMaxCommandBytes + 2) {
    return Refuse("command", fmt::format("longer than {} bytes", kMaxCommandBytes));
  }
  if (line.ends_with('\n')) line.remove_suffix(1);
  if (line.ends_with('\r')) line.remove_suffix(1);
  if (line.size() > kMaxCommandBytes) return Refuse("command", fmt::format("longer than {} bytes", kMaxCommandBytes));
  for (const char c : line) {
    if (c < 0x20 || c > 0x7e) return Refuse("command", "only printable ASCII is allowed");
  }
  std::vector<std::string_view> words;
  size_t start = 0;
  while (start <= line.size()) {
    const size_t space = line.find(' ', start);
    const size_t end = space == std::string_view::npos ? line.size() : space;
    words.push_back(line.substr(start, end - start));
    if (space == std::string_view::npos) break;
    start = space + 1;
  }
  for (const std::string_view w : words) {
    if (w.empty()) return Refuse("command", "words are separated by one space, with none before or after");
  }
  const std::string_view word = words.front();
  struct Known {
    std::string_view name;
    DebriefAction action;
    const char* argument;  // null: none
  };
  static constexpr Known kKnown[] = {{"play", DebriefAction::kPlay, nullptr},
                                     {"pause", DebriefAction::kPause, nullptr},
                                     {"seek", DebriefAction::kSeek, "time"},
                                     {"next", DebriefAction::kNextStep, nullptr},
                                     {"prev", DebriefAction::kPreviousStep, nullptr},
                                     {"speed", DebriefAction::kSpeed, "factor"}};
  const Known* known = nullptr;
  for (const Known& k : kKnown) {
    if (k.name == word) known = &k;
  }
  if (known == nullptr) {
    return Refuse("action", fmt::format("'{}' is not one of play, pause, seek, next, prev, speed",
                                        word.substr(0, 16)));
  }
  const size_t wanted = known->argument ? 2 : 1;
  if (words.size() != wanted) {
    return Refuse(known->argument ? known->argument : "command",
                  known->argument ? fmt::format("{} takes one number, its {}", known->name, known->argument)
                                  : fmt::format("{} takes nothing after it", known->name));
  }
  DebriefCommand command{.action = known->action};
  if (known->argument) {
    const auto value = ParseNumber(words[1]);
    if (!value) {
      return Refuse(known->argument, fmt::format("'{}' is not a finite decimal number", words[1].substr(0, 24)));
    }
    if (command.action == DebriefAction::kSeek) {
      if (*value < 0.0 || *value > kMaxSeekSeconds) {
        return Refuse("time", fmt::format("{:g} s is outside [0, {:g}] s", *value, kMaxSeekSeconds));
      }
      command.time = *value;
    } else {
      if (*value < kMinSpeed || *value > kMaxSpeed) {
        return Refuse("factor", fmt::format("{:g} is outside [{:g}, {:g}]", *value, kMinSpeed, kMaxSpeed));
      }
      command.speed = *value;
    }
  }
  return {.command = command, .field = {}, .error = {}};
}

std::string FormatDebriefCommand(const DebriefCommand& command) {
  switch (command.action) {
    case DebriefAction::kSeek:
      return fmt::format("seek {:.6f}", command.time);
    case DebriefAction::kSpeed:
      return fmt::format("speed {:.6g}", command.speed);
    default:
      return ActionName(command.action);
  }
}

}  // namespace cutsim::debrief
