// [parallel]: what a run on several ranks lets a user choose (docs/parallel.md, docs/decks.md);
// ignored on one. Read with the deck (engine/scene/scene.cpp), used by the decomposition
// (engine/domain/).
#pragma once

#include <Eigen/Core>
#include <string>

namespace stiffmd {

// The load balance (docs/parallel.md, "Load balance"). The work measure is a domain's home beads
// (the beads whose position, wrapped into the box, lies in it): deterministic, an integer, the same
// for any number of ranks, known before any neighbour list exists. The imbalance is the measure's
// max/mean over the domains; the domains are recut when it exceeds `threshold`: from the initial
// state (start), and also at a selection of the pair sets (dynamic).
struct BalanceSettings {
  enum class When { off, start, dynamic };
  When when = When::off;
  double threshold = 1.1;
};

struct ParallelSettings {
  Eigen::Vector3i grid = Eigen::Vector3i::Zero();  // domains per axis; 0: chosen (least cut surface)
  double halo_margin = 0.0;                        // the pair sets beyond the cutoff; 0: 1.5 × skin (docs/parallel.md)
  BalanceSettings balance{BalanceSettings::When::dynamic, 1.1};  // the deck's default: recut when uneven
  // halo_pairs = "once": a pair of a home bead and a halo bead computed on one rank, the halo
  // bead's force sent back (Newton's third law across ranks: the trajectory one process's to
  // round-off); "both" (the default): on both beads' homes, one process's bits (docs/parallel.md).
  bool halo_pairs_once = false;
  // "file:line: parallel.grid" (or the --set that gave it), for errors at the key; empty: not given.
  std::string grid_where, halo_margin_where, balance_where, halo_pairs_where;
};

}  // namespace stiffmd
