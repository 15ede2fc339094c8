#include "engine/io/lammps_data_parts.hpp"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <fstream>
#include <limits>
#include <memory>
#include <numeric>
#include <stdexcept>
#include <unordered_set>

#include "core/disjoint_sets.hpp"
#include "core/errors.hpp"
#include "engine/io/lammps_data_format.hpp"

namespace stiffmd {

namespace {

using namespace lammps_format;
using detail::parse_double;
using detail::parse_long;
using detail::quote;
using detail::trim;

// The file's lines with something before '#' (the title line skipped), one at a time; a place in
// the file can be remembered and gone back to.
class Lines {
 public:
  explicit Lines(const std::string& path)
      : path_((detail::check_lammps_data_file(path), path)), in_(path, std::ios::binary) {
    if (!in_) throw InputError(path + ": cannot open file (missing or unreadable)");
    std::string title;
    std::getline(in_, title);
    number_ = 1;
  }
  struct Mark {
    std::streamoff offset;
    int number;
  };
  Mark mark() { return {static_cast<std::streamoff>(in_.tellg()), number_}; }
  void go(const Mark& m) {
    in_.clear();
    in_.seekg(m.offset);
    number_ = m.number;
  }
  // The next line with data; false at the end of the file.
  bool next() {
    while (std::getline(in_, raw_)) {
      ++number_;
      const size_t hash = raw_.find('#');
      data_ = trim(std::string_view(raw_).substr(0, hash));
      comment_ = hash == std::string::npos ? std::string_view() : trim(std::string_view(raw_).substr(hash + 1));
      if (!data_.empty()) return true;
    }
    return false;
  }
  std::string_view data() const { return data_; }
  std::string_view comment() const { return comment_; }
  int number() const { return number_; }
  [[noreturn]] void fail(const std::string& what) const {
    throw InputError(path_ + ": line " + std::to_string(number_) + ": " + what);
  }

 private:
  std::string path_;
  std::ifstream in_;
  std::string raw_;
  std::string_view data_, comment_;
  int number_ = 0;
};

// The bonded sections: their count, their atoms per entry.
struct Bonded {
  std::string_view name;
  Count count, types;
  int atoms;
};
constexpr Bonded kBonded[] = {{"Bonds", kBonds, kBondTypes, 2},
                              {"Angles", kAngles, kAngleTypes, 3},
                              {"Dihedrals", kDihedrals, kDihedralTypes, 4},
                              {"Impropers", kImpropers, kImproperTypes, 4}};

class PartReader {
 public:
  PartReader(const std::string& path, const std::string& style, const KeepAnchor& keep, bool header_only = false)
      : path_(path), requested_(style), keep_(keep), lines_(path), header_only_(header_only) {}
  PartReader(const std::string& path, const std::string& style, const KeepBlock& block)
      : path_(path), requested_(style), keep_(no_anchor_), lines_(path), block_(block), by_block_(true) {
    if (block.parts < 1 || block.part < 0 || block.part >= block.parts)
      throw std::invalid_argument("read_lammps_data_part: block " + std::to_string(block.part) + " of " +
                                  std::to_string(block.parts));
  }

  ImportedBox box() {
    header();
    return {lo_, hi_};
  }

