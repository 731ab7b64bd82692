// The lab's score history: entries round-trip per trainee; a file of another
// schema version, not a database, corrupt or locked is refused naming the
// file; a writer killed mid-transaction leaves the history whole.

#include "common/record/score_history.h"

#include <signal.h>
#include <sqlite3.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <cmath>
#include <cstdio>
#include <exception>
#include <filesystem>
#include <fstream>
#include <limits>
#include <string>

#include <gtest/gtest.h>

#include "common/core/error.h"

namespace cutsim::record {
namespace {
namespace fs = std::filesystem;

SessionEntry Entry(const std::string& trainee, int64_t when, double deviation) {
  SessionEntry e;
  e.trainee = trainee;
  e.session = "bench1";
  e.scene = "ligament";
  e.finished_unix_s = when;
  e.duration = 12.5;
  e.cuts = 17;
  e.mean_deviation = deviation;
  e.max_deviation = 2.0 * deviation;
  e.depth_error = -0.0004;
  e.coverage = 0.93;
  e.opened_area_outside = 1.5e-6;
  e.cut_off_volume = 2.5e-9;
  e.max_stress_outside = 3.2e4;
  e.peak_force = 1.75;
  e.mean_force = 0.6;
  e.contact_time = 4.25;
  return e;
}

/// Runs SQL on a raw connection (the test's own writer, outside the class).
void RawExec(const fs::path& path, const std::string& sql) {
  sqlite3* db = nullptr;
  ASSERT_EQ(sqlite3_open(path.c_str(), &db), SQLITE_OK);
  char* error = nullptr;
  const int rc = sqlite3_exec(db, sql.c_str(), nullptr, nullptr, &error);
  const std::string message = error != nullptr ? error : "";
  sqlite3_free(error);
  sqlite3_close(db);
  ASSERT_EQ(rc, SQLITE_OK) << message;
}

class ScoreHistoryTest : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = fs::temp_directory_path() / ("cutsim-history-" + std::to_string(::getpid()) + "-" +
                                        ::testing::UnitTest::GetInstance()->current_test_info()->name());
    fs::remove_all(dir_);
    fs::create_directories(dir_);
    path_ = (dir_ / "lab.sqlite").string();
  }
  void TearDown() override { fs::remove_all(dir_); }

  /// The message of the InputError `f` throws, or "" (a test failure).
  template <typename F>
  std::string ErrorOf(F&& f) {
    try {
      f();
    } catch (const InputError& e) {
      return e.what();
    }
    ADD_FAILURE() << "no InputError";
    return "";
  }

  fs::path dir_;
  std::string path_;
};

TEST_F(ScoreHistoryTest, EntriesRoundTripPerTraineeOldestFirst) {
  {
    ScoreHistory h = ScoreHistory::Open(path_);
    h.Append(Entry("alice", 2000, 0.0012));
    h.Append(Entry("bob", 1500, 0.0030));
    h.Append(Entry("alice", 1000, 0.0021));
    EXPECT_EQ(h.size(), 3);
  }
  const ScoreHistory h = ScoreHistory::Open(path_);  // reopened: durable
  const auto alice = h.ForTrainee("alice");
  ASSERT_EQ(alice.size(), 2u);
  EXPECT_EQ(alice[0].finished_unix_s, 1000);
  EXPECT_EQ(alice[1].finished_unix_s, 2000);
  const SessionEntry want = Entry("alice", 2000, 0.0012);
  const SessionEntry& got = alice[1];
  EXPECT_EQ(got.trainee, want.trainee);
  EXPECT_EQ(got.session, want.session);
  EXPECT_EQ(got.scene, want.scene);
  EXPECT_EQ(got.cuts, want.cuts);
  EXPECT_EQ(got.duration, want.duration);
  EXPECT_EQ(got.mean_deviation, want.mean_deviation);
  EXPECT_EQ(got.max_deviation, want.max_deviation);
  EXPECT_EQ(got.depth_error, want.depth_error);
  EXPECT_EQ(got.coverage, want.coverage);
  EXPECT_EQ(got.opened_area_outside, want.opened_area_outside);
  EXPECT_EQ(got.cut_off_volume, want.cut_off_volume);
  EXPECT_EQ(got.max_stress_outside, want.max_stress_outside);
  EXPECT_EQ(got.peak_force, want.peak_force);
  EXPECT_EQ(got.mean_force, want.mean_force);
  EXPECT_EQ(got.contact_time, want.contact_time);
  EXPECT_EQ(h.ForTrainee("bob").size(), 1u);
  EXPECT_TRUE(h.ForTrainee("carol").empty());
}

