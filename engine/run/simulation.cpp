#include "engine/run/simulation.hpp"

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <ctime>
#include <filesystem>
#include <fstream>
#include <memory>
#include <optional>
#include <sstream>

#include "engine/core/errors.hpp"
#include "engine/core/parallel.hpp"
#include "engine/observe/monitor.hpp"
#include "engine/observe/observables.hpp"
#include "engine/run/checkpoint.hpp"
#include "engine/run/outputs.hpp"
#include "engine/run/progress.hpp"
#include "engine/run/screen.hpp"
#include "engine/run/signals.hpp"
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

// Restores a checkpoint (read and checked against the scene by read_checkpoint_for, which also
// loaded the force terms' states) into the scene's state and the integrator; the deck supplies
// everything else. With another method the integrator starts afresh from the checkpoint's state.
void restore(Scene& sc, Integrator& integrator, const Checkpoint& c, const std::string& path, std::ostream& log) {
  sc.state = c.state;
  if (c.method != sc.integrator.method || c.h != sc.integrator.h)
    log << "note: " << path << " was written by " << c.method << " with h = " << c.h << "; continuing with "
        << sc.integrator.method << ", h = " << sc.integrator.h << " (not bit-identical to an uninterrupted run)\n";
  if (c.method != sc.integrator.method) integrator.prepare(sc.state, log);  // else: its state is loaded
  log << "restart from " << path << " at step " << sc.state.step << " (t = " << sc.state.t << ")\n";
}

// Macro steps of size h to cover a time span, rounded as Scene::num_steps: to the nearest whole
// step when span/h is an integer up to rounding, else up.
std::int64_t steps_to(double span, double h) {
  const double r = span / h, nearest = std::round(r);
  return static_cast<std::int64_t>(std::abs(r - nearest) <= 1e-9 * std::max(1.0, r) ? nearest : std::ceil(r));
}

// The observables as the run counts them: the rigid constraints of the constrained methods take
// one degree of freedom each.
ObservableSettings run_observables(const Scene& sc) {
  ObservableSettings observables = sc.observables;
  if (find_method(sc.integrator.method)->rigid_constraints)
    observables.rigid_constraints = static_cast<int>(sc.forces->stiff_bonds()->bonds.size());
  return observables;
}

}  // namespace

void check_finite(const State& s) {
  // In the particle blocks of the threads, as the integrators write x and v: read serially, the
  // blocks the other threads had just written came over from their cores.
  const int parts = threads_for(s.size());
  std::array<char, kMaxParts> finite{};
  run_parts(parts, [&](int u) {
    const std::int64_t b = block_begin(s.size(), parts, u), e = block_begin(s.size(), parts, u + 1);
    finite[u] = s.x.middleCols(b, e - b).allFinite() && s.v.middleCols(b, e - b).allFinite();
  });
  if (std::all_of(finite.begin(), finite.begin() + parts, [](char f) { return f != 0; })) return;
  int bad = 0;
  while (bad < s.size() && s.x.col(bad).allFinite() && s.v.col(bad).allFinite()) ++bad;
  std::ostringstream m;
  m.precision(10);
  m << "numerical failure: non-finite position or velocity of particle " << bad << " at step " << s.step
    << " (t = " << s.t << "); reduce integrator.h or micro_dt";
  throw NumericalError(m.str());
}

void take_step(Integrator& integrator, State& s, double h, std::int64_t k, double t_k) {
  try {
    integrator.step(s, h);
  } catch (const NumericalError& e) {
    std::ostringstream m;
    m.precision(10);
    m << "numerical failure in step " << k << " (from t = " << s.t << "): " << e.what();
    throw NumericalError(m.str());
  }
  s.step = k;
  s.t = t_k;
  check_finite(s);
}

void check_start(Scene& sc, std::ostream& log) {
  const State initial = sc.state;
  std::unique_ptr<Integrator> integrator = make_integrator(sc.integrator, *sc.forces, sc.state.inv_mass);
  Thermo thermo(*sc.forces, sc.state.inv_mass, run_observables(sc), &sc.topology);
  integrator->prepare(sc.state, log);
  try {
    check_finite(sc.state);
    thermo.sample(sc.state, integrator->model_potential(sc.state.x), integrator->constraint_virial(sc.state),
                  integrator->kinetic_energy_estimate(sc.state));
  } catch (...) {
    sc.state = initial;
    throw;
  }
  sc.state = initial;
}

