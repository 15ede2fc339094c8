#include "engine/simulation.hpp"

#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <memory>
#include <sstream>

#include "engine/errors.hpp"
#include "engine/observables.hpp"
#include "engine/progress.hpp"
#include "engine/writers.hpp"

namespace stiffmd {
namespace fs = std::filesystem;

namespace {

// Locates the first non-finite coordinate, to say where a blow-up happened.
void check_finite(const State& s) {
  if (s.x.allFinite() && s.v.allFinite()) return;
  int bad = 0;
  while (bad < s.size() && s.x.col(bad).allFinite() && s.v.col(bad).allFinite()) ++bad;
  std::ostringstream m;
  m.precision(10);
  m << "numerical failure: non-finite position or velocity of particle " << bad << " at step " << s.step
    << " (t = " << s.t << "); reduce integrator.h or micro_dt";
  throw NumericalError(m.str());
}

std::string prepare_output(const fs::path& dir, const std::string& name, std::ostream& log, RunSummary& summary) {
  const fs::path p = dir / name;
  if (fs::exists(p)) log << "note: overwriting " << p.string() << " from a previous run\n";
  summary.outputs.push_back(p.string());
  return p.string();
}

}  // namespace

RunSummary run_simulation(Scene& sc, const RunOptions& opt, std::ostream& log) {
  RunSummary summary;
  summary.method = sc.integrator.method;
  summary.h = sc.integrator.h;
  summary.micro_steps = sc.integrator.micro_steps;
  summary.t_end = sc.run.t_end;

  const fs::path dir(opt.out_dir);
  std::error_code ec;
  fs::create_directories(dir, ec);
  if (ec || !fs::is_directory(dir)) throw InputError(opt.out_dir + ": cannot create output directory: " + ec.message());

  std::vector<std::string> species;
  for (int t : sc.particle_type) species.push_back(sc.types[t].element);
  std::unique_ptr<XyzWriter> xyz;
  std::unique_ptr<CsvWriter> csv;
  if (!sc.output.xyz.empty())
    xyz = std::make_unique<XyzWriter>(prepare_output(dir, sc.output.xyz, log, summary), species, sc.box,
                                      sc.output.xyz_velocities);
  Thermo thermo(*sc.forces);
  if (!sc.output.thermo.empty())
    csv = std::make_unique<CsvWriter>(prepare_output(dir, sc.output.thermo, log, summary), thermo.columns());
  IntervalSchedule xyz_due(sc.output.xyz_interval), thermo_due(sc.output.thermo_interval);

  std::unique_ptr<Integrator> integrator;
  try {
    integrator = make_integrator(sc.integrator, *sc.forces);
  } catch (const std::invalid_argument& e) {
    throw InputError(sc.deck_path + ": integrator.method: " + e.what());
  }

  State& s = sc.state;
  const std::int64_t n = sc.num_steps();
  const double h = sc.integrator.h;
  const double t0 = s.t;
  const std::int64_t step0 = s.step;
  sc.forces->reset_counters();

  double max_err = 0.0;
  auto observe = [&]() {
    if (thermo_due.due(s.t)) {
      const auto& row = thermo.sample(s);
      max_err = std::max(max_err, std::abs(row[6]));
      if (csv) csv->write(row);
    }
    if (xyz && xyz_due.due(s.t)) xyz->write(s);
  };

  check_finite(s);
  observe();
  summary.initial_energy = thermo.initial_energy();
  Progress progress(opt.progress, n);
  const auto start = std::chrono::steady_clock::now();
  for (std::int64_t k = 1; k <= n; ++k) {
    integrator->step(s, h);
    s.step = step0 + k;
    s.t = t0 + static_cast<double>(k) * h;  // no accumulated round-off in t
    check_finite(s);
    if (k < n) observe();
    progress.update(k);
  }
  summary.wall_seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  progress.finish();
  // The final state is always written, exactly once, whatever the intervals.
  const auto& row = thermo.sample(s);
  max_err = std::max(max_err, std::abs(row[6]));
  if (csv) csv->write(row);
  if (xyz) xyz->write(s);

  summary.steps = n;
  summary.final_energy = row[5];
  summary.max_energy_error = max_err;
  summary.slow_evaluations = sc.forces->evaluations(Level::slow);
  summary.fast_evaluations = sc.forces->evaluations(Level::fast);
  return summary;
}

std::string format_summary(const RunSummary& s) {
  std::ostringstream o;
  o.precision(6);
  o << "method:        " << s.method << " (h = " << s.h;
  if (s.micro_steps > 1) o << ", " << s.micro_steps << " micro steps of " << s.h / s.micro_steps;
  o << ")\n";
  o << "steps:         " << s.steps << " to t = " << s.t_end << " in " << s.wall_seconds << " s wall\n";
  o << "force evals:   " << s.slow_evaluations << " slow, " << s.fast_evaluations << " fast\n";
  const double rel = s.initial_energy != 0.0 ? s.max_energy_error / std::abs(s.initial_energy) : s.max_energy_error;
  o << "energy:        E(0) = " << s.initial_energy << ", E(end) = " << s.final_energy << ", max |E - E(0)| = "
    << s.max_energy_error << " (relative " << rel << ")\n";
  o << "outputs:       ";
  for (size_t k = 0; k < s.outputs.size(); ++k) o << (k ? "\n               " : "") << s.outputs[k];
  o << "\n";
  return o.str();
}

}  // namespace stiffmd
