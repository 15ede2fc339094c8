// Neighbour search for short-range pair styles: cell lists and a half Verlet list with a skin
// (Allen & Tildesley, "Computer Simulation of Liquids", 2nd ed., §5.3), and the special-bond
// weights of bonded neighbours (LAMMPS `special_bonds lj w12 w13 w14`).
//
// The list holds every pair i < j whose minimum-image distance was < cutoff + skin when it was
// built. It is valid while every pair now closer than the cutoff is in it. Particles that moved
// D_i, D_j since the build approached each other by at most D_i + D_j, so a pair not listed is
// still beyond the cutoff while D_i + D_j ≤ skin: the list is valid while no particle moved more
// than skin/2 (Allen & Tildesley's rule). `update` goes further before rebuilding: while no particle
// moved more than the skin, only pairs with a "fast" particle (D > skin/2) can have come within
// the cutoff unlisted, and it checks those directly — each fast particle against the particles
// of the build's cells around its current position (every particle within the cutoff of it now
// sat there at the build: it moved at most skin, and a cell is at least cutoff + skin wide) — and
// rebuilds if one such pair is not listed, if a particle moved more than the skin, or when the
// fast particles are too many for the check to stay cheap (more than 1/256 of all; checking that
// many takes ≈ 1 % of a build's distance tests).
//
// Ghosts (set_ghosts): under domain decomposition a rank holds its own particles and copies of
// other ranks' particles near its domain, the ghosts, whose forces it ignores. A pair of two
// ghosts then only costs time, so it is never listed, nor tested: the cells hold their owned
// particles first, then their ghosts; an owned particle's row is searched as without ghosts, a
// ghost's only against the owned particles of the forward cells, each pair as the search without
// ghosts tests it. Every other pair is listed, as without ghosts: the list is the one without
// ghosts less its pairs of two ghosts, row by row. With the ghost pairs once (set_ghost_pairs_once:
// a decomposed run whose pairs of an owned particle and a ghost are computed on one rank only, the
// ghost's forces sent back) a pair i < j with ghost i is left out too: the rows of the ghosts are
// empty, so of a pair of two ranks' owned particles only the rank owning the lower index (the
// particle sets are in increasing global index) lists it.
//
// Each row is sorted (increasing j), and the pair loop reads positions wrapped at the call: a
// particle's pair forces are then the same sums, bit for bit, whenever and on whichever particle
// set (with its partners, in the same relative order) the list was built (docs/parallel.md).
#pragma once

#include <Eigen/Core>
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <functional>
#include <span>
#include <vector>

#include "core/box.hpp"
#include "core/topology.hpp"
#include "forcefields/counting_sort.hpp"

namespace stiffmd {

// Minimum image for unwrapped coordinates, without a branch on periodicity: on a periodic axis
// d − L·round(d/L); an open axis has L = 1/L = 0, which leaves d unchanged. The rounding is
// round_nearest (core/box.hpp), shared with Box::min_image. Ties (|d| = L/2) round to even:
// both images are at the same distance, ≥ the cutoff.
struct MinimumImage {
  double length[3] = {0.0, 0.0, 0.0};
  double inv_length[3] = {0.0, 0.0, 0.0};

  MinimumImage() = default;
  explicit MinimumImage(const Box& box) {
    for (int a = 0; a < 3; ++a)
      if (box.periodic[a]) {
        length[a] = box.lengths[a];
        inv_length[a] = 1.0 / box.lengths[a];
      }
  }

  static double wrap(double d, double len, double inv_len) { return d - len * round_nearest(d * inv_len); }
  void apply(double& dx, double& dy, double& dz) const {
    dx = wrap(dx, length[0], inv_length[0]);
    dy = wrap(dy, length[1], inv_length[1]);
    dz = wrap(dz, length[2], inv_length[2]);
  }
};

// Minimum image of a separation between two positions from NeighborList::wrapped_positions,
// each within the skin of the box while the list is valid (no particle moved more than the skin
// since the build): then |d| < L + 2 skin ≤ 1.5 L (update rebuilds on a periodic axis shorter
// than 4 skin), so one fold by ±L gives the minimum image. In a box many list radii wide, pairs
// across a face are a few per cent of all, the fold's branches are well predicted, and folding is
// cheaper than rounding d/L. In a box a few list radii wide it is not: a listed pair crosses a
// face on an axis with probability ≈ E|d_a|/L = 3R/(8L) for the list radius R (LAMMPS's peptide
// example: 12 Å in 27 Å, one pair in six per axis, at random), and the mispredicted branches cost
// more than the rounding. Given the list radius, a box with an axis shorter than kRoundBelow · R
// rounds (d − L·round(d/L), without a branch): the same separation as the fold, d − L, d + L or d,
// except within rounding of |d| = L/2, where either image is at L/2 — beyond every cutoff (the
// box is at least two list radii wide), so the forces are the same. Open axes never fold.
struct NearestImage {
  // Where rounding pays: an estimate (a mispredicted branch ≈ 15 cycles, against a few cycles of
  // rounding per axis), measured on the peptide (docs/performance.md); data.chain has L/R ≈ 25.
  static constexpr double kRoundBelow = 6.0;
  double length[3] = {0.0, 0.0, 0.0};
  double half[3] = {INFINITY, INFINITY, INFINITY};
  double inv_length[3] = {0.0, 0.0, 0.0};
  bool rounded = false;

