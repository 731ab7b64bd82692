#pragma once
/// @file
/// Reads a scene (protobuf text format, schema proto/cutsim/v1/scene.proto)
/// and checks every field a simulation relies on. Errors name the file and
/// the line/column (parse errors) or the field (semantic errors); a scene that
/// loads is complete: defaults are filled in, paths are resolved.

#include <filesystem>
#include <string>

#include "cutsim/v1/scene.pb.h"

namespace cutsim::sim {

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
