// The LAMMPS data-file writer (write_lammps_data, lammps_data.hpp).
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
  std::string t = title;
  std::replace(t.begin(), t.end(), '\n', ' ');
  std::replace(t.begin(), t.end(), '\r', ' ');
  out += t + "\n\n";
  put(out, static_cast<long long>(n));
  out += " atoms\n";
  if (has_bonds) {
    put(out, static_cast<long long>(s.bonds.size()));
    out += " bonds\n";
  }
  if (has_angles) {
    put(out, static_cast<long long>(s.angles.size()));
    out += " angles\n";
  }
  // Dihedral and improper lines only when there is something of the kind: files without them
  // stay as they were.
  const bool dihedral_lines = has_quads && ndt > 0, improper_lines = has_quads && nit > 0;
  if (dihedral_lines) {
    put(out, static_cast<long long>(s.dihedrals.size()));
    out += " dihedrals\n";
  }
  if (improper_lines) {
    put(out, static_cast<long long>(s.impropers.size()));
    out += " impropers\n";
  }
  put(out, ntypes);
  out += " atom types\n";
  if (has_bonds) {
    put(out, nbt);
    out += " bond types\n";
  }
  if (has_angles) {
    put(out, nat);
    out += " angle types\n";
  }
  if (dihedral_lines) {
    put(out, ndt);
    out += " dihedral types\n";
  }
  if (improper_lines) {
    put(out, nit);
    out += " improper types\n";
  }
  out += "\n";
  static constexpr const char* kAxes[] = {" xlo xhi\n", " ylo yhi\n", " zlo zhi\n"};
  for (int d = 0; d < 3; ++d) {
    put(out, s.lo[d]);
    out += ' ';
    put(out, s.hi[d]);
    out += kAxes[d];
  }
  if (ntypes > 0) {
    out += "\nMasses\n\n";
    for (const auto& [type, mass] : s.type_mass) {
      put(out, type);
      out += ' ';
      put(out, mass);
      out += '\n';
    }
  }
  for (const auto& c : s.coeffs) {
    out += "\n" + c.name + (c.style.empty() ? std::string() : " # " + c.style) + "\n\n";
    for (const auto& r : c.rows) out += r + "\n";
  }
  if (n > 0) {
    out += "\nAtoms # ";
    out += st->name;
    out += "\n\n";
    for (size_t k = 0; k < n; ++k) {
      const auto c = static_cast<Eigen::Index>(k);
      put(out, id_of(k));
      out += ' ';
      if (st->molecule) {
        put(out, s.molecule.empty() ? 0 : s.molecule[k]);
        out += ' ';
      }
      put(out, s.type[k]);
      if (st->charge) {
        out += ' ';
        put(out, s.charge.empty() ? 0.0 : s.charge[k]);
      }
      std::array<int, 3> img{};
      for (int d = 0; d < 3; ++d) {
        const auto [w, m] = wrap_exact(s.x(d, c), s.lo[d], s.hi[d]);
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
  }
  if (with_v && n > 0) {
    out += "\nVelocities\n\n";
    for (size_t k = 0; k < n; ++k) {
      put(out, id_of(k));
      for (int d = 0; d < 3; ++d) {
        out += ' ';
        put(out, s.v(d, static_cast<Eigen::Index>(k)));
      }
      out += '\n';
    }
  }
  if (!s.bonds.empty()) {
    out += "\nBonds\n\n";
    long long k = 0;
    for (const auto& b : s.bonds) {
      put(out, ++k);
      out += ' ';
      put(out, b.type);
      out += ' ';
      put(out, id_of(static_cast<size_t>(b.i)));
      out += ' ';
      put(out, id_of(static_cast<size_t>(b.j)));
      out += '\n';
    }
  }
  if (!s.angles.empty()) {
    out += "\nAngles\n\n";
    long long k = 0;
    for (const auto& a : s.angles) {
      put(out, ++k);
      out += ' ';
      put(out, a.type);
      for (int i : {a.i, a.j, a.k}) {
        out += ' ';
        put(out, id_of(static_cast<size_t>(i)));
      }
      out += '\n';
    }
  }

  for (auto [quads, section] :
       {std::pair{&s.dihedrals, "\nDihedrals\n\n"}, std::pair{&s.impropers, "\nImpropers\n\n"}}) {
    if (quads->empty()) continue;
    out += section;
    long long k = 0;
    for (const auto& q : *quads) {
      put(out, ++k);
      out += ' ';
      put(out, q.type);
      for (int i : {q.i, q.j, q.k, q.l}) {
        out += ' ';
        put(out, id_of(static_cast<size_t>(i)));
      }
      out += '\n';
    }
  }

  std::ofstream f(path, std::ios::binary | std::ios::trunc);
  if (!f) fail("cannot open the file for writing");
  f.write(out.data(), static_cast<std::streamsize>(out.size()));
  f.close();
  if (!f) fail("write failed (disk full?)");
}

}  // namespace stiffmd
