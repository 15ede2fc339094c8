// Polymer builders and Maxwell–Boltzmann velocities (see builders.hpp for the contract).
#include "engine/scene/builders.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <random>
#include <sstream>
#include <stdexcept>
#include <string>

#include "core/format.hpp"
#include "core/portable_random.hpp"
#include "engine/scene/builder_geometry.hpp"

// No fused multiply-adds: contracting a*b+c changes the last bit, which can flip an accept/
// reject decision and so the whole configuration between machines. GCC in ISO mode (-std=c++20,
// as CMake builds us) does not contract; clang does by default.
#if defined(__clang__)
#pragma clang fp contract(off)
#endif

namespace stiffmd {
namespace {

using namespace portable;  // V3, Rng, portable_cbrt, …

// ---------------------------------------------------------------------------------------------
// Cell list over the beads placed so far, in wrapped coordinates (periodic axes: measured from
// the box origin, in [0, L)). Cells are at least `reach` wide (with a 1e-9 margin
// against rounding at cell faces), so every bead within `reach` of a point lies in the 3×3×3
// block around the point's cell. On an open axis the cell index is taken modulo the cell
// count: far-away beads may share a cell (looked at and dismissed by distance, harmless), while
// any two beads within `reach` still have cell indices at most 1 apart. Which beads are
// accepted never depends on the cell layout.
class CellGrid {
 public:
  CellGrid(const Box& box, const V3& start_lo, const V3& start_span, double extent, double reach, int n_beads)
      : cell_of_(static_cast<size_t>(n_beads), -1) {
    const double c_min = reach * (1.0 + 1e-9);
    const double max_cells = std::max(27.0, 4.0 * n_beads);  // memory ~ beads even for a tiny reach
    double prod = 1.0;
    for (int a = 0; a < 3; ++a) {
      periodic_[a] = box.periodic[a] != 0;
      lo_[a] = periodic_[a] ? 0.0 : at(start_lo, a) - extent;
      span_[a] = periodic_[a] ? box.lengths[a] : at(start_span, a) + 2.0 * extent;
      n_[a] = static_cast<int>(std::clamp(std::floor(span_[a] / c_min), 1.0, 1024.0));
      prod *= n_[a];
    }
    if (prod > max_cells) {  // coarser cells, still at least c_min wide
      const double f = portable_cbrt(prod / max_cells);
      for (int a = 0; a < 3; ++a) n_[a] = std::max(1, static_cast<int>(n_[a] / f));
    }
    for (int a = 0; a < 3; ++a) cell_[a] = std::max(span_[a] / n_[a], periodic_[a] ? 0.0 : c_min);
    cells_.resize(static_cast<size_t>(n_[0]) * n_[1] * n_[2]);
  }

  void insert(int i, const V3& p) {
    const int c = flat(index(0, p.x), index(1, p.y), index(2, p.z));
    cells_[c].push_back(i);
    cell_of_[i] = c;
  }

  void erase(int i) {
    std::vector<int>& cell = cells_[cell_of_[i]];
    auto it = std::find(cell.begin(), cell.end(), i);
    *it = cell.back();  // order within a cell does not matter
    cell.pop_back();
    cell_of_[i] = -1;
  }

  // Calls f(j) for the beads j in the block of cells around p (at least those within `reach`)
  // until f returns false; returns whether it ran to the end.
  template <class F>
  bool for_each_near(const V3& p, F&& f) const {
    int idx[3][3], cnt[3];
    for (int a = 0; a < 3; ++a) {
      const int k = index(a, at(p, a)), n = n_[a];
      if (n >= 3) {
        idx[a][0] = (k + n - 1) % n;
        idx[a][1] = k;
        idx[a][2] = (k + 1) % n;
        cnt[a] = 3;
      } else {  // one or two cells: visit each once
        for (int m = 0; m < n; ++m) idx[a][m] = m;
        cnt[a] = n;
      }
    }
    for (int ia = 0; ia < cnt[0]; ++ia)
      for (int ib = 0; ib < cnt[1]; ++ib)
        for (int ic = 0; ic < cnt[2]; ++ic)
          for (int j : cells_[flat(idx[0][ia], idx[1][ib], idx[2][ic])])
            if (!f(j)) return false;
    return true;
  }

