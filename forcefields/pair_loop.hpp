// The loop over non-bonded pairs, written once and shared by every pair style (docs/design.md §11.1,
// after HOOMD's PotentialPair and miniMD's force_lj): a style supplies only a kernel (see
// pair_potentials.hpp)
//     static void eval(double r2, const Params& p, double& energy, double& fpair);
// with fpair = −(dE/dr)/r. For the pair d = x_i − x_j (minimum image) the force on i is
// fpair·d and, by Newton's third law, −fpair·d on j; the pair's virial r_ij·f_ij is fpair·r².
//
// A charged kernel (coulomb_potentials.hpp; `static constexpr bool kCharged = true`) instead has
//     static void eval(double r2, const Params& p, double qq, double factor_lj, double factor_coul,
//                      double& evdwl, double& ecoul, double& fpair);
// with qq = qqrd2e q_i q_j and the special-bond factors of the pair (LAMMPS special_lj and
// special_coul; 1 and 1 in the listed pairs), returning the van der Waals and the Coulomb energies
// apart (LAMMPS's evdwl and ecoul). The uncharged kernels' loop is the same code as before: the
// charged path is a compile-time branch.
//
// What a call accumulates (forces, virial) and whether the box is periodic are template
// parameters, so the inner loop carries no run-time branch for them. The loop reads only its
// arguments — no hidden state — and works on a range of rows, so that the OpenMP version gives
// fixed row blocks to threads with private force buffers and reduces them in a fixed order
// (deterministic, bit for bit, for a given thread count).
#pragma once

#include <Eigen/Core>
#include <algorithm>
#include <array>
#include <bit>
#include <cstdint>
#include <cstdlib>
#include <new>
#include <span>
#include <sstream>
#include <stdexcept>
#include <type_traits>
#include <vector>

#if defined(__x86_64__)
#include <immintrin.h>
#endif

#include "core/box.hpp"
#include "core/exact_sum.hpp"
#include "core/parallel.hpp"
#include "forcefields/neighbor_list.hpp"

namespace stiffmd {

// A symmetric matrix indexed by particle type: per-type-pair coefficients (LAMMPS pair_coeff).
// Row-major and contiguous, so the loop hoists the row of particle i and indexes it by type j.
template <class T>
class TypePairMatrix {
 public:
  TypePairMatrix() = default;
  explicit TypePairMatrix(int num_types)
      : n_(num_types), value_(static_cast<std::size_t>(num_types) * num_types), given_(value_.size(), 0) {
    if (num_types < 1) throw std::invalid_argument("a type-pair matrix needs at least one particle type");
  }

  int num_types() const { return n_; }

  // Sets (a, b) and (b, a).
  void set(int a, int b, const T& value) {
    check(a, b);
    value_[index(a, b)] = value_[index(b, a)] = value;
    given_[index(a, b)] = given_[index(b, a)] = 1;
  }
  bool is_set(int a, int b) const {
    check(a, b);
    return given_[index(a, b)] != 0;
  }
  const T& operator()(int a, int b) const {
    check(a, b);
    return value_[index(a, b)];
  }
  // Row a: row(a)[b] is (a, b). Unchecked, for the inner loop.
  const T* row(int a) const { return value_.data() + static_cast<std::size_t>(a) * n_; }

  // The matrix of f(value) over the entries that are set.
  template <class F>
  auto transform(F f) const -> TypePairMatrix<std::invoke_result_t<F, const T&>> {
    TypePairMatrix<std::invoke_result_t<F, const T&>> out(n_);
    for (int a = 0; a < n_; ++a)
      for (int b = a; b < n_; ++b)
        if (is_set(a, b)) out.set(a, b, f((*this)(a, b)));
    return out;
  }

 private:
  std::size_t index(int a, int b) const { return static_cast<std::size_t>(a) * n_ + b; }
  void check(int a, int b) const {
    if (a < 0 || b < 0 || a >= n_ || b >= n_) {
      std::ostringstream s;
      s << "type pair (" << a << ", " << b << ") outside 0 … " << n_ - 1;
      throw std::out_of_range(s.str());
    }
  }