TEST_F(ScoreHistoryTest, NewFileCarriesTheSchemaVersion) {
  (void)ScoreHistory::Open(path_);
  sqlite3* db = nullptr;
  ASSERT_EQ(sqlite3_open(path_.c_str(), &db), SQLITE_OK);
  sqlite3_stmt* stmt = nullptr;
  ASSERT_EQ(sqlite3_prepare_v2(db, "PRAGMA user_version", -1, &stmt, nullptr), SQLITE_OK);
  ASSERT_EQ(sqlite3_step(stmt), SQLITE_ROW);
  EXPECT_EQ(sqlite3_column_int(stmt, 0), ScoreHistory::kSchemaVersion);
  sqlite3_finalize(stmt);
  sqlite3_close(db);
}

TEST_F(ScoreHistoryTest, AnotherSchemaVersionIsRefusedNamingIt) {
  RawExec(path_, "CREATE TABLE sessions (id INTEGER PRIMARY KEY, trainee TEXT); PRAGMA user_version = 7;");
  const std::string what = ErrorOf([&] { (void)ScoreHistory::Open(path_); });
  EXPECT_NE(what.find(path_), std::string::npos) << what;
  EXPECT_NE(what.find("schema version 7"), std::string::npos) << what;
  EXPECT_NE(what.find("reads version 1"), std::string::npos) << what;
}

TEST_F(ScoreHistoryTest, ADatabaseOfSomethingElseIsRefused) {
  RawExec(path_, "CREATE TABLE recipes (name TEXT);");  // user_version 0, not empty
  const std::string what = ErrorOf([&] { (void)ScoreHistory::Open(path_); });
  EXPECT_NE(what.find(path_), std::string::npos) << what;
  EXPECT_NE(what.find("schema version 0"), std::string::npos) << what;
}

TEST_F(ScoreHistoryTest, AFileThatIsNoDatabaseIsRefused) {
  std::ofstream(path_) << std::string(4096, 'x');
  const std::string what = ErrorOf([&] { (void)ScoreHistory::Open(path_); });
  EXPECT_NE(what.find(path_), std::string::npos) << what;
  EXPECT_NE(what.find("not an SQLite database"), std::string::npos) << what;
}

TEST_F(ScoreHistoryTest, AFolderIsRefused) {
  fs::create_directories(path_);
  const std::string what = ErrorOf([&] { (void)ScoreHistory::Open(path_); });
  EXPECT_NE(what.find("not a regular file"), std::string::npos) << what;
}

TEST_F(ScoreHistoryTest, ACorruptFileIsRefusedNamingIt) {
  (void)ScoreHistory::Open(path_);
  // 400 sessions in one transaction (400 synced appends take seconds).
  RawExec(path_,
          "WITH RECURSIVE n(i) AS (SELECT 1 UNION ALL SELECT i + 1 FROM n WHERE i < 400) "
          "INSERT INTO sessions (trainee, session, scene, finished_unix_s, duration_s, cuts, mean_deviation_m, "
          "max_deviation_m, depth_error_m, coverage, opened_area_outside_m2, cut_off_volume_m3, "
          "max_stress_outside_pa, peak_force_n, mean_force_n, contact_time_s) "
          "SELECT 'alice', 'bench1', 'ligament', i, 1, 1, 1, 1, 1, 1, 1, 1, 1, 1, 1, 1 FROM n;");
  // Scribble over the pages after the first (the schema's): the table's
  // b-tree pages no longer parse.
  const auto size = fs::file_size(path_);
  ASSERT_GT(size, 4u * 4096u);
  {
    std::fstream f(path_, std::ios::in | std::ios::out | std::ios::binary);
    f.seekp(4096);
    const std::string junk(static_cast<size_t>(size) - 4096, '\x5a');
    f.write(junk.data(), static_cast<std::streamsize>(junk.size()));
  }
  const std::string what = ErrorOf([&] {
    ScoreHistory h = ScoreHistory::Open(path_);
    h.Append(Entry("alice", 9999, 0.001));
  });
  EXPECT_NE(what.find(path_), std::string::npos) << what;
  EXPECT_NE(what.find("corrupt"), std::string::npos) << what;
}

