#include "engine/run/run.hpp"

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <optional>
#include <sstream>

#include "core/errors.hpp"
#include "core/finite.hpp"
#include "core/parallel.hpp"
#include "core/peak_memory.hpp"
#include "engine/observe/histograms.hpp"
#include "integrators/methods.hpp"

namespace stiffmd {
namespace fs = std::filesystem;

namespace {

// Writes the file whole or not at all: a temporary file renamed into place.
void write_atomically(const fs::path& p, const std::string& text) {
  const fs::path tmp = p.string() + ".tmp";
  {
    std::ofstream out(tmp);
    out << text;
    if (!out) throw InputError(tmp.string() + ": write failed");
  }
  fs::rename(tmp, p);
}

// The observables as the run counts them: the rigid constraints of the constrained methods take
// one degree of freedom each; what a resonance of the stiff modes means depends on the method.
ObservableSettings run_observables(const Scene& sc) {
  ObservableSettings observables = sc.observables;
  const MethodInfo& method = *find_method(sc.integrator.method);
  if (method.rigid_constraints)
    observables.rigid_constraints = static_cast<int>(whole_stiff_bonds(sc));
  observables.resonances = method.follows_effective   ? ObservableSettings::Resonances::effective
                           : method.rigid_constraints ? ObservableSettings::Resonances::none
                                                      : ObservableSettings::Resonances::actions;
  observables.fixman = method.needs_temperature;  // its model potential is a free energy: Fixman's U_F
  return observables;
}

// A scene of descriptions holds no particle: a decomposed run's parts are made by their source
// (RunOptions::part) and every number of the whole system is summed from them.
bool described(const Scene& sc, const RunOptions& opt) {
  return opt.part && sc.state.size() == 0;
}

// The thermo row's first Thermo: from the whole scene's masses and topology, or, for a scene of
// descriptions, of no particle until the parts' numbers replace it (Run::Run, after the start).
Thermo first_thermo(const Scene& sc, const RunOptions& opt) {
  if (described(sc, opt)) return Thermo(*sc.forces, ThermoNumbers{}, run_observables(sc));
  return Thermo(*sc.forces, sc.state.inv_mass, run_observables(sc), &sc.topology);
}

// A restart's checkpoint, read and checked against the scene (which loads the force terms'
// states) before anything else: a damaged or foreign one is refused before any output is touched.
// A restart of a scene of descriptions reads its checkpoint by parts once its integrator is made
// (Run::Run: CheckpointParts needs the integrator's layout of words).
Checkpoint resumed_checkpoint(Scene& sc, const RunOptions& opt) {
  if (opt.restart.empty() || described(sc, opt)) return {};
  return opt.checkpoint ? *opt.checkpoint : read_checkpoint_for(sc, opt.restart);
}

// The run's integrator: the deck's method, on more than one process wrapped in the decomposition
// (engine/domain/domain_integrator.hpp).
std::unique_ptr<Integrator> run_integrator(Scene& sc, const RunOptions& opt) {
  std::unique_ptr<Integrator> method = make_integrator(sc.integrator, *sc.forces, sc.state.inv_mass);
  if (!opt.processes || opt.processes->size() == 1) return method;
  return std::make_unique<DomainIntegrator>(sc, *opt.processes, std::move(method));
}

double seconds_now() {
  return std::chrono::duration<double>(std::chrono::steady_clock::now().time_since_epoch()).count();
}

}  // namespace

namespace {

bool finite_state(const State& s) {
  // Below kParallelMin particles every loop is serial at any thread count: one pass over x and v,
  // without the blocks' run_parts, their 64-bit divisions and Eigen's allFinite on blocks of
  // dynamic size (at the pendulum's 18 values ≈ 10 ns a step against ≈ 23 ns with them:
  // docs/performance.md, "The run loop's cost per step").
  if (s.size() < kParallelMin) return all_finite(s.x.data(), s.x.size()) && all_finite(s.v.data(), s.v.size());
  // In the particle blocks of the threads, as the integrators write x and v: read serially, the
  // blocks the other threads had just written came over from their cores. Each block by the
  // one-pass four-sum test (core/finite.hpp), as the ranks do, not Eigen's allFinite, which tests
  // value by value (docs/parallel.md, "Work figures").
  const int parts = threads_for(s.size());
  std::array<char, kMaxParts> finite{};
  run_parts(parts, [&](int u) {
    const std::int64_t b = block_begin(s.size(), parts, u), e = block_begin(s.size(), parts, u + 1);
    finite[u] = all_finite(s.x.data() + 3 * b, 3 * (e - b)) && all_finite(s.v.data() + 3 * b, 3 * (e - b));
  });
  return std::all_of(finite.begin(), finite.begin() + parts, [](char f) { return f != 0; });
}

}  // namespace

void check_finite(const State& s) {
  if (finite_state(s)) return;
  int bad = 0;
  while (bad < s.size() && s.x.col(bad).allFinite() && s.v.col(bad).allFinite()) ++bad;
  std::ostringstream m;
  m.precision(10);
  m << "numerical failure: non-finite position or velocity of particle " << bad << " at step " << s.step
    << " (t = " << s.t << "); reduce integrator.h or micro_dt";
  throw NumericalError(m.str());
}

namespace {
// The failure of step k from the state s, named: out of take_step, which runs every step.
[[noreturn, gnu::noinline, gnu::cold]] void throw_step_failure(const NumericalError& e, std::int64_t k,
                                                               const State& s) {
  std::ostringstream m;
  m.precision(10);
  m << "numerical failure in step " << k << " (from t = " << s.t << "): " << e.what();
  if (const auto* agreed = dynamic_cast<const AgreedStop*>(&e)) throw AgreedStop(m.str(), agreed->printed_here());
  throw NumericalError(m.str());
}
}  // namespace

void take_step(Integrator& integrator, State& s, double h, std::int64_t k, double t_k, bool check) {
  try {
    integrator.step(s, h);
  } catch (const NumericalError& e) {
    throw_step_failure(e, k, s);
  }
  s.step = k;
  s.t = t_k;
  if (check && !integrator.checked_finite()) check_finite(s);
}

Run::Run(Scene& sc, const RunOptions& opt, std::ostream& log)
    : sc_(sc),
      has_kspace_(std::any_of(sc.forces->terms().begin(), sc.forces->terms().end(),
                              [](const auto& t) { return t->phase() == Phase::kspace; })),
      s_(sc.state),
      options_(opt),
      log_(log),
      resumed_(resumed_checkpoint(sc, opt)),
      integrator_(run_integrator(sc, opt)),
      domain_(dynamic_cast<DomainIntegrator*>(integrator_.get())),
      thermo_(first_thermo(sc, opt)),
      monitor_(sc.monitor, thermo_, sc.forces->stiff_bonds() ? sc.forces->stiff_bonds()->epsilon : 0.0,
               find_method(sc.integrator.method)->effective),
      stats_(sc.forces->num_levels()),
      h_(sc.integrator.h) {
  described_ = described(sc, opt);
  if (described_ && !domain_)
    throw std::logic_error("Run: a scene of descriptions is a decomposed run's, started from its parts");
  summary_.method = sc.integrator.method;
  summary_.units = sc.units.name;
  summary_.stage = sc.stage;
  summary_.h = sc.integrator.h * sc.units.out(Dimension::time);
  summary_.micro_steps = sc.integrator.micro_steps;
  summary_.t_end = sc.run.t_end * sc.units.out(Dimension::time);
  if (const StiffBonds* sb = sc.forces->stiff_bonds()) summary_.epsilon = sb->epsilon;
  if (opt.restart.empty()) summary_.minimize = sc.minimized;

  const bool restarting = !opt.restart.empty();
  auto refuse = [&](const std::string& what) { throw InputError(opt.restart + ": " + what); };
  // A restart by parts (docs/parallel.md, "A restart by parts"): every rank reads the checkpoint's
  // blocks that are not per particle, and later the rows of its particles alone; what
  // read_checkpoint_for checks and loads besides the state and the fingerprint is checked here,
  // every rank alike (agreed: a refusal is one line on every rank).
  std::unique_ptr<CheckpointParts> checkpoint_parts;
  if (restarting && described_) {
    checkpoint_parts =
        std::make_unique<CheckpointParts>(opt.restart, *opt.processes, domain_->word_layout(), sc.integrator.method);
    resumed_ = checkpoint_parts->rest();
    agree(opt.processes, [&] { load_checkpoint_rest(sc, resumed_, opt.restart); });
  }
  bool prepare_integrator = false;  // a fresh start, or a restart with another method
  if (restarting) {
    // By parts: every rank alike, agreed.
    agree(checkpoint_parts ? opt.processes : nullptr, [&] {
      if (resumed_.method == sc.integrator.method) try {
          integrator_->load_state(resumed_.integrator_state);
        } catch (const std::invalid_argument& e) {
          refuse(e.what());
        }
      if (!thermo_.load_state(resumed_.thermo_state)) refuse("thermo state does not fit this scene's observables");
      if (const std::string e = stats_.load(resumed_.run_state); !e.empty()) refuse(e);
    });
    if (!monitor_.load_state(resumed_.monitor_state))  // [observables] actions changed with --set
      log << "note: " << opt.restart << ": the monitor's reference is taken afresh (the actions observed changed)\n";
    summary_.initial_actions = stats_.initial_actions;
    // The scene's state becomes the checkpoint's; the deck supplies everything else. With another
    // method the integrator starts afresh from that state.
    s_ = resumed_.state;
    if (resumed_.method != sc.integrator.method || resumed_.h != sc.integrator.h)
      log << "note: " << opt.restart << " was written by " << resumed_.method << " with h = " << resumed_.h
          << "; continuing with " << sc.integrator.method << ", h = " << sc.integrator.h
          << " (not bit-identical to an uninterrupted run)\n";
    if (resumed_.method != sc.integrator.method) prepare_integrator = true;  // else: its state is loaded
  } else {
    prepare_integrator = true;
  }
  // A rigid method projects its initial data (Rattle::prepare); a start from the source's parts
  // projects the parts once they exist (DomainIntegrator::project_parts), as no rank holds the
  // whole state.
  const bool rigid = find_method(sc.integrator.method)->rigid_constraints;
  const bool project_parts = prepare_integrator && rigid && domain_ && opt.part;
  if (prepare_integrator && !project_parts) integrator_->prepare(s_, log);
  if (restarting) log << "restart from " << opt.restart << " at step " << s_.step << " (t = " << s_.t << ")\n";

  const bool new_h = restarting && s_.t != static_cast<double>(s_.step) * h_;
  t0_ = new_h ? s_.t : 0.0;
  k0_ = new_h ? s_.step : 0;
  first_action_ = thermo_.column("action_1");
  num_actions_ = thermo_.modes() ? thermo_.modes()->num_modes() : 0;
  sc.forces->reset_counters();
  // The list is built before the run (relaxation, first force); on restart the rebuilds of the
  // run so far come from the checkpoint.
  for (const auto& term : sc.forces->terms()) rebuilds_at_start_ += term->neighbor_list_rebuilds();
  check_finite(s_);
  // The scene's fingerprint (the checkpoint's), of the scene as the deck made it: from here on a
  // decomposed run's whole scene need not hold its particles.
  if (!described_) fingerprint_ = scene_fingerprint(sc);
  // A decomposed run's parts are built now, before the first sample: each rank then evaluates
  // the forces of its part only, and the whole system's force terms never build a neighbour list
  // or a pair buffer on a rank (docs/parallel.md, "What a rank holds").
  if (domain_ && opt.part) {
    ScenePart mine = opt.part();
    // A scene of descriptions has no particle to take the fingerprint of: the parts give it
    // (the same value, summed by blocks: engine/run/checkpoint.hpp).
    if (described_) fingerprint_ = scene_fingerprint_parts(sc, mine.molecules, *opt.processes);
    if (checkpoint_parts) {
      // The restart's state of these molecules: their rows of x, v (the source's are the fresh
      // run's), their inverse masses checked against theirs, and the scene's fingerprint against
      // the checkpoint's, as read_checkpoint_of checks the whole scene's; the integrator's
      // carried columns of the particles each rank owns once the molecules are at their owners.
      std::int64_t count = mine.molecules.size();
      opt.processes->sum(&count, 1);
      if (count != checkpoint_parts->num_particles())
        throw AgreedInputError(opt.restart + ": checkpoint holds " + std::to_string(checkpoint_parts->num_particles()) +
                                   " particles, the deck " + std::to_string(count) + ": not a checkpoint of this scene",
                               root());
      Eigen::VectorXd inv_mass;
      checkpoint_parts->particles(mine.molecules.global, mine.x, mine.v, inv_mass);
      agree(opt.processes, [&] {
        if (!std::equal(mine.molecules.inv_mass.begin(), mine.molecules.inv_mass.end(), inv_mass.data(),
                        inv_mass.data() + inv_mass.size()))
          refuse("checkpoint masses differ from the deck's: not a checkpoint of this scene");
      });
      if (fingerprint_ != resumed_.scene_fingerprint)
        throw AgreedInputError(opt.restart +
                                   ": checkpoint of another scene (particle types, topology, box, levels or their "
                                   "kicks, force terms or their parameters differ from the deck's)",
                               root());
      const bool carries = resumed_.method == sc.integrator.method;
      const DomainIntegrator::CarriedRows rows = [&](const std::vector<int>& ids) {
        return checkpoint_parts->columns(ids);
      };
      if (carries)
        domain_->distribute(std::move(mine.molecules), std::move(mine.x), std::move(mine.v), s_, rows);
      else
        domain_->distribute(std::move(mine.molecules), std::move(mine.x), std::move(mine.v), s_);
    } else {
      domain_->distribute(std::move(mine.molecules), std::move(mine.x), std::move(mine.v), s_);
    }
  } else if (domain_) {
    domain_->distribute(s_);
  }
  if (domain_) summary_.domain_setup = opt.part ? "parts" : "whole";
  if (domain_) summary_.domain_scene = described_ ? "description" : "whole";
  // A description holds no position of its counted chains: the whole load's check for
  // overlapping particles is made on the parts now, with the same message (exit 2), unless
  // [minimize] relaxes them (as load_scene lets it).
  if (domain_ && opt.part && !restarting && !sc.overlap_rules.empty() && !sc.minimize.requested && sc.stage.number <= 1)
    if (const std::string found = domain_->overlaps(sc); !found.empty()) throw AgreedInputError(found, root());
  // A start from the source's parts leaves [prepare] and [minimize] to the parts (one process's
  // positions and velocities bit for bit: engine/domain/part_prepare.cpp, part_minimize.cpp) in
  // prepare_scene's order — project and relax, minimise, thermalise the bonds — then a rigid
  // method's projection; the parts then start afresh from the prepared molecules, as the whole
  // path starts from its prepared scene.
  if (domain_ && opt.part && !restarting) {
    const PrepareTable& p = sc.prepare;
    const bool vibrate_after = p.requested && sc.minimize.requested && p.vibrational_temperature > 0.0;
    std::ostream* progress = root() && opt.progress ? &std::cerr : nullptr;
    auto prepare = [&](const PrepareSettings& settings) {
      try {
        const std::string note = domain_->prepare_parts(settings, progress);
        if (!note.empty()) log << note << "\n";
      } catch (const AgreedInputError& e) {
        throw AgreedInputError(p.where + ": " + e.what(), e.printed_here());
      }
    };
    if (p.requested) {
      PrepareSettings first = p;
      if (vibrate_after) first.vibrational_temperature = 0.0;
      prepare(first);
    }
    if (sc.minimize.requested && !sc.minimized) {
      try {
        sc.minimized = domain_->minimize(sc.minimize, progress);
      } catch (const AgreedStop& e) {  // every rank's: each stops here, rank 0 says why (exit 3)
        throw AgreedStop(sc.minimize.where + ": " + e.what(), e.printed_here());
      } catch (const NumericalError& e) {  // this rank's alone (a bond past its range): it ends the job (exit 3)
        throw NumericalError(sc.minimize.where + ": " + e.what());
      }
      log << describe(*sc.minimized) << "\n";
      summary_.minimize = sc.minimized;
    }
    if (vibrate_after) {
      PrepareSettings vibrate = p;
      vibrate.project = false;
      vibrate.relax_steps = 0;
      prepare(vibrate);
    }
  }
  if (project_parts) log << domain_->project_parts() << "\n";
  if (project_parts || (domain_ && opt.part && !restarting && (sc.prepare.requested || sc.minimize.requested)))
    domain_->start_again();
  // The particle count as the parts sum it (the whole scene's on one process): the Run, its
  // outputs and the checkpoint read no whole array once the parts exist.
  num_particles_ = domain_ ? domain_->whole_particles() : s_.size();
  // A row summed by parts takes its columns from the whole system's numbers as the parts summed
  // them (the degrees of freedom, whether there are rg and end_to_end columns), not from the whole
  // scene's masses and topology: the same columns, its state and the monitor's carried over.
  // A scene of descriptions has only these (nothing was sampled yet: no state to carry over).
  if (described_ && !sampled_by_parts())
    throw std::logic_error("Run: a scene of descriptions whose thermo row cannot be summed by parts");
  if (sampled_by_parts()) {
    Thermo by_parts(*sc.forces, domain_->thermo_numbers(), run_observables(sc));
    if (!described_ &&
        (by_parts.columns() != thermo_.columns() || by_parts.degrees_of_freedom() != thermo_.degrees_of_freedom()))
      throw std::logic_error("Run: the thermo row's columns from the parts are not the whole scene's");
    if (!described_ || restarting) by_parts.load_state(thermo_.save_state());
    Monitor monitor(sc.monitor, by_parts, sc.forces->stiff_bonds() ? sc.forces->stiff_bonds()->epsilon : 0.0,
                    find_method(sc.integrator.method)->effective);
    if (!described_ || restarting) monitor.load_state(monitor_.save_state());
    thermo_ = std::move(by_parts);
    monitor_ = std::move(monitor);
  }
  if (domain_ && opt.started) opt.started();
  if (!restarting) {  // E(0) and the initial actions
    const double model = integrator_->model_potential(s_.x), virial = integrator_->constraint_virial(s_);
    const double kinetic = integrator_->kinetic_energy_estimate(s_), heat = integrator_->thermostat_heat();
    std::optional<ThermoSums> parts;
    if (sampled_by_parts()) parts = domain_->sample_sums();
    // The row is rank 0's, as at every later sample: a sample of the whole state (the actions) is
    // made there alone, with the whole system's terms.
    if (root()) {
      const auto& row = parts ? thermo_.sample(s_, *parts, model, virial, kinetic, heat)
                              : thermo_.sample(s_, model, virial, kinetic, heat);
      if (first_action_ >= 0) {
        stats_.initial_actions.assign(row.begin() + first_action_, row.begin() + first_action_ + num_actions_);
        summary_.initial_actions = stats_.initial_actions;
      }
    }
  }
  // A restart samples nothing here: E(0) and the initial actions come from the checkpoint, and
  // an extra evaluation would move the neighbour list on where the interrupted run did not.
  for (const auto& note : thermo_.take_notes()) log << note << "\n";

  // Outputs: fresh files, or on restart the same files cut back to the step before the
  // checkpoint, t_{k−1}; the frame at t_k is written again below if the uninterrupted run would
  // have written one. So the files end up exactly as an uninterrupted run's (without the
  // interrupted run's off-grid final frame).
  // Rank 0 prepares the directory; its outcome is agreed, so that it exists before any rank opens
  // the shared H5MD file in it and a failure ends every rank alike (docs/parallel.md, "Errors").
  agree(domain_ ? opt.processes : nullptr, [&] {
    if (!opt.out_dir.empty() && root()) prepare_output_directory(sc, opt.out_dir);
  });
  const double cut = new_h ? s_.t - resumed_.h : static_cast<double>(s_.step - 1) * h_;
  // A scene of descriptions: the trajectories' time-independent data from the parts' molecules.
  std::optional<StaticParts> parts;
  if (described_)
    parts.emplace(StaticParts{domain_->owned_molecules(), domain_->owned_state().x, domain_->owned_state().v});
  outputs_ =
      std::make_unique<RunOutputs>(sc, num_particles_, opt.out_dir, thermo_, restarting ? &cut : nullptr,
                                   summary_.outputs, log, domain_ ? opt.processes : nullptr, parts ? &*parts : nullptr);
  // The terminal: the thermo lines (from the rows the thermo file gets) and the progress bar.
  bool levels = false;
  for (const auto& term : sc.forces->terms()) levels |= term->level() == Level::fast;
  screen_ = std::make_unique<ThermoScreen>(outputs_->thermo_table(), sc.output.screen_interval, opt.screen, levels);
  if (restarting) screen_->served_until(cut);
  col_total_ = thermo_.column("total");
  col_drift_ = thermo_.column("energy_drift");
  col_econserve_ = thermo_.column("econserve");
  col_violation_ = thermo_.column("max_violation");
  col_alerts_ = thermo_.column("alerts");

  // run.steps names the final step itself: a restart with another h still ends at step N.
  final_step_ = sc.run.steps > 0 ? sc.run.steps : k0_ + whole_steps(sc.run.t_end - t0_, h_);
  if (sc.run.steps > 0)
    summary_.t_end = (t0_ + static_cast<double>(final_step_ - k0_) * h_) * sc.units.out(Dimension::time);
  first_step_ = s_.step + 1;
  progress_ = std::make_unique<Progress>(opt.progress, final_step_ - s_.step);
  checkpoint_path_ = outputs_->checkpoint_path();  // rank 0's, on every rank: they write it together
  if (domain_) opt.processes->broadcast(checkpoint_path_, 0);
  writes_checkpoints_ = !checkpoint_path_.empty();

  observe();
  summary_.initial_energy = thermo_.initial_energy();
  // Periodic checkpoints on their time grid ([output] checkpoint_interval), from the start's time
  // on: the first at or after the first multiple of the interval.
  if (sc.output.checkpoint_interval > 0.0 && writes_checkpoints_) {
    checkpoint_due_.emplace(sc.output.checkpoint_interval);
    checkpoint_due_->served_until(s_.t);
    next_checkpoint_ = checkpoint_due_->next_due_step(s_.step, h_, [this](std::int64_t j) { return time_at(j); });
  }
  if (opt.handle_signals) install_stop_handlers();
  signal_at_ = SignalAtStep::from_environment();  // tests: a signal at an exact step
  if (opt.started_at >= 0.0) summary_.setup_seconds = seconds_now() - opt.started_at;
  cpu_start_ = std::clock();
}

Run::~Run() = default;

void Run::step_to(std::int64_t k) {
  // The step loop's time, and where it goes: the phase clock and the time inside the parallel
  // loops run only while stepping, and only where timed_by_phase: a small system's step is too
  // short to time by parts (a mark costs two clock reads, ≈ 50 ns here, against 240 ns for a whole
  // velocity-Verlet step of the pendulum).
  const double entered = seconds_now();
  const bool timed = timed_by_phase();
  if (timed) {
    reset_parallel_seconds();
    clock_.resume();
  }
  reset_widest_team();
  // The time inside MPI's calls during the loop (Communicator::blocked): a rank's waits for the
  // others, apart from its own work.
  const Communicator::Blocked blocked = options_.processes ? options_.processes->blocked() : Communicator::Blocked{};
  struct Pause {
    Run& r;
    double entered;
    bool timed;
    Communicator::Blocked blocked;
    ~Pause() {
      if (r.options_.processes) {
        const Communicator::Blocked now = r.options_.processes->blocked();
        r.loop_blocked_.exchanges += now.exchanges - blocked.exchanges;
        r.loop_blocked_.reductions += now.reductions - blocked.reductions;
      }
      if (timed) {
        r.clock_.pause();
        r.parallel_seconds_ += parallel_seconds();
        stop_parallel_seconds();
      }
      r.loop_seconds_ += seconds_now() - entered;
      r.threads_used_ = std::max(r.threads_used_, widest_team());
    }
  } pause{*this, entered, timed, blocked};
  while (s_.step < k) {
    if (pending_) {
      pending_ = false;
      after_step();
      if (stopped()) return;
    }
    const std::int64_t j = s_.step + 1;
    // A decomposed run checks its parts (DomainIntegrator::step); s_ is current only when gathered.
    take_step(*integrator_, s_, h_, j, time_at(j), !domain_);
    pending_ = true;
  }
}

// Every step pays for what runs here, so the grids are not asked between their due steps (every
// rank of a decomposed run skips the same steps: the grids are the same on all). The signal poll
// stays per step: a decomposed run's ranks agree on it every step, and a stop takes the step it
// was asked at.
void Run::after_step() {
  if (s_.step >= next_observe_) observe();
  signal_at_.at(s_.step);
  if (options_.handle_signals)
    if (const int sig = static_cast<int>(agreed(stop_requested()))) {
      summary_.stopped_by_signal = sig;
      return;
    }
  if (s_.step >= next_checkpoint_) checkpoint_step();
  progress_->update(s_.step - first_step_ + 1);
}

void Run::checkpoint_step() {
  if (checkpoint_due_->due(s_.t)) write_checkpoint_now();
  next_checkpoint_ = checkpoint_due_->next_due_step(s_.step, h_, [this](std::int64_t j) { return time_at(j); });
}

const RunSummary& Run::finish() {
  summary_.cpu_seconds = static_cast<double>(std::clock() - cpu_start_) / CLOCKS_PER_SEC;
  summary_.wall_seconds = loop_seconds_;
  summary_.loop_seconds = loop_seconds_;
  summary_.peak_rss_mib = peak_resident_mib();
  if (domain_) {  // every rank's step loop: the slowest sets the pace, max/mean is the imbalance
    const Communicator& c = *options_.processes;
    summary_.rank_loop_seconds_mean = c.sum(loop_seconds_) / c.size();
    summary_.rank_loop_seconds_max = c.max(loop_seconds_);
    summary_.rank_exchange_seconds_mean = c.sum(loop_blocked_.exchanges) / c.size();
    summary_.rank_exchange_seconds_max = c.max(loop_blocked_.exchanges);
    summary_.rank_reduction_seconds_mean = c.sum(loop_blocked_.reductions) / c.size();
    summary_.rank_reduction_seconds_max = c.max(loop_blocked_.reductions);
    summary_.rank_peak_rss_mib_mean = c.sum(summary_.peak_rss_mib) / c.size();
    summary_.rank_peak_rss_mib_max = c.max(summary_.peak_rss_mib);
    if (summary_.setup_seconds >= 0.0) {
      summary_.rank_setup_seconds_mean = c.sum(summary_.setup_seconds) / c.size();
      summary_.rank_setup_seconds_max = c.max(summary_.setup_seconds);
    }
    summary_.wall_seconds = summary_.loop_seconds = summary_.rank_loop_seconds_max;
    summary_.domains = domain_->report();
    summary_.h5md_writers = outputs_->h5md_writers();
  }
  summary_.threads = threads_used_;  // not OMP_NUM_THREADS: loops over few items run on one
  summary_.phase_seconds.clear();
  if (timed_by_phase()) {
    for (int p = 0; p < static_cast<int>(Phase::count); ++p) summary_.phase_seconds.push_back(clock_.seconds(Phase(p)));
    if (domain_) {
      const Communicator& c = *options_.processes;
      const int n = static_cast<int>(summary_.phase_seconds.size());
      summary_.rank_phase_seconds_mean = summary_.rank_phase_seconds_max = summary_.phase_seconds;
      c.sum(summary_.rank_phase_seconds_mean.data(), n);
      for (double& v : summary_.rank_phase_seconds_mean) v /= c.size();
      c.max(summary_.rank_phase_seconds_max.data(), n);
    }
    if (loop_seconds_ > 0.0) summary_.serial_share = std::clamp(1.0 - parallel_seconds_ / loop_seconds_, 0.0, 1.0);
  }
  progress_->finish(s_.step - first_step_ + 1);  // where it stopped: a signal leaves the bar short of 100 %
  write_checkpoint_now();
  summary_.steps = s_.step;
  if (stopped()) {  // outputs are flushed frame by frame; no summary.json: not finished
    outputs_->close();
    return summary_;
  }
  // The final state is always written, exactly once, whatever the intervals.
  pending_ = false;
  observe(true);
  const std::vector<double>& row = last_row_;
  // A scene of descriptions has no whole state or topology for the histograms: the parts make
  // them (collective), the same bytes.
  bool histograms_by_parts = false;
  if (described_ && sc_.observables.histograms && !options_.out_dir.empty()) {
    const Scene& part = domain_->part_scene();
    histograms_by_parts = write_histograms_parts((fs::path(options_.out_dir) / "histograms.csv").string(), part.state.x,
                                                 part.topology, *options_.processes);
  }
  if (!root()) {  // rank 0 writes the files and the summary
    outputs_->close();
    return summary_;
  }
  outputs_->write_final(summary_.outputs);
  if (histograms_by_parts) summary_.outputs.push_back((fs::path(options_.out_dir) / "histograms.csv").string());
  outputs_->close();
  summary_.final_energy = row[col_total_];
  // The energy conserved with the thermostat's heat (E itself without one): its drift per particle
  // and time unit over the run, (E_c(end) − E_c(0)) / (N t), GROMACS's "conserved energy drift".
  summary_.thermostat = col_econserve_ >= 0;
  summary_.particles = num_particles_;
  summary_.initial_conserved_energy = thermo_.initial_conserved_energy();
  summary_.final_conserved_energy = col_econserve_ >= 0 ? row[col_econserve_] : row[col_total_];
  summary_.max_conserved_error = col_econserve_ >= 0 ? stats_.max_conserved_error : stats_.max_energy_error;
  const double span = s_.t - thermo_.initial_time();
  if (span > 0.0 && num_particles_ > 0)
    summary_.conserved_energy_drift = (summary_.final_conserved_energy - summary_.initial_conserved_energy) /
                                      (static_cast<double>(num_particles_) * span) * sc_.units.out(Dimension::energy) /
                                      sc_.units.out(Dimension::time);
  summary_.final_max_violation = row[col_violation_];
  if (first_action_ >= 0)
    summary_.final_actions.assign(row.begin() + first_action_, row.begin() + first_action_ + num_actions_);
  summary_.max_energy_error = stats_.max_energy_error;
  bool has_pairs = false;
  for (const auto& term : sc_.forces->terms()) has_pairs |= term->uses_neighbor_list();
  if (has_pairs) summary_.neighbor_rebuilds = rebuilds_now();
  // The pairs the lists hold (a decomposed run's ranks summed: a pair of a home and a halo bead is
  // listed on both its beads' homes).
  if (has_pairs && domain_) {
    summary_.neighbor_pairs = summary_.domains.neighbor_pairs;
  } else if (has_pairs) {
    summary_.neighbor_pairs = 0;
    for (const auto& term : sc_.forces->terms()) summary_.neighbor_pairs += term->listed_pairs();
  }
  const std::vector<std::int64_t> now = evaluations_now();
  summary_.slow_evaluations = stats_.evaluations.back() + now.back();
  summary_.fast_evaluations = stats_.evaluations.front() + now.front();
  summary_.level_evaluations.clear();
  for (int k = 0; k < sc_.forces->num_levels(); ++k)
    summary_.level_evaluations.emplace_back(sc_.forces->level_name(Level{k}), stats_.evaluations[k] + now[k]);
  if (!options_.out_dir.empty()) {
    const fs::path summary_path = fs::path(options_.out_dir) / "summary.json";
    summary_.outputs.push_back(summary_path.string());
    write_atomically(summary_path, summary_json(summary_));
  }
  return summary_;
}

bool Run::sampled_by_parts() const {
  return domain_ && domain_->samples_by_parts() && !thermo_.modes() && !thermo_.has_molecular_pressure();
}

const std::vector<double>& Run::sample() {
  // The integrator's sums first (on every rank: a decomposed run reduces them), then the row's
  // sums: each rank's part's, added up (DomainIntegrator::sample_sums), or rank 0's of the whole
  // system, gathered for it (the actions).
  const double model = integrator_->model_potential(s_.x), virial = integrator_->constraint_virial(s_);
  const double kinetic = integrator_->kinetic_energy_estimate(s_), heat = integrator_->thermostat_heat();
  std::optional<ThermoSums> parts;
  if (sampled_by_parts()) parts = domain_->sample_sums();
  if (root()) {
    last_row_ = parts ? thermo_.sample(s_, *parts, model, virial, kinetic, heat)
                      : thermo_.sample(s_, model, virial, kinetic, heat);
    stats_.max_energy_error = std::max(stats_.max_energy_error, std::abs(last_row_[col_drift_]));
    if (col_econserve_ >= 0)
      stats_.max_conserved_error = std::max(stats_.max_conserved_error,
                                            std::abs(last_row_[col_econserve_] - thermo_.initial_conserved_energy()));
    for (const auto& note : thermo_.take_notes()) log_ << note << "\n";
    alerts_ = monitor_.check(last_row_, thermo_.initial_energy(), log_);
    last_row_[col_alerts_] = alerts_;
  }
  if (monitor_.stops() && agreed(alerts_ == 0) != 0) {  // the run as of this sample, kept
    std::vector<double> words = integrator_->save_state();
    if (root()) {
      last_good_.state = s_;
      snapshot(last_good_, std::move(words));
    }
  }
  return last_row_;
}

// One sample of the observables serves the thermo row and the H5MD frame of the same step.
void Run::observe(bool final) {
  const ScopedPhase phase(Phase::output);
  bool sampled = outputs_->due(s_.t, final);
  bool xyz_by_blocks = false;
  next_observe_ = outputs_->next_due_step(s_.step, h_, [this](std::int64_t j) { return time_at(j); });
  if (domain_) {  // rank 0's outputs decide; the others take part in the gather and the sums
    // The whole state, gathered on rank 0: for the files it writes from it, the final state, a
    // sample that cannot be summed by parts, and the state the [monitor] keeps.
    // An XYZ frame of a distributed run is streamed from the ranks' rows (RunOutputs::write).
    const bool stream = outputs_->xyz_due() && domain_->distributed();
    // A scene of descriptions has no whole state to gather into, nor an output that needs one
    // (whole_scene_needed): its final histograms are summed by parts (Run::finish).
    const bool whole = outputs_->needs_whole_state(stream) || (final && !described_) ||
                       (sampled && (!sampled_by_parts() || monitor_.stops()));
    const std::int64_t due = agreed((sampled ? 1 : 0) | (whole ? 2 : 0) | (stream ? 4 : 0));
    sampled = (due & 1) != 0;
    xyz_by_blocks = (due & 4) != 0;
    if ((due & 2) != 0) domain_->gather(s_);
  }
  if (sampled) sample();
  if (domain_ && (outputs_->shares_frame() || xyz_by_blocks)) {  // every rank writes its particles' rows
    std::optional<ProcessRows> mine;
    if (domain_->distributed()) {
      if (outputs_->shares_frame() && sc_.output.h5md_force) domain_->owned_forces(owned_force_);
      // The rows' types name their species in an XYZ frame (a scene of descriptions has none).
      mine.emplace(ProcessRows{domain_->owned_ids(), domain_->owned_state().x, domain_->owned_state().v, &owned_force_,
                               &domain_->part_scene().particle_type});
    }
    outputs_->write(s_, last_row_, mine ? &*mine : nullptr, xyz_by_blocks);
  } else if (root()) {
    outputs_->write(s_, last_row_);
  }
  if (root() && outputs_->thermo_sampled() && screen_->due(s_.t, final)) {
    progress_->clear();  // a line of its own, not after the bar (when both are on one terminal)
    screen_->print(outputs_->thermo_row(), s_.step);
  }
  const bool stop = sampled && monitor_.stops() && agreed(alerts_ > 0) != 0;
  if (stop && !root()) throw AgreedStop("stopped by rank 0's [monitor]", false);
  if (stop) {
    // The outputs hold the alerting sample; the checkpoint the last state within the thresholds.
    std::ostringstream m;
    m.precision(10);
    m << monitor_.last_alert() << "; stopped ([monitor] on_alert = \"stop\"), ";
    const std::string& path = outputs_->checkpoint_path();
    if (last_good_.method.empty()) {  // the first sample alerted: there is no state to keep
      m << "no sampled state was within the thresholds, no checkpoint written";
    } else if (!path.empty()) {
      write_checkpoint(path, last_good_);
      summary_.checkpoint = path;
      m << "the last state within the thresholds (step " << last_good_.state.step << ", t = " << last_good_.state.t
        << ") is in " << path;
    }
    if (domain_) throw AgreedStop(m.str(), true);
    throw NumericalError(m.str());
  }
}

const std::vector<double>& Run::sample_now() {
  last_row_ = thermo_.sample(s_, integrator_->model_potential(s_.x), integrator_->constraint_virial(s_),
                             integrator_->kinetic_energy_estimate(s_), integrator_->thermostat_heat());
  for (const auto& note : thermo_.take_notes()) log_ << note << "\n";
  return last_row_;
}

void Run::close_outputs() {
  outputs_->close();
}

void Run::state_changed() {
  integrator_->reset();
  thermo_.take_reference_at_next_sample();
  sample_now();
}

std::int64_t Run::agreed(std::int64_t rank0_value) const {
  if (domain_) options_.processes->broadcast(&rank0_value, 1);
  return rank0_value;
}

std::vector<std::int64_t> Run::evaluations_now() const {
  if (domain_) return domain_->evaluations();
  std::vector<std::int64_t> e;
  for (int k = 0; k < sc_.forces->num_levels(); ++k) e.push_back(sc_.forces->evaluations(Level{k}));
  return e;
}

long Run::rebuilds_now() const {
  if (domain_) return stats_.neighbor_rebuilds + domain_->neighbor_rebuilds();
  long r = 0;
  for (const auto& term : sc_.forces->terms()) r += term->neighbor_list_rebuilds();
  return stats_.neighbor_rebuilds + r - rebuilds_at_start_;
}

// What the checkpoint's prefix names: the method, h and the stage (the same on every rank).
Checkpoint& Run::identity(Checkpoint& c) const {
  c.method = sc_.integrator.method;
  c.h = h_;
  c.stage = sc_.stage.number;
  c.stage_name = sc_.stage.name;
  return c;
}

// Everything but the state that a restart needs (checkpoint.hpp), as of now.
Checkpoint& Run::snapshot(Checkpoint& c, std::vector<double> integrator_state) {
  identity(c);
  c.scene_fingerprint = fingerprint_;
  c.integrator_state = std::move(integrator_state);
  c.force_term_states.clear();
  for (const auto& term : sc_.forces->terms()) c.force_term_states.push_back(term->save_state());
  c.thermo_state = thermo_.save_state();
  c.monitor_state = monitor_.save_state();
  c.run_state = stats_.save(evaluations_now(), rebuilds_now());
  c.box = sc_.forces->box();
  return c;
}

void Run::write_checkpoint_now() {
  if (!writes_checkpoints_) return;
  const ScopedPhase phase(Phase::output);
  if (!domain_) {
    write_checkpoint(checkpoint_path_, s_, snapshot(now_, integrator_->save_state()));
    summary_.checkpoint = checkpoint_path_;
    return;
  }
  // Tests (tests/test_domains.py): the same checkpoint beside it as one process writes it, from
  // the state and carried columns gathered on rank 0, to compare the bytes with.
  if (std::getenv("STIFFMD_GATHERED_CHECKPOINT")) {
    State none;  // a scene of descriptions: the state gathered apart, with its inverse masses
    none.t = s_.t;
    none.step = s_.step;
    State& whole = described_ ? none : s_;
    domain_->gather(whole);
    std::vector<double> words = integrator_->save_state();
    Checkpoint gathered;
    if (root()) write_checkpoint(checkpoint_path_ + ".gathered", whole, snapshot(gathered, std::move(words)));
  }
  // Every rank writes its block of the state and of the integrator's carried columns into the one
  // file (engine/run/checkpoint.hpp); rank 0 the rest. Nothing is gathered.
  const StateBlock b = domain_->state_block(s_);
  if (root())
    snapshot(now_, {});
  else
    identity(now_);
  now_.state.step = s_.step;
  now_.state.t = s_.t;
  CheckpointBlock mine{num_particles_, b.block, b.x, b.v, b.inv_mass, {}, &b.words, b.owned};
  for (const Eigen::Matrix3Xd& column : b.columns) mine.columns.push_back(column.data());
  write_checkpoint(checkpoint_path_, *options_.processes, mine, now_);
  if (root()) summary_.checkpoint = checkpoint_path_;
}

RunSummary run_simulation(Scene& sc, const RunOptions& opt, std::ostream& log) {
  Run run(sc, opt, log);
  try {
    run.step_to(run.final_step());
  } catch (const AgreedStop&) {  // every rank stops here: they close the shared files together
    run.close_outputs();
    throw;
  }
  return run.finish();
}

std::string whole_scene_needed(const Scene& sc) {
  if (sc.observables.actions) return "[observables] actions are sampled from the gathered whole state";
  if (sc.observables.barostat) return "a barostat's molecular pressure is sampled from the gathered whole state";
  if (sc.monitor.stop) return "[monitor] on_alert = \"stop\" keeps the gathered whole state";
  if (!sc.output.h5md.empty() && !H5mdWriter::shared_files())
    return "an H5MD frame is written from the gathered whole state without parallel HDF5";
  if (!sc.output.lammps_data.empty()) return "output.lammps_data is written from the gathered whole state";
  if (!sc.output.state.empty()) return "output.state is written from the whole state";
  return "";
}

void check_run(Scene& sc, std::ostream& log) {
  const State initial = sc.state;
  try {
    RunOptions no_outputs;
    no_outputs.handle_signals = false;
    Run run(sc, no_outputs, log);
  } catch (...) {
    sc.state = initial;
    throw;
  }
  sc.state = initial;
}

}  // namespace stiffmd