 private:
  int index(int a, double x) const {
    if (periodic_[a]) return std::clamp(static_cast<int>(x / cell_[a]), 0, n_[a] - 1);
    const double w = x - lo_[a];
    const double k = std::floor(w / cell_[a]);
    const double n = n_[a];
    return static_cast<int>(k - n * std::floor(k / n));  // k mod n in [0, n)
  }
  int flat(int i, int j, int k) const { return (i * n_[1] + j) * n_[2] + k; }

  bool periodic_[3] = {false, false, false};
  double lo_[3] = {0, 0, 0}, span_[3] = {0, 0, 0}, cell_[3] = {1, 1, 1};
  int n_[3] = {1, 1, 1};
  std::vector<std::vector<int>> cells_;
  std::vector<int> cell_of_;
};

// ---------------------------------------------------------------------------------------------
// Growth plans: a molecule is a sequence of steps, each placing one bead bonded to an earlier
// one, so that backing off k beads is dropping the last k steps.
enum class StepKind {
  Start,   // the first bead: anywhere in the start region
  Walk,    // at bond_length from parent, uniform direction
  Bridge,  // at bond_length from parent, biased towards anchor, which it must reach in `remaining` bonds
  Close,   // at bond_length from both parent and partner (a ring's last bead)
};

struct Step {
  StepKind kind = StepKind::Start;
  int bead = 0;
  int parent = -1;
  int partner = -1;   // Close: the other tip of the ring
  int anchor = -1;    // Bridge: the other tip of the ring
  int remaining = 0;  // Bridge: bonds from this bead to anchor through the beads still to place
};

struct Plan {
  int first = 0, end = 0;          // the molecule's beads are [first, end)
  int ring = 0;                    // a ring's size (positions are cyclic), else 0
  std::vector<int> arm, position;  // per bead (index bead − first): its branch (−1: a star's
                                   // core, on every branch) and its place along the branch
  std::vector<Step> steps;
};

// The plan of an unbranched molecule (chain or ring) of n beads from `first`: one branch, beads
// placed in index order along it. Its steps are added by the builder.
Plan unbranched_plan(int first, int n, int ring) {
  Plan p;
  p.first = first;
  p.end = first + n;
  p.ring = ring;
  p.arm.assign(static_cast<size_t>(n), 0);
  for (int k = 0; k < n; ++k) p.position.push_back(k);
  return p;
}

// The effort per bead: up to kTrials random positions, of which the first kCandidates
// admissible ones compete (below). A molecule's first bead takes the first admissible of up to
// kStartTrials points: it has the whole start region to search.
constexpr int kTrials = 100;
constexpr int kStartTrials = 500;
constexpr int kCandidates = 32;
// Contacts are counted out to this multiple of min_distance, and within the own molecule only
// with beads at least this many bonds away along the same branch (or on another arm).
constexpr double kContactRange = 1.3;
constexpr int kSelfContactGap = 5;
// Failed steps allowed per attempt at a molecule before it starts again elsewhere, attempts
// before giving up, and failed steps in all before giving up, which bounds the time to fail
// (a few seconds for 10⁴ beads). The most a success needed, per bead, for 100 molecules at
// density 0.85 (8 seeds): chains of 100 0.03 at min_distance 0.85 and 0.13 at 0.94; rings of
// 100 0.18 at 0.85 and 0.36 at 0.88; stars of 4 × 25 0.15 at 0.9.
constexpr int kMaxAttempts = 4;
int failures_per_attempt(size_t steps) {
  return 200 + 4 * static_cast<int>(steps);
}
long long total_failure_budget(int n_beads) {
  return std::max(1000LL, static_cast<long long>(n_beads));
}

// Grows the molecules of a builder. Which admissible candidate wins: the one with the most
// contact, Σ (1 − r²/r_c²) over the beads within r_c = 1.3·min_distance. Taking the first
// admissible position instead leaves the box riddled with holes too small for a bead but too
// many to ignore, and at density 0.85 the last chains find no way through above min_distance
// ≈ 0.8; packing snugly keeps the free volume in one piece (measurements in builders.hpp).
// Beads fewer than kSelfContactGap bonds away along the same chain or arm do not count: the
// chain would otherwise curl up locally (counting every own bead made ⟨R²⟩/(Nℓ²) ≈ 0.9 in the
// 0.85 melt; counting none let one long chain never fill a box, and stars of 12 arms not pack
// their cores). What remains, in the 0.85 melt at min_distance 0.9, is a mild local
// stiffening, ⟨cos θ⟩ ≈ 0.32 between successive bonds against ≈ 0.2 for an unbiased walk with
// the same excluded volume, ⟨R²⟩/(Nℓ²) ≈ 1.8 for chains of 100 and ⟨R_g²⟩/(Nℓ²) ≈ 0.15 for
// rings of 100 — near the ideal values; equilibration refines them. A molecule with nothing
// near it (dilute, open space) walks unbiased.
class Grower {
 public:
  Grower(const char* who, const char* unit, const ChainSpec& spec, const Box& box, int n_beads, int beads_per_molecule)
      : who_(who),
        unit_(unit),
        box_(box),
        bond_(spec.bond_length),
        sigma_(spec.min_distance),
        sigma2_(spec.min_distance * spec.min_distance),
        contact2_(kContactRange * kContactRange * spec.min_distance * spec.min_distance),
        rng_(spec.seed),
        pos_(static_cast<size_t>(n_beads)),
        wrapped_(static_cast<size_t>(n_beads)),
        grid_(box, start_lo(box), start_span(box),
              // open axes: a random walk of n bonds rarely strays beyond 3√n bonds (only a cost if it does)
              3.0 * std::sqrt(static_cast<double>(beads_per_molecule)) * spec.bond_length + spec.min_distance,
              kContactRange * spec.min_distance, n_beads) {}

