#include "common/record/score_history.h"

#include <sqlite3.h>

#include <cmath>
#include <filesystem>
#include <system_error>
#include <utility>

#include <fmt/format.h>

#include "common/core/error.h"

namespace cutsim::record {
namespace {

// One row per finished session. Columns in SI units, named with them.
constexpr const char* kCreateSchema = R"sql(
CREATE TABLE sessions (
  id INTEGER PRIMARY KEY,
  trainee TEXT NOT NULL,
  session TEXT NOT NULL,
  scene TEXT NOT NULL,
  finished_unix_s INTEGER NOT NULL,
  duration_s REAL NOT NULL,
  cuts INTEGER NOT NULL,
  mean_deviation_m REAL NOT NULL,
  max_deviation_m REAL NOT NULL,
  depth_error_m REAL NOT NULL,
  coverage REAL NOT NULL,
  opened_area_outside_m2 REAL NOT NULL,
  cut_off_volume_m3 REAL NOT NULL,
  max_stress_outside_pa REAL NOT NULL,
  peak_force_n REAL NOT NULL,
  mean_force_n REAL NOT NULL,
  contact_time_s REAL NOT NULL
);
CREATE INDEX sessions_by_trainee ON sessions (trainee, finished_unix_s);
)sql";

constexpr const char* kColumns =
    "trainee, session, scene, finished_unix_s, duration_s, cuts, mean_deviation_m, max_deviation_m, "
    "depth_error_m, coverage, opened_area_outside_m2, cut_off_volume_m3, max_stress_outside_pa, peak_force_n, "
    "mean_force_n, contact_time_s";

/// The entry's numbers in column order after the three names and the time.
struct NumberField {
  const char* name;
  double SessionEntry::*member;
};
constexpr NumberField kNumbers[] = {
    {"duration", &SessionEntry::duration},
    {"mean_deviation", &SessionEntry::mean_deviation},
    {"max_deviation", &SessionEntry::max_deviation},
    {"depth_error", &SessionEntry::depth_error},
    {"coverage", &SessionEntry::coverage},
    {"opened_area_outside", &SessionEntry::opened_area_outside},
    {"cut_off_volume", &SessionEntry::cut_off_volume},
    {"max_stress_outside", &SessionEntry::max_stress_outside},
    {"peak_force", &SessionEntry::peak_force},
    {"mean_force", &SessionEntry::mean_force},
    {"contact_time", &SessionEntry::contact_time},
};

[[noreturn]] void FailWith(sqlite3* db, const std::string& path, std::string_view doing) {
  const int code = sqlite3_extended_errcode(db);
  std::string why = sqlite3_errmsg(db);
  if ((code & 0xff) == SQLITE_BUSY || (code & 0xff) == SQLITE_LOCKED) {
    why = fmt::format("locked by another writer for more than {} ms ({})", ScoreHistory::kBusyTimeoutMs, why);
  } else if ((code & 0xff) == SQLITE_NOTADB) {
    why = fmt::format("not an SQLite database ({})", why);
  } else if ((code & 0xff) == SQLITE_CORRUPT) {
    why = fmt::format("corrupt ({})", why);
  }
  ThrowFileError(path, fmt::format("score history: {}: {}", doing, why));
}

/// A prepared statement, finalized on scope exit.
class Statement {
 public:
  Statement(sqlite3* db, const std::string& path, const char* sql) {
    if (sqlite3_prepare_v2(db, sql, -1, &stmt_, nullptr) != SQLITE_OK) FailWith(db, path, "preparing a statement");
  }
  ~Statement() { sqlite3_finalize(stmt_); }
  Statement(const Statement&) = delete;
  Statement& operator=(const Statement&) = delete;
  [[nodiscard]] sqlite3_stmt* get() const { return stmt_; }

