// The LAMMPS data-file writer (write_lammps_data, lammps_data.hpp).
#include <algorithm>
#include <array>
#include <bit>
#include <charconv>
#include <cmath>
#include <cstdint>
#include <fstream>
#include <limits>
#include <numeric>
#include <string>
#include <tuple>
#include <utility>

#include "core/errors.hpp"
#include "core/format.hpp"
#include "engine/io/lammps_data.hpp"
#include "engine/io/lammps_data_format.hpp"
#include "engine/io/lammps_data_rows.hpp"

namespace stiffmd {
namespace {

using detail::quote;
using namespace lammps_format;

// Output helpers: shortest text that reads back as the same double (core/format.hpp).
void put(std::string& out, double v) {
  append_shortest(out, v);
}
void put(std::string& out, long long v) {
  char buf[24];
  const auto r = std::to_chars(buf, buf + sizeof buf, v);
  out.append(buf, r.ptr);
}
void put(std::string& out, int v) {
  put(out, static_cast<long long>(v));
}

// == would take +0.0 for -0.0.
bool same_bits(double a, double b) {
  return std::bit_cast<std::uint64_t>(a) == std::bit_cast<std::uint64_t>(b);
}

// (w, n) with lo <= w < hi and unwrap(w, n, L) == x bit for bit; (x, 0) when no such pair exists.
// With lo = -hi, L = 2 hi is exact and, for x outside the box, x - n L is a multiple of hi's ulp
// smaller than hi, hence a double: the first candidate already reproduces x.
std::pair<double, int> wrap_exact(double x, double lo, double hi) {
  if (x >= lo && x < hi) return {x, 0};
  const double L = hi - lo;
  const double f = std::floor((x - lo) / L);
  if (!(std::abs(f) < (1 << 20))) return {x, 0};
  const int n0 = static_cast<int>(f);
  for (const int n : {n0, n0 - 1, n0 + 1}) {
    if (n == 0) continue;
    // x - nL rounded once; the exact sum may still round to a neighbour of x, so try the few
    // nearest candidates for w (the rounding of w + nL is monotone in w).
    const double w0 = std::fma(-static_cast<double>(n), L, x);
    double up = w0, down = w0;
    for (int k = 0; k < 4; ++k) {
      for (const double w : {up, down})
        if (w >= lo && w < hi && same_bits(unwrap(w, n, L), x)) return {w, n};
      up = std::nextafter(up, std::numeric_limits<double>::infinity());
      down = std::nextafter(down, -std::numeric_limits<double>::infinity());
    }
  }
  return {x, 0};
}

}  // namespace

void write_lammps_data(const std::string& path, const ImportedSystem& s, const std::string& atom_style,
                       const std::string& title) {
  const auto fail = [&](const std::string& what) { throw InputError(path + ": cannot write LAMMPS data: " + what); };
  const Style* st = find_style(atom_style);
  if (!st) fail("atom_style " + quote(atom_style) + " is not supported; expected " + std::string(kSupportedStyles));
  const bool has_bonds = st->molecule, has_angles = st->molecule && st->name != "bond",
             has_quads = has_angles && st->name != "angle";
  const auto n = static_cast<size_t>(s.x.cols());
  const auto N = std::to_string(n);
  if (s.type.size() != n)
    fail("type has " + std::to_string(s.type.size()) + " entries, expected " + N + " (one per column of x)");
  if (!s.id.empty() && s.id.size() != n) fail("id has " + std::to_string(s.id.size()) + " entries, expected 0 or " + N);
  if (!s.molecule.empty() && s.molecule.size() != n)
    fail("molecule has " + std::to_string(s.molecule.size()) + " entries, expected 0 or " + N);
  if (!s.charge.empty() && s.charge.size() != n)
    fail("charge has " + std::to_string(s.charge.size()) + " entries, expected 0 or " + N);
  const bool with_v = s.v.cols() > 0;
  if (with_v && static_cast<size_t>(s.v.cols()) != n)
    fail("v has " + std::to_string(s.v.cols()) + " columns, expected 0 or " + N);
  if (!has_bonds && !s.bonds.empty())
    fail("atom_style " + std::string(st->name) + " cannot hold bonds; expected bond, angle, molecular or full");
  if (!has_angles && !s.angles.empty())
    fail("atom_style " + std::string(st->name) + " cannot hold angles; expected angle, molecular or full");
  if (!has_quads && (!s.dihedrals.empty() || !s.impropers.empty()))
    fail("atom_style " + std::string(st->name) + " cannot hold dihedrals or impropers; expected molecular or full");
  for (int d = 0; d < 3; ++d)
    if (!(std::isfinite(s.lo[d]) && std::isfinite(s.hi[d]) && s.lo[d] < s.hi[d]))
      fail("box axis " + std::to_string(d) + " has lo = " + std::to_string(s.lo[d]) +
           ", hi = " + std::to_string(s.hi[d]) + "; expected finite lo < hi");

  const auto id_of = [&](size_t k) {
    return s.id.empty() ? static_cast<long long>(k + 1) : static_cast<long long>(s.id[k]);
  };
  {
    std::vector<long long> ids(n);
    for (size_t k = 0; k < n; ++k) ids[k] = id_of(k);
    std::sort(ids.begin(), ids.end());
    if (n > 0 && ids[0] < 1) fail("atom id " + std::to_string(ids[0]) + " is not positive");
    for (size_t k = 1; k < n; ++k)
      if (ids[k] == ids[k - 1]) fail("atom id " + std::to_string(ids[k]) + " appears twice");
  }
  int ntypes = s.num_atom_types;
  for (size_t k = 0; k < n; ++k) {
    if (s.type[k] < 1)
      fail("atom " + std::to_string(id_of(k)) + " has type " + std::to_string(s.type[k]) + "; expected >= 1");
    ntypes = std::max(ntypes, s.type[k]);
  }
  if (!s.type_mass.empty()) ntypes = std::max(ntypes, s.type_mass.rbegin()->first);
  for (int t = 1; t <= ntypes; ++t) {
    const auto it = s.type_mass.find(t);
    if (it == s.type_mass.end()) fail("atom type " + std::to_string(t) + " has no mass; LAMMPS needs one per type");
    if (!(std::isfinite(it->second) && it->second > 0))
      fail("atom type " + std::to_string(t) + " has mass " + std::to_string(it->second) + "; expected > 0");
  }
  if (!s.type_mass.empty() && s.type_mass.begin()->first < 1)
    fail("type_mass has type " + std::to_string(s.type_mass.begin()->first) + "; expected types >= 1");
  int nbt = s.num_bond_types, nat = s.num_angle_types;
  const auto check_atom = [&](int i, const char* what, size_t k) {
    if (i < 0 || static_cast<size_t>(i) >= n)
      fail(std::string(what) + " " + std::to_string(k) + " refers to atom index " + std::to_string(i) +
           "; expected 0.." + std::to_string(static_cast<long long>(n) - 1));
  };
  for (size_t k = 0; k < s.bonds.size(); ++k) {
    const auto& b = s.bonds[k];
    check_atom(b.i, "bond", k);
    check_atom(b.j, "bond", k);
    if (b.i == b.j) fail("bond " + std::to_string(k) + " joins atom index " + std::to_string(b.i) + " to itself");
    if (b.type < 1) fail("bond " + std::to_string(k) + " has type " + std::to_string(b.type) + "; expected >= 1");
    nbt = std::max(nbt, b.type);
  }
  for (size_t k = 0; k < s.angles.size(); ++k) {
    const auto& a = s.angles[k];
    check_atom(a.i, "angle", k);
    check_atom(a.j, "angle", k);
    check_atom(a.k, "angle", k);
    if (a.i == a.j || a.j == a.k || a.i == a.k) fail("angle " + std::to_string(k) + " repeats an atom");
    if (a.type < 1) fail("angle " + std::to_string(k) + " has type " + std::to_string(a.type) + "; expected >= 1");
    nat = std::max(nat, a.type);
  }
  int ndt = s.num_dihedral_types, nit = s.num_improper_types;
  for (auto [quads, what, ntypes_q] :
       {std::tuple{&s.dihedrals, "dihedral", &ndt}, std::tuple{&s.impropers, "improper", &nit}})
    for (size_t k = 0; k < quads->size(); ++k) {
      const auto& q = (*quads)[k];
      for (int i : {q.i, q.j, q.k, q.l}) check_atom(i, what, k);
      if (q.i == q.j || q.i == q.k || q.i == q.l || q.j == q.k || q.j == q.l || q.k == q.l)
        fail(std::string(what) + " " + std::to_string(k) + " repeats an atom");
      if (q.type < 1)
        fail(std::string(what) + " " + std::to_string(k) + " has type " + std::to_string(q.type) + "; expected >= 1");
      *ntypes_q = std::max(*ntypes_q, q.type);
    }
  // Coefficient sections are written back as read; each needs its kind of type declared.
  for (const auto& c : s.coeffs) {
    const int declared = c.name == "Pair Coeffs" || c.name == "PairIJ Coeffs" ? ntypes
                         : c.name == "Bond Coeffs"                            ? nbt
                         : c.name == "Angle Coeffs" || c.name == "BondBond Coeffs" || c.name == "BondAngle Coeffs" ? nat
                         : c.name == "Improper Coeffs" || c.name == "AngleAngle Coeffs"                            ? nit
                                                                                        : ndt;
    if (declared == 0) fail(c.name + ": a coefficient section without any type of its kind");
    for (const auto& r : c.rows)
      if (r.empty() || r.find_first_of("\n#") != std::string::npos)
        fail(c.name + ": row " + quote(r) + " is not one line of data");
  }
  for (size_t k = 0; k < n; ++k)
    for (int d = 0; d < 3; ++d) {
      const auto c = static_cast<Eigen::Index>(k);
      if (!std::isfinite(s.x(d, c)) || (with_v && !std::isfinite(s.v(d, c))) ||
          (!s.charge.empty() && !std::isfinite(s.charge[k])))
        throw NumericalError(path + ": cannot write LAMMPS data: atom id " + std::to_string(id_of(k)) +
                             " has a non-finite position, velocity or charge");
    }

  std::string out;
  out.reserve(96 * (n + 1) + 24 * (s.bonds.size() + s.angles.size()));
  lammps_rows::Header header;
  header.title = title;
  header.style = st;
  header.atoms = static_cast<long long>(n);
  header.bonds = static_cast<long long>(s.bonds.size());
  header.angles = static_cast<long long>(s.angles.size());
  header.dihedrals = static_cast<long long>(s.dihedrals.size());
  header.impropers = static_cast<long long>(s.impropers.size());
  header.atom_types = ntypes, header.bond_types = nbt, header.angle_types = nat;
  header.dihedral_types = ndt, header.improper_types = nit;
  header.lo = s.lo, header.hi = s.hi;
  header.type_mass = &s.type_mass;
  header.coeffs = &s.coeffs;
  lammps_rows::append_header(out, header);
  if (n > 0) {
    lammps_rows::append_section(out, "Atoms # " + std::string(st->name));
    for (size_t k = 0; k < n; ++k) {
      const double x[3] = {s.x(0, static_cast<Eigen::Index>(k)), s.x(1, static_cast<Eigen::Index>(k)),
                           s.x(2, static_cast<Eigen::Index>(k))};
      lammps_rows::append_atom(out, *st, id_of(k), s.molecule.empty() ? 0 : s.molecule[k], s.type[k],
                               s.charge.empty() ? 0.0 : s.charge[k], x, s.lo, s.hi);
    }
  }
  if (with_v && n > 0) {
    lammps_rows::append_section(out, "Velocities");
    for (size_t k = 0; k < n; ++k) lammps_rows::append_velocity(out, id_of(k), &s.v(0, static_cast<Eigen::Index>(k)));
  }
  const auto id = [&](int i) { return id_of(static_cast<size_t>(i)); };
  if (!s.bonds.empty()) {
    lammps_rows::append_section(out, "Bonds");
    long long k = 0;
    for (const auto& b : s.bonds) lammps_rows::append_item(out, ++k, b.type, {id(b.i), id(b.j)});
  }
  if (!s.angles.empty()) {
    lammps_rows::append_section(out, "Angles");
    long long k = 0;
    for (const auto& a : s.angles) lammps_rows::append_item(out, ++k, a.type, {id(a.i), id(a.j), id(a.k)});
  }
  for (auto [quads, section] : {std::pair{&s.dihedrals, "Dihedrals"}, std::pair{&s.impropers, "Impropers"}}) {
    if (quads->empty()) continue;
    lammps_rows::append_section(out, section);
    long long k = 0;
    for (const auto& q : *quads) lammps_rows::append_item(out, ++k, q.type, {id(q.i), id(q.j), id(q.k), id(q.l)});
  }

  std::ofstream f(path, std::ios::binary | std::ios::trunc);
  if (!f) fail("cannot open the file for writing");
  f.write(out.data(), static_cast<std::streamsize>(out.size()));
  f.close();
  if (!f) fail("write failed (disk full?)");
}

namespace lammps_rows {

void append_header(std::string& out, const Header& h) {
  const lammps_format::Style* st = h.style;
  const bool has_bonds = st->molecule, has_angles = st->molecule && st->name != "bond",
             has_quads = has_angles && st->name != "angle";
  std::string t = h.title;
  std::replace(t.begin(), t.end(), '\n', ' ');
  std::replace(t.begin(), t.end(), '\r', ' ');
  out += t + "\n\n";
  put(out, h.atoms);
  out += " atoms\n";
  if (has_bonds) {
    put(out, h.bonds);
    out += " bonds\n";
  }
  if (has_angles) {
    put(out, h.angles);
    out += " angles\n";
  }
  // Dihedral and improper lines only when there is something of the kind: files without them
  // stay as they were.
  const bool dihedral_lines = has_quads && h.dihedral_types > 0, improper_lines = has_quads && h.improper_types > 0;
  if (dihedral_lines) {
    put(out, h.dihedrals);
    out += " dihedrals\n";
  }
  if (improper_lines) {
    put(out, h.impropers);
    out += " impropers\n";
  }
  put(out, h.atom_types);
  out += " atom types\n";
  if (has_bonds) {
    put(out, h.bond_types);
    out += " bond types\n";
  }
  if (has_angles) {
    put(out, h.angle_types);
    out += " angle types\n";
  }
  if (dihedral_lines) {
    put(out, h.dihedral_types);
    out += " dihedral types\n";
  }
  if (improper_lines) {
    put(out, h.improper_types);
    out += " improper types\n";
  }
  out += "\n";
  static constexpr const char* kAxes[] = {" xlo xhi\n", " ylo yhi\n", " zlo zhi\n"};
  for (int d = 0; d < 3; ++d) {
    put(out, h.lo[d]);
    out += ' ';
    put(out, h.hi[d]);
    out += kAxes[d];
  }
  if (h.atom_types > 0 && h.type_mass) {
    out += "\nMasses\n\n";
    for (const auto& [type, mass] : *h.type_mass) {
      put(out, type);
      out += ' ';
      put(out, mass);
      out += '\n';
    }
  }
  if (h.coeffs)
    for (const auto& c : *h.coeffs) {
      out += "\n" + c.name + (c.style.empty() ? std::string() : " # " + c.style) + "\n\n";
      for (const auto& r : c.rows) out += r + "\n";
    }
}

void append_section(std::string& out, const std::string& name) {
  out += "\n";
  out += name;
  out += "\n\n";
}

void append_atom(std::string& out, const Style& style, long long id, long long molecule, int type, double charge,
                 const double* x, const Eigen::Vector3d& lo, const Eigen::Vector3d& hi) {
  put(out, id);
  out += ' ';
  if (style.molecule) {
    put(out, molecule);
    out += ' ';
  }
  put(out, type);
  if (style.charge) {
    out += ' ';
    put(out, charge);
  }
  std::array<int, 3> img{};
  for (int d = 0; d < 3; ++d) {
    const auto [w, m] = wrap_exact(x[d], lo[d], hi[d]);
    img[static_cast<size_t>(d)] = m;
    out += ' ';
    put(out, w);
  }
  for (int m : img) {
    out += ' ';
    put(out, m);
  }
  out += '\n';
}

void append_velocity(std::string& out, long long id, const double* v) {
  put(out, id);
  for (int d = 0; d < 3; ++d) {
    out += ' ';
    put(out, v[d]);
  }
  out += '\n';
}

void append_item(std::string& out, long long k, int type, std::initializer_list<long long> ids) {
  put(out, k);
  out += ' ';
  put(out, type);
  for (long long i : ids) {
    out += ' ';
    put(out, i);
  }
  out += '\n';
}

}  // namespace lammps_rows
}  // namespace stiffmd