RunSummary run_simulation(Scene& sc, const RunOptions& opt, std::ostream& log) {
  RunSummary summary;
  summary.method = sc.integrator.method;
  summary.units = sc.units.name;
  summary.h = sc.integrator.h * sc.units.out(Dimension::time);
  summary.micro_steps = sc.integrator.micro_steps;
  summary.t_end = sc.run.t_end * sc.units.out(Dimension::time);
  if (const StiffBonds* sb = sc.forces->stiff_bonds()) summary.epsilon = sb->epsilon;

  // A restart's checkpoint is read, checked and loaded first: a damaged or foreign one is refused
  // before any output is touched.
  const bool restarting = !opt.restart.empty();
  Checkpoint resumed;
  if (restarting) resumed = opt.checkpoint ? *opt.checkpoint : read_checkpoint_for(sc, opt.restart);
  auto refuse = [&](const std::string& what) { throw InputError(opt.restart + ": " + what); };
  // load_scene built it once already (check_integrator): what it refuses was refused there.
  std::unique_ptr<Integrator> integrator = make_integrator(sc.integrator, *sc.forces, sc.state.inv_mass);
  if (restarting && resumed.method == sc.integrator.method) {
    try {
      integrator->load_state(resumed.integrator_state);
    } catch (const std::invalid_argument& e) {
      refuse(e.what());
    }
  }
  const MethodInfo& method = *find_method(sc.integrator.method);  // load_scene checked the name
  Thermo thermo(*sc.forces, sc.state.inv_mass, run_observables(sc), &sc.topology);
  Monitor monitor(sc.monitor, thermo, summary.epsilon, method.effective);
  // Run statistics carried by checkpoints, so that a restarted run's summary is the whole run's:
  // max |E − E(0)|, force evaluations of the outermost and innermost level and neighbour-list
  // rebuilds so far, then those of the levels in between (innermost first; none with two levels),
  // then the initial actions.
  double max_err = 0.0;
  const int levels_between = std::max(0, sc.forces->num_levels() - 2);
  std::vector<std::int64_t> before(sc.forces->num_levels(), 0);  // evaluations per level so far
  std::int64_t& slow_before = before.back();
  std::int64_t& fast_before = before.front();
  long rebuilds_in_run = 0;
  if (restarting) {
    if (!thermo.load_state(resumed.thermo_state)) refuse("thermo state does not fit this scene's observables");
    if (!monitor.load_state(resumed.monitor_state))  // [observables] actions changed with --set
      log << "note: " << opt.restart << ": the monitor's reference is taken afresh (the actions observed changed)\n";
    const std::vector<double>& r = resumed.run_state;  // read_checkpoint checked its size
    max_err = r[0];
    slow_before = static_cast<std::int64_t>(r[1]);
    fast_before = static_cast<std::int64_t>(r[2]);
    rebuilds_in_run = static_cast<long>(r[3]);
    if (r.size() < 4u + static_cast<size_t>(levels_between)) refuse("run statistics do not fit this scene's levels");
    for (int k = 0; k < levels_between; ++k) before[k + 1] = static_cast<std::int64_t>(r[4 + k]);
    summary.initial_actions.assign(r.begin() + 4 + levels_between, r.end());
  }

  State& s = sc.state;
  if (restarting)
    restore(sc, *integrator, resumed, opt.restart, log);
  else
    integrator->prepare(s, log);

  // Step k is at t_k = t0 + (k − k0) h. From the start, and on a restart whose checkpoint is at
  // t = k h (the same h throughout), t0 = k0 = 0: t_k = k h exactly, the uninterrupted run's times.
  // After a change of h the run continues from the checkpoint's time (k0 = its step) instead of
  // jumping to k0 h.
  const bool new_h = restarting && s.t != static_cast<double>(s.step) * sc.integrator.h;
  const double t0 = new_h ? s.t : 0.0;
  const std::int64_t k0 = new_h ? s.step : 0;
  const int first_action = thermo.column("action_1");
  const int num_actions = thermo.modes() ? thermo.modes()->num_modes() : 0;
  sc.forces->reset_counters();
  // The list is built before the run (relaxation, first force); on restart its count comes from
  // the checkpoint, of which rebuilds_in_run happened in the run so far.
  long rebuilds_before = -rebuilds_in_run;
  for (const auto& term : sc.forces->terms()) rebuilds_before += term->neighbor_list_rebuilds();
  auto rebuilds_now = [&] {
    long r = 0;
    for (const auto& term : sc.forces->terms()) r += term->neighbor_list_rebuilds();
    return r - rebuilds_before;
  };
  check_finite(s);
  if (!restarting) {
    const auto& row = thermo.sample(s, integrator->model_potential(s.x), integrator->constraint_virial(s),
                                    integrator->kinetic_energy_estimate(s));  // E(0) and the initial actions
    if (first_action >= 0)
      summary.initial_actions.assign(row.begin() + first_action, row.begin() + first_action + num_actions);
  }
  // A restart samples nothing here: E(0) and the initial actions come from the checkpoint, and
  // an extra evaluation would move the neighbour list on where the interrupted run did not.
  for (const auto& note : thermo.take_notes()) log << note << "\n";
  // Everything above can fail on the initial state (the method's preparation, the first force
  // evaluation: exit 3, or 2 for a foreign checkpoint) before any output is touched; the files
  // are opened only now.
  prepare_output_directory(sc, opt.out_dir);

  // Outputs: fresh files, or on restart the same files cut back to the step before the
  // checkpoint, t_{k−1}; the frame at t_k is written again below if the uninterrupted run would
  // have written one. So the files end up exactly as an uninterrupted run's (without the
  // interrupted run's off-grid final frame).
  const double cut = new_h ? s.t - resumed.h : static_cast<double>(s.step - 1) * sc.integrator.h;
  RunOutputs outputs(sc, opt.out_dir, thermo, restarting ? &cut : nullptr, summary.outputs, log);
  const std::string& checkpoint_path = outputs.checkpoint_path();
  // The terminal: the thermo lines (from the rows the thermo file gets) and the progress bar.
  bool levels = false;
  for (const auto& term : sc.forces->terms()) levels |= term->level() == Level::fast;
  ThermoScreen screen(outputs.thermo_table(), sc.output.screen_interval, opt.screen, levels);
  if (restarting) screen.served_until(cut);
  // Thermo columns by name (Thermo::columns), looked up once.
  const int col_total = thermo.column("total"), col_drift = thermo.column("energy_drift"),
            col_violation = thermo.column("max_violation"), col_alerts = thermo.column("alerts");

  const std::int64_t n = k0 + steps_to(sc.run.t_end - t0, sc.integrator.h);
  const std::int64_t first = s.step + 1;
  Progress progress(opt.progress, n - s.step);
  const double h = sc.integrator.h;

  const std::uint64_t fingerprint = scene_fingerprint(sc);
  // Everything but the state that a restart needs (checkpoint.hpp), as of now.
  auto snapshot = [&](Checkpoint& c) {
    c.method = sc.integrator.method;
    c.h = h;
    c.scene_fingerprint = fingerprint;
    c.integrator_state = integrator->save_state();
    c.force_term_states.clear();
    for (const auto& term : sc.forces->terms()) c.force_term_states.push_back(term->save_state());
    c.thermo_state = thermo.save_state();
    c.monitor_state = monitor.save_state();
    c.run_state = {max_err, static_cast<double>(slow_before + sc.forces->evaluations(sc.forces->outermost())),
                   static_cast<double>(fast_before + sc.forces->evaluations(sc.forces->innermost())),
                   static_cast<double>(rebuilds_now())};
    for (int k = 0; k < levels_between; ++k)
      c.run_state.push_back(static_cast<double>(before[k + 1] + sc.forces->evaluations(Level{k + 1})));
    c.run_state.insert(c.run_state.end(), summary.initial_actions.begin(), summary.initial_actions.end());
  };
  Checkpoint last_good;  // with on_alert = "stop": the run as of the last sample without alerts
  int alerts = 0;        // of the last sample
  // One sample of the observables serves the thermo row and the H5MD frame of the same step.
  std::vector<double> last_row;
  auto sample = [&]() -> const std::vector<double>& {
    last_row = thermo.sample(s, integrator->model_potential(s.x), integrator->constraint_virial(s),
                             integrator->kinetic_energy_estimate(s));
    max_err = std::max(max_err, std::abs(last_row[col_drift]));
    for (const auto& note : thermo.take_notes()) log << note << "\n";
    alerts = monitor.check(last_row, thermo.initial_energy(), log);
    last_row[col_alerts] = alerts;
    if (alerts == 0 && monitor.stops()) {
      last_good.state = s;
      snapshot(last_good);
    }
    return last_row;
  };

  Checkpoint now;  // snapshot() of the current step, written with s (no copy of the state)
  auto checkpoint = [&] {
    snapshot(now);
    write_checkpoint(checkpoint_path, s, now);
    summary.checkpoint = checkpoint_path;
  };
  // Outputs due at this step; `final` writes everything (the last state, whatever the grids).
  auto observe = [&](bool final = false) {
    const bool sampled = outputs.due(s.t, final);
    if (sampled) sample();
    outputs.write(s, last_row);
    if (outputs.thermo_sampled() && screen.due(s.t, final)) {
      progress.clear();  // a line of its own, not after the bar (when both are on one terminal)
      screen.print(outputs.thermo_row(), s.step);
    }
    if (sampled && alerts > 0 && monitor.stops()) {
      // The outputs hold the alerting sample; the checkpoint the last state within the thresholds.
      std::ostringstream m;
      m.precision(10);
      m << monitor.last_alert() << "; stopped ([monitor] on_alert = \"stop\"), ";
      if (last_good.method.empty()) {  // the first sample alerted: there is no state to keep
        m << "no sampled state was within the thresholds, no checkpoint written";
      } else {
        write_checkpoint(checkpoint_path, last_good);
        summary.checkpoint = checkpoint_path;
        m << "the last state within the thresholds (step " << last_good.state.step << ", t = " << last_good.state.t
          << ") is in " << checkpoint_path;
      }
      throw NumericalError(m.str());
    }
  };

  observe();
  summary.initial_energy = thermo.initial_energy();

  // Steps are numbered from the start of the run (k = step), so a restart continues the same
  // sequence of times t_k = k h exactly (t0 + (k − k0) h after a change of h).
  // Periodic checkpoints on their time grid ([output] checkpoint_interval), from the start's time
  // on: the first at or after the first multiple of the interval.
  std::optional<IntervalSchedule> checkpoint_due;
  if (sc.output.checkpoint_interval > 0.0) {
    checkpoint_due.emplace(sc.output.checkpoint_interval);
    checkpoint_due->served_until(s.t);
  }
  install_stop_handlers();
  const SignalAtStep signal_at = SignalAtStep::from_environment();  // tests: a signal at an exact step
  const auto start = std::chrono::steady_clock::now();
  const std::clock_t cpu_start = std::clock();
  for (std::int64_t k = first; k <= n; ++k) {
    take_step(*integrator, s, h, k, new_h ? t0 + static_cast<double>(k - k0) * h : static_cast<double>(k) * h);
    if (k == n) break;
    observe();
    signal_at.at(k);
    if (const int sig = stop_requested()) {
      summary.stopped_by_signal = sig;
      break;
    }
    if (checkpoint_due && checkpoint_due->due(s.t)) checkpoint();
    progress.update(k - first + 1);
  }
  summary.cpu_seconds = static_cast<double>(std::clock() - cpu_start) / CLOCKS_PER_SEC;
  summary.wall_seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  progress.finish(s.step - first + 1);  // where it stopped: a signal leaves the bar short of 100 %
  checkpoint();
  if (summary.stopped_by_signal) {
    summary.steps = s.step;
    return summary;  // outputs are flushed frame by frame; no summary.json: the run is not finished
  }
  // The final state is always written, exactly once, whatever the intervals.
  observe(true);
  const std::vector<double>& row = last_row;

  outputs.write_final(summary.outputs);
  summary.steps = n;
  summary.final_energy = row[col_total];
  summary.final_max_violation = row[col_violation];
  if (first_action >= 0)
    summary.final_actions.assign(row.begin() + first_action, row.begin() + first_action + num_actions);
  summary.max_energy_error = max_err;
  bool has_pairs = false;
  long rebuilds_after = 0;
  for (const auto& term : sc.forces->terms()) {
    has_pairs |= term->uses_neighbor_list();
    rebuilds_after += term->neighbor_list_rebuilds();
  }
  if (has_pairs) summary.neighbor_rebuilds = rebuilds_after - rebuilds_before;
  summary.slow_evaluations = slow_before + sc.forces->evaluations(sc.forces->outermost());
  summary.fast_evaluations = fast_before + sc.forces->evaluations(sc.forces->innermost());
  for (int k = 0; k < sc.forces->num_levels(); ++k)
    summary.level_evaluations.emplace_back(sc.forces->level_name(Level{k}),
                                           before[k] + sc.forces->evaluations(Level{k}));
  const fs::path summary_path = fs::path(opt.out_dir) / "summary.json";
  summary.outputs.push_back(summary_path.string());
  write_atomically(summary_path, summary_json(summary));
  return summary;
}