 private:
  sqlite3_stmt* stmt_ = nullptr;
};

/// Runs SQL without results; throws naming the file and what it was doing.
void Exec(sqlite3* db, const std::string& path, const char* sql, std::string_view doing) {
  if (sqlite3_exec(db, sql, nullptr, nullptr, nullptr) != SQLITE_OK) FailWith(db, path, doing);
}

/// A query's single integer result.
int64_t QueryInt(sqlite3* db, const std::string& path, const char* sql, std::string_view doing) {
  sqlite3_stmt* stmt = nullptr;
  if (sqlite3_prepare_v2(db, sql, -1, &stmt, nullptr) != SQLITE_OK) FailWith(db, path, doing);
  const int rc = sqlite3_step(stmt);
  const int64_t value = rc == SQLITE_ROW ? sqlite3_column_int64(stmt, 0) : 0;
  sqlite3_finalize(stmt);
  if (rc != SQLITE_ROW && rc != SQLITE_DONE) FailWith(db, path, doing);
  return value;
}

/// SQLite's quick check: "ok", or the first problem it found.
std::string QuickCheck(sqlite3* db, const std::string& path) {
  sqlite3_stmt* stmt = nullptr;
  if (sqlite3_prepare_v2(db, "PRAGMA quick_check(1)", -1, &stmt, nullptr) != SQLITE_OK) {
    FailWith(db, path, "checking the file");
  }
  const int rc = sqlite3_step(stmt);
  std::string result;
  if (rc == SQLITE_ROW) {
    const auto* text = sqlite3_column_text(stmt, 0);
    result = text != nullptr ? reinterpret_cast<const char*>(text) : "";
  }
  sqlite3_finalize(stmt);
  if (rc != SQLITE_ROW) FailWith(db, path, "checking the file");
  return result;
}

/// Creates the schema in an empty file, or checks the one present.
void PrepareSchema(sqlite3* db, const std::string& path) {
  // Write lock first: two servers opening a new file at once create the
  // schema once.
  Exec(db, path, "BEGIN IMMEDIATE", "opening");
  try {
    const int64_t version = QueryInt(db, path, "PRAGMA user_version", "reading the schema version");
    const int64_t objects = QueryInt(db, path, "SELECT count(*) FROM sqlite_schema", "reading the schema");
    if (version == 0 && objects == 0) {
      Exec(db, path, kCreateSchema, "creating the schema");
      Exec(db, path, fmt::format("PRAGMA user_version = {}", ScoreHistory::kSchemaVersion).c_str(),
           "setting the schema version");
    } else if (version != ScoreHistory::kSchemaVersion) {
      ThrowFileError(path, fmt::format("score history: schema version {} (PRAGMA user_version), but this cutsim "
                                       "reads version {}; keep that file and name another",
                                       version, ScoreHistory::kSchemaVersion));
    }
    Exec(db, path, "COMMIT", "creating the schema");
  } catch (...) {
    sqlite3_exec(db, "ROLLBACK", nullptr, nullptr, nullptr);
    throw;
  }
}

}  // namespace

std::string CheckTraineeName(std::string_view name) {
  if (name.empty()) return "is empty";
  if (name.size() > kMaxTraineeNameBytes) {
    return fmt::format("is {} bytes long, the limit is {}", name.size(), kMaxTraineeNameBytes);
  }
  for (const char c : name) {
    const bool ok = (c >= 'A' && c <= 'Z') || (c >= 'a' && c <= 'z') || (c >= '0' && c <= '9') || c == '.' ||
                    c == '_' || c == '-';
    if (!ok) return "may hold only A-Z, a-z, 0-9, '.', '_' and '-'";
  }
  return {};
}

void ScoreHistory::Closer::operator()(sqlite3* db) const { sqlite3_close_v2(db); }

ScoreHistory::ScoreHistory(std::string path, std::unique_ptr<sqlite3, Closer> db)
    : path_(std::move(path)), db_(std::move(db)) {}
ScoreHistory::ScoreHistory(ScoreHistory&&) noexcept = default;
ScoreHistory& ScoreHistory::operator=(ScoreHistory&&) noexcept = default;
ScoreHistory::~ScoreHistory() = default;

