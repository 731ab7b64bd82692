#pragma once
/// @file
/// JSON text helpers for the benchmarks, which build their JSON with printf
/// or fmt: printf and fmt write a non-finite double as `nan`, `-nan`, `inf`
/// or `-inf`, which is not JSON. `NullNonFinite` turns those bare words
/// (outside strings) into `null`, so every output parses whatever the
/// measurement gave.

#include <cctype>
#include <cstdarg>
#include <cstdio>
#include <string>
#include <string_view>
#include <vector>

namespace cutsim::bench {

/// `json` with every bare `nan`, `inf` (any case, with or without a sign)
/// outside a string replaced by `null`. Text inside strings is kept as is.
inline std::string NullNonFinite(std::string_view json) {
  std::string out;
  out.reserve(json.size());
  bool in_string = false;
  for (size_t i = 0; i < json.size();) {
    const char c = json[i];
    if (in_string) {
      out += c;
      if (c == '\\' && i + 1 < json.size()) {
        out += json[i + 1];
        i += 2;
        continue;
      }
      in_string = c != '"';
      ++i;
      continue;
    }
    if (c == '"') {
      in_string = true;
      out += c;
      ++i;
      continue;
    }
    if (std::isalpha(static_cast<unsigned char>(c)) || c == '-' || c == '+') {
      size_t end = i + ((c == '-' || c == '+') ? 1 : 0);
      while (end < json.size() && std::isalpha(static_cast<unsigned char>(json[end]))) ++end;
      std::string word(json.substr(i, end - i));
      for (char& w : word) w = static_cast<char>(std::tolower(static_cast<unsigned char>(w)));
      if (word == "nan" || word == "-nan" || word == "+nan" || word == "inf" || word == "-inf" ||
          word == "+inf" || word == "infinity" || word == "-infinity") {
        out += "null";
        i = end;
        continue;
      }
    }
    out += c;
    ++i;
  }
  return out;
}

/// `text` escaped for a JSON string: quote, backslash and control characters.
inline std::string JsonEscape(std::string_view text) {
  std::string out;
  out.reserve(text.size());
  for (const char c : text) {
    const auto u = static_cast<unsigned char>(c);
    if (u < 0x20) {
      char buf[8];
      std::snprintf(buf, sizeof buf, "\\u%04x", static_cast<unsigned>(u));
      out += buf;
      continue;
    }
    if (c == '"' || c == '\\') out += '\\';
    out += c;
  }
  return out;
}

/// Appends printf-formatted text to `out`.
[[gnu::format(printf, 2, 3)]] inline void Appendf(std::string& out, const char* format, ...) {
  std::va_list args;
  va_start(args, format);
  std::va_list copy;
  va_copy(copy, args);
  const int n = std::vsnprintf(nullptr, 0, format, copy);
  va_end(copy);
  if (n > 0) {
    const size_t at = out.size();
    out.resize(at + static_cast<size_t>(n) + 1);
    std::vsnprintf(out.data() + at, static_cast<size_t>(n) + 1, format, args);
    out.resize(at + static_cast<size_t>(n));
  }
  va_end(args);
}

/// Writes `text` to `path`; false (and a message on stderr naming the path)
/// if the file cannot be written.
inline bool WriteTextFile(const char* bench, const std::string& path, const std::string& text) {
  std::FILE* out = std::fopen(path.c_str(), "w");
  bool ok = out != nullptr && std::fputs(text.c_str(), out) >= 0;
  if (out != nullptr) ok = std::fclose(out) == 0 && ok;
  if (!ok) std::fprintf(stderr, "%s: cannot write %s\n", bench, path.c_str());
  return ok;
}

/// Prints each missed target on stderr ("<bench>: target missed: <what>")
/// and returns the exit code: 0 when `missed` is empty, else 1.
inline int ExitCodeForTargets(const char* bench, const std::vector<std::string>& missed) {
  for (const std::string& m : missed) std::fprintf(stderr, "%s: target missed: %s\n", bench, m.c_str());
  return missed.empty() ? 0 : 1;
}

}  // namespace cutsim::bench
