#include "common/cli/flag_modes.h"

#include <fmt/format.h>

#include "common/core/error.h"

namespace cutsim::cli {

FlagModes::FlagModes(std::vector<std::string> mode_names) : mode_names_(std::move(mode_names)) {
  CUTSIM_CHECK(!mode_names_.empty() && mode_names_.size() <= 32, "FlagModes: 1 to 32 modes");
}

ModeSet FlagModes::all() const {
  return mode_names_.size() == 32 ? ~ModeSet{0} : (ModeSet{1} << mode_names_.size()) - 1;
}

CLI::Option* FlagModes::Declare(CLI::Option* option, ModeSet modes) {
  CUTSIM_CHECK(option != nullptr && modes != 0 && (modes & ~all()) == 0, "FlagModes::Declare: no mode, or unknown");
  CUTSIM_CHECK(ModesOf(option) == 0, "FlagModes::Declare: declared twice");
  declared_.emplace_back(option, modes);
  return option;
}

ModeSet FlagModes::ModesOf(const CLI::Option* option) const {
  for (const auto& [declared, modes] : declared_) {
    if (declared == option) return modes;
  }
  return 0;
}

void FlagModes::DeclareRest(const CLI::App& app, ModeSet modes) {
  for (const CLI::Option* option : app.get_options()) {
    if (option == app.get_help_ptr() || option == app.get_help_all_ptr() || ModesOf(option) != 0) continue;
    declared_.emplace_back(option, modes);
  }
}

std::optional<std::string> FlagModes::Refusal(const CLI::App& app, int mode) const {
  CUTSIM_CHECK(mode >= 0 && static_cast<size_t>(mode) < mode_names_.size(), "FlagModes::Refusal: unknown mode");
  for (const CLI::Option* option : app.get_options()) {
    if (option == app.get_help_ptr() || option == app.get_help_all_ptr()) continue;
    const ModeSet modes = ModesOf(option);
    CUTSIM_CHECK(modes != 0, fmt::format("option {} declares no modes (FlagModes::Declare)", option->get_name()));
    if (option->count() == 0 || (modes & (ModeSet{1} << mode)) != 0) continue;
    std::string acts_in;
    for (size_t i = 0; i < mode_names_.size(); ++i) {
      if ((modes & (ModeSet{1} << i)) == 0) continue;
      acts_in += acts_in.empty() ? "" : ", ";
      acts_in += mode_names_[i];
    }
    return fmt::format("{}: does nothing in {} (it acts in {}): drop it", option->get_name(),
                       mode_names_[static_cast<size_t>(mode)], acts_in);
  }
  return std::nullopt;
}

}  // namespace cutsim::cli
