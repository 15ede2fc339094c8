// The runs of an [ensemble] deck (engine/scene/ensemble_deck.hpp): member k is one whole run of
// the deck with the command line's --set and then the member's own, written to OUT/member_k —
// exactly the files of `stiffmd run DECK -o OUT/member_k --set …` with those overrides. The
// members are independent: which process runs which (engine/run/processes.hpp) changes no bit.
#pragma once

#include <cstdio>
#include <ostream>
#include <string>
#include <vector>

#include "engine/scene/ensemble_deck.hpp"

namespace stiffmd {

struct EnsembleJob {
  std::string deck_path;
  std::vector<std::string> overrides;  // the command line's --set, before each member's own
  Ensemble ensemble;
  std::string out_dir;
  int processes = 1;  // the members are divided among them, each member whole on one

  int members() const { return ensemble.size(); }
  // OUT/member_k, k zero-padded to the digits of the member count (member_00 … member_11).
  std::string member_dir(int k) const;
  std::vector<std::string> member_overrides(int k) const;
  // "member 2 (thermostat.seed=3)"
  std::string member_name(int k) const;
};

// Loads every member's scene (and discards it), so that a bad value fails before any member
// runs: an InputError naming the member, the varied key's line and the member's value when the
// value is what fails.
void load_members(const EnsembleJob& job);

// `stiffmd check` of an ensemble deck: every member loads, prepares and builds its run.
void check_members(const EnsembleJob& job, std::ostream& log);

// Where a member's terminal output goes: thermo lines (null: none), the progress bar on `log`.
struct MemberTerminal {
  std::FILE* screen = nullptr;
  bool progress = false;
};

struct MemberOutcome {
  int member = 0;
  int exit_code = 0;  // 0, 2 bad input, 3 numerical failure, 1 internal error, 128 + signal
  std::string line;   // one line: the member's summary, or its error
};

// Member k from its deck to run.t_end, into member_dir(k); its notes, warnings (and progress)
// on `log`. Every failure is caught and becomes the outcome's exit code and line.
MemberOutcome run_member(const EnsembleJob& job, int k, const MemberTerminal& terminal, std::ostream& log);

}  // namespace stiffmd
