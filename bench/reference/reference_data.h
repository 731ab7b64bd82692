#pragma once
/// @file
/// Loader of the independent CalculiX references in bench/reference/
/// (written by run_calculix.py; the JSON files beside them hold the full
/// convergence data). Self-contained: the standard library only.
///
///   beam_nu_sweep.csv     poisson,element,tip_m,tip_uncertainty_m,
///                         tip_5x5_mean_m,tip_5x5_uncertainty_m
///   compressed_block.csv  variant,element,volume_change,
///                         volume_change_uncertainty,top_force_z_n,
///                         top_force_z_uncertainty_n
///
/// Lines starting with '#' are comments; the first other line is the header
/// and must read exactly as above. Bad input throws std::runtime_error naming
/// the file, the line and the field.

#include <cmath>
#include <cstdlib>
#include <fstream>
#include <optional>
#include <sstream>
#include <stdexcept>
#include <string>
#include <vector>

namespace cutsim::bench::reference {

/// Converged static tip deflection of scenes/beam.pbtxt at one Poisson ratio.
/// Deflections are signed (negative: down), m.
struct BeamReference {
  double poisson = 0;
  std::string element;              ///< CalculiX element type of the reference run.
  double tip_m = 0;                 ///< Area mean of u_z over the end face x = L.
  double tip_uncertainty_m = 0;     ///< |finest − previous refinement|.
  double tip_5x5_mean_m = 0;        ///< Mean u_z at the 5 × 5 tip nodes of the 20 × 4 × 4 mesh.
  double tip_5x5_uncertainty_m = 0;
};

/// The 20 mm cube compressed by 20 % (ν = 0.499): one boundary variant.
struct BlockReference {
  std::string variant;  ///< "slip" (faces held along z only) or "bonded".
  std::string element;
  double volume_change = 0;  ///< V/V₀ − 1.
  double volume_change_uncertainty = 0;
  double top_force_z_n = 0;  ///< z reaction summed over the top face, N (negative: pushes down).
  double top_force_z_uncertainty_n = 0;
};

namespace internal {

inline const char* const kBeamHeader =
    "poisson,element,tip_m,tip_uncertainty_m,tip_5x5_mean_m,tip_5x5_uncertainty_m";
inline const char* const kBlockHeader =
    "variant,element,volume_change,volume_change_uncertainty,top_force_z_n,top_force_z_uncertainty_n";

[[noreturn]] inline void Fail(const std::string& path, int line, const std::string& what) {
  throw std::runtime_error(path + ":" + std::to_string(line) + ": " + what);
}

inline std::vector<std::string> Split(const std::string& text) {
  std::vector<std::string> fields;
  std::stringstream stream(text);
  std::string field;
  while (std::getline(stream, field, ',')) fields.push_back(field);
  if (!text.empty() && text.back() == ',') fields.emplace_back();
  return fields;
}

inline double Number(const std::string& path, int line, const std::string& name, const std::string& text) {
  char* end = nullptr;
  const double value = std::strtod(text.c_str(), &end);
  if (text.empty() || end != text.c_str() + text.size() || !std::isfinite(value)) {
    Fail(path, line, "field " + name + ": not a finite number: '" + text + "'");
  }
  return value;
}

/// Rows of a CSV file with the given header, each split into fields; calls
/// row(fields, line number, header names) for each data line.
template <typename Row>
void ReadCsv(const std::string& path, const char* header, Row&& row) {
  std::ifstream in(path);
  if (!in) throw std::runtime_error(path + ": cannot open");
  const std::vector<std::string> names = Split(header);
  std::string text;
  bool seen_header = false;
  for (int line = 1; std::getline(in, text); ++line) {
    if (!text.empty() && text.back() == '\r') text.pop_back();
    if (text.empty() || text.front() == '#') continue;
    if (!seen_header) {
      if (text != header) Fail(path, line, "header must be '" + std::string(header) + "'");
      seen_header = true;
      continue;
    }
    const std::vector<std::string> fields = Split(text);
    if (fields.size() != names.size()) {
      Fail(path, line, "expected " + std::to_string(names.size()) + " fields, got " + std::to_string(fields.size()));
    }
    row(fields, line, names);
  }
  if (!seen_header) throw std::runtime_error(path + ": no header line");
}

}  // namespace internal

/// Reads beam_nu_sweep.csv: one entry per Poisson ratio, in file order.
inline std::vector<BeamReference> LoadBeamReference(const std::string& path) {
  std::vector<BeamReference> out;
  internal::ReadCsv(path, internal::kBeamHeader,
                    [&](const std::vector<std::string>& f, int line, const std::vector<std::string>& names) {
                      const auto num = [&](size_t i) { return internal::Number(path, line, names[i], f[i]); };
                      out.push_back({num(0), f[1], num(2), num(3), num(4), num(5)});
                    });
  return out;
}

/// Reads compressed_block.csv: one entry per boundary variant.
inline std::vector<BlockReference> LoadBlockReference(const std::string& path) {
  std::vector<BlockReference> out;
  internal::ReadCsv(path, internal::kBlockHeader,
                    [&](const std::vector<std::string>& f, int line, const std::vector<std::string>& names) {
                      const auto num = [&](size_t i) { return internal::Number(path, line, names[i], f[i]); };
                      out.push_back({f[0], f[1], num(2), num(3), num(4), num(5)});
                    });
  return out;
}

/// The entry for Poisson ratio `poisson` (to 1e-9), if the sweep has one.
inline std::optional<BeamReference> FindBeamReference(const std::vector<BeamReference>& sweep, double poisson) {
  for (const BeamReference& r : sweep) {
    if (std::abs(r.poisson - poisson) < 1e-9) return r;
  }
  return std::nullopt;
}

}  // namespace cutsim::bench::reference