  // Grows every plan, all molecules together (one step each per round); returns the positions.
  std::vector<V3> run(const std::vector<Plan>& plans) {
    const size_t nm = plans.size();
    std::vector<size_t> done(nm, 0), best(nm, 0);
    std::vector<int> stuck(nm, 0), failures(nm, 0), attempts(nm, 1);
    const long long budget = total_failure_budget(static_cast<int>(pos_.size()));
    long long total_failures = 0;
    size_t incomplete = nm;
    while (incomplete > 0) {
      for (size_t m = 0; m < nm; ++m) {
        const std::vector<Step>& steps = plans[m].steps;
        if (done[m] == steps.size()) continue;
        own_first_ = plans[m].first;
        own_end_ = plans[m].end;
        ring_ = plans[m].ring;
        arm_ = plans[m].arm.data();
        position_ = plans[m].position.data();
        const int bead = steps[done[m]].bead - own_first_;
        cur_arm_ = arm_[bead];
        cur_position_ = position_[bead];
        if (try_step(steps[done[m]])) {
          if (++done[m] > best[m]) {  // new ground: forget how stuck we were
            best[m] = done[m];
            stuck[m] = 0;
          }
          if (done[m] == steps.size()) --incomplete;
          continue;
        }
        // A dead end: back off one bead, then further the longer this spot resists.
        if (++total_failures > budget) fail(m, nm, total_failures);
        ++stuck[m];
        size_t back = std::min(static_cast<size_t>(stuck[m]), done[m]);
        if (++failures[m] > failures_per_attempt(steps.size())) {  // start this molecule afresh
          if (++attempts[m] > kMaxAttempts) fail(m, nm, total_failures);
          back = done[m];
          best[m] = 0;
          stuck[m] = 0;
          failures[m] = 0;
        }
        for (; back > 0; --back) grid_.erase(steps[--done[m]].bead);
      }
    }
    return pos_;
  }

