// Flags declared per mode: a flag given in a mode where it does nothing is
// refused by name, one given where it acts is not, and an option that
// declares no modes is a programming error.
#include <optional>
#include <string>
#include <vector>

#include <CLI/CLI.hpp>
#include <gtest/gtest.h>

#include "common/cli/flag_modes.h"

namespace cutsim::cli {
namespace {

constexpr ModeSet kLive = 1U << 0;
constexpr ModeSet kBatch = 1U << 1;

struct Parsed {
  std::optional<std::string> live;   // the refusal in mode 0
  std::optional<std::string> batch;  // the refusal in mode 1
};

Parsed Parse(std::vector<std::string> args) {
  CLI::App app{"test"};
  FlagModes modes({"a live session", "--batch"});
  std::string name;
  bool quiet = false;
  double rate = 0;
  modes.Declare(app.add_option("--name", name), modes.all());
  modes.Declare(app.add_flag("!--no-quiet", quiet), kBatch);
  modes.Declare(app.add_option("--rate", rate), kLive);
  std::vector<std::string> reversed(args.rbegin(), args.rend());
  app.parse(reversed);
  return {modes.Refusal(app, 0), modes.Refusal(app, 1)};
}

TEST(FlagModesTest, AFlagGivenWhereItDoesNothingIsRefusedByName) {
  const Parsed rate = Parse({"--rate", "5"});
  EXPECT_EQ(rate.live, std::nullopt);
  ASSERT_TRUE(rate.batch.has_value());
  EXPECT_EQ(*rate.batch, "--rate: does nothing in --batch (it acts in a live session): drop it");
  const Parsed quiet = Parse({"--no-quiet"});
  ASSERT_TRUE(quiet.live.has_value());
  EXPECT_NE(quiet.live->find("--no-quiet: does nothing in a live session (it acts in --batch)"), std::string::npos)
      << *quiet.live;
  EXPECT_EQ(quiet.batch, std::nullopt);
}

TEST(FlagModesTest, FlagsOfEveryModeAndFlagsNotGivenPass) {
  const Parsed none = Parse({"--name", "x"});
  EXPECT_EQ(none.live, std::nullopt);
  EXPECT_EQ(none.batch, std::nullopt);
}

TEST(FlagModesTest, DeclareRestCoversWhatIsLeft) {
  CLI::App app{"test"};
  FlagModes modes({"a", "b"});
  int x = 0, y = 0;
  modes.Declare(app.add_option("--x", x), kLive);
  app.add_option("--y", y);
  modes.DeclareRest(app, kBatch);
  app.parse(std::vector<std::string>{"1", "--y"});
  ASSERT_TRUE(modes.Refusal(app, 0).has_value());
  EXPECT_EQ(modes.Refusal(app, 0)->rfind("--y:", 0), 0u);
  EXPECT_EQ(modes.Refusal(app, 1), std::nullopt);
}

TEST(FlagModesDeathTest, AnOptionWithoutModesIsAProgrammingError) {
  EXPECT_DEATH(
      {
        CLI::App app{"test"};
        FlagModes modes({"a", "b"});
        int x = 0;
        app.add_option("--x", x);
        app.parse(std::vector<std::string>{});
        (void)modes.Refusal(app, 0);
      },
      "--x declares no modes");
}

}  // namespace
}  // namespace cutsim::cli
