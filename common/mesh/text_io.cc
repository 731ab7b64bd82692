#include "common/mesh/text_io.h"

#include <cctype>
#include <cerrno>
#include <charconv>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <sstream>

#include <fmt/format.h>

#include "common/core/error.h"
#include "common/core/input_file.h"

namespace cutsim::mesh::internal {

std::string ReadFileOrThrow(const std::string& path) { return ReadInputFile(path, "mesh file"); }

void WriteFileAtomically(const std::string& path, std::string_view content) {
  cutsim::WriteFileAtomically(path, content);
}

Tokenizer::Tokenizer(std::string path, std::string text, bool hash_comments)
    : path_(std::move(path)), text_(std::move(text)), hash_comments_(hash_comments) {}

void Tokenizer::SkipSpace() {
  while (pos_ < text_.size()) {
    const char c = text_[pos_];
    if (c == '\n') {
      ++line_;
      ++pos_;
    } else if (c == ' ' || c == '\t' || c == '\r' || c == '\f' || c == '\v') {
      ++pos_;
    } else if (hash_comments_ && c == '#') {
      while (pos_ < text_.size() && text_[pos_] != '\n') ++pos_;
    } else {
      break;
    }
  }
}

bool Tokenizer::HasNext() {
  SkipSpace();
  return pos_ < text_.size();
}

bool Tokenizer::NextOnSameLine() { return HasNext() && line_ == token_line_; }

void Tokenizer::SkipLine() {
  while (pos_ < text_.size() && text_[pos_] != '\n') ++pos_;
}

std::string_view Tokenizer::Next(std::string_view what) {
  SkipSpace();
  if (pos_ >= text_.size()) {
    ThrowInputError(SourceRef{.file = path_, .line = line_},
                    fmt::format("unexpected end of file while reading {} (truncated file?)", what));
  }
  const size_t begin = pos_;
  while (pos_ < text_.size() && !std::isspace(static_cast<unsigned char>(text_[pos_])) &&
         !(hash_comments_ && text_[pos_] == '#')) {
    ++pos_;
  }
  token_line_ = line_;
  return std::string_view(text_).substr(begin, pos_ - begin);
}

int64_t Tokenizer::NextInt(std::string_view what) {
  const std::string_view tok = Next(what);
  int64_t value = 0;
  const auto [end, ec] = std::from_chars(tok.data(), tok.data() + tok.size(), value);
  if (ec != std::errc() || end != tok.data() + tok.size()) {
    Fail(fmt::format("expected an integer for {}, got '{}'", what, tok));
  }
  return value;
}

double Tokenizer::NextDouble(std::string_view what) {
  std::string_view tok = Next(what);
  if (!tok.empty() && tok.front() == '+') tok.remove_prefix(1);  // from_chars rejects '+'
  double value = 0.0;
  const auto [end, ec] = std::from_chars(tok.data(), tok.data() + tok.size(), value);
  if (ec != std::errc() || end != tok.data() + tok.size()) {
    Fail(fmt::format("expected a number for {}, got '{}'", what, tok));
  }
  return value;
}

void Tokenizer::RequireCountFits(int64_t count, int64_t min_bytes_each, std::string_view what) const {
  cutsim::RequireCountFits(count, min_bytes_each, bytes_left(),
                           SourceRef{.file = path_, .line = token_line_ > 0 ? token_line_ : line_}, what);
}

void Tokenizer::Fail(std::string_view message) const {
  ThrowInputError(SourceRef{.file = path_, .line = token_line_ > 0 ? token_line_ : line_}, message);
}

}  // namespace cutsim::mesh::internal
