#include "engine/lammps_data.hpp"

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
#include <sstream>
#include <unordered_set>

#include "engine/errors.hpp"

namespace stiffmd {

namespace detail {

std::string read_text_file(const std::string& path) {
  std::error_code ec;
  const auto status = std::filesystem::status(path, ec);
  if (std::filesystem::is_directory(status)) throw InputError(path + ": is a directory, expected a file");
  // A device or FIFO (/dev/zero, a pipe) could be read forever: only regular files are read.
  if (std::filesystem::exists(status) && !std::filesystem::is_regular_file(status))
    throw InputError(path + ": is not a regular file (a device or pipe?), expected a file");
#ifdef FUZZING_BUILD_MODE_UNSAFE_FOR_PRODUCTION
  // A fuzzing build reads small files only, so that a deck naming a big one stays fast.
  if (const auto size = std::filesystem::file_size(path, ec); !ec && size > (256u << 10))
    throw InputError(path + ": larger than a fuzzing build reads");
#endif
  std::ifstream in(path, std::ios::binary);
  if (!in) throw InputError(path + ": cannot open file (missing or unreadable)");
  std::ostringstream buf;
  buf << in.rdbuf();
  if (in.bad()) throw InputError(path + ": read error");
  std::string text = std::move(buf).str();
  // The trajectory writer produces .gz files; say so rather than report binary garbage on line 1.
  if (text.size() >= 2 && static_cast<unsigned char>(text[0]) == 0x1f && static_cast<unsigned char>(text[1]) == 0x8b)
    throw InputError(path + ": is gzip-compressed; decompress it first (gunzip)");
  return text;
}

// from_chars rejects a leading '+', which Fortran- and printf("%+g")-style writers emit.
static std::string_view drop_plus(std::string_view s) {
  if (s.size() >= 2 && s[0] == '+' && s[1] != '-' && s[1] != '+') s.remove_prefix(1);
  return s;
}

bool parse_double(std::string_view s, double& out) {
  s = drop_plus(s);
  if (s.empty()) return false;
  const auto [p, ec] = std::from_chars(s.data(), s.data() + s.size(), out);
  return ec == std::errc() && p == s.data() + s.size() && std::isfinite(out);
}

bool parse_long(std::string_view s, long long& out) {
  s = drop_plus(s);
  if (s.empty()) return false;
  const auto [p, ec] = std::from_chars(s.data(), s.data() + s.size(), out);
  return ec == std::errc() && p == s.data() + s.size();
}

std::string quote(std::string_view s) {
  constexpr size_t kMax = 40;
  std::string q = "'";
  for (size_t k = 0; k < s.size() && k < kMax; ++k) {
    const auto c = static_cast<unsigned char>(s[k]);
    q += (c >= 0x20 && c < 0x7f) ? static_cast<char>(c) : '?';
  }
  if (s.size() > kMax) q += "...";
  return q + "'";
}

static bool is_space(char c) {
  return c == ' ' || c == '\t' || c == '\r' || c == '\v' || c == '\f';
}

static void split_ws_into(std::string_view s, std::vector<std::string_view>& out) {
  out.clear();
  size_t k = 0;
  while (k < s.size()) {
    while (k < s.size() && is_space(s[k])) ++k;
    const size_t b = k;
    while (k < s.size() && !is_space(s[k])) ++k;
    if (k > b) out.push_back(s.substr(b, k - b));
  }
}

std::vector<std::string_view> split_ws(std::string_view s) {
  std::vector<std::string_view> out;
  split_ws_into(s, out);
  return out;
}

}  // namespace detail

namespace {

using detail::parse_double;
using detail::parse_long;
using detail::quote;

std::string_view trim(std::string_view s) {
  while (!s.empty() && detail::is_space(s.front())) s.remove_prefix(1);
  while (!s.empty() && detail::is_space(s.back())) s.remove_suffix(1);
  return s;
}

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

// Keyword lines start with a letter; header and entry lines with a number.
bool starts_numeric(std::string_view s) {
  if (s.empty()) return false;
  size_t k = (s[0] == '-' || s[0] == '+') ? 1 : 0;
  if (k < s.size() && s[k] == '.') ++k;
  return k < s.size() && s[k] >= '0' && s[k] <= '9';
}

std::string join(const std::vector<std::string_view>& tok, size_t from) {
  std::string s;
  for (size_t k = from; k < tok.size(); ++k) {
    if (k > from) s += ' ';
    s += tok[k];
  }
  return s;
}

enum Count {
  kAtoms,
  kBonds,
  kAngles,
  kDihedrals,
  kImpropers,
  kAtomTypes,
  kBondTypes,
  kAngleTypes,
  kDihedralTypes,
  kImproperTypes,
  kPairIJ,
  kNumCounts
};
constexpr std::array<std::string_view, kPairIJ> kCountKeyword = {
    "atoms",      "bonds",      "angles",      "dihedrals",      "impropers",
    "atom types", "bond types", "angle types", "dihedral types", "improper types"};

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

struct Style {
  std::string_view name;
  size_t columns;           // without image flags
  std::string_view layout;  // for messages
  bool molecule, charge;
};
constexpr Style kStyles[] = {
    {"atomic", 5, "id type x y z", false, false},   {"bond", 6, "id mol type x y z", true, false},
    {"angle", 6, "id mol type x y z", true, false}, {"molecular", 6, "id mol type x y z", true, false},
    {"full", 7, "id mol type q x y z", true, true},
};
// LAMMPS styles whose Atoms columns differ from all of the above: a hint naming one must not be
// mistaken for a free comment, or its columns would be read under the wrong names.
constexpr std::string_view kOtherLammpsStyles[] = {
    "charge",     "hybrid", "sphere",     "ellipsoid", "dipole",     "body",   "line", "tri",
    "template",   "peri",   "electron",   "dpd",       "edpd",       "mdpd",   "tdpd", "spin",
    "wavepacket", "sph",    "bpm/sphere", "oxdna",     "dielectric", "amoeba", "rheo", "rheo/thermal"};

const Style* find_style(std::string_view name) {
  for (const Style& s : kStyles)
    if (s.name == name) return &s;
  return nullptr;
}

constexpr std::string_view kSupportedStyles = "atomic, bond, angle, molecular or full";

// x = w + n L, exactly as the writer checks it; fma rounds once whatever the compiler contracts.
// n = 0 returns w untouched so that -0.0 survives.
double unwrap(double w, int n, double L) {
  return n == 0 ? w : std::fma(static_cast<double>(n), L, w);
}

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
    if (spec.name == "Dihedrals" || spec.name == "Impropers") return skip_quads(spec, b, e);
    skip_coeffs(spec, b, e);
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
    std::array<long long, 3> ids;
  };