TEST_F(ScoreHistoryTest, ALockHeldByAnotherWriterFailsWithinTheTimeout) {
  ScoreHistory h = ScoreHistory::Open(path_);
  sqlite3* other = nullptr;
  ASSERT_EQ(sqlite3_open(path_.c_str(), &other), SQLITE_OK);
  ASSERT_EQ(sqlite3_exec(other, "BEGIN EXCLUSIVE", nullptr, nullptr, nullptr), SQLITE_OK);
  const auto start = std::chrono::steady_clock::now();
  const std::string what = ErrorOf([&] { h.Append(Entry("alice", 1, 0.001)); });
  const double waited = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  EXPECT_NE(what.find(path_), std::string::npos) << what;
  EXPECT_NE(what.find("locked"), std::string::npos) << what;
  EXPECT_GE(waited, 0.9 * ScoreHistory::kBusyTimeoutMs * 1e-3);
  EXPECT_LT(waited, 3.0 * ScoreHistory::kBusyTimeoutMs * 1e-3);
  // Opening is refused the same way while the lock is held.
  EXPECT_NE(ErrorOf([&] { (void)ScoreHistory::Open(path_); }).find("locked"), std::string::npos);
  ASSERT_EQ(sqlite3_exec(other, "ROLLBACK", nullptr, nullptr, nullptr), SQLITE_OK);
  sqlite3_close(other);
  h.Append(Entry("alice", 2, 0.001));  // released: the same handle writes again
  EXPECT_EQ(h.size(), 1);
}

TEST_F(ScoreHistoryTest, AWriterKilledMidTransactionLeavesTheHistoryWhole) {
  {
    ScoreHistory h = ScoreHistory::Open(path_);
    for (int i = 0; i < 5; ++i) h.Append(Entry("alice", i, 0.001));
  }
  const auto size_before = fs::file_size(path_);
  int ready[2];
  ASSERT_EQ(::pipe(ready), 0);
  const pid_t child = ::fork();
  ASSERT_GE(child, 0);
  if (child == 0) {
    // A writer whose tiny page cache spills uncommitted pages into the file
    // (the journal synced first), killed before it commits.
    sqlite3* db = nullptr;
    if (sqlite3_open(path_.c_str(), &db) != SQLITE_OK) ::_exit(10);
    const char* sql =
        "PRAGMA cache_size = 2; BEGIN IMMEDIATE;"
        "WITH RECURSIVE n(i) AS (SELECT 1 UNION ALL SELECT i + 1 FROM n WHERE i < 3000) "
        "INSERT INTO sessions (trainee, session, scene, finished_unix_s, duration_s, cuts, mean_deviation_m, "
        "max_deviation_m, depth_error_m, coverage, opened_area_outside_m2, cut_off_volume_m3, "
        "max_stress_outside_pa, peak_force_n, mean_force_n, contact_time_s) "
        "SELECT 'mallory', printf('s%0200d', i), 'x', i, 1, 1, 1, 1, 1, 1, 1, 1, 1, 1, 1, 1 FROM n;";
    if (sqlite3_exec(db, sql, nullptr, nullptr, nullptr) != SQLITE_OK) ::_exit(11);
    const char byte = 1;
    if (::write(ready[1], &byte, 1) != 1) ::_exit(12);
    ::pause();
    ::_exit(13);
  }
  ::close(ready[1]);
  char byte = 0;
  ASSERT_EQ(::read(ready[0], &byte, 1), 1) << "the writer did not reach its open transaction";
  ::close(ready[0]);
  ASSERT_EQ(::kill(child, SIGKILL), 0);
  int status = 0;
  ASSERT_EQ(::waitpid(child, &status, 0), child);
  ASSERT_TRUE(WIFSIGNALED(status));
  // The kill left a hot journal and uncommitted pages in the file.
  EXPECT_TRUE(fs::exists(path_ + "-journal"));
  EXPECT_GT(fs::file_size(path_), size_before);

  ScoreHistory h = ScoreHistory::Open(path_);  // rolls the journal back, passes the quick check
  EXPECT_EQ(h.size(), 5);
  EXPECT_TRUE(h.ForTrainee("mallory").empty());
  h.Append(Entry("alice", 99, 0.002));
  EXPECT_EQ(h.ForTrainee("alice").size(), 6u);
  EXPECT_FALSE(fs::exists(path_ + "-journal"));
}

