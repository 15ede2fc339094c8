// The Python module `stiffmd` (pybind11): a simulation made from a deck, stepped from Python.
//
// It drives the CLI's run (engine/run/run.hpp): Deck → load_scene → prepare_scene (or a
// checkpoint) → Run, then Run::step_to and Run::finish, so that n steps here are the CLI's n steps
// bit for bit, with the same outputs, checkpoints, restart and [monitor] when given an output
// directory. Positions, velocities, energies, forces and the thermo row are read back as numpy
// arrays.
//
// Units: every number that crosses the module's boundary is in the deck's units (`units`, README
// "Units"), as the CLI's inputs and outputs are; DeckUnits below does every conversion.
//
// Errors: InputError (bad deck, bad --set) → ValueError with its one line; NumericalError
// (non-finite state, a constraint solve that fails) → stiffmd.NumericalError (a RuntimeError).
#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <limits>
#include <memory>
#include <optional>
#include <sstream>
#include <stdexcept>
#include <string>
#include <vector>

#include "core/errors.hpp"
#include "engine/deck/deck.hpp"
#include "engine/observe/observables.hpp"
#include "engine/run/checkpoint.hpp"
#include "engine/run/launcher.hpp"
#include "engine/run/run.hpp"
#include "engine/scene/ensemble_deck.hpp"
#include "engine/scene/scene.hpp"
#include "integrators/methods.hpp"

namespace py = pybind11;
using namespace stiffmd;

namespace {

// A Python value as the right-hand side of a --set override (TOML text; a str goes as it is,
// which the deck reads as TOML or else as a string, like the command line).
std::string toml_value(const py::handle& v) {
  if (py::isinstance<py::str>(v)) return v.cast<std::string>();
  if (py::isinstance<py::bool_>(v)) return v.cast<bool>() ? "true" : "false";
  if (py::isinstance<py::int_>(v)) return py::str(v).cast<std::string>();
  if (py::isinstance<py::float_>(v)) return py::repr(v).cast<std::string>();  // shortest round trip
  if (py::isinstance<py::list>(v) || py::isinstance<py::tuple>(v)) {
    std::string s = "[";
    bool first = true;
    for (const py::handle& e : v) {
      s += (first ? "" : ", ") + (py::isinstance<py::str>(e) ? py::repr(e).cast<std::string>() : toml_value(e));
      first = false;
    }
    return s + "]";
  }
  throw py::type_error("set: expected str, bool, int, float or a list of them, got " +
                       py::str(py::type::of(v)).cast<std::string>());
}

std::vector<std::string> overrides(const py::dict& set) {
  std::vector<std::string> out;
  for (const auto& [key, value] : set) out.push_back(py::str(key).cast<std::string>() + "=" + toml_value(value));
  return out;
}

// 3×N (the engine's column per particle) → N×3 numpy array, a copy, each entry times `scale`.
py::array_t<double> to_numpy(const Eigen::Matrix3Xd& m, double scale) {
  py::array_t<double> a({static_cast<py::ssize_t>(m.cols()), py::ssize_t{3}});
  auto r = a.mutable_unchecked<2>();
  for (Eigen::Index i = 0; i < m.cols(); ++i)
    for (int k = 0; k < 3; ++k) r(i, k) = m(k, i) * scale;
  return a;
}

// N×3 array-like → 3×N, each entry times `scale`, refusing another shape or a non-finite entry
// (ValueError).
void from_numpy(const py::handle& obj, Eigen::Matrix3Xd& m, double scale, const char* what) {
  const auto a = py::array_t<double, py::array::c_style | py::array::forcecast>::ensure(obj);
  if (!a) throw py::value_error(std::string(what) + ": expected an array of numbers");
  if (a.ndim() != 2 || a.shape(0) != m.cols() || a.shape(1) != 3)
    throw py::value_error(std::string(what) + ": expected shape (" + std::to_string(m.cols()) + ", 3)");
  auto r = a.unchecked<2>();
  for (Eigen::Index i = 0; i < m.cols(); ++i)
    for (int k = 0; k < 3; ++k)
      if (!std::isfinite(r(i, k)))
        throw py::value_error(std::string(what) + ": non-finite value for particle " + std::to_string(i));
  for (Eigen::Index i = 0; i < m.cols(); ++i)
    for (int k = 0; k < 3; ++k) m(k, i) = scale * r(i, k);
}

// The deck's units at the module's boundary (core/units.hpp), the one place where the
// module converts. Out of the engine a value of dimension d is multiplied by Units::out(d), as the
// CLI's outputs are (real: time in fs, velocity in Å/fs, as its data files write them); into it by
// the factor the deck's own values get (times as Units::time_in, velocities as imported ones,
// Units::velocity_in(1)·v). Lengths, energies and forces pass with the factor 1 (their internal
// unit is the deck's: Å, kcal/mol, kcal/(mol Å) in real units); so do masses (g/mol), which have
// no Dimension. The thermo row goes through the CLI's ThermoOutput, which converts each column by
// its thermo_column_dimension.
class DeckUnits {
 public:
  explicit DeckUnits(const Units& units) : units_(units) {}
  const std::string& name() const { return units_.name; }
  double out(double value, Dimension d) const { return value * units_.out(d); }
  py::array_t<double> out(const Eigen::Matrix3Xd& m, Dimension d) const { return to_numpy(m, units_.out(d)); }
  double in(double value, Dimension d) const { return in_factor(d) * value; }
  void in(const py::handle& a, Eigen::Matrix3Xd& m, Dimension d, const char* what) const {
    from_numpy(a, m, in_factor(d), what);
  }

