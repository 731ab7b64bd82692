#pragma once
/// @file
/// The fault-injection command-line flags shared by the haptic client, the
/// server and test tools (header-only so that the transport library does not
/// depend on CLI11; link CLI11::CLI11 where you include it).

#include <CLI/CLI.hpp>

#include "common/transport/fault_injection.h"

namespace cutsim::transport {

/// Adds --fault-delay-ms, --fault-jitter-ms, --fault-drop, --fault-dup,
/// --fault-reorder, --fault-reorder-ms and --fault-seed, filling `config`.
/// Call `ValidateFaultConfig` after parsing.
inline void AddFaultFlags(CLI::App& app, FaultConfig* config, const std::string& group = "Fault injection") {
  app.add_option("--fault-delay-ms", config->delay_ms, "One-way delay added to every message, ms")
      ->group(group)->capture_default_str();
  app.add_option("--fault-jitter-ms", config->jitter_ms, "Extra delay drawn uniformly from [0, J] ms")
      ->group(group)->capture_default_str();
  app.add_option("--fault-drop", config->drop, "Probability a message is lost (0..1)")
      ->group(group)->capture_default_str();
  app.add_option("--fault-dup", config->duplicate, "Probability a message is sent twice (0..1)")
      ->group(group)->capture_default_str();
  app.add_option("--fault-reorder", config->reorder,
                 "Probability a message is held back --fault-reorder-ms so later ones overtake it")
      ->group(group)->capture_default_str();
  app.add_option("--fault-reorder-ms", config->reorder_ms, "Hold-back of a reordered message, ms")
      ->group(group)->capture_default_str();
  app.add_option("--fault-seed", config->seed, "Seed of the fault generator")
      ->group(group)->capture_default_str();
}

}  // namespace cutsim::transport
