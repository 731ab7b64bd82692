// The server appends each finished session's score to the lab's history
// (--history FILE --trainee NAME), and a bad history never stops a session:
// a corrupt file, one of another schema version and one locked by another
// writer are logged naming the file, the session ends normally with its
// score in the summary, and the file is left as it was.

#include <signal.h>
#include <sqlite3.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <string>
#include <utility>
#include <vector>

#include <gtest/gtest.h>

#include "common/record/score_history.h"
#include "tests/integration/subprocess.h"

namespace cutsim {
namespace {

using namespace std::chrono_literals;
using testing::BinPath;
using testing::JsonNumber;
using testing::RunProcess;
using testing::TempDir;

/// The shipped ligament, headless, for `duration` simulated seconds (its
/// scripted blade severs it at about 2 s), one thread.
testing::RunResult RunLigament(const std::vector<std::string>& flags, const std::string& duration = "2.0") {
  std::vector<std::string> argv = {BinPath("cutsim-server"), "--headless", "--scene",
                                   std::string(CUTSIM_SOURCE_DIR) + "/scenes/ligament.pbtxt",
                                   "--duration", duration, "--no-progress", "--threads", "1"};
  argv.insert(argv.end(), flags.begin(), flags.end());
  return RunProcess(argv, 300s);
}

std::string FileBytes(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  return {std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
}

void RawExec(const std::string& path, const char* sql) {
  sqlite3* db = nullptr;
  ASSERT_EQ(sqlite3_open(path.c_str(), &db), SQLITE_OK);
  ASSERT_EQ(sqlite3_exec(db, sql, nullptr, nullptr, nullptr), SQLITE_OK) << sqlite3_errmsg(db);
  sqlite3_close(db);
}

TEST(HistoryTest, EachFinishedSessionIsAppendedForItsTrainee) {
  TempDir dir;
  const std::string db = dir.path() + "/lab.sqlite";
  const auto first = RunLigament({"--history", db, "--trainee", "alice", "--session", "bench1"});
  ASSERT_EQ(first.exit_code, 0) << first.err;
  const auto second = RunLigament({"--history", db, "--trainee", "alice", "--session", "bench1"}, "1.6");
  ASSERT_EQ(second.exit_code, 0) << second.err;
  const auto other = RunLigament({"--history", db, "--trainee", "bob"}, "0.6");
  ASSERT_EQ(other.exit_code, 0) << other.err;

  const record::ScoreHistory history = record::ScoreHistory::Open(db);
  EXPECT_EQ(history.size(), 3);
  const auto alice = history.ForTrainee("alice");
  ASSERT_EQ(alice.size(), 2u);
  // The same score as the session's summary, to the digits JSON prints.
  EXPECT_EQ(alice[0].session, "bench1");
  EXPECT_EQ(alice[0].scene, "ligament");
  EXPECT_NEAR(alice[0].duration, 2.0, 1e-9);
  EXPECT_NEAR(alice[1].duration, 1.6, 1e-9);
  for (const auto& [entry, run] : {std::pair{alice[0], first}, std::pair{alice[1], second}}) {
    const double scale = std::max(1e-12, std::abs(JsonNumber(run.out, "mean_deviation")));
    EXPECT_NEAR(entry.mean_deviation, JsonNumber(run.out, "mean_deviation"), 1e-9 * scale) << run.out;
    EXPECT_NEAR(entry.peak_force, JsonNumber(run.out, "peak_force"), 1e-9 * JsonNumber(run.out, "peak_force"));
    EXPECT_EQ(entry.cuts, static_cast<int64_t>(JsonNumber(run.out, "cuts")));
  }
  EXPECT_GT(alice[0].cuts, 0) << "the blade did not cut within 2 s";
  EXPECT_GT(alice[0].peak_force, 0.0);
  EXPECT_EQ(history.ForTrainee("bob").size(), 1u);
}

/// A session against a bad history: it ends normally (exit 0) with its
/// score in the summary, logs an error naming the file and `why`, and leaves
/// the file's bytes as they were.
void ExpectSessionUnharmed(const std::string& db, const std::string& why) {
  const std::string before = FileBytes(db);
  const auto r = RunLigament({"--history", db, "--trainee", "alice"}, "0.6");
  EXPECT_EQ(r.exit_code, 0) << r.err;
  EXPECT_NE(r.out.find("\"score\""), std::string::npos) << r.out;
  EXPECT_NE(r.err.find(db), std::string::npos) << r.err;
  EXPECT_NE(r.err.find(why), std::string::npos) << r.err;
  EXPECT_NE(r.err.find("NOT in the history"), std::string::npos) << r.err;
  EXPECT_EQ(FileBytes(db), before) << "the server changed a history it could not use";
}

TEST(HistoryTest, ACorruptHistoryNeverStopsTheSession) {
  TempDir dir;
  const std::string db = dir.path() + "/lab.sqlite";
  std::ofstream(db) << std::string(8192, '\x5a');
  ExpectSessionUnharmed(db, "not an SQLite database");
}

TEST(HistoryTest, AHistoryOfAnotherSchemaVersionIsRefusedByName) {
  TempDir dir;
  const std::string db = dir.path() + "/lab.sqlite";
  RawExec(db, "CREATE TABLE sessions (id INTEGER PRIMARY KEY); PRAGMA user_version = 9;");
  ExpectSessionUnharmed(db, "schema version 9");
}

/// Another process holding the history's write lock (BEGIN EXCLUSIVE) from
/// construction until destruction. A process of its own: POSIX locks are
/// per process, and this one reads the file while the lock is held.
class LockHolder {
 public:
  explicit LockHolder(const std::string& path) {
    int ready[2];
    if (::pipe(ready) != 0) return;
    pid_ = ::fork();
    if (pid_ == 0) {
      sqlite3* db = nullptr;
      if (sqlite3_open(path.c_str(), &db) != SQLITE_OK) ::_exit(10);
      if (sqlite3_exec(db, "BEGIN EXCLUSIVE", nullptr, nullptr, nullptr) != SQLITE_OK) ::_exit(11);
      const char byte = 1;
      if (::write(ready[1], &byte, 1) != 1) ::_exit(12);
      ::pause();
      ::_exit(0);
    }
    ::close(ready[1]);
    char byte = 0;
    locked_ = pid_ > 0 && ::read(ready[0], &byte, 1) == 1;
    ::close(ready[0]);
  }
  ~LockHolder() {
    if (pid_ <= 0) return;
    ::kill(pid_, SIGKILL);
    ::waitpid(pid_, nullptr, 0);
  }
  LockHolder(const LockHolder&) = delete;
  LockHolder& operator=(const LockHolder&) = delete;
  [[nodiscard]] bool locked() const { return locked_; }

 private:
  pid_t pid_ = -1;
  bool locked_ = false;
};

TEST(HistoryTest, ALockedHistoryNeverStopsTheSession) {
  TempDir dir;
  const std::string db = dir.path() + "/lab.sqlite";
  (void)record::ScoreHistory::Open(db);
  {
    LockHolder holder(db);
    ASSERT_TRUE(holder.locked());
    ExpectSessionUnharmed(db, "locked by another writer");
  }
  EXPECT_EQ(record::ScoreHistory::Open(db).size(), 0);
}

TEST(HistoryTest, FlagsAreCheckedBeforeTheSession) {
  TempDir dir;
  const std::string db = dir.path() + "/lab.sqlite";
  auto r = RunLigament({"--history", db});
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_NE(r.err.find("--trainee"), std::string::npos) << r.err;
  r = RunLigament({"--history", db, "--trainee", "alice smith"});
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_NE(r.err.find("--trainee 'alice smith'"), std::string::npos) << r.err;
  EXPECT_FALSE(std::filesystem::exists(db));
}

}  // namespace
}  // namespace cutsim
