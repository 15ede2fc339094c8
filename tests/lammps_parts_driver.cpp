// One rank's read of a LAMMPS data file, for measuring what it costs (docs/parallel.md, "What a
// rank holds"): the whole import (read_lammps_data), or rank r of P's part (read_lammps_data_part
// on the box's domain grid for P ranks, chosen as a decomposed run chooses it). Prints one JSON
// line: the atoms and bonds kept, the file's atoms, the seconds and the process's peak resident set.
//
//   build/tests/lammps_parts_driver FILE whole
//   build/tests/lammps_parts_driver FILE part RANK RANKS
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <string>

#include "core/errors.hpp"
#include "core/peak_memory.hpp"
#include "engine/domain/decomposition.hpp"
#include "engine/io/lammps_data.hpp"
#include "engine/io/lammps_data_parts.hpp"

int main(int argc, char** argv) {
  using namespace stiffmd;
  const std::string mode = argc > 2 ? argv[2] : "";
  if (!(argc == 3 && mode == "whole") && !(argc == 5 && mode == "part")) {
    std::fprintf(stderr, "usage: %s FILE whole | FILE part RANK RANKS\n", argv[0]);
    return 2;
  }
  const auto start = std::chrono::steady_clock::now();
  long kept = 0, bonds = 0, atoms = 0;
  try {
    if (mode == "whole") {
      const ImportedSystem s = read_lammps_data(argv[1]);
      kept = atoms = s.x.cols();
      bonds = static_cast<long>(s.bonds.size());
    } else {
      const int rank = std::atoi(argv[3]), ranks = std::atoi(argv[4]);
      const ImportedBox b = read_lammps_data_box(argv[1]);
      Box box;
      box.origin = b.lo, box.lengths = b.hi - b.lo, box.periodic = Eigen::Vector3i::Ones();
      const DomainGrid grid = make_domain_grid(box, ranks, nullptr, Eigen::Matrix3Xd());
      const ImportedPart p = read_lammps_data_part(
          argv[1], "auto", [&](const Eigen::Vector3d& anchor) { return grid.domain_of(anchor) == rank; });
      kept = p.system.x.cols();
      bonds = static_cast<long>(p.system.bonds.size());
      atoms = p.num_atoms;
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
