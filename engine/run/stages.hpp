// A staged protocol (docs/decks.md "[[stage]]", docs/design.md §8): the deck's stages run one after
// the other in one `stiffmd run`, each a whole run of its own deck (engine/scene/stage_deck.hpp)
// from the state the previous one left (pass_state), into OUT/<k>_<name>; OUT/protocol.json lists
// them at the end.
//
// Each stage counts its steps and time from 0: stage k is exactly the run of its deck from the
// state passed on, fresh or restarted, so its checkpoints, time grids and restarts are a plain
// run's (t_k = k h with the stage's own h). Its checkpoints name the stage (number and name,
// Checkpoint::stage): `--restart` with one continues that stage and then runs the later ones; a
// checkpoint at its stage's end (its final one) starts the next stage from its state. So a
// protocol restarted from any checkpoint ends in the uninterrupted protocol's state bit for bit.
//
// On several processes (docs/parallel.md) every stage is decomposed over all of them. What each
// rank does alone between two stages (loading the next stage's scene, passing the state on,
// [minimize]) is agreed before the next collective call: a stage's setup fails alike on every rank.
#pragma once

#include <cstdint>
#include <cstdio>
#include <memory>
#include <optional>
#include <ostream>
#include <string>
#include <vector>

#include "core/communicator.hpp"
#include "engine/deck/deck.hpp"
#include "engine/run/checkpoint.hpp"
#include "engine/run/run.hpp"
#include "engine/scene/stage_deck.hpp"

namespace stiffmd {

// The state a stage leaves to the next: positions and velocities (the masses are the same scene's),
// and the box; the next stage's step and time start at 0. (The force field and its pair terms keep
// the box they were built with: a box that changed during a stage must be set there too.)
void pass_state(const Scene& from, Scene& to);

struct Protocol {
  std::string deck_path;
  std::vector<StageSpec> stages;
  std::vector<std::unique_ptr<Deck>> decks;  // stage k's deck (stage_deck)
  // Where the run starts: stage `start` (0-based) on `scene` — prepared ([prepare], the stage's
  // [minimize]), or holding the state a finished stage's checkpoint passed on — or, with
  // `checkpoint`, continuing that checkpoint (`restart` its path) inside the stage.
  std::size_t start = 0;
  std::optional<Scene> scene;
  std::optional<Checkpoint> checkpoint;
  std::string restart;
  // The stages' notes and warnings from loading, each once ("stage k (name): " before it).
  std::vector<std::string> notes;

  int count() const { return static_cast<int>(stages.size()); }
};

// Every stage's deck built and its scene loaded (load_stage_scene: errors name the stage), each
// checked to be one scene with stage 1's (scene_fingerprint) and, with `ranks` > 1, against the
// decomposition (check_parallel_grid); keeps stage 1's scene. Work of this process alone.
Protocol load_protocol(const Deck& base, std::vector<StageSpec> stages, int ranks);

// A fresh protocol: stage 1's scene prepared (prepare_scene: [prepare], then the stage's
// [minimize]). Work of this process alone.
void start_protocol(Protocol& p, std::ostream& log, std::ostream* progress);

// A restart from the checkpoint at `path`: it must be of one of the deck's stages (number and
// name) — then the protocol starts inside that stage from it, or, when it is that stage's final
// checkpoint, at the next stage from its state — else InputError (exit 2) with one line. Work of
// this process alone.
void resume_protocol(Protocol& p, const std::string& path, std::ostream& log, std::ostream* progress);

// `stiffmd check`: every stage's run built and discarded (check_run), stage 1 on its prepared
// state and each later one on that state passed on (a later stage's [minimize] runs only in a run).
// Returns the description: the scene once, then each stage's settings.
std::string check_protocol(Protocol& p, std::ostream& log);

struct ProtocolOutcome {
  std::vector<RunSummary> summaries;  // of the stages run here
  int stopped_by_signal = 0;          // SIGINT/SIGTERM: stopped after writing `checkpoint`
  std::string checkpoint;             // the checkpoint to continue from
  std::string where;                  // "in stage 2 (equilibrate)", "after stage 1 (relax)"
  std::string protocol_json;          // OUT/protocol.json, written when the last stage finished
};

// Runs the stages from p.start into options.out_dir/<k>_<name> (every other option as for one
// run). `stages_out`: where "stage k/N name -> DIR" and each
// stage's summary go (null: nowhere). Stops after the stage in progress on SIGINT/SIGTERM, or
// between stages, with the checkpoint to continue from.
ProtocolOutcome run_protocol(Protocol& p, const RunOptions& options, std::ostream& log, std::FILE* stages_out);

}  // namespace stiffmd