  // The structure pass alone, counting (read_lammps_data_description).
  ImportedDescription describe(const std::vector<double>* type_charge) {
    if (requested_ != "auto" && !find_style(requested_))
      throw InputError(path_ + ": atom_style " + quote(requested_) + " is not supported; expected auto, " +
                       std::string(kSupportedStyles));
    describing_ = true;
    type_charge_ = type_charge;
    structure();
    ImportedDescription d;
    d.lo = lo_, d.hi = hi_;
    d.type_mass = std::move(sys_.type_mass);
    d.coeffs = std::move(sys_.coeffs);
    d.num_atoms = num_atoms_;
    d.num_molecule_ids = static_cast<int>(molecule_ids_.size());
    // Atom types by their first atom's index (ids increase with the index).
    d.atoms_of_type = std::move(atoms_of_type_);
    d.first_atom_of_type.assign(d.atoms_of_type.size(), -1);
    for (size_t t = 0; t < d.atoms_of_type.size(); ++t)
      if (d.atoms_of_type[t] > 0) {
        d.first_atom_of_type[t] = index_of(first_id_of_type_[t]);
        d.types_used.atom.push_back(static_cast<int>(t));
      }
    std::sort(d.types_used.atom.begin(), d.types_used.atom.end(), [&](int a, int b) {
      return d.first_atom_of_type[static_cast<size_t>(a)] < d.first_atom_of_type[static_cast<size_t>(b)];
    });
    d.types_used.bond = std::move(types_in_order_[0]);
    d.types_used.angle = std::move(types_in_order_[1]);
    d.types_used.dihedral = std::move(types_in_order_[2]);
    d.types_used.improper = std::move(types_in_order_[3]);
    d.items_of_type = std::move(items_of_type_);
    d.charge_column = style_->charge;
    d.charge_sum = charge_sum_, d.charge_scale = charge_scale_, d.first_charge = first_charge_;
    d.first_charged = first_charged_id_ > 0 ? index_of(first_charged_id_) : -1;
    return d;
  }

  ImportedPart read() {
    if (requested_ != "auto" && !find_style(requested_))
      throw InputError(path_ + ": atom_style " + quote(requested_) + " is not supported; expected auto, " +
                       std::string(kSupportedStyles));
    structure();
    anchors();
    return part();
  }

 private:
  [[noreturn]] void fail(const std::string& what) const { throw InputError(path_ + ": " + what); }

  long long integer(std::string_view s, std::string_view name, long long min, long long max) {
    long long v = 0;
    if (!parse_long(s, v))
      lines_.fail(std::string(section_) + ": " + std::string(name) + " is " + quote(s) + ", expected an integer");
    if (v < min || v > max)
      lines_.fail(std::string(section_) + ": " + std::string(name) + " " + std::to_string(v) + " is out of range " +
                  std::to_string(min) + ".." +
                  (max == std::numeric_limits<long long>::max() ? "" : std::to_string(max)));
    return v;
  }
  double real(std::string_view s, std::string_view name) {
    double v = 0;
    if (!parse_double(s, v))
      lines_.fail(std::string(section_) + ": " + std::string(name) + " is " + quote(s) + ", expected a finite number");
    return v;
  }
  // The next entry of the current section, split into tok_.
  void entry(long long k, long long n) {
    if (!lines_.next())
      fail("line " + std::to_string(lines_.number()) + ": " + std::string(section_) + ": file ends after " +
           std::to_string(k) + " of the " + std::to_string(n) + " entries declared in the header; truncated file?");
    if (!starts_numeric(lines_.data()))
      lines_.fail(std::string(section_) + ": only " + std::to_string(k) + " of the " + std::to_string(n) +
                  " entries declared in the header; expected another entry, found " + quote(lines_.data()));
    detail::split_ws_into(lines_.data(), tok_);
  }
  void expect_columns(size_t n) {
    if (tok_.size() != n)
      lines_.fail(std::string(section_) + ": expected " + std::to_string(n) + " columns, found " +
                  std::to_string(tok_.size()));
  }

  // The index (0 … N − 1, by increasing id) of an atom id, −1 when the Atoms section has none.
  int index_of(long long id) const {
    if (dense_) return id >= 1 && id <= num_atoms_ ? static_cast<int>(id - 1) : -1;
    const auto it = std::lower_bound(ids_.begin(), ids_.end(), id);
    return it != ids_.end() && *it == id ? static_cast<int>(it - ids_.begin()) : -1;
  }

