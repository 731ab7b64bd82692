#pragma once
// Private helpers for the text mesh formats: whole-file reading, a tokenizer
// that tracks line numbers, atomic writes.

#include <cstdint>
#include <string>
#include <string_view>
#include <vector>

namespace cutsim::mesh::internal {

/// Reads the whole file; InputError naming it if it cannot be opened.
std::string ReadFileOrThrow(const std::string& path);

/// Writes `content` to a temp sibling and renames it over `path`.
void WriteFileAtomically(const std::string& path, std::string_view content);

/// Whitespace tokenizer over a file's text, with `#` comments if enabled.
class Tokenizer {
 public:
  Tokenizer(std::string path, std::string text, bool hash_comments);

  /// True if another token exists (skips whitespace and comments).
  bool HasNext();
  /// Next token; InputError "unexpected end of file … while reading <what>".
  std::string_view Next(std::string_view what);
  int64_t NextInt(std::string_view what);
  double NextDouble(std::string_view what);
  /// Line (1-based) of the last token returned.
  [[nodiscard]] int64_t line() const { return token_line_; }
  /// Bytes not yet read, for checking a header's counts against the file.
  [[nodiscard]] uint64_t bytes_left() const { return text_.size() - pos_; }
  /// Throws (at the last token's line) unless `count` records of at least
  /// `min_bytes_each` bytes fit in the rest of the file.
  void RequireCountFits(int64_t count, int64_t min_bytes_each, std::string_view what) const;
  /// Skips the rest of the current line.
  void SkipLine();
  /// True if the next token is on the same line as the last one.
  bool NextOnSameLine();
  [[noreturn]] void Fail(std::string_view message) const;
  [[nodiscard]] const std::string& path() const { return path_; }

 private:
  void SkipSpace();
  std::string path_;
  std::string text_;
  bool hash_comments_;
  size_t pos_ = 0;
  int64_t line_ = 1;        // line at pos_
  int64_t token_line_ = 0;  // line of the last token
};

}  // namespace cutsim::mesh::internal

#include "common/mesh/mesh_validation.h"

namespace cutsim::mesh::internal {

/// The last step of every reader: orient tets positively, then validate.
void FinishRead(TetMesh& mesh, const std::string& path, const MeshOrigin& origin);

}  // namespace cutsim::mesh::internal

namespace cutsim::mesh::internal {

/// Region tags for gmsh output (1 if the mesh has none); InputError naming
/// `path` and the element if a region is ≤ 0.
std::vector<int32_t> GmshTags(const std::string& path, const TetMesh& mesh);

/// Gmsh 2.2 ASCII, written by hand.
void WriteMsh22Ascii(const std::string& path, const TetMesh& mesh);

}  // namespace cutsim::mesh::internal