  explicit NearestImage(const Box& box, double list_radius = 0.0) {
    for (int a = 0; a < 3; ++a)
      if (box.periodic[a]) {
        length[a] = box.lengths[a];
        half[a] = 0.5 * box.lengths[a];
        inv_length[a] = 1.0 / box.lengths[a];
        rounded |= box.lengths[a] < kRoundBelow * list_radius;
      }
  }
  static double fold(double d, double len, double h) {
    if (d > h) return d - len;
    if (d < -h) return d + len;
    return d;
  }
  void apply(double& dx, double& dy, double& dz) const {
    if (rounded) {
      dx = MinimumImage::wrap(dx, length[0], inv_length[0]);
      dy = MinimumImage::wrap(dy, length[1], inv_length[1]);
      dz = MinimumImage::wrap(dz, length[2], inv_length[2]);
      return;
    }
    dx = fold(dx, length[0], half[0]);
    dy = fold(dy, length[1], half[1]);
    dz = fold(dz, length[2], half[2]);
  }
};

// A position wrapped into the box on its periodic axes, x − L·floor((x − origin)/L) (open axes: x),
// as the pair loop reads it (NeighborList::wrapped_positions; a decomposed run's halo writes the
// extended positions so, NeighborList::set_positions_wrapped): a function of the position alone,
// the same bits wherever it is computed.
class BoxWrap {
 public:
  explicit BoxWrap(const Box& box) {
    for (int a = 0; a < 3; ++a) {
      const bool periodic = box.periodic[a] != 0;
      lo_[a] = box.origin[a];
      len_[a] = periodic ? box.lengths[a] : 0.0;
      inv_[a] = periodic ? 1.0 / box.lengths[a] : 0.0;
    }
  }
  double operator()(double x, int a) const { return x - len_[a] * floor_of((x - lo_[a]) * inv_[a]); }
  // Particles first … last − 1 of x (3×N, column-major) wrapped into out, each coordinate as
  // operator() gives it, bit for bit (four particles at a time with AVX2 where the CPU has it).
  // out may be x (in place).
  void wrap_particles(const double* x, double* out, std::int64_t first, std::int64_t last) const;

 private:
  // floor by truncation and a correction: one conversion each way, no call (x86-64 before SSE4.1
  // has no floor instruction); the same value as std::floor for |q| < 2⁶³.
  static double floor_of(double q) {
    const double t = static_cast<double>(static_cast<std::int64_t>(q));
    return t > q ? t - 1.0 : t;
  }
  double lo_[3], len_[3], inv_[3];
};

// Throws std::invalid_argument when a periodic axis is shorter than 2 × (cutoff + skin): the
// minimum image is then not the only image within the list radius, and a pair could interact
// through two images at once.
void check_box_for_cutoff(const Box& box, double cutoff, double skin);

// LAMMPS `special_bonds lj w12 w13 w14`: the pair interaction of particles one bond apart (1-2) is
// scaled by w12, two bonds apart (1-3) by w13, three (1-4, the ends of a dihedral) by w14. A
// weight of 0 removes the pair from the neighbour list; 1 leaves it an ordinary pair. Default:
// bonded neighbours do not interact, 1-3 and 1-4 fully (the Kremer–Grest bead-spring convention,
// LAMMPS `special_bonds fene`).
struct SpecialWeights {
  double w12 = 0.0;
  double w13 = 1.0;
  double w14 = 1.0;
};

// A bonded pair with its weights: `weight` scales the pair energy of an uncharged style and the
// van der Waals part of a charged one (LAMMPS special_lj), `weight_coul` the Coulomb part of a
// charged one (special_coul; an uncharged style never reads it).
struct SpecialPair {
  int i;  // i < j
  int j;
  double weight;
  double weight_coul;
};

// Every pair whose special weight is not 1, sorted by (i, j), each once. A pair that is both
// 1-2 and 1-3 (a three-membered ring) takes the 1-2 weight, as in LAMMPS. Throws
// std::invalid_argument for a bond to a particle outside [0, num_particles) or to itself.
// weight_coul = weight.
std::vector<SpecialPair> special_pairs(int num_particles, const std::vector<Bond>& bonds, SpecialWeights w);
// The same with separate weights (LAMMPS special_bonds lj w12 w13 w14 coul w12 w13 w14): every pair
// with either weight not 1, `lj` giving its weight and `coul` its weight_coul.
std::vector<SpecialPair> special_pairs(int num_particles, const std::vector<Bond>& bonds, SpecialWeights lj,
                                       SpecialWeights coul);

// Half Verlet list in CSR form: the neighbours of particle i are
//   neighbors()[offsets()[i]] … neighbors()[offsets()[i+1] − 1],   all j > i,
// so each pair appears once. Pairs set as excluded never appear. All arrays are members reused
// from one build to the next: once their capacity is reached, a rebuild allocates nothing.
class NeighborList {
 public:
  // cutoff: the largest interaction range; skin ≥ 0: the extra shell that lets the list be
  // reused while particles move less than skin/2. Throws std::invalid_argument otherwise.
  NeighborList(double cutoff, double skin);

