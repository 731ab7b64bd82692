#pragma once
/// @file
/// The one gate every reader passes before it trusts a file: only regular
/// files (not directories, devices, FIFOs such as /dev/zero or /dev/stdin),
/// no larger than a stated cap, read whole with an out-of-memory error that
/// names the file. Counts a header claims are checked against the bytes
/// actually present before anything is allocated for them. Outputs are
/// checked for writability when a program starts, not when it ends.

#include <cstdint>
#include <string>
#include <string_view>

#include "common/core/error.h"

namespace cutsim {

/// Largest input file any reader accepts, bytes (1 GiB).
inline constexpr uint64_t kMaxInputFileBytes = uint64_t{1} << 30;

/// Throws `InputError` naming `path` unless it names an existing regular file
/// (symlinks followed) of at most `max_bytes`. `what` says what the file is
/// for ("mesh file", "checkpoint"…). Returns the file's size in bytes.
uint64_t CheckInputFile(const std::string& path, std::string_view what,
                        uint64_t max_bytes = kMaxInputFileBytes);

/// `CheckInputFile`, then the whole file. Read errors and running out of
/// memory are `InputError`s naming the file.
[[nodiscard]] std::string ReadInputFile(const std::string& path, std::string_view what,
                                        uint64_t max_bytes = kMaxInputFileBytes);

/// Throws `InputError` at `where` unless `count` items of at least
/// `min_bytes_each` bytes fit in the `bytes_left` bytes still unread, so a
/// header claiming 10⁸ nodes in a 20-byte file fails before any allocation.
void RequireCountFits(int64_t count, int64_t min_bytes_each, uint64_t bytes_left, const SourceRef& where,
                      std::string_view what);

/// Throws `InputError` naming `path` and `what` unless `path` can be written:
/// it is not a directory, and either it exists as a writable file or its
/// directory exists and is writable. Called at start for every output, so a
/// bad path fails before the work, not after it.
void CheckOutputPath(const std::string& path, std::string_view what);

/// Writes `content` to `path + ".tmp"`, flushes it to disk (fsync) and renames
/// it over `path`: a crash or a full disk never leaves a torn file in place of
/// a good one. Every write, the fsync and the close are checked; failures are
/// `InputError`s naming `path` and the reason.
void WriteFileAtomically(const std::string& path, std::string_view content);

}  // namespace cutsim