  void header() {
    while (lines_.next()) {
      detail::split_ws_into(lines_.data(), tok_);
      if (!starts_numeric(tok_[0])) return;
      size_t nnum = 0;
      while (nnum < tok_.size() && starts_numeric(tok_[nnum])) ++nnum;
      std::string kw;
      for (size_t k = nnum; k < tok_.size(); ++k) {
        if (k > nnum) kw += ' ';
        kw += tok_[k];
      }
      bool known = false;
      for (int c = 0; c < kPairIJ; ++c)
        if (kw == kCountKeyword[c]) {
          long long v = 0;
          if (nnum != 1 || !parse_long(tok_[0], v) || v < 0 || v > std::numeric_limits<int>::max())
            lines_.fail("header '" + kw + "': expected one non-negative integer count");
          count_[c] = v, known = true;
        }
      static constexpr std::string_view kAxes[] = {"xlo xhi", "ylo yhi", "zlo zhi"};
      for (int a = 0; a < 3; ++a)
        if (kw == kAxes[a]) {
          if (nnum != 2 || !parse_double(tok_[0], lo_[a]) || !parse_double(tok_[1], hi_[a]) || !(lo_[a] < hi_[a]))
            lines_.fail("header '" + kw + "': expected two finite numbers lo < hi");
          known = true;
        }
      if (kw == "xy xz yz") {
        double t = 0;
        for (size_t k = 0; k < std::min<size_t>(nnum, 3); ++k)
          if (!parse_double(tok_[k], t) || t != 0.0)
            lines_.fail("header 'xy xz yz': tilted (triclinic) boxes are not supported; expected an orthorhombic box");
        known = true;
      }
      if (kw.starts_with("extra ") && kw.ends_with(" per atom")) known = true;
      if (!known) lines_.fail("header: unknown keyword " + quote(kw) + " for the data file read by parts");
    }
    if (!header_only_) fail("no section after the header; expected Masses and Atoms");
  }

  // Pass 1: the header, the masses, the coefficients, the atom ids and style, the molecules (a
  // union–find over the bonded terms) and where each section starts.
  void structure() {
    header();
    if (count_[kAtoms] == 0) fail("the header declares no atoms; expected 'N atoms'");
    num_atoms_ = static_cast<int>(count_[kAtoms]);
    bool have_atoms = false, have_masses = false;
    do {
      detail::split_ws_into(lines_.data(), tok_);
      std::string name;
      for (size_t k = 0; k < tok_.size(); ++k) {
        if (k) name += ' ';
        name += tok_[k];
      }
      section_name_ = name;
      section_ = section_name_;
      const std::string comment(lines_.comment());
      const Lines::Mark at = lines_.mark();
      if (name == "Masses") {
        have_masses = true;
        for (long long k = 0; k < count_[kAtomTypes]; ++k) {
          entry(k, count_[kAtomTypes]);
          expect_columns(2);
          const int t = static_cast<int>(integer(tok_[0], "atom type", 1, count_[kAtomTypes]));
          const double m = real(tok_[1], "mass");
          if (!(m > 0)) lines_.fail("Masses: mass of atom type " + std::to_string(t) + " must be > 0");
          if (!sys_.type_mass.emplace(t, m).second)
            lines_.fail("Masses: atom type " + std::to_string(t) + " given twice");
        }
      } else if (name == "Atoms") {
        have_atoms = true;
        atoms_at_ = at;
        atoms_comment_ = comment;
        atom_ids();
      } else if (name == "Velocities") {
        if (!have_atoms) lines_.fail("Velocities: before the Atoms section; expected Atoms first");
        velocities_at_ = at, have_velocities_ = true;
        skip(count_[kAtoms]);
      } else if (const Bonded* b = bonded(name)) {
        if (!have_atoms) lines_.fail(std::string(b->name) + ": before the Atoms section; expected Atoms first");
        bonded_at_[b - kBonded] = at, have_bonded_[b - kBonded] = true;
        join(*b);
      } else if (name.ends_with(" Coeffs")) {
        coeffs(name, comment);
      } else {
        lines_.fail(
            "unknown section " + quote(name) +
            "; expected Masses, Atoms, Velocities, Bonds, Angles, Dihedrals, Impropers or a '… Coeffs' section");
      }
    } while (lines_.next());
    if (!have_atoms) fail("no Atoms section, but the header declares " + std::to_string(num_atoms_) + " atoms");
    if (!have_masses) fail("no Masses section; expected the atom types' masses");
    // Without image flags a molecule's positions are wrapped and its anchor is not its centre of
    // mass: the whole import makes molecules whole along their bonds, which needs the molecule.
    // A block of molecules needs no anchor: its molecules are made whole after the read, as the
    // whole import makes them.
    if (!by_block_ && !describing_ && !images_ &&
        (count_[kBonds] || count_[kAngles] || count_[kDihedrals] || count_[kImpropers]))
      fail(
          "Atoms: no image flags (ix iy iz); a file with bonded terms is read by parts only with them, as "
          "write_lammps_data and LAMMPS's write_data write it");
    for (int b = 0; b < 4; ++b)
      if (count_[kBonded[b].count] > 0 && !have_bonded_[b])
        fail("no " + std::string(kBonded[b].name) + " section, but the header declares " +
             std::to_string(count_[kBonded[b].count]) + " " + std::string(kCountKeyword[kBonded[b].count]));
  }

