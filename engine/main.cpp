// The stiffmd command line (docs/design.md §8):
//   stiffmd run DECK [-o DIR] [--set key=value]...   exit 0 ok, 2 bad input, 3 numerical failure
//   stiffmd check DECK [--set key=value]... [--write-data FILE]
//                                                    validate and describe the scene; write its
//                                                    prepared initial state as LAMMPS data
// A deck with [ensemble] is many runs (engine/run/ensemble.hpp): run writes member k to
// DIR/member_k, one after the other, or divided among the processes of `mpiexec -n N`
// (engine/run/processes.hpp); check checks every member.
#include <CLI/CLI.hpp>
#include <algorithm>
#include <chrono>
#include <filesystem>
#include <iostream>
#include <limits>
#include <optional>
#include <sstream>
#include <tuple>
#include <vector>

#include "core/errors.hpp"
#include "engine/deck/deck.hpp"
#include "engine/domain/part_load.hpp"
#include "engine/io/h5md_writer.hpp"
#include "engine/run/checkpoint.hpp"
#include "engine/run/ensemble.hpp"
#include "engine/run/processes.hpp"
#include "engine/run/run.hpp"
#include "engine/run/stages.hpp"
#include "engine/scene/ensemble_deck.hpp"
#include "engine/scene/force_registry.hpp"
#include "engine/scene/scene.hpp"

namespace {

constexpr int kExitBadInput = 2;
constexpr int kExitNumerical = 3;

// One line, whatever the message held.
std::string one_line(std::string s) {
  std::replace(s.begin(), s.end(), '\n', ' ');
  std::replace(s.begin(), s.end(), '\t', ' ');
  return s;
}

struct TerminalFlags {
  bool quiet = false, no_progress = false;
};

// `stiffmd run` of an [ensemble] deck, whose members' decks all loaded (load_members: a bad value
// fails before any output, on every process alike); process r of N runs members r, r + N, … (N at most the member
// count: within a member there is no domain decomposition yet). One process alone prints each member's thermo lines as
// a plain run does, under a line naming the member; several print no thermo lines and no progress (they would
// interleave) and prefix each note and warning with the member. Errors come as "error: member k (…): …" on stderr when
// they happen; at the end rank 0 prints one line per member on stdout, and the job exits with the code of the first
// member (by index) that failed.
int run_ensemble(stiffmd::Processes& processes, const stiffmd::EnsembleJob& job, TerminalFlags flags) {
  const int members = job.members(), ranks = processes.size();
  const int groups = std::min(ranks, members);
  const int group = processes.split(groups);
  const bool speaker = processes.rank() == 0;
  if (speaker)
    std::cout << "stiffmd " STIFFMD_VERSION ": " << job.deck_path << " -> " << job.out_dir << " (" << members
              << " members on " << ranks << (ranks == 1 ? " process" : " processes") << ")\n"
              << std::flush;
  std::ostringstream outcomes;  // "member<TAB>exit code<TAB>line" per member run here
  for (int k = group; k < members; k += groups) {
    stiffmd::MemberOutcome o;
    if (ranks == 1) {
      std::cout << job.member_name(k) << " -> " << job.member_dir(k) << "\n" << std::flush;
      o = stiffmd::run_member(job, k, {flags.quiet ? nullptr : stdout, !flags.quiet && !flags.no_progress}, std::cerr);
    } else {
      std::ostringstream log;
      o = stiffmd::run_member(job, k, {}, log);
      std::istringstream lines(log.str());
      for (std::string line; std::getline(lines, line);) std::cerr << job.member_name(k) << ": " << line << "\n";
    }
    if (o.exit_code != 0) std::cerr << "error: " << one_line(o.line) << "\n" << std::flush;
    outcomes << k << '\t' << o.exit_code << '\t' << one_line(o.line) << '\n';
    if (o.exit_code > 128) break;  // stopped by a signal: this process starts no other member
  }
  int code = 0;
  std::vector<std::tuple<int, int, std::string>> by_member;  // member, exit code, line
  for (const std::string& text : processes.gather(outcomes.str())) {
    std::istringstream rows(text);
    for (std::string row; std::getline(rows, row);) {
      const auto a = row.find('\t'), b = row.find('\t', a + 1);
      by_member.emplace_back(std::stoi(row.substr(0, a)), std::stoi(row.substr(a + 1, b - a - 1)), row.substr(b + 1));
    }
  }
  std::sort(by_member.begin(), by_member.end());
  for (const auto& [k, exit_code, line] : by_member) {
    if (exit_code == 0)
      std::cout << line << "\n";
    else
      std::cout << job.member_name(k) << ": failed (exit " << exit_code << ")\n";
    if (code == 0) code = exit_code;
  }
  if (speaker && static_cast<int>(by_member.size()) < members)
    std::cout << members - static_cast<int>(by_member.size()) << " members not run (stopped by a signal)\n";
  return processes.broadcast(code);
}

// The outcome of what each process did alone (exit code, 0 for none, and its message), agreed:
// every process gets the code of the lowest process that failed and, in `problem`, its message
// (prefixed "rank r: " when that is not rank 0). Collective.
int agreed_outcome(const stiffmd::Processes& processes, int code, std::string& problem) {
  const stiffmd::Communicator& c = processes.communicator();
  const stiffmd::Communicator::Problem first = c.first_problem(code != 0 ? problem : std::string());
  if (first.rank < 0) return 0;
  std::int64_t agreed = first.rank == c.rank() ? code : std::numeric_limits<std::int64_t>::max();
  c.min(&agreed, 1);
  problem = first.said();
  return static_cast<int>(agreed);
}

// What an [ensemble] deck cannot do with this command line (the same on every process).
void check_ensemble_command(const stiffmd::EnsembleJob& job, const std::string& restart, bool check,
                            const std::string& data_path, int ranks) {
  const stiffmd::Ensemble& ensemble = job.ensemble;
  if (!restart.empty())
    throw stiffmd::InputError(ensemble.where + ": --restart continues one run, and [ensemble] makes " +
                              std::to_string(job.members()) +
                              ": members do not restart yet (run a member's checkpoint, DIR/member_k/"
                              "checkpoint.bin, with a deck without [ensemble] and the member's --set)");
  if (check && !data_path.empty())
    throw stiffmd::InputError(ensemble.where + ": --write-data writes one scene, and [ensemble] makes " +
                              std::to_string(job.members()));
  if (!check && ranks > job.members())
    throw stiffmd::InputError(
        ensemble.where + ": " + std::to_string(ranks) + " processes for " + std::to_string(job.members()) +
        " members: domain decomposition within a member is not built yet; use at most " +
        std::to_string(job.members()) + " processes (mpiexec -n " + std::to_string(job.members()) + ")");
}

}  // namespace