std::string format_summary(const RunSummary& s) {
  std::ostringstream o;
  o.precision(6);
  o << "method:        " << s.method << " (h = " << s.h;
  if (s.micro_steps > 1) o << ", " << s.micro_steps << " micro steps of " << s.h / s.micro_steps;
  o << ")\n";
  o << "steps:         " << s.steps << " to t = " << s.t_end << " in " << s.wall_seconds << " s wall\n";
  o << "force evals:   ";
  if (s.level_evaluations.size() > 2) {
    for (size_t k = s.level_evaluations.size(); k-- > 0;)
      o << s.level_evaluations[k].second << " " << s.level_evaluations[k].first << (k ? ", " : "");
  } else {
    o << s.slow_evaluations << " slow, " << s.fast_evaluations << " fast";
  }
  if (s.neighbor_rebuilds >= 0) o << "; " << s.neighbor_rebuilds << " neighbour-list rebuilds";
  o << "\n";
  const double rel = s.initial_energy != 0.0 ? s.max_energy_error / std::abs(s.initial_energy) : s.max_energy_error;
  o << "energy:        E(0) = " << s.initial_energy << ", E(end) = " << s.final_energy
    << ", max |E - E(0)| = " << s.max_energy_error << " (relative " << rel << ")\n";
  if (!s.final_actions.empty()) {
    o << "actions:       ";
    for (size_t k = 0; k < s.final_actions.size(); ++k)
      o << (k ? ", " : "") << "I_" << k + 1 << " " << s.initial_actions[k] << " -> " << s.final_actions[k];
    o << "\n";
  }
  o << "outputs:       ";
  for (size_t k = 0; k < s.outputs.size(); ++k) o << (k ? "\n               " : "") << s.outputs[k];
  o << "\n";
  return o.str();
}

