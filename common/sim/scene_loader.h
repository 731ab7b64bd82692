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
inline constexpr double kMaxCoordinate = 1e3;           ///< m, every position, length and distance in a scene
inline constexpr double kMaxGravity = 1e3;              ///< m/s², each component of gravity
inline constexpr double kMinModulus = 1.0;              ///< Pa, E or μ
inline constexpr double kMaxModulus = 1e12;             ///< Pa, E, λ, μ, cutting.critical_stress
inline constexpr double kMinDensity = 1e-3;             ///< kg/m³
inline constexpr double kMaxDensity = 1e5;              ///< kg/m³
inline constexpr double kMaxViscosity = 1e6;            ///< Pa·s, damping_psi, damping_phi
inline constexpr double kMaxRate = 1e6;                 ///< 1/s, mass_damping, haptics.decay_per_second
inline constexpr double kMaxEnergy = 1e9;               ///< J, rest.kinetic_energy
inline constexpr double kMaxContactStiffness = 1e9;     ///< N/m (N·s/m), tool contact stiffness and damping
inline constexpr double kMaxCuttingFactor = 1e6;        ///< cutting.alpha, cutting.kappa
inline constexpr double kMaxBoundaryDisplacement = 1.0;     ///< m, each component of boundary[i].displacement
inline constexpr double kMaxBoundaryForce = 1e6;            ///< N, each component of boundary[i].force
inline constexpr uint64_t kMaxSceneFileBytes = uint64_t{16} << 20;  ///< 16 MiB

/// Throws `InputError` naming the field unless every magnitude of `scene`
/// (moduli, densities, lengths, rates, …) lies within the limits above.
/// Called by ValidateScene.
void CheckMagnitudes(const cutsim::v1::Scene& scene, const std::string& source_name);

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
