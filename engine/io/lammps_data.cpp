#include "engine/io/lammps_data.hpp"

#include <algorithm>
#include <array>
#include <bit>
#include <charconv>
#include <cmath>
#include <cstdint>
#include <filesystem>
#include <fstream>
#include <limits>
#include <numeric>
#include <set>
#include <sstream>
#include <tuple>
#include <unordered_set>

#include "core/errors.hpp"
#include "engine/io/lammps_data_format.hpp"

namespace stiffmd {

namespace {

using namespace lammps_format;
using detail::parse_double;
using detail::parse_long;
using detail::quote;
using detail::trim;

// One line with something on it besides a comment (blank and comment-only lines carry nothing in
// this format, and the title line is free text).
struct Line {
  int number = 0;            // 1-based
  std::string_view data;     // before '#', trimmed
  std::string_view comment;  // after '#', trimmed (the "Atoms # full" style hint lives here)
};

std::vector<Line> content_lines(std::string_view text, int& last_line) {
  std::vector<Line> lines;
  int number = 0;
  size_t pos = 0;
  while (pos < text.size()) {
    size_t end = text.find('\n', pos);
    if (end == std::string_view::npos) end = text.size();
    const std::string_view raw = text.substr(pos, end - pos);
    pos = end + 1;
    if (++number == 1) continue;  // title
    const size_t hash = raw.find('#');
    Line l;
    l.number = number;
    l.data = trim(raw.substr(0, hash));
    if (hash != std::string_view::npos) l.comment = trim(raw.substr(hash + 1));
    if (!l.data.empty()) lines.push_back(l);
  }
  last_line = number;
  return lines;
}

std::string join(const std::vector<std::string_view>& tok, size_t from) {
  std::string s;
  for (size_t k = from; k < tok.size(); ++k) {
    if (k > from) s += ' ';
    s += tok[k];
  }
  return s;
}

// Fewest bytes an entry of each kind occupies (every column at least one character plus a
// separator): bounds header counts by the file size before anything is allocated for them.
constexpr std::array<long long, kAtomTypes> kMinEntryBytes = {10, 8, 10, 12, 12};

struct SectionSpec {
  std::string_view name;
  Count count;
};
constexpr SectionSpec kSections[] = {
    {"Masses", kAtomTypes},
    {"Atoms", kAtoms},
    {"Velocities", kAtoms},
    {"Bonds", kBonds},
    {"Angles", kAngles},
    {"Dihedrals", kDihedrals},
    {"Impropers", kImpropers},
    {"Pair Coeffs", kAtomTypes},
    {"PairIJ Coeffs", kPairIJ},
    {"Bond Coeffs", kBondTypes},
    {"Angle Coeffs", kAngleTypes},
    {"Dihedral Coeffs", kDihedralTypes},
    {"Improper Coeffs", kImproperTypes},
    {"BondBond Coeffs", kAngleTypes},
    {"BondAngle Coeffs", kAngleTypes},
    {"MiddleBondTorsion Coeffs", kDihedralTypes},
    {"EndBondTorsion Coeffs", kDihedralTypes},
    {"AngleTorsion Coeffs", kDihedralTypes},
    {"AngleAngleTorsion Coeffs", kDihedralTypes},
    {"BondBond13 Coeffs", kDihedralTypes},
    {"AngleAngle Coeffs", kImproperTypes},
};

// LAMMPS styles whose Atoms columns differ from all of the above: a hint naming one must not be
// mistaken for a free comment, or its columns would be read under the wrong names.
constexpr std::string_view kOtherLammpsStyles[] = {
    "charge",     "hybrid", "sphere",     "ellipsoid", "dipole",     "body",   "line", "tri",
    "template",   "peri",   "electron",   "dpd",       "edpd",       "mdpd",   "tdpd", "spin",
    "wavepacket", "sph",    "bpm/sphere", "oxdna",     "dielectric", "amoeba", "rheo", "rheo/thermal"};

// Entry rows: one place that words every per-field error alike.
struct Row {
  const std::string& path;
  const Line& line;
  std::string_view section;
  std::string_view layout;
  const std::vector<std::string_view>& tok;

