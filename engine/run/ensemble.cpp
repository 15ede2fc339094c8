#include "engine/run/ensemble.hpp"

#include <filesystem>
#include <sstream>

#include "core/errors.hpp"
#include "engine/deck/deck.hpp"
#include "engine/run/run.hpp"
#include "engine/scene/scene.hpp"

namespace stiffmd {

namespace {

constexpr int kExitInternal = 1;
constexpr int kExitBadInput = 2;
constexpr int kExitNumerical = 3;

// [parallel] divides one run among processes; on several processes an ensemble runs each member
// whole on one of them, so a key there would do nothing: refused at the key, as a plain run
// refuses a grid that does not fit its processes.
void refuse_parallel_keys(const Scene& sc, const EnsembleJob& job) {
  if (job.processes < 2) return;  // on one process [parallel] is ignored by every deck alike
  const std::string why = ", and an [ensemble] runs each member whole on one process (" +
                          std::to_string(job.members()) + " members on " + std::to_string(job.processes) +
                          " processes): expected no ";
  const Eigen::Vector3i& g = sc.parallel.grid;
  if (!sc.parallel.grid_where.empty())
    throw InputError(sc.parallel.grid_where + ": " + std::to_string(g.prod()) + " domains (" + std::to_string(g[0]) +
                     " x " + std::to_string(g[1]) + " x " + std::to_string(g[2]) + ") divide one run among ranks" +
                     why + "grid (without [ensemble] one run is divided)");
  if (!sc.parallel.halo_margin_where.empty())
    throw InputError(sc.parallel.halo_margin_where + ": the halo of one run divided among ranks" + why +
                     "halo_margin (without [ensemble] one run is divided)");
  if (!sc.parallel.halo_pairs_where.empty())
    throw InputError(sc.parallel.halo_pairs_where + ": the halo of one run divided among ranks" + why +
                     "halo_pairs (without [ensemble] one run is divided)");
  if (!sc.parallel.balance_where.empty())
    throw InputError(sc.parallel.balance_where + ": the domains of one run divided among ranks" + why +
                     "balance (without [ensemble] one run is divided)");
}

// Member k's deck loaded. A failure at one of the member's values ("--set KEY" in the message,
// Deck::location) is named at the varied key's line, with the member: the line a user edits.
Scene load_member(const EnsembleJob& job, int k) {
  try {
    const Deck deck(job.deck_path, job.member_overrides(k));
    Scene scene = load_scene(deck);
    refuse_parallel_keys(scene, job);
    return scene;
  } catch (const InputError& e) {
    const std::string what = e.what();
    for (const auto& list : job.ensemble.varied)
      if (what.find("--set " + list.key) != std::string::npos)
        throw InputError(list.where + ": ensemble.vary." + list.key + ": " + job.member_name(k) + ": " + what);
    throw;
  }
}

}  // namespace

std::string EnsembleJob::member_dir(int k) const {
  const std::string digits = std::to_string(members());
  std::string index = std::to_string(k);
  index.insert(0, digits.size() - std::min(digits.size(), index.size()), '0');
  return (std::filesystem::path(out_dir) / ("member_" + index)).string();
}

std::vector<std::string> EnsembleJob::member_overrides(int k) const {
  std::vector<std::string> all = overrides;
  for (std::string& o : ensemble.overrides(k)) all.push_back(std::move(o));
  return all;
}

std::string EnsembleJob::member_name(int k) const {
  return "member " + std::to_string(k) + " (" + ensemble.label(k) + ")";
}

void load_members(const EnsembleJob& job) {
  for (int k = 0; k < job.members(); ++k) load_member(job, k);
}

void check_members(const EnsembleJob& job, std::ostream& log) {
  for (int k = 0; k < job.members(); ++k) {
    Scene scene = load_member(job, k);
    prepare_scene(scene, log);
    check_run(scene, log);
  }
}

MemberOutcome run_member(const EnsembleJob& job, int k, const MemberTerminal& terminal, std::ostream& log) {
  MemberOutcome out{k, 0, ""};
  const std::string dir = job.member_dir(k);
  const std::string name = job.member_name(k);
  try {
    Scene scene = load_member(job, k);
    for (const auto& note : scene.notes) log << note << "\n";
    prepare_scene(scene, log, terminal.progress ? &log : nullptr);
    RunOptions options;
    options.out_dir = dir;
    options.progress = terminal.progress;
    options.screen = terminal.screen;
    const RunSummary s = run_simulation(scene, options, log);
    std::ostringstream line;
    line.precision(6);
    line << name << " -> " << dir << ": " << s.steps << " steps to t = " << s.t_end << " in " << s.wall_seconds
         << " s wall";
    if (s.stopped_by_signal) {
      out.exit_code = 128 + s.stopped_by_signal;
      line << ", stopped by signal " << s.stopped_by_signal << " (checkpoint " << s.checkpoint << ")";
    }
    out.line = line.str();
  } catch (const InputError& e) {
    out = {k, kExitBadInput, name + ": " + e.what()};
  } catch (const NumericalError& e) {
    out = {k, kExitNumerical, name + ": " + e.what()};
  } catch (const std::exception& e) {
    out = {k, kExitInternal, name + ": internal error: " + e.what()};
  }
  return out;
}

}  // namespace stiffmd