TEST_F(ScoreHistoryTest, SessionsOfALabAppendAtOnce) {
  // Servers of several sessions start together on a new file and append
  // at once: the schema is created once, every append waits its turn.
  constexpr int kWriters = 3;
  constexpr int kEach = 20;
  pid_t pids[kWriters];
  for (int w = 0; w < kWriters; ++w) {
    pids[w] = ::fork();
    ASSERT_GE(pids[w], 0);
    if (pids[w] == 0) {
      try {
        ScoreHistory h = ScoreHistory::Open(path_);
        for (int i = 0; i < kEach; ++i) h.Append(Entry("trainee" + std::to_string(w), i, 0.001 * (i + 1)));
      } catch (const std::exception& e) {
        std::fprintf(stderr, "writer %d: %s\n", w, e.what());
        ::_exit(1);
      }
      ::_exit(0);
    }
  }
  for (const pid_t pid : pids) {
    int status = 0;
    ASSERT_EQ(::waitpid(pid, &status, 0), pid);
    EXPECT_TRUE(WIFEXITED(status) && WEXITSTATUS(status) == 0) << "a writer failed (its error is above)";
  }
  const ScoreHistory h = ScoreHistory::Open(path_);
  EXPECT_EQ(h.size(), kWriters * kEach);
  for (int w = 0; w < kWriters; ++w) EXPECT_EQ(h.ForTrainee("trainee" + std::to_string(w)).size(), size_t{kEach});
}

TEST_F(ScoreHistoryTest, InvalidEntriesAreRefusedNamingTheField) {
  ScoreHistory h = ScoreHistory::Open(path_);
  SessionEntry e = Entry("alice", 1, 0.001);
  e.peak_force = std::numeric_limits<double>::quiet_NaN();
  std::string what = ErrorOf([&] { h.Append(e); });
  EXPECT_NE(what.find("peak_force"), std::string::npos) << what;
  e = Entry("alice; DROP TABLE sessions", 1, 0.001);
  what = ErrorOf([&] { h.Append(e); });
  EXPECT_NE(what.find("trainee"), std::string::npos) << what;
  EXPECT_EQ(h.size(), 0);
}

TEST(TraineeName, Limits) {
  EXPECT_EQ(CheckTraineeName("alice.b_2-x"), "");
  EXPECT_NE(CheckTraineeName(""), "");
  EXPECT_NE(CheckTraineeName(std::string(kMaxTraineeNameBytes + 1, 'a')), "");
  EXPECT_EQ(CheckTraineeName(std::string(kMaxTraineeNameBytes, 'a')), "");
  EXPECT_NE(CheckTraineeName("al ice"), "");
  EXPECT_NE(CheckTraineeName("alice\n"), "");
}

}  // namespace
}  // namespace cutsim::record
