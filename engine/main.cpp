// The stiffmd command line (docs/design.md §8):
//   stiffmd run DECK [-o DIR] [--set key=value]...   exit 0 ok, 2 bad input, 3 numerical failure
//   stiffmd check DECK [--set key=value]... [--write-data FILE]
//                                                    validate and describe the scene; write its
//                                                    prepared initial state as LAMMPS data
#include <CLI/CLI.hpp>
#include <filesystem>
#include <iostream>
#include <optional>
#include <sstream>

#include "engine/core/errors.hpp"
#include "engine/deck/deck.hpp"
#include "engine/run/checkpoint.hpp"
#include "engine/run/run.hpp"
#include "engine/scene/scene.hpp"

namespace {

constexpr int kExitBadInput = 2;
constexpr int kExitNumerical = 3;

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"stiffmd " STIFFMD_VERSION
               " - molecular dynamics with stiff bonds: impulse, mollified and projected impulse,\n"
               "RATTLE, velocity Verlet and the effective (eps -> 0) dynamics"};
  app.set_version_flag("--version", "stiffmd " STIFFMD_VERSION);
  app.require_subcommand(1);

  std::string deck_path, out_dir, restart;
  std::vector<std::string> overrides;
  bool no_progress = false, quiet = false;

  CLI::App* run = app.add_subcommand("run", "run a deck");
  run->add_option("deck", deck_path, "deck file (TOML)")->required();
  run->add_option("-o,--output", out_dir, "output directory (default: out/<deck name>)");
  run->add_option("--set", overrides, "override a deck key, e.g. --set variables.eps=1e-4 --set integrator.h=0.01")
      ->take_all();
  run->add_option("--restart", restart, "continue from a checkpoint (appends to the run's outputs)");
  run->add_flag("--no-progress", no_progress, "no progress bar on stderr");
  run->add_flag("-q,--quiet", quiet,
                "no thermo lines on stdout, no progress bar or [prepare] progress on stderr: stdout holds only "
                "the first line and the summary, stderr only notes, warnings and errors");

  CLI::App* check = app.add_subcommand("check", "validate a deck and print what the scene contains");
  check->add_option("deck", deck_path, "deck file (TOML)")->required();
  check->add_option("--set", overrides, "override a deck key")->take_all();
  std::string data_path;
  check->add_option("--write-data", data_path,
                    "write the prepared initial state (after [prepare]) as a LAMMPS data file");

  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    const int code = app.exit(e);
    return code == 0 ? 0 : kExitBadInput;
  }

  try {
    const stiffmd::Deck deck(deck_path, overrides);
    stiffmd::Scene scene = stiffmd::load_scene(deck);
    // A restart's checkpoint is checked (format, checksum, version, scene) before anything is
    // printed or written: a damaged or foreign one is one line and exit 2.
    std::optional<stiffmd::Checkpoint> checkpoint;
    if (run->parsed() && !restart.empty()) checkpoint = stiffmd::read_checkpoint_for(scene, restart);
    for (const auto& note : scene.notes) std::cerr << note << "\n";
    if (restart.empty())  // a restart's state is the checkpoint's
      stiffmd::prepare_scene(scene, std::cerr, quiet || !run->parsed() ? nullptr : &std::cerr);
    if (check->parsed()) {
      std::ostringstream start_log;  // the method's preparation notes belong to a run's log
      stiffmd::check_run(scene, start_log);
      std::cout << stiffmd::describe(scene) << "deck is valid\n";
      if (!data_path.empty()) {
        stiffmd::write_scene_lammps_data(scene, data_path, "stiffmd " STIFFMD_VERSION " initial state of " + deck_path);
        std::cout << "initial state written to " << data_path << "\n";
      }
      return 0;
    }
    if (out_dir.empty()) out_dir = (std::filesystem::path("out") / std::filesystem::path(deck_path).stem()).string();
    std::cout << "stiffmd " STIFFMD_VERSION ": " << deck_path << " -> " << out_dir << "\n" << std::flush;
    const auto summary = stiffmd::run_simulation(
        scene,
        {out_dir, !no_progress && !quiet, restart, checkpoint ? &*checkpoint : nullptr, quiet ? nullptr : stdout},
        std::cerr);
    if (summary.stopped_by_signal) {
      std::cerr << "stopped by signal " << summary.stopped_by_signal << " after step " << summary.steps
                << "; outputs flushed, checkpoint " << summary.checkpoint << "; continue with: stiffmd run "
                << deck_path << " -o " << out_dir << " --restart " << summary.checkpoint << " (and the same --set)\n";
      return 128 + summary.stopped_by_signal;
    }
    std::cout << stiffmd::format_summary(summary);
    return 0;
  } catch (const stiffmd::InputError& e) {
    std::cerr << "error: " << e.what() << "\n";
    return kExitBadInput;
  } catch (const stiffmd::NumericalError& e) {
    std::cerr << "error: " << e.what() << "\n";
    return kExitNumerical;
  } catch (const std::exception& e) {
    std::cerr << "internal error: " << e.what() << "\n";
    return 1;
  }
}