 private:
  static V3 start_lo(const Box& box) {
    V3 lo;
    for (int a = 0; a < 3; ++a) at(lo, a) = box.periodic[a] ? box.origin[a] : box.origin[a] - 0.5 * box.lengths[a];
    return lo;
  }
  static V3 start_span(const Box& box) { return {box.lengths[0], box.lengths[1], box.lengths[2]}; }

  [[noreturn]] void fail(size_t m, size_t nm, long long failures) const {
    std::ostringstream msg;
    msg << who_ << ": could not place " << unit_ << ' ' << m << " (0-based, of " << nm << "; gave up after " << failures
        << " dead ends in all): too crowded for min_distance = " << sigma_ << " with bond_length = " << bond_
        << "; lower the density or min_distance (a soft-pair push-off can relax closer contacts afterwards)";
    throw std::runtime_error(msg.str());
  }

  // Periodic axes: the coordinate measured from the origin, wrapped into [0, L); open axes: as is.
  V3 wrap(V3 p) const { return wrap_into_cell(box_, p); }
  V3 min_image_wrapped(V3 d) const { return min_image_of_wrapped(box_, d); }

  // Does a bead of the growing molecule (index within it) count as a contact for the bead being
  // placed: on another arm of a star, or at least kSelfContactGap bonds away along the branch?
  bool far_along_own(int k) const {
    if (arm_[k] >= 0 && cur_arm_ >= 0 && arm_[k] != cur_arm_) return true;
    int gap = std::abs(position_[k] - cur_position_);
    if (ring_ > 0) gap = std::min(gap, ring_ - gap);
    return gap >= kSelfContactGap;
  }

  // Is p (wrapped: pw) at least min_distance from every placed bead other than its bonded ones
  // (skip1, skip2)? If so, `contact` is its contact with its surroundings (class comment).
  bool admissible(const V3& pw, int skip1, int skip2, double& contact) const {
    contact = 0.0;
    if (sigma2_ == 0.0) return true;
    return grid_.for_each_near(pw, [&](int j) {
      if (j == skip1 || j == skip2) return true;
      const V3 d = min_image_wrapped(pw - wrapped_[j]);
      const double r2 = dot(d, d);
      if (r2 < sigma2_) return false;
      if (r2 < contact2_ && (j < own_first_ || j >= own_end_ || far_along_own(j - own_first_)))
        contact += 1.0 - r2 / contact2_;
      return true;
    });
  }

  // Draws up to `trials` positions from `candidate`; of the first `candidates` admissible ones
  // places the one with the most contact (the first of equals). False if none was admissible.
  template <class Candidate>
  bool place_best(const Step& s, int skip2, int trials, int candidates, Candidate&& candidate) {
    double best = -1.0;
    V3 best_p, best_w;
    int admitted = 0;
    for (int t = 0; t < trials && admitted < candidates; ++t) {
      const V3 p = candidate(), pw = wrap(p);
      double contact = 0.0;
      if (!admissible(pw, s.parent, skip2, contact)) continue;
      ++admitted;
      if (contact > best) {
        best = contact;
        best_p = p;
        best_w = pw;
      }
    }
    if (admitted == 0) return false;
    pos_[s.bead] = best_p;
    wrapped_[s.bead] = best_w;
    grid_.insert(s.bead, best_w);
    return true;
  }

  bool try_step(const Step& s) {
    switch (s.kind) {
      case StepKind::Start:  // the first admissible point: starts spread evenly, not in clumps
        return place_best(s, -1, kStartTrials, 1, [&] {
          V3 p;
          for (int a = 0; a < 3; ++a) {
            const double u = rng_.uniform();
            at(p, a) =
                box_.periodic[a] ? box_.origin[a] + box_.lengths[a] * u : box_.origin[a] + box_.lengths[a] * (u - 0.5);
          }
          return p;
        });
      case StepKind::Walk:
        return place_best(s, -1, kTrials, kCandidates, [&] { return pos_[s.parent] + bond_ * rng_.unit_vector(); });
      case StepKind::Bridge:
        return bridge_step(s);
      case StepKind::Close:
        return close_step(s);
    }
    return false;
  }