 private:
  double in_factor(Dimension d) const {
    switch (d) {
      case Dimension::time:  // as the deck's h and t_end (engine/scene/scene.cpp)
        return units_.time_in(1.0);
      case Dimension::velocity:  // as [[particles]] velocity and imported Velocities
        return units_.velocity_in(1.0);
      case Dimension::length:
      case Dimension::force:
      case Dimension::energy:
        return 1.0;
      default:  // nothing else comes in
        throw std::logic_error("DeckUnits::in: a dimension the module does not take in");
    }
  }

  const Units& units_;
};

// A level by its name in the scene ("fast", "slow", or the deck's [[integrator.levels]]).
Level parse_level_or_throw(const ForceField& forces, const std::string& name) {
  if (auto l = forces.find_level(name)) return *l;
  std::string known;
  for (int k = 0; k < forces.num_levels(); ++k) known += (k ? ", \"" : "\"") + forces.level_name(Level{k}) + "\"";
  throw py::value_error("level: expected one of " + known + " (or None for all), got \"" + name + "\"");
}

// The module runs one process. Started as one of several (mpiexec -n N python3 …), each process
// would run the whole deck into the same files: refused before anything is read or written, with
// the command that runs the deck on N ranks.
std::unique_ptr<Deck> one_process_only(std::unique_ptr<Deck> deck) {
  const int n = launched_processes();
  if (n <= 1) return deck;
  throw py::value_error("stiffmd.Simulation runs one process, but this is one of " + std::to_string(n) +
                        " started by a launcher; run the deck on " + std::to_string(n) +
                        " ranks with the command line instead: mpiexec -n " + std::to_string(n) + " stiffmd run " +
                        deck->path() + " -o DIR");
}

class Simulation {
 public:
  // The CLI's run (engine/run/run.hpp) driven from Python: `output` a directory for the deck's
  // outputs, periodic checkpoints and summary.json (none: no files, the thermo samples and the
  // [monitor] still on their grid); `restart` a checkpoint to continue, checked before anything
  // is prepared, as `stiffmd run --restart` does.
  Simulation(std::unique_ptr<Deck> deck, const std::optional<std::string>& output,
             const std::optional<std::string>& restart)
      : deck_(one_process_only(std::move(deck))), scene_(load_scene(*deck_)), units_(scene_.units) {
    // An [ensemble] deck is many runs (engine/run/ensemble.*): stepping its base deck would look
    // like a member and be none of them.
    DeckTable root = deck_->root();
    if (const auto ensemble = read_ensemble(root))
      throw py::value_error(ensemble->where + ": an [ensemble] deck is " + std::to_string(ensemble->size()) +
                            " runs: run it with `stiffmd run`, or step one member here with its overrides in set= (" +
                            ensemble->label(0) + " for member 0) and the [ensemble] table removed");
    for (const auto& note : scene_.notes) log_ << note << "\n";
    std::optional<Checkpoint> checkpoint;
    if (restart)
      checkpoint = read_checkpoint_for(scene_, *restart);
    else
      prepare_scene(scene_, log_);  // a restart's state is the checkpoint's
    RunOptions options;
    options.out_dir = output.value_or("");
    options.restart = restart.value_or("");
    options.checkpoint = checkpoint ? &*checkpoint : nullptr;
    options.handle_signals = false;  // Ctrl-C is Python's (run)
    run_ = std::make_unique<Run>(scene_, options, log_);
  }