  int n_ = 0;
  std::vector<T> value_;
  std::vector<char> given_;
};

// A kernel that takes the charges (see the top).
template <class Kernel>
concept ChargedKernel = requires {
  requires Kernel::kCharged;
};
// A charged kernel whose Coulomb part is the real-space half of an Ewald sum (coul/long): the
// pairs excluded by special bonds (both weights 0) are evaluated too within the cutoff, for the
// reciprocal sum's interaction of them that the pair term subtracts (LAMMPS: excluded pairs stay
// in the neighbour list when a kspace style is defined).
template <class Kernel>
concept EwaldKernel = requires {
  requires Kernel::kLong;
};

// The charges a charged kernel reads: q[i] per particle (in e), qqrd2e the Coulomb constant in the
// run's units (Units::coulomb: 332.06371 kcal Å/(mol e²) in real units, 1 in lj). Unused by the
// uncharged kernels.
struct PairCharges {
  const double* q = nullptr;
  double qqrd2e = 1.0;
};

struct PairSums {
  double energy = 0.0;   // Σ E over the pairs
  double coulomb = 0.0;  // of which the Coulomb part (charged kernels: LAMMPS's ecoul; the rest is evdwl)
  double virial = 0.0;   // Σ r_ij · f_ij over the pairs
  // With kForces and kVirial (the barostat's pass, integrators/barostat.hpp): the virial tensor's
  // diagonal Σ (r_ij)_a (f_ij)_a, summed exactly, each pair as two halves (one per particle: a
  // pair with a ghost counts one, its owner's rank the other), so that its value does not depend on
  // the thread count or the number of processes. `virial` stays the plain sum it was.
  ExactDiagonal diagonal;
};

// Adds a pair's d_a² fpair, a = x, y, z, to the exact diagonal, `halves` times half of it.
inline void add_pair_diagonal(ExactDiagonal& w, double fpair, double dx, double dy, double dz, int halves) {
  if (fpair == 0.0) return;  // most listed pairs: beyond the cutoff
  w.axis[0].add(0.5 * fpair * dx * dx, halves);
  w.axis[1].add(0.5 * fpair * dy * dy, halves);
  w.axis[2].add(0.5 * fpair * dz * dz, halves);
}

// The ghost flags by which a pair with a ghost counts half in this process's sums (kShares), or
// null where every listed pair counts whole: no ghosts, or the ghost pairs once
// (NeighborList::set_ghost_pairs_once: such a pair is evaluated by one process only, which counts
// it whole).
inline const char* list_share_flags(const NeighborList& list) {
  return list.ghosts().empty() || list.ghost_pairs_once() ? nullptr : list.ghosts().data();
}

// One pair's share (1, or ½ for a pair with a ghost: kShares) of the energy, the Coulomb part
// (charged kernels), the virial and its diagonal, into sums. A share of 1 adds the values
// themselves (× 1 is exact): one process's sums are the plain ones.
template <bool kCharged, bool kForces, bool kVirial>
inline void add_pair_sums(PairSums& sums, double share, double e, double ecoul, double fpair, double r2, double dx,
                          double dy, double dz) {
  sums.energy += share * e;
  if constexpr (kCharged) sums.coulomb += share * ecoul;
  if constexpr (kVirial) sums.virial += share * (fpair * r2);
  if constexpr (kVirial && kForces) add_pair_diagonal(sums.diagonal, fpair, dx, dy, dz, share < 1.0 ? 1 : 2);
}

// Rows first … last − 1 of the half list. xw: the positions from list.wrapped_positions(x),
// whose minimum image is one fold away (NearestImage). f (3×N, column-major: f[3j + a]) may be
// null when kForces is false. type[i] indexes params.
//
// kShares: the energy and virial are this process's share when the list has ghosts
// (NeighborList::set_ghosts): a pair of an owned particle and a ghost counts half, its other half
// being the ghost's owner's, so that the processes' shares add up to the whole system's
// (docs/parallel.md). Without ghosts the sums are the plain ones.
template <class Kernel, bool kPeriodic, bool kForces, bool kVirial, bool kShares = false>
PairSums accumulate_pair_rows(const NeighborList& list, int first, int last,
                              const TypePairMatrix<typename Kernel::Params>& params, const int* type,
                              const Eigen::Matrix3Xd& xw, const NearestImage& near, double* f,
                              const PairCharges& charges = {}) {
  using Params = typename Kernel::Params;
  const double* xp = xw.data();
  const std::int64_t* offset = list.offsets().data();
  const int* nbr = list.neighbors().data();
  const char* ghost = kShares ? list_share_flags(list) : nullptr;
  PairSums sums;
  for (int i = first; i < last; ++i) {
    // A row with no listed pair adds nothing (f_i + 0 is f_i, but for a −0 component, which it
    // would make +0): passed over, as accumulate_pair_forces_rows passes it.
    if (offset[i] == offset[i + 1]) continue;
    const bool i_ghost = ghost && ghost[i];
    const double xi = xp[3 * i], yi = xp[3 * i + 1], zi = xp[3 * i + 2];
    const Params* prow = params.row(type[i]);
    [[maybe_unused]] double qi = 0.0;  // qqrd2e q_i (charged kernels), as LAMMPS forms qqrd2e q_i q_j
    if constexpr (ChargedKernel<Kernel>) qi = charges.qqrd2e * charges.q[i];
    double fxi = 0.0, fyi = 0.0, fzi = 0.0;  // f_i summed in registers, stored once per row
    for (std::int64_t k = offset[i]; k < offset[i + 1]; ++k) {
      const int j = nbr[k];
      double dx = xi - xp[3 * j], dy = yi - xp[3 * j + 1], dz = zi - xp[3 * j + 2];
      if constexpr (kPeriodic) near.apply(dx, dy, dz);
      const double r2 = dx * dx + dy * dy + dz * dz;
      const Params& p = prow[type[j]];
      // Listed within cutoff + skin, interacting within the cutoff: a third to a half of the
      // listed pairs (WCA, skin 0.3σ), in no predictable order, so mask the result rather than
      // branch around eval — measured ~1.5× faster on a dense liquid. A charged kernel (a table
      // of two degree-7 polynomials, or erfc: several times a WCA pair) is worth the mispredicted
      // branch around it: the same bits (a masked pair adds exact zeros), docs/electrostatics.md
      // has the speed-up.
      if constexpr (ChargedKernel<Kernel>)
        if (!(r2 < p.rc2)) continue;
      const double inside = r2 < p.rc2 ? 1.0 : 0.0;
      double e = 0.0, fpair = 0.0;
      [[maybe_unused]] double ecoul = 0.0;
      if constexpr (ChargedKernel<Kernel>) {
        double evdwl = 0.0;
        Kernel::eval(r2, p, qi * charges.q[j], 1.0, 1.0, evdwl, ecoul, fpair);
        e = evdwl + ecoul;
        ecoul *= inside;
      } else {
        Kernel::eval(r2, p, e, fpair);
      }
      e *= inside;
      fpair *= inside;
      add_pair_sums<ChargedKernel<Kernel>, kForces, kVirial>(
          sums, kShares && ghost && (i_ghost || ghost[j]) ? 0.5 : 1.0, e, ecoul, fpair, r2, dx, dy, dz);
      if constexpr (kForces) {
        const double fx = fpair * dx, fy = fpair * dy, fz = fpair * dz;
        fxi += fx;
        fyi += fy;
        fzi += fz;
        f[3 * j] -= fx;
        f[3 * j + 1] -= fy;
        f[3 * j + 2] -= fz;
      }
    }
    if constexpr (kForces) {
      f[3 * i] += fxi;
      f[3 * i + 1] += fyi;
      f[3 * i + 2] += fzi;
    }
  }
  return sums;
}

// The force-only pass of rows first … last − 1 (the integrators' forces: no energy, no virial, no
// sums), adding into f exactly what accumulate_pair_rows<…, kForces = true, …> adds, bit for bit.
// Of the listed pairs (within cutoff + skin) a third to a half interact, in no predictable order:
// accumulate_pair_rows masks the others and so evaluates the kernel on every listed pair. Here the
// rows are taken in chunks of at most kChunk listed pairs, in three passes:
//   1. the separations d = x_i − x_j (minimum image) and r², and the pairs with r² < rc² compacted
//      into a buffer, without a branch (each written, the count advanced by 0 or 1);
//   2. the kernel on the buffer's pairs alone: a loop with no branch and no gather, which the
//      compiler vectorises where the kernel allows (the Lennard-Jones family: r² in, fpair out,
//      IEEE operations lane by lane, so the same bits as one pair at a time);
//   3. the forces fpair·d added as accumulate_pair_rows adds them: f_j −= fpair d in list order and
//      f_i += Σ_j fpair d summed in the row's order, added once per row (across chunks too).
// A pair beyond the cutoff adds exact zeros in accumulate_pair_rows (fpair masked to 0, then
// f_i + 0 and f_j − 0 are f_i and f_j), so leaving it out gives the same sums.
// uniform: every particle has this type (≥ 0; kOneType, its coefficients held in registers), or −1.
// Pass 1 prefetches x_j kPairPrefetch listed pairs ahead: the neighbours of a row lie anywhere in
// memory (a melt's chains wander), and the loads of x_j are where its time goes.
inline constexpr int kPairChunk = 256;
inline constexpr int kPairPrefetch = 64;

// The buffers of one chunk of accumulate_pair_forces_rows (at most kPairChunk listed pairs): the
// kept pairs' separations, r², fpair, f_j's place in f (j3 = 3j), their coefficients (several
// types) and qqrd2e q_i q_j (charged kernels); per row met, its index and its end in the buffer.
// One object, so that a pass addresses every array from one register. kRoom more entries than
// pairs: the AVX2 pass's packed stores write four.
template <class Params, bool kOneType, bool kCharged>
struct PairChunkBuffers {
  static constexpr int kRoom = 4;
  static constexpr bool kUniform = kOneType;  // every pair has the coefficients `one` (pn unused)
  alignas(64) double dx[kPairChunk + kRoom];
  alignas(64) double dy[kPairChunk + kRoom];
  alignas(64) double dz[kPairChunk + kRoom];
  alignas(64) double r2[kPairChunk + kRoom];
  alignas(64) double fpair[kPairChunk];
  std::uint32_t j3[kPairChunk + kRoom];
  const Params* pn[kOneType ? 1 : kPairChunk + kRoom];
  double qq[kCharged ? kPairChunk + kRoom : 1];
  int seg_row[kPairChunk], seg_end[kPairChunk];
};

#if defined(__x86_64__)
// Pass 1 of accumulate_pair_forces_rows four listed pairs at a time (AVX2), for every style: the
// separations, their minimum images and r² as the scalar pass computes them — the same IEEE
// operations lane by lane (no FMA: -ffp-contract=off), the fold as a select, the rounding as
// (s + 1.5·2⁵²) − 1.5·2⁵², so the same values bit for bit — and the pairs with r² < rc² appended in
// the list's order. A chunk is a stretch of the list's pairs (rows end inside groups of four: the
// scalar pass's rows, the same pairs in the same order, so the same forces). The x_j are loaded by
// index (a row's partners lie anywhere) and transposed into lanes, the lanes past the chunk's end
// given x_i = +∞, so that no test keeps them; the kept lanes are packed to the front by a
// permutation chosen by the 4-bit mask (PairPackTable) and stored four at a time, the count
// advanced by the mask's population (the buffers have 3 entries of room past the chunk). x_j is
// prefetched kPairPrefetch listed pairs ahead, as in the scalar pass.
struct PairPackTable {
  // One cache line per mask: both orders at one address, mask · 64.
  struct alignas(64) Entry {
    int doubles[8];          // _mm256_permutevar8x32: the kept doubles' halves, in order
    unsigned char ints[16];  // _mm_shuffle_epi8: the kept 32-bit indices' bytes, in order
    unsigned char unused[16];
  };
  Entry entry[16];
  constexpr PairPackTable() : entry{} {
    for (int mask = 0; mask < 16; ++mask) {
      Entry& t = entry[mask];
      int out = 0;
      for (int lane = 0; lane < 4; ++lane)
        if (mask & (1 << lane)) {
          t.doubles[2 * out] = 2 * lane;
          t.doubles[2 * out + 1] = 2 * lane + 1;
          for (int b = 0; b < 4; ++b) t.ints[4 * out + b] = static_cast<unsigned char>(4 * lane + b);
          ++out;
        }
      for (; out < 4; ++out) {
        t.doubles[2 * out] = t.doubles[2 * out + 1] = 0;
        for (int b = 0; b < 4; ++b) t.ints[4 * out + b] = 0x80;
      }
    }
  }
};
inline constexpr PairPackTable kPairPack;

// Whether the CPU runs the AVX2 passes (asked once).
inline bool pair_loop_avx2() {
  static const bool avx2 = __builtin_cpu_supports("avx2") && __builtin_cpu_supports("popcnt");
  return avx2;
}

// Where pass 1 of a chunk stands: row i, its listed pair k, n pairs kept, the rows met (seg_row,
// seg_end: each row's index and its end in the buffer), and whether the chunk ends inside row i.
struct PairChunkCursor {
  int i;
  std::int64_t k;
  int n = 0, segments = 0;
  bool split = false;
};

// Room past a chunk in the buffers of the AVX2 passes: a row's x_i is stored eight lanes at a time
// from its first pair, and the packed stores write four.
inline constexpr int kPairChunkRoom = 8;

// Pass 1 of one chunk (accumulate_pair_forces_rows: the kPairChunk listed pairs from (i, k) on,
// rows up to last − 1) four listed pairs at a time, the lanes running on across the rows' ends: a
// row holds ≈ 5 listed pairs (in.chain), so groups of four within a row left a quarter of their
// lanes empty. Each row's x_i (its coefficient row, its qqrd2e q_i) is first written into every
// slot of its pairs in the chunk (xi, yi, zi; prow; qi), so that a group reads the x_i of its
// lanes as it reads their x_j. Each group records its kept count before it (group_n) and its mask
// (group_mask), from which a row's end in the buffer is read afterwards. kRounded:
// NearestImage::rounded (a box a few list radii wide). kOneType: every pair has the coefficients
// `one`; else each lane's are params' (type_i, type_j), whose address is kept (pn) and whose rc²
// the lane is tested against. kCharged: each kept pair's qq = (qqrd2e q_i) q_j too.
//
// The fold (NearestImage::fold, d − L where d > L/2, d + L where d < −L/2) changes a separation only
// on an axis where |d_a| > L_a/2; a group all of whose lanes have r² = (d_x² + d_y²) + d_z² below
// min_a (L_a/2)² skips it (in.chain: 87 % of the groups; a pair across a face has |d_a| ≈ L_a;
// docs/performance.md, "The pair loop's first pass without the fold where no lane needs it").
// The same values bit for bit: the rounded squares and sums are monotone, so fl(d_a²) ≤ r² <
// fl((L_a/2)²) gives |d_a| ≤ L_a/2, where the fold returns d_a itself; a group with a lane at or
// above the bound (or a NaN) folds and computes its r² again, as before.
//
// f_j's place in f, 3j, is formed once here, in lanes, and kept (j3) for the scatter; the positions
// are read at the unsigned offsets 3j, so no extension of a signed index per load.
template <bool kPeriodic, bool kRounded, bool kOneType, bool kCharged, class Params>
[[gnu::target("avx2,popcnt")]] void pair_chunk_separations_avx2(
    PairChunkBuffers<Params, kOneType, kCharged>& b, PairChunkCursor& c, const double* __restrict xp,
    const int* __restrict nbr, const std::int64_t* __restrict offset, int last, std::int64_t last_pair,
    const NearestImage& near, const Params& one, const TypePairMatrix<Params>& params, const int* __restrict type,
    const PairCharges& charges) {
  constexpr int kChunk = kPairChunk;
  alignas(32) double xi[kChunk + kPairChunkRoom], yi[kChunk + kPairChunkRoom], zi[kChunk + kPairChunkRoom];
  [[maybe_unused]] alignas(32) const Params* prow[kOneType ? 1 : kChunk + kPairChunkRoom];
  [[maybe_unused]] alignas(32) double qi[kCharged ? kChunk + kPairChunkRoom : 1];
  // Per group, at its first slot: the kept count before it and its mask.
  int group_n[kChunk + 4], group_mask[kChunk + 4];
  // The rows: each one's x_i into its pairs' slots, its end as a slot of the chunk. At most kChunk
  // rows are met (seg_row, seg_end: those with listed pairs; a row without is passed over, as the
  // scalar pass passes it: a decomposed run's halo rows are often empty, all of them with the halo
  // pairs once).
  const std::int64_t k0 = c.k, k1 = std::min<std::int64_t>(k0 + kChunk, offset[last]);
  const int i0 = c.i, row_limit = static_cast<int>(std::min<std::int64_t>(last, std::int64_t{i0} + kChunk));
  int i = i0, segments = 0;
  std::int64_t k = k0;
  bool split = false;
  for (; i < row_limit; ++i) {
    const std::int64_t end = offset[i + 1], stop = std::min(end, k1);
    if (end == k) continue;  // no listed pair (left in this row)
    const int from = static_cast<int>(k - k0), to = static_cast<int>(stop - k0);
    const __m256d vx = _mm256_set1_pd(xp[3 * i]), vy = _mm256_set1_pd(xp[3 * i + 1]),
                  vz = _mm256_set1_pd(xp[3 * i + 2]);
    [[maybe_unused]] __m256i vp;
    [[maybe_unused]] __m256d vq;
    if constexpr (!kOneType) vp = _mm256_set1_epi64x(reinterpret_cast<long long>(params.row(type[i])));
    if constexpr (kCharged) vq = _mm256_set1_pd(charges.qqrd2e * charges.q[i]);
    // Eight slots without a test (most rows hold fewer), then the rest of a longer row.
    int q = from;
    do {
      _mm256_storeu_pd(xi + q, vx);
      _mm256_storeu_pd(yi + q, vy);
      _mm256_storeu_pd(zi + q, vz);
      _mm256_storeu_pd(xi + q + 4, vx);
      _mm256_storeu_pd(yi + q + 4, vy);
      _mm256_storeu_pd(zi + q + 4, vz);
      if constexpr (!kOneType) {
        _mm256_storeu_si256(reinterpret_cast<__m256i*>(prow + q), vp);
        _mm256_storeu_si256(reinterpret_cast<__m256i*>(prow + q + 4), vp);
      }
      if constexpr (kCharged) {
        _mm256_storeu_pd(qi + q, vq);
        _mm256_storeu_pd(qi + q + 4, vq);
      }
      q += 8;
    } while (q < to);
    b.seg_row[segments] = i;
    b.seg_end[segments] = to;  // a slot for now: made a buffer end below
    ++segments;
    k = stop;
    if (stop < end) {  // the chunk ends inside the row
      split = true;
      break;
    }
  }
  const int listed = static_cast<int>(k - k0);
  const int slots = (listed + 3) & ~3;  // the groups' lanes
  // The lanes past the chunk's end: x_i = +∞ (every r² then +∞ or NaN: no test keeps them), a
  // valid coefficient row, q_i = 0; their j are 0 (below), a valid index.
  {
    const __m256d inf = _mm256_set1_pd(INFINITY);
    _mm256_storeu_pd(xi + listed, inf);
    _mm256_storeu_pd(yi + listed, inf);
    _mm256_storeu_pd(zi + listed, inf);
    if constexpr (!kOneType)
      _mm256_storeu_si256(reinterpret_cast<__m256i*>(prow + listed),
                          _mm256_set1_epi64x(reinterpret_cast<long long>(params.row(0))));
    if constexpr (kCharged) _mm256_storeu_pd(qi + listed, _mm256_setzero_pd());
  }
  const __m256d vrc2 = _mm256_set1_pd(one.rc2);
  __m256d len[3], half[3], nhalf[3], inv[3];
  double half2 = INFINITY;  // min_a (L_a/2)²: below it no lane folds
  for (int a = 0; a < 3; ++a) {
    len[a] = _mm256_set1_pd(near.length[a]);
    half[a] = _mm256_set1_pd(near.half[a]);
    nhalf[a] = _mm256_set1_pd(-near.half[a]);
    inv[a] = _mm256_set1_pd(near.inv_length[a]);
    half2 = std::min(half2, near.half[a] * near.half[a]);
  }
  const __m256d unfolded = _mm256_set1_pd(half2);
  const __m256d round_k = _mm256_set1_pd(6755399441055744.0);  // round_nearest's 1.5 · 2⁵²
  // The groups' indices j: the list's own where the last group ends at or before last_pair, else a
  // copy with 0 past it; and the prefetch's, kPairPrefetch listed pairs ahead of each group's: the
  // list's own where they lie before last_pair, else a copy clamped to it (a part's last chunks).
  const int* js = nbr + k0;
  alignas(16) int js_padded[kChunk + 4];
  if (k0 + slots > last_pair + 1) {
    for (int r = 0; r < slots; ++r) js_padded[r] = r < listed ? nbr[k0 + r] : 0;
    js = js_padded;
  }
  const int* ahead = nbr + k0 + kPairPrefetch;
  alignas(16) int ahead_clamped[kChunk + 4];
  if (k0 + kPairPrefetch + slots > last_pair + 1) {
    for (int r = 0; r < slots; ++r) ahead_clamped[r] = nbr[std::min<std::int64_t>(k0 + kPairPrefetch + r, last_pair)];
    ahead = ahead_clamped;
  }
  const unsigned char* pack = reinterpret_cast<const unsigned char*>(kPairPack.entry);
  std::ptrdiff_t n = 0;
  for (int at = 0; at < slots; at += 4) {
    const __m128i j = _mm_loadu_si128(reinterpret_cast<const __m128i*>(js + at));
    {
      const __m128i a = _mm_loadu_si128(reinterpret_cast<const __m128i*>(ahead + at));
      const __m128i a3 = _mm_add_epi32(a, _mm_add_epi32(a, a));
      __builtin_prefetch(xp + static_cast<std::uint32_t>(_mm_cvtsi128_si32(a3)));
      __builtin_prefetch(xp + static_cast<std::uint32_t>(_mm_extract_epi32(a3, 1)));
      __builtin_prefetch(xp + static_cast<std::uint32_t>(_mm_extract_epi32(a3, 2)));
      __builtin_prefetch(xp + static_cast<std::uint32_t>(_mm_extract_epi32(a3, 3)));
    }
    const __m128i j3 = _mm_add_epi32(j, _mm_add_epi32(j, j));
    // x_j of each lane as (x, y) and z, transposed into lanes (loads beat a gather here).
    const double* p0 = xp + static_cast<std::uint32_t>(_mm_cvtsi128_si32(j3));
    const double* p1 = xp + static_cast<std::uint32_t>(_mm_extract_epi32(j3, 1));
    const double* p2 = xp + static_cast<std::uint32_t>(_mm_extract_epi32(j3, 2));
    const double* p3 = xp + static_cast<std::uint32_t>(_mm_extract_epi32(j3, 3));
    const __m256d xy02 = _mm256_insertf128_pd(_mm256_castpd128_pd256(_mm_loadu_pd(p0)), _mm_loadu_pd(p2), 1);
    const __m256d xy13 = _mm256_insertf128_pd(_mm256_castpd128_pd256(_mm_loadu_pd(p1)), _mm_loadu_pd(p3), 1);
    const __m256d z02 = _mm256_insertf128_pd(_mm256_castpd128_pd256(_mm_load_sd(p0 + 2)), _mm_load_sd(p2 + 2), 1);
    const __m256d z13 = _mm256_insertf128_pd(_mm256_castpd128_pd256(_mm_load_sd(p1 + 2)), _mm_load_sd(p3 + 2), 1);
    __m256d e[3] = {_mm256_sub_pd(_mm256_load_pd(xi + at), _mm256_unpacklo_pd(xy02, xy13)),
                    _mm256_sub_pd(_mm256_load_pd(yi + at), _mm256_unpackhi_pd(xy02, xy13)),
                    _mm256_sub_pd(_mm256_load_pd(zi + at), _mm256_unpacklo_pd(z02, z13))};
    if constexpr (kPeriodic && kRounded)
      for (int a = 0; a < 3; ++a) {  // d − L·round_nearest(d/L)
        const __m256d q = _mm256_sub_pd(_mm256_add_pd(_mm256_mul_pd(e[a], inv[a]), round_k), round_k);
        e[a] = _mm256_sub_pd(e[a], _mm256_mul_pd(len[a], q));
      }
    __m256d s =
        _mm256_add_pd(_mm256_add_pd(_mm256_mul_pd(e[0], e[0]), _mm256_mul_pd(e[1], e[1])), _mm256_mul_pd(e[2], e[2]));
    if constexpr (kPeriodic && !kRounded)
      if (_mm256_movemask_pd(_mm256_cmp_pd(s, unfolded, _CMP_LT_OQ)) != 0xF) [[unlikely]] {
        for (int a = 0; a < 3; ++a) {  // the fold: d − L (d > L/2), d + L (d < −L/2), else d
          const __m256d above = _mm256_cmp_pd(e[a], half[a], _CMP_GT_OQ);
          const __m256d below = _mm256_cmp_pd(e[a], nhalf[a], _CMP_LT_OQ);
          const __m256d folded = _mm256_blendv_pd(e[a], _mm256_sub_pd(e[a], len[a]), above);
          e[a] = _mm256_blendv_pd(folded, _mm256_add_pd(folded, len[a]), below);
        }
        s = _mm256_add_pd(_mm256_add_pd(_mm256_mul_pd(e[0], e[0]), _mm256_mul_pd(e[1], e[1])),
                          _mm256_mul_pd(e[2], e[2]));
      }
    __m256d lane_rc2 = vrc2;
    [[maybe_unused]] __m256i lane_p;
    [[maybe_unused]] int j0, j1, j2, j3i;
    if constexpr (!kOneType || kCharged) {
      j0 = _mm_cvtsi128_si32(j), j1 = _mm_extract_epi32(j, 1), j2 = _mm_extract_epi32(j, 2),
      j3i = _mm_extract_epi32(j, 3);
    }
    if constexpr (!kOneType) {
      const Params *q0 = prow[at] + type[j0], *q1 = prow[at + 1] + type[j1], *q2 = prow[at + 2] + type[j2],
                   *q3 = prow[at + 3] + type[j3i];
      lane_rc2 = _mm256_setr_pd(q0->rc2, q1->rc2, q2->rc2, q3->rc2);
      lane_p = _mm256_setr_epi64x(reinterpret_cast<long long>(q0), reinterpret_cast<long long>(q1),
                                  reinterpret_cast<long long>(q2), reinterpret_cast<long long>(q3));
    }
    const unsigned mask = static_cast<unsigned>(_mm256_movemask_pd(_mm256_cmp_pd(s, lane_rc2, _CMP_LT_OQ)));
    group_n[at] = static_cast<int>(n);
    group_mask[at] = static_cast<int>(mask);
    const unsigned char* entry = pack + 64 * mask;
    const __m256i order = _mm256_load_si256(reinterpret_cast<const __m256i*>(entry));
    if constexpr (!kOneType)
      _mm256_storeu_si256(reinterpret_cast<__m256i*>(b.pn + n), _mm256_permutevar8x32_epi32(lane_p, order));
    if constexpr (kCharged) {
      const __m256d lane_qq = _mm256_mul_pd(
          _mm256_load_pd(qi + at),
          _mm256_setr_pd(charges.q[j0], charges.q[j1], charges.q[j2], charges.q[j3i]));  // (qqrd2e q_i) q_j
      _mm256_storeu_pd(b.qq + n, _mm256_castps_pd(_mm256_permutevar8x32_ps(_mm256_castpd_ps(lane_qq), order)));
    }
    _mm256_storeu_pd(b.dx + n, _mm256_castps_pd(_mm256_permutevar8x32_ps(_mm256_castpd_ps(e[0]), order)));
    _mm256_storeu_pd(b.dy + n, _mm256_castps_pd(_mm256_permutevar8x32_ps(_mm256_castpd_ps(e[1]), order)));
    _mm256_storeu_pd(b.dz + n, _mm256_castps_pd(_mm256_permutevar8x32_ps(_mm256_castpd_ps(e[2]), order)));
    _mm256_storeu_pd(b.r2 + n, _mm256_castps_pd(_mm256_permutevar8x32_ps(_mm256_castpd_ps(s), order)));
    _mm_storeu_si128(reinterpret_cast<__m128i*>(b.j3 + n),
                     _mm_shuffle_epi8(j3, _mm_load_si128(reinterpret_cast<const __m128i*>(entry + 32))));
    n += _mm_popcnt_u32(mask);
  }
  // A row ending at slot e ends in the buffer at the kept count before e's group plus its kept
  // lanes below e.
  group_n[slots] = static_cast<int>(n);
  group_mask[slots] = 0;
  for (int r = 0; r < segments; ++r) {
    const int e = b.seg_end[r], g = e & ~3;
    b.seg_end[r] = group_n[g] + _mm_popcnt_u32(static_cast<unsigned>(group_mask[g] & ((1 << (e & 3)) - 1)));
  }
  c.i = i;
  c.k = k;
  c.n = static_cast<int>(n);
  c.segments = segments;
  c.split = split;
}

// Pass 3 of accumulate_pair_forces_rows with the x and y components side by side (AVX's 128-bit
// operations) and no branch per row: f_j −= fpair d and f_i += fpair d as the scalar pass adds
// them — the same products and sums, component by component. A row holds ≈ 1.6 interacting pairs
// on in.chain, a number that changes from row to row at random, so a loop over each row's pairs
// ends with a mispredicted branch in most rows; here two loops of fixed length instead:
//   A. over the chunk's kept pairs m in the list's order: f_j −= fpair d, and the rows' running
//      sums as a segmented scan, S_m = (S_{m−1} if m is not its row's first pair, else 0) + fpair d
//      (the row's first sum 0 + fpair d, as the scalar pass's f_i = 0, f_i += fpair d);
//   B. over the chunk's rows in order: f_i += S at the row's last pair (0 for a row with no kept
//      pair, which the scalar pass adds too).
// Each f_i is the same sum in the row's order. The order of the additions into one f_k is
// unchanged too: every listed pair has j > i (NeighborList), so the pairs that subtract from f_k
// lie in rows before row k, and each of them came before row k's f_k += S in the scalar pass as it
// does here (B follows A; rows and chunks run in order). fi: the open row's f_i (carried over a
// chunk's end), in and out.
template <class Buffers>
[[gnu::target("avx2")]] inline void pair_chunk_forces_avx2(int n, int segments, const Buffers& b, bool carried,
                                                           bool split, double* f, double fi[3]) {
  constexpr int kSize = kPairChunk + 1;
  alignas(16) double sum_xy[kSize][2];
  alignas(16) double sum_z[kSize];
  // Per kept pair: all ones, or 0 where a row's sum starts afresh (its first pair).
  std::uint64_t keep[kSize];
  for (int m = 0; m < n; ++m) keep[m] = ~std::uint64_t{0};
  keep[0] = carried ? ~std::uint64_t{0} : 0;
  for (int s = 0; s + 1 < segments; ++s) keep[b.seg_end[s]] = 0;  // row s + 1's first pair (or n)
  const __m128d carry_xy = carried ? _mm_setr_pd(fi[0], fi[1]) : _mm_setzero_pd();
  const __m128d carry_z = carried ? _mm_set_sd(fi[2]) : _mm_setzero_pd();
  __m128d sxy = carry_xy, sz = carry_z;
  _mm_store_pd(sum_xy[0], sxy);  // read (and not chosen) by B where the chunk keeps no pair
  _mm_store_sd(sum_z, sz);
  for (int m = 0; m < n; ++m) {
    double* fj = f + b.j3[m];
    const __m128d p = _mm_set1_pd(b.fpair[m]);
    const __m128d fxy = _mm_mul_pd(p, _mm_loadh_pd(_mm_load_sd(b.dx + m), b.dy + m));
    const __m128d fz = _mm_mul_sd(p, _mm_load_sd(b.dz + m));
    const __m128d k = _mm_castsi128_pd(_mm_set1_epi64x(static_cast<long long>(keep[m])));
    sxy = _mm_add_pd(_mm_and_pd(sxy, k), fxy);
    sz = _mm_add_sd(_mm_and_pd(sz, k), fz);
    _mm_store_pd(sum_xy[m], sxy);
    _mm_store_sd(sum_z + m, sz);
    _mm_storeu_pd(fj, _mm_sub_pd(_mm_loadu_pd(fj), fxy));
    _mm_store_sd(fj + 2, _mm_sub_sd(_mm_load_sd(fj + 2), fz));
  }
  // Row s's f_i: the scan at its last pair, or, with no pair in this chunk, the carried sum (row 0)
  // or 0. The last row, if the chunk ends inside it, is carried on instead.
  const int rows = split ? segments - 1 : segments;
  __m128d rxy = carry_xy, rz = carry_z;
  int start = 0;
  for (int s = 0; s < segments; ++s) {
    const int end = b.seg_end[s], at = end > 0 ? end - 1 : 0;
    const __m128d has = _mm_castsi128_pd(_mm_set1_epi64x(end > start ? -1 : 0));
    const __m128d base_xy = s == 0 ? carry_xy : _mm_setzero_pd(), base_z = s == 0 ? carry_z : _mm_setzero_pd();
    rxy = _mm_blendv_pd(base_xy, _mm_load_pd(sum_xy[at]), has);
    rz = _mm_blendv_pd(base_z, _mm_load_sd(sum_z + at), has);
    if (s < rows) {
      double* fr = f + 3 * static_cast<std::size_t>(b.seg_row[s]);
      _mm_storeu_pd(fr, _mm_add_pd(_mm_loadu_pd(fr), rxy));
      _mm_store_sd(fr + 2, _mm_add_sd(_mm_load_sd(fr + 2), rz));
    }
    start = end;
  }
  _mm_storel_pd(fi, rxy);
  _mm_storeh_pd(fi + 1, rxy);
  _mm_store_sd(fi + 2, rz);
}
#else
inline bool pair_loop_avx2() {
  return false;
}
#endif

// Pass 2 of accumulate_pair_forces_rows: the kernel on a chunk's n kept pairs, fpair from r² (and
// the coefficients, qqrd2e q_i q_j). A loop with no branch and no gather, which the compiler
// vectorises where the kernel allows (the Lennard-Jones family): IEEE operations lane by lane, so
// the same bits as one pair at a time, whatever the vector width.
template <class Kernel, class Buffers, class Params>
[[gnu::always_inline]] inline void pair_chunk_kernel(Buffers& b, int n, const Params& one) {
  for (int m = 0; m < n; ++m) {
    const Params* p;
    if constexpr (Buffers::kUniform)
      p = &one;
    else
      p = b.pn[m];
    double e = 0.0, fp = 0.0;
    if constexpr (ChargedKernel<Kernel>) {
      double ecoul = 0.0;
      Kernel::eval(b.r2[m], *p, b.qq[m], 1.0, 1.0, e, ecoul, fp);
    } else {
      Kernel::eval(b.r2[m], *p, e, fp);
    }
    b.fpair[m] = fp;
  }
}

#if defined(__x86_64__)
// The same compiled for AVX2 (no FMA: the same operations, four lanes per division where SSE2 has
// two), for the uncharged kernels: the charged ones (coulomb_potentials.hpp: tables, erfc) do not
// vectorise, and their calls are not inlined across the change of target (the peptide's pair phase
// measured ≈ 1.2× slower so).
template <class Kernel, class Buffers, class Params>
[[gnu::target("avx2")]] void pair_chunk_kernel_avx2(Buffers& b, int n, const Params& one) {
  pair_chunk_kernel<Kernel>(b, n, one);
}
#else
template <class Kernel, class Buffers, class Params>
void pair_chunk_kernel_avx2(Buffers& b, int n, const Params& one) {  // not called: no AVX2 here
  pair_chunk_kernel<Kernel>(b, n, one);
}
#endif

template <class Kernel, bool kPeriodic, bool kOneType>
void accumulate_pair_forces_rows(const NeighborList& list, int first, int last,
                                 const TypePairMatrix<typename Kernel::Params>& params, const int* type, int uniform,
                                 const Eigen::Matrix3Xd& xw, const NearestImage& near, double* f,
                                 const PairCharges& charges = {}, bool vector = true) {
  using Params = typename Kernel::Params;
  constexpr int kChunk = kPairChunk;
  constexpr bool kCharged = ChargedKernel<Kernel>;
  const double* xp = xw.data();
  const std::int64_t* offset = list.offsets().data();
  const int* nbr = list.neighbors().data();
  const std::int64_t last_pair = first < last ? offset[last] - 1 : 0;  // the prefetch reads no further
  [[maybe_unused]] const Params one = kOneType ? params.row(uniform)[uniform] : Params{};
  PairChunkBuffers<Params, kOneType, kCharged> b;
  // The AVX2 passes where the CPU has it (pass 1: pair_chunk_separations_avx2; pass 2 for the
  // uncharged kernels: pair_chunk_kernel_avx2; pass 3: pair_chunk_forces_avx2); vector = false, the
  // scalar ones (the reference of the tests and of tools/benchmarks/pair_loop.cpp).
  [[maybe_unused]] const bool avx2 = vector && pair_loop_avx2();
  double fxi = 0.0, fyi = 0.0, fzi = 0.0;  // f_i of the open row, carried over a chunk's end
  int i = first;
  std::int64_t k = first < last ? offset[first] : 0;
  bool carried = false;  // the chunk opens in the middle of row i (its f_i sums carried)
  while (i < last) {
    // Pass 1: listed pairs from (i, k) on, at most kChunk of them, the interacting ones compacted.
    int n = 0, segments = 0;
    bool split = false;  // the chunk ends in the middle of its last row
#if defined(__x86_64__)
    if (avx2) {
      PairChunkCursor c{i, k};
      if (kPeriodic && near.rounded)
        pair_chunk_separations_avx2<true, true, kOneType, kCharged>(b, c, xp, nbr, offset, last, last_pair, near, one,
                                                                    params, type, charges);
      else
        pair_chunk_separations_avx2<kPeriodic, false, kOneType, kCharged>(b, c, xp, nbr, offset, last, last_pair, near,
                                                                          one, params, type, charges);
      i = c.i;
      k = c.k;
      n = c.n;
      segments = c.segments;
      split = c.split;
    }
#endif
    while (!avx2 && i < last && segments < kChunk) {
      const std::int64_t end = offset[i + 1];
      if (end == k) {  // no listed pair (left in this row): passed over, as pass 1 with AVX2 does
        ++i;
        continue;
      }
      const std::int64_t stop = std::min<std::int64_t>(end, k + (kChunk - n));
      const double xi = xp[3 * i], yi = xp[3 * i + 1], zi = xp[3 * i + 2];
      [[maybe_unused]] const Params* prow = kOneType ? nullptr : params.row(type[i]);
      [[maybe_unused]] double qi = 0.0;
      if constexpr (kCharged) qi = charges.qqrd2e * charges.q[i];
      for (; k < stop; ++k) {
        const int j = nbr[k];
        __builtin_prefetch(xp + 3 * nbr[std::min(k + kPairPrefetch, last_pair)]);
        double ex = xi - xp[3 * j], ey = yi - xp[3 * j + 1], ez = zi - xp[3 * j + 2];
        if constexpr (kPeriodic) near.apply(ex, ey, ez);
        const double s = ex * ex + ey * ey + ez * ez;
        double rc2;
        if constexpr (kOneType) {
          rc2 = one.rc2;
        } else {
          const Params* p = prow + type[j];
          b.pn[n] = p;
          rc2 = p->rc2;
        }
        b.j3[n] = 3 * static_cast<std::uint32_t>(j);
        b.dx[n] = ex;
        b.dy[n] = ey;
        b.dz[n] = ez;
        b.r2[n] = s;
        if constexpr (kCharged) b.qq[n] = qi * charges.q[j];
        n += s < rc2 ? 1 : 0;
      }
      b.seg_row[segments] = i;
      b.seg_end[segments] = n;
      ++segments;
      if (k < end) {  // the buffer is full
        split = true;
        break;
      }
      ++i;  // k = offset[i]: the next row starts where this one ended
      if (n == kChunk) break;
    }
    // Pass 2: the kernel on the interacting pairs.
    if (avx2 && !kCharged)
      pair_chunk_kernel_avx2<Kernel>(b, n, one);
    else
      pair_chunk_kernel<Kernel>(b, n, one);
#if defined(__x86_64__)
    // Pass 3: the forces, in the list's order.
    if (avx2) {
      double fi[3] = {fxi, fyi, fzi};
      pair_chunk_forces_avx2(n, segments, b, carried, split, f, fi);
      fxi = fi[0], fyi = fi[1], fzi = fi[2];
      carried = split;
      continue;
    }
#endif
    // Pass 3 without AVX2: the same, one row after another.
    int m = 0;
    for (int s = 0; s < segments; ++s) {
      if (!(s == 0 && carried)) fxi = fyi = fzi = 0.0;
      for (; m < b.seg_end[s]; ++m) {
        double* fj = f + b.j3[m];
        const double fx = b.fpair[m] * b.dx[m], fy = b.fpair[m] * b.dy[m], fz = b.fpair[m] * b.dz[m];
        fxi += fx;
        fyi += fy;
        fzi += fz;
        fj[0] -= fx;
        fj[1] -= fy;
        fj[2] -= fz;
      }
      if (s + 1 < segments || !split) {
        const int row = b.seg_row[s];
        f[3 * row] += fxi;
        f[3 * row + 1] += fyi;
        f[3 * row + 2] += fzi;
      }
    }
    carried = split;
  }
}

// accumulate_pair_forces_rows with its type specialisation chosen (uniform ≥ 0: every particle of
// that type).
template <class Kernel, bool kPeriodic>
void pair_forces_rows(const NeighborList& list, int first, int last,
                      const TypePairMatrix<typename Kernel::Params>& params, const int* type, int uniform,
                      const Eigen::Matrix3Xd& xw, const NearestImage& near, double* f, const PairCharges& charges) {
  if (uniform >= 0)
    accumulate_pair_forces_rows<Kernel, kPeriodic, true>(list, first, last, params, type, uniform, xw, near, f,
                                                         charges);
  else
    accumulate_pair_forces_rows<Kernel, kPeriodic, false>(list, first, last, params, type, -1, xw, near, f, charges);
}

// The special pairs with 0 < w < 1 (special_bonds): the same kernel, energy and force scaled
// by w (kEnergy false: the forces alone, no sums). They are kept out of the Verlet list, so they are looked at every
// call — a short list (at most a few per particle), and the common case w12 = 0, w13 = 1 has none. ghost (kShares): as
// in accumulate_pair_rows, a pair with a ghost counts half in the sums (null: every pair whole). A charged kernel gets
// the pair's two weights as its factors (SpecialPair::weight, weight_coul) and scales its energies itself; the pairs
// handed in are those the term evaluates (with an EwaldKernel the excluded ones too).
template <class Kernel, bool kForces, bool kVirial, bool kShares = false, bool kEnergy = true>
PairSums accumulate_scaled_pairs(std::span<const SpecialPair> pairs,
                                 const TypePairMatrix<typename Kernel::Params>& params, const int* type,
                                 const Eigen::Matrix3Xd& x, const MinimumImage& mi, double* f,
                                 const char* ghost = nullptr, const PairCharges& charges = {}) {
  using Params = typename Kernel::Params;
  const double* xp = x.data();
  PairSums sums;
  for (const SpecialPair& sp : pairs) {
    const int i = sp.i, j = sp.j;
    double dx = xp[3 * i] - xp[3 * j], dy = xp[3 * i + 1] - xp[3 * j + 1], dz = xp[3 * i + 2] - xp[3 * j + 2];
    mi.apply(dx, dy, dz);
    const double r2 = dx * dx + dy * dy + dz * dz;
    const Params& p = params.row(type[i])[type[j]];
    if (!(r2 < p.rc2)) continue;
    double e = 0.0, fpair = 0.0;
    [[maybe_unused]] double ecoul = 0.0;
    if constexpr (ChargedKernel<Kernel>) {
      double evdwl = 0.0;
      Kernel::eval(r2, p, charges.qqrd2e * charges.q[i] * charges.q[j], sp.weight, sp.weight_coul, evdwl, ecoul, fpair);
      e = evdwl + ecoul;
    } else {
      Kernel::eval(r2, p, e, fpair);
      fpair *= sp.weight;
      e *= sp.weight;
    }
    if constexpr (kEnergy)
      add_pair_sums<ChargedKernel<Kernel>, kForces, kVirial>(
          sums, kShares && ghost && (ghost[i] || ghost[j]) ? 0.5 : 1.0, e, ecoul, fpair, r2, dx, dy, dz);
    if constexpr (kForces) {
      f[3 * i] += fpair * dx;
      f[3 * i + 1] += fpair * dy;
      f[3 * i + 2] += fpair * dz;
      f[3 * j] -= fpair * dx;
      f[3 * j + 1] -= fpair * dy;
      f[3 * j + 2] -= fpair * dz;
    }
  }
  return sums;
}

// A set of particle indices as ascending, disjoint runs [begin, end).
using IndexRuns = std::vector<std::array<int, 2>>;

// The particles that rows first … last − 1 of the half list read and write: the rows themselves
// and their neighbours j, as runs, two runs with a gap of at most kRunGap particles between them
// taken as one (the gap's 48 bytes of f lie mostly in cache lines the runs touch anyway, and each
// run costs a loop of its own in each pass). marks: a bit per particle, all 0 on entry and on
// return. In a melt whose chains lie at consecutive indices the set is the neighbourhoods of a
// part's chains, however many particles there are: a part of the parallel pair loop clears,
// copies and adds only these.
inline constexpr int kRunGap = 2;

inline void touched_runs(const NeighborList& list, int first, int last, std::vector<std::uint64_t>& marks,
                         IndexRuns& runs) {
  runs.clear();
  if (first >= last) return;
  const int n = list.num_particles();
  const std::size_t words = (static_cast<std::size_t>(n) + 63) / 64;
  if (marks.size() < words) marks.resize(words, 0);
  const std::span<const std::int64_t> offset = list.offsets();
  const int* nbr = list.neighbors().data();
  const auto mark = [&](int k) { marks[k >> 6] |= std::uint64_t{1} << (k & 63); };
  for (int i = first; i < last; ++i) mark(i);
  for (std::int64_t k = offset[first]; k < offset[last]; ++k) mark(nbr[k]);
  int begin = 0, end = -1;  // the run being extended
  for (std::size_t w = static_cast<std::size_t>(first) >> 6; w < words; ++w) {
    std::uint64_t bits = marks[w];
    if (bits == 0) continue;
    marks[w] = 0;
    while (bits != 0) {  // each stretch of set bits, lowest first
      const int b = std::countr_zero(bits);
      const int len = std::countr_one(bits >> b);
      const int k = static_cast<int>(64 * w) + b;
      if (end >= 0 && k - end <= kRunGap) {
        end = k + len;
      } else {
        if (end >= 0) runs.push_back({begin, end});
        begin = k;
        end = k + len;
      }
      bits = b + len == 64 ? 0 : bits & ~(((std::uint64_t{1} << len) - 1) << b);
    }
  }
  runs.push_back({begin, end});
}

// The parallel pair loop's passes over a part's runs of particles (each run 3 (e − b) doubles, a
// flat array): the sum of a buffer into f, which sets the buffer back to 0, and the copy of the
// positions. A run is ≈ 10 particles in a melt, the rows' own runs a few thousand; four doubles at a
// time where the CPU has AVX2 (each lane the scalar addition: the same bits). GCC makes the copy's
// loop a call of memcpy, the sum's stays a loop: no call of memset per run.
#if defined(__x86_64__)
[[gnu::target("avx2")]] inline void add_and_clear_avx2(double* __restrict dst, double* __restrict src,
                                                       std::int64_t len) {
  const __m256d zero = _mm256_setzero_pd();
  std::int64_t m = 0;
  for (; m + 4 <= len; m += 4) {
    _mm256_storeu_pd(dst + m, _mm256_add_pd(_mm256_loadu_pd(dst + m), _mm256_loadu_pd(src + m)));
    _mm256_storeu_pd(src + m, zero);
  }
  for (; m < len; ++m) {
    dst[m] += src[m];
    src[m] = 0.0;
  }
}

[[gnu::target("avx2")]] inline void copy_doubles_avx2(double* __restrict dst, const double* __restrict src,
                                                      std::int64_t len) {
  std::int64_t m = 0;
  for (; m + 4 <= len; m += 4) _mm256_storeu_pd(dst + m, _mm256_loadu_pd(src + m));
  for (; m < len; ++m) dst[m] = src[m];
}
#endif

// dst[m] += src[m], then src[m] = 0, for m < len: a part's buffer added into f and left as it was
// before the part wrote there (0), so that no call has to clear it first.
inline void add_and_clear(double* __restrict dst, double* __restrict src, std::int64_t len) {
#if defined(__x86_64__)
  if (pair_loop_avx2()) return add_and_clear_avx2(dst, src, len);
#endif
  for (std::int64_t m = 0; m < len; ++m) {
    dst[m] += src[m];
    src[m] = 0.0;
  }
}

// dst[m] = src[m] for m < len.
inline void copy_doubles(double* __restrict dst, const double* __restrict src, std::int64_t len) {
#if defined(__x86_64__)
  if (pair_loop_avx2()) return copy_doubles_avx2(dst, src, len);
#endif
  Eigen::Map<Eigen::VectorXd>(dst, len) = Eigen::Map<const Eigen::VectorXd>(src, len);
}

// A part's force buffer: doubles that start as 0, from calloc — a large block comes as fresh
// pages of zeros, so the pages a part never writes are never written, where clearing the whole
// buffer would write them all. Not part of any value: a copy is empty (a call sizes it again).
class ZeroedDoubles {
 public:
  ZeroedDoubles() = default;
  ZeroedDoubles(const ZeroedDoubles&) {}
  ZeroedDoubles& operator=(const ZeroedDoubles&) {
    release();
    return *this;
  }
  ~ZeroedDoubles() { release(); }

