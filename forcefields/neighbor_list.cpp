#include "forcefields/neighbor_list.hpp"

#include "core/parallel.hpp"

#include <algorithm>
#include <array>
#include <atomic>
#include <compare>
#include <limits>
#include <sstream>
#include <stdexcept>
#include <string>
#include <tuple>

#if defined(__x86_64__)
#include <immintrin.h>
#endif

namespace stiffmd {
namespace {

constexpr char kAxis[3] = {'x', 'y', 'z'};

bool same_box(const Box& a, const Box& b) {
  return a.periodic == b.periodic && a.lengths == b.lengths && a.origin == b.origin;
}

// Cell coordinate of a scaled coordinate s ∈ [0, n], clamped into 0 … n − 1. Written so that
// NaN (a blown-up configuration) lands in cell 0 instead of an out-of-range index: the engine
// reports non-finite states itself, the list must only not write out of bounds.
int cell_coordinate(double s, int n) {
  if (s >= 0.0 && s < n) return static_cast<int>(s);
  return s >= n ? n - 1 : 0;
}

// The distance test of one particle at (xi, yi, zi) against the candidates t = first … last − 1
// (positions xs, ys, zs; their particle indices ks): the indices of those with
// (dx² + dy²) + dz² < r2, d = x_i − x_t, written to hit in the order met; returns their count. A
// candidate is written and kept by advancing the count, without a branch (about one in seven is a
// neighbour, at random: a branch would mispredict often). hit has room for last − first + 3
// entries, and xs, ys, zs, ks may be read up to 3 entries past last (padding: see the AVX2 form).
int test_candidates_scalar(double xi, double yi, double zi, const double* __restrict xs, const double* __restrict ys,
                           const double* __restrict zs, const int* __restrict ks, int first, int last, double r2,
                           int* __restrict hit) {
  int found = 0;
  for (int t = first; t < last; ++t) {
    const double dx = xi - xs[t], dy = yi - ys[t], dz = zi - zs[t];
    hit[found] = ks[t];
    found += dx * dx + dy * dy + dz * dz < r2;
  }
  return found;
}

#if defined(__x86_64__)
// The same test four candidates at a time (AVX2): the same IEEE operations lane by lane (no FMA:
// -ffp-contract=off), so the same candidates pass. The slots of the passing ones are packed to
// the front of a 128-bit vector by a byte shuffle chosen by the 4-bit mask (kPack) and stored at
// hit + found: a store of four, of which the count advances by the mask's population — entries
// past it are overwritten by the next store or ignored. The last group reads up to three entries
// past `last` and masks them off: no scalar loop for the remainder, whose 0 … 3 iterations
// mispredicted its exit branch about once per call.
struct PackTable {
  alignas(16) unsigned char control[16][16];
  constexpr PackTable() : control{} {
    for (int mask = 0; mask < 16; ++mask) {
      int out = 0;
      for (int lane = 0; lane < 4; ++lane)
        if (mask & (1 << lane)) {
          for (int b = 0; b < 4; ++b) control[mask][4 * out + b] = static_cast<unsigned char>(4 * lane + b);
          ++out;
        }
      for (; out < 4; ++out)
        for (int b = 0; b < 4; ++b) control[mask][4 * out + b] = 0x80;  // zero
    }
  }
};
constexpr PackTable kPack;

// The lanes of a group of four that lie before the end, by the entries left (at most 4).
constexpr int kLanesBefore[5] = {0, 1, 3, 7, 15};

// kSentinels: the three entries past `last` are known to fail the test (x = +∞, written by the
// caller), so the last group needs no mask.
template <bool kSentinels = false>
[[gnu::target("avx2,popcnt")]] int test_candidates_avx2(double xi, double yi, double zi, const double* __restrict xs,
                                                        const double* __restrict ys, const double* __restrict zs,
                                                        const int* __restrict ks, int first, int last, double r2,
                                                        int* __restrict hit) {
  const __m256d vx = _mm256_set1_pd(xi), vy = _mm256_set1_pd(yi), vz = _mm256_set1_pd(zi), vr2 = _mm256_set1_pd(r2);
  int found = 0;
  for (int t = first; t < last; t += 4) {
    const __m256d dx = _mm256_sub_pd(vx, _mm256_loadu_pd(xs + t));
    const __m256d dy = _mm256_sub_pd(vy, _mm256_loadu_pd(ys + t));
    const __m256d dz = _mm256_sub_pd(vz, _mm256_loadu_pd(zs + t));
    const __m256d d2 =
        _mm256_add_pd(_mm256_add_pd(_mm256_mul_pd(dx, dx), _mm256_mul_pd(dy, dy)), _mm256_mul_pd(dz, dz));
    int mask = _mm256_movemask_pd(_mm256_cmp_pd(d2, vr2, _CMP_LT_OQ));
    if constexpr (!kSentinels) mask &= kLanesBefore[std::min(last - t, 4)];
    const __m128i slots = _mm_loadu_si128(reinterpret_cast<const __m128i*>(ks + t));
    const __m128i control = _mm_load_si128(reinterpret_cast<const __m128i*>(kPack.control[mask]));
    _mm_storeu_si128(reinterpret_cast<__m128i*>(hit + found), _mm_shuffle_epi8(slots, control));
    found += _mm_popcnt_u32(static_cast<unsigned>(mask));
  }
  return found;
}

#endif

// Entries first … last − 1 of the cell order (coordinates xs, ys, zs, particle indices ps) copied to
// to_x, to_y, to_z, to_p at x_j + shift (d = x_i − (x_j + shift)), four at a time: the copy reads and
// writes up to three entries past the range (the arrays' padding); those are overwritten by the
// next copy or never read as candidates. A range holds ≈ 3–9 particles on a melt: a loop of
// whole groups of four, without a remainder, is a few instructions per entry where the loop by
// entry with its remainder took ≈ 27.
void gather_shifted_scalar(const double* __restrict xs, const double* __restrict ys, const double* __restrict zs,
                           const int* __restrict ps, int first, int last, double sx, double sy, double sz,
                           double* __restrict to_x, double* __restrict to_y, double* __restrict to_z,
                           int* __restrict to_p) {
  for (int t = first; t < last; t += 4)
    for (int l = 0; l < 4; ++l) {
      to_x[t - first + l] = xs[t + l] + sx;
      to_y[t - first + l] = ys[t + l] + sy;
      to_z[t - first + l] = zs[t + l] + sz;
      to_p[t - first + l] = ps[t + l];
    }
}

#if defined(__x86_64__)
[[gnu::target("avx2")]] void gather_shifted_avx2(const double* __restrict xs, const double* __restrict ys,
                                                 const double* __restrict zs, const int* __restrict ps, int first,
                                                 int last, double sx, double sy, double sz, double* __restrict to_x,
                                                 double* __restrict to_y, double* __restrict to_z,
                                                 int* __restrict to_p) {
  const __m256d vx = _mm256_set1_pd(sx), vy = _mm256_set1_pd(sy), vz = _mm256_set1_pd(sz);
  for (int t = first; t < last; t += 4) {
    const int o = t - first;
    _mm256_storeu_pd(to_x + o, _mm256_add_pd(_mm256_loadu_pd(xs + t), vx));
    _mm256_storeu_pd(to_y + o, _mm256_add_pd(_mm256_loadu_pd(ys + t), vy));
    _mm256_storeu_pd(to_z + o, _mm256_add_pd(_mm256_loadu_pd(zs + t), vz));
    _mm_storeu_si128(reinterpret_cast<__m128i*>(to_p + o), _mm_loadu_si128(reinterpret_cast<const __m128i*>(ps + t)));
  }
}
#endif

// One part's share of the half-stencil search (NeighborList::search_half_stencil): the cells of
// columns first_column … last_column − 1 in the cell order, each cell's candidates gathered (its
// own particles, the next cell along z, four columns of three cells), each of its particles
// tested against the later candidates, and the hits recorded as pairs (min, max) less the
// exclusions, counted per row for the CSR sort. A template over the kernels so that the AVX2
// instantiation inlines the copies and the tests into the loop (search_columns_avx2): the calls of
// one copy per range and one test per particle, with their arguments, were a third of the loop's
// instructions.
//
// With ghosts (kHalo: a decomposed run's pair set, its home beads and its halo) the bins put each
// cell's home beads first (NeighborList::bin): the home beads' rows are searched exactly as
// without ghosts — every pair of theirs is one the list keeps — and a ghost's row only against
// the home beads of the forward cells, a prefix of each cell's range, so no pair of two ghosts
// is formed and no flag is read per candidate. Every kept pair is tested as the search without
// ghosts tests it: d = x_i − (x_j + shift), i in the cell whose forward cell holds j (within a
// cell the order of i and j may swap, which negates d exactly): the same hits, and after the rows
// are sorted the same list, less its pairs of two ghosts.
//
// The candidates of a cell's particles are gathered once per cell into contiguous arrays
// (structure of arrays): the cell's own particles first, then those of its forward neighbours,
// shifted next to it. The m-th particle of the cell is then tested against entries m + 1 … end in
// one loop. The same candidates in the same order as a loop per neighbour cell, whose few
// iterations (≈ 2.6 particles per cell on a melt) made the loop's exit branch mispredict about
// once per cell visited.
struct HalfStencilPart {
  const double *cxs, *cys, *czs;  // the cell order's positions (structure of arrays)
  const int* cp;                  // the cell order's particles
  const int* cs;                  // the cells' starts
  const int* adjacent[3];         // NeighborList::adjacent_, adjacent_shift_
  const double* adjacent_shift[3];
  int ny, nz;
  // The stored cells' z coordinate that follows the box's face (NeighborList::bin's window: a
  // window across the face stores cell nz_full − 1 next to cell 0, a shift of L apart; 0 when the
  // window does not cross it): the ranges that merge consecutive cells along z stop there.
  int z_face;
  double rlist2;
  int first_column, last_column;
  double *gxs, *gys, *gzs;  // the candidates of one cell (padded)
  int* gks;
  int* hit;                 // one particle's hits (padded)
  const int* excl_offsets;  // the exclusions, CSR (null: none)
  const int* excl;
  int* row_count;            // the part's pairs per row
  std::vector<int>*pi, *pj;  // the part's pair buffers (their size is their capacity)
  std::size_t used;          // pairs in them
  // With halo beads (ghosts): each cell's beads that are not, a prefix of the cell's range (null:
  // no ghosts), and a second candidate buffer for the forward cells' home beads (padded).
  const int* home;
  double *hxs, *hys, *hzs;
  int* hks;
};

#if defined(__x86_64__)
// The hits of particle i (hit[0 … count − 1], read in groups of four up to three past count) as
// pairs (min, max) at to_i, to_j (room for count + 3), less i's exclusions [excl, excl_end), in the
// order found, each row's count raised: the kept ones packed by the mask's shuffle (kPack), their
// min and max four at a time. Returns the pairs written.
[[gnu::target("avx2,popcnt")]] int record_hits_avx2(int i, const int* __restrict hit, int count,
                                                    const int* __restrict excl, const int* __restrict excl_end,
                                                    int* __restrict to_i, int* __restrict to_j,
                                                    int* __restrict row_count) {
  const __m128i vi = _mm_set1_epi32(i);
  int kept = 0;
  for (int h = 0; h < count; h += 4) {
    const __m128i j = _mm_loadu_si128(reinterpret_cast<const __m128i*>(hit + h));
    __m128i excluded = _mm_setzero_si128();
    for (const int* e = excl; e != excl_end; ++e)
      excluded = _mm_or_si128(excluded, _mm_cmpeq_epi32(j, _mm_set1_epi32(*e)));
    const int mask = ~_mm_movemask_ps(_mm_castsi128_ps(excluded)) & kLanesBefore[std::min(count - h, 4)];
    const __m128i control = _mm_load_si128(reinterpret_cast<const __m128i*>(kPack.control[mask]));
    const __m128i packed = _mm_shuffle_epi8(j, control);
    _mm_storeu_si128(reinterpret_cast<__m128i*>(to_i + kept), _mm_min_epi32(packed, vi));
    _mm_storeu_si128(reinterpret_cast<__m128i*>(to_j + kept), _mm_max_epi32(packed, vi));
    kept += _mm_popcnt_u32(static_cast<unsigned>(mask));
  }
  for (int k = 0; k < kept; ++k) ++row_count[to_i[k]];
  return kept;
}
#endif

template <bool kAvx2, bool kHalo>
inline void search_columns(HalfStencilPart& p) {
  static constexpr int kColumns[4][2] = {{0, 1}, {1, -1}, {1, 0}, {1, 1}};
  const int ny = p.ny, nz = p.nz, z_face = p.z_face;
  const int* const cs = p.cs;
  double* const gxs = p.gxs;
  double* const gys = p.gys;
  double* const gzs = p.gzs;
  int* const gks = p.gks;
  int* const hit = p.hit;
  int* to_i = p.pi->data();
  int* to_j = p.pj->data();
  std::size_t capacity = p.pi->size(), used = p.used;
  int total = 0;
  // Entries first … last − 1 of the cell order, shifted, to the candidates at `at` (to_x …).
  auto gather_to = [&](double* to_x, double* to_y, double* to_z, int* to_k, int& at, int first, int last, double sx,
                       double sy, double sz) {
#if defined(__x86_64__)
    if constexpr (kAvx2)
      gather_shifted_avx2(p.cxs, p.cys, p.czs, p.cp, first, last, sx, sy, sz, to_x + at, to_y + at, to_z + at,
                          to_k + at);
    else
#endif
      gather_shifted_scalar(p.cxs, p.cys, p.czs, p.cp, first, last, sx, sy, sz, to_x + at, to_y + at, to_z + at,
                            to_k + at);
    at += std::max(0, last - first);
  };
  auto gather = [&](int first, int last, double sx, double sy, double sz) {
    gather_to(gxs, gys, gzs, gks, total, first, last, sx, sy, sz);
  };
  auto gather_cell = [&](int gx, int gy, int gz, double sx, double sy, double sz) {
    if (gx < 0 || gy < 0 || gz < 0) return;  // past an open edge
    const int cell = (gx * ny + gy) * nz + gz;
    gather(cs[cell], cs[cell + 1], sx, sy, sz);
  };
  // Particle i (at xi, yi, zi) tested against candidates first … total − 1 of (xs, ys, zs, ks),
  // whose three entries past the end fail every test, and its hits recorded as pairs (min, max)
  // less i's exclusions, each written and kept without a branch.
  auto test_and_record = [&](int i, double xi, double yi, double zi, const double* xs, const double* ys,
                             const double* zs, const int* ks, int first, int end) {
    int count;
#if defined(__x86_64__)
    if constexpr (kAvx2)
      count = test_candidates_avx2<true>(xi, yi, zi, xs, ys, zs, ks, first, end, p.rlist2, hit);
    else
#endif
      count = test_candidates_scalar(xi, yi, zi, xs, ys, zs, ks, first, end, p.rlist2, hit);
    if (used + count + 4 > capacity) {  // rare: the buffers grow geometrically, then stay
      capacity = std::max(2 * capacity, used + count + 1024);
      p.pi->resize(capacity);
      p.pj->resize(capacity);
      to_i = p.pi->data();
      to_j = p.pj->data();
    }
    const int* first_excl = p.excl;
    const int* last_excl = first_excl;
    if (p.excl_offsets) {
      first_excl += p.excl_offsets[i];
      last_excl += p.excl_offsets[i + 1];
    }
#if defined(__x86_64__)
    if constexpr (kAvx2) {
      used = record_hits_avx2(i, hit, count, first_excl, last_excl, to_i + used, to_j + used, p.row_count) + used;
      return;
    }
#endif
    std::size_t kept = used;
    for (int h = 0; h < count; ++h) {
      const int j = hit[h];
      bool keep = true;
      for (const int* e = first_excl; e != last_excl; ++e) keep &= *e != j;
      const int row = std::min(i, j);
      to_i[kept] = row;
      to_j[kept] = std::max(i, j);
      p.row_count[row] += keep;
      kept += keep;
    }
    used = kept;
  };
  // Three entries past the candidates that fail every distance test (x − ∞ = −∞, squared +∞,
  // not < r²; NaN neither), so the AVX2 test's last group needs no mask.
  auto sentinels = [](double* xs, int end) {
    for (int t = end; t < end + 3; ++t) xs[t] = std::numeric_limits<double>::infinity();
  };
  for (int column = p.first_column; column < p.last_column; ++column) {
    const int cx = column / ny, cy = column % ny;
    for (int cz = 0; cz < nz; ++cz) {
      const int c = (cx * ny + cy) * nz + cz;
      const int own = cs[c + 1] - cs[c];
      if (own == 0) continue;
      // With halo beads, a cell's home beads come first in its range (NeighborList::bin): they
      // are the rows searched as one process searches them.
      const int home_here = kHalo ? p.home[c] : own;
      if (home_here > 0) {
        total = 0;
        if (cz + 1 < nz && cz + 1 != z_face) {  // the cell and the next along z, one range
          gather(cs[c], cs[c + 2], 0.0, 0.0, 0.0);
        } else {
          gather(cs[c], cs[c + 1], 0.0, 0.0, 0.0);
          gather_cell(cx, cy, p.adjacent[2][3 * cz + 2], 0.0, 0.0, p.adjacent_shift[2][3 * cz + 2]);
        }
        for (const auto& col : kColumns) {
          const int gx = p.adjacent[0][3 * cx + col[0] + 1], gy = p.adjacent[1][3 * cy + col[1] + 1];
          if (gx < 0 || gy < 0) continue;
          const double sx = p.adjacent_shift[0][3 * cx + col[0] + 1], sy = p.adjacent_shift[1][3 * cy + col[1] + 1];
          if (cz >= 1 && cz + 1 < nz && cz != z_face && cz + 1 != z_face) {  // cz − 1 … cz + 1: one range
            const int base = (gx * ny + gy) * nz;
            gather(cs[base + cz - 1], cs[base + cz + 2], sx, sy, 0.0);
          } else {
            for (int dz = 0; dz < 3; ++dz)
              gather_cell(gx, gy, p.adjacent[2][3 * cz + dz], sx, sy, p.adjacent_shift[2][3 * cz + dz]);
          }
        }
        sentinels(gxs, total);
        for (int m = 0; m < home_here; ++m)
          test_and_record(gks[m], gxs[m], gys[m], gzs[m], gxs, gys, gzs, gks, m + 1, total);
      }
      if constexpr (kHalo) {
        if (home_here == own) continue;
        // The cell's halo beads, rows home_here … own − 1: one process tests each against the
        // later beads of the cell (halo beads: none kept) and every bead of the forward cells, as
        // x_i − (x_j + shift) with the shift on j. Here only against the forward cells' home beads
        // (each cell's prefix), with those shifts: the same pairs with a home bead, the same
        // separations (x_i + 0.0 as the gather above makes it), and no pair of two halo beads.
        int homes = 0;
        auto gather_home = [&](int gx, int gy, int gz, double sx, double sy, double sz) {
          if (gx < 0 || gy < 0 || gz < 0) return;  // past an open edge
          const int cell = (gx * ny + gy) * nz + gz;
          gather_to(p.hxs, p.hys, p.hzs, p.hks, homes, cs[cell], cs[cell] + p.home[cell], sx, sy, sz);
        };
        gather_home(cx, cy, p.adjacent[2][3 * cz + 2], 0.0, 0.0, p.adjacent_shift[2][3 * cz + 2]);
        for (const auto& col : kColumns) {
          const int gx = p.adjacent[0][3 * cx + col[0] + 1], gy = p.adjacent[1][3 * cy + col[1] + 1];
          if (gx < 0 || gy < 0) continue;
          const double sx = p.adjacent_shift[0][3 * cx + col[0] + 1], sy = p.adjacent_shift[1][3 * cy + col[1] + 1];
          for (int dz = 0; dz < 3; ++dz)
            gather_home(gx, gy, p.adjacent[2][3 * cz + dz], sx, sy, p.adjacent_shift[2][3 * cz + dz]);
        }
        if (homes == 0) continue;
        sentinels(p.hxs, homes);
        for (int k = cs[c] + home_here; k < cs[c + 1]; ++k)
          test_and_record(p.cp[k], p.cxs[k] + 0.0, p.cys[k] + 0.0, p.czs[k] + 0.0, p.hxs, p.hys, p.hzs, p.hks, 0,
                          homes);
      }
    }
  }
  p.used = used;
}

void search_columns_portable(HalfStencilPart& p) {
  search_columns<false, false>(p);
}
void search_columns_halo_portable(HalfStencilPart& p) {
  search_columns<false, true>(p);
}
#if defined(__x86_64__)
[[gnu::target("avx2,popcnt"), gnu::flatten]] void search_columns_avx2(HalfStencilPart& p) {
  search_columns<true, false>(p);
}
[[gnu::target("avx2,popcnt"), gnu::flatten]] void search_columns_halo_avx2(HalfStencilPart& p) {
  search_columns<true, true>(p);
}
#endif

// Rows b … e − 1 of a CSR list (neighbors, offsets) each sorted in increasing order. A row's
// partners are distinct: each goes to the place of the count of smaller ones (branch-free
// compares, which the compiler vectorises; rows hold a few dozen at most); a longer row by
// std::sort.
void sort_rows_portable(int* neighbors, const std::int64_t* offsets, std::int64_t b, std::int64_t e) {
  for (std::int64_t i = b; i < e; ++i) {
    int* const row = neighbors + offsets[i];
    const std::int64_t count = offsets[i + 1] - offsets[i];
    if (count > 48) {
      std::sort(row, row + count);
      continue;
    }
    int copy[48];
    std::copy(row, row + count, copy);
    for (std::int64_t a = 0; a < count; ++a) {
      int smaller = 0;
      for (std::int64_t c = 0; c < count; ++c) smaller += copy[c] < copy[a];
      row[smaller] = copy[a];
    }
  }
}

#if defined(__x86_64__)
// The same with AVX2 for rows of up to 16 (in.chain's half rows hold ≈ 5): the row in two vectors
// of eight, padded with INT_MAX (never smaller than a partner), and the count of smaller ones for
// each partner as the population of one compare's mask — the same places as the portable form.
[[gnu::target("avx2,popcnt")]] void sort_rows_avx2(int* neighbors, const std::int64_t* offsets, std::int64_t b,
                                                   std::int64_t e) {
  const __m256i pad = _mm256_set1_epi32(std::numeric_limits<int>::max());
  for (std::int64_t i = b; i < e; ++i) {
    int* const row = neighbors + offsets[i];
    const int count = static_cast<int>(offsets[i + 1] - offsets[i]);
    if (count > 16) {
      sort_rows_portable(neighbors, offsets, i, i + 1);
      continue;
    }
    alignas(32) int copy[16];
    _mm256_store_si256(reinterpret_cast<__m256i*>(copy), pad);
    _mm256_store_si256(reinterpret_cast<__m256i*>(copy + 8), pad);
    for (int a = 0; a < count; ++a) copy[a] = row[a];
    const __m256i lo = _mm256_load_si256(reinterpret_cast<const __m256i*>(copy));
    const __m256i hi = _mm256_load_si256(reinterpret_cast<const __m256i*>(copy + 8));
    for (int a = 0; a < count; ++a) {
      const __m256i v = _mm256_set1_epi32(copy[a]);
      const unsigned smaller =
          static_cast<unsigned>(_mm256_movemask_ps(_mm256_castsi256_ps(_mm256_cmpgt_epi32(v, lo)))) |
          static_cast<unsigned>(_mm256_movemask_ps(_mm256_castsi256_ps(_mm256_cmpgt_epi32(v, hi)))) << 8;
      row[_mm_popcnt_u32(smaller)] = copy[a];
    }
  }
}
#endif

// The binning of particles first … last − 1 of x (3×N, column-major) into a grid of cells (see
// NeighborList::bin): each one's image L·floor((x − lo)/L) on periodic axes (0 on open ones), its
// position less the image, and its key, counted per key: its flattened cell c, or with halo flags
// (ghost not null) 2c + ghost[i], so that the sort puts a cell's home beads before its halo beads.
// The box's cells (ncell per axis) and the window of them that is stored: per axis `stored`
// consecutive cell coordinates from `first` on (modulo ncell on a periodic axis; first = 0 and
// stored = ncell: every cell).
struct BinGrid {
  double lo[3], inv_len[3], len[3];
  bool periodic[3];
  int ncell[3];
  int first[3], stored[3];
};

// The cell coordinate in the box's grid of coordinate x along axis a, and its image im:
// L·floor((x − lo)/L) on a periodic axis (positions are unwrapped: their image inside the box is
// binned), 0 on an open one.
inline int box_cell_coordinate(const BinGrid& g, double x, int a, double& im) {
  double s = (x - g.lo[a]) * g.inv_len[a];
  im = 0.0;
  if (g.periodic[a]) {
    const double whole = std::floor(s);
    s -= whole;
    im = whole * g.len[a];
  }
  return cell_coordinate(s * g.ncell[a], g.ncell[a]);
}

// The place in the window of the box grid's cell coordinate c along axis a.
inline int window_coordinate(const BinGrid& g, int c, int a) {
  c -= g.first[a];
  return c + (c < 0 ? g.ncell[a] : 0);
}

// Particle i's key from its window coordinates c (its cell, or with halo flags 2 × cell + flag),
// recorded and counted.
inline void record_key(const BinGrid& g, const int c[3], const char* __restrict ghost, std::int64_t i,
                       int* __restrict key_of, int* __restrict count) {
  const int cell = (c[0] * g.stored[1] + c[1]) * g.stored[2] + c[2];
  const int key = ghost ? 2 * cell + ghost[i] : cell;
  key_of[i] = key;
  ++count[key];
}

// kWindow: a window of the cells is stored (else every cell: first = 0, stored = ncell); kStore:
// each image and wrapped position is stored (else every image is 0: NeighborList::bin).
template <bool kWindow, bool kStore>
inline void bin_particles_as(const BinGrid& g, const double* __restrict x, const char* __restrict ghost,
                             std::int64_t first, std::int64_t last, double* __restrict image,
                             double* __restrict wrapped, int* __restrict key_of, int* __restrict count) {
  for (std::int64_t i = first; i < last; ++i) {
    int c[3];
    for (int a = 0; a < 3; ++a) {
      double im;
      c[a] = box_cell_coordinate(g, x[3 * i + a], a, im);
      if constexpr (kWindow) c[a] = window_coordinate(g, c[a], a);
      if constexpr (kStore) {
        image[3 * i + a] = im;
        wrapped[3 * i + a] = x[3 * i + a] - im;
      }
    }
    record_key(g, c, ghost, i, key_of, count);
  }
}

// image, wrapped null: every image is 0, none stored.
inline void bin_particles(const BinGrid& g, const double* x, const char* ghost, std::int64_t first, std::int64_t last,
                          double* image, double* wrapped, int* key_of, int* count) {
  const bool window = g.first[0] != 0 || g.first[1] != 0 || g.first[2] != 0;
  if (image && !window) return bin_particles_as<false, true>(g, x, ghost, first, last, image, wrapped, key_of, count);
  if (image) return bin_particles_as<true, true>(g, x, ghost, first, last, image, wrapped, key_of, count);
  if (!window) return bin_particles_as<false, false>(g, x, ghost, first, last, image, wrapped, key_of, count);
  bin_particles_as<true, false>(g, x, ghost, first, last, image, wrapped, key_of, count);
}

// The cell coordinates of particles first … last − 1 marked per axis (occupied[a][c] = 1), by the
// same arithmetic as bin_particles, and kept (cells[3i + a], in the box's grid) for
// bin_particles_from_cells; returns whether some image is not 0.
inline bool mark_cell_coordinates(const BinGrid& g, const double* __restrict x, std::int64_t first, std::int64_t last,
                                  char* const occupied[3], int* __restrict cells) {
  bool image = false;
  for (std::int64_t i = first; i < last; ++i)
    for (int a = 0; a < 3; ++a) {
      double im;
      const int c = box_cell_coordinate(g, x[3 * i + a], a, im);
      cells[3 * i + a] = c;
      occupied[a][c] = 1;
      image |= im != 0.0;
    }
  return image;
}

// bin_particles where every image is 0 (none stored) and mark_cell_coordinates has found each
// particle's cell coordinates in the box's grid: the same keys and counts from those, placed in
// the window, without computing them again.
inline void bin_particles_from_cells(const BinGrid& g, const int* __restrict cells, const char* __restrict ghost,
                                     std::int64_t first, std::int64_t last, int* __restrict key_of,
                                     int* __restrict count) {
  for (std::int64_t i = first; i < last; ++i) {
    const int c[3] = {window_coordinate(g, cells[3 * i], 0), window_coordinate(g, cells[3 * i + 1], 1),
                      window_coordinate(g, cells[3 * i + 2], 2)};
    record_key(g, c, ghost, i, key_of, count);
  }
}

#if defined(__x86_64__)
// The same where the CPU has SSE4.1, whose roundsd is floor in one instruction (x86-64's baseline
// calls the library's floor): floor is exact, the same values.
[[gnu::target("sse4.1"), gnu::flatten]] void bin_particles_sse41(const BinGrid& g, const double* x, const char* ghost,
                                                                 std::int64_t first, std::int64_t last, double* image,
                                                                 double* wrapped, int* key_of, int* count) {
  bin_particles(g, x, ghost, first, last, image, wrapped, key_of, count);
}
[[gnu::target("sse4.1"), gnu::flatten]] bool mark_cell_coordinates_sse41(const BinGrid& g, const double* x,
                                                                         std::int64_t first, std::int64_t last,
                                                                         char* const occupied[3], int* cells) {
  return mark_cell_coordinates(g, x, first, last, occupied, cells);
}
#endif

// The window of a periodic axis's n cell coordinates that holds every occupied one: the
// complement of the longest circular run of unoccupied ones (first, stored); the whole axis
// (0, n) when none is unoccupied or none occupied.
std::pair<int, int> occupied_window(const char* occupied, int n) {
  int p = 0;
  while (p < n && !occupied[p]) ++p;
  if (p == n) return {0, n};
  int best_start = 0, best_length = 0, run_start = 0, run_length = 0;
  for (int k = 1; k <= n; ++k) {  // from the coordinate after p round to p
    const int c = (p + k) % n;
    if (!occupied[c]) {
      if (run_length++ == 0) run_start = c;
      if (run_length > best_length) best_start = run_start, best_length = run_length;
    } else {
      run_length = 0;
    }
  }
  if (best_length == 0) return {0, n};
  return {(best_start + best_length) % n, n - best_length};
}

// needs_rebuild's pass over a block of particles: the largest squared displacement since the build
// (x − x0, both 3×N column-major; its minimum image by `fold` where it exceeds half the skin, as
// a wrapped position that crossed a face does), and the fast particles (d² > half2) in index
// order, at most `most` of them (more: too_many). A NaN d² is passed over, as std::max(w, NaN)
// passes it.
struct DisplacementScan {
  const double* x;
  const double* x0;
  double half2;
  const NearestImage* fold;
  std::vector<int>* fast;
  std::size_t most;
  double worst;  // the largest d² so far (start: 0)
  char too_many;
};

inline void scan_displacements(DisplacementScan& s, std::int64_t first, std::int64_t last) {
  const double* const xp = s.x;
  const double* const x0 = s.x0;
  double w = s.worst;  // no early exit: a loop over the block whose branch is rarely taken is faster
  for (std::int64_t i = first; i < last; ++i) {
    double dx = xp[3 * i] - x0[3 * i], dy = xp[3 * i + 1] - x0[3 * i + 1], dz = xp[3 * i + 2] - x0[3 * i + 2];
    double d2 = dx * dx + dy * dy + dz * dz;
    if (d2 > s.half2) {  // rare: a fast particle, or a wrapped one that crossed a face
      s.fold->apply(dx, dy, dz);
      d2 = dx * dx + dy * dy + dz * dz;
    }
    w = std::max(w, d2);
    if (d2 > s.half2) {
      if (s.fast->size() < s.most)
        s.fast->push_back(static_cast<int>(i));
      else
        s.too_many = 1;
    }
  }
  s.worst = w;
}

#if defined(__x86_64__)
// The same four particles at a time (AVX2): their twelve coordinates in three vectors, the
// squared differences transposed into one vector per axis, d² = (dx² + dy²) + dz² lane by lane —
// the scalar pass's operations, the same values. A group with a lane past half the skin (rare) is
// passed to the scalar pass, which folds and records it; the others' largest d² is kept by
// vmaxpd(d², w), which keeps w for a NaN as std::max(w, d²) does. The largest of a set does not
// depend on the order it is taken in: the same worst as the scalar pass, the same fast particles
// in the same order. It was 39 instructions per particle at every step.
[[gnu::target("avx2")]] void scan_displacements_avx2(DisplacementScan& s, std::int64_t first, std::int64_t last) {
  const double* const xp = s.x;
  const double* const x0 = s.x0;
  const __m256d half2 = _mm256_set1_pd(s.half2);
  __m256d w = _mm256_setzero_pd();
  std::int64_t i = first;
  for (; i + 4 <= last; i += 4) {
    const __m256d d0 = _mm256_sub_pd(_mm256_loadu_pd(xp + 3 * i), _mm256_loadu_pd(x0 + 3 * i));
    const __m256d d1 = _mm256_sub_pd(_mm256_loadu_pd(xp + 3 * i + 4), _mm256_loadu_pd(x0 + 3 * i + 4));
    const __m256d d2v = _mm256_sub_pd(_mm256_loadu_pd(xp + 3 * i + 8), _mm256_loadu_pd(x0 + 3 * i + 8));
    // Lanes x0 y0 z0 x1 | y1 z1 x2 y2 | z2 x3 y3 z3 of the squares into x0 x1 x2 x3, y…, z….
    const __m256d q0 = _mm256_mul_pd(d0, d0), q1 = _mm256_mul_pd(d1, d1), q2 = _mm256_mul_pd(d2v, d2v);
    const __m256d sx =
        _mm256_permute4x64_pd(_mm256_blend_pd(_mm256_blend_pd(q0, q1, 0b0100), q2, 0b0010), _MM_SHUFFLE(1, 2, 3, 0));
    const __m256d sy =
        _mm256_permute4x64_pd(_mm256_blend_pd(_mm256_blend_pd(q0, q1, 0b1001), q2, 0b0100), _MM_SHUFFLE(2, 3, 0, 1));
    const __m256d sz =
        _mm256_permute4x64_pd(_mm256_blend_pd(_mm256_blend_pd(q0, q1, 0b0010), q2, 0b1001), _MM_SHUFFLE(3, 0, 1, 2));
    const __m256d r2 = _mm256_add_pd(_mm256_add_pd(sx, sy), sz);
    const __m256d fast = _mm256_cmp_pd(r2, half2, _CMP_GT_OQ);
    if (_mm256_movemask_pd(fast) != 0) {  // rare: the scalar pass for these four
      scan_displacements(s, i, i + 4);
      continue;
    }
    w = _mm256_max_pd(r2, w);
  }
  alignas(32) double lanes[4];
  _mm256_store_pd(lanes, w);
  for (const double l : lanes) s.worst = std::max(s.worst, l);
  scan_displacements(s, i, last);
}
#endif

#if defined(__x86_64__)
// BoxWrap::wrap_particles four particles (twelve coordinates, three vectors) at a time: the same
// IEEE operations as BoxWrap::operator() lane by lane, the vectors' lanes on the axes x y z x |
// y z x y | z x y z. floor_of truncates and corrects; for |q| < 2⁶³ that is the exact floor, which
// vroundpd gives, except that floor(−0) is −0 where the truncation gives +0: adding +0 turns −0
// into +0 and leaves every other integer as it is. The same values for every finite position
// within 2⁶³ box lengths of the origin (a non-finite one stays non-finite). out may be x: each
// vector is loaded before the same one is stored.
[[gnu::target("avx2")]] void wrap_particles_avx2(const double* __restrict lo, const double* __restrict len,
                                                 const double* __restrict inv, const double* x, double* out,
                                                 std::int64_t first, std::int64_t last) {
  __m256d vlo[3], vlen[3], vinv[3];
  for (int v = 0; v < 3; ++v) {
    const int a0 = (4 * v) % 3, a1 = (4 * v + 1) % 3, a2 = (4 * v + 2) % 3, a3 = (4 * v + 3) % 3;
    vlo[v] = _mm256_setr_pd(lo[a0], lo[a1], lo[a2], lo[a3]);
    vlen[v] = _mm256_setr_pd(len[a0], len[a1], len[a2], len[a3]);
    vinv[v] = _mm256_setr_pd(inv[a0], inv[a1], inv[a2], inv[a3]);
  }
  const __m256d zero = _mm256_setzero_pd();
  for (std::int64_t i = first; i + 4 <= last; i += 4)
    for (int v = 0; v < 3; ++v) {
      const __m256d p = _mm256_loadu_pd(x + 3 * i + 4 * v);
      const __m256d q = _mm256_mul_pd(_mm256_sub_pd(p, vlo[v]), vinv[v]);
      const __m256d whole = _mm256_add_pd(_mm256_round_pd(q, _MM_FROUND_TO_NEG_INF | _MM_FROUND_NO_EXC), zero);
      _mm256_storeu_pd(out + 3 * i + 4 * v, _mm256_sub_pd(p, _mm256_mul_pd(vlen[v], whole)));
    }
}
#endif

}  // namespace

void BoxWrap::wrap_particles(const double* x, double* out, std::int64_t first, std::int64_t last) const {
  std::int64_t i = first;
#if defined(__x86_64__)
  static const bool avx2 = __builtin_cpu_supports("avx2");
  if (avx2) {
    wrap_particles_avx2(lo_, len_, inv_, x, out, first, last);
    i = first + (last - first) / 4 * 4;
  }
#endif
  for (; i < last; ++i)
    for (int a = 0; a < 3; ++a) out[3 * i + a] = (*this)(x[3 * i + a], a);
}

void check_box_for_cutoff(const Box& box, double cutoff, double skin) {
  const double need = 2.0 * (cutoff + skin);
  for (int a = 0; a < 3; ++a) {
    if (!box.periodic[a]) continue;
    const double len = box.lengths[a];
    if (!(len >= need) || !std::isfinite(len)) {
      std::ostringstream s;
      s << "periodic box length L = " << len << " on axis " << kAxis[a]
        << ": box length L < 2 × (cutoff + skin) = 2 × (" << cutoff << " + " << skin << ") = " << need
        << ", so the minimum image is ambiguous; enlarge the box or reduce the cutoff or skin";
      throw std::invalid_argument(s.str());
    }
  }
}

std::vector<SpecialPair> special_pairs(int num_particles, const std::vector<Bond>& bonds, SpecialWeights w) {
  return special_pairs(num_particles, bonds, w, w);
}

std::vector<SpecialPair> special_pairs(int num_particles, const std::vector<Bond>& bonds, SpecialWeights w,
                                       SpecialWeights coul) {
  if (num_particles < 0) throw std::invalid_argument("special_pairs: negative particle count");
  // Bonded partners per particle (CSR), to walk 1-2 and then 1-3 neighbours.
  std::vector<int> deg(static_cast<std::size_t>(num_particles) + 1, 0);
  for (const Bond& b : bonds) {
    if (b.i < 0 || b.i >= num_particles || b.j < 0 || b.j >= num_particles) {
      std::ostringstream s;
      s << "bond (" << b.i << ", " << b.j << ") refers to a particle outside 0 … " << num_particles - 1;
      throw std::invalid_argument(s.str());
    }
    if (b.i == b.j)
      throw std::invalid_argument("bond (" + std::to_string(b.i) + ", " + std::to_string(b.j) +
                                  ") joins a particle to itself");
    ++deg[b.i + 1];
    ++deg[b.j + 1];
  }
  for (int i = 0; i < num_particles; ++i) deg[i + 1] += deg[i];
  std::vector<int> partner(deg.back()), fill(deg.begin(), deg.end() - 1);
  for (const Bond& b : bonds) {
    partner[fill[b.i]++] = b.j;
    partner[fill[b.j]++] = b.i;
  }

  // Every 1-2, 1-3 (and, when w14 ≠ 1, 1-4) relation, tagged with its distance along the bonds;
  // after sorting, the first entry of a pair is its closest relation (1-2 before 1-3 before 1-4),
  // whose weight it takes.
  struct Relation {
    int i, j, bonds_apart;
    auto operator<=>(const Relation&) const = default;
  };
  std::vector<Relation> rel;
  for (const Bond& b : bonds) rel.push_back({std::min(b.i, b.j), std::max(b.i, b.j), 1});
  for (int k = 0; k < num_particles; ++k)
    for (int p = deg[k]; p < deg[k + 1]; ++p)
      for (int q = p + 1; q < deg[k + 1]; ++q)  // both bonded to k: 1-3 through k
        if (partner[p] != partner[q])
          rel.push_back({std::min(partner[p], partner[q]), std::max(partner[p], partner[q]), 2});
  if (w.w14 != 1.0 || coul.w14 != 1.0)  // 1-4 about each bond j–k: a partner of j (not k) and a partner of k (not j)
    for (const Bond& b : bonds)
      for (int p = deg[b.i]; p < deg[b.i + 1]; ++p)
        for (int q = deg[b.j]; q < deg[b.j + 1]; ++q) {
          const int a = partner[p], c = partner[q];
          if (a != b.j && c != b.i && a != c) rel.push_back({std::min(a, c), std::max(a, c), 3});
        }
  std::sort(rel.begin(), rel.end());

  std::vector<SpecialPair> out;
  for (std::size_t r = 0; r < rel.size(); ++r) {
    if (r > 0 && rel[r].i == rel[r - 1].i && rel[r].j == rel[r - 1].j) continue;
    const int k = rel[r].bonds_apart;
    const double weight = k == 1 ? w.w12 : k == 2 ? w.w13 : w.w14;
    const double weight_coul = k == 1 ? coul.w12 : k == 2 ? coul.w13 : coul.w14;
    if (weight != 1.0 || weight_coul != 1.0)  // both 1: an ordinary pair
      out.push_back({rel[r].i, rel[r].j, weight, weight_coul});
  }
  return out;
}

NeighborList::NeighborList(double cutoff, double skin) : cutoff_(cutoff), skin_(skin) {
  if (!(cutoff > 0.0) || !std::isfinite(cutoff))
    throw std::invalid_argument("neighbour list: cutoff must be finite and > 0");
  if (!(skin >= 0.0) || !std::isfinite(skin))
    throw std::invalid_argument("neighbour list: skin must be finite and >= 0");
}

void NeighborList::set_exclusions(int num_particles, std::span<const SpecialPair> pairs) {
  excl_particles_ = num_particles;
  // CSR rows in the arrays' capacity (a decomposed run moves its lists onto a new pair set at
  // each selection): each row's count at offsets[i + 2], their prefix sums, so that offsets[i + 1]
  // is row i's start; each pair placed at its rows' cursors offsets[i + 1]++, which leaves
  // offsets[i + 1] at row i's end, row i + 1's start: the CSR offsets without a shift back.
  const std::size_t rows = static_cast<std::size_t>(num_particles);
  excl_offsets_.assign(rows + 2, 0);
  int* const offsets = excl_offsets_.data();
  // Pairs i < j in increasing (i, j), as special_pairs gives them, leave each row sorted: row r
  // takes the i < r of the pairs (i, r) in increasing i, then the j > r of the pairs (r, j) in
  // increasing j, all of the first before any of the second.
  bool ordered = true;
  int last_i = -1, last_j = -1;
  const auto n = static_cast<unsigned>(num_particles);
  for (const SpecialPair& p : pairs) {
    if (static_cast<unsigned>(p.i) >= n || static_cast<unsigned>(p.j) >= n)
      throw std::invalid_argument("neighbour list: excluded pair refers to a particle out of range");
    ++offsets[p.i + 2];
    ++offsets[p.j + 2];
    ordered &= p.i < p.j && (p.i > last_i || (p.i == last_i && p.j > last_j));
    last_i = p.i;
    last_j = p.j;
  }
  for (std::size_t i = 2; i < rows + 2; ++i) offsets[i] += offsets[i - 1];
  excl_.resize(static_cast<std::size_t>(offsets[rows + 1]));
  int* const excl = excl_.data();
  for (const SpecialPair& p : pairs) {
    excl[offsets[p.i + 1]++] = p.j;
    excl[offsets[p.j + 1]++] = p.i;
  }
  excl_offsets_.resize(rows + 1);  // keeps the capacity
  if (!ordered)
    for (std::size_t i = 0; i < rows; ++i) std::sort(excl_.begin() + offsets[i], excl_.begin() + offsets[i + 1]);
  built_ = false;
}

void NeighborList::set_ghosts(std::span<const char> ghost) {
  for (char g : ghost)
    if (g != 0 && g != 1) throw std::invalid_argument("neighbour list: a ghost flag must be 0 or 1");
  // None set: the list without ghosts. The flags are copied into the member's capacity.
  const bool none = std::find(ghost.begin(), ghost.end(), char{1}) == ghost.end();
  if (none) {
    if (!ghost_.empty()) built_ = false;
    ghost_.clear();
    return;
  }
  if (!std::equal(ghost.begin(), ghost.end(), ghost_.begin(), ghost_.end())) built_ = false;
  ghost_.assign(ghost.begin(), ghost.end());
}

void NeighborList::set_ghost_pairs_once(bool once) {
  if (once != ghost_once_) built_ = false;
  ghost_once_ = once;
}

bool NeighborList::excluded(int i, int j) const {
  // Rows hold a handful of bonded neighbours: a linear scan beats a search.
  for (int k = excl_offsets_[i]; k < excl_offsets_[i + 1]; ++k)
    if (excl_[k] == j) return true;
  return false;
}

bool NeighborList::deformed_needs_rebuild(const Eigen::Matrix3Xd& x, const Box& box) const {
  // Wrapped positions jump by box lengths, and the small-box search lists images by the build's
  // box: rebuild on any change there.
  if (positions_wrapped_ || small_box_) return true;
  Eigen::Vector3d mu = Eigen::Vector3d::Ones();
  for (int a = 0; a < 3; ++a)
    if (box.periodic[a]) mu[a] = box.lengths[a] / box_at_build_.lengths[a];
  const double reach = mu.minCoeff() * (cutoff_ + skin_) - cutoff_;  // the bound on 2U
  if (!(reach > 0.0)) return true;
  const double bound2 = 0.25 * reach * reach;
  const Eigen::Vector3d o = box.origin, o0 = box_at_build_.origin;
  const Eigen::Index n = x.cols();
  const int parts = threads_for(n);
  std::array<char, kMaxParts> far{};
  run_parts(parts, [&](int u) {
    for (std::int64_t i = block_begin(n, parts, u); i < block_begin(n, parts, u + 1); ++i) {
      const Eigen::Vector3d d = x.col(i) - (o + mu.cwiseProduct(x_at_build_.col(i) - o0));
      if (!(d.squaredNorm() <= bound2)) {
        far[u] = 1;
        break;
      }
    }
  });
  return std::any_of(far.begin(), far.begin() + parts, [](char f) { return f != 0; });
}

bool NeighborList::needs_rebuild(const Eigen::Matrix3Xd& x, const Box& box) const {
  if (!built_ || x.cols() != x_at_build_.cols() || box.periodic != box_at_build_.periodic) return true;
  if (!same_box(box, box_at_build_)) {
    check_box_for_cutoff(box, cutoff_, skin_);
    return deformed_needs_rebuild(x, box);
  }
  // Raw (unwrapped) displacements: the engine never wraps positions, and if something did, the
  // jump of a box length would only cause an early rebuild. Positions given wrapped
  // (set_positions_wrapped): both in the box, so one fold gives a displacement's minimum image.
  const double half2 = 0.25 * skin_ * skin_, skin2 = skin_ * skin_;
  const NearestImage fold(positions_wrapped_ ? box : Box{});
  const double* xp = x.data();
  const double* x0 = x_at_build_.data();
  const Eigen::Index n = x.cols();
  const int parts = threads_for(n);
  // One pass per block: the largest squared displacement, and the fast particles (D > skin/2) in
  // index order while they are few enough to be worth checking (at most 1/256 of all; a block
  // with more stops recording them and marks itself).
  const std::size_t most = static_cast<std::size_t>(n) / 256;
  if (fast_.size() < static_cast<std::size_t>(parts)) fast_.resize(parts);
  std::array<double, kMaxParts> worst{};
  std::array<char, kMaxParts> too_many{};
  run_parts(parts, [&](int u) {
    std::vector<int>& f = fast_[u];
    f.clear();
    DisplacementScan scan{xp, x0, half2, &fold, &f, most, 0.0, 0};
    const std::int64_t b = block_begin(n, parts, u), e = block_begin(n, parts, u + 1);
#if defined(__x86_64__)
    static const bool avx2 = __builtin_cpu_supports("avx2");
    if (avx2)
      scan_displacements_avx2(scan, b, e);
    else
#endif
      scan_displacements(scan, b, e);
    worst[u] = scan.worst;
    too_many[u] = scan.too_many;
  });
  const double d2 = *std::max_element(worst.begin(), worst.begin() + parts);
  const double limit = displacement_limit_ > 0.0 ? std::min(displacement_limit_, skin_) : skin_;
  if (!(d2 <= limit * limit)) return true;  // (a non-finite position too)
  if (d2 <= half2) return false;            // every D_i + D_j ≤ skin
  // The fast particles' check needs a particle within the cutoff of a fast one to have sat in the
  // build's cells around the fast one's position now (D ≤ skin), the build's cell search (not the
  // small-box one), and NearestImage to stay exact for the pair loop: positions within the skin of
  // the box, |d| < L + 2 skin ≤ 1.5 L on periodic axes.
  if (!(d2 <= skin2) || small_box_) return true;
  for (int a = 0; a < 3; ++a)
    if (box.periodic[a] && !(4.0 * skin_ <= box.lengths[a])) return true;
  std::size_t count = 0;
  for (int u = 0; u < parts; ++u) count += fast_[u].size();
  if (count > most || std::any_of(too_many.begin(), too_many.begin() + parts, [](char t) { return t != 0; }))
    return true;
  std::array<char, kMaxParts> missed{};
  run_parts(parts, [&](int u) { missed[u] = fast_particle_misses_a_pair(x, box, fast_[u]); });
  return std::any_of(missed.begin(), missed.begin() + parts, [](char m) { return m != 0; });
}

bool NeighborList::listed(int i, int j) const {
  const int row = std::min(i, j), other = std::max(i, j);
  for (std::int64_t k = offsets_[row]; k < offsets_[row + 1]; ++k)
    if (neighbors_[k] == other) return true;
  return false;
}

bool NeighborList::fast_particle_misses_a_pair(const Eigen::Matrix3Xd& x, const Box& box,
                                               const std::vector<int>& fast) const {
  const MinimumImage mi(box);
  const double rc2 = cutoff_ * cutoff_;
  const int ny = stored_[1], nz = stored_[2];
  // The stored cell next to the box grid's coordinate c along axis a (offset o − 1), or −1: past
  // an open edge or out of the window (an empty cell at the build).
  const auto neighbour = [&](int a, int c, int o) {
    int cc = c + o - 1;
    if (box.periodic[a])
      cc = (cc + ncell_[a]) % ncell_[a];
    else if (cc < 0 || cc >= ncell_[a])
      return -1;
    return stored_cell(a, cc);
  };
  const bool have_exclusions = !excl_.empty();
  for (const int i : fast) {
    // i's cell now, in the build's grid: its position in the build's image frame, wrapped back into
    // the box on periodic axes (it may have left it by up to the skin), clamped on open ones.
    int c[3];
    Eigen::Vector3d xi;
    for (int a = 0; a < 3; ++a) {
      xi[a] = images_stored_ ? x(a, i) - image_(a, i) : x(a, i);
      double s = bin_len_[a] > 0.0 ? (xi[a] - bin_lo_[a]) / bin_len_[a] : 0.0;
      if (box.periodic[a]) s -= std::floor(s);
      c[a] = cell_coordinate(s * ncell_[a], ncell_[a]);
    }
    for (int ox = 0; ox < 3; ++ox) {
      const int gx = neighbour(0, c[0], ox);
      if (gx < 0) continue;
      for (int oy = 0; oy < 3; ++oy) {
        const int gy = neighbour(1, c[1], oy);
        if (gy < 0) continue;
        for (int oz = 0; oz < 3; ++oz) {
          const int gz = neighbour(2, c[2], oz);
          if (gz < 0) continue;
          const int cell = (gx * ny + gy) * nz + gz;
          for (int k = cell_start_[cell]; k < cell_start_[cell + 1]; ++k) {
            const int j = cell_particles_[k];
            if (j == i || left_out(i, j)) continue;
            double dx, dy, dz;
            if (images_stored_)
              dx = xi[0] - (x(0, j) - image_(0, j)), dy = xi[1] - (x(1, j) - image_(1, j)),
              dz = xi[2] - (x(2, j) - image_(2, j));
            else
              dx = xi[0] - x(0, j), dy = xi[1] - x(1, j), dz = xi[2] - x(2, j);
            mi.apply(dx, dy, dz);
            if (!(dx * dx + dy * dy + dz * dz < rc2)) continue;
            if (have_exclusions && excluded(i, j)) continue;
            if (!listed(i, j)) return true;
          }
        }
      }
    }
  }
  return false;
}

const Eigen::Matrix3Xd& NeighborList::wrapped_positions(const Eigen::Matrix3Xd& x) {
  if (x.cols() != x_at_build_.cols())
    throw std::invalid_argument("neighbour list: wrapped_positions before a build for these particles");
  if (positions_wrapped_) return x;
  wrapped_now_.resize(3, x.cols());  // no allocation once sized
  // Wrapped now, not with the build's images: a separation then depends only on the two
  // positions (not on when the list was built), so the forces are the same bits whenever the
  // list is rebuilt (docs/parallel.md).
  const BoxWrap wrap(box_now_);
  parallel_blocks(x.cols(), threads_for(x.cols()),
                  [&](std::int64_t b, std::int64_t e) { wrap.wrap_particles(x.data(), wrapped_now_.data(), b, e); });
  return wrapped_now_;
}

bool NeighborList::update(const Eigen::Matrix3Xd& x, const Box& box) {
  box_now_ = box;
  const bool stale = next_verdict_ >= 0 ? next_verdict_ != 0 : needs_rebuild(x, box);
  next_verdict_ = -1;
  if (!(agree_ ? agree_(stale) : stale)) return false;
  build(x, box);
  return true;
}

void NeighborList::bin(const Eigen::Matrix3Xd& x, const Box& box) {
  const int n = static_cast<int>(x.cols());
  const double width = cutoff_ + skin_;

  // Binned extent per axis: the box on periodic axes (coordinates wrapped into it), the
  // particles' bounding box on open ones.
  double lo[3], len[3];
  for (int a = 0; a < 3; ++a) {
    if (box.periodic[a]) {
      lo[a] = box.origin[a];
      len[a] = box.lengths[a];
    } else if (n == 0) {
      lo[a] = len[a] = 0.0;
    } else {
      const double mn = x.row(a).minCoeff(), mx = x.row(a).maxCoeff();
      lo[a] = mn;
      len[a] = mx - mn;
    }
  }

  // Cells at least `width` wide, so that every pair within the list radius lies in the same or
  // adjacent cells. Sparse or spread-out systems (open boxes, a few particles in a big box) get
  // wider cells: at most ~2 cells per particle, so memory and the stencil walk stay O(N). A list
  // with ghosts (a decomposed run's pair set: a domain and its halo, a part of the box) may have 8
  // per particle it holds: the box's own cells, one process's, up to ~20 ranks on a melt (in.chain
  // has a cell per 3.5 beads), where 2 per particle made them twice as wide along an axis and each
  // home bead tested twice the candidates; the search skips the empty ones. On one process's
  // cells every pair is tested from the same bead with the same shift as one process tests it
  // (docs/parallel.md, "The design").
  const double per_particle = ghost_.empty() ? 2.0 : 8.0;
  const double max_cells = std::max(27.0, per_particle * n);
  double want[3];
  for (int a = 0; a < 3; ++a) want[a] = len[a] > width ? std::min(std::floor(len[a] / width), max_cells) : 1.0;
  while (want[0] * want[1] * want[2] > max_cells) {
    const int a = static_cast<int>(std::max_element(want, want + 3) - want);
    want[a] = std::max(1.0, std::floor(want[a] / 2.0));
  }
  for (int a = 0; a < 3; ++a) {
    ncell_[a] = static_cast<int>(want[a]);
    bin_lo_[a] = lo[a];
    bin_len_[a] = len[a];
  }
  double inv_len[3];
  for (int a = 0; a < 3; ++a) inv_len[a] = len[a] > 0.0 ? 1.0 / len[a] : 0.0;
  // A periodic axis with fewer than 3 cells: the small-box search, which reads each cell's
  // particles in increasing index.
  small_box_ = false;
  for (int a = 0; a < 3; ++a)
    if (box.periodic[a] && ncell_[a] < 3) small_box_ = true;
  const bool periodic[3] = {box.periodic[0] != 0, box.periodic[1] != 0, box.periodic[2] != 0};
  const int parts = threads_for(n);
  BinGrid grid{{lo[0], lo[1], lo[2]},
               {inv_len[0], inv_len[1], inv_len[2]},
               {len[0], len[1], len[2]},
               {periodic[0], periodic[1], periodic[2]},
               {ncell_[0], ncell_[1], ncell_[2]},
               {0, 0, 0},
               {ncell_[0], ncell_[1], ncell_[2]}};
  // With ghosts (a pair set: a domain and its halo, a part of the box on the box's own cells) the
  // cells stored are a window of the box's: per periodic axis the cell coordinates between the
  // longest run of unoccupied ones round the box, which a cell past either end of the window
  // then lies in (empty: the search meets it as an open edge). Every pair of cells is met from
  // the same cell with the same shift as on the whole grid (the adjacency below is the box
  // grid's, renumbered), so the pairs and their separations are the same; the per-cell arrays
  // (the sort's counts and starts, each cell's start and home count) are the window's size, not
  // the box's — a rank's pair set on 8 ranks holds about a sixth of the box's cells.
  //
  // Positions given wrapped (set_positions_wrapped: a pair set's) have the image 0 but where the
  // wrap's rounding put one on the box's upper face (or a hair below its lower one): the same pass
  // tells, and when every image is 0 no image or wrapped copy is stored — the wrapped positions
  // are x itself, bit for bit (x − 0 = x) — where they were two arrays of the positions' size.
  const bool windows = !ghost_.empty() && !small_box_;
  images_stored_ = true;
  const bool marked = (windows || positions_wrapped_) && n > 0;  // box_cells_ then holds each particle's cells
  if (marked) {
    const std::size_t marks = static_cast<std::size_t>(ncell_[0] + ncell_[1] + ncell_[2]);
    occupied_.assign(static_cast<std::size_t>(parts) * marks, 0);
    box_cells_.resize(3 * static_cast<std::size_t>(n));
    std::array<char, kMaxParts> image{};
    parallel_numbered_blocks(n, parts, [&](int u, std::int64_t first, std::int64_t last) {
      char* const at = occupied_.data() + u * marks;
      char* const occupied[3] = {at, at + ncell_[0], at + ncell_[0] + ncell_[1]};
#if defined(__x86_64__)
      static const bool sse41 = __builtin_cpu_supports("sse4.1");
      if (sse41) {
        image[u] = mark_cell_coordinates_sse41(grid, x.data(), first, last, occupied, box_cells_.data());
        return;
      }
#endif
      image[u] = mark_cell_coordinates(grid, x.data(), first, last, occupied, box_cells_.data());
    });
    for (int u = 1; u < parts; ++u)
      for (std::size_t k = 0; k < marks; ++k) occupied_[k] |= occupied_[u * marks + k];
    if (windows)
      for (int a = 0, at = 0; a < 3; at += ncell_[a], ++a)
        if (periodic[a]) std::tie(grid.first[a], grid.stored[a]) = occupied_window(occupied_.data() + at, ncell_[a]);
    images_stored_ = !positions_wrapped_ || std::any_of(image.begin(), image.begin() + parts, [](char c) { return c; });
  }
  for (int a = 0; a < 3; ++a) window_first_[a] = grid.first[a], stored_[a] = grid.stored[a];
  const int ncells = stored_[0] * stored_[1] * stored_[2];

  cell_of_.resize(n);
  if (images_stored_) {
    image_.resize(3, n);
    wrapped_x_.resize(3, n);
  }
  binned_x_ = images_stored_ ? wrapped_x_.data() : x.data();
  double* const image_out = images_stored_ ? image_.data() : nullptr;
  double* const wrapped_out = images_stored_ ? wrapped_x_.data() : nullptr;
  cell_start_.resize(static_cast<std::size_t>(ncells) + 1);
  // Padded (kCellPadding): the search's copies read a few entries past a cell's end.
  const std::size_t stride = static_cast<std::size_t>(n) + kCellPadding;
  cell_particles_.resize(stride);
  cell_x_.resize(3 * stride);
  // Each particle's image and cell on the threads (independent per particle), counted per block;
  // then the cells' starts and the counting sort's scatter (counting_sort.hpp), which keeps each
  // cell's particles in increasing index for any number of blocks. With halo flags (and the
  // half-stencil search) the key is 2 × cell + flag: a cell's home beads, in increasing index,
  // then its halo beads, in increasing index, and the search takes the home ones as a prefix
  // (cell_home_) rather than reading a flag per candidate.
  const char* const halo = ghost_.empty() || small_box_ ? nullptr : ghost_.data();
  cell_sort_.begin(parts, halo ? 2 * ncells : ncells);
  parallel_numbered_blocks(n, parts, [&](int u, std::int64_t first, std::int64_t last) {
    int* count = cell_sort_.clear(u);
    if (marked && !images_stored_)
      return bin_particles_from_cells(grid, box_cells_.data(), halo, first, last, cell_of_.data(), count);
#if defined(__x86_64__)
    static const bool sse41 = __builtin_cpu_supports("sse4.1");
    if (sse41) {
      bin_particles_sse41(grid, x.data(), halo, first, last, image_out, wrapped_out, cell_of_.data(), count);
      return;
    }
#endif
    bin_particles(grid, x.data(), halo, first, last, image_out, wrapped_out, cell_of_.data(), count);
  });
  if (halo) {
    key_start_.resize(2 * static_cast<std::size_t>(ncells) + 1);
    cell_home_.resize(static_cast<std::size_t>(ncells));
    cell_sort_.starts(key_start_.data());
    parallel_blocks(ncells, parts, [&](std::int64_t b, std::int64_t e) {
      const int* const ks = key_start_.data();
      for (std::int64_t c = b; c < e; ++c) {
        cell_start_[c] = ks[2 * c];
        cell_home_[c] = ks[2 * c + 1] - ks[2 * c];
      }
    });
    cell_start_[ncells] = n;
  } else {
    cell_sort_.starts(cell_start_.data());
  }
  parallel_numbered_blocks(n, parts, [&](int u, std::int64_t first, std::int64_t last) {
    auto cursor = cell_sort_.cursor(u);
    double* const cx = cell_x_.data();
    const double* const w = binned_x_;
    for (std::int64_t i = first; i < last; ++i) {
      const int k = cursor.slot(cell_of_[i]);
      cell_particles_[k] = static_cast<int>(i);
      cx[k] = w[3 * i];
      cx[stride + k] = w[3 * i + 1];
      cx[2 * stride + k] = w[3 * i + 2];
    }
  });

  // The adjacency of the box's grid, on the stored cells' numbering.
  for (int a = 0; a < 3; ++a) {
    const int m = ncell_[a], stored = stored_[a];
    adjacent_[a].resize(3 * static_cast<std::size_t>(stored));
    adjacent_shift_[a].resize(3 * static_cast<std::size_t>(stored));
    for (int c = 0; c < stored; ++c)
      for (int o = -1; o <= 1; ++o) {
        int cc = (window_first_[a] + c) % m + o;  // in the box's grid
        double sh = 0.0;
        if (box.periodic[a]) {
          if (cc < 0) sh = -len[a];  // cell m − 1 seen from cell 0: its image below the box
          if (cc >= m) sh = len[a];
          cc = stored_cell(a, (cc + m) % m);
        } else if (cc < 0 || cc >= m) {
          cc = -1;  // past an open edge: no cell
        }
        adjacent_[a][3 * c + o + 1] = cc;
        adjacent_shift_[a][3 * c + o + 1] = sh;
      }
  }
}

int NeighborList::stored_cell(int a, int c) const {
  const int m = ncell_[a];
  const int k = c - window_first_[a] + (c < window_first_[a] ? m : 0);
  return k < stored_[a] ? k : -1;
}

// Each pair of cells once (a cell with itself, and with the 13 of its 26 neighbours that lie
// "forward"), each pair of particles once: half the candidates of a full stencil, and no test
// on the particle indices. Needs ≥ 3 cells on every periodic axis, so that the 27 neighbours
// of a cell are distinct. The pairs are gathered, then sorted into rows by their smaller index
// (a stable counting sort). Threads (parallel.hpp) search runs of columns of cells, in cell order,
// into their own pair buffers; the buffers taken in order are the pairs in the order one
// thread finds them, so the list does not depend on the thread count; each row is then sorted by j
// (see the top of neighbor_list.hpp), so it does not depend on the search order either: any search
// that finds the same pairs gives the same list, array for array. The cells are searched by
// search_columns (above: the copies, the tests and the recording of the hits in one loop, four
// entries at a time with AVX2), with ghosts by its form that takes a cell's home beads as a
// prefix: a home bead's row as one process's, a ghost's against the forward cells' home beads.
void NeighborList::search_half_stencil(int n, bool have_exclusions) {
  const double rlist2 = (cutoff_ + skin_) * (cutoff_ + skin_);
  const std::size_t stride = static_cast<std::size_t>(n) + kCellPadding;
  const double* const cxs = cell_x_.data();  // the cell order's x, y, z (structure of arrays)
  const double* const cys = cxs + stride;
  const double* const czs = cys + stride;
  const int* cp = cell_particles_.data();
  const int* cs = cell_start_.data();
  // The stored cells (bin's window of the box's cells).
  const int nx = stored_[0], ny = stored_[1], nz = stored_[2];
  const int z_face = (ncell_[2] - window_first_[2]) % ncell_[2];
  // With halo flags each cell's home beads are a prefix of its range, cell_home_ long (bin).
  const bool halo = !ghost_.empty();
  const bool once = halo && ghost_once_;
  // Threads take contiguous runs of columns (cx, cy) in the search order, of about equal particle
  // counts: slabs of whole x-planes balanced poorly (23 planes on data.chain: 12 against 11).
  const int columns = nx * ny;
  const int parts = std::max(1, std::min(threads_for(n), columns));
  std::array<int, kMaxParts + 1> first_column{};
  for (int u = 0; u <= parts; ++u) {
    if (u == parts) {
      first_column[u] = columns;
      continue;
    }
    const std::int64_t target = block_begin(n, parts, u);  // the first particle of part u
    int lo = 0, hi = columns;                              // the first column starting at or past it
    while (lo < hi) {
      const int mid = (lo + hi) / 2;
      if (cs[mid * nz] < target)
        lo = mid + 1;
      else
        hi = mid;
    }
    first_column[u] = u == 0 ? 0 : lo;
  }
  row_sort_.begin(parts, n);
  if (static_cast<int>(pair_i_.size()) < parts) {
    pair_i_.resize(parts);
    pair_j_.resize(parts);
    hits_.resize(parts);
    scratch_.resize(parts);
    pair_count_.resize(parts);
  }
  run_parts(parts, [&](int u) {
    // The thread's pair buffers: their size is their capacity, pair_count_[u] the pairs in them.
    // Written through local pointers: the vector objects of all threads sit side by side, and
    // a push_back through them wrote the end pointer into a cache line the other thread's
    // push_backs wrote too (false sharing).
    std::vector<int>& pi = pair_i_[u];
    std::vector<int>& pj = pair_j_[u];
    // One particle's hits, as particle indices (at most n).
    std::vector<int>& hits = hits_[u];
    if (hits.size() < static_cast<std::size_t>(n) + kCellPadding)
      hits.resize(static_cast<std::size_t>(n) + kCellPadding);
    int* const hit = hits.data();
    int* const row_count = row_sort_.clear(u);  // the part's pairs per row, for the CSR sort
    // One cell's candidates (search_columns), each array padded (kCellPadding): the copies and
    // the tests read and write whole groups of four. With halo flags a second set for the
    // forward cells' home beads, the candidates of the cell's halo beads.
    CandidateScratch& sc = scratch_[u];
    if (sc.x.size() < stride) {
      sc.x.resize(stride);
      sc.y.resize(stride);
      sc.z.resize(stride);
      sc.k.resize(stride);
    }
    if (halo && sc.gx.size() < stride) {
      sc.gx.resize(stride);
      sc.gy.resize(stride);
      sc.gz.resize(stride);
      sc.gk.resize(stride);
    }
    HalfStencilPart part{cxs,
                         cys,
                         czs,
                         cp,
                         cs,
                         {adjacent_[0].data(), adjacent_[1].data(), adjacent_[2].data()},
                         {adjacent_shift_[0].data(), adjacent_shift_[1].data(), adjacent_shift_[2].data()},
                         ny,
                         nz,
                         z_face,
                         rlist2,
                         first_column[u],
                         first_column[u + 1],
                         sc.x.data(),
                         sc.y.data(),
                         sc.z.data(),
                         sc.k.data(),
                         hit,
                         have_exclusions ? excl_offsets_.data() : nullptr,
                         excl_.data(),
                         row_count,
                         &pi,
                         &pj,
                         0,
                         halo ? cell_home_.data() : nullptr,
                         sc.gx.data(),
                         sc.gy.data(),
                         sc.gz.data(),
                         sc.gk.data()};
#if defined(__x86_64__)
    static const bool avx2 = __builtin_cpu_supports("avx2") && __builtin_cpu_supports("popcnt");
    if (avx2) {
      if (halo)
        search_columns_halo_avx2(part);
      else
        search_columns_avx2(part);
    } else
#endif
    {
      if (halo)
        search_columns_halo_portable(part);
      else
        search_columns_portable(part);
    }
    pair_count_[u] = part.used;
    // With the ghost pairs once, a pair whose lower index is a ghost is left out (see the top of
    // neighbor_list.hpp): the ghosts' rows counted empty here, and their pairs skipped below.
    if (once)
      for (int i = 0; i < n; ++i) row_count[i] &= ghost_[i] ? 0 : ~0;
  });

  // The pairs into CSR rows by i: a counting sort of the parts' buffers in part order
  // (counting_sort.hpp), on the threads.
  offsets_.resize(static_cast<std::size_t>(n) + 1);
  row_sort_.starts(offsets_.data());
  neighbors_.resize(static_cast<std::size_t>(offsets_[n]));
  run_parts(parts, [&](int u) {
    auto cursor = row_sort_.cursor(u);
    const int* pi = pair_i_[u].data();
    const int* pj = pair_j_[u].data();
    int* to = neighbors_.data();
    if (once) {
      const char* ghost = ghost_.data();
      for (std::size_t p = 0; p < pair_count_[u]; ++p)
        if (!ghost[pi[p]]) to[cursor.slot(pi[p])] = pj[p];
      return;
    }
    for (std::size_t p = 0; p < pair_count_[u]; ++p) to[cursor.slot(pi[p])] = pj[p];
  });
  // Each row in increasing j: the pairs of a particle are then summed in an order that depends
  // only on which particles they are, not on where the cells were at the build (docs/parallel.md:
  // a decomposed run's forces are the same sums, bit for bit).
  parallel_blocks(n, threads_for(n), [&](std::int64_t b, std::int64_t e) {
#if defined(__x86_64__)
    static const bool avx2 = __builtin_cpu_supports("avx2") && __builtin_cpu_supports("popcnt");
    if (avx2) {
      sort_rows_avx2(neighbors_.data(), offsets_.data(), b, e);
      return;
    }
#endif
    sort_rows_portable(neighbors_.data(), offsets_.data(), b, e);
  });
}

// Boxes with fewer than 3 cells on a periodic axis (a few cutoffs wide): the neighbour cells
// c − 1 and c + 1 coincide, so visit each distinct neighbour cell once from every particle,
// keep j > i, and round every separation to the minimum image.
void NeighborList::search_small_box(int n, const MinimumImage& mi, bool have_exclusions) {
  const double rlist2 = (cutoff_ + skin_) * (cutoff_ + skin_);
  const double* xw = binned_x_;
  const std::size_t stride = static_cast<std::size_t>(n) + kCellPadding;
  const double* const cxs = cell_x_.data();  // the cell order's x, y, z (structure of arrays)
  const double* const cys = cxs + stride;
  const double* const czs = cys + stride;
  const int* cp = cell_particles_.data();
  const int* cs = cell_start_.data();
  const int ny = stored_[1], nz = stored_[2];  // every cell: no window on a small box
  offsets_.resize(static_cast<std::size_t>(n) + 1);
  offsets_[0] = 0;
  neighbors_.clear();  // keeps its capacity
  if (ncell_[0] <= 2 && ncell_[1] <= 2 && ncell_[2] <= 2) {
    search_all_pairs(n, mi, have_exclusions);
    return;
  }
  // Per axis and cell coordinate, the distinct neighbour coordinates.
  int distinct[3][3], count[3];
  for (int i = 0; i < n; ++i) {
    const bool i_ghost = !ghost_.empty() && ghost_[i];
    const int cell = cell_of_[i];
    const int ci[3] = {cell / (ny * nz), (cell / nz) % ny, cell % nz};
    for (int a = 0; a < 3; ++a) {
      count[a] = 0;
      for (int o = 0; o < 3; ++o) {
        const int cc = adjacent_[a][3 * ci[a] + o];
        if (cc >= 0 && std::find(distinct[a], distinct[a] + count[a], cc) == distinct[a] + count[a])
          distinct[a][count[a]++] = cc;
      }
    }
    const bool may_exclude = have_exclusions && excl_offsets_[i + 1] > excl_offsets_[i];
    const double xi = xw[3 * i], yi = xw[3 * i + 1], zi = xw[3 * i + 2];
    for (int sx = 0; sx < count[0]; ++sx)
      for (int sy = 0; sy < count[1]; ++sy)
        for (int sz = 0; sz < count[2]; ++sz) {
          const int c = (distinct[0][sx] * ny + distinct[1][sy]) * nz + distinct[2][sz];
          // j > i only: a cell's particles are in increasing index, so those are a suffix.
          for (int k = cs[c + 1] - 1; k >= cs[c] && cp[k] > i; --k) {
            double dx = xi - cxs[k], dy = yi - cys[k], dz = zi - czs[k];
            mi.apply(dx, dy, dz);
            if (dx * dx + dy * dy + dz * dz < rlist2 && !(may_exclude && excluded(i, cp[k])) &&
                !(i_ghost && left_out(i, cp[k])))
              neighbors_.push_back(cp[k]);
          }
        }
    std::sort(neighbors_.begin() + offsets_[i], neighbors_.end());
    offsets_[i + 1] = static_cast<std::int64_t>(neighbors_.size());
  }
}

// At most 2 cells on every axis (a box under two list radii wide, as LAMMPS's peptide example's
// 27 Å for 10 + 2 Å): every cell neighbours every cell, so the candidates of i are all j > i. Read
// in index order they give search_small_box's rows — the same pairs, the same separations
// (wrapped_x_ is what cell_x_ holds, in index order), already sorted — without the walk over
// cells or the sort of each row. The distance test keeps a candidate without a branch (about
// two in three are beyond the list radius, at random: a branch would mispredict often); the
// exclusions (bonded neighbours) and ghost pairs are then dropped from the few kept.
void NeighborList::search_all_pairs(int n, const MinimumImage& mi, bool have_exclusions) {
  const double rlist2 = (cutoff_ + skin_) * (cutoff_ + skin_);
  const double* xw = binned_x_;
  if (hits_.empty()) hits_.resize(1);
  std::vector<int>& hits = hits_[0];
  if (hits.size() < static_cast<std::size_t>(n) + 1) hits.resize(static_cast<std::size_t>(n) + 1);
  int* const hit = hits.data();
  for (int i = 0; i < n; ++i) {
    const double xi = xw[3 * i], yi = xw[3 * i + 1], zi = xw[3 * i + 2];
    int count = 0;
    for (int j = i + 1; j < n; ++j) {
      double dx = xi - xw[3 * j], dy = yi - xw[3 * j + 1], dz = zi - xw[3 * j + 2];
      mi.apply(dx, dy, dz);
      hit[count] = j;
      count += dx * dx + dy * dy + dz * dz < rlist2;
    }
    const bool may_exclude = have_exclusions && excl_offsets_[i + 1] > excl_offsets_[i];
    const bool i_ghost = !ghost_.empty() && ghost_[i];
    if (may_exclude || i_ghost) {
      int kept = 0;
      for (int h = 0; h < count; ++h) {
        const int j = hit[h];
        hit[kept] = j;
        kept += !(may_exclude && excluded(i, j)) && !(i_ghost && left_out(i, j));
      }
      count = kept;
    }
    neighbors_.insert(neighbors_.end(), hit, hit + count);
    offsets_[i + 1] = static_cast<std::int64_t>(neighbors_.size());
  }
}

void NeighborList::build(const Eigen::Matrix3Xd& x, const Box& box) {
  check_box_for_cutoff(box, cutoff_, skin_);
  const int n = static_cast<int>(x.cols());
  const bool have_exclusions = !excl_.empty();
  if (have_exclusions && excl_particles_ != n) {
    std::ostringstream s;
    s << "neighbour list: exclusions were set for " << excl_particles_ << " particles, positions have " << n;
    throw std::invalid_argument(s.str());
  }
  bin(x, box);
  if (small_box_)
    search_small_box(n, MinimumImage(box), have_exclusions);
  else
    search_half_stencil(n, have_exclusions);

  x_at_build_.resize(3, n);  // same size after the first build: Eigen reuses the storage
  parallel_blocks(n, threads_for(n),
                  [&](std::int64_t b, std::int64_t e) { x_at_build_.middleCols(b, e - b) = x.middleCols(b, e - b); });
  box_at_build_ = box_now_ = box;
  built_ = true;
  ++rebuilds_;
  static std::atomic<std::uint64_t> builds{0};  // every list's, for build_id
  build_id_ = ++builds;
}

void NeighborList::restore(const Eigen::Matrix3Xd& x_at_build, const Box& box, long rebuilds) {
  build(x_at_build, box);
  rebuilds_ = rebuilds;
}

void NeighborList::release() {
  built_ = false;
  // Swapped with empty containers: clear() would keep the capacity.
  auto free = [](auto& c) { std::remove_reference_t<decltype(c)>().swap(c); };
  free(cell_home_), free(key_start_), free(occupied_), free(offsets_), free(neighbors_), free(fast_), free(cell_of_);
  free(cell_start_), free(cell_particles_), free(pair_i_), free(pair_j_), free(pair_count_), free(hits_);
  free(scratch_);
  for (int a = 0; a < 3; ++a) free(adjacent_[a]), free(adjacent_shift_[a]);
  free(cell_x_);
  for (Eigen::Matrix3Xd* m : {&x_at_build_, &image_, &wrapped_x_, &wrapped_now_}) m->resize(3, 0);
  cell_sort_ = {};
  row_sort_ = {};
}

}  // namespace stiffmd