// `stiffmd list`: the methods, force styles, thermostats and builders a deck may name; `--help`
// says where to find them.
CLI::App* add_list_command(CLI::App& app) {
  app.footer("Methods, force styles, thermostats and builders: stiffmd list");
  return app.add_subcommand("list", "list the integrator methods, force styles, thermostats and builders");
}

// " (rank r)" for a message of one rank of a decomposed run.
std::string rank_tag(const stiffmd::Processes& p, bool decomposed) {
  return decomposed ? " (rank " + std::to_string(p.rank()) + ")" : "";
}

int main(int argc, char** argv) {
  // The set-up time counts from here (summary.json setup_seconds): MPI's start-up, the deck, the scene.
  const double started_at = std::chrono::duration<double>(std::chrono::steady_clock::now().time_since_epoch()).count();
  stiffmd::Processes processes(argc, argv);
  // What every process finds alike (a bad deck, a bad command line) is printed by rank 0 alone.
  const bool speaker = processes.rank() == 0;
  CLI::App app{"stiffmd " STIFFMD_VERSION
               " - molecular dynamics with stiff bonds: impulse, mollified and projected impulse,\n"
               "RATTLE, velocity Verlet and the effective (eps -> 0) dynamics"};
  // The version and what this build can do on many cores and processes (README, "Running on many
  // cores and machines").
#ifdef _OPENMP
  const std::string threads = "OpenMP";
#else
  const std::string threads = "one";
#endif
#ifdef STIFFMD_MPI
  const std::string ranks = "MPI";
#else
  const std::string ranks = "one";
#endif
  const std::string build = " (threads: " + threads + "; processes: " + ranks +
                            "; H5MD written by every rank: " + (stiffmd::H5mdWriter::shared_files() ? "yes" : "no") +
                            ")";
  app.set_version_flag("--version", "stiffmd " STIFFMD_VERSION + build);
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

  CLI::App* list = add_list_command(app);

  CLI::App* check = app.add_subcommand("check", "validate a deck and print what the scene contains");
  check->add_option("deck", deck_path, "deck file (TOML)")->required();
  check->add_option("--set", overrides, "override a deck key")->take_all();
  std::string data_path;
  check->add_option("--write-data", data_path,
                    "write the prepared initial state (after [prepare]) as a LAMMPS data file");

  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    // A first word that is no subcommand: CLI11 would say only that one is required.
    if (argc > 1 && argv[1][0] != '-' && app.get_subcommands().empty()) {
      const std::string typed = argv[1];
      const std::string nearest =
          stiffmd::nearest_name(typed, {run->get_name(), check->get_name(), list->get_name()}, true);
      if (speaker)
        std::cerr << "error: unknown subcommand '" << typed << "'"
                  << (nearest.empty() ? "; expected run, check or list" : "; did you mean '" + nearest + "'?") << "\n";
      return kExitBadInput;
    }
    const int code = speaker ? app.exit(e) : e.get_exit_code();
    return code == 0 ? 0 : kExitBadInput;
  }
  if (list->parsed()) {
    if (speaker) std::cout << stiffmd::list_styles();
    return 0;
  }

  // Each process first does alone what needs no other (the deck, the scene, a restart's
  // checkpoint, [prepare]; check's whole work); what it found is agreed before the first collective
  // call (docs/parallel.md, "Errors"), so that a process that fails there, and only there (a file
  // its machine cannot read), ends every process with its message instead of leaving them waiting.
  std::optional<stiffmd::Deck> deck;
  std::optional<stiffmd::EnsembleJob> job;
  std::optional<stiffmd::Scene> scene;
  std::optional<stiffmd::Checkpoint> checkpoint;
  std::optional<stiffmd::Protocol> protocol;  // a deck with [[stage]] tables (engine/run/stages.hpp)
  std::string description;                    // check's of a protocol
  stiffmd::PartMaker source = nullptr;        // a decomposed run's parts made by their source
  std::ostringstream quiet_log, check_log;
  std::ostream& log = speaker ? std::cerr : quiet_log;
  const bool decomposed = processes.size() > 1;
  {
    int code = 0;
    std::string problem;
    try {
      if (!processes.problem().empty()) throw stiffmd::InputError(processes.problem());
      deck.emplace(deck_path, overrides);
      stiffmd::DeckTable root = deck->root();
      std::ostream* progress = quiet || !run->parsed() || !speaker ? nullptr : &std::cerr;
      if (auto stages = stiffmd::read_stages(root); !stages.empty()) {
        // Every stage loaded (a bad value in any stage fails now, before stage 1 runs), on every
        // rank alike; then the first stage's state: prepared, or a restart's.
        protocol.emplace(stiffmd::load_protocol(*deck, std::move(stages), processes.size()));
        for (const auto& note : protocol->notes) log << note << "\n";
        if (check->parsed())
          description = stiffmd::check_protocol(*protocol, check_log);
        else if (!restart.empty())
          stiffmd::resume_protocol(*protocol, restart, log, progress);
        else
          stiffmd::start_protocol(*protocol, log, progress);
      } else if (auto ensemble = stiffmd::read_ensemble(root)) {
        if (out_dir.empty())
          out_dir = (std::filesystem::path("out") / std::filesystem::path(deck_path).stem()).string();
        job.emplace(stiffmd::EnsembleJob{deck_path, overrides, *ensemble, out_dir, processes.size()});
        check_ensemble_command(*job, restart, check->parsed(), data_path, processes.size());
        if (check->parsed())
          stiffmd::check_members(*job, check_log);
        else
          stiffmd::load_members(*job);
      } else {
        // On several processes one run is decomposed (docs/parallel.md): every rank loads and
        // prepares the whole scene alike, rank 0 alone speaks and writes.
        // A fresh decomposed run loads the deck's description first (engine/scene/scene.hpp:
        // SceneContent::description, by-molecule chains counted, not built): when a source makes
        // every particle by parts and the run needs nothing of the whole scene, no rank builds it
        // (docs/parallel.md, "The scene's description"); else the whole scene, as everywhere. So
        // does a decomposed restart from a checkpoint of format 8 on (whose fingerprint the parts
        // give): it reads the checkpoint by parts, each rank its molecules' rows, never the whole
        // file (docs/parallel.md, "A restart by parts").
        const bool fresh_run = decomposed && run->parsed() && restart.empty();
        const bool restart_run =
            decomposed && run->parsed() && !restart.empty() &&
            stiffmd::checkpoint_format_version(restart) >= stiffmd::kFirstFingerprintByDescriptions;
        const auto content =
            fresh_run || restart_run ? stiffmd::SceneContent::description : stiffmd::SceneContent::whole;
        try {
          scene.emplace(stiffmd::load_scene(*deck, {}, content));
        } catch (const stiffmd::InputError&) {
          // A data file's description reads its structure in the reader by parts' words: rank 0,
          // whose message the agreement prints, words the fault as the whole load does (the
          // whole import's message; its own when the whole load accepts the deck).
          if (content != stiffmd::SceneContent::description || processes.communicator().rank() != 0 ||
              !deck->root().gives("import"))
            throw;
          stiffmd::load_scene(*deck);
          throw;
        }
        if (scene->described() &&
            (!stiffmd::part_source(*deck, *scene).make || !stiffmd::whole_scene_needed(*scene).empty() ||
             (restart_run && scene->state.size() != 0)))
          scene.emplace(stiffmd::load_scene(*deck));
        const bool restart_by_parts = restart_run && scene->described();
        if (decomposed) {  // every rank alike, before the run
          stiffmd::check_parallel_grid(*scene, processes.size());
          stiffmd::check_parallel_outputs(*scene, processes.size());
        }
        // A restart's checkpoint is checked (format, checksum, version, scene) before anything is
        // printed or written: a damaged or foreign one is one line and exit 2.
        if (run->parsed() && !restart.empty() && !restart_by_parts)
          checkpoint = stiffmd::read_checkpoint_for(*scene, restart);
        for (const auto& note : scene->notes) log << note << "\n";
        // A fresh decomposed run of a deck whose particles a source makes by parts starts from
        // each rank's own molecules (engine/domain/part_load.hpp), not from the whole scene's cut;
        // its [prepare] and [minimize] are the Run's, on the parts after the start.
        // A restart by parts takes its molecules from the source too, their state from the checkpoint.
        if (fresh_run || restart_by_parts) source = stiffmd::part_source(*deck, *scene).make;
        if (restart.empty() && !source)  // a restart's state is the checkpoint's
          stiffmd::prepare_scene(*scene, log, progress);
        if (check->parsed()) stiffmd::check_run(*scene, check_log);  // the method's notes belong to a run's log
      }
    } catch (const stiffmd::InputError& e) {
      code = kExitBadInput, problem = e.what();
    } catch (const stiffmd::NumericalError& e) {
      code = kExitNumerical, problem = e.what();
    } catch (const std::exception& e) {
      code = 1, problem = e.what();
    }
    if (decomposed || job) code = agreed_outcome(processes, code, problem);
    if (code != 0) {
      if (speaker) std::cerr << (code == 1 ? "internal error: " : "error: ") << problem << "\n";
      return code;
    }
  }

  bool running = false;  // a decomposed run's Run is being built or stepped: its errors may be one rank's
  try {
    if (job) {
      if (check->parsed()) {
        if (speaker) {
          std::cout << "ensemble:    " << job->members() << " members, varying";
          for (const auto& list : job->ensemble.varied) std::cout << " " << list.key;
          std::cout << "\ndeck is valid\n";
        }
        return 0;
      }
      return run_ensemble(processes, *job, {quiet, no_progress});
    }
    if (check->parsed()) {
      if (!speaker) return 0;
      std::cout << (protocol ? description : stiffmd::describe(*scene)) << "deck is valid\n";
      if (!data_path.empty()) {
        stiffmd::write_scene_lammps_data(protocol ? *protocol->scene : *scene, data_path,
                                         "stiffmd " STIFFMD_VERSION " initial state of " + deck_path);
        std::cout << "initial state written to " << data_path << "\n";
      }
      return 0;
    }
    if (out_dir.empty()) out_dir = (std::filesystem::path("out") / std::filesystem::path(deck_path).stem()).string();
    if (speaker) std::cout << "stiffmd " STIFFMD_VERSION ": " << deck_path << " -> " << out_dir << "\n" << std::flush;
    if (protocol) {  // the stages one after the other, each into OUT/<k>_<name>
      stiffmd::RunOptions options{out_dir, speaker && !no_progress && !quiet, "", nullptr,
                                  speaker && !quiet ? stdout : nullptr};
      if (decomposed) options.processes = &processes.communicator();
      running = decomposed;
      const stiffmd::ProtocolOutcome outcome =
          stiffmd::run_protocol(*protocol, options, log, speaker ? stdout : nullptr);
      const int sig = outcome.stopped_by_signal;
      if (!speaker) return sig ? 128 + sig : 0;
      if (sig) {
        std::cerr << "stopped by signal " << sig << " " << outcome.where << "; outputs flushed, checkpoint "
                  << outcome.checkpoint << "; continue with: stiffmd run " << deck_path << " -o " << out_dir
                  << " --restart " << outcome.checkpoint << " (and the same --set)\n";
        return 128 + sig;
      }
      std::cout << "protocol:      " << protocol->count() << " stages; " << outcome.protocol_json << "\n";
      return 0;
    }
    stiffmd::RunOptions options{out_dir, speaker && !no_progress && !quiet, restart,
                                checkpoint ? &*checkpoint : nullptr, speaker && !quiet ? stdout : nullptr};
    if (decomposed) options.processes = &processes.communicator();
    // A restart by parts takes its molecules' state from the checkpoint (Run::Run); the others,
    // and a restart with the whole scene (the checkpoint's state, read whole), start from the
    // whole scene's cut.
    if (source) options.part = [&] { return source(*deck, *scene, processes.communicator()); };
    options.started_at = started_at;
    running = decomposed;
    const auto summary = stiffmd::run_simulation(*scene, options, log);
    if (!speaker) return summary.stopped_by_signal ? 128 + summary.stopped_by_signal : 0;
    if (summary.stopped_by_signal) {
      std::cerr << "stopped by signal " << summary.stopped_by_signal << " after step " << summary.steps
                << "; outputs flushed, checkpoint " << summary.checkpoint << "; continue with: stiffmd run "
                << deck_path << " -o " << out_dir << " --restart " << summary.checkpoint << " (and the same --set)\n";
      return 128 + summary.stopped_by_signal;
    }
    std::cout << stiffmd::format_summary(summary);
    return 0;
  } catch (const stiffmd::AgreedInputError& e) {  // every rank stops here; rank 0 says why
    if (e.printed_here()) std::cerr << "error: " << e.what() << "\n";
    return kExitBadInput;
  } catch (const stiffmd::InputError& e) {
    // Within a decomposed run an error not agreed is this rank's alone, and the others wait for it
    // in a collective: it says so, and the job ends (no collective clean-up on the way: the shared
    // H5MD file is left as a killed writer's, H5mdWriter::close).
    if (speaker || running) std::cerr << "error" << rank_tag(processes, running) << ": " << e.what() << "\n";
    if (running) processes.abort(kExitBadInput);
    return kExitBadInput;
  } catch (const stiffmd::AgreedStop& e) {  // every rank stops here; rank 0 says why
    if (e.printed_here()) std::cerr << "error: " << e.what() << "\n";
    return kExitNumerical;
  } catch (const stiffmd::NumericalError& e) {
    // In a decomposed run this rank alone failed: it says so, and the job ends (the others wait
    // for it in a collective); rank 0's outputs so far are flushed frame by frame.
    if (speaker || running) std::cerr << "error" << rank_tag(processes, running) << ": " << e.what() << "\n";
    if (running) processes.abort(kExitNumerical);
    return kExitNumerical;
  } catch (const std::exception& e) {
    std::cerr << "internal error" << rank_tag(processes, decomposed) << ": " << e.what() << "\n";
    if (running) processes.abort(1);
    return 1;
  }
}