  // Pairs left out of every build (special weight ≠ 1: excluded or handled separately), for
  // particles 0 … num_particles − 1. Forces the next update to rebuild.
  void set_exclusions(int num_particles, std::span<const SpecialPair> pairs);

  // ghost[i] = 1: particle i is a ghost (see the top): from the next build on no pair of two
  // ghosts is listed, and the fast particles' check ignores such pairs. Empty or all 0: no
  // ghosts (the default), the list without ghosts bit for bit. A change forces the next update
  // to rebuild. Throws std::invalid_argument for a flag other than 0 or 1.
  void set_ghosts(std::span<const char> ghost);
  const std::vector<char>& ghosts() const { return ghost_; }
  // From the next build on, also no pair i < j with ghost i (see the top): each pair of an owned
  // particle and a ghost is listed by one of the two ranks that hold both. A change forces the
  // next update to rebuild.
  void set_ghost_pairs_once(bool once);
  bool ghost_pairs_once() const { return ghost_once_; }

  // Rebuilds the list if it may miss a pair within the cutoff (never built, another particle count
  // or box, or the test above); returns whether it rebuilt. The decision is a function of x and
  // the positions at the build only (not of the thread count), or, with a rebuild agreement, of
  // every agreeing list's. Throws std::invalid_argument if the box is too small
  // (check_box_for_cutoff).
  bool update(const Eigen::Matrix3Xd& x, const Box& box);
  // Lists that rebuild together: `agree` takes this list's verdict (whether it may miss a pair)
  // and returns the verdict all of them follow, each then rebuilding or not alike. A decomposed
  // run's ranks (docs/parallel.md) agree by a max-reduction in each update, which every rank
  // reaches at the same point: a rank that rebuilt alone would keep the others waiting for it,
  // and an early rebuild costs nothing else (the pair sums do not depend on when the list was
  // built). Empty: the list's own verdict (the default).
  using RebuildAgreement = std::function<bool(bool)>;
  void set_rebuild_agreement(RebuildAgreement agree) { agree_ = std::move(agree); }
  // The next update's verdict, already known to the caller (it asked needs_rebuild at the same x
  // and box, and the ranks agreed on it): that update does not compute it again.
  void set_next_verdict(bool stale) { next_verdict_ = stale ? 1 : 0; }
  // A displacement since the build past which the list counts as stale whatever the fast
  // particles' test says (> 0; the skin when larger): a decomposed run's pair set holds the
  // partners of its beads only while none moved half the halo's margin.
  void set_displacement_limit(double limit) { displacement_limit_ = limit; }
  bool needs_rebuild(const Eigen::Matrix3Xd& x, const Box& box) const;
  // needs_rebuild after the box changed its lengths or origin since the build (a barostat): the
  // list stays complete while 2U ≤ μ_min (cutoff + skin) − cutoff, U the largest displacement of
  // a particle from the build's position mapped affinely into the new box (x₀ → o + μ(x₀ − o₀),
  // μ_a = L_a / L_a,build) — a pair within the cutoff now was within (cutoff + 2U)/μ_min of each
  // other at the build (docs/design.md, "Constant pressure").
  bool deformed_needs_rebuild(const Eigen::Matrix3Xd& x, const Box& box) const;
  void build(const Eigen::Matrix3Xd& x, const Box& box);