  void tuples(size_t b, size_t e, std::string_view section, std::string_view layout, size_t natoms, Count types,
              std::vector<Tuple>& out) {
    std::vector<std::string_view> tok;
    out.reserve(e - b);
    const std::string why = type_range(types);
    static constexpr std::string_view kCol[] = {"atom1", "atom2", "atom3"};
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

  void skip_quads(const SectionSpec& spec, size_t b, size_t e) {
    const Count types = spec.name == "Dihedrals" ? kDihedralTypes : kImproperTypes;
    std::vector<std::string_view> tok;
    const std::string why = type_range(types);
    for (size_t k = b; k < e; ++k) {
      detail::split_ws_into(lines_[k].data, tok);
      const Row r{path_, lines_[k], spec.name, "id type atom1 atom2 atom3 atom4", tok};
      r.expect_columns(6);
      r.integer(1, "type", 1, count_[types], why);
      for (size_t c = 2; c < 6; ++c) r.integer(c, "atom id", 1, std::numeric_limits<long long>::max());
    }
  }

  void skip_coeffs(const SectionSpec& spec, size_t b, size_t e) {
    std::vector<std::string_view> tok;
    const long long ntypes = spec.count == kPairIJ ? count_[kAtomTypes] : count_[spec.count];
    for (size_t k = b; k < e; ++k) {
      detail::split_ws_into(lines_[k].data, tok);
      const Row r{path_, lines_[k], spec.name, "type coefficients…", tok};
      r.integer(0, "type", 1, ntypes);
    }
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
  std::vector<Tuple> bonds_, angles_;

  ImportedSystem sys_;
};

// Output helpers: shortest text that reads back as the same double (to_chars' guarantee).
void put(std::string& out, double v) {
  char buf[32];
  const auto r = std::to_chars(buf, buf + sizeof buf, v);
  out.append(buf, r.ptr);
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

ImportedSystem read_lammps_data(const std::string& path, const std::string& atom_style) {
  return DataReader(path, atom_style).read();
}

void write_lammps_data(const std::string& path, const ImportedSystem& s, const std::string& atom_style,
                       const std::string& title) {
  const auto fail = [&](const std::string& what) { throw InputError(path + ": cannot write LAMMPS data: " + what); };
  const Style* st = find_style(atom_style);
  if (!st) fail("atom_style " + quote(atom_style) + " is not supported; expected " + std::string(kSupportedStyles));
  const bool has_bonds = st->molecule, has_angles = st->molecule && st->name != "bond";
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

  std::ofstream f(path, std::ios::binary | std::ios::trunc);
  if (!f) fail("cannot open the file for writing");
  f.write(out.data(), static_cast<std::streamsize>(out.size()));
  f.close();
  if (!f) fail("write failed (disk full?)");
}

}  // namespace stiffmd
