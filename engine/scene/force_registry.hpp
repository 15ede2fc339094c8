// The one table of force-term styles a deck may name (docs/design.md §11.6). Each row reads a
// [forces.NAME] table into the term's validated parameters; the term itself (forcefields/)
// knows nothing about decks. A bond or pair style is a kernel (forcefields/bond_potentials.hpp,
// pair_potentials.hpp) plus one row in force_styles() (see ARCHITECTURE.md).
#pragma once

#include <memory>
#include <string>
#include <vector>

#include "engine/deck/deck.hpp"
#include "engine/scene/scene.hpp"
#include "forcefields/force_term.hpp"

namespace stiffmd {

// What a style's reader may see of the scene being assembled.
struct TermContext {
  const Scene& scene;                             // particles, types, topology and box so far
  std::vector<std::string>& bond_type_owner;      // per bond type: the term that defines it ("" = none yet)
  std::vector<std::string>& angle_type_owner;     // likewise per angle type
  std::vector<std::string>& dihedral_type_owner;  // and per dihedral type
  std::vector<std::string>& improper_type_owner;  // and per improper type
  LammpsCoeffs* lammps = nullptr;                 // where the readers put their LAMMPS coefficients (null: nowhere)
  // The pair terms' overlap finding (the closest two particles closer than the potential bears,
  // the whole error line): load_scene refuses it unless [minimize] relaxes the start.
  std::string* overlap = nullptr;
  // A description's (Scene::described()) pair terms' overlap rules, which the run applies to the
  // parts at the start (null: not kept).
  std::vector<OverlapRule>* overlap_rules = nullptr;
  // Per angle type: 1 when the stiff-harmonic term makes its angles rigid (angle_types), which
  // defines them without an angle term (one may still claim the type). Null: not recorded.
  std::vector<char>* rigid_angle_type = nullptr;
};

struct ForceStyle {
  const char* name;
  const char*
      kind;  // "bond", "angle", "dihedral", "improper", "pair", "kspace" or "external": how `stiffmd list` groups it
  Level default_level;
  const char* summary;
  std::unique_ptr<ForceTerm> (*read)(const std::string& name, Level level, DeckTable& table, TermContext& ctx);
};

const std::vector<ForceStyle>& force_styles();

// What a deck may name, for `stiffmd list` and `stiffmd --help`: the integrator methods
// (integrators/methods.hpp), the force styles grouped by kind, the thermostats and the builders,
// one line each with its summary.
std::string list_styles();

}  // namespace stiffmd
