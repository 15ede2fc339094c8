// Linear chains built molecule by molecule (see chains_by_molecule.hpp for the contract).
#include "engine/scene/chains_by_molecule.hpp"

#include <algorithm>
#include <cmath>
#include <stdexcept>
#include <string>

#include "core/format.hpp"
#include "core/molecule_anchor.hpp"
#include "core/portable_random.hpp"
#include "engine/scene/builder_geometry.hpp"

// No fused multiply-adds (builders.cpp): an accept/reject decision must not move with the compiler.
#if defined(__clang__)
#pragma clang fp contract(off)
#endif

namespace stiffmd {
namespace {

using namespace portable;  // V3, Rng, dot, at

std::uint64_t mix64(std::uint64_t z) {  // splitmix64's finaliser (Steele, Lea & Flood 2014)
  z = (z ^ (z >> 30)) * 0xbf58476d1ce4e5b9ULL;
  z = (z ^ (z >> 27)) * 0x94d049bb133111ebULL;
  return z ^ (z >> 31);
}
constexpr std::uint64_t kGolden = 0x9e3779b97f4a7c15ULL;

// The effort per bead and per molecule, as the other builders' (builders.cpp): up to kTrials
// directions per bead; a molecule that fails more than 200 + 4 n steps starts again from a new
// first bead, up to kMaxAttempts times.
constexpr int kTrials = 100;
constexpr int kMaxAttempts = 4;

// The beads of the molecule being grown, hashed by cells at least min_distance wide in wrapped
// coordinates, so that a new bead is checked against the few beads near it: O(n) per chain of n,
// whatever the box. Beads leave in the reverse order they came (backing off drops the last ones),
// so each cell's list is a stack: a bead is pushed on its cell's head and popped from it.
// Which beads are accepted never depends on the cells (a bead is refused if any bead is too close).
class OwnBeads {
 public:
  OwnBeads(const Box& box, double reach, int beads) : next_(static_cast<size_t>(beads)), slot_(next_.size()) {
    const double c_min = reach * (1.0 + 1e-9);
    for (int a = 0; a < 3; ++a) {
      periodic_[a] = box.periodic[a] != 0;
      if (periodic_[a]) {
        n_[a] = std::max(1L, static_cast<long>(std::min(box.lengths[a] / c_min, 1e15)));
        cell_[a] = box.lengths[a] / static_cast<double>(n_[a]);
      } else {
        cell_[a] = c_min;
      }
    }
    size_t cap = 64;
    while (cap < 4 * next_.size()) cap *= 2;
    table_.resize(cap);
  }

  void clear() {
    for (size_t s : used_) table_[s] = Entry{};
    used_.clear();
  }

  // Cells emptied by backing off keep their slots: past half the table, forget them (clear, then
  // push the beads still placed again, in order).
  bool crowded() const { return 2 * used_.size() > table_.size(); }

  void push(int k, const V3& w) {
    const size_t s = insert(cell_of(w));
    next_[k] = table_[s].head;
    table_[s].head = k;
    slot_[k] = s;
  }

  void pop(int k) {  // k is the last bead pushed, so the head of its cell
    table_[slot_[k]].head = next_[k];
  }

  // Is no bead but `skip` within sqrt(sigma2) of w (minimum image; wrapped: the beads' wrapped positions)?
  template <class MinImage>
  bool clear_of(const V3& w, int skip, double sigma2, const std::vector<V3>& wrapped, MinImage&& min_image) const {
    const Cell c = cell_of(w);
    long idx[3][3];
    int cnt[3];
    for (int a = 0; a < 3; ++a) {
      const long n = n_[a];
      if (!periodic_[a]) {
        for (int d = 0; d < 3; ++d) idx[a][d] = c[a] + d - 1;
        cnt[a] = 3;
      } else if (n >= 3) {
        idx[a][0] = (c[a] + n - 1) % n, idx[a][1] = c[a], idx[a][2] = (c[a] + 1) % n;
        cnt[a] = 3;
      } else {  // one or two cells: each once
        for (long m = 0; m < n; ++m) idx[a][m] = m;
        cnt[a] = static_cast<int>(n);
      }
    }
    for (int i = 0; i < cnt[0]; ++i)
      for (int j = 0; j < cnt[1]; ++j)
        for (int k = 0; k < cnt[2]; ++k) {
          const size_t s = find({idx[0][i], idx[1][j], idx[2][k]});
          if (s == kNone) continue;
          for (int b = table_[s].head; b >= 0; b = next_[b]) {
            if (b == skip) continue;
            const V3 d = min_image(w - wrapped[b]);
            if (dot(d, d) < sigma2) return false;
          }
        }
    return true;
  }

 private:
  using Cell = std::array<long, 3>;
  struct Entry {
    Cell cell{0, 0, 0};
    int head = -1;
    bool used = false;
  };
  static constexpr size_t kNone = static_cast<size_t>(-1);

