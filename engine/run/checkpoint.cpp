#include "engine/run/checkpoint.hpp"

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>
#include <zlib.h>

#include <algorithm>
#include <array>
#include <cerrno>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <limits>
#include <memory>
#include <span>
#include <sstream>
#include <system_error>

#include "core/errors.hpp"
#include "engine/domain/part_molecules.hpp"
#include "engine/scene/scene.hpp"
#include "engine/scene/stage_deck.hpp"
#include "forcefields/charmm_terms.hpp"
#include "forcefields/parameter_record.hpp"
#include "forcefields/particle_selection.hpp"
#include "forcefields/particle_subset.hpp"
#include "forcefields/stiff_harmonic_bond.hpp"
#include "forcefields/type_claim.hpp"
#include "integrators/methods.hpp"

namespace stiffmd {
namespace {

constexpr char kMagic[8] = {'S', 'T', 'F', 'M', 'D', 'C', 'K', 'P'};
constexpr char kMagicVersion1[8] = {'S', 'T', 'F', 'M', 'D', 'C', 'K', '1'};  // stiffmd before format versions
constexpr std::uint32_t kByteOrderMark = 0x01020304;
constexpr std::size_t kHeader = 40;   // magic … fingerprint: fixed offsets, see checkpoint.hpp
constexpr std::size_t kCrcFrom = 12;  // the crc32 covers bytes 12 … end

std::uint32_t crc32_of(std::uint32_t crc, const char* p, std::size_t n) {
  while (n > 0) {  // zlib takes uInt lengths
    const uInt k = static_cast<uInt>(std::min<std::size_t>(n, 1u << 30));
    crc = static_cast<std::uint32_t>(::crc32(crc, reinterpret_cast<const Bytef*>(p), k));
    p += k;
    n -= k;
  }
  return crc;
}

// A host-byte-order binary image; checkpoints are for restarting on a machine of the same byte
// order and double format (checked when read), not for archiving (the trajectory formats are).
//
// One piece of the image: consecutive bytes from `offset` on, written through a 64 KiB buffer
// (the whole image is never held in memory: a checkpoint of a large system would otherwise double
// the run's peak memory at its end), its crc32 computed as it goes.
struct Piece {
  std::uint64_t offset = 0, length = 0;
  std::uint32_t crc = 0;
};

class Writer {
 public:
  Writer(int fd, std::uint64_t offset) : fd_(fd) {
    piece_.offset = offset;
    buf_.reserve(kBuffer);
  }
  template <class T>
  void put(const T& v) {
    append(reinterpret_cast<const char*>(&v), sizeof(T));
  }
  void put(const std::string& s) {
    put<std::uint64_t>(s.size());
    append(s.data(), s.size());
  }
  void put(const double* d, size_t n) {  // a block: its count, then its values
    put<std::uint64_t>(n);
    put_values(d, n);
  }
  void put_values(const double* d, size_t n) { append(reinterpret_cast<const char*>(d), n * sizeof(double)); }
  // Everything put, written: the piece.
  Piece done() {
    flush();
    return piece_;
  }

 private:
  static constexpr size_t kBuffer = 1 << 16;
  void flush() {
    piece_.crc = crc32_of(piece_.crc, buf_.data(), buf_.size());
    size_t done = 0;
    while (done < buf_.size()) {
      const ssize_t k = ::pwrite(fd_, buf_.data() + done, buf_.size() - done,
                                 static_cast<off_t>(piece_.offset + piece_.length + done));
      if (k < 0) {
        if (errno == EINTR) continue;
        throw std::system_error(errno, std::generic_category(), "write");
      }
      done += static_cast<size_t>(k);
    }
    piece_.length += buf_.size();
    buf_.clear();
  }
  void append(const char* p, size_t n) {
    while (n > 0) {
      const size_t k = std::min(n, kBuffer - buf_.size());
      buf_.insert(buf_.end(), p, p + k);
      p += k;
      n -= k;
      if (buf_.size() == kBuffer) flush();
    }
  }
  int fd_;
  std::vector<char> buf_;
  Piece piece_;
};

// The integrator's words as runs: spans of words, or a carried column (3 N words) by index.
struct Run {
  std::span<const double> words;
  int column = -1;
};

// Where the sections of the image start (checkpoint.hpp), from what every process knows: N, the
// method's and the stage's names, the integrator's runs. x, v, inv_mass, integrator: the offset
// of the block's count word; column: of each carried column's first word; tail: of the thermo
// block, from which rank 0 writes the rest.
struct Layout {
  std::uint64_t x = 0, v = 0, inv_mass = 0, integrator = 0, integrator_words = 0, tail = 0;
  std::vector<std::uint64_t> column;
};

Layout layout_of(std::uint64_t n, const Checkpoint& c, std::span<const Run> runs) {
  Layout l;
  // particle count, step, t, h; the method (length + bytes); the stage (number; length + bytes)
  l.x = kHeader + 4 * 8 + 8 + c.method.size() + 8 + 8 + c.stage_name.size();
  l.v = l.x + 8 + 24 * n;
  l.inv_mass = l.v + 8 + 24 * n;
  l.integrator = l.inv_mass + 8 + 8 * n;
  std::uint64_t at = l.integrator + 8;
  for (const Run& r : runs) {
    if (r.column >= 0) {
      if (l.column.size() <= static_cast<size_t>(r.column)) l.column.resize(static_cast<size_t>(r.column) + 1, 0);
      l.column[static_cast<size_t>(r.column)] = at;
      l.integrator_words += 3 * n;
      at += 24 * n;
    } else {
      l.integrator_words += r.words.size();
      at += 8 * r.words.size();
    }
  }
  l.tail = at;
  return l;
}

// This process's pieces of the image (but the header): its block of every per-particle array,
// and on rank 0 everything between them. Throws std::system_error on a failed write.
std::vector<Piece> write_pieces(int fd, bool root, std::uint64_t n, std::int64_t step, double t, ParticleBlock b,
                                const double* x, const double* v, const double* inv_mass,
                                const std::vector<const double*>& columns, std::span<const Run> runs,
                                const Checkpoint& c) {
  const Layout l = layout_of(n, c, runs);
  std::vector<Piece> pieces;
  auto rows = [&](std::uint64_t at, const double* values, int per_particle) {
    if (b.count == 0 || !values) return;  // none: written by rounds (write_rounds)
    Writer w(fd, at + 8 * static_cast<std::uint64_t>(per_particle * b.first));
    w.put_values(values, static_cast<size_t>(per_particle * b.count));
    pieces.push_back(w.done());
  };
  rows(l.x + 8, x, 3);
  rows(l.v + 8, v, 3);
  rows(l.inv_mass + 8, inv_mass, 1);
  for (size_t k = 0; k < l.column.size(); ++k) rows(l.column[k], columns.empty() ? nullptr : columns.at(k), 3);
  if (!root) return pieces;

  auto count_word = [&](std::uint64_t at, std::uint64_t words) {
    Writer w(fd, at);
    w.put<std::uint64_t>(words);
    pieces.push_back(w.done());
  };
  Writer head(fd, kHeader);
  head.put<std::int64_t>(static_cast<std::int64_t>(n));
  head.put<std::int64_t>(step);
  head.put<double>(t);
  head.put<double>(c.h);
  head.put(c.method);
  head.put<std::int64_t>(c.stage);
  head.put(c.stage_name);
  head.put<std::uint64_t>(3 * n);
  pieces.push_back(head.done());
  count_word(l.v, 3 * n);
  count_word(l.inv_mass, n);
  count_word(l.integrator, l.integrator_words);
  std::uint64_t at = l.integrator + 8;
  for (const Run& r : runs) {
    if (r.column >= 0) {
      at += 24 * n;
    } else if (!r.words.empty()) {
      Writer w(fd, at);
      w.put_values(r.words.data(), r.words.size());
      pieces.push_back(w.done());
      at += 8 * r.words.size();
    }
  }
  Writer tail(fd, l.tail);
  for (const std::vector<double>* block : {&c.thermo_state, &c.monitor_state, &c.run_state})
    tail.put(block->data(), block->size());
  const double box[6] = {c.box.origin[0],  c.box.origin[1],  c.box.origin[2],
                         c.box.lengths[0], c.box.lengths[1], c.box.lengths[2]};
  tail.put(box, 6);
  tail.put<std::uint64_t>(c.force_term_states.size());
  for (const std::vector<double>& block : c.force_term_states) tail.put(block.data(), block.size());
  pieces.push_back(tail.done());
  return pieces;
}

class Reader {
 public:
  Reader(const std::vector<char>& b, std::size_t pos, std::string path) : buf_(b), path_(std::move(path)), pos_(pos) {}
  template <class T>
  T get() {
    need(sizeof(T));
    T v;
    std::memcpy(&v, buf_.data() + pos_, sizeof(T));
    pos_ += sizeof(T);
    return v;
  }
  std::string string() {
    const auto n = get<std::uint64_t>();
    need(n);
    std::string s(buf_.data() + pos_, n);
    pos_ += n;
    return s;
  }
  std::vector<double> doubles() {
    const auto n = get<std::uint64_t>();
    if (n > buf_.size()) bad("a block longer than the file");
    need(n * sizeof(double));
    std::vector<double> v(n);
    if (n > 0) std::memcpy(v.data(), buf_.data() + pos_, n * sizeof(double));  // no null pointer to memcpy
    pos_ += n * sizeof(double);
    return v;
  }
  bool at_end() const { return pos_ == buf_.size(); }
  // Past the checksum, a malformed body means a writer bug or a forged file: still one line.
  [[noreturn]] void bad(const std::string& what) const {
    throw InputError(path_ + ": malformed checkpoint (" + what + ")");
  }

