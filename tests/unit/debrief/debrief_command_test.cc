// The debrief's control language: every command parses, and every bad line
// is refused naming its field.
#include "common/debrief/debrief_command.h"

#include <string>

#include <gtest/gtest.h>

namespace cutsim::debrief {
namespace {

TEST(DebriefCommandTest, ParsesEveryCommand) {
  EXPECT_EQ(ParseDebriefCommand("play").command->action, DebriefAction::kPlay);
  EXPECT_EQ(ParseDebriefCommand("pause\n").command->action, DebriefAction::kPause);
  EXPECT_EQ(ParseDebriefCommand("next\r\n").command->action, DebriefAction::kNextStep);
  EXPECT_EQ(ParseDebriefCommand("prev").command->action, DebriefAction::kPreviousStep);
  const CommandParse seek = ParseDebriefCommand("seek 12.5");
  ASSERT_TRUE(seek.command);
  EXPECT_EQ(seek.command->action, DebriefAction::kSeek);
  EXPECT_DOUBLE_EQ(seek.command->time, 12.5);
  const CommandParse speed = ParseDebriefCommand("speed 0.25");
  ASSERT_TRUE(speed.command);
  EXPECT_DOUBLE_EQ(speed.command->speed, 0.25);
  for (const char* line : {"play", "pause", "next", "prev", "seek 3.250000", "speed 2"}) {
    const CommandParse p = ParseDebriefCommand(line);
    ASSERT_TRUE(p.command) << line;
    EXPECT_EQ(FormatDebriefCommand(*p.command), line);
  }
}

TEST(DebriefCommandTest, RefusesByField) {
  const struct {
    std::string line;
    const char* field;
  } kCases[] = {
      {"", "command"},
      {"jump 3", "action"},
      {"PLAY", "action"},
      {"play now", "command"},
      {"seek", "time"},
      {"seek 1 2", "time"},
      {"seek nan", "time"},
      {"seek inf", "time"},
      {"seek 0x10", "time"},
      {"seek -1", "time"},
      {"seek 1e300", "time"},
      {"seek 1e400", "time"},
      {"speed 0", "factor"},
      {"speed 100", "factor"},
      {"speed fast", "factor"},
      {" play", "command"},
      {"seek  2", "command"},
      {std::string("play\0", 5), "command"},
      {"seek \xff", "command"},
      {std::string(200, 'a'), "command"},
  };
  for (const auto& c : kCases) {
    const CommandParse p = ParseDebriefCommand(c.line);
    EXPECT_FALSE(p.command) << c.line;
    EXPECT_EQ(p.field, c.field) << c.line << ": " << p.error;
    EXPECT_FALSE(p.error.empty()) << c.line;
  }
}

}  // namespace
}  // namespace cutsim::debrief