  static const Bonded* bonded(std::string_view name) {
    for (const Bonded& b : kBonded)
      if (b.name == name) return &b;
    return nullptr;
  }

  void skip(long long n) {
    for (long long k = 0; k < n; ++k) entry(k, n);
  }

  const Style& atoms_style(size_t ncols) {
    const auto fits = [&](const Style& s) { return ncols == s.columns || ncols == s.columns + 3; };
    const Style* s = nullptr;
    if (requested_ != "auto") {
      s = find_style(requested_);
    } else {
      const std::vector<std::string_view> hint = detail::split_ws(atoms_comment_);
      if (!hint.empty()) s = find_style(hint[0]);
      if (!s)
        for (const Style& c : kStyles)
          if (fits(c) && !s) s = &c;
    }
    if (!s || !fits(*s))
      lines_.fail("Atoms: cannot read " + std::to_string(ncols) + " columns as atom_style " +
                  (s ? std::string(s->name) : std::string("atomic, bond or full")) + "; pass the atom style");
    return *s;
  }

  // The Atoms section's ids (dense_ when they are 1 … N in order: no table then) and style; the
  // union–find over the atoms.
  void atom_ids() {
    const long long n = count_[kAtoms];
    dense_ = true;
    for (long long k = 0; k < n; ++k) {
      entry(k, n);
      if (k == 0) {
        style_ = &atoms_style(tok_.size());
        ncols_ = tok_.size();
        images_ = ncols_ == style_->columns + 3;
      }
      if (tok_.size() != ncols_)
        lines_.fail("Atoms: expected " + std::to_string(ncols_) + " columns as on the section's first line, found " +
                    std::to_string(tok_.size()));
      const long long id = integer(tok_[0], "atom id", 1, std::numeric_limits<long long>::max());
      // Every atom's molecule id and type: the dense molecule ids and the types an import names
      // need the whole file's, and each rank then refuses the same file.
      size_t c = 1;
      if (style_->molecule) {
        const int mol = static_cast<int>(integer(tok_[c++], "molecule id", 0, std::numeric_limits<int>::max()));
        if (molecule_ids_.empty() || molecule_ids_.back() != mol) molecule_ids_.push_back(mol);
      }
      const auto type = static_cast<size_t>(integer(tok_[c], "atom type", 1, count_[kAtomTypes]));
      if (atom_type_used_.size() <= type) atom_type_used_.resize(type + 1, 0);
      atom_type_used_[type] = 1;
      if (describing_) count_atom(id, type, c);
      if (dense_ && id != k + 1) {
        dense_ = false;
        ids_.resize(static_cast<size_t>(k));
        std::iota(ids_.begin(), ids_.end(), 1LL);
      }
      if (!dense_) ids_.push_back(id);
    }
    if (!dense_) {
      file_order_sorted_ = std::is_sorted(ids_.begin(), ids_.end());
      std::sort(ids_.begin(), ids_.end());
      if (const auto d = std::adjacent_find(ids_.begin(), ids_.end()); d != ids_.end())
        fail("Atoms: atom id " + std::to_string(*d) + " given twice; expected unique ids");
    }
    if (!style_->molecule) molecule_ids_.push_back(0);
    std::sort(molecule_ids_.begin(), molecule_ids_.end());
    molecule_ids_.erase(std::unique(molecule_ids_.begin(), molecule_ids_.end()), molecule_ids_.end());
    if (!describing_) sets_ = std::make_unique<DisjointSets>(num_atoms_);
  }