 private:
  void need(std::uint64_t n) const {
    if (n > buf_.size() - pos_) bad("a field runs past the end");  // pos_ <= size; no wrap
  }
  const std::vector<char>& buf_;
  std::string path_;
  std::size_t pos_;
};

void fail_io(const std::string& path, const char* what) {
  throw InputError(path + ": cannot " + what + " checkpoint: " + std::strerror(errno));
}

template <class T>
void put_raw(std::array<char, kHeader>& h, std::size_t at, T v) {
  std::memcpy(h.data() + at, &v, sizeof(T));
}
template <class T>
T get_raw(const std::vector<char>& b, std::size_t at) {
  T v;
  std::memcpy(&v, b.data() + at, sizeof(T));
  return v;
}

}  // namespace

namespace {
// How a term enters the fingerprint: by its own definition, lists and all (ForceTerm::define:
// the sequential fingerprint and format version 7), or by its description's (format version 8:
// description_definition).
enum class TermRecord { own, description };

// The 1-4 table of a charmm-dihedral (ε₁₄, σ₁₄ per pair of particle types, mixed), whether its
// pairs carry Coulomb and its qqrd2e: what the term's 1-4 pairs are made of besides the dihedrals,
// the particle types and charges, and which its definition holds only through its pairs — none on
// a subset of no particle. Probed: for each pair of particle types a ≤ b, the description made
// on four particles per claimed dihedral type (types a, a, b, b; charges 1, 0, 0, 1) holding one
// dihedral of that type, whose definition then holds A = 4 w ε σ¹², B = 4 w σ⁶ ε and Q = w qqrd2e
// (0 without Coulomb) of the pair (a, b) for each type with w > 0; a table without the pair
// where a type with w > 0 needs it refuses the probe, recorded as such. O(types² · (types² +
// dihedral types)): each probe copies the table; never the system's size.
void define_charmm_14(ParameterRecord& r, const CharmmDihedral& term, int particle_types, const Box& box) {
  const std::vector<int>& claim = term.type_claim();
  for (int a = 0; a < particle_types; ++a)
    for (int b = a; b < particle_types; ++b) {
      std::vector<int> global, types;
      std::vector<double> charges;
      Topology probe;
      for (std::size_t t = 0; t < claim.size(); ++t) {
        if (claim[t] < 0) continue;
        const int at = static_cast<int>(global.size());
        for (int k = 0; k < 4; ++k) global.push_back(at + k);
        types.insert(types.end(), {a, a, b, b});
        charges.insert(charges.end(), {1.0, 0.0, 0.0, 1.0});
        probe.dihedrals.push_back({at, at + 1, at + 2, at + 3, static_cast<int>(t)});
      }
      r.add("lj14 pair", {a, b});
      try {
        term.on_subset(ParticleSubset{global, types, probe, charges}, box)->define(r);
      } catch (const std::invalid_argument&) {
        r.add("lj14 pair", "not set");
      }
    }
}

// A term's record in format version 8: what defines it without the lists that the scene's
// particles and topology items (summed by blocks) make by its rules — the definition of its
// description (the term made on a subset of no particle: ForceTerm::on_subset; its coefficients,
// no list) and its rule, which that definition lacks: a bonded term's claim on the topology's
// types (TypeClaim), the stiff bonds' rule (StiffBondRule), an external term's selection
// (ParticleSelection), a charmm-dihedral's 1-4 table (define_charmm_14). The pair and k-space
// terms and gravity have no rule: their lists (per-particle types, charges and masses, special
// pairs of the bonds) are the particles' and items' own. A term without its rule (one made from
// its lists alone) or that cannot be made on a subset is recorded by its own definition, lists
// and all. A description made on no particle of a term is the same description (its
// coefficients and rule, copied), so the record of a scene whose terms are descriptions is the
// whole scene's.
void description_definition(ParameterRecord& r, const ForceTerm& term, const Scene& sc) {
  const auto* claim = dynamic_cast<const TypeClaim*>(&term);
  const auto* stiff = dynamic_cast<const StiffHarmonicBond*>(&term);
  const auto* selection = dynamic_cast<const SelectionRule*>(&term);
  const bool ruleless = (claim && claim->type_claim().empty()) || (stiff && stiff->rule().empty()) ||
                        (selection && !selection->has_selection());
  std::unique_ptr<ForceTerm> description;
  if (!ruleless) {
    const std::vector<int> none;
    const Topology empty;
    try {
      description = term.on_subset(ParticleSubset{none, none, empty}, sc.box);
    } catch (const std::invalid_argument&) {
    }
  }
  if (!description) {
    r.add("definition", "own");
    term.define(r);
    return;
  }
  r.add("definition", "description");
  description->define(r);
  if (claim) r.add("type claim", std::span<const int>(claim->type_claim()));
  if (stiff) {
    const StiffBondRule& rule = stiff->rule();
    r.add("bond claim", std::span<const int>(rule.bond_claim));
    for (const StiffBond& c : rule.bond_coeffs) r.add("length alpha", {c.length, c.alpha});
    for (const RigidAngleType& a : rule.rigid_angles) {
      r.add("rigid angle type", a.type);
      r.add("cos theta0 alpha", {a.cos_theta0, a.alpha});
    }
  }
  if (selection) {
    const ParticleSelection& s = selection->selection();
    r.add("selection", static_cast<int>(s.kind));
    r.add("listed", std::span<const int>(s.listed));
    r.add("type", s.type);
  }
  if (const auto* charmm = dynamic_cast<const CharmmDihedral*>(&term))
    define_charmm_14(r, *charmm, static_cast<int>(sc.types.size()), sc.box);
}

// The description's last part, the same in every fingerprint: the box, the levels with their
// kicks, the units and each term's record (TermRecord).
void add_box_levels_units_terms(ParameterRecord& r, const Scene& sc, TermRecord how) {
  for (int a = 0; a < 3; ++a) {
    r.add("periodic", sc.box.periodic[a]);
    r.add("origin", sc.box.origin[a]);
    r.add("length", sc.box.lengths[a]);
  }
  r.add("levels", sc.integrator.levels.size());  // none without [[integrator.levels]]
  // A level's kick where it is not the method's own (a restart would otherwise load cached kick
  // forces of another strategy); absent otherwise, so that the decks without one keep their
  // fingerprints.
  const MethodInfo* method = find_method(sc.integrator.method);
  for (const LevelSettings& l : sc.integrator.levels) {
    r.add("level", l.name);
    if (l.kick && (!method || l.kick != method->kick)) r.add("kick", std::string(kick_name(*l.kick)));
  }
  // The units give the deck's times and temperatures their meaning.
  r.add("units", sc.units.name);
  // Each term writes its own parameters (ForceTerm::define): the coefficients the forces are
  // computed from, bit for bit; its lists too (TermRecord::own), or its rule instead.
  r.add("terms", sc.forces->terms().size());
  for (const auto& term : sc.forces->terms()) {
    r.add("name", term->name());
    r.add("style", term->style());
    r.add("level", term->level().index);
    if (how == TermRecord::own)
      term->define(r);
    else
      description_definition(r, *term, sc);
  }
}
}  // namespace

std::uint64_t scene_fingerprint_sequential(const Scene& sc) {
  ParameterRecord r;
  r.add("particles", sc.state.size());
  r.add("inverse masses",
        std::span<const double>(sc.state.inv_mass.data(), static_cast<std::size_t>(sc.state.inv_mass.size())));
  r.add("particle type", std::span<const int>(sc.particle_type));
  if (sc.charged()) r.add("charge", std::span<const double>(sc.charge));
  r.add("types", sc.types.size());
  for (const ParticleType& t : sc.types) {
    r.add("name", t.name);
    r.add("mass", t.mass);
  }
  const Topology& top = sc.topology;
  r.add("bonds", top.bonds.size());
  for (const Bond& b : top.bonds) r.add("bond", {b.i, b.j, b.type});
  r.add("angles", top.angles.size());
  for (const Angle& a : top.angles) r.add("angle", {a.i, a.j, a.k, a.type});
  r.add("dihedrals", top.dihedrals.size());
  for (const Dihedral& d : top.dihedrals) r.add("dihedral", {d.i, d.j, d.k, d.l, d.type});
  if (!top.impropers.empty()) {  // only then: the fingerprints of scenes without impropers are unchanged
    r.add("impropers", top.impropers.size());
    for (const Improper& d : top.impropers) r.add("improper", {d.i, d.j, d.k, d.l, d.type});
  }
  r.add("molecule", std::span<const int>(top.molecule));
  add_box_levels_units_terms(r, sc, TermRecord::own);
  return r.value();
}

namespace {

// One particle's or item's hash: FNV-1a of its words (each as its 8 bytes, as ParameterRecord
// writes numbers), then MurmurHash3's 64-bit finaliser (a bijection: it adds no collision), so
// that a change in any bit of any word moves every bit of the hash about half the time. A sum of
// such hashes, in any order, then changes with any one record changed (one particle's mass, one
// bond's type) unless its FNV-1a value collides, and with several changed unless their changes
// cancel mod 2⁶⁴: about 2⁻⁶⁴ either way for records that are not built to collide.
class RecordHash {
 public:
  explicit RecordHash(std::int64_t kind) { word(kind); }
  RecordHash& word(std::int64_t n) { return bytes(&n, sizeof n); }
  RecordHash& real(double v) { return bytes(&v, sizeof v); }
  std::uint64_t value() const {
    std::uint64_t h = h_;
    h ^= h >> 33;
    h *= 0xff51afd7ed558ccdull;
    h ^= h >> 33;
    h *= 0xc4ceb9fe1a85ec53ull;
    h ^= h >> 33;
    return h;
  }