  [[noreturn]] void fail(const std::string& what) const {
    throw InputError(path + ": line " + std::to_string(line.number) + ": " + std::string(section) + ": " + what);
  }
  void expect_columns(size_t n) const {
    if (tok.size() != n)
      fail("expected " + std::to_string(n) + " columns '" + std::string(layout) + "', found " +
           std::to_string(tok.size()));
  }
  double real(size_t col, std::string_view name) const {
    double v = 0;
    if (!parse_double(tok[col], v))
      fail("column " + std::to_string(col + 1) + " (" + std::string(name) + ") is " + quote(tok[col]) +
           ", expected a finite number ('" + std::string(layout) + "')");
    return v;
  }
  long long integer(size_t col, std::string_view name, long long min, long long max,
                    const std::string& range_why = "") const {
    long long v = 0;
    if (!parse_long(tok[col], v))
      fail("column " + std::to_string(col + 1) + " (" + std::string(name) + ") is " + quote(tok[col]) +
           ", expected an integer ('" + std::string(layout) + "')");
    if (v < min || v > max)
      fail(std::string(name) + " " + std::to_string(v) + " is out of range " + std::to_string(min) + ".." +
           (max == std::numeric_limits<long long>::max() ? std::string() : std::to_string(max)) +
           (range_why.empty() ? "" : " (" + range_why + ")"));
    return v;
  }
};

class DataReader {
 public:
  DataReader(std::string path, std::string atom_style)
      : path_(std::move(path)), requested_style_(std::move(atom_style)) {}

  ImportedSystem read() {
    if (requested_style_ != "auto" && !find_style(requested_style_))
      throw InputError(path_ + ": atom_style " + quote(requested_style_) + " is not supported; expected auto, " +
                       std::string(kSupportedStyles));
    text_ = detail::read_text_file(path_);
    if (text_.empty())
      throw InputError(path_ + ": file is empty; expected a LAMMPS data file (title line, header, sections)");
    lines_ = content_lines(text_, last_line_);
    size_t i = read_header();
    read_sections(i);
    // The sections are parsed into the raw arrays: the text and its lines (1.7 bytes per byte of a
    // 10⁶-atom file) go before the system is assembled beside those arrays, so the peak is the
    // parse's, not the parse's and the assembly's together (docs/parallel.md, "The set-up by parts").
    std::vector<Line>().swap(lines_);
    std::string().swap(text_);
    return assemble();
  }

 private:
  [[noreturn]] void fail(int line, const std::string& what) const {
    throw InputError(path_ + ": line " + std::to_string(line) + ": " + what);
  }
  [[noreturn]] void fail(const std::string& what) const { throw InputError(path_ + ": " + what); }

  std::string declared(Count c) const {
    return std::to_string(count_[c]) + " " + std::string(kCountKeyword[c]) +
           (count_line_[c] ? " on line " + std::to_string(count_line_[c]) : "");
  }

  size_t read_header() {
    std::vector<std::string_view> tok;
    size_t i = 0;
    for (; i < lines_.size(); ++i) {
      const Line& l = lines_[i];
      detail::split_ws_into(l.data, tok);
      if (!starts_numeric(tok[0])) break;
      size_t nnum = 0;
      while (nnum < tok.size() && starts_numeric(tok[nnum])) ++nnum;
      const std::string kw = join(tok, nnum);
      header_keyword(l, tok, nnum, kw);
    }
    if (!count_line_[kAtoms])
      fail((i < lines_.size() ? lines_[i].number : last_line_),
           "header: no 'N atoms' line before the first section; expected a LAMMPS data file header");
    if (count_[kAtoms] > 0 && count_[kAtomTypes] == 0)
      fail(count_line_[kAtoms], "header: atoms are declared but no 'N atom types' line; expected at least 1 atom type");
    count_[kPairIJ] = count_[kAtomTypes] * (count_[kAtomTypes] + 1) / 2;
    return i;
  }