  // x wrapped into the box (BoxWrap), so NearestImage gives the minimum image of a separation.
  // Call after update with the same x; the result is a member, overwritten by the next call (with
  // set_positions_wrapped, x itself).
  const Eigen::Matrix3Xd& wrapped_positions(const Eigen::Matrix3Xd& x);
  // The positions this list is given are wrapped already (BoxWrap, as a decomposed run's halo
  // writes them): wrapped_positions returns them as they are (no pass of its own), and the
  // displacements since the build are taken through the minimum image (a bead crossing a face
  // jumps by a box length). Forces the next update to rebuild.
  void set_positions_wrapped(bool wrapped) {
    positions_wrapped_ = wrapped;
    built_ = false;
  }

  std::span<const std::int64_t> offsets() const { return offsets_; }
  std::span<const int> neighbors() const { return neighbors_; }
  int num_particles() const { return static_cast<int>(offsets_.empty() ? 0 : offsets_.size() - 1); }
  std::size_t num_pairs() const { return neighbors_.size(); }

  double cutoff() const { return cutoff_; }
  double skin() const { return skin_; }
  long rebuilds() const { return rebuilds_; }  // builds so far, the first included
  // The latest build's number, shared by no other build of any list in this process (0: never
  // built): the key of a cache of facts about the pairs (PairScratch's touched runs). A copy of
  // the list keeps it, with the same pairs.
  std::uint64_t build_id() const { return build_id_; }
  const Eigen::Vector3i& cells_per_axis() const { return ncell_; }  // of the last build
  // The cells the last build stored per axis: a window of cells_per_axis on a list with ghosts
  // (bin: the cell coordinates its particles occupy), all of them without.
  Eigen::Vector3i stored_cells_per_axis() const { return {stored_[0], stored_[1], stored_[2]}; }
  // Whether the last build stored each particle's image and wrapped position (false: positions
  // given wrapped whose images were all 0, x itself the wrapped positions).
  bool images_stored() const { return images_stored_; }

  // For checkpoints: the list is a function of the positions and box of its last build (bin and
  // search read nothing else, and neither depends on the thread count), so those positions are
  // its whole state. restore(x_at_build, box, rebuilds) rebuilds the same pairs in the same
  // order with the same periodic images, and the same staleness reference; nothing to restore
  // when built() was false.
  bool built() const { return built_; }
  const Eigen::Matrix3Xd& positions_at_build() const { return x_at_build_; }
  const Box& box_at_build() const { return box_at_build_; }
  void restore(const Eigen::Matrix3Xd& x_at_build, const Box& box, long rebuilds);
  // Forgets the list and frees its arrays and scratch (the next update builds it again); keeps the
  // settings, exclusions, ghosts and the rebuild count. A decomposed run's whole-system terms once
  // the parts have taken over (docs/parallel.md, "What a rank holds").
  void release();

 private:
  void bin(const Eigen::Matrix3Xd& x, const Box& box);
  bool excluded(int i, int j) const;
  bool listed(int i, int j) const;  // (i, j) in the list (i ≠ j, either order)
  // Whether the ghosts leave the pair (i, j) out of every build: two ghosts, or with the ghost
  // pairs once a ghost as the lower index.
  bool left_out(int i, int j) const {
    if (ghost_.empty()) return false;
    return (ghost_[i] && ghost_[j]) || (ghost_once_ && ghost_[std::min(i, j)]);
  }
  // The fast particles' check (see the top): whether some fast particle i of `fast` has a partner
  // j, not excluded, not a pair the ghosts leave out (left_out), and not listed, with |x_i − x_j| < cutoff (minimum
  // image) at x.
  bool fast_particle_misses_a_pair(const Eigen::Matrix3Xd& x, const Box& box, const std::vector<int>& fast) const;

  double cutoff_;
  double skin_;
  long rebuilds_ = 0;
  std::uint64_t build_id_ = 0;
  bool built_ = false;
  bool positions_wrapped_ = false;  // set_positions_wrapped
  RebuildAgreement agree_;
  int next_verdict_ = -1;            // set_next_verdict's, for the next update only (−1: none)
  double displacement_limit_ = 0.0;  // set_displacement_limit's (0: the skin)
  std::vector<char> ghost_;          // set_ghosts (empty: none)
  bool ghost_once_ = false;          // set_ghost_pairs_once
  std::vector<int> cell_home_;       // with ghosts, per cell: its particles that are not (a prefix)
  std::vector<int> key_start_;       // with ghosts, bin's scratch: the starts by (cell, flag)

  // The list (CSR) and the state it was built for.
  std::vector<std::int64_t> offsets_;
  std::vector<int> neighbors_;
  Eigen::Matrix3Xd x_at_build_;
  Box box_at_build_;
  Box box_now_;  // the box of the last update: wrapped_positions wraps into it