  // The next bead of a ring, at bond_length from its parent (one tip). The m bonds left must
  // still span the gap to the other tip, the anchor: |x_new − x_anchor| ≤ m·ℓ, i.e. u·d̂ ≥ c
  // with d = x_anchor − x_parent.
  // Within that cap the direction follows the Gaussian bridge of a freely jointed chain,
  // p(u) ∝ exp(−3|d − ℓu|²/(2mℓ²)) ∝ exp(κ u·d̂), κ = 3|d|/(mℓ): a von Mises–Fisher law
  // whose cosine w = u·d̂ is sampled exactly by inverting its CDF on [c, 1]. (Pulling twice as
  // hard lets rings of 100 reach min_distance 0.9 in the 0.85 melt, at ~10% smaller R_g²; we
  // keep the free bridge.)
  bool bridge_step(const Step& s) {
    const V3 origin = pos_[s.parent];
    const V3 d = pos_[s.anchor] - origin;
    const double dist = std::sqrt(dot(d, d)), reach = s.remaining * bond_;
    V3 axis{0, 0, 1}, e1{1, 0, 0}, e2{0, 1, 0};
    double c = -1.0, kappa = 0.0;
    if (dist > 0.0) {  // the parent is the anchor itself for the ring's second bead: no bias
      axis = (1.0 / dist) * d;
      perpendicular_basis(axis, e1, e2);
      c = std::clamp((bond_ * bond_ + dist * dist - reach * reach) / (2.0 * bond_ * dist), -1.0, 1.0);
      kappa = 3.0 * dist / reach;
    }
    const double tail = portable_exp(-kappa * (1.0 - c));  // e^{κ(c−1)}: the CDF's lower end
    return place_best(s, -1, kTrials, kCandidates, [&] {
      const double xi = 1.0 - rng_.uniform();  // (0, 1]
      double w = kappa * (1.0 - c) < 1e-12 ? c + (1.0 - c) * xi : 1.0 + portable_log(xi + (1.0 - xi) * tail) / kappa;
      w = std::clamp(w, c, 1.0);
      double cs = 0.0, sn = 0.0;
      rng_.unit_circle(cs, sn);
      const double r = std::sqrt(std::max(0.0, 1.0 - w * w));
      return origin + bond_ * (w * axis + (r * cs) * e1 + (r * sn) * e2);
    });
  }

  // A ring's last bead: on the circle of points at bond_length from both tips (they are at
  // most 2ℓ apart by the bridge constraint), at a uniform random angle.
  bool close_step(const Step& s) {
    const V3 a = pos_[s.parent], b = pos_[s.partner];
    const V3 d = b - a;
    const double dist = std::sqrt(dot(d, d));
    if (!(dist > 0.0)) return false;  // neighbours on top of each other (only possible with min_distance 0)
    const V3 mid = a + 0.5 * d;
    const double radius = std::sqrt(std::max(0.0, bond_ * bond_ - 0.25 * dist * dist));
    V3 e1, e2;
    perpendicular_basis((1.0 / dist) * d, e1, e2);
    return place_best(s, s.partner, kTrials, kCandidates, [&] {
      double cs = 0.0, sn = 0.0;
      rng_.unit_circle(cs, sn);
      return mid + (radius * cs) * e1 + (radius * sn) * e2;
    });
  }

