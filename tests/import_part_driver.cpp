// One rank's part of a deck's LAMMPS data import, for measuring what it costs (docs/parallel.md,
// "The set-up by parts"): the whole scene as load_scene assembles it, or rank r of P's part
// (import_part, engine/domain/import_part.hpp) by block of molecules or by anchor on the box's
// domain grid for P ranks. Reads the deck's [units], [types] and [import] only (no friction: a
// deck's Langevin frictions do not change what is read). Prints one JSON line: the particles and
// bonds kept, the file's particles, the seconds and the process's peak resident set.
//
//   build/tests/import_part_driver DECK whole
//   build/tests/import_part_driver DECK block RANK RANKS
//   build/tests/import_part_driver DECK anchor RANK RANKS
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <string>
#include <vector>

#include "core/errors.hpp"
#include "core/peak_memory.hpp"
#include "core/units.hpp"
#include "engine/deck/deck.hpp"
#include "engine/domain/decomposition.hpp"
#include "engine/domain/import_part.hpp"
#include "engine/scene/scene.hpp"

int main(int argc, char** argv) {
  using namespace stiffmd;
  const std::string mode = argc > 2 ? argv[2] : "";
  if (!(argc == 3 && mode == "whole") && !(argc == 5 && (mode == "block" || mode == "anchor"))) {
    std::fprintf(stderr, "usage: %s DECK whole | DECK block RANK RANKS | DECK anchor RANK RANKS\n", argv[0]);
    return 2;
  }
  const auto start = std::chrono::steady_clock::now();
  long kept = 0, bonds = 0, atoms = 0;
  try {
    const Deck deck(argv[1], {});
    if (mode == "whole") {
      const Scene sc = load_scene(deck);
      kept = atoms = sc.state.size();
      bonds = static_cast<long>(sc.topology.bonds.size());
    } else {
      DeckTable root = deck.root();
      const auto units = Units::named(root.string("units", "lj"));
      if (!units) throw InputError(std::string(argv[1]) + ": units: expected \"lj\" or \"real\"");
      std::vector<ParticleType> types;
      for (auto& [name, t] : root.table("types")->named_tables()) {
        ParticleType pt;
        pt.name = name;
        pt.mass = t.number("mass");
        pt.charge = t.number("charge", 0.0);
        types.push_back(pt);
      }
      auto table = root.table("import");
      if (!table) throw InputError(std::string(argv[1]) + ": no [import]");
      const LammpsImportDeck d = read_lammps_import(*table, std::filesystem::path(deck.path()).parent_path().string());
      const int rank = std::atoi(argv[3]), ranks = std::atoi(argv[4]);
      ImportSelection select{nullptr, {rank, ranks}};
      if (mode == "anchor") {
        const ImportedBox b = read_lammps_data_box(d.path);
        Box box;
        box.origin = b.lo, box.lengths = b.hi - b.lo, box.periodic = Eigen::Vector3i::Ones();
        const DomainGrid grid = make_domain_grid(box, ranks, nullptr, Eigen::Matrix3Xd());
        select.keep = [grid, rank](const Eigen::Vector3d& anchor) { return grid.domain_of(anchor) == rank; };
      }
      const ImportedMolecules p = import_part(d, {types, units->velocity_in(1.0), {}}, select);
      kept = p.molecules.size();
      bonds = static_cast<long>(p.molecules.bonds.size());
      atoms = p.num_particles;
    }
  } catch (const InputError& e) {
    std::fprintf(stderr, "%s\n", e.what());
    return 2;
  }
  const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  std::printf(
      "{\"mode\": \"%s\", \"atoms\": %ld, \"atoms_kept\": %ld, \"bonds_kept\": %ld, \"seconds\": %.3f, "
      "\"peak_rss_mib\": %.1f}\n",
      mode.c_str(), atoms, kept, bonds, seconds, peak_resident_mib());
  return 0;
}
