#pragma once
/// @file
/// The debrief's control language, one command a line, shared by the
/// server's standard input and the instructor's page (whose messages the
/// browser bridge checks with the same parser before they go anywhere):
///
///   play            play at the current speed
///   pause           hold the picture
///   seek T          show the recording at T seconds
///   next            go to the next cut step (the end of the frame that cut)
///   prev            go to the previous cut step
///   speed F         play at F × real time (0.05 to 8)
///
/// Every line is hostile until parsed: at most kMaxCommandBytes, ASCII
/// words separated by single spaces, numbers finite and in range. A refusal
/// names the field ("action", "time", "factor" or "command") and why.

#include <cstddef>
#include <optional>
#include <string>
#include <string_view>

namespace cutsim::debrief {

enum class DebriefAction { kPlay, kPause, kSeek, kNextStep, kPreviousStep, kSpeed };

/// Slowest and fastest play, × real time.
inline constexpr double kMinSpeed = 0.05;
inline constexpr double kMaxSpeed = 8.0;
/// Longest command line, bytes.
inline constexpr size_t kMaxCommandBytes = 64;
/// Latest time a seek may name, s (a day; the player clamps to the recording).
inline constexpr double kMaxSeekSeconds = 86400.0;

/// One checked command.
struct DebriefCommand {
  DebriefAction action = DebriefAction::kPause;
  double time = 0.0;   ///< s, for kSeek
  double speed = 1.0;  ///< × real time, for kSpeed
};

/// A parse: the command, or the field at fault and why.
struct CommandParse {
  std::optional<DebriefCommand> command;
  std::string field;  ///< "command", "action", "time" or "factor" when refused
  std::string error;  ///< why, for the person who typed it
};

/// Parses one line (a trailing '\n' or "\r\n" is ignored).
[[nodiscard]] CommandParse ParseDebriefCommand(std::string_view line);

/// The command's word ("play", "seek", …).
[[nodiscard]] const char* ActionName(DebriefAction action);

/// The command as a line ParseDebriefCommand reads back (without '\n').
[[nodiscard]] std::string FormatDebriefCommand(const DebriefCommand& command);

}  // namespace cutsim::debrief
