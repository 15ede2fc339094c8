// Shared test helpers: load bundled decks with overrides, run a scene in-process.
#pragma once

#include <string>
#include <vector>

#include "engine/deck.hpp"
#include "engine/scene.hpp"
#include "integrators/integrator.hpp"

namespace stiffmd::test {

inline std::string source_path(const std::string& rel) { return std::string(STIFFMD_SOURCE_DIR) + "/" + rel; }

inline Scene load(const std::string& rel_deck, const std::vector<std::string>& overrides = {}) {
  const Deck deck(source_path(rel_deck), overrides);
  return load_scene(deck);
}

// The seed pendulum (inputs/double_pendulum.toml) at a given ε, method and step.
inline Scene pendulum(double eps, const std::string& method, double h, double t_end,
                      std::vector<std::string> extra = {}) {
  std::vector<std::string> o = {"variables.eps=" + std::to_string(eps), "integrator.method=" + method,
                                "integrator.h=" + std::to_string(h), "run.t_end=" + std::to_string(t_end)};
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
  auto integ = make_integrator(sc.integrator, *sc.forces);
  advance(sc, n, *integ);
}

}  // namespace stiffmd::test
