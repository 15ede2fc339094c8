// Shared test helpers: load bundled decks with overrides, run a scene in-process.
#pragma once

#include <gtest/gtest.h>

#include <algorithm>
#include <cstdio>
#include <string>
#include <vector>

#include "core/parallel.hpp"
#include "engine/deck/deck.hpp"
#include "engine/scene/scene.hpp"
#include "integrators/integrator.hpp"
#include "integrators/methods.hpp"

namespace stiffmd::test {

// The engine's thread count (set_max_threads) for a scope, the previous one restored after it.
class ThreadCount {
 public:
  explicit ThreadCount(int threads) { set_max_threads(threads); }
  ~ThreadCount() { set_max_threads(restore_); }
  ThreadCount(const ThreadCount&) = delete;
  ThreadCount& operator=(const ThreadCount&) = delete;

 private:
  int restore_ = max_threads();
};

// Every integrator method of the method table (integrators/methods.hpp), for tests
// parameterised over them: a method added to the table is tested by every such suite.
inline std::vector<std::string> all_methods() {
  std::vector<std::string> names;
  for (const MethodInfo& m : methods()) names.emplace_back(m.name);
  return names;
}
inline const std::vector<std::string> kAllMethods = all_methods();
// Test names may not hold '-'.
inline std::string method_test_name(const ::testing::TestParamInfo<std::string>& info) {
  std::string n = info.param;
  std::replace(n.begin(), n.end(), '-', '_');
  return n;
}

inline std::string source_path(const std::string& rel) {
  return std::string(STIFFMD_SOURCE_DIR) + "/" + rel;
}

inline Scene load(const std::string& rel_deck, const std::vector<std::string>& overrides = {}) {
  const Deck deck(source_path(rel_deck), overrides);
  Scene sc = load_scene(deck);
  std::ostringstream log;
  prepare_scene(sc, log);
  return sc;
}

// The seed pendulum (inputs/double_pendulum.toml) at a given ε, method and step.
// Full precision: std::to_string would print 2.5e-6 as 0.000003.
inline std::string exact(double v) {
  char buf[32];
  std::snprintf(buf, sizeof buf, "%.17g", v);
  return buf;
}

inline Scene pendulum(double eps, const std::string& method, double h, double t_end,
                      std::vector<std::string> extra = {}) {
  std::vector<std::string> o = {"variables.eps=" + exact(eps), "integrator.method=" + method,
                                "integrator.h=" + exact(h), "run.t_end=" + exact(t_end)};
  o.insert(o.end(), extra.begin(), extra.end());
  return load("inputs/double_pendulum.toml", o);
}

// Integrates the scene's own state n macro steps with its own integrator settings.
inline void advance(Scene& sc, std::int64_t n, Integrator& integ) {
  for (std::int64_t k = 0; k < n; ++k) {
    integ.step(sc.state, sc.integrator.h);
    sc.state.t += sc.integrator.h;
  }
}

inline void advance(Scene& sc, std::int64_t n) {
  auto integ = make_integrator(sc.integrator, *sc.forces, sc.state.inv_mass);
  advance(sc, n, *integ);
}

}  // namespace stiffmd::test

#include <fstream>
#include <sstream>
#include <stdexcept>

#include "engine/observe/observables.hpp"

namespace stiffmd::test {

// A numeric CSV file (thermo.csv, state.csv): its header and rows; col(name) finds a column.
struct CsvTable {
  std::vector<std::string> header;
  std::vector<std::vector<double>> rows;
  size_t col(const std::string& name) const {
    const auto it = std::find(header.begin(), header.end(), name);
    if (it == header.end()) throw std::runtime_error("no column " + name);
    return static_cast<size_t>(it - header.begin());
  }
};

inline CsvTable read_csv(const std::string& path) {
  std::ifstream in(path);
  CsvTable t;
  std::string line;
  std::getline(in, line);
  std::stringstream hs(line);
  for (std::string cell; std::getline(hs, cell, ',');) t.header.push_back(cell);
  while (std::getline(in, line)) {
    std::stringstream ls(line);
    t.rows.emplace_back();
    for (std::string cell; std::getline(ls, cell, ',');) t.rows.back().push_back(std::stod(cell));
  }
  return t;
}

// Positions and projected momenta P(x)p at every macro step (index 0 = after prepare()).
struct Trajectory {
  std::vector<Eigen::Matrix3Xd> x, pp;
  std::string log;
};

// Prepares (ACIV projection for rattle/effective) and runs n macro steps of the scene's own
// integrator, recording every `every` steps.
inline Trajectory record(Scene& sc, std::int64_t n, std::int64_t every = 1) {
  auto integ = make_integrator(sc.integrator, *sc.forces, sc.state.inv_mass);
  std::ostringstream log;
  integ->prepare(sc.state, log);
  ProjectedMomenta pp(*sc.forces->stiff_bonds(), sc.state.inv_mass);
  Trajectory tr;
  tr.log = log.str();
  for (std::int64_t k = 0; k <= n; ++k) {
    if (k > 0) integ->step(sc.state, sc.integrator.h);
    if (k % every == 0) {
      tr.x.push_back(sc.state.x);
      tr.pp.push_back(pp(sc.state));
    }
  }
  return tr;
}

// max over the common times of |a − b|∞; b is recorded `ratio` times more often than a.
inline std::pair<double, double> max_errors(const Trajectory& a, const Trajectory& b, std::int64_t ratio) {
  double ex = 0.0, ep = 0.0;
  for (size_t k = 0; k < a.x.size(); ++k) {
    ex = std::max(ex, (a.x[k] - b.x[k * ratio]).cwiseAbs().maxCoeff());
    ep = std::max(ep, (a.pp[k] - b.pp[k * ratio]).cwiseAbs().maxCoeff());
  }
  return {ex, ep};
}

}  // namespace stiffmd::test
