// The station's and the viewer's flags that act only with some devices or
// with --serve or --lab: given elsewhere they are refused before anything starts,
// naming the flag, the mode and where the flag acts (exit 2). The server's
// are in server_headless_test.cc.
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "tests/integration/subprocess.h"

namespace cutsim {
namespace {

using testing::BinPath;
using testing::RunProcess;
using namespace std::chrono_literals;

struct Case {
  std::vector<std::string> args;
  std::string refusal;  // the start of the message
};

void ExpectRefused(const std::string& binary, const std::vector<Case>& cases) {
  for (const Case& c : cases) {
    std::vector<std::string> args = {BinPath(binary)};
    args.insert(args.end(), c.args.begin(), c.args.end());
    const auto r = RunProcess(args, 30s);
    EXPECT_EQ(r.exit_code, 2) << c.refusal << ": " << r.err;
    EXPECT_NE(r.err.find(c.refusal), std::string::npos) << r.err;
  }
}

TEST(AppFlagModesTest, StationFlagsOfAnotherDeviceAreRefused) {
  ExpectRefused("cutsim-haptic",
                {
                    {{"--device", "scripted", "--path", "p.path", "--serve", "127.0.0.1:1"},
                     "--serve: does nothing in --device scripted (it acts in --device browser)"},
                    {{"--device", "scripted", "--path", "p.path", "--device-arg", "x=1"},
                     "--device-arg: does nothing in --device scripted (it acts in a device plugin)"},
                    {{"--device", "replay", "--log", "r.lcm", "--path", "p.path"},
                     "--path: does nothing in --device replay (it acts in --device scripted)"},
                    {{"--device", "example_spring", "--log", "r.lcm"},
                     "--log: does nothing in a device plugin (it acts in --device replay)"},
                    {{"--device", "browser", "--log-channel", "C"},
                     "--log-channel: does nothing in --device browser"},
                    {{"--device", "example_spring", "--no-page-view"},
                     "--no-page-view: does nothing in a device plugin"},
                });
}

TEST(AppFlagModesTest, ViewerPageFlagsWithoutServeAreRefused) {
  ExpectRefused("cutsim-viewer", {
                                     {{"--token-file", "t"}, "--token-file: does nothing in a viewer without --serve"},
                                     {{"--host-name", "lab"}, "--host-name: does nothing in a viewer without --serve"},
                                     {{"--web-root", "w"}, "--web-root: does nothing in a viewer without --serve"},
                                     {{"--lab-root", "w"}, "--lab-root: does nothing in a viewer without --serve"},
                                     {{"--serve", "127.0.0.1:0", "--lab-root", "w"},
                                      "--lab-root: does nothing in --serve (it acts in --lab)"},
                                     {{"--serve", "127.0.0.1:0", "--lab", "127.0.0.1:0"},
                                      "--serve watches one session and --lab every session"},
                                 });
}

}  // namespace
}  // namespace cutsim