std::string summary_json(const RunSummary& s) {
  std::ostringstream o;
  o.precision(17);
  auto list = [&](const std::vector<double>& v) {
    o << "[";
    for (size_t k = 0; k < v.size(); ++k) o << (k ? ", " : "") << v[k];
    o << "]";
  };
  o << "{\n  \"method\": \"" << s.method << "\",\n  \"units\": \"" << s.units << "\",\n  \"h\": " << s.h
    << ",\n  \"micro_steps\": " << s.micro_steps << ",\n  \"epsilon\": " << s.epsilon << ",\n  \"steps\": " << s.steps
    << ",\n  \"t_end\": " << s.t_end << ",\n  \"wall_seconds\": " << s.wall_seconds
    << ",\n  \"cpu_seconds\": " << s.cpu_seconds << ",\n  \"neighbor_rebuilds\": " << s.neighbor_rebuilds
    << ",\n  \"slow_evaluations\": " << s.slow_evaluations << ",\n  \"fast_evaluations\": " << s.fast_evaluations
    << ",\n  \"level_evaluations\": {";
  for (size_t k = 0; k < s.level_evaluations.size(); ++k)
    o << (k ? ", " : "") << "\"" << s.level_evaluations[k].first << "\": " << s.level_evaluations[k].second;
  o << "}"
    << ",\n  \"initial_energy\": " << s.initial_energy << ",\n  \"final_energy\": " << s.final_energy
    << ",\n  \"max_energy_error\": " << s.max_energy_error << ",\n  \"final_max_violation\": " << s.final_max_violation
    << ",\n  \"initial_actions\": ";
  list(s.initial_actions);
  o << ",\n  \"final_actions\": ";
  list(s.final_actions);
  o << "\n}\n";
  return o.str();
}

}  // namespace stiffmd