  void header_keyword(const Line& l, const std::vector<std::string_view>& tok, size_t nnum, const std::string& kw) {
    auto need_numbers = [&](size_t n) {
      if (nnum != n)
        fail(l.number, "header '" + kw + "': expected " + std::to_string(n) + " number" + (n > 1 ? "s" : "") +
                           " before the keyword, found " + std::to_string(nnum));
    };
    auto count_value = [&]() {
      need_numbers(1);
      long long v = 0;
      if (!parse_long(tok[0], v) || v < 0)
        fail(l.number, "header '" + kw + "': " + quote(tok[0]) + " is not a non-negative integer count");
      for (int c = kAtoms; c < kAtomTypes; ++c)
        if (kw == kCountKeyword[c] && v > static_cast<long long>(text_.size()) / kMinEntryBytes[c])
          fail(l.number, "header '" + kw + "': " + std::to_string(v) + " " + kw + " cannot fit in this file of " +
                             std::to_string(text_.size()) + " bytes; expected the number of entries in its section");
      if (v > std::numeric_limits<int>::max())
        fail(l.number, "header '" + kw + "': " + std::to_string(v) + " exceeds the supported " +
                           std::to_string(std::numeric_limits<int>::max()));
      return v;
    };
    for (int c = kAtoms; c < kPairIJ; ++c)
      if (kw == kCountKeyword[c]) {
        if (count_line_[c])
          fail(l.number, "header '" + kw + "': given twice (first on line " + std::to_string(count_line_[c]) + ")");
        count_[c] = count_value();
        count_line_[c] = l.number;
        return;
      }
    static constexpr std::string_view kAxes[] = {"xlo xhi", "ylo yhi", "zlo zhi"};
    for (int a = 0; a < 3; ++a)
      if (kw == kAxes[a]) {
        need_numbers(2);
        double lo = 0, hi = 0;
        if (!parse_double(tok[0], lo) || !parse_double(tok[1], hi))
          fail(l.number, "header '" + kw + "': expected two finite numbers, found " + quote(l.data));
        if (!(lo < hi)) fail(l.number, "header '" + kw + "': expected lo < hi, found " + quote(l.data));
        if (box_line_[a])
          fail(l.number, "header '" + kw + "': given twice (first on line " + std::to_string(box_line_[a]) + ")");
        lo_[a] = lo;
        hi_[a] = hi;
        box_line_[a] = l.number;
        return;
      }
    if (kw == "xy xz yz") {
      need_numbers(3);
      for (size_t k = 0; k < 3; ++k) {
        double t = 0;
        if (!parse_double(tok[k], t)) fail(l.number, "header 'xy xz yz': expected three finite numbers");
        // Zero tilts describe an orthorhombic box; anything else the engine's Box cannot hold.
        if (t != 0.0)
          fail(l.number,
               "header 'xy xz yz': tilted (triclinic) boxes are not supported; expected an "
               "orthorhombic box (tilt factors 0 or no 'xy xz yz' line)");
      }
      return;
    }
    if (kw == "avec" || kw == "bvec" || kw == "cvec" || kw == "abc origin")
      fail(l.number, "header '" + kw + "': general triclinic boxes are not supported; expected an orthorhombic box");
    if (kw == "extra bond per atom" || kw == "extra angle per atom" || kw == "extra dihedral per atom" ||
        kw == "extra improper per atom" || kw == "extra special per atom") {
      count_value();  // memory hints for LAMMPS itself
      return;
    }
    if (kw == "ellipsoids" || kw == "lines" || kw == "triangles" || kw == "bodies") {
      if (count_value() != 0) fail(l.number, "header '" + kw + "': extended particles are not supported; expected 0");
      return;
    }
    fail(l.number, "header: unknown keyword " + quote(kw) +
                       "; expected 'atoms', 'bonds', 'angles', 'dihedrals', 'impropers', '… types', "
                       "'xlo xhi', 'ylo yhi', 'zlo zhi'");
  }

