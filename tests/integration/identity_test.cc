// One server per session, and viewers that only believe it. Real processes
// inside a private network namespace (deploy/netns-run.sh):
//  * a second cutsim-server on a served session refuses to run, naming the
//    first, and the first says a second one tried;
//  * a keyed viewer watching a keyed server while a forger publishes the
//    same session's frames (signed with a wrong key, and unsigned, each from
//    a newer "server" with high sequence numbers) shows only the server's
//    frames and counts every forged one.
#include <chrono>
#include <csignal>
#include <filesystem>
#include <fstream>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "tests/integration/subprocess.h"

namespace cutsim {
namespace {

using namespace std::chrono_literals;
using testing::BinPath;
using testing::JsonNumber;
using testing::ReadTextFile;
using testing::Subprocess;
using testing::TempDir;
using testing::UniqueTestIndex;
using testing::WaitUntil;

constexpr char kKeyHex[] = "5a1c2e3d4a5b6c7d8e9fa0b1c2d3e4f5061728394a5b6c7d8e9fa0b1c2d3e4f5";
constexpr char kWrongKeyHex[] = "ffeeddccbbaa99887766554433221100ffeeddccbbaa99887766554433221100";

struct Lab {
  TempDir dir{"cutsim-identity"};
  int k = UniqueTestIndex();
  std::string session = "id" + std::to_string(k);
  std::string lcm = "udpm://239.255.76.67:" + std::to_string(7300 + k) + "?ttl=0";
  std::string domain = std::to_string(1 + k % 200);
  std::string scene = std::string(CUTSIM_SOURCE_DIR) + "/scenes/ligament.pbtxt";
  std::string key = dir.path() + "/session.key";
  std::string wrong_key = dir.path() + "/wrong.key";

  Lab() {
    std::ofstream(key) << kKeyHex << "\n";
    std::ofstream(wrong_key) << kWrongKeyHex << "\n";
  }
  std::vector<std::string> Server(const std::string& stats) const {
    return {BinPath("cutsim-server"), "--scene", scene, "--session", session, "--lcm-url", lcm,
            "--dds-domain", domain, "--key-file", key, "--stats-json", dir.path() + "/" + stats,
            "--no-rt"};
  }
};

bool Running(const Subprocess& server) {
  return server.Stderr().find("physics") != std::string::npos;
}

// The server has ignored a server message of its session that failed the
// check (server_presence.cc logs the first).
bool IgnoredAServerMessage(const Subprocess& server) {
  return server.Stderr().find("server message that failed its check") != std::string::npos;
}

TEST(IdentityTest, ASecondServerOnTheSessionIsRefusedAndBothSaySo) {
  Lab s;
  Subprocess first(s.Server("first.json"));
  ASSERT_TRUE(WaitUntil([&] { return Running(first); }, 30s, 50ms)) << first.Stderr();

  Subprocess second(s.Server("second.json"));
  const auto code = second.Wait(30s);
  ASSERT_TRUE(code.has_value()) << "the second server kept running\n" << second.Stderr();
  EXPECT_EQ(*code, 6) << second.Stderr();
  EXPECT_NE(second.Stderr().find("already served by cutsim-server pid " + std::to_string(first.pid())),
            std::string::npos)
      << second.Stderr();
  EXPECT_FALSE(std::filesystem::exists(s.dir.path() + "/second.json"));
  ASSERT_TRUE(WaitUntil([&] { return first.Stderr().find("a second server") != std::string::npos; }, 10s,
                        50ms))
      << first.Stderr();

  // A server with another session key is another session to the first: it
  // cannot make the first give way, nor be stopped by it.
  std::vector<std::string> other = s.Server("other.json");
  for (size_t i = 0; i < other.size(); ++i) {
    if (other[i] == s.key) other[i] = s.wrong_key;
  }
  Subprocess outsider(other);
  ASSERT_TRUE(WaitUntil([&] { return Running(outsider); }, 30s, 50ms)) << outsider.Stderr();
  // Each has heard the other (the outsider's probe, the first's
  // announcements) and ignored it: neither gives way.
  ASSERT_TRUE(WaitUntil([&] { return IgnoredAServerMessage(outsider); }, 30s, 50ms)) << outsider.Stderr();
  ASSERT_TRUE(WaitUntil([&] { return IgnoredAServerMessage(first); }, 30s, 50ms)) << first.Stderr();
  outsider.Signal(SIGTERM);
  EXPECT_EQ(outsider.Wait(30s), std::optional<int>(0)) << outsider.Stderr();

  first.Signal(SIGTERM);
  ASSERT_EQ(first.Wait(30s), std::optional<int>(0)) << first.Stderr();
}

TEST(IdentityTest, ForgedObserverFramesAreRefused) {
  Lab s;
  Subprocess server(s.Server("server.json"));
  ASSERT_TRUE(WaitUntil([&] { return Running(server); }, 30s, 50ms)) << server.Stderr();
  const std::string summary = s.dir.path() + "/viewer.json";
  Subprocess viewer({BinPath("cutsim-viewer"), "--session", s.session, "--dds-domain", s.domain,
                     "--key-file", s.key, "--duration", "8", "--fps", "5", "--summary", summary});
  // The forgers start once the viewer follows the real server.
  ASSERT_TRUE(WaitUntil([&] { return viewer.Stderr().find("first verified frame") != std::string::npos; }, 30s,
                        50ms))
      << viewer.Stderr();
  // Two forgers of the same session, each a newer "server" (started later)
  // whose sequence numbers start at its start time in ms: one signs with a
  // wrong key, one does not sign.
  Subprocess forger_keyed({BinPath("cutsim-fake-mesh-server"), "--session", s.session, "--dds-domain",
                           s.domain, "--key-file", s.wrong_key, "--duration", "5", "--rate", "20"});
  Subprocess forger_open({BinPath("cutsim-fake-mesh-server"), "--session", s.session, "--dds-domain",
                          s.domain, "--duration", "5", "--rate", "20"});
  ASSERT_EQ(forger_keyed.Wait(30s), std::optional<int>(0)) << forger_keyed.Stderr();
  ASSERT_EQ(forger_open.Wait(30s), std::optional<int>(0)) << forger_open.Stderr();
  ASSERT_EQ(viewer.Wait(60s), std::optional<int>(0)) << viewer.Stderr();
  server.Signal(SIGTERM);
  ASSERT_EQ(server.Wait(30s), std::optional<int>(0)) << server.Stderr();

  const std::string v = ReadTextFile(summary);
  EXPECT_GT(JsonNumber(v, "frames"), 5) << v;
  EXPECT_GT(JsonNumber(v, "forged"), 10) << v;
  EXPECT_GT(JsonNumber(v, "unsigned_samples"), 10) << v;
  EXPECT_EQ(JsonNumber(v, "server_changes"), 0) << v;
  EXPECT_EQ(JsonNumber(v, "hash_mismatches"), 0) << v;
  EXPECT_EQ(JsonNumber(v, "resyncs"), 0) << v;
}

}  // namespace
}  // namespace cutsim