ScoreHistory ScoreHistory::Open(const std::string& path) {
  std::error_code ec;
  const auto status = std::filesystem::status(path, ec);
  if (std::filesystem::exists(status) && !std::filesystem::is_regular_file(status)) {
    ThrowFileError(path, "score history: not a regular file");
  }
  sqlite3* raw = nullptr;
  const int rc = sqlite3_open_v2(path.c_str(), &raw, SQLITE_OPEN_READWRITE | SQLITE_OPEN_CREATE, nullptr);
  std::unique_ptr<sqlite3, Closer> db(raw);
  if (rc != SQLITE_OK) {
    if (!db) ThrowFileError(path, "score history: out of memory opening it");
    FailWith(db.get(), path, "opening");
  }
  sqlite3_extended_result_codes(db.get(), 1);
  sqlite3_busy_timeout(db.get(), kBusyTimeoutMs);
  // Rollback journal, synced at every commit: an append is whole or absent
  // after a crash or a kill, and the next opener rolls a torn one back.
  Exec(db.get(), path, "PRAGMA journal_mode = DELETE", "opening");
  Exec(db.get(), path, "PRAGMA synchronous = FULL", "opening");
  const std::string check = QuickCheck(db.get(), path);
  if (check != "ok") ThrowFileError(path, fmt::format("score history: corrupt (quick_check: {})", check));
  PrepareSchema(db.get(), path);
  return ScoreHistory(path, std::move(db));
}

void ScoreHistory::Append(const SessionEntry& e) {
  if (const std::string why = CheckTraineeName(e.trainee); !why.empty()) {
    ThrowInputError(SourceRef{.file = path_, .field = "trainee"}, fmt::format("the trainee's name {}", why));
  }
  for (const NumberField& f : kNumbers) {
    if (!std::isfinite(e.*f.member)) {
      ThrowInputError(SourceRef{.file = path_, .field = f.name}, "not a finite number: the entry is not appended");
    }
  }
  const std::string sql = fmt::format("INSERT INTO sessions ({}) VALUES (?,?,?,?,?,?,?,?,?,?,?,?,?,?,?,?)", kColumns);
  Statement stmt(db_.get(), path_, sql.c_str());
  sqlite3_stmt* s = stmt.get();
  sqlite3_bind_text(s, 1, e.trainee.data(), static_cast<int>(e.trainee.size()), SQLITE_TRANSIENT);
  sqlite3_bind_text(s, 2, e.session.data(), static_cast<int>(e.session.size()), SQLITE_TRANSIENT);
  sqlite3_bind_text(s, 3, e.scene.data(), static_cast<int>(e.scene.size()), SQLITE_TRANSIENT);
  sqlite3_bind_int64(s, 4, e.finished_unix_s);
  sqlite3_bind_double(s, 5, e.duration);
  sqlite3_bind_int64(s, 6, e.cuts);
  int column = 7;
  for (const NumberField& f : kNumbers) {
    if (f.member == &SessionEntry::duration) continue;
    sqlite3_bind_double(s, column++, e.*f.member);
  }
  // A single INSERT is its own transaction: journalled, synced, atomic.
  if (sqlite3_step(s) != SQLITE_DONE) FailWith(db_.get(), path_, "appending a session");
}

std::vector<SessionEntry> ScoreHistory::ForTrainee(const std::string& trainee) const {
  const std::string sql = fmt::format(
      "SELECT {} FROM sessions WHERE trainee = ? ORDER BY finished_unix_s, id LIMIT {}", kColumns, kMaxReadEntries);
  Statement stmt(db_.get(), path_, sql.c_str());
  sqlite3_stmt* s = stmt.get();
  sqlite3_bind_text(s, 1, trainee.data(), static_cast<int>(trainee.size()), SQLITE_TRANSIENT);
  std::vector<SessionEntry> out;
  auto text = [s](int i) {
    const auto* t = sqlite3_column_text(s, i);
    return t != nullptr ? std::string(reinterpret_cast<const char*>(t)) : std::string();
  };
  int rc = SQLITE_ROW;
  while ((rc = sqlite3_step(s)) == SQLITE_ROW) {
    SessionEntry& e = out.emplace_back();
    e.trainee = text(0);
    e.session = text(1);
    e.scene = text(2);
    e.finished_unix_s = sqlite3_column_int64(s, 3);
    e.duration = sqlite3_column_double(s, 4);
    e.cuts = sqlite3_column_int64(s, 5);
    int column = 6;
    for (const NumberField& f : kNumbers) {
      if (f.member == &SessionEntry::duration) continue;
      e.*f.member = sqlite3_column_double(s, column++);
    }
  }
  if (rc != SQLITE_DONE) FailWith(db_.get(), path_, "reading a trainee's sessions");
  return out;
}

int64_t ScoreHistory::size() const {
  return QueryInt(db_.get(), path_, "SELECT count(*) FROM sessions", "counting the sessions");
}

}  // namespace cutsim::record