  void read_sections(size_t i) {
    std::vector<std::string_view> tok;
    std::string_view previous;
    while (i < lines_.size()) {
      const Line& kl = lines_[i];
      detail::split_ws_into(kl.data, tok);
      if (starts_numeric(tok[0])) {
        if (previous.empty())
          fail(kl.number, "expected a section keyword (Masses, Atoms, Bonds, …), found " + quote(kl.data));
        fail(kl.number, std::string(previous) + ": more entries than the " + std::to_string(section_count_) +
                            " declared in the header; expected a section "
                            "keyword after them, found " +
                            quote(kl.data));
      }
      const std::string name = join(tok, 0);
      const SectionSpec* spec = nullptr;
      for (const SectionSpec& s : kSections)
        if (s.name == name) spec = &s;
      if (!spec)
        fail(kl.number, "unknown section " + quote(name) +
                            "; expected Masses, Atoms, Velocities, Bonds, Angles, Dihedrals, Impropers or a "
                            "'… Coeffs' section");
      for (const auto& [seen, at] : seen_sections_)
        if (seen == spec->name)
          fail(kl.number, std::string(spec->name) + ": section given twice (first on line " + std::to_string(at) + ")");
      seen_sections_.emplace_back(spec->name, kl.number);

      const long long n = count_[spec->count];
      if (n == 0) {
        const std::string what =
            spec->count == kPairIJ ? std::string("atom types") : std::string(kCountKeyword[spec->count]);
        fail(kl.number, std::string(spec->name) + ": section present, but the header declares no " + what +
                            "; expected a 'N " + what + "' header line");
      }
      const size_t first = i + 1;
      for (long long k = 0; k < n; ++k) {
        const size_t j = first + static_cast<size_t>(k);
        if (j >= lines_.size())
          fail(last_line_, std::string(spec->name) + ": file ends after " + std::to_string(k) + " of the " +
                               std::to_string(n) + " entries declared in the header; truncated file?");
        if (!starts_numeric(lines_[j].data))
          fail(lines_[j].number, std::string(spec->name) + ": only " + std::to_string(k) + " of the " +
                                     std::to_string(n) +
                                     " entries declared in the header; expected another entry, "
                                     "found " +
                                     quote(lines_[j].data));
      }
      section(*spec, kl, first, first + static_cast<size_t>(n));
      previous = spec->name;
      section_count_ = n;
      i = first + static_cast<size_t>(n);
    }
  }

  void section(const SectionSpec& spec, const Line& keyword, size_t b, size_t e) {
    if (spec.name == "Masses") return masses(b, e);
    if (spec.name == "Atoms") return atoms(keyword, b, e);
    if (spec.name == "Velocities") return velocities(b, e);
    if (spec.name == "Bonds") return bonds(b, e);
    if (spec.name == "Angles") return angles(b, e);
    if (spec.name == "Dihedrals")
      return tuples(b, e, "Dihedrals", "id type atom1 atom2 atom3 atom4", 4, kDihedralTypes, dihedrals_);
    if (spec.name == "Impropers")
      return tuples(b, e, "Impropers", "id type atom1 atom2 atom3 atom4", 4, kImproperTypes, impropers_);
    coeffs(spec, keyword, b, e);
  }

  std::string type_range(Count c) const { return "the header declares " + declared(c); }

  void masses(size_t b, size_t e) {
    masses_line_ = lines_[b - 1].number;
    std::vector<std::string_view> tok;
    const std::string why = type_range(kAtomTypes);
    for (size_t k = b; k < e; ++k) {
      detail::split_ws_into(lines_[k].data, tok);
      const Row r{path_, lines_[k], "Masses", "type mass", tok};
      r.expect_columns(2);
      const int t = static_cast<int>(r.integer(0, "atom type", 1, count_[kAtomTypes], why));
      const double m = r.real(1, "mass");
      if (!(m > 0)) r.fail("mass " + std::string(tok[1]) + " of atom type " + std::to_string(t) + " must be > 0");
      if (!sys_.type_mass.emplace(t, m).second) r.fail("atom type " + std::to_string(t) + " given twice");
    }
  }