  // The description's numbers of one atom (its Atoms line in tok_, its type in column `c`): its
  // type's count and first id, and its charge (the q column, or its type's).
  void count_atom(long long id, size_t type, size_t c) {
    if (atoms_of_type_.size() <= type) atoms_of_type_.resize(type + 1, 0), first_id_of_type_.resize(type + 1, 0);
    if (atoms_of_type_[type]++ == 0 || id < first_id_of_type_[type]) first_id_of_type_[type] = id;
    double q = 0.0;
    if (style_->charge)
      q = real(tok_[c + 1], "q");
    else if (type_charge_ && type < type_charge_->size())
      q = (*type_charge_)[type];
    else
      return;
    charge_sum_ += q;
    if (q == 0.0) return;
    charge_scale_ = std::max(charge_scale_, std::abs(q));
    if (first_charged_id_ == 0 || id < first_charged_id_) first_charged_id_ = id, first_charge_ = q;
  }

  void join(const Bonded& b) {
    const long long n = count_[b.count];
    const auto kind = static_cast<size_t>(&b - kBonded);
    std::vector<char> used(static_cast<size_t>(count_[b.types]) + 1, 0);
    for (long long k = 0; k < n; ++k) {
      entry(k, n);
      expect_columns(2 + static_cast<size_t>(b.atoms));
      const auto type = static_cast<size_t>(integer(tok_[1], "type", 1, count_[b.types]));
      if (!used[type]) used[type] = 1, types_in_order_[kind].push_back(static_cast<int>(type));
      if (describing_) {
        auto& counts = items_of_type_[kind];
        if (counts.size() <= type) counts.resize(type + 1, 0);
        ++counts[type];
      }
      int first = -1;
      for (int a = 0; a < b.atoms; ++a) {
        const int at = resolve(tok_[2 + a], a);
        if (!sets_) continue;
        first < 0 ? void(first = at) : sets_->join(first, at);
      }
    }
  }

  int resolve(std::string_view token, int a) {
    const long long id = integer(token, "atom" + std::to_string(a + 1), 1, std::numeric_limits<long long>::max());
    const int at = index_of(id);
    if (at < 0)
      lines_.fail(std::string(section_) + ": atom id " + std::to_string(id) + " (column " + std::to_string(3 + a) +
                  ") is not in the Atoms section");
    return at;
  }

  void coeffs(const std::string& name, const std::string& comment) {
    long long n = count_[kAtomTypes];
    if (name == "PairIJ Coeffs")
      n = n * (n + 1) / 2;
    else if (name == "Bond Coeffs")
      n = count_[kBondTypes];
    else if (name == "Angle Coeffs" || name == "BondBond Coeffs" || name == "BondAngle Coeffs")
      n = count_[kAngleTypes];
    else if (name == "Dihedral Coeffs" || name == "MiddleBondTorsion Coeffs" || name == "EndBondTorsion Coeffs" ||
             name == "AngleTorsion Coeffs" || name == "AngleAngleTorsion Coeffs" || name == "BondBond13 Coeffs")
      n = count_[kDihedralTypes];
    else if (name == "Improper Coeffs" || name == "AngleAngle Coeffs")
      n = count_[kImproperTypes];
    else if (name != "Pair Coeffs")
      lines_.fail("unknown section " + quote(name));
    ImportedSystem::CoeffSection sec{name, comment, {}};
    for (long long k = 0; k < n; ++k) {
      entry(k, n);
      sec.rows.emplace_back(lines_.data());
    }
    sys_.coeffs.push_back(std::move(sec));
  }