  // Macro steps: step k ends at t = k h exactly, the CLI's step k bit for bit.
  void run(std::int64_t steps) {
    if (steps < 0) throw py::value_error("steps: expected a number >= 0");
    if (finished_) throw py::value_error("run: the run is finished (finish() was called)");
    const State& s = scene_.state;
    const std::int64_t last = s.step + steps;
    py::gil_scoped_release free;
    while (s.step < last) {
      run_->step_to(std::min(last, s.step + 1024));
      py::gil_scoped_acquire held;  // Ctrl-C: stop between steps, the state consistent
      if (PyErr_CheckSignals() != 0) throw py::error_already_set();
    }
  }

  // To the first step at or after t (in the deck's time unit), rounded as run.t_end is.
  void run_to(double t_deck) {
    const double t = units_.in(t_deck, Dimension::time);
    const std::int64_t n = std::isfinite(t) ? whole_steps(t, scene_.integrator.h) : -1;
    if (n < scene_.state.step) {
      std::ostringstream m;
      m.precision(17);
      m << "run_to: t = " << t_deck << " is before the current time " << time();
      throw py::value_error(m.str());
    }
    run(n - scene_.state.step);
  }

  // Ends the run as `stiffmd run` ends it: the checkpoint, the final state in every output and
  // summary.json (with an output directory); returns the summary. No step after it.
  py::dict finish() {
    if (finished_) throw py::value_error("finish: the run is finished already");
    finished_ = true;
    const RunSummary& r = run_->finish();
    py::dict d;
    d["method"] = r.method;
    d["units"] = r.units;
    d["steps"] = r.steps;
    d["h"] = r.h;
    d["initial_energy"] = r.initial_energy;
    d["final_energy"] = r.final_energy;
    d["max_energy_error"] = r.max_energy_error;
    d["conserved_energy_drift"] = r.conserved_energy_drift;
    d["max_conserved_energy_error"] = r.max_conserved_error;
    d["outputs"] = r.outputs;
    d["checkpoint"] = r.checkpoint;
    return d;
  }

  // A state set from outside: the integrator's cached forces are stale, and energy_drift (and
  // the conserved energy's) is measured from the new state's energy on.
  void set_positions(const py::handle& a) {
    units_.in(a, scene_.state.x, Dimension::length, "positions");
    run_->state_changed();
  }
  void set_velocities(const py::handle& a) {
    units_.in(a, scene_.state.v, Dimension::velocity, "velocities");
    run_->state_changed();
  }
  py::array_t<double> positions() const { return units_.out(scene_.state.x, Dimension::length); }
  py::array_t<double> velocities() const { return units_.out(scene_.state.v, Dimension::velocity); }
  double time() const { return units_.out(scene_.state.t, Dimension::time); }
  double h() const { return units_.out(scene_.integrator.h, Dimension::time); }
  double t_end() const { return units_.out(scene_.run.t_end, Dimension::time); }
  const std::string& units() const { return units_.name(); }
  // The method's preparation of the current state again (projection onto g = 0 for RATTLE and
  // the effective dynamics, the actions of the latter), as at the start of a run.
  void prepare() {
    run_->integrator().prepare(scene_.state, log_);
    run_->state_changed();
  }