  Cell cell_of(const V3& w) const {
    Cell c{};
    for (int a = 0; a < 3; ++a) {
      const double x = at(w, a) / cell_[a];
      c[a] = periodic_[a] ? std::clamp(static_cast<long>(x), 0L, n_[a] - 1) : static_cast<long>(std::floor(x));
    }
    return c;
  }

  // The slot holding the cell, or the empty slot where it would go (linear probing).
  size_t probe(const Cell& c) const {
    const std::uint64_t h = mix64(static_cast<std::uint64_t>(c[0]) * 0x9e3779b97f4a7c15ULL ^
                                  static_cast<std::uint64_t>(c[1]) * 0xc2b2ae3d27d4eb4fULL ^
                                  static_cast<std::uint64_t>(c[2]) * 0x165667b19e3779f9ULL);
    const size_t mask = table_.size() - 1;
    size_t s = h & mask;
    while (table_[s].used && table_[s].cell != c) s = (s + 1) & mask;
    return s;
  }
  size_t find(const Cell& c) const {
    const size_t s = probe(c);
    return table_[s].used ? s : kNone;
  }
  size_t insert(const Cell& c) {
    const size_t s = probe(c);
    if (!table_[s].used) {
      table_[s].used = true;
      table_[s].cell = c;
      used_.push_back(s);
    }
    return s;
  }

  bool periodic_[3] = {false, false, false};
  long n_[3] = {1, 1, 1};
  double cell_[3] = {1, 1, 1};
  std::vector<Entry> table_;
  std::vector<size_t> used_;  // the slots in use, to clear
  std::vector<int> next_;
  std::vector<size_t> slot_;
};

// Grows one molecule at a time into its own arrays (reused from molecule to molecule).
class ChainGrower {
 public:
  ChainGrower(const ChainSpec& spec, const Box& box)
      : spec_(spec),
        box_(box),
        sigma2_(spec.min_distance * spec.min_distance),
        pos_(static_cast<size_t>(spec.beads)),
        wrapped_(pos_.size()),
        own_(box, spec.min_distance > 0.0 ? spec.min_distance : spec.bond_length, spec.beads) {}

  // Molecule m's beads, unwrapped: bead k at pos()[k].
  const std::vector<V3>& grow(int m) {
    Rng rng(molecule_stream_key(spec_.seed, m));
    const int n = spec_.beads;
    const int per_attempt = 200 + 4 * n;
    own_.clear();
    int done = 0, best = 0, stuck = 0, failures = 0, attempts = 1;
    while (done < n) {
      if (place(rng, done)) {
        if (own_.crowded()) {
          own_.clear();
          for (int k = 0; k < done; ++k) own_.push(k, wrapped_[k]);
        }
        own_.push(done, wrapped_[done]);
        if (++done > best) best = done, stuck = 0;  // new ground: forget how stuck we were
        continue;
      }
      // A dead end: back off one bead, then further the longer this spot resists.
      int back = std::min(++stuck, done);
      if (++failures > per_attempt) {  // start this molecule afresh
        if (++attempts > kMaxAttempts) fail(m);
        back = done, best = 0, stuck = 0, failures = 0;
      }
      for (; back > 0; --back) own_.pop(--done);
    }
    return pos_;
  }

 private:
  [[noreturn]] void fail(int m) const {
    throw std::runtime_error("build_linear_chains_by_molecule: could not grow chain " + std::to_string(m) +
                             " (0-based) of " + std::to_string(spec_.beads) +
                             " beads without two of its beads closer " +
                             "than min_distance = " + format_number(spec_.min_distance) + " after " +
                             std::to_string(kMaxAttempts) + " attempts; lower min_distance");
  }

  // Bead k: the first bead uniform in the start region (builders.hpp); the others the first of up
  // to kTrials positions at bond_length from bead k − 1 in a uniform direction that keeps
  // min_distance from every own bead but k − 1.
  bool place(Rng& rng, int k) {
    if (k == 0) {
      V3 p;
      for (int a = 0; a < 3; ++a) {
        const double u = rng.uniform();
        at(p, a) =
            box_.periodic[a] ? box_.origin[a] + box_.lengths[a] * u : box_.origin[a] + box_.lengths[a] * (u - 0.5);
      }
      pos_[0] = p, wrapped_[0] = wrap(p);
      return true;
    }
    for (int t = 0; t < kTrials; ++t) {
      const V3 p = pos_[k - 1] + spec_.bond_length * rng.unit_vector(), w = wrap(p);
      if (sigma2_ > 0.0 &&
          !own_.clear_of(w, k - 1, sigma2_, wrapped_, [this](const V3& d) { return min_image_wrapped(d); }))
        continue;
      pos_[k] = p, wrapped_[k] = w;
      return true;
    }
    return false;
  }