  const Style& atoms_style(const Line& keyword, const Line& first, size_t ncols) {
    const auto fits = [&](const Style& s) { return ncols == s.columns || ncols == s.columns + 3; };
    const auto want = [](const Style& s) {
      return std::to_string(s.columns) + " or " + std::to_string(s.columns + 3) + " columns '" + std::string(s.layout) +
             " [ix iy iz]'";
    };
    const auto by_columns = [&]() -> const Style* {
      for (const Style& s : kStyles)
        if (fits(s)) return &s;
      return nullptr;
    };
    if (requested_style_ != "auto") {
      const Style& s = *find_style(requested_style_);
      if (!fits(s))
        fail(first.number,
             "Atoms: atom_style " + std::string(s.name) + " expects " + want(s) + ", found " + std::to_string(ncols));
      style_how_ = "as requested";
      return s;
    }
    const std::vector<std::string_view> hint = detail::split_ws(keyword.comment);
    if (!hint.empty()) {
      if (const Style* s = find_style(hint[0])) {
        if (!fits(*s)) {
          const Style* other = by_columns();
          fail(first.number,
               "Atoms: the '# " + std::string(s->name) + "' hint on line " + std::to_string(keyword.number) +
                   " expects " + want(*s) + ", found " + std::to_string(ncols) +
                   (other ? " (which would fit atom_style " + std::string(other->name) + ")" : std::string()) +
                   "; pass the atom style explicitly");
        }
        style_how_ = "from the hint on line " + std::to_string(keyword.number);
        return *s;
      }
      for (std::string_view other : kOtherLammpsStyles)
        if (hint[0] == other)
          fail(keyword.number, "Atoms: atom_style " + quote(other) + " (from the hint) is not supported; expected " +
                                   std::string(kSupportedStyles));
    }
    const Style* s = by_columns();
    if (!s)
      fail(first.number,
           "Atoms: cannot tell the atom style from " + std::to_string(ncols) +
               " columns: expected 5 or 8 (atomic), 6 or 9 (bond, angle, molecular) or 7 or 10 (full); add a "
               "'# full'-style hint after 'Atoms' or pass the atom style");
    style_how_ = "inferred from " + std::to_string(ncols) + " columns";
    return *s;
  }

  void atoms(const Line& keyword, size_t b, size_t e) {
    std::vector<std::string_view> tok;
    detail::split_ws_into(lines_[b].data, tok);
    const Style& st = atoms_style(keyword, lines_[b], tok.size());
    style_ = &st;
    images_ = tok.size() == st.columns + 3;
    const size_t ncols = tok.size();
    const std::string layout = std::string(st.layout) + (images_ ? " ix iy iz" : "");
    const std::string section = "Atoms (atom_style " + std::string(st.name) + ", " + style_how_ + ")";
    const size_t n = e - b;
    a_id_.reserve(n);
    a_line_.reserve(n);
    a_type_.reserve(n);
    a_mol_.reserve(n);
    if (st.charge) a_q_.reserve(n);
    a_x_.reserve(3 * n);
    if (images_) a_img_.reserve(3 * n);
    const size_t xcol = st.columns - 3;
    const std::string why = type_range(kAtomTypes);
    for (size_t k = b; k < e; ++k) {
      detail::split_ws_into(lines_[k].data, tok);
      const Row r{path_, lines_[k], section, layout, tok};
      if (tok.size() != ncols)
        r.fail("expected " + std::to_string(ncols) + " columns '" + layout + "' as on line " +
               std::to_string(lines_[b].number) + ", found " + std::to_string(tok.size()));
      a_line_.push_back(lines_[k].number);
      a_id_.push_back(r.integer(0, "atom id", 1, std::numeric_limits<long long>::max()));
      size_t c = 1;
      a_mol_.push_back(st.molecule ? static_cast<int>(r.integer(c++, "molecule id", 0, std::numeric_limits<int>::max()))
                                   : 0);
      a_type_.push_back(static_cast<int>(r.integer(c++, "atom type", 1, count_[kAtomTypes], why)));
      if (st.charge) a_q_.push_back(r.real(c++, "q"));
      static constexpr std::string_view kX[] = {"x", "y", "z"}, kI[] = {"ix", "iy", "iz"};
      for (size_t d = 0; d < 3; ++d) a_x_.push_back(r.real(xcol + d, kX[d]));
      // LAMMPS packs image flags into at most 21 bits per axis; the bound keeps x + n L finite.
      constexpr long long kImgMax = 1 << 20;
      if (images_)
        for (size_t d = 0; d < 3; ++d)
          a_img_.push_back(static_cast<int>(r.integer(xcol + 3 + d, kI[d], -kImgMax, kImgMax)));
    }
  }

