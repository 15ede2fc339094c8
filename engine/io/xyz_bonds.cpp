#include "engine/io/xyz_bonds.hpp"

#include <algorithm>
#include <cctype>
#include <cstdint>
#include <limits>
#include <unordered_map>
#include <unordered_set>

#include "core/errors.hpp"

namespace stiffmd {

namespace {

using detail::parse_double;
using detail::parse_long;
using detail::quote;
using detail::split_ws;

// Lines of a text with their 1-based numbers; '\r' of CRLF files dropped.
class LineCursor {
 public:
  explicit LineCursor(std::string_view text) : text_(text) {}
  bool next(std::string_view& line) {
    if (pos_ >= text_.size()) return false;
    size_t end = text_.find('\n', pos_);
    if (end == std::string_view::npos) end = text_.size();
    line = text_.substr(pos_, end - pos_);
    if (!line.empty() && line.back() == '\r') line.remove_suffix(1);
    pos_ = end + 1;
    ++number_;
    return true;
  }
  int number() const { return number_; }

 private:
  std::string_view text_;
  size_t pos_ = 0;
  int number_ = 0;
};

bool iequals(std::string_view a, std::string_view b) {
  return a.size() == b.size() && std::equal(a.begin(), a.end(), b.begin(), [](char p, char q) {
           return std::tolower(static_cast<unsigned char>(p)) == std::tolower(static_cast<unsigned char>(q));
         });
}

// The key=value pairs of an extended-XYZ comment line; values may be "double quoted". A plain
// comment is free text, so an unbalanced quote just runs to the end of the line: if it hid a key
// that matters, that key's own parse reports it.
std::vector<std::pair<std::string_view, std::string_view>> key_values(std::string_view s) {
  std::vector<std::pair<std::string_view, std::string_view>> kv;
  size_t k = 0;
  const auto space = [](char c) { return c == ' ' || c == '\t'; };
  while (k < s.size()) {
    while (k < s.size() && space(s[k])) ++k;
    if (k >= s.size()) break;
    const size_t kb = k;
    while (k < s.size() && !space(s[k]) && s[k] != '=') ++k;
    const std::string_view key = s.substr(kb, k - kb);
    std::string_view value;
    if (k < s.size() && s[k] == '=') {
      ++k;
      if (k < s.size() && s[k] == '"') {
        const size_t close = std::min(s.find('"', k + 1), s.size());
        value = s.substr(k + 1, close - k - 1);
        k = close + 1;
      } else {
        const size_t vb = k;
        while (k < s.size() && !space(s[k])) ++k;
        value = s.substr(vb, k - vb);
      }
    }
    kv.emplace_back(key, value);
  }
  return kv;
}

struct Columns {
  size_t total = 4;
  size_t species = 0;  // column of the species
  size_t pos = 1;      // first of three
  long velo = -1;      // first of three, or -1
};

Columns parse_properties(std::string_view spec, const std::string& where) {
  std::vector<std::string_view> parts;
  size_t b = 0;
  while (true) {
    const size_t c = spec.find(':', b);
    parts.push_back(spec.substr(b, c == std::string_view::npos ? std::string_view::npos : c - b));
    if (c == std::string_view::npos) break;
    b = c + 1;
  }
  const std::string hint = "; expected name:type:count triples like species:S:1:pos:R:3";
  if (parts.size() % 3 != 0)
    throw InputError(where + ": Properties=" + quote(spec) + " is not a list of triples" + hint);
  Columns cols;
  cols.total = 0;
  long species = -1, pos = -1;
  for (size_t p = 0; p < parts.size(); p += 3) {
    const std::string_view name = parts[p], type = parts[p + 1];
    long long count = 0;
    if (name.empty() || (type != "S" && type != "R" && type != "I" && type != "L") ||
        !parse_long(parts[p + 2], count) || count < 1 || count > 1000)
      throw InputError(where + ": Properties: " +
                       quote(std::string(name) + ":" + std::string(type) + ":" + std::string(parts[p + 2])) +
                       " is not a valid property (type S, R, I or L; count 1..1000)" + hint);
    const auto at = static_cast<long>(cols.total);
    const auto require = [&](std::string_view t, long long c) {
      if (type != t || count != c)
        throw InputError(where + ": Properties: " + std::string(name) + " is " + std::string(type) + ":" +
                         std::to_string(count) + ", expected " + std::string(t) + ":" + std::to_string(c));
    };
    if (name == "species") {
      require("S", 1);
      species = at;
    } else if (name == "pos") {
      require("R", 3);
      pos = at;
    } else if (name == "velo") {
      require("R", 3);
      cols.velo = at;
    }
    cols.total += static_cast<size_t>(count);
  }
  if (pos < 0) throw InputError(where + ": Properties has no pos:R:3; expected the positions' columns");
  // Without a species column every atom is of one type; column 0 then stands in (its value only
  // names the type, and a single constant name would be the same).
  cols.species = species < 0 ? std::numeric_limits<size_t>::max() : static_cast<size_t>(species);
  cols.pos = static_cast<size_t>(pos);
  return cols;
}

}  // namespace

ImportedSystem read_xyz_with_bonds(const std::string& xyz_path, const std::string& bonds_path) {
  const std::string text = detail::read_text_file(xyz_path);
  const auto fail = [&](int line, const std::string& what) {
    throw InputError(xyz_path + ": line " + std::to_string(line) + ": " + what);
  };
  LineCursor cur(text);
  std::string_view line;
  if (!cur.next(line) || split_ws(line).empty()) fail(1, "expected the atom count, found an empty line or file");
  long long count = 0;
  {
    const auto tok = split_ws(line);
    if (tok.size() != 1 || !parse_long(tok[0], count) || count < 0)
      fail(1, "expected the atom count (a non-negative integer), found " + quote(line));
  }
  // Each atom line holds at least "A 0 0 0\n"; a larger count cannot be this file's, and must not
  // size an allocation.
  if (count > static_cast<long long>(text.size() / 8) || count > std::numeric_limits<int>::max())
    fail(1, "atom count " + std::to_string(count) + " cannot fit in this file of " + std::to_string(text.size()) +
                " bytes; expected the number of atom lines that follow");
  const auto n = static_cast<size_t>(count);
  if (!cur.next(line))
    fail(2, "file ends before the comment line; expected line 2 and " + std::to_string(n) + " atom lines");

  ImportedSystem s;
  Columns cols;
  bool extended = false;
  const std::string where2 = xyz_path + ": line 2";
  for (const auto& [key, value] : key_values(line)) {
    if (iequals(key, "Properties")) {
      cols = parse_properties(value, where2);
      extended = true;
    } else if (iequals(key, "Lattice")) {
      const auto tok = split_ws(value);
      double m[9] = {};
      bool ok = tok.size() == 9;
      for (size_t k = 0; ok && k < 9; ++k) ok = parse_double(tok[k], m[k]);
      if (!ok) fail(2, "Lattice=" + quote(value) + ": expected 9 finite numbers (three cell vectors)");
      for (int a = 0; a < 3; ++a)
        for (int b = 0; b < 3; ++b)
          if (a != b && m[3 * a + b] != 0.0)
            fail(2, "Lattice: tilted cells are not supported; expected a diagonal (orthorhombic) lattice");
      for (int a = 0; a < 3; ++a) {
        if (!(m[4 * a] > 0))
          fail(2, "Lattice: cell vector " + std::to_string(a + 1) + " has length <= 0; expected > 0");
        s.hi[a] = m[4 * a];  // shifted by the origin below
      }
    } else if (iequals(key, "Origin")) {
      const auto tok = split_ws(value);
      bool ok = tok.size() == 3;
      for (size_t k = 0; ok && k < 3; ++k) ok = parse_double(tok[k], s.lo[static_cast<Eigen::Index>(k)]);
      if (!ok) fail(2, "Origin=" + quote(value) + ": expected 3 finite numbers");
    }
  }
  s.hi += s.lo;
  if (s.hi == s.lo) s.hi = s.lo = Eigen::Vector3d::Zero();  // an Origin without a Lattice is no box

  const std::string layout = extended ? "the " + std::to_string(cols.total) + " columns of Properties on line 2"
                                      : std::string("4 columns 'species x y z'");
  s.x.resize(3, static_cast<Eigen::Index>(n));
  s.v = Eigen::Matrix3Xd::Zero(3, static_cast<Eigen::Index>(n));
  std::vector<std::string_view> species(n);
  static constexpr const char* kAxis[] = {"x", "y", "z"};
  for (size_t k = 0; k < n; ++k) {
    if (!cur.next(line))
      fail(cur.number(), "file ends after " + std::to_string(k) + " of the " + std::to_string(n) +
                             " atom lines declared on line 1; truncated file?");
    const auto tok = split_ws(line);
    if (tok.size() != cols.total)
      fail(cur.number(), "expected " + layout + ", found " + std::to_string(tok.size()) + " columns" +
                             (extended ? "" : " (for more columns use extended XYZ with Properties=)"));
    const auto c = static_cast<Eigen::Index>(k);
    species[k] = cols.species < tok.size() ? tok[cols.species] : std::string_view("X");
    for (size_t d = 0; d < 3; ++d)
      if (!parse_double(tok[cols.pos + d], s.x(static_cast<Eigen::Index>(d), c)))
        fail(cur.number(), std::string(kAxis[d]) + " is " + quote(tok[cols.pos + d]) + "; expected a finite number");
    if (cols.velo >= 0)
      for (size_t d = 0; d < 3; ++d)
        if (!parse_double(tok[static_cast<size_t>(cols.velo) + d], s.v(static_cast<Eigen::Index>(d), c)))
          fail(cur.number(), "velo " + std::string(kAxis[d]) + " is " + quote(tok[static_cast<size_t>(cols.velo) + d]) +
                                 "; expected a finite number");
  }

  s.type.resize(n);
  s.molecule.assign(n, 0);
  s.id.resize(n);
  for (size_t k = 0; k < n; ++k) s.id[k] = static_cast<long>(k + 1);
  const bool numeric = std::all_of(species.begin(), species.end(), [](std::string_view sp) {
    long long t = 0;
    return parse_long(sp, t) && t >= 1 && t <= std::numeric_limits<int>::max();
  });
  if (numeric) {
    for (size_t k = 0; k < n; ++k) {
      long long t = 0;
      parse_long(species[k], t);
      s.type[k] = static_cast<int>(t);
      s.num_atom_types = std::max(s.num_atom_types, s.type[k]);
    }
  } else {
    std::unordered_map<std::string_view, int> index;
    for (size_t k = 0; k < n; ++k) {
      const auto [it, fresh] = index.emplace(species[k], static_cast<int>(index.size()) + 1);
      if (fresh) s.type_names.emplace_back(species[k]);
      s.type[k] = it->second;
    }
    s.num_atom_types = static_cast<int>(s.type_names.size());
  }

  const std::string btext = detail::read_text_file(bonds_path);
  LineCursor bc(btext);
  std::unordered_set<std::uint64_t> seen;
  while (bc.next(line)) {
    const auto bfail = [&](const std::string& what) {
      throw InputError(bonds_path + ": line " + std::to_string(bc.number()) + ": bond: " + what);
    };
    const auto tok = split_ws(line.substr(0, line.find('#')));
    if (tok.empty()) continue;
    if (tok.size() > 3) bfail("expected 'i j [type]', found " + std::to_string(tok.size()) + " columns");
    if (tok.size() < 2) bfail("expected 'i j [type]' (two 0-based atom indices), found " + quote(line));
    long long ij[2] = {}, type = 1;
    for (size_t a = 0; a < 2; ++a) {
      if (!parse_long(tok[a], ij[a])) bfail(quote(tok[a]) + " is not an integer; expected a 0-based atom index");
      if (ij[a] < 0 || ij[a] >= count)
        bfail("atom index " + std::to_string(ij[a]) + " is out of range 0.." + std::to_string(count - 1) + " (" +
              xyz_path + " has " + std::to_string(count) + " atoms; indices are 0-based)");
    }
    if (tok.size() == 3 && (!parse_long(tok[2], type) || type < 1 || type > std::numeric_limits<int>::max()))
      bfail("type " + quote(tok[2]) + " is not an integer >= 1");
    if (ij[0] == ij[1]) bfail("atom " + std::to_string(ij[0]) + " is bonded to itself; expected two distinct atoms");
    const auto lo = static_cast<std::uint64_t>(std::min(ij[0], ij[1])),
               hi = static_cast<std::uint64_t>(std::max(ij[0], ij[1]));
    if (!seen.insert((lo << 32) | hi).second)
      bfail("duplicate bond between atoms " + std::to_string(lo) + " and " + std::to_string(hi) +
            "; expected each pair once");
    s.bonds.push_back({static_cast<int>(type), static_cast<int>(ij[0]), static_cast<int>(ij[1])});
    s.num_bond_types = std::max(s.num_bond_types, static_cast<int>(type));
  }
  return s;
}

}  // namespace stiffmd