  const char* who_;
  const char* unit_;
  Box box_;
  double bond_, sigma_, sigma2_, contact2_;
  Rng rng_;
  std::vector<V3> pos_;      // unwrapped positions (the output)
  std::vector<V3> wrapped_;  // the same, wrapped (see wrap): what the distance checks use
  CellGrid grid_;
  // The growing molecule and bead, for far_along_own.
  int own_first_ = 0, own_end_ = 0, ring_ = 0, cur_arm_ = 0, cur_position_ = 0;
  const int* arm_ = nullptr;
  const int* position_ = nullptr;
};

// ---------------------------------------------------------------------------------------------
// Validation shared by the builders.
[[noreturn]] void invalid(const char* who, const std::string& what) {
  throw std::invalid_argument(std::string(who) + ": " + what);
}

void validate(const char* who, const ChainSpec& spec, int min_beads, const Box& box, long long total_beads) {
  if (spec.chains < 1) invalid(who, "chains = " + std::to_string(spec.chains) + ": expected at least 1");
  if (spec.beads < min_beads)
    invalid(who, "beads = " + std::to_string(spec.beads) + ": expected at least " + std::to_string(min_beads));
  if (!(spec.bond_length > 0.0) || !std::isfinite(spec.bond_length))
    invalid(who, "bond_length = " + format_number(spec.bond_length) + ": expected a finite length > 0");
  if (!(spec.min_distance >= 0.0) || !(spec.min_distance < 2.0 * spec.bond_length))
    invalid(who, "min_distance = " + format_number(spec.min_distance) +
                     ": expected 0 <= min_distance < 2*bond_length = " + format_number(2.0 * spec.bond_length) +
                     " (beads two bonds apart are at most 2*bond_length apart)");
  if (total_beads > std::numeric_limits<int>::max())
    invalid(who, "too many beads (" + std::to_string(total_beads) + ")");
  bool point_region = true;
  for (int a = 0; a < 3; ++a) {
    const char axis = static_cast<char>('x' + a);
    if (!std::isfinite(box.origin[a])) invalid(who, std::string("box origin is not finite on axis ") + axis);
    if (!std::isfinite(box.lengths[a]) || box.lengths[a] < 0.0)
      invalid(who,
              std::string("box length on axis ") + axis + " = " + format_number(box.lengths[a]) + ": expected >= 0");
    if (box.periodic[a] && !(box.lengths[a] > 2.0 * spec.bond_length))
      invalid(who, std::string("periodic box length on axis ") + axis + " = " + format_number(box.lengths[a]) +
                       ": expected more than 2*bond_length = " + format_number(2.0 * spec.bond_length) +
                       " (so that the minimum image of a bond is the bond)");
    if (box.lengths[a] > 0.0) point_region = false;
  }
  if (point_region && spec.chains > 1 && spec.min_distance > 0.0)
    invalid(who, std::to_string(spec.chains) +
                     " molecules but the start region is a single point (open box with zero lengths): give the box "
                     "lengths (a region around the origin) or a density");
}

// Every (i, j, k) with i–j and j–k bonded, each pair of j's neighbours once, by vertex j; the
// neighbours in the order the bonds list them: (j−1, j, j+1) along a chain, (1, 0, n−1) at a
// ring's first bead, arms in order at a star's core.
std::vector<std::array<int, 3>> angles_from_bonds(int n, const std::vector<std::pair<int, int>>& bonds) {
  std::vector<std::vector<int>> nb(static_cast<size_t>(n));
  for (const auto& [i, j] : bonds) {
    nb[i].push_back(j);
    nb[j].push_back(i);
  }
  std::vector<std::array<int, 3>> angles;
  for (int j = 0; j < n; ++j)
    for (size_t p = 0; p < nb[j].size(); ++p)
      for (size_t q = p + 1; q < nb[j].size(); ++q) angles.push_back({nb[j][p], j, nb[j][q]});
  return angles;
}

// Every (i, j, k, l) about each bond j–k (in bond order), i a neighbour of j other than k, l a
// neighbour of k other than j and i (a 3-ring has none).
std::vector<std::array<int, 4>> dihedrals_from_bonds(int n, const std::vector<std::pair<int, int>>& bonds) {
  std::vector<std::vector<int>> nb(static_cast<size_t>(n));
  for (const auto& [i, j] : bonds) {
    nb[i].push_back(j);
    nb[j].push_back(i);
  }
  std::vector<std::array<int, 4>> out;
  for (const auto& [j, k] : bonds)
    for (const int i : nb[j])
      for (const int l : nb[k])
        if (i != k && l != j && i != l) out.push_back({i, j, k, l});
  return out;
}

Polymer assemble(const std::vector<V3>& pos, std::vector<std::pair<int, int>> bonds, std::vector<int> molecule) {
  Polymer p;
  const int n = static_cast<int>(pos.size());
  p.x.resize(3, n);
  for (int i = 0; i < n; ++i) p.x.col(i) << pos[i].x, pos[i].y, pos[i].z;
  p.angles = angles_from_bonds(n, bonds);
  p.dihedrals = dihedrals_from_bonds(n, bonds);
  p.bonds = std::move(bonds);
  p.molecule = std::move(molecule);
  return p;
}

}  // namespace

void validate_chain_spec(const char* who, const ChainSpec& spec, int min_beads, const Box& box, long long total_beads) {
  validate(who, spec, min_beads, box, total_beads);
}

// ---------------------------------------------------------------------------------------------

Polymer build_linear_chains(const ChainSpec& spec, const Box& box) {
  const char* who = "build_linear_chains";
  const long long total = static_cast<long long>(spec.chains) * spec.beads;
  validate(who, spec, 2, box, total);
  const int n = spec.beads;
  std::vector<Plan> plans(static_cast<size_t>(spec.chains));
  std::vector<std::pair<int, int>> bonds;
  std::vector<int> molecule;
  for (int c = 0; c < spec.chains; ++c) {
    const int first = c * n;
    plans[c] = unbranched_plan(first, n, 0);
    std::vector<Step>& steps = plans[c].steps;
    steps.push_back({StepKind::Start, first});
    for (int k = 1; k < n; ++k) {
      steps.push_back({StepKind::Walk, first + k, first + k - 1});
      bonds.emplace_back(first + k - 1, first + k);
    }
    molecule.insert(molecule.end(), static_cast<size_t>(n), c);
  }
  Grower grower(who, "chain", spec, box, static_cast<int>(total), n);
  return assemble(grower.run(plans), std::move(bonds), std::move(molecule));
}

Polymer build_rings(const ChainSpec& spec, const Box& box) {
  const char* who = "build_rings";
  const long long total = static_cast<long long>(spec.chains) * spec.beads;
  validate(who, spec, 3, box, total);
  const int n = spec.beads;
  std::vector<Plan> plans(static_cast<size_t>(spec.chains));
  std::vector<std::pair<int, int>> bonds;
  std::vector<int> molecule;
  for (int c = 0; c < spec.chains; ++c) {
    const int first = c * n;
    plans[c] = unbranched_plan(first, n, n);
    std::vector<Step>& steps = plans[c].steps;
    // Two tips grow from bead 0 in turn, 1, n−1, 2, n−2, …, each bridged to the other tip, and
    // the last bead closes the gap between them wherever they meet: a closure tied to bead 0's
    // neighbourhood, which the other molecules fill meanwhile, fails far more often in a melt.
    steps.push_back({StepKind::Start, first});
    int up = 0, down = n, gap = n - 1;  // tips (down ≡ 0 mod n) and beads not yet placed
    for (bool rising = true; gap > 1; rising = !rising, --gap) {
      if (rising) {
        ++up;
        steps.push_back({StepKind::Bridge, first + up, first + up - 1, -1, first + down % n, gap});
      } else {
        --down;
        steps.push_back({StepKind::Bridge, first + down, first + (down + 1) % n, -1, first + up, gap});
      }
    }
    steps.push_back({StepKind::Close, first + up + 1, first + up, first + (up + 2) % n});
    for (int k = 1; k < n; ++k) bonds.emplace_back(first + k - 1, first + k);
    bonds.emplace_back(first + n - 1, first);
    molecule.insert(molecule.end(), static_cast<size_t>(n), c);
  }
  Grower grower(who, "ring", spec, box, static_cast<int>(total), n);
  return assemble(grower.run(plans), std::move(bonds), std::move(molecule));
}

Polymer build_stars(const ChainSpec& spec, int arms, const Box& box) {
  const char* who = "build_stars";
  if (arms < 1 || arms > kMaxStarArms)
    invalid(who, "arms = " + std::to_string(arms) + ": expected 1 .. " + std::to_string(kMaxStarArms) +
                     " (a core with n arms has n(n - 1)/2 angles)");
  const long long per_star = 1 + static_cast<long long>(arms) * spec.beads;
  const long long total = spec.chains * per_star;
  validate(who, spec, 1, box, total);
  // The first beads of the arms lie on the sphere of radius bond_length around the core, at least
  // min_distance apart: disjoint caps of angular radius asin(min_distance / (2 bond_length))
  // around them bound their number by 2 / (1 − cos of that angle). Past the bound the star can
  // never be placed; say so now instead of exhausting the growth's failure budget.
  if (spec.min_distance > 0.0) {
    const double most = 2.0 / (1.0 - std::cos(std::asin(spec.min_distance / (2.0 * spec.bond_length))));
    if (arms > most)
      invalid(who, "arms = " + std::to_string(arms) + ": at most " + format_number(std::floor(most)) +
                       " arms fit around a core with bond_length = " + format_number(spec.bond_length) +
                       " and min_distance = " + format_number(spec.min_distance) +
                       "; expected fewer arms or a smaller min_distance");
  }
  const int b = spec.beads, size = static_cast<int>(per_star);
  std::vector<Plan> plans(static_cast<size_t>(spec.chains));
  std::vector<std::pair<int, int>> bonds;
  std::vector<int> molecule;
  for (int c = 0; c < spec.chains; ++c) {
    const int core = c * size;
    auto bead = [&](int arm, int k) { return core + 1 + arm * b + k; };
    std::vector<Step>& steps = plans[c].steps;
    plans[c].first = core;
    plans[c].end = core + size;
    plans[c].arm.push_back(-1);  // the core: position 0 on every arm
    plans[c].position.push_back(0);
    for (int a = 0; a < arms; ++a)
      for (int k = 0; k < b; ++k) {
        plans[c].arm.push_back(a);
        plans[c].position.push_back(k + 1);
      }
    steps.push_back({StepKind::Start, core});
    for (int k = 0; k < b; ++k)  // arms in turn, one bead each
      for (int a = 0; a < arms; ++a) steps.push_back({StepKind::Walk, bead(a, k), k == 0 ? core : bead(a, k - 1)});
    for (int a = 0; a < arms; ++a)
      for (int k = 0; k < b; ++k) bonds.emplace_back(k == 0 ? core : bead(a, k - 1), bead(a, k));
    molecule.insert(molecule.end(), static_cast<size_t>(size), c);
  }
  Grower grower(who, "star", spec, box, static_cast<int>(total), b);
  return assemble(grower.run(plans), std::move(bonds), std::move(molecule));
}

Box box_for_density(int total_beads, double density) {
  if (total_beads < 1)
    throw std::invalid_argument("box_for_density: total_beads = " + std::to_string(total_beads) +
                                ": expected at least 1");
  if (!(density > 0.0) || !std::isfinite(density))
    throw std::invalid_argument("box_for_density: density = " + format_number(density) +
                                ": expected a finite number density > 0");
  const double volume = total_beads / density;
  if (!std::isfinite(volume))
    throw std::invalid_argument("box_for_density: density = " + format_number(density) + " is too small");
  Box box;
  box.lengths.setConstant(portable_cbrt(volume));
  box.periodic.setOnes();
  return box;
}

}  // namespace stiffmd