  void velocities(size_t b, size_t e) {
    std::vector<std::string_view> tok;
    v_id_.reserve(e - b);
    v_line_.reserve(e - b);
    v_.reserve(3 * (e - b));
    for (size_t k = b; k < e; ++k) {
      detail::split_ws_into(lines_[k].data, tok);
      const Row r{path_, lines_[k], "Velocities", "id vx vy vz", tok};
      r.expect_columns(4);
      v_id_.push_back(r.integer(0, "atom id", 1, std::numeric_limits<long long>::max()));
      v_line_.push_back(lines_[k].number);
      v_.push_back(r.real(1, "vx"));
      v_.push_back(r.real(2, "vy"));
      v_.push_back(r.real(3, "vz"));
    }
  }

  // Bonds and angles keep the file's ids until the Atoms section has been sorted.
  struct Tuple {
    int type;
    int line;
    std::array<long long, 4> ids;
  };

  void tuples(size_t b, size_t e, std::string_view section, std::string_view layout, size_t natoms, Count types,
              std::vector<Tuple>& out) {
    std::vector<std::string_view> tok;
    out.reserve(e - b);
    const std::string why = type_range(types);
    static constexpr std::string_view kCol[] = {"atom1", "atom2", "atom3", "atom4"};
    for (size_t k = b; k < e; ++k) {
      detail::split_ws_into(lines_[k].data, tok);
      const Row r{path_, lines_[k], section, layout, tok};
      r.expect_columns(2 + natoms);
      r.integer(0, "id", 1, std::numeric_limits<long long>::max());
      Tuple t{};
      t.type = static_cast<int>(r.integer(1, "type", 1, count_[types], why));
      t.line = lines_[k].number;
      for (size_t a = 0; a < natoms; ++a) {
        t.ids[a] = r.integer(2 + a, kCol[a], 1, std::numeric_limits<long long>::max());
        for (size_t o = 0; o < a; ++o)
          if (t.ids[o] == t.ids[a])
            r.fail("atom id " + std::to_string(t.ids[a]) + " appears twice; expected " + std::to_string(natoms) +
                   " distinct atoms");
      }
      out.push_back(t);
    }
  }

  void bonds(size_t b, size_t e) { tuples(b, e, "Bonds", "id type atom1 atom2", 2, kBondTypes, bonds_); }
  void angles(size_t b, size_t e) { tuples(b, e, "Angles", "id type atom1 atom2 atom3", 3, kAngleTypes, angles_); }