  // The atom's type, charge and unwrapped position from the Atoms line in tok_.
  struct Atom {
    long long id;
    int mol, type;
    double q;
    Eigen::Vector3d x;
  };
  Atom atom() {
    if (tok_.size() != ncols_)
      lines_.fail("Atoms: expected " + std::to_string(ncols_) + " columns, found " + std::to_string(tok_.size()));
    Atom a{};
    a.id = integer(tok_[0], "atom id", 1, std::numeric_limits<long long>::max());
    size_t c = 1;
    a.mol =
        style_->molecule ? static_cast<int>(integer(tok_[c++], "molecule id", 0, std::numeric_limits<int>::max())) : 0;
    a.type = static_cast<int>(integer(tok_[c++], "atom type", 1, count_[kAtomTypes]));
    a.q = style_->charge ? real(tok_[c++], "q") : 0.0;
    const size_t xcol = style_->columns - 3;
    const Eigen::Vector3d L = hi_ - lo_;
    for (int d = 0; d < 3; ++d) {
      const double w = real(tok_[xcol + d], "coordinate");
      constexpr long long kImgMax = 1 << 20;
      a.x[d] =
          images_ ? unwrap(w, static_cast<int>(integer(tok_[xcol + 3 + d], "image flag", -kImgMax, kImgMax)), L[d]) : w;
    }
    return a;
  }

  // Pass 2: each molecule's anchor from the Atoms section, and whether this part keeps it.
  void anchors() {
    // The molecules numbered by their least atom (DisjointSets' roots), each atom's molecule in
    // place of the union–find.
    molecule_.resize(num_atoms_);
    int molecules = 0;
    for (int i = 0; i < num_atoms_; ++i) {
      const int r = sets_->root(i);
      molecule_[i] = r == i ? molecules++ : molecule_[r];
    }
    sets_.reset();
    num_molecules_ = molecules;
    if (by_block_) {
      // whole_block's numbers: molecules [M·part/parts, M·(part + 1)/parts).
      const std::int64_t first = std::int64_t{molecules} * block_.part / block_.parts,
                         end = std::int64_t{molecules} * (block_.part + 1) / block_.parts;
      keep_molecule_.assign(molecules, 0);
      for (std::int64_t m = first; m < end; ++m) keep_molecule_[static_cast<size_t>(m)] = 1;
      return;
    }
    std::vector<Eigen::Vector3d> sum(molecules, Eigen::Vector3d::Zero());
    std::vector<double> total(molecules, 0.0);
    lines_.go(atoms_at_);
    section_ = "Atoms";
    for (long long k = 0; k < count_[kAtoms]; ++k) {
      entry(k, count_[kAtoms]);
      const Atom a = atom();
      const auto m = sys_.type_mass.find(a.type);
      if (m == sys_.type_mass.end())
        lines_.fail("Atoms: atom type " + std::to_string(a.type) + " has no mass in the Masses section");
      // The decomposition's mass: the inverse of the inverse mass a scene keeps.
      const double mass = 1.0 / (1.0 / m->second);
      const int mol = molecule_[index_of(a.id)];
      sum[mol] += mass * a.x;
      total[mol] += mass;
    }
    keep_molecule_.assign(molecules, 0);
    for (int m = 0; m < molecules; ++m) keep_molecule_[m] = keep_(Eigen::Vector3d(sum[m] / total[m])) ? 1 : 0;
  }

