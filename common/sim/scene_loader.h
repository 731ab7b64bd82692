#pragma once
/// @file
/// Reads a scene (protobuf text format, schema proto/cutsim/v1/scene.proto)
/// and checks every field a simulation relies on. Errors name the file and
/// the line/column (parse errors) or the field (semantic errors); a scene that
/// loads is complete: defaults are filled in, paths are resolved.

#include <filesystem>
#include <string>

#include "common/core/error.h"
#include "cutsim/v1/scene.pb.h"

namespace cutsim::sim {

/// Limits a scene must respect (scenes/README.md, "Limits"). Each bounds the
/// work a scene can ask for, so a valid-looking scene cannot run forever.
inline constexpr int64_t kMaxThreads = 256;               ///< time_step.threads, --threads, recordings
inline constexpr double kMinFrameDt = 1e-4;               ///< s, time_step.frame_dt
inline constexpr double kMaxFrameDt = 1.0;                ///< s
inline constexpr double kMinSafetyFactor = 0.01;          ///< time_step.safety_factor
inline constexpr double kMaxStepsPerSimSecond = 1e7;      ///< explicit steps per simulated second
inline constexpr double kMinFixedDt = 1.0 / kMaxStepsPerSimSecond;  ///< s, time_step.fixed_dt
inline constexpr double kMinScale = 1e-6;                 ///< mesh.scale
inline constexpr double kMaxScale = 1e6;
inline constexpr double kMaxSimSeconds = 86400.0;         ///< s: --duration, --max-time, tool path ends
inline constexpr uint64_t kMaxSceneFileBytes = uint64_t{16} << 20;  ///< 16 MiB

/// Throws `InputError` at `where` unless 0 ≤ threads ≤ kMaxThreads.
void CheckThreads(int64_t threads, const SourceRef& where);

/// A loaded scene and where it came from.
struct LoadedScene {
  cutsim::v1::Scene scene;        ///< Validated, defaults filled in.
  std::filesystem::path path;     ///< The scene file.
  std::filesystem::path base_dir; ///< Relative paths in the scene resolve here.
};

/// Parses and validates `path`. Throws InputError naming file:line:column
/// (syntax) or file: field (values).
LoadedScene LoadScene(const std::filesystem::path& path);

/// Parses scene text; `source_name` is used in errors. Relative paths resolve
/// against `base_dir`.
LoadedScene ParseScene(const std::string& text, const std::string& source_name,
                       const std::filesystem::path& base_dir);

/// Fills defaults and checks ranges; throws InputError naming `source_name`
/// and the field. Exposed for scenes built in code.
void ValidateScene(cutsim::v1::Scene& scene, const std::string& source_name);

}  // namespace cutsim::sim