  // size doubles, every one 0 (what it held is dropped).
  void zeros(std::size_t size) {
    release();
    if (size == 0) return;
    data_ = static_cast<double*>(std::calloc(size, sizeof(double)));
    if (data_ == nullptr) throw std::bad_alloc();
    size_ = size;
  }
  double* data() { return data_; }
  std::size_t size() const { return size_; }

 private:
  void release() {
    std::free(data_);
    data_ = nullptr;
    size_ = 0;
  }
  double* data_ = nullptr;
  std::size_t size_ = 0;
};

// Per-thread buffers of the parallel pair loop, reused from call to call. A part's positions hold
// values only on its touched runs; the rest is never written nor read. Its force buffer is 0
// everywhere between calls: a call writes only its touched runs, and the sum that adds them into f
// sets them back to 0 (add_and_clear).
struct PairScratch {
  std::vector<ZeroedDoubles> force;               // one per part (part 0 writes into f itself): 3N doubles
  std::vector<Eigen::Matrix3Xd> positions;        // one per part: its own copy of the positions it reads
  std::vector<IndexRuns> touched;                 // per part: touched_runs of its rows
  std::vector<std::vector<std::uint64_t>> marks;  // per part: touched_runs' scratch
  std::uint64_t touched_build = 0;                // the list's build_id that `touched` is for …
  int touched_parts = 0;                          // … and the part count
  // Every force buffer is 0 (of its size). False while a call runs: a call that did not end (a part
  // threw) leaves it false, and the next one clears the buffers whole.
  bool force_zero = true;
  std::array<PairSums, kMaxParts> sums;
  std::array<int, kMaxParts + 1> first_row;
};

// The listed pairs on `parts` threads (parallel.hpp): part u takes a contiguous block of rows
// holding about 1/parts of the pairs and writes f_i and f_j into its own buffer (a neighbour j
// may belong to any block) — part 0 into f itself; then each thread adds, for a block of
// particles, the other buffers in part order. Fixed blocks and a fixed order: the same sums for a
// given thread count.
//
// A part touches only its rows and their neighbours (touched_runs, found once per list build): it
// copies the positions there alone, and the sum adds buffer u into f_k only where part u touched
// k — the other buffers hold 0 there, and f_k + 0 = f_k, so the sum is the one over every buffer.
// The sum also sets what it read back to 0 (add_and_clear), so a buffer is 0 at the next call
// without a pass that clears it. Memory traffic per call: Σ_u |touched_u| particles, ≈ N + the
// neighbours of the parts' boundaries when the particle order follows space, at most N + pairs,
// rather than N per part.
//
// xl: the positions of the list's frame (NeighborList::wrapped_positions when periodic, computed
// in particle blocks). Each part first copies the runs of them it reads, sequential passes
// (copying them rather than wrapping again per part: the wrap is done once). Why a copy: the
// neighbours x_j of a part's rows lie anywhere in the system, and read in place the lines of x
// that the other threads had just written (the drift and the wrap run in particle blocks) would
// come over one scattered read at a time, which makes each part's pairs dearer on two threads
// than on one (docs/performance_notes.md).
//
// kEnergy false: the force-only pass (accumulate_pair_forces_rows; uniform as there), no sums.
template <class Kernel, bool kPeriodic, bool kForces, bool kVirial, bool kShares = false, bool kEnergy = true>
PairSums accumulate_pair_rows_parallel(const NeighborList& list, int parts,
                                       const TypePairMatrix<typename Kernel::Params>& params, const int* type,
                                       const Eigen::Matrix3Xd& xl, const NearestImage& near, double* f,
                                       PairScratch& scratch, const PairCharges& charges = {}, int uniform = -1) {
  static_assert(kEnergy || (kForces && !kVirial && !kShares), "the force-only pass adds forces and nothing else");
  const int n = list.num_particles();
  const std::span<const std::int64_t> offset = list.offsets();
  const std::int64_t pairs = offset[n];
  for (int u = 0; u <= parts; ++u)  // row block u: the rows whose pairs start in [u, u+1)·pairs/parts
    scratch.first_row[u] =
        u == parts ? n
                   : static_cast<int>(std::lower_bound(offset.begin(), offset.end(), block_begin(pairs, parts, u)) -
                                      offset.begin());
  scratch.first_row[0] = 0;
  if (kForces && static_cast<int>(scratch.force.size()) < parts) scratch.force.resize(parts);
  if (static_cast<int>(scratch.positions.size()) < parts) scratch.positions.resize(parts);
  if (static_cast<int>(scratch.touched.size()) < parts) {
    scratch.touched.resize(parts);
    scratch.marks.resize(parts);
  }
  const bool find_touched = scratch.touched_build != list.build_id() || scratch.touched_parts != parts;
  scratch.touched_build = 0;  // until every part has found its runs
  const bool force_zero = scratch.force_zero;
  scratch.force_zero = false;  // until the sum has set every buffer back to 0
  run_parts(parts, [&](int u) {
    const int first = scratch.first_row[u], last = std::max(first, scratch.first_row[u + 1]);
    if (find_touched) touched_runs(list, first, last, scratch.marks[u], scratch.touched[u]);
    const IndexRuns& runs = scratch.touched[u];
    Eigen::Matrix3Xd& xw = scratch.positions[u];
    xw.resize(3, n);  // allocates only the first time
    for (const auto& [b, e] : runs) copy_doubles(xw.data() + 3 * b, xl.data() + 3 * b, 3 * (e - b));
    double* fu = nullptr;
    if constexpr (kForces) {
      if (u == 0) {
        fu = f;  // part 0 adds into f itself: one buffer fewer to sum
      } else {
        ZeroedDoubles& fw = scratch.force[u];
        const std::size_t size = 3 * static_cast<std::size_t>(n);
        if (!force_zero || fw.size() != size) fw.zeros(size);  // the first call, a new particle count
        fu = fw.data();
      }
    }
    if constexpr (kEnergy) {
      scratch.sums[u] = accumulate_pair_rows<Kernel, kPeriodic, kForces, kVirial, kShares>(list, first, last, params,
                                                                                           type, xw, near, fu, charges);
    } else {
      pair_forces_rows<Kernel, kPeriodic>(list, first, last, params, type, uniform, xw, near, fu, charges);
      scratch.sums[u] = PairSums{};
    }
  });
  scratch.touched_build = list.build_id();
  scratch.touched_parts = parts;
  if constexpr (kForces)
    parallel_blocks(n, parts, [&](std::int64_t begin, std::int64_t end) {
      for (int u = 1; u < parts; ++u) {  // f_k += buffer u's f_k where part u touched k, in part order
        const IndexRuns& runs = scratch.touched[u];
        double* fu = scratch.force[u].data();
        auto r = std::lower_bound(runs.begin(), runs.end(), begin,
                                  [](const std::array<int, 2>& run, std::int64_t k) { return run[1] <= k; });
        for (; r != runs.end() && (*r)[0] < end; ++r) {
          const std::int64_t lo = std::max<std::int64_t>(begin, (*r)[0]), hi = std::min<std::int64_t>(end, (*r)[1]);
          add_and_clear(f + 3 * lo, fu + 3 * lo, 3 * (hi - lo));
        }
      }
    });
  scratch.force_zero = kForces || force_zero;  // a pass without forces leaves the buffers as they were
  PairSums total;
  for (int u = 0; u < parts; ++u) {
    total.energy += scratch.sums[u].energy;
    total.coulomb += scratch.sums[u].coulomb;
    total.virial += scratch.sums[u].virial;
    total.diagonal.add(scratch.sums[u].diagonal);
  }
  return total;
}

// The whole half list plus the scaled special pairs: adds −∇E into f (if kForces) and returns
// Σ E and Σ r_ij·f_ij (if kVirial; with kShares this process's share of both, see
// accumulate_pair_rows, the scaled pairs' too). The list must be up to date for x and box (update).
// kEnergy false (with kForces alone): the force-only pass, the same forces bit for bit and empty
// sums; uniform ≥ 0 says every particle has that type (accumulate_pair_forces_rows).
template <class Kernel, bool kForces, bool kVirial, bool kShares = false, bool kEnergy = true>
PairSums accumulate_pairs(NeighborList& list, std::span<const SpecialPair> scaled,
                          const TypePairMatrix<typename Kernel::Params>& params, const int* type,
                          const Eigen::Matrix3Xd& x, const Box& box, double* f, PairScratch& scratch,
                          const PairCharges& charges = {}, int uniform = -1) {
  static_assert(kEnergy || (kForces && !kVirial && !kShares), "the force-only pass adds forces and nothing else");
  const int n = list.num_particles();
  const int parts = threads_for(static_cast<std::int64_t>(list.num_pairs()));
  const bool periodic = box.any_periodic();
  const Eigen::Matrix3Xd& xl = periodic ? list.wrapped_positions(x) : x;
  const NearestImage near(box, list.cutoff() + list.skin());
  PairSums listed;
  if (parts > 1) {  // each part copies the wrapped positions it reads
    listed = periodic ? accumulate_pair_rows_parallel<Kernel, true, kForces, kVirial, kShares, kEnergy>(
                            list, parts, params, type, xl, near, f, scratch, charges, uniform)
                      : accumulate_pair_rows_parallel<Kernel, false, kForces, kVirial, kShares, kEnergy>(
                            list, parts, params, type, xl, near, f, scratch, charges, uniform);
  } else {
    run_as_one_part(static_cast<std::int64_t>(list.num_pairs()), [&] {
      if constexpr (!kEnergy) {
        if (periodic)
          pair_forces_rows<Kernel, true>(list, 0, n, params, type, uniform, xl, near, f, charges);
        else
          pair_forces_rows<Kernel, false>(list, 0, n, params, type, uniform, xl, near, f, charges);
        return;
      }
      listed = periodic ? accumulate_pair_rows<Kernel, true, kForces, kVirial, kShares>(list, 0, n, params, type, xl,
                                                                                        near, f, charges)
                        : accumulate_pair_rows<Kernel, false, kForces, kVirial, kShares>(list, 0, n, params, type, xl,
                                                                                         near, f, charges);
    });
  }
  // The scaled pairs round the separations of the wrapped positions (MinimumImage): they are few,
  // and not tied to the list's build. Wrapped, as the listed pairs: a decomposed run's halo hands
  // the pair terms wrapped positions (NeighborList::set_positions_wrapped), and the same positions
  // give the same bits.
  const PairSums special = accumulate_scaled_pairs<Kernel, kForces, kVirial, kShares, kEnergy>(
      scaled, params, type, xl, MinimumImage(box), f, kShares ? list_share_flags(list) : nullptr, charges);
  PairSums total;
  total.energy = listed.energy + special.energy;
  total.coulomb = listed.coulomb + special.coulomb;
  total.virial = listed.virial + special.virial;
  total.diagonal.add(listed.diagonal);
  total.diagonal.add(special.diagonal);
  return total;
}

}  // namespace stiffmd
