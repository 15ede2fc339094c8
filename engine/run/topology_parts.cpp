#include "engine/run/topology_parts.hpp"

#include <algorithm>
#include <cmath>
#include <fstream>
#include <limits>
#include <stdexcept>
#include <vector>

#include "core/errors.hpp"
#include "engine/io/lammps_data_rows.hpp"
#include "engine/io/rows_to_root.hpp"
#include "engine/run/lammps_type_numbers.hpp"

namespace stiffmd {
namespace {

// A failure found on every rank alike: agreed when there are several.
template <class Error, class AgreedError>
[[noreturn]] void fail_alike(const Communicator& ranks, const std::string& what) {
  if (ranks.size() > 1) throw AgreedError(what, ranks.root());
  throw Error(what);
}

// Rank 0's file, written block by block as the rows arrive.
struct RootFile {
  std::ofstream file;
  std::string text;
  void flush() {
    file.write(text.data(), static_cast<std::streamsize>(text.size()));
    text.clear();
  }
};

// One section of bonded items (by place): its rows (type number, then the atoms' ids) streamed to
// rank 0, numbered from 1 in the whole system's order.
template <class Item, std::size_t M>
void stream_items(const Communicator& ranks, const std::vector<PartMolecules::Placed<Item>>& items,
                  int Item::*const (&members)[M], const std::vector<int>& number, std::int64_t total,
                  const char* section, RootFile& out) {
  if (total == 0) return;
  if (ranks.root()) lammps_rows::append_section(out.text, section);
  constexpr int kWidth = 1 + static_cast<int>(M);
  stream_rows_to_root(
      ranks, {total, kWidth}, items.size(), [&](std::size_t k) { return items[k].place; },
      [&](std::size_t k, double* row) {
        row[0] = number[static_cast<std::size_t>(items[k].item.type)];
        for (std::size_t m = 0; m < M; ++m) row[1 + m] = items[k].item.*members[m] + 1.0;
      },
      [&](std::int64_t first, std::int64_t count, const double* rows) {
        for (std::int64_t r = 0; r < count; ++r) {
          const double* row = rows + r * kWidth;
          long long id[M];
          for (std::size_t m = 0; m < M; ++m) id[m] = static_cast<long long>(row[1 + m]);
          const long long k = first + r + 1;
          const int type = static_cast<int>(row[0]);
          if constexpr (M == 2)
            lammps_rows::append_item(out.text, k, type, {id[0], id[1]});
          else if constexpr (M == 3)
            lammps_rows::append_item(out.text, k, type, {id[0], id[1], id[2]});
          else
            lammps_rows::append_item(out.text, k, type, {id[0], id[1], id[2], id[3]});
        }
        out.flush();
      });
}

constexpr int Bond::*kBondMembers[] = {&Bond::i, &Bond::j};
constexpr int Angle::*kAngleMembers[] = {&Angle::i, &Angle::j, &Angle::k};
constexpr int Dihedral::*kDihedralMembers[] = {&Dihedral::i, &Dihedral::j, &Dihedral::k, &Dihedral::l};
constexpr int Improper::*kImproperMembers[] = {&Improper::i, &Improper::j, &Improper::k, &Improper::l};

}  // namespace

void write_topology_parts(const Scene& sc, const PartMolecules& mine, const Eigen::Matrix3Xd& x,
                          const Eigen::Matrix3Xd& v, std::int64_t n, const Communicator& ranks, const std::string& path,
                          const std::string& title) {
  const auto here = static_cast<std::size_t>(mine.size());
  if (static_cast<std::size_t>(x.cols()) != here || static_cast<std::size_t>(v.cols()) != here ||
      mine.type.size() != here || mine.charge.size() != here)
    throw std::invalid_argument("write_topology_parts: x, v and the part's arrays need one column per particle");
  const auto fail = [&](const std::string& what) { return path + ": cannot write LAMMPS data: " + what; };

  // The whole system's counts, and whether any particle is charged (the atom style: `full`).
  std::int64_t counts[5] = {static_cast<std::int64_t>(mine.bonds.size()), static_cast<std::int64_t>(mine.angles.size()),
                            static_cast<std::int64_t>(mine.dihedrals.size()),
                            static_cast<std::int64_t>(mine.impropers.size()),
                            std::any_of(mine.charge.begin(), mine.charge.end(), [](double q) { return q != 0.0; })};
  ranks.sum(counts, 5);
  const std::int64_t bonds = counts[0], angles = counts[1], dihedrals = counts[2], impropers = counts[3];
  const bool charged = counts[4] > 0;

  // The first atom (by id) with a non-finite position, velocity (in the file's units) or charge.
  const double velocity_unit = sc.units.out(Dimension::velocity);  // LAMMPS's (real: Å/fs)
  std::int64_t bad = n;
  for (std::size_t k = 0; k < here && bad == n; ++k) {
    const auto c = static_cast<Eigen::Index>(k);
    for (int d = 0; d < 3; ++d)
      if (!std::isfinite(x(d, c)) || !std::isfinite(v(d, c) * velocity_unit) ||
          (charged && !std::isfinite(mine.charge[k])))
        bad = mine.global[k];
  }
  ranks.min(&bad, 1);
  if (bad < n)
    fail_alike<NumericalError, AgreedStop>(
        ranks, fail("atom id " + std::to_string(bad + 1) + " has a non-finite position, velocity or charge"));

  // The box: the periodic one now (a barostat moves it), else the particles' bounding box ± 1.
  Eigen::Vector3d lo, hi;
  if (sc.box.periodic.all()) {
    lo = sc.forces->box().origin;
    hi = sc.forces->box().origin + sc.forces->box().lengths;
  } else {
    double extent[6];  // −min, max per axis: one reduction
    for (int d = 0; d < 3; ++d) {
      extent[d] = extent[3 + d] = -std::numeric_limits<double>::infinity();
      for (Eigen::Index c = 0; c < x.cols(); ++c) {
        extent[d] = std::max(extent[d], -x(d, c));
        extent[3 + d] = std::max(extent[3 + d], x(d, c));
      }
    }
    ranks.max(extent, 6);
    for (int d = 0; d < 3; ++d) lo[d] = -extent[d] - 1.0, hi[d] = extent[3 + d] + 1.0;
  }

  const LammpsTypes numbers = lammps_types(sc);
  const lammps_format::Style* style = lammps_format::find_style(charged                          ? "full"
                                                                : dihedrals > 0 || impropers > 0 ? "molecular"
                                                                : angles == 0                    ? "bond"
                                                                                                 : "angle");
  RootFile out;
  std::string problem;
  if (ranks.root()) {
    out.file.open(path, std::ios::binary | std::ios::trunc);
    if (!out.file) problem = fail("cannot open the file for writing");
  }
  if (const Communicator::Problem first = ranks.first_problem(problem); first.rank >= 0)
    fail_alike<InputError, AgreedInputError>(ranks, first.said());

  if (ranks.root()) {
    lammps_rows::Header header;
    header.title = title;
    header.style = style;
    header.atoms = n, header.bonds = bonds, header.angles = angles;
    header.dihedrals = dihedrals, header.impropers = impropers;
    header.atom_types = numbers.atom_types, header.bond_types = numbers.bond_types;
    header.angle_types = numbers.angle_types, header.dihedral_types = numbers.dihedral_types;
    header.improper_types = numbers.improper_types;
    header.lo = lo, header.hi = hi;
    header.type_mass = &numbers.type_mass;
    lammps_rows::append_header(out.text, header);
  }
  const auto global = [&](std::size_t k) { return static_cast<std::int64_t>(mine.global[k]); };
  if (n > 0) {
    // Atoms: molecule id (from 1; 0 without molecules), type number, charge, position.
    if (ranks.root()) lammps_rows::append_section(out.text, "Atoms # " + std::string(style->name));
    stream_rows_to_root(
        ranks, {n, 6}, here, global,
        [&](std::size_t k, double* row) {
          row[0] = mine.molecule_id.empty() ? 0.0 : mine.molecule_id[k] + 1.0;
          row[1] = numbers.atom[static_cast<std::size_t>(mine.type[k])];
          row[2] = charged ? mine.charge[k] : 0.0;
          for (int d = 0; d < 3; ++d) row[3 + d] = x(d, static_cast<Eigen::Index>(k));
        },
        [&](std::int64_t first, std::int64_t count, const double* rows) {
          for (std::int64_t r = 0; r < count; ++r) {
            const double* row = rows + 6 * r;
            lammps_rows::append_atom(out.text, *style, first + r + 1, static_cast<long long>(row[0]),
                                     static_cast<int>(row[1]), row[2], row + 3, lo, hi);
          }
          out.flush();
        });
    if (ranks.root()) lammps_rows::append_section(out.text, "Velocities");
    stream_rows_to_root(
        ranks, {n, 3}, here, global,
        [&](std::size_t k, double* row) {
          for (int d = 0; d < 3; ++d) row[d] = v(d, static_cast<Eigen::Index>(k)) * velocity_unit;
        },
        [&](std::int64_t first, std::int64_t count, const double* rows) {
          for (std::int64_t r = 0; r < count; ++r) lammps_rows::append_velocity(out.text, first + r + 1, rows + 3 * r);
          out.flush();
        });
  }
  stream_items(ranks, mine.bonds, kBondMembers, numbers.bond, bonds, "Bonds", out);
  stream_items(ranks, mine.angles, kAngleMembers, numbers.angle, angles, "Angles", out);
  stream_items(ranks, mine.dihedrals, kDihedralMembers, numbers.dihedral, dihedrals, "Dihedrals", out);
  stream_items(ranks, mine.impropers, kImproperMembers, numbers.improper, impropers, "Impropers", out);

  if (ranks.root()) {
    out.flush();
    out.file.close();
    if (!out.file) problem = fail("write failed (disk full?)");
  }
  if (const Communicator::Problem first = ranks.first_problem(problem); first.rank >= 0)
    fail_alike<InputError, AgreedInputError>(ranks, first.said());
}

}  // namespace stiffmd