  double energy(const std::optional<std::string>& level) const {
    const Eigen::Matrix3Xd& x = scene_.state.x;
    if (level)
      return units_.out(scene_.forces->energy(x, parse_level_or_throw(*scene_.forces, *level)), Dimension::energy);
    double u = scene_.forces->energy(x, Level{0});
    for (int k = 1; k < scene_.forces->num_levels(); ++k) u += scene_.forces->energy(x, Level{k});
    return units_.out(u, Dimension::energy);
  }
  py::array_t<double> forces(const std::optional<std::string>& level) {
    Eigen::Matrix3Xd f;
    if (level) {
      const Level l = parse_level_or_throw(*scene_.forces, *level);
      scene_.forces->compute(scene_.state.x, {l}, f);
    } else {
      scene_.forces->compute(scene_.state.x, scene_.forces->all_levels(), f);
    }
    return units_.out(f, Dimension::force);
  }

  // The thermo row {column: value} at the current state as the CLI's thermo.csv writes it (its
  // columns, thermo_norm, the deck's units: ThermoOutput), sampled now; alerts are the run's
  // [monitor] at its own samples.
  py::dict thermo() {
    const std::vector<double>& row = run_->as_written(run_->sample_now());
    py::dict d;
    const auto& columns = run_->thermo_table().columns();
    for (size_t k = 0; k < columns.size(); ++k)
      if (columns[k] != "alerts") d[py::str(columns[k])] = row[k];
    return d;
  }

  const Scene& scene() const { return scene_; }
  std::string log() const { return log_.str(); }

 private:
  std::unique_ptr<Deck> deck_;
  Scene scene_;
  DeckUnits units_;
  std::ostringstream log_;
  std::unique_ptr<Run> run_;
  bool finished_ = false;
};

}  // namespace