  // Exclusions, CSR by particle (both directions), each row sorted: looked up only while building.
  int excl_particles_ = 0;
  std::vector<int> excl_offsets_;
  std::vector<int> excl_;

  // Cell list of the last build: particles of cell c are cell_particles_[cell_start_[c] …
  // cell_start_[c+1] − 1], in increasing index (a counting sort keeps the order; with ghosts and
  // the half-stencil search, the owned ones in increasing index, then the ghosts), and their
  // positions, wrapped into the box on periodic axes, are cell_x_ in the same order, so the
  // search reads neighbouring particles from contiguous memory: the x coordinates, then the y,
  // then the z (structure of arrays), each n + kCellPadding long, so that the search copies a
  // range four entries at a time (cell_particles_ likewise padded).
  static constexpr int kCellPadding = 4;
  Eigen::Vector3i ncell_ = Eigen::Vector3i::Ones();  // the box's grid (cells_per_axis)
  // The cells stored (bin): per axis stored_[a] consecutive coordinates of the box's grid from
  // window_first_[a] on (modulo ncell_ on a periodic axis); every cell without ghosts.
  int window_first_[3] = {0, 0, 0};
  int stored_[3] = {1, 1, 1};
  std::vector<char> occupied_;  // bin's scratch with ghosts: per part, per axis, the coordinates occupied
  std::vector<int> box_cells_;  // bin's scratch with that pass: per particle, its 3 cell coordinates in the box's grid
  // The stored coordinate of the box grid's coordinate c along axis a (−1: outside the window).
  int stored_cell(int a, int c) const;
  double bin_lo_[3] = {0.0, 0.0, 0.0}, bin_len_[3] = {0.0, 0.0, 0.0};  // the binned extent per axis
  mutable std::vector<std::vector<int>> fast_;  // needs_rebuild's scratch: per part, the fast particles
  std::vector<int> cell_of_;                    // per particle, its cell (bin: with ghosts, 2 × cell + flag)
  std::vector<int> cell_start_;
  std::vector<int> cell_particles_;
  Eigen::Matrix3Xd image_;      // per particle, index order: L·floor((x − origin)/L) at build
  Eigen::Matrix3Xd wrapped_x_;  // per particle, index order: x − image_ at build
  // Whether the last build stored image_ and wrapped_x_; false: every image was 0 (positions
  // given wrapped, bin), and the wrapped positions were x itself.
  bool images_stored_ = true;
  const double* binned_x_ = nullptr;  // during a build: wrapped_x_'s data, or x's
  Eigen::Matrix3Xd wrapped_now_;      // x − image_ for the latest wrapped_positions(x)
  std::vector<double> cell_x_;        // per particle, cell order: x … , y … , z … (see above)
  // Per axis, for each cell coordinate c and offset o = −1, 0, 1 (slot 3c + o + 1): the
  // neighbouring cell coordinate (wrapped on periodic axes, −1 past an open edge) and the shift
  // (0 or ±L) that brings a wrapped position in that cell next to cell c.
  std::vector<int> adjacent_[3];
  std::vector<double> adjacent_shift_[3];
  // A periodic axis with fewer than 3 cells wraps onto itself: its neighbour cell is both
  // c − 1 and c + 1, so no single shift is right and the search rounds to the minimum image.
  bool small_box_ = false;
  // Scratch of the half-stencil search: the pairs found, before they are sorted into rows.
  std::vector<std::vector<int>> pair_i_, pair_j_;  // per thread (run of cell columns), sized to capacity
  std::vector<std::size_t> pair_count_;            // per thread: the pairs in pair_i_, pair_j_
  std::vector<std::vector<int>> hits_;             // per thread: one particle's neighbours found
  struct CandidateScratch {                        // per thread: one cell's candidates (search_half_stencil)
    std::vector<double> x, y, z;
    std::vector<int> k;  // their particle indices
    // With ghosts, the ghosts among the candidates apart (x, y, z, k then hold the others).
    std::vector<double> gx, gy, gz;
    std::vector<int> gk;
  };
  std::vector<CandidateScratch> scratch_;
  CountingSort<int> cell_sort_;          // particles into cells (bin)
  CountingSort<std::int64_t> row_sort_;  // pairs into rows (search_half_stencil)

  void search_half_stencil(int n, bool have_exclusions);
  void search_small_box(int n, const MinimumImage& mi, bool have_exclusions);
  void search_all_pairs(int n, const MinimumImage& mi, bool have_exclusions);  // ≤ 2 cells per axis
};

}  // namespace stiffmd