  // Pass 3: the kept atoms, their velocities and the bonded terms among them.
  ImportedPart part() {
    ImportedPart out;
    ImportedSystem& s = sys_;
    std::vector<Atom> kept;
    std::vector<int> global;
    lines_.go(atoms_at_);
    section_ = "Atoms";
    for (long long k = 0; k < count_[kAtoms]; ++k) {
      entry(k, count_[kAtoms]);
      long long id = 0;
      parse_long(tok_[0], id);
      const int g = index_of(id);
      if (!keep_molecule_[molecule_[g]]) continue;
      kept.push_back(atom());
      global.push_back(g);
    }
    std::vector<size_t> order(kept.size());
    std::iota(order.begin(), order.end(), size_t{0});
    if (!file_order_sorted_)
      std::sort(order.begin(), order.end(), [&](size_t a, size_t b) { return global[a] < global[b]; });
    const auto n = static_cast<Eigen::Index>(kept.size());
    s.x.resize(3, n);
    s.v = Eigen::Matrix3Xd::Zero(3, n);
    s.id.resize(kept.size());
    s.type.resize(kept.size());
    s.molecule.resize(kept.size());
    if (style_->charge) s.charge.resize(kept.size());
    out.global.resize(kept.size());
    out.molecule_rank.resize(kept.size());
    for (size_t k = 0; k < kept.size(); ++k) {
      const Atom& a = kept[order[k]];
      s.x.col(static_cast<Eigen::Index>(k)) = a.x;
      s.id[k] = static_cast<long>(a.id);
      s.type[k] = a.type;
      s.molecule[k] = a.mol;
      if (style_->charge) s.charge[k] = a.q;
      out.global[k] = global[order[k]];
      out.molecule_rank[k] =
          static_cast<int>(std::lower_bound(molecule_ids_.begin(), molecule_ids_.end(), a.mol) - molecule_ids_.begin());
    }
    const auto local = [&](int g) {
      const auto it = std::lower_bound(out.global.begin(), out.global.end(), g);
      return it != out.global.end() && *it == g ? static_cast<int>(it - out.global.begin()) : -1;
    };
    if (have_velocities_) {
      lines_.go(velocities_at_);
      section_ = "Velocities";
      std::vector<char> seen(kept.size(), 0);
      for (long long k = 0; k < count_[kAtoms]; ++k) {
        entry(k, count_[kAtoms]);
        expect_columns(4);
        const long long id = integer(tok_[0], "atom id", 1, std::numeric_limits<long long>::max());
        const int g = index_of(id);
        if (g < 0) lines_.fail("Velocities: atom id " + std::to_string(id) + " is not in the Atoms section");
        const int at = keep_molecule_[molecule_[g]] ? local(g) : -1;
        if (at < 0) continue;
        if (seen[at])
          lines_.fail("Velocities: atom id " + std::to_string(id) + " given twice; expected one line per atom");
        seen[at] = 1;
        for (int d = 0; d < 3; ++d) s.v(d, at) = real(tok_[1 + d], "velocity");
      }
    }
    std::unordered_set<std::uint64_t> bond_seen;
    std::vector<std::int64_t>* const places[] = {&out.bond_place, &out.angle_place, &out.dihedral_place,
                                                 &out.improper_place};
    for (int b = 0; b < 4; ++b) {
      if (!have_bonded_[b]) continue;
      const Bonded& spec = kBonded[b];
      lines_.go(bonded_at_[b]);
      section_ = spec.name;
      for (long long k = 0; k < count_[spec.count]; ++k) {
        entry(k, count_[spec.count]);
        const int g0 = resolve(tok_[2], 0);
        if (!keep_molecule_[molecule_[g0]]) continue;
        const int type = static_cast<int>(integer(tok_[1], "type", 1, count_[spec.types]));
        std::array<int, 4> at{};
        for (int a = 0; a < spec.atoms; ++a) at[a] = local(resolve(tok_[2 + a], a));
        places[b]->push_back(k);
        if (b == 0) {
          const auto key = (static_cast<std::uint64_t>(std::min(at[0], at[1])) << 32) |
                           static_cast<std::uint32_t>(std::max(at[0], at[1]));
          if (!bond_seen.insert(key).second)
            lines_.fail("Bonds: duplicate bond between atom ids " + std::string(tok_[2]) + " and " +
                        std::string(tok_[3]) + "; expected each pair once");
          s.bonds.push_back({type, at[0], at[1]});
        } else if (b == 1) {
          s.angles.push_back({type, at[0], at[1], at[2]});
        } else {
          (b == 2 ? s.dihedrals : s.impropers).push_back({type, at[0], at[1], at[2], at[3]});
        }
      }
    }
    s.lo = lo_, s.hi = hi_;
    s.image_flags = images_;
    s.atom_style = std::string(style_->name);
    s.num_atom_types = static_cast<int>(count_[kAtomTypes]);
    s.num_bond_types = static_cast<int>(count_[kBondTypes]);
    s.num_angle_types = static_cast<int>(count_[kAngleTypes]);
    s.num_dihedral_types = static_cast<int>(count_[kDihedralTypes]);
    s.num_improper_types = static_cast<int>(count_[kImproperTypes]);
    for (size_t t = 0; t < atom_type_used_.size(); ++t)
      if (atom_type_used_[t]) out.types_used.atom.push_back(static_cast<int>(t));
    out.types_used.bond = std::move(types_in_order_[0]);
    out.types_used.angle = std::move(types_in_order_[1]);
    out.types_used.dihedral = std::move(types_in_order_[2]);
    out.types_used.improper = std::move(types_in_order_[3]);
    out.system = std::move(s);
    out.num_atoms = num_atoms_;
    out.num_molecules = num_molecules_;
    return out;
  }