  // A "… Coeffs" section: each row starts with its type (two for PairIJ Coeffs), in range and
  // given once; the rest is the style's coefficients, kept as text (LAMMPS's own check of them
  // needs the style, which the file does not always name).
  void coeffs(const SectionSpec& spec, const Line& keyword, size_t b, size_t e) {
    std::vector<std::string_view> tok;
    const Count types = spec.count == kPairIJ ? kAtomTypes : spec.count;
    const size_t ntype_cols = spec.count == kPairIJ ? 2 : 1;
    const std::string why = type_range(types);
    const std::string layout = ntype_cols == 2 ? "type1 type2 coefficients…" : "type coefficients…";
    ImportedSystem::CoeffSection sec{std::string(spec.name), std::string(keyword.comment), {}};
    std::set<std::pair<long long, long long>> seen;
    for (size_t k = b; k < e; ++k) {
      detail::split_ws_into(lines_[k].data, tok);
      const Row r{path_, lines_[k], spec.name, layout, tok};
      if (tok.size() < ntype_cols + 1) r.fail("expected '" + layout + "', found " + quote(lines_[k].data));
      const long long t1 = r.integer(0, "type", 1, count_[types], why);
      const long long t2 = ntype_cols == 2 ? r.integer(1, "type", t1, count_[types], why + ", type2 >= type1") : 0;
      if (!seen.insert({t1, t2}).second)
        r.fail("type " + std::to_string(t1) + (ntype_cols == 2 ? " " + std::to_string(t2) : std::string()) +
               " given twice; expected one row per type");
      sec.rows.emplace_back(lines_[k].data);
    }
    sys_.coeffs.push_back(std::move(sec));
  }

  int index_of(long long id) const {
    const auto it = std::lower_bound(sys_.id.begin(), sys_.id.end(), id);
    return (it != sys_.id.end() && *it == id) ? static_cast<int>(it - sys_.id.begin()) : -1;
  }

  void require_section(Count c, std::string_view name) const {
    if (count_[c] == 0) return;
    for (const auto& [seen, at] : seen_sections_)
      if (seen == name) return;
    fail("no " + std::string(name) + " section, but the header declares " + declared(c) + "; truncated file?");
  }