 private:
  RecordHash& bytes(const void* p, std::size_t n) {
    const auto* c = static_cast<const unsigned char*>(p);
    for (std::size_t k = 0; k < n; ++k) h_ = (h_ ^ c[k]) * 0x100000001b3ull;
    return *this;
  }
  std::uint64_t h_ = 0xcbf29ce484222325ull;
};

// The record kinds: a particle, and the topology's four kinds of item.
enum RecordKind : std::int64_t { kParticle = 1, kBondItem, kAngleItem, kDihedralItem, kImproperItem };

// What blocks of the system contribute, summed: the per-particle and per-item hashes (mod 2⁶⁴)
// and the counts.
struct BlockSums {
  std::uint64_t particles = 0, items = 0;
  std::int64_t count[5] = {0, 0, 0, 0, 0};  // particles, bonds, angles, dihedrals, impropers

  void particle(std::int64_t g, double inv_mass, std::int64_t type, double charge, std::int64_t molecule) {
    particles += RecordHash(kParticle).word(g).real(inv_mass).word(type).real(charge).word(molecule).value();
    ++count[0];
  }
  void item(const Bond& b, std::int64_t place) {
    items += RecordHash(kBondItem).word(place).word(b.i).word(b.j).word(b.type).value();
    ++count[1];
  }
  void item(const Angle& a, std::int64_t place) {
    items += RecordHash(kAngleItem).word(place).word(a.i).word(a.j).word(a.k).word(a.type).value();
    ++count[2];
  }
  void item(const Dihedral& d, std::int64_t place) {
    items += RecordHash(kDihedralItem).word(place).word(d.i).word(d.j).word(d.k).word(d.l).word(d.type).value();
    ++count[3];
  }
  void item(const Improper& d, std::int64_t place) {
    items += RecordHash(kImproperItem).word(place).word(d.i).word(d.j).word(d.k).word(d.l).word(d.type).value();
    ++count[4];
  }
};

// The whole fingerprint (version 7 or 8) from the system's sums and the scene's description: the
// description in sequence (the ParameterRecord of scene_fingerprint_sequential but its
// per-particle arrays and topology items, which the sums stand for), then the counts and sums.
// Version 7 records each term by its own definition, version 8 by its description's and rule
// (description_definition).
std::uint64_t fingerprint_of(const Scene& sc, const BlockSums& s, std::uint32_t version) {
  ParameterRecord r;
  r.add("fingerprint by blocks", static_cast<int>(version));
  r.add("particles", s.count[0]);
  r.add("bonds", s.count[1]);
  r.add("angles", s.count[2]);
  r.add("dihedrals", s.count[3]);
  r.add("impropers", s.count[4]);
  r.add("particle sum", static_cast<std::int64_t>(s.particles));
  r.add("item sum", static_cast<std::int64_t>(s.items));
  r.add("types", sc.types.size());
  for (const ParticleType& t : sc.types) {
    r.add("name", t.name);
    r.add("mass", t.mass);
  }
  add_box_levels_units_terms(r, sc,
                             version >= kFirstFingerprintByDescriptions ? TermRecord::description : TermRecord::own);
  return r.value();
}

template <class Item>
void add_items(BlockSums& s, const std::vector<Item>& items) {
  for (std::size_t k = 0; k < items.size(); ++k) s.item(items[k], static_cast<std::int64_t>(k));
}
template <class Item>
void add_items(BlockSums& s, const std::vector<PartMolecules::Placed<Item>>& items) {
  for (const auto& p : items) s.item(p.item, p.place);
}

// A u64 sum mod 2⁶⁴ over the ranks, exactly: its two 32-bit halves summed apart as integers (each
// below 2³² a rank, so below 2⁶³ for any number of ranks below 2³¹), then carried.
std::uint64_t sum_mod_2_64(std::uint64_t mine, const Communicator& ranks) {
  std::int64_t halves[2] = {static_cast<std::int64_t>(mine & 0xffffffffull), static_cast<std::int64_t>(mine >> 32)};
  ranks.sum(halves, 2);
  return static_cast<std::uint64_t>(halves[0]) + (static_cast<std::uint64_t>(halves[1]) << 32);
}

}  // namespace

namespace {
// The whole scene's sums, particle by particle and item by item.
BlockSums whole_sums(const Scene& sc) {
  BlockSums s;
  const auto n = static_cast<std::size_t>(sc.state.size());
  const Topology& top = sc.topology;
  for (std::size_t g = 0; g < n; ++g)
    s.particle(static_cast<std::int64_t>(g), sc.state.inv_mass[static_cast<Eigen::Index>(g)], sc.particle_type[g],
               g < sc.charge.size() ? sc.charge[g] : 0.0, top.molecule.empty() ? -1 : top.molecule[g]);
  add_items(s, top.bonds);
  add_items(s, top.angles);
  add_items(s, top.dihedrals);
  add_items(s, top.impropers);
  return s;
}
}  // namespace

std::uint64_t scene_fingerprint(const Scene& sc) {
  return fingerprint_of(sc, whole_sums(sc), kCheckpointVersion);
}

std::uint64_t scene_fingerprint_v7(const Scene& sc) {
  return fingerprint_of(sc, whole_sums(sc), 7);
}

std::uint64_t scene_fingerprint_parts(const Scene& description, const PartMolecules& part, const Communicator& ranks) {
  BlockSums s;
  for (int k = 0; k < part.size(); ++k) {
    const auto u = static_cast<std::size_t>(k);
    s.particle(part.global[u], part.inv_mass[u], part.type[u], u < part.charge.size() ? part.charge[u] : 0.0,
               part.molecule_id.empty() ? -1 : part.molecule_id[u]);
  }
  add_items(s, part.bonds);
  add_items(s, part.angles);
  add_items(s, part.dihedrals);
  add_items(s, part.impropers);
  s.particles = sum_mod_2_64(s.particles, ranks);
  s.items = sum_mod_2_64(s.items, ranks);
  ranks.sum(s.count, 5);
  return fingerprint_of(description, s, kCheckpointVersion);
}

namespace {

// The header (magic, version, byte order, double size, length, fingerprint, the crc32 of bytes 12
// … end: the header's own, combined with the pieces' in file order), written over the first
// kHeader bytes. The pieces must tile [kHeader, end).
void write_header(int fd, const std::string& path, std::vector<Piece> pieces, std::uint64_t fingerprint) {
  std::sort(pieces.begin(), pieces.end(), [](const Piece& a, const Piece& b) { return a.offset < b.offset; });
  std::uint64_t end = kHeader;
  for (const Piece& p : pieces) {
    if (p.offset != end)
      throw InputError(path +
                       ": cannot write checkpoint: the processes' pieces do not tile the file (a gap or an "
                       "overlap at byte " +
                       std::to_string(end) + ")");
    end += p.length;
  }
  std::array<char, kHeader> head{};
  std::memcpy(head.data(), kMagic, sizeof kMagic);
  put_raw<std::uint32_t>(head, 12, kCheckpointVersion);
  put_raw<std::uint32_t>(head, 16, kByteOrderMark);
  put_raw<std::uint32_t>(head, 20, sizeof(double));
  put_raw<std::uint64_t>(head, 24, end);
  put_raw<std::uint64_t>(head, 32, fingerprint);
  auto crc = static_cast<uLong>(crc32_of(0, head.data() + kCrcFrom, kHeader - kCrcFrom));
  for (const Piece& p : pieces) crc = ::crc32_combine(crc, p.crc, static_cast<z_off_t>(p.length));
  put_raw<std::uint32_t>(head, 8, static_cast<std::uint32_t>(crc));
  for (size_t done = 0; done < head.size();) {
    const ssize_t k = ::pwrite(fd, head.data() + done, head.size() - done, static_cast<off_t>(done));
    if (k < 0) {
      if (errno == EINTR) continue;
      fail_io(path, "write");
    }
    done += static_cast<size_t>(k);
  }
}

// The per-particle arrays of a process's own particles (x, v, inv_mass, the carried columns, in
// the order of the global indices `owned`) brought to the blocks and written there, in rounds of
// `round` rows of every block (the same rounds on every process: ⌈⌈N / P⌉ / round⌉):
// each round's rows, once they arrive, are one piece per array. A process holds one round's rows
// and messages, not its block (docs/parallel.md, "What a rank holds"). Collective: a failed write
// is kept (`failed`) and the rounds go on, so that every process reaches every exchange.
void write_rounds(int fd, const Communicator& comm, std::uint64_t n, ParticleBlock b, const std::vector<int>& owned,
                  const double* x, const double* v, const double* inv_mass, const std::vector<const double*>& columns,
                  std::int64_t round, const Layout& l, std::vector<Piece>& pieces, int& failed) {
  const auto total = static_cast<std::int64_t>(n);
  const std::int64_t most = (total + comm.size() - 1) / comm.size();
  std::vector<BlockArray> arrays = {{x, nullptr, 3}, {v, nullptr, 3}, {inv_mass, nullptr, 1}};
  for (const double* c : columns) arrays.push_back({c, nullptr, 3});
  std::vector<std::uint64_t> at = {l.x + 8, l.v + 8, l.inv_mass + 8};
  at.insert(at.end(), l.column.begin(), l.column.end());
  if (at.size() != arrays.size()) throw std::logic_error("write_checkpoint: a carried column without its place");
  std::vector<std::vector<double>> chunk(arrays.size());
  BlockExchange exchange;
  if (round < 1) throw std::logic_error("write_checkpoint: a round of no particle");
  for (std::int64_t from = 0; from < most; from += round) {
    const std::int64_t to = std::min(from + round, most);
    const std::int64_t first = std::min(from, b.count), count = std::min(to, b.count) - first;
    for (size_t a = 0; a < arrays.size(); ++a) {
      chunk[a].resize(static_cast<size_t>(arrays[a].rows * count));
      arrays[a].block = chunk[a].data();
    }
    exchange.run(comm, total, owned, arrays, from, to);
    if (count == 0 || failed) continue;
    try {
      for (size_t a = 0; a < arrays.size(); ++a) {
        Writer w(fd, at[a] + 8 * static_cast<std::uint64_t>(arrays[a].rows * (b.first + first)));
        w.put_values(chunk[a].data(), chunk[a].size());
        pieces.push_back(w.done());
      }
    } catch (const std::system_error& e) {
      failed = e.code().value();
    }
  }
}

// The file written by every process: rank 0 creates the temporary file; each process writes its
// pieces into it and syncs them; rank 0 writes the header from every piece's crc32, syncs, renames
// it over the old file and syncs the directory. Each step ends in an agreement (core/
// communicator.hpp `agree`: every process reaches every collective call, and a failure on one
// ends every one with its message). With one process, the same steps without agreements.
void write_together(const std::string& path, const Communicator& comm, std::uint64_t n, std::int64_t step, double t,
                    ParticleBlock b, const double* x, const double* v, const double* inv_mass,
                    const std::vector<const double*>& columns, std::span<const Run> runs, const Checkpoint& c,
                    const std::vector<int>* owned = nullptr, std::int64_t round = kCheckpointRound) {
  const std::string tmp = path + ".tmp";
  const bool root = comm.root();
  int fd = -1;
  try {
    agree(&comm, [&] {
      if (!root) return;
      fd = ::open(tmp.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
      if (fd < 0) fail_io(path, "create");
    });
    std::vector<Piece> pieces;
    agree(&comm, [&] {
      if (!root && (fd = ::open(tmp.c_str(), O_WRONLY)) < 0) fail_io(path, "open");
      try {
        if (owned)  // the per-particle arrays by rounds, below
          pieces = write_pieces(fd, root, n, step, t, b, nullptr, nullptr, nullptr, {}, runs, c);
        else
          pieces = write_pieces(fd, root, n, step, t, b, x, v, inv_mass, columns, runs, c);
      } catch (const std::system_error& e) {
        errno = e.code().value();
        fail_io(path, "write");
      }
    });
    if (owned) {
      int failed = 0;
      write_rounds(fd, comm, n, b, *owned, x, v, inv_mass, columns, round, layout_of(n, c, runs), pieces, failed);
      agree(&comm, [&] {
        if (failed == 0) return;
        errno = failed;
        fail_io(path, "write");
      });
    }
    agree(&comm, [&] {
      if (!root) {
        const bool synced = ::fsync(fd) == 0;
        const bool closed = ::close(fd) == 0;
        fd = -1;
        if (!synced || !closed) fail_io(path, "sync");
      }
    });
    // Every process's pieces on rank 0: offset, length, crc32 (each exact in a double).
    std::vector<double> mine;
    for (const Piece& p : pieces)
      mine.insert(mine.end(),
                  {static_cast<double>(p.offset), static_cast<double>(p.length), static_cast<double>(p.crc)});
    std::vector<std::vector<double>> all;
    comm.gather(mine, all);
    agree(&comm, [&] {
      if (!root) return;
      std::vector<Piece> every;
      for (const std::vector<double>& words : all)
        for (size_t k = 0; k + 3 <= words.size(); k += 3)
          every.push_back({static_cast<std::uint64_t>(words[k]), static_cast<std::uint64_t>(words[k + 1]),
                           static_cast<std::uint32_t>(words[k + 2])});
      write_header(fd, path, std::move(every), c.scene_fingerprint);
      const bool synced = ::fsync(fd) == 0;
      const bool closed = ::close(fd) == 0;
      fd = -1;
      if (!synced || !closed) fail_io(path, "sync");
      if (std::rename(tmp.c_str(), path.c_str()) != 0) fail_io(path, "rename");
      const std::string dir = std::filesystem::path(path).parent_path().string();
      const int dfd = ::open(dir.empty() ? "." : dir.c_str(), O_RDONLY | O_DIRECTORY);
      if (dfd >= 0) {
        ::fsync(dfd);
        ::close(dfd);
      }
    });
  } catch (...) {
    if (fd >= 0) ::close(fd);
    if (root) ::unlink(tmp.c_str());
    throw;
  }
}

}  // namespace

void write_checkpoint(const std::string& path, const State& state, const Checkpoint& c) {
  static const OneProcess one;
  const auto n = static_cast<std::uint64_t>(state.size());
  const Run words[1] = {{std::span<const double>(c.integrator_state), -1}};
  write_together(path, one, n, state.step, state.t, {0, state.size()}, state.x.data(), state.v.data(),
                 state.inv_mass.data(), {}, words, c);
}

void write_checkpoint(const std::string& path, const Communicator& processes, const CheckpointBlock& mine,
                      const Checkpoint& rest) {
  std::vector<Run> runs;
  for (const WordRun& r : *mine.integrator) runs.push_back({std::span<const double>(r.words), r.column});
  write_together(path, processes, static_cast<std::uint64_t>(mine.num_particles), rest.state.step, rest.state.t,
                 mine.block, mine.x, mine.v, mine.inv_mass, mine.columns, runs, rest, mine.owned, mine.round);
}

namespace {
// The blocks after the integrator's words, to the file's end, read alike from memory (Reader) and
// by pread (FileFields): thermo, monitor, run statistics, the box (version 6 on; a version-5
// file's run kept the deck's), the force terms' states. `size`: the file's, a bound on the count.
template <class Fields>
void read_tail(Fields& r, Checkpoint& c, std::uint64_t size) {
  c.thermo_state = r.doubles();
  c.monitor_state = r.doubles();
  c.run_state = r.doubles();
  if (c.version >= 6) {
    const auto box = r.doubles();
    if (box.size() != 6) r.bad("box");
    c.box.origin = Eigen::Vector3d(box[0], box[1], box[2]);
    c.box.lengths = Eigen::Vector3d(box[3], box[4], box[5]);
    c.has_box = true;
  }
  const auto terms = r.template get<std::uint64_t>();
  if (terms > size) r.bad("term count");
  for (std::uint64_t k = 0; k < terms; ++k) c.force_term_states.push_back(r.doubles());
  if (!r.at_end()) r.bad("bytes after the last block");
  if (c.run_state.size() < 4) r.bad("run statistics");
}

// Why a checkpoint of another format version is not read (one line, after the path).
std::string unread_version(std::uint32_t version) {
  return "checkpoint of format version " + std::to_string(version) +
         (version > kCheckpointVersion ? " (a newer"
          : version >= 2               ? " (an older"
                                       : " (an unknown") +
         " stiffmd); this stiffmd reads versions " + std::to_string(kOldestCheckpointVersion) + " to " +
         std::to_string(kCheckpointVersion);
}
}  // namespace

Checkpoint read_checkpoint(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw InputError(path + ": cannot open checkpoint: " + std::strerror(errno));
  const std::vector<char> b((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  auto fail = [&](const std::string& what) -> void { throw InputError(path + ": " + what); };
  if (b.size() >= 8 && std::memcmp(b.data(), kMagicVersion1, 8) == 0)
    fail(
        "checkpoint of format version 1 (an older stiffmd), which lacks the integrator and neighbour-list state "
        "needed to continue a run exactly; start the run afresh");
  if (b.size() < kHeader || std::memcmp(b.data(), kMagic, 8) != 0)
    fail(b.size() >= 8 && std::memcmp(b.data(), kMagic, 8) == 0
             ? "truncated checkpoint (" + std::to_string(b.size()) + " bytes, shorter than its header)"
             : "not a stiffmd checkpoint");
  const auto bom = get_raw<std::uint32_t>(b, 16);
  if (bom == __builtin_bswap32(kByteOrderMark))
    fail("checkpoint written on a machine of the other byte order; checkpoints are not portable across byte orders");
  const auto length = get_raw<std::uint64_t>(b, 24);
  const auto stored_crc = get_raw<std::uint32_t>(b, 8);
  const std::uint32_t crc = crc32_of(0, b.data() + kCrcFrom, b.size() - kCrcFrom);
  if (crc != stored_crc) {
    std::ostringstream m;
    if (bom == kByteOrderMark && length > b.size())
      m << "truncated checkpoint (" << b.size() << " of " << length << " bytes)";
    else
      m << "damaged checkpoint (crc32 " << std::hex << crc << ", recorded " << stored_crc << ")";
    fail(m.str());
  }
  const auto version = get_raw<std::uint32_t>(b, 12);
  if (version < kOldestCheckpointVersion || version > kCheckpointVersion) fail(unread_version(version));
  if (bom != kByteOrderMark || get_raw<std::uint32_t>(b, 20) != sizeof(double) || length != b.size())
    fail("malformed checkpoint header (byte order, double size or length)");

  Checkpoint c;
  c.version = version;
  c.scene_fingerprint = get_raw<std::uint64_t>(b, 32);
  Reader r(b, kHeader, path);
  const auto n = r.get<std::int64_t>();
  c.state.step = r.get<std::int64_t>();
  c.state.t = r.get<double>();
  c.h = r.get<double>();
  c.method = r.string();
  if (version >= 6) {  // the stage; a version-5 file is of a run without stages
    const auto stage = r.get<std::int64_t>();
    if (stage < 0 || stage > std::numeric_limits<int>::max()) r.bad("stage number");
    c.stage = static_cast<int>(stage);
    c.stage_name = r.string();
    if ((c.stage == 0) != c.stage_name.empty()) r.bad("stage number and name");
  }
  const auto x = r.doubles(), v = r.doubles(), im = r.doubles();
  c.integrator_state = r.doubles();
  read_tail(r, c, b.size());
  if (n < 0 || x.size() != 3 * static_cast<size_t>(n) || v.size() != x.size() || im.size() != static_cast<size_t>(n))
    r.bad("array sizes disagree with the particle count");
  if (c.state.step < 0 || !(c.state.t >= 0.0) || !std::isfinite(c.state.t) || !(c.h > 0.0) || !std::isfinite(c.h))
    r.bad("step " + std::to_string(c.state.step) + ", t or h out of range");
  c.state.x = Eigen::Map<const Eigen::Matrix3Xd>(x.data(), 3, n);
  c.state.v = Eigen::Map<const Eigen::Matrix3Xd>(v.data(), 3, n);
  c.state.inv_mass = Eigen::Map<const Eigen::VectorXd>(im.data(), n);
  return c;
}

void check_checkpoint_stage(const Scene& sc, const Checkpoint& c, const std::string& path) {
  const std::string again = ": continue it with the deck it was written with";
  const StageIdentity written{c.stage, 0, c.stage_name};
  if (c.stage > 0 && !sc.stage.staged())
    throw InputError(path + ": checkpoint of " + stage_label(written) +
                     " of a staged protocol, and the deck has no [[stage]] tables" + again);
  if (c.stage == 0 && sc.stage.staged())
    throw InputError(path + ": checkpoint of a run without stages, and the deck is a protocol of " +
                     std::to_string(sc.stage.count) + " stages" + again);
  if (c.stage != sc.stage.number || c.stage_name != sc.stage.name)
    throw InputError(path + ": checkpoint of " + stage_label(written) + ", not of the deck's " + stage_label(sc.stage) +
                     again);
}

Checkpoint read_checkpoint_of(const Scene& sc, const std::string& path) {
  Checkpoint c = read_checkpoint(path);
  check_checkpoint_stage(sc, c, path);
  if (c.state.size() != sc.state.size())
    throw InputError(path + ": checkpoint holds " + std::to_string(c.state.size()) + " particles, the deck " +
                     std::to_string(sc.state.size()) + ": not a checkpoint of this scene");
  if (c.state.inv_mass != sc.state.inv_mass)
    throw InputError(path + ": checkpoint masses differ from the deck's: not a checkpoint of this scene");
  // A file of version 7 holds the fingerprint by blocks of the terms' own definitions, one before
  // version 7 the sequential fingerprint of the whole scene.
  const std::uint64_t expected = c.version >= kFirstFingerprintByDescriptions ? scene_fingerprint(sc)
                                 : c.version >= kFirstFingerprintByBlocks     ? scene_fingerprint_v7(sc)
                                                                              : scene_fingerprint_sequential(sc);
  if (c.scene_fingerprint != expected)
    throw InputError(path +
                     ": checkpoint of another scene (particle types, topology, box, levels or their kicks, force "
                     "terms or their parameters differ from the deck's)");
  const auto& terms = sc.forces->terms();
  if (c.force_term_states.size() != terms.size())
    throw InputError(path + ": checkpoint holds the state of " + std::to_string(c.force_term_states.size()) +
                     " force terms, the deck has " + std::to_string(terms.size()));
  return c;
}

bool checkpoint_at_end(const Scene& sc, const Checkpoint& c) {
  return sc.run.steps > 0 ? c.state.step >= sc.run.steps : c.state.t >= sc.run.t_end * (1 - 1e-12);
}

Checkpoint read_checkpoint_for(Scene& sc, const std::string& path) {
  Checkpoint c = read_checkpoint_of(sc, path);
  load_checkpoint_rest(sc, c, path);
  return c;
}

void load_checkpoint_rest(Scene& sc, const Checkpoint& c, const std::string& path) {
  check_checkpoint_stage(sc, c, path);
  const auto& terms = sc.forces->terms();
  if (c.force_term_states.size() != terms.size())
    throw InputError(path + ": checkpoint holds the state of " + std::to_string(c.force_term_states.size()) +
                     " force terms, the deck has " + std::to_string(terms.size()));
  if (sc.run.steps > 0 && c.state.step >= sc.run.steps)
    throw InputError(path + ": checkpoint is at step " + std::to_string(c.state.step) + ", not before run.steps = " +
                     std::to_string(sc.run.steps) + " (raise it with --set run.steps=...)");
  if (sc.run.steps == 0 && c.state.t >= sc.run.t_end * (1 - 1e-12)) {
    std::ostringstream m;
    m.precision(10);
    m << path << ": checkpoint is at t = " << c.state.t << ", not before run.t_end = " << sc.run.t_end
      << " (raise it with --set run.t_end=...)";
    throw InputError(m.str());
  }
  // The box as it was (a barostat moves it; the scene's is the deck's, which the fingerprint holds).
  if (c.has_box) {
    Box box = sc.forces->box();
    box.origin = c.box.origin;
    box.lengths = c.box.lengths;
    sc.forces->set_box(box);
  }
  for (size_t k = 0; k < terms.size(); ++k) {
    try {
      terms[k]->load_state(c.force_term_states[k]);
    } catch (const std::invalid_argument& e) {
      throw InputError(path + ": " + e.what());
    }
  }
}

std::uint32_t checkpoint_format_version(const std::string& path) {
  const int fd = ::open(path.c_str(), O_RDONLY);
  if (fd < 0) return 0;
  std::array<char, 16> h{};
  const ssize_t got = ::pread(fd, h.data(), h.size(), 0);
  ::close(fd);
  if (got != static_cast<ssize_t>(h.size()) || std::memcmp(h.data(), kMagic, 8) != 0) return 0;
  std::uint32_t version = 0;
  std::memcpy(&version, h.data() + 12, sizeof version);
  return version;
}

namespace {

// n bytes at `at`, or false (an error, or the end of the file first).
bool read_at(int fd, void* out, std::uint64_t n, std::uint64_t at) {
  auto* p = static_cast<char*>(out);
  while (n > 0) {
    const ssize_t k = ::pread(fd, p, static_cast<size_t>(std::min<std::uint64_t>(n, 1u << 30)), static_cast<off_t>(at));
    if (k < 0 && errno == EINTR) continue;
    if (k <= 0) return false;
    p += k;
    at += static_cast<std::uint64_t>(k);
    n -= static_cast<std::uint64_t>(k);
  }
  return true;
}

// The fields of the file read in sequence from `pos` by pread, as Reader reads them from memory:
// a field past the end is a malformed checkpoint (the checksum was right: a writer bug or a forged
// file). Counts the bytes it reads.
class FileFields {
 public:
  FileFields(int fd, std::uint64_t size, std::uint64_t pos, const std::string& path, std::uint64_t& count)
      : fd_(fd), size_(size), pos_(pos), path_(path), count_(count) {}
  template <class T>
  T get() {
    T v;
    bytes(&v, sizeof(T));
    return v;
  }
  std::string string() {
    const auto n = get<std::uint64_t>();
    need(n);
    std::string s(n, '\0');
    bytes(s.data(), n);
    return s;
  }
  std::vector<double> doubles() {
    const auto n = get<std::uint64_t>();
    if (n > size_) bad("a block longer than the file");
    need(n * sizeof(double));
    std::vector<double> v(n);
    bytes(v.data(), n * sizeof(double));
    return v;
  }
  // A block's count word, checked to be `expected`; its values skipped. Returns their offset.
  std::uint64_t skip_block(std::uint64_t expected, const char* what) {
    if (get<std::uint64_t>() != expected)
      bad(std::string("array sizes disagree with the particle count (") + what + ")");
    const std::uint64_t at = pos_;
    skip(expected * sizeof(double));
    return at;
  }
  void skip(std::uint64_t n) {
    need(n);
    pos_ += n;
  }
  std::uint64_t pos() const { return pos_; }
  bool at_end() const { return pos_ == size_; }
  [[noreturn]] void bad(const std::string& what) const {
    throw InputError(path_ + ": malformed checkpoint (" + what + ")");
  }

 private:
  void need(std::uint64_t n) const {
    if (n > size_ - pos_) bad("a field runs past the end");
  }
  void bytes(void* out, std::uint64_t n) {
    need(n);
    if (n > 0 && !read_at(fd_, out, n, pos_))
      throw InputError(path_ + ": cannot read checkpoint: " + std::strerror(errno));
    pos_ += n;
    count_ += n;
  }
  int fd_;
  std::uint64_t size_, pos_;
  const std::string& path_;
  std::uint64_t& count_;
};

}  // namespace

CheckpointParts::CheckpointParts(const std::string& path, const Communicator& ranks, const std::vector<WordRun>& layout,
                                 const std::string& method)
    : path_(path), ranks_(ranks) {
  const Communicator* comm = &ranks;
  auto fail = [&](const std::string& what) { throw InputError(path + ": " + what); };
  std::uint64_t size = 0;
  std::array<char, kHeader> h{};
  // The header, as read_checkpoint checks it, every rank alike.
  try {
    agree(comm, [&] {
      fd_ = ::open(path.c_str(), O_RDONLY);
      if (fd_ < 0) fail(std::string("cannot open checkpoint: ") + std::strerror(errno));
      struct stat st {};
      if (::fstat(fd_, &st) != 0) fail(std::string("cannot open checkpoint: ") + std::strerror(errno));
      size = static_cast<std::uint64_t>(st.st_size);
      const std::uint64_t head = std::min<std::uint64_t>(size, kHeader);
      if (!read_at(fd_, h.data(), head, 0)) fail(std::string("cannot read checkpoint: ") + std::strerror(errno));
      bytes_read_ += head;
      if (size >= 8 && std::memcmp(h.data(), kMagicVersion1, 8) == 0)
        fail(
            "checkpoint of format version 1 (an older stiffmd), which lacks the integrator and neighbour-list state "
            "needed to continue a run exactly; start the run afresh");
      if (size < kHeader || std::memcmp(h.data(), kMagic, 8) != 0)
        fail(size >= 8 && std::memcmp(h.data(), kMagic, 8) == 0
                 ? "truncated checkpoint (" + std::to_string(size) + " bytes, shorter than its header)"
                 : "not a stiffmd checkpoint");
      std::uint32_t bom = 0;
      std::memcpy(&bom, h.data() + 16, sizeof bom);
      if (bom == __builtin_bswap32(kByteOrderMark))
        fail(
            "checkpoint written on a machine of the other byte order; checkpoints are not portable across byte "
            "orders");
    });
    // The crc32 of bytes 12 … end by blocks: each rank its range, rank 0 combines them in file order.
    const ParticleBlock mine = block_of(static_cast<std::int64_t>(size - kCrcFrom), ranks.size(), ranks.rank());
    std::uint32_t crc = 0;
    bool read = true;
    {
      std::vector<char> buf(1 << 16);
      for (std::int64_t done = 0; read && done < mine.count;) {
        const auto k = std::min<std::int64_t>(mine.count - done, static_cast<std::int64_t>(buf.size()));
        read = read_at(fd_, buf.data(), static_cast<std::uint64_t>(k),
                       kCrcFrom + static_cast<std::uint64_t>(mine.first + done));
        crc = crc32_of(crc, buf.data(), static_cast<std::size_t>(k));
        done += k;
      }
      crc_bytes_read_ = static_cast<std::uint64_t>(mine.count);
    }
    agree(comm, [&] {
      if (!read) fail(std::string("cannot read checkpoint: ") + std::strerror(errno));
    });
    std::vector<std::vector<double>> all;
    ranks.gather({static_cast<double>(mine.count), static_cast<double>(crc)}, all);
    agree(comm, [&] {
      if (!ranks.root()) return;
      std::uint64_t length = 0;
      std::uint32_t stored = 0;
      std::memcpy(&length, h.data() + 24, sizeof length);
      std::memcpy(&stored, h.data() + 8, sizeof stored);
      auto whole = static_cast<uLong>(0);
      for (const std::vector<double>& piece : all)
        whole = ::crc32_combine(whole, static_cast<uLong>(piece[1]), static_cast<z_off_t>(piece[0]));
      if (static_cast<std::uint32_t>(whole) == stored) return;
      std::uint32_t bom = 0;
      std::memcpy(&bom, h.data() + 16, sizeof bom);
      std::ostringstream m;
      if (bom == kByteOrderMark && length > size)
        m << "truncated checkpoint (" << size << " of " << length << " bytes)";
      else
        m << "damaged checkpoint (crc32 " << std::hex << static_cast<std::uint32_t>(whole) << ", recorded " << stored
          << ")";
      fail(m.str());
    });
    // The rest of the header, the prefix and the blocks but the per-particle rows, every rank alike.
    agree(comm, [&] {
      std::uint32_t version = 0, bom = 0, dsize = 0;
      std::uint64_t length = 0;
      std::memcpy(&version, h.data() + 12, sizeof version);
      std::memcpy(&bom, h.data() + 16, sizeof bom);
      std::memcpy(&dsize, h.data() + 20, sizeof dsize);
      std::memcpy(&length, h.data() + 24, sizeof length);
      if (version < kOldestCheckpointVersion || version > kCheckpointVersion) fail(unread_version(version));
      if (version < kFirstFingerprintByDescriptions)
        fail("checkpoint of format version " + std::to_string(version) +
             ", whose fingerprint a restart by parts cannot check; restart it with the whole scene");
      if (bom != kByteOrderMark || dsize != sizeof(double) || length != size)
        fail("malformed checkpoint header (byte order, double size or length)");
      Checkpoint& c = rest_;
      c.version = version;
      std::memcpy(&c.scene_fingerprint, h.data() + 32, sizeof c.scene_fingerprint);
      FileFields r(fd_, size, kHeader, path_, bytes_read_);
      n_ = r.get<std::int64_t>();
      c.state.step = r.get<std::int64_t>();
      c.state.t = r.get<double>();
      c.h = r.get<double>();
      c.method = r.string();
      const auto stage = r.get<std::int64_t>();
      if (stage < 0 || stage > std::numeric_limits<int>::max()) r.bad("stage number");
      c.stage = static_cast<int>(stage);
      c.stage_name = r.string();
      if ((c.stage == 0) != c.stage_name.empty()) r.bad("stage number and name");
      if (n_ < 0 || static_cast<std::uint64_t>(n_) > size / 8) r.bad("array sizes disagree with the particle count");
      const auto n = static_cast<std::uint64_t>(n_);
      x_ = r.skip_block(3 * n, "x");
      v_ = r.skip_block(3 * n, "v");
      inv_mass_ = r.skip_block(n, "inverse masses");
      // The integrator's words: the layout's runs, each column 3 N words.
      const auto words = r.get<std::uint64_t>();
      if (words > size / 8) r.bad("a block longer than the file");
      std::uint64_t expected = 0;
      for (const WordRun& run : layout) expected += run.column >= 0 ? 3 * n : run.words.size();
      // Another method's words (a restart that changes the method starts it afresh): not read.
      if (c.method != method) {
        r.skip(8 * words);
      } else {
        if (words != expected)
          fail("checkpoint holds " + std::to_string(words) + " words of " + c.method +
               " state, the deck's settings lay out " + std::to_string(expected) +
               " (restart it with the whole scene)");
        for (const WordRun& run : layout) {
          if (run.column >= 0) {
            const auto k = static_cast<std::size_t>(run.column);
            if (column_.size() <= k) column_.resize(k + 1, 0);
            column_[k] = r.pos();
            r.skip(24 * n);
            continue;
          }
          for (std::size_t w = 0; w < run.words.size(); ++w) c.integrator_state.push_back(r.get<double>());
        }
      }
      read_tail(r, c, size);
      if (c.state.step < 0 || !(c.state.t >= 0.0) || !std::isfinite(c.state.t) || !(c.h > 0.0) || !std::isfinite(c.h))
        r.bad("step " + std::to_string(c.state.step) + ", t or h out of range");
    });
  } catch (...) {
    if (fd_ >= 0) ::close(fd_);
    fd_ = -1;
    throw;
  }
}

CheckpointParts::~CheckpointParts() {
  if (fd_ >= 0) ::close(fd_);
}

void CheckpointParts::rows(std::uint64_t first_word, int per_particle, const std::vector<int>& ids, double* out) const {
  const auto per = static_cast<std::uint64_t>(per_particle);
  for (std::size_t k = 0; k < ids.size();) {
    std::size_t e = k + 1;
    while (e < ids.size() && ids[e] == ids[e - 1] + 1) ++e;
    if (ids[k] < 0 || ids[e - 1] >= n_)
      throw InputError(path_ + ": checkpoint holds " + std::to_string(n_) + " particles, the deck's particle " +
                       std::to_string(ids[k] < 0 ? ids[k] : ids[e - 1]) + " is not among them");
    const std::uint64_t bytes = 8 * per * (e - k);
    if (!read_at(fd_, out + per * k, bytes, first_word + 8 * per * static_cast<std::uint64_t>(ids[k])))
      throw InputError(path_ + ": cannot read checkpoint: " + std::strerror(errno));
    bytes_read_ += bytes;
    k = e;
  }
}

void CheckpointParts::particles(const std::vector<int>& ids, Eigen::Matrix3Xd& x, Eigen::Matrix3Xd& v,
                                Eigen::VectorXd& inv_mass) const {
  const auto m = static_cast<Eigen::Index>(ids.size());
  x.resize(3, m);
  v.resize(3, m);
  inv_mass.resize(m);
  agree(&ranks_, [&] {
    rows(x_, 3, ids, x.data());
    rows(v_, 3, ids, v.data());
    rows(inv_mass_, 1, ids, inv_mass.data());
  });
}

std::vector<Eigen::Matrix3Xd> CheckpointParts::columns(const std::vector<int>& ids) const {
  std::vector<Eigen::Matrix3Xd> out(column_.size(), Eigen::Matrix3Xd(3, static_cast<Eigen::Index>(ids.size())));
  agree(&ranks_, [&] {
    for (std::size_t k = 0; k < column_.size(); ++k) rows(column_[k], 3, ids, out[k].data());
  });
  return out;
}

}  // namespace stiffmd
