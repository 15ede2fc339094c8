// [[stage]]: a deck that is a protocol of runs, one per stage, each from the state the previous
// one left (docs/decks.md, "[[stage]]"; the runs: engine/run/stages.hpp).
//
//   [[stage]]
//   name = "equilibrate"
//   steps = 2000                 # or t_end = 10.0: exactly one
//   [stage.thermostat]
//   style = "langevin"
//   ...
//
// Stage k's deck is the base deck (every table but [[stage]]) with stage k's tables merged over
// it key by key (Deck::Merge): every stage starts from the base deck, not from the previous
// stage's. A stage sets how the scene is run — integrator, thermostat, barostat, output,
// minimize, monitor, observables, and its length — never the scene itself (particles, topology,
// force field, box, units).
#pragma once

#include <memory>
#include <string>
#include <vector>

#include "engine/deck/deck.hpp"
#include "engine/scene/scene.hpp"

namespace stiffmd {

// The tables a [[stage]] may hold (besides name, steps and t_end).
inline constexpr const char* kStageTables[] = {"integrator", "thermostat", "barostat",   "output",
                                               "minimize",   "monitor",    "observables"};

struct StageSpec {
  StageIdentity identity;  // number 1..count, name
  std::size_t index = 0;   // in the deck's array: stage[index]
  std::string where;       // "file:line: stage[index]"
};

// The deck's [[stage]] tables, validated at their keys — a name each (letters, digits, '_' and
// '-': it names the stage's output directory), unique; exactly one of steps (>= 0) and t_end
// (> 0); no table but kStageTables, and of those no [[stage.integrator.levels]] (the levels are
// the force field's) — and the top-level tables a staged deck may not have: [run] (each stage
// gives its length), [minimize] (a stage minimises at its start: give it to that stage) and
// [ensemble]. Empty when the deck has no [[stage]].
std::vector<StageSpec> read_stages(DeckTable& root);

// Stage k's deck: the base deck with the stage's tables merged over it, its steps or t_end as
// [run]'s (Deck::Merge). Messages name a stage's values where they are written, "stage[1].steps".
std::unique_ptr<Deck> stage_deck(const Deck& base, const StageSpec& stage);

// Stage k's scene: load_scene of its deck with its identity; an error is prefixed with the stage
// ("stage 2 (equilibrate): file:line: …"). Its thermostat's noise is the stage's own: from stage 2
// on the seed is stage_seed(seed, k), so that two stages with one seed, each counting its steps
// from 0, do not draw the same normals at the same step.
Scene load_stage_scene(const Deck& stage_deck, const StageSpec& stage);
std::uint64_t stage_seed(std::uint64_t seed, int number);

// "stage 2 (equilibrate)"
std::string stage_label(const StageIdentity& stage);
// "2_equilibrate": the stage's directory in the protocol's (the number zero-padded to the digits
// of the stage count, as an ensemble's members are).
std::string stage_directory(const StageIdentity& stage);

}  // namespace stiffmd