  const KeepAnchor no_anchor_;
  std::string path_, requested_;
  const KeepAnchor& keep_;
  Lines lines_;
  std::vector<std::string_view> tok_;
  std::string section_name_;
  std::string_view section_;
  std::array<long long, kNumCounts> count_{};
  // LAMMPS's default box when the header gives none.
  Eigen::Vector3d lo_ = Eigen::Vector3d::Constant(-0.5), hi_ = Eigen::Vector3d::Constant(0.5);
  ImportedSystem sys_;
  const Style* style_ = nullptr;
  size_t ncols_ = 0;
  bool images_ = false;
  std::string atoms_comment_;
  Lines::Mark atoms_at_{}, velocities_at_{};
  std::array<Lines::Mark, 4> bonded_at_{};
  std::array<bool, 4> have_bonded_{};
  bool have_velocities_ = false;
  int num_atoms_ = 0, num_molecules_ = 0;
  bool header_only_ = false;
  KeepBlock block_;
  bool by_block_ = false;
  bool dense_ = true, file_order_sorted_ = true;
  std::vector<int> molecule_ids_;                   // the file's distinct molecule ids, increasing (pass 1)
  std::vector<char> atom_type_used_;                // per atom type number: some atom has it
  std::array<std::vector<int>, 4> types_in_order_;  // per bonded section: its types by first entry
  std::vector<long long> ids_;                      // sorted, when not dense_
  std::unique_ptr<DisjointSets> sets_;              // pass 1
  std::vector<int> molecule_;                       // per atom index, from pass 2 on
  std::vector<char> keep_molecule_;
  // The description's numbers (describe): per atom type its atoms and least id, per bonded type
  // its items, the charges' sum, largest magnitude and first charged atom (by id).
  bool describing_ = false;
  const std::vector<double>* type_charge_ = nullptr;
  std::vector<std::int64_t> atoms_of_type_;
  std::vector<long long> first_id_of_type_;
  std::array<std::vector<std::int64_t>, 4> items_of_type_;
  double charge_sum_ = 0.0, charge_scale_ = 0.0, first_charge_ = 0.0;
  long long first_charged_id_ = 0;
};

}  // namespace

ImportedBox read_lammps_data_box(const std::string& path) {
  const KeepAnchor none;
  return PartReader(path, "auto", none, true).box();
}

ImportedDescription read_lammps_data_description(const std::string& path, const std::string& atom_style,
                                                 const std::vector<double>* type_charge) {
  const KeepAnchor none;
  return PartReader(path, atom_style, none).describe(type_charge);
}

ImportedPart read_lammps_data_part(const std::string& path, const std::string& atom_style, const KeepAnchor& keep) {
  return PartReader(path, atom_style, keep).read();
}

ImportedPart read_lammps_data_part(const std::string& path, const std::string& atom_style, const KeepBlock& block) {
  return PartReader(path, atom_style, block).read();
}

}  // namespace stiffmd
