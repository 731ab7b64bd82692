#pragma once
/// @file
/// A lab's record of its trainees across sessions: every finished session's
/// score appended to one SQLite file per lab, read back per trainee. The
/// file carries its schema version (`PRAGMA user_version`); a file of
/// another version, one that is not an SQLite database, a corrupt one and
/// one another writer keeps locked are refused with an `InputError` naming
/// the file, so the caller can log it and go on. SQLite's rollback journal
/// makes each append all or nothing, also when the writer is killed.

#include <cstdint>
#include <memory>
#include <string>
#include <string_view>
#include <vector>

struct sqlite3;

namespace cutsim::record {

/// One finished session of one trainee. SI units.
struct SessionEntry {
  std::string trainee;               ///< trainee's name (`CheckTraineeName`)
  std::string session;               ///< session name
  std::string scene;                 ///< scene name
  int64_t finished_unix_s = 0;       ///< wall clock when the session ended, s since 1970-01-01 UTC
  double duration = 0.0;             ///< s, simulated time of the session
  int64_t cuts = 0;                  ///< cut steps taken
  double mean_deviation = 0.0;       ///< m, from the planned line, over the cut points
  double max_deviation = 0.0;        ///< m
  double depth_error = 0.0;          ///< m, reached − planned (negative: too shallow)
  double coverage = 0.0;             ///< fraction of the planned cut surface opened
  double opened_area_outside = 0.0;  ///< m², opened outside the incision's band
  double cut_off_volume = 0.0;       ///< m³
  double max_stress_outside = 0.0;   ///< Pa
  double peak_force = 0.0;           ///< N
  double mean_force = 0.0;           ///< N, in contact
  double contact_time = 0.0;         ///< s
};

/// Longest trainee name, bytes.
inline constexpr size_t kMaxTraineeNameBytes = 64;

/// Empty when `name` is a valid trainee name (1 to 64 of A–Z, a–z, 0–9,
/// '.', '_' and '-'), else what is wrong with it.
[[nodiscard]] std::string CheckTraineeName(std::string_view name);

/// An open score history. Move-only; closes the file on destruction.
class ScoreHistory {
 public:
  /// The schema this code reads and writes (`PRAGMA user_version`).
  static constexpr int kSchemaVersion = 1;
  /// How long an append or an open waits for another writer's lock, ms.
  static constexpr int kBusyTimeoutMs = 2000;
  /// Most entries one read returns.
  static constexpr size_t kMaxReadEntries = 100000;

  /// Opens `path`, creating it with the current schema when it does not
  /// exist or is empty. Throws `InputError` naming the file when it is not a
  /// regular file, not an SQLite database, fails SQLite's quick check
  /// (corrupt), carries another schema version (naming it and this one), or
  /// stays locked longer than `kBusyTimeoutMs`.
  [[nodiscard]] static ScoreHistory Open(const std::string& path);

  ScoreHistory(ScoreHistory&&) noexcept;
  ScoreHistory& operator=(ScoreHistory&&) noexcept;
  ~ScoreHistory();

  /// Appends `entry` in one transaction, durable when this returns. Throws
  /// `InputError` naming the file and the field when the entry is invalid
  /// (a bad trainee name, a non-finite number), or naming the file when the
  /// write fails (locked, full disk, read-only, corrupt).
  void Append(const SessionEntry& entry);

  /// `trainee`'s sessions, oldest first, at most `kMaxReadEntries`.
  [[nodiscard]] std::vector<SessionEntry> ForTrainee(const std::string& trainee) const;

  /// Number of entries of all trainees.
  [[nodiscard]] int64_t size() const;

  [[nodiscard]] const std::string& path() const { return path_; }

 private:
  struct Closer {
    void operator()(sqlite3* db) const;
  };
  ScoreHistory(std::string path, std::unique_ptr<sqlite3, Closer> db);

  std::string path_;
  std::unique_ptr<sqlite3, Closer> db_;
};

}  // namespace cutsim::record