  ImportedSystem assemble() {
    require_section(kAtoms, "Atoms");
    require_section(kBonds, "Bonds");
    require_section(kAngles, "Angles");
    require_section(kDihedrals, "Dihedrals");
    require_section(kImpropers, "Impropers");
    const size_t n = a_id_.size();
    if (n > 0 && !masses_line_)
      fail("no Masses section: atom type " + std::to_string(a_type_[0]) + " (atom id " + std::to_string(a_id_[0]) +
           ", line " + std::to_string(a_line_[0]) + ") needs a mass; expected a Masses section (the header declares " +
           declared(kAtomTypes) + ")");

    std::vector<size_t> order(n);
    std::iota(order.begin(), order.end(), size_t{0});
    std::sort(order.begin(), order.end(), [&](size_t p, size_t q) { return a_id_[p] < a_id_[q]; });
    for (size_t k = 1; k < n; ++k)
      if (a_id_[order[k]] == a_id_[order[k - 1]]) {
        const size_t p = std::min(order[k], order[k - 1]), q = std::max(order[k], order[k - 1]);
        fail(a_line_[q], "Atoms: atom id " + std::to_string(a_id_[q]) + " given twice (first on line " +
                             std::to_string(a_line_[p]) + "); expected unique ids");
      }

    ImportedSystem& s = sys_;
    s.atom_style = style_ ? std::string(style_->name) : std::string();
    s.lo = lo_;
    s.hi = hi_;
    const Eigen::Vector3d L = hi_ - lo_;
    s.num_atom_types = static_cast<int>(count_[kAtomTypes]);
    s.num_bond_types = static_cast<int>(count_[kBondTypes]);
    s.num_angle_types = static_cast<int>(count_[kAngleTypes]);
    s.num_dihedral_types = static_cast<int>(count_[kDihedralTypes]);
    s.num_improper_types = static_cast<int>(count_[kImproperTypes]);
    s.x.resize(3, static_cast<Eigen::Index>(n));
    s.v = Eigen::Matrix3Xd::Zero(3, static_cast<Eigen::Index>(n));
    s.id.resize(n);
    s.type.resize(n);
    s.molecule.resize(n);
    if (style_ && style_->charge) s.charge.resize(n);
    s.image_flags = images_;
    for (size_t k = 0; k < n; ++k) {
      const size_t p = order[k];
      s.id[k] = static_cast<long>(a_id_[p]);
      s.type[k] = a_type_[p];
      s.molecule[k] = a_mol_[p];
      if (!s.charge.empty()) s.charge[k] = a_q_[p];
      for (int d = 0; d < 3; ++d) {
        const double w = a_x_[3 * p + static_cast<size_t>(d)];
        s.x(d, static_cast<Eigen::Index>(k)) = images_ ? unwrap(w, a_img_[3 * p + static_cast<size_t>(d)], L[d]) : w;
      }
    }

    std::vector<char> has_v(n, 0);
    for (size_t k = 0; k < v_id_.size(); ++k) {
      const int at = index_of(v_id_[k]);
      if (at < 0) fail(v_line_[k], "Velocities: atom id " + std::to_string(v_id_[k]) + " is not in the Atoms section");
      if (has_v[static_cast<size_t>(at)])
        fail(v_line_[k],
             "Velocities: atom id " + std::to_string(v_id_[k]) + " given twice; expected one line per atom");
      has_v[static_cast<size_t>(at)] = 1;
      for (int d = 0; d < 3; ++d) s.v(d, at) = v_[3 * k + static_cast<size_t>(d)];
    }

    const auto resolve = [&](const Tuple& t, size_t a, std::string_view section) {
      const int at = index_of(t.ids[a]);
      if (at < 0)
        fail(t.line, std::string(section) + ": atom id " + std::to_string(t.ids[a]) + " (column " +
                         std::to_string(3 + a) + ") is not in the Atoms section");
      return at;
    };
    s.bonds.reserve(bonds_.size());
    std::unordered_set<std::uint64_t> seen;
    seen.reserve(bonds_.size());
    std::vector<int> bond_line;
    for (const Tuple& t : bonds_) {
      const int i = resolve(t, 0, "Bonds"), j = resolve(t, 1, "Bonds");
      // The deck refuses duplicate bonds too: a doubled stiff bond is a doubled constraint.
      const auto key = (static_cast<std::uint64_t>(std::min(i, j)) << 32) | static_cast<std::uint32_t>(std::max(i, j));
      if (!seen.insert(key).second)
        fail(t.line, "Bonds: duplicate bond between atom ids " + std::to_string(t.ids[0]) + " and " +
                         std::to_string(t.ids[1]) + "; expected each pair once");
      s.bonds.push_back({t.type, i, j});
    }
    s.angles.reserve(angles_.size());
    for (const Tuple& t : angles_)
      s.angles.push_back({t.type, resolve(t, 0, "Angles"), resolve(t, 1, "Angles"), resolve(t, 2, "Angles")});
    for (auto [tuples, out, name] :
         {std::tuple{&dihedrals_, &s.dihedrals, "Dihedrals"}, std::tuple{&impropers_, &s.impropers, "Impropers"}}) {
      out->reserve(tuples->size());
      for (const Tuple& t : *tuples)
        out->push_back({t.type, resolve(t, 0, name), resolve(t, 1, name), resolve(t, 2, name), resolve(t, 3, name)});
    }
    return std::move(sys_);
  }

  std::string path_, requested_style_, text_;
  std::vector<Line> lines_;
  int last_line_ = 0;

  std::array<long long, kNumCounts> count_{};
  std::array<int, kNumCounts> count_line_{};
  // LAMMPS's default box when the header gives none.
  Eigen::Vector3d lo_ = Eigen::Vector3d::Constant(-0.5), hi_ = Eigen::Vector3d::Constant(0.5);
  std::array<int, 3> box_line_{};
  std::vector<std::pair<std::string_view, int>> seen_sections_;
  long long section_count_ = 0;
  int masses_line_ = 0;

  const Style* style_ = nullptr;
  std::string style_how_;
  bool images_ = false;
  std::vector<long long> a_id_;
  std::vector<int> a_line_, a_type_, a_mol_, a_img_;
  std::vector<double> a_q_, a_x_;
  std::vector<long long> v_id_;
  std::vector<int> v_line_;
  std::vector<double> v_;
  std::vector<Tuple> bonds_, angles_, dihedrals_, impropers_;

  ImportedSystem sys_;
};

}  // namespace

ImportedSystem read_lammps_data(const std::string& path, const std::string& atom_style) {
  return DataReader(path, atom_style).read();
}

}  // namespace stiffmd