  // Periodic axes: measured from the origin, wrapped into [0, L); open axes: as is (builders.cpp).
  V3 wrap(V3 p) const { return wrap_into_cell(box_, p); }
  V3 min_image_wrapped(V3 d) const { return min_image_of_wrapped(box_, d); }

  ChainSpec spec_;
  Box box_;
  double sigma2_;
  std::vector<V3> pos_, wrapped_;
  OwnBeads own_;
};

void validate(const ChainSpec& spec, const Box& box) {
  validate_chain_spec("build_linear_chains_by_molecule", spec, 2, box,
                      static_cast<long long>(spec.chains) * spec.beads);
}

// The molecule's anchor (core/molecule_anchor.hpp) over the columns [first, first + n) of x.
Eigen::Vector3d centre_of_mass(const Eigen::Matrix3Xd& x, Eigen::Index first, int n, double mass) {
  MoleculeAnchor anchor;
  for (Eigen::Index g = first; g < first + n; ++g) anchor.add(mass, x.col(g));
  return anchor.value();
}

}  // namespace

std::uint64_t molecule_stream_key(std::uint64_t seed, int molecule) {
  return mix64(mix64(seed + kGolden) + static_cast<std::uint64_t>(molecule) * kGolden);
}

BuiltMolecules build_linear_chains_by_molecule(const ChainSpec& spec, const Box& box,
                                               const std::function<bool(int)>& wanted, double inv_mass) {
  validate(spec, box);
  std::vector<int> molecules;
  for (int m = 0; m < spec.chains; ++m)
    if (wanted(m)) molecules.push_back(m);
  const int n = spec.beads, count = static_cast<int>(molecules.size());
  const double mass = anchor_mass(inv_mass);
  BuiltMolecules out;
  out.x.resize(3, static_cast<Eigen::Index>(count) * n);
  out.anchors.resize(3, count);
  out.global.reserve(static_cast<size_t>(count) * n);
  out.molecule.reserve(out.global.capacity());
  out.bonds.reserve(static_cast<size_t>(count) * (n - 1));
  out.angles.reserve(static_cast<size_t>(count) * std::max(0, n - 2));
  out.dihedrals.reserve(static_cast<size_t>(count) * std::max(0, n - 3));
  ChainGrower grower(spec, box);
  for (int c = 0; c < count; ++c) {
    const int m = molecules[static_cast<size_t>(c)];
    const std::vector<V3>& pos = grower.grow(m);
    const Eigen::Index col = static_cast<Eigen::Index>(c) * n;
    const int g0 = m * n;
    for (int k = 0; k < n; ++k) {
      out.x.col(col + k) << pos[k].x, pos[k].y, pos[k].z;
      out.global.push_back(g0 + k);
      out.molecule.push_back(m);
    }
    out.anchors.col(c) = centre_of_mass(out.x, col, n, mass);
    // The whole build's items of this chain in the whole build's order (builders.cpp's
    // angles_from_bonds and dihedrals_from_bonds on a chain).
    for (int k = 1; k < n; ++k) out.bonds.emplace_back(g0 + k - 1, g0 + k);
    for (int k = 1; k + 1 < n; ++k) out.angles.push_back({g0 + k - 1, g0 + k, g0 + k + 1});
    for (int k = 1; k + 2 < n; ++k) out.dihedrals.push_back({g0 + k - 1, g0 + k, g0 + k + 1, g0 + k + 2});
  }
  out.molecules = std::move(molecules);
  return out;
}

BuiltMolecules build_linear_chains_by_molecule(const ChainSpec& spec, const Box& box, int first, int end,
                                               double inv_mass) {
  return build_linear_chains_by_molecule(
      spec, box, [first, end](int m) { return m >= first && m < end; }, inv_mass);
}

Eigen::Matrix3Xd chain_anchors_by_molecule(const ChainSpec& spec, const Box& box, double inv_mass) {
  validate(spec, box);
  const int n = spec.beads;
  const double mass = anchor_mass(inv_mass);
  Eigen::Matrix3Xd anchors(3, spec.chains), x(3, n);
  ChainGrower grower(spec, box);
  for (int m = 0; m < spec.chains; ++m) {
    const std::vector<V3>& pos = grower.grow(m);
    for (int k = 0; k < n; ++k) x.col(k) << pos[k].x, pos[k].y, pos[k].z;
    anchors.col(m) = centre_of_mass(x, 0, n, mass);
  }
  return anchors;
}

Polymer build_linear_chains_by_molecule(const ChainSpec& spec, const Box& box) {
  BuiltMolecules b = build_linear_chains_by_molecule(spec, box, [](int) { return true; });
  Polymer p;
  p.x = std::move(b.x);
  p.bonds = std::move(b.bonds);
  p.angles = std::move(b.angles);
  p.dihedrals = std::move(b.dihedrals);
  p.molecule = std::move(b.molecule);
  return p;
}

}  // namespace stiffmd