PYBIND11_MODULE(stiffmd, m) {
  m.doc() = "stiffmd: molecular dynamics with stiff bonds, stepped from Python";
  static py::exception<NumericalError> numerical_error(m, "NumericalError", PyExc_RuntimeError);
  py::register_exception_translator([](std::exception_ptr p) {
    try {
      if (p) std::rethrow_exception(p);
    } catch (const InputError& e) {
      PyErr_SetString(PyExc_ValueError, e.what());
    } catch (const NumericalError& e) {
      numerical_error(e.what());
    } catch (const std::invalid_argument& e) {  // make_integrator: a method the scene cannot run
      PyErr_SetString(PyExc_ValueError, e.what());
    }
  });

  m.def(
      "methods",
      [] {
        std::vector<std::string> names;
        for (const MethodInfo& info : stiffmd::methods()) names.emplace_back(info.name);
        return names;
      },
      "The integrator methods (integrator.method), in the order of README.");

  py::class_<Simulation>(m, "Simulation",
                         "A scene from a deck with its integrator, prepared as `stiffmd run` prepares it.\n\n"
                         "Every number in and out is in the deck's units (`units`), as the CLI's: with "
                         "units = \"lj\" reduced (sigma, m, epsilon, tau); with units = \"real\" lengths in "
                         "Angstrom, masses in g/mol, energies in kcal/mol, forces in kcal/(mol Angstrom), "
                         "times in fs, velocities in Angstrom/fs, temperature in K, pressure in atm.")
      .def(py::init([](const std::string& path, const py::dict& set, const std::optional<std::string>& output,
                       const std::optional<std::string>& restart) {
             return std::make_unique<Simulation>(std::make_unique<Deck>(path, overrides(set)), output, restart);
           }),
           py::arg("deck"), py::arg("set") = py::dict(), py::arg("output") = py::none(),
           py::arg("restart") = py::none(),
           "From a deck file; `set` overrides keys like --set: {\"integrator.method\": \"rattle\"}; `output` a "
           "directory for the deck's outputs, checkpoints and summary.json, as `stiffmd run -o` (None: no files); "
           "`restart` a checkpoint to continue from, as --restart.")
      .def_static(
          "from_toml",
          [](const std::string& text, const py::dict& set, const std::string& name,
             const std::optional<std::string>& output, const std::optional<std::string>& restart) {
            return std::make_unique<Simulation>(std::make_unique<Deck>(Deck::Text{name, text}, overrides(set)), output,
                                                restart);
          },
          py::arg("text"), py::arg("set") = py::dict(), py::arg("name") = "<toml>", py::arg("output") = py::none(),
          py::arg("restart") = py::none(), "From TOML text; `name` stands for the file in error messages.")
      .def("finish", &Simulation::finish,
           "End the run as `stiffmd run` does: the checkpoint, the final state in every output and summary.json "
           "(with an output directory); returns the summary as a dict. No step after it.")
      .def("run", &Simulation::run, py::arg("steps"), "Take `steps` macro steps of size h.")
      .def("run_to", &Simulation::run_to, py::arg("t"),
           "Step to time t (the deck's time unit: fs in real units), the first step at or after t.")
      .def("prepare", &Simulation::prepare,
           "Apply the method's preparation to the current state again (projection onto the constraints, actions).")
      .def("energy", &Simulation::energy, py::arg("level") = py::none(),
           "Potential energy (the deck's energy unit: kcal/mol in real units) of a level (\"fast\", \"slow\", or a "
           "name of the deck's [[integrator.levels]]) or of all (None) at the current positions.")
      .def("forces", &Simulation::forces, py::arg("level") = py::none(),
           "Forces (N×3; kcal/(mol Angstrom) in real units) of a level (\"fast\", \"slow\", or a name of the deck's "
           "[[integrator.levels]]) or of all (None) at the current positions.")
      .def("thermo", &Simulation::thermo,
           "The thermo row {column: value} at the current state, as the CLI's thermo.csv writes it: its columns "
           "(\"_per_atom\" with output.thermo_norm), each in the deck's units (real: time in fs, energies in "
           "kcal/mol, temperature in K, pressure in atm, lengths in Angstrom, frequencies in 1/fs); no alerts.")
      .def_property("positions", &Simulation::positions, &Simulation::set_positions,
                    "Positions, N×3 (Angstrom in real units; a copy; assign an N×3 array to set).")
      .def_property("velocities", &Simulation::velocities, &Simulation::set_velocities,
                    "Velocities, N×3 (Angstrom/fs in real units, as the CLI's data files; a copy; assign an N×3 "
                    "array to set).")
      .def_property_readonly(
          "masses",
          [](const Simulation& s) {
            const Eigen::VectorXd& w = s.scene().state.inv_mass;
            py::array_t<double> a(w.size());
            auto r = a.mutable_unchecked<1>();
            for (Eigen::Index i = 0; i < w.size(); ++i)
              r(i) = w[i] > 0.0 ? 1.0 / w[i] : std::numeric_limits<double>::infinity();
            return a;
          },
          "Masses (g/mol in real units; inf for a fixed particle).")
      .def_property_readonly("units", &Simulation::units, "The deck's units: \"lj\" or \"real\".")
      .def_property_readonly("time", &Simulation::time, "The current time t = step h (fs in real units).")
      .def_property_readonly("step", [](const Simulation& s) { return s.scene().state.step; })
      .def_property_readonly("h", &Simulation::h, "The macro step integrator.h (fs in real units).")
      .def_property_readonly("micro_steps", [](const Simulation& s) { return s.scene().integrator.micro_steps; })
      .def_property_readonly("method", [](const Simulation& s) { return s.scene().integrator.method; })
      .def_property_readonly(
          "levels",
          [](const Simulation& s) {
            std::vector<std::string> names;
            for (int k = 0; k < s.scene().forces->num_levels(); ++k)
              names.push_back(s.scene().forces->level_name(Level{k}));
            return names;
          },
          "The force levels' names, innermost first.")
      .def_property_readonly("t_end", &Simulation::t_end, "The deck's run.t_end (fs in real units).")
      .def_property_readonly("num_particles", [](const Simulation& s) { return s.scene().state.size(); })
      .def_property_readonly("log", &Simulation::log, "What preparation said (the CLI prints it on stderr).")
      .def("__repr__", [](const Simulation& s) {
        std::ostringstream o;
        o << "<stiffmd.Simulation " << s.scene().deck_path << ": " << s.scene().state.size() << " particles, "
          << s.scene().integrator.method << ", units " << s.units() << ", h = " << s.h() << ", t = " << s.time() << ">";
        return o.str();
      });
}
