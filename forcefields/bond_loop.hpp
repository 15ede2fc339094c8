// The loop over two-body bonds, written once and shared by every bond style (docs/design.md §11.1,
// after HOOMD's EvaluatorBond*): a style supplies only a kernel
//     static void eval(double r, const Params& p, double& energy, double& dE_dr);
//
// Threads (parallel.hpp): owner computes. Thread t owns a contiguous range of particles and
// evaluates every bond with an end it owns, adding the force only to the ends it owns; a bond
// whose ends have different owners is evaluated by both. No two threads write one particle, so
// there is no race and no per-thread force copy, and the sums are in a fixed order for a given
// thread count. In chains numbered along the backbone only the bonds at the range boundaries
// are evaluated twice.
#pragma once

#include <Eigen/Core>
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <type_traits>
#include <vector>

#include "core/box.hpp"
#include "core/errors.hpp"
#include "core/molecule_blocks.hpp"
#include "core/parallel.hpp"
#include "core/state.hpp"
#include "forcefields/neighbor_list.hpp"
#include "forcefields/tuple_partition.hpp"

namespace stiffmd {

template <class Params>
struct BondInstance {
  int i;
  int j;
  Params params;
};

// Work items per block of the bond loop (bond_block below).
inline constexpr int kBondBlock = 64;

// Items begin … end − 1 cut into segments {begin, end, chain} appended to `out`, in order: chain
// runs — two or more items, each continuing the one before (links(k): item k + 1 continues item
// k's chain) — and between them the other items, each stretch extended up to the next chain run.
template <class Links, class Segment>
void append_chain_runs(std::int64_t begin, std::int64_t end, const Links& links, std::vector<Segment>& out) {
  std::int64_t k = begin;
  while (k < end) {
    std::int64_t e = k + 1;
    while (e < end && links(e - 1)) ++e;
    const bool chain = e - k >= 2;
    if (!chain)
      while (e < end && !(e + 1 < end && links(e))) ++e;
    out.push_back({k, e, chain});
    k = e;
  }
}

// Which bonds each thread evaluates, and for which ends (owner computes, see above).
class BondPartition {
 public:
  struct Work {
    int bond;
    bool add_i;  // this thread owns particle i: add f_i, and count the bond's energy
    bool add_j;  // this thread owns particle j: add f_j
  };

  // Rebuilds for `threads` owners if the thread count or the bonds changed. The particle ranges
  // are split so that each owns about the same number of bond ends.
  template <class Params>
  void prepare(const std::vector<BondInstance<Params>>& bonds, int threads) {
    if (threads == threads_ && bonds.size() == num_bonds_) return;
    threads_ = threads;
    num_bonds_ = bonds.size();
    start_.assign(threads + 1, 0);
    work_.clear();
    if (threads == 1) {  // every bond, both ends, in order: item k is bond k, read without work items
      segments_.clear();
      segment_start_.assign(2, 0);
      auto links = [&](std::int64_t k) {  // bond k + 1 continues bond k's chain
        const auto &a = bonds[k], &b = bonds[k + 1];
        return a.j == a.i + 1 && b.i == a.j && b.j == b.i + 1;
      };
      append_chain_runs(0, static_cast<std::int64_t>(bonds.size()), links, segments_);
      segment_start_[1] = static_cast<std::int64_t>(segments_.size());
      find_uniform(bonds);
      return;
    }
    int n = 0;
    for (const auto& b : bonds) n = std::max({n, b.i + 1, b.j + 1});
    std::vector<std::int64_t> ends(n + 1, 0);  // ends[p + 1]: bond ends at particles ≤ p
    for (const auto& b : bonds) {
      ++ends[b.i + 1];
      ++ends[b.j + 1];
    }
    const std::vector<int> first = owner_ranges(ends, threads);  // owner t: particles first[t] … first[t+1] − 1
    auto owner = [&](int p) {
      return static_cast<int>(std::upper_bound(first.begin(), first.end() - 1, p) - first.begin()) - 1;
    };
    std::vector<std::vector<Work>> per(threads);
    for (std::size_t k = 0; k < bonds.size(); ++k) {
      const int oi = owner(bonds[k].i), oj = owner(bonds[k].j);
      if (oi == oj) {
        per[oi].push_back({static_cast<int>(k), true, true});
      } else {
        per[oi].push_back({static_cast<int>(k), true, false});
        per[oj].push_back({static_cast<int>(k), false, true});
      }
    }
    for (int t = 0; t < threads; ++t) {
      start_[t + 1] = start_[t] + static_cast<std::int64_t>(per[t].size());
      work_.insert(work_.end(), per[t].begin(), per[t].end());
    }
    find_segments(bonds);
    find_uniform(bonds);
  }

  int threads() const { return threads_; }
  // Owner t's work items (none when prepared for one thread: its segments index the bonds).
  const Work* begin(int t) const { return work_.data() + start_[t]; }
  const Work* end(int t) const { return work_.data() + start_[t + 1]; }
  double* energy_slots() { return energy_.data(); }  // one per owner
  // Owner t's work split into segments, in work order: chain runs —
  // consecutive items that are bonds k, k + 1, … joining particles p, p + 1, p + 2, … with both
  // ends owned — and the other items.
  struct Segment {
    std::int64_t begin, end;  // work items
    bool chain;
  };
  const Segment* segments_begin(int t) const { return segments_.data() + segment_start_[t]; }
  const Segment* segments_end(int t) const { return segments_.data() + segment_start_[t + 1]; }
  const Work* work() const { return work_.data(); }
  // Whether every bond has the same coefficients (those of bond 0, bit for bit), and then the
  // bonds' ends, i then j for each bond in bond order — what the one-thread loop and the chain
  // runs read in place of the bonds (8 bytes a bond, not 8 + sizeof(Params)).
  bool uniform() const { return uniform_; }
  const int* ends() const { return ends_.data(); }

 private:
  int threads_ = 0;
  std::size_t num_bonds_ = 0;
  std::vector<std::int64_t> start_;
  std::vector<Work> work_;
  std::vector<Segment> segments_;
  std::vector<std::int64_t> segment_start_;

  template <class Params>
  void find_uniform(const std::vector<BondInstance<Params>>& bonds) {
    static_assert(std::is_trivially_copyable_v<Params>);
    uniform_ = std::all_of(bonds.begin(), bonds.end(), [&](const BondInstance<Params>& b) {
      return std::memcmp(&b.params, &bonds.front().params, sizeof(Params)) == 0;
    });
    ends_.clear();
    if (!uniform_) return;
    ends_.resize(2 * bonds.size());
    for (std::size_t k = 0; k < bonds.size(); ++k) ends_[2 * k] = bonds[k].i, ends_[2 * k + 1] = bonds[k].j;
  }
  bool uniform_ = false;
  std::vector<int> ends_;

  template <class Params>
  void find_segments(const std::vector<BondInstance<Params>>& bonds) {
    segments_.clear();
    segment_start_.assign(threads_ + 1, 0);
    auto links = [&](std::int64_t k) {  // item k + 1 continues item k's chain
      const Work &a = work_[k], &b = work_[k + 1];
      const auto &ba = bonds[a.bond], &bb = bonds[b.bond];
      return a.add_i && a.add_j && b.add_i && b.add_j && b.bond == a.bond + 1 && ba.j == ba.i + 1 && bb.i == ba.j &&
             bb.j == bb.i + 1;
    };
    for (int t = 0; t < threads_; ++t) {
      append_chain_runs(start_[t], start_[t + 1], links, segments_);
      segment_start_[t + 1] = static_cast<std::int64_t>(segments_.size());
    }
  }
  std::vector<double> energy_ = std::vector<double>(kMaxParts, 0.0);
};

// The force factor of one bond: −(1/r) dE/dr (the force on i is this times x_i − x_j, on j its
// negative), and its energy into e, from r² = |x_i − x_j|². A kernel with eval_sq
// (bond_potentials.hpp) takes r² as it is and marks a bond outside its domain by a NaN energy —
// the caller tests the block's energy, as a throw inside the loop would keep the loop scalar; the
// others take r = √r² and throw themselves.
template <class Kernel>
inline constexpr bool kSquaredKernel = requires(double r_sq, const typename Kernel::Params& p, double& e, double& g) {
  Kernel::eval_sq(r_sq, p, e, g);
};

template <class Kernel, class Params>
[[gnu::always_inline]] inline double bond_force_factor(double r_sq, const Params& p, double& e) {
  if constexpr (kSquaredKernel<Kernel>) {
    double g = 0.0;
    Kernel::eval_sq(r_sq, p, e, g);
    return -g;
  } else {
    const double r = std::sqrt(r_sq);
    double de_dr = 0.0;
    Kernel::eval(r, p, e, de_dr);
    return -de_dr / r;
  }
}

// After a kernel with eval_sq: a NaN energy is a bond outside its domain (the term finds and
// names it). Kernels with eval throw themselves; a NaN they give is left to the run's checks.
template <class Kernel>
inline void check_bond_domain(double e) {
  if constexpr (kSquaredKernel<Kernel>)
    if (std::isnan(e)) throw NumericalError("a bond left the kernel's domain");
}

// The bonds a block reads, three ways (each a view with the ends i(q), j(q), the coefficients
// params(q), which ends get the force, and whether the energy is counted, for item q):
//   OwnerItems    an owner's work items (BondPartition::Work: several threads, the fused step);
//   AllBonds      every bond in order, both ends (one thread);
//   UniformBonds  the same with one set of coefficients for every bond, read once, and the ends
//                 from BondPartition::ends (one thread, one bond type: the common case).
template <class Params>
struct OwnerItems {
  static constexpr bool kUniform = false;
  const BondInstance<Params>* bonds;
  const BondPartition::Work* work;
  int i(std::int64_t q) const { return bonds[work[q].bond].i; }
  int j(std::int64_t q) const { return bonds[work[q].bond].j; }
  const Params& params(std::int64_t q) const { return bonds[work[q].bond].params; }
  bool add_i(std::int64_t q) const { return work[q].add_i; }  // and count the energy: the owner of i
  bool add_j(std::int64_t q) const { return work[q].add_j; }
};
template <class Params>
struct AllBonds {
  static constexpr bool kUniform = false;
  const BondInstance<Params>* bonds;
  int i(std::int64_t q) const { return bonds[q].i; }
  int j(std::int64_t q) const { return bonds[q].j; }
  const Params& params(std::int64_t q) const { return bonds[q].params; }
  static constexpr bool add_i(std::int64_t) { return true; }
  static constexpr bool add_j(std::int64_t) { return true; }
};
template <class Params>
struct UniformBonds {
  static constexpr bool kUniform = true;
  const int* ends;  // i, j of each bond
  const Params* coefficients;
  int i(std::int64_t q) const { return ends[2 * q]; }
  int j(std::int64_t q) const { return ends[2 * q + 1]; }
  const Params& params(std::int64_t) const { return *coefficients; }
  static constexpr bool add_i(std::int64_t) { return true; }
  static constexpr bool add_j(std::int64_t) { return true; }
};

// Kernels whose energy has a logarithmic part apart (eval_sq_split, log_weight: FENE).
template <class Kernel>
inline constexpr bool kSplitLogKernel = requires(double r_sq, const typename Kernel::Params& p, double& e, double& u,
                                                 double& g) {
  Kernel::eval_sq_split(r_sq, p, e, u, g);
  Kernel::log_weight(p);
};

// The forces of a gathered block: d[·][k] = x_i − x_j of its item k on entry, the force on i on
// return; Σ counted[k] E_k (every E_k without kCounted) added to e_t. One loop without branches or
// memory dependences, which the compiler vectorises: with eval_sq kernels the whole kernel, else
// the square roots and divisions, two per instruction. p: the items' coefficients, or with
// kUniform p[0] for all.
//
// One type and every energy counted, with a kernel whose energy is e_rest + w ln u (FENE): the
// block's logarithms are added as one, w ln Π_k u_k — a product per bond in place of a logarithm
// per bond, which was most of the kernel's work. Each factor has a relative rounding error below
// 2⁻⁵³, so the sum's error is that of adding the bonds' logarithms; a product below 2⁻¹⁰⁰⁰ (which
// would lose digits as a subnormal: bonds near R₀) is redone bond by bond.
// kCheck false: a bond outside the kernel's domain is not thrown here but left as a NaN in e_t,
// for the caller to test (chain_block: a function compiled with target_clones must not throw).
// kEnergy false: the energies are not formed (nor added to e_t) — for callers that discard them
// (the micro steps) with a kernel that does not mark its domain by the energy (eval, not eval_sq).
// Always inlined: in chain_block_forces each target clone must compile it for its own instruction
// set. Left to GCC's heuristics, one out-of-line copy for the default target was called from the
// AVX2 clone once its translation unit grew (FENE on inputs/kremer_grest.toml: 214 M instructions
// in 100 steps against 144 M inlined, callgrind).
template <class Kernel, bool kUniform, bool kCounted, bool kCheck = true, bool kEnergy = true, class Params>
[[gnu::always_inline]] inline void block_forces(double (&d)[3][kBondBlock], const Params* __restrict p,
                                                const double* __restrict counted, int nb, double& e_t) {
  static_assert(kEnergy || !kSquaredKernel<Kernel>, "an eval_sq kernel's energy is its domain test");
  // Locals, not e_t: a store the loop could alias would keep it scalar.
  const Params p0 = p[0];
  if constexpr (kUniform && !kCounted && kEnergy && kSplitLogKernel<Kernel>) {
    alignas(64) double e_rest[kBondBlock], u[kBondBlock];
    for (int k = 0; k < nb; ++k) {
      double g = 0.0;
      Kernel::eval_sq_split(d[0][k] * d[0][k] + d[1][k] * d[1][k] + d[2][k] * d[2][k], p0, e_rest[k], u[k], g);
      for (int a = 0; a < 3; ++a) d[a][k] *= -g;
    }
    // The sum and the product in four interleaved parts, combined in a fixed order (an in-order
    // product would be one multiplication's latency per bond, and is not vectorised).
    double sum[4] = {0.0, 0.0, 0.0, 0.0}, product[4] = {1.0, 1.0, 1.0, 1.0};
    int k = 0;
    for (; k + 4 <= nb; k += 4)
      for (int l = 0; l < 4; ++l) {
        sum[l] += e_rest[k + l];
        product[l] *= u[k + l];
      }
    for (; k < nb; ++k) {
      sum[0] += e_rest[k];
      product[0] *= u[k];
    }
    const double e_sum = (sum[0] + sum[1]) + (sum[2] + sum[3]);
    if constexpr (kCheck) check_bond_domain<Kernel>(e_sum);
    const double all = (product[0] * product[1]) * (product[2] * product[3]);
    double log_sum = std::log(all);
    if (!(all >= 0x1p-1000)) {
      log_sum = 0.0;
      for (int b = 0; b < nb; ++b) log_sum += std::log(u[b]);
    }
    e_t += e_sum + Kernel::log_weight(p0) * log_sum;
    return;
  }
  double e_sum = e_t;
  for (int k = 0; k < nb; ++k) {
    double e = 0.0;
    const double scale =
        bond_force_factor<Kernel>(d[0][k] * d[0][k] + d[1][k] * d[1][k] + d[2][k] * d[2][k], kUniform ? p0 : p[k], e);
    if constexpr (kEnergy && kCounted)
      e_sum += counted[k] * e;  // 0 · NaN is NaN: an item whose energy another owner counts is tested too
    else if constexpr (kEnergy)
      e_sum += e;
    for (int a = 0; a < 3; ++a) d[a][k] *= scale;
  }
  if constexpr (kCheck) check_bond_domain<Kernel>(e_sum);
  e_t = e_sum;
}

// Items q … q + nb − 1 (nb ≤ kBondBlock) of a view: gather the separations, compute every force of
// the block (block_forces), then add the forces into f (the ends the view adds). Adds the block's energy (bonds counted
// by the owner of i), in item order, to e_t. Adding each force as soon as it is known was measured at the latency of
// sqrt + div per bond: in a chain, bond k + 1 adds into the particle bond k has just written.
//
// A block of at most kFewBonds items (a small molecule, a pendulum, an owner's last items) is
// done bond by bond: the same operations in the same order, so the same bits, without the
// gathered block — whose vector loads of just-stored scalars stall store-to-load forwarding, which
// a handful of bonds does not amortise.
inline constexpr int kFewBonds = 4;

template <class Kernel, class Bonds>
inline void bond_block(const Bonds& bonds, std::int64_t q0, int nb, const double* __restrict xp, double* __restrict fp,
                       double& e_t) {
  if (nb <= kFewBonds) {
    for (int k = 0; k < nb; ++k) {
      const std::int64_t q = q0 + k;
      const int i = bonds.i(q), j = bonds.j(q);
      double d[3] = {xp[3 * i] - xp[3 * j], xp[3 * i + 1] - xp[3 * j + 1], xp[3 * i + 2] - xp[3 * j + 2]};
      double e = 0.0;
      const double scale = bond_force_factor<Kernel>(d[0] * d[0] + d[1] * d[1] + d[2] * d[2], bonds.params(q), e);
      check_bond_domain<Kernel>(e);
      e_t += (bonds.add_i(q) ? 1.0 : 0.0) * e;
      for (int a = 0; a < 3; ++a) d[a] *= scale;
      if (bonds.add_i(q))
        for (int a = 0; a < 3; ++a) fp[3 * i + a] += d[a];
      if (bonds.add_j(q))
        for (int a = 0; a < 3; ++a) fp[3 * j + a] -= d[a];
    }
    return;
  }
  using Params = std::remove_cvref_t<decltype(bonds.params(0))>;
  alignas(64) double d[3][kBondBlock], counted[kBondBlock];
  Params p[Bonds::kUniform ? 1 : kBondBlock];  // the block's coefficients, unless one for all
  for (int k = 0; k < nb; ++k) {
    const std::int64_t q = q0 + k;
    const int i = bonds.i(q), j = bonds.j(q);
    for (int a = 0; a < 3; ++a) d[a][k] = xp[3 * i + a] - xp[3 * j + a];
    if constexpr (!Bonds::kUniform) p[k] = bonds.params(q);
    counted[k] = bonds.add_i(q) ? 1.0 : 0.0;  // the energy is counted once, by the owner of i
  }
  if constexpr (Bonds::kUniform) p[0] = bonds.params(q0);
  block_forces<Kernel, Bonds::kUniform, true>(d, p, counted, nb, e_t);
  for (int k = 0; k < nb; ++k) {
    const std::int64_t q = q0 + k;
    const int i = bonds.i(q), j = bonds.j(q);
    if (bonds.add_i(q))
      for (int a = 0; a < 3; ++a) fp[3 * i + a] += d[a][k];
    if (bonds.add_j(q))
      for (int a = 0; a < 3; ++a) fp[3 * j + a] -= d[a][k];
  }
}

// Items q … q + nb − 1 of a chain run of one thread (BondPartition::Segment; both ends added,
// every energy counted): bond q + k joins particles p + k and p + k + 1, p = i(q). The separations
// are differences of consecutive positions, and each particle's force is written once:
//   f_p += f₀,   f_{p+k} = (f_{p+k} − f_{k−1}) + f_k,   f_{p+nb} −= f_{nb−1}
// — bond_block's operations on each particle in the same order (−f of bond k − 1, then +f of bond
// k), so the same bits, without the ends' indices and with the gather and scatter streaming.
// Compiled twice, for AVX2 and for the baseline x86-64 (the build's default target), the one the
// CPU has chosen at load time: the kernel's loop then takes four bonds per instruction where the
// CPU allows. The same bits either way: every operation is an IEEE one, element by element, none
// is contracted into an FMA (-std=c++20 compiles with -ffp-contract=off), and the sums are in the
// order written.
//
// It never throws: GCC 12 takes a call of a target_clones function for one that cannot, and an
// exception thrown through it ends the program (in a parallel region, or in a try block with no
// other call that may throw). A bond outside the kernel's domain leaves e_t NaN, which chain_block
// below tests. kEnergy false (block_forces): e_t is left as it is, the energies not formed.
template <class Kernel, bool kEnergy, class Bonds>
[[gnu::target_clones("avx2", "default")]] void chain_block_forces(const Bonds& bonds, std::int64_t q0, int nb,
                                                                  const double* __restrict xp, double* __restrict fp,
                                                                  double& e_t) {
  using Params = std::remove_cvref_t<decltype(bonds.params(0))>;
  const std::int64_t first = bonds.i(q0);
  const double* __restrict x = xp + 3 * first;
  double* __restrict f = fp + 3 * first;
  alignas(64) double d[3][kBondBlock];
  Params p[Bonds::kUniform ? 1 : kBondBlock];
  for (int k = 0; k < nb; ++k)
    for (int a = 0; a < 3; ++a) d[a][k] = x[3 * k + a] - x[3 * k + 3 + a];
  if constexpr (Bonds::kUniform)
    p[0] = bonds.params(q0);
  else
    for (int k = 0; k < nb; ++k) p[k] = bonds.params(q0 + k);
  block_forces<Kernel, Bonds::kUniform, false, false, kEnergy>(d, p, nullptr, nb, e_t);
  for (int a = 0; a < 3; ++a) f[a] += d[a][0];
  for (int k = 1; k < nb; ++k)
    for (int a = 0; a < 3; ++a) f[3 * k + a] = (f[3 * k + a] - d[a][k - 1]) + d[a][k];
  for (int a = 0; a < 3; ++a) f[3 * nb + a] -= d[a][nb - 1];
}

// chain_block_forces, then its domain test (check_bond_domain): NaN energy so far, a bond outside.
template <class Kernel, bool kEnergy = true, class Bonds>
inline void chain_block(const Bonds& bonds, std::int64_t q0, int nb, const double* __restrict xp, double* __restrict fp,
                        double& e_t) {
  chain_block_forces<Kernel, kEnergy>(bonds, q0, nb, xp, fp, e_t);
  check_bond_domain<Kernel>(e_t);
}

// Adds −∇E into f for every bond and returns Σ E. The bond vector is x_i − x_j of the unwrapped
// positions (bond_vector, core/state.hpp): molecules are whole, so it is the minimum image
// without computing one, and `box` is not needed. `partition` is the per-term thread plan
// (rebuilt when the thread count changes). Each owner works in blocks: its chain runs through
// chain_block, the rest through bond_block; one thread reads the bonds in order without the plan's
// work items, and with one set of coefficients for all bonds only their ends (UniformBonds), as do
// the chain runs of several owners. Every path gives each bond the same operations and each
// particle its forces in bond order: the forces' bits at any thread count (the energy's sum is
// blocked by segment, so its bits are fixed for a given thread count).
template <class Kernel, class Params>
double accumulate_bond_forces(const std::vector<BondInstance<Params>>& bonds, const Eigen::Matrix3Xd& x, const Box& box,
                              Eigen::Matrix3Xd& f, BondPartition& partition) {
  (void)box;
  double* fp = f.data();
  const double* xp = x.data();
  const int threads = threads_for(static_cast<std::int64_t>(bonds.size()));
  partition.prepare(bonds, threads);
  if (threads == 1) {
    double e = 0.0;
    auto run = [&](const auto& view) {  // the segments of the one owner: chain runs and the rest
      for (const auto* seg = partition.segments_begin(0); seg < partition.segments_end(0); ++seg)
        for (std::int64_t q = seg->begin; q < seg->end; q += kBondBlock) {
          const int nb = static_cast<int>(std::min<std::int64_t>(kBondBlock, seg->end - q));
          if (seg->chain)
            chain_block<Kernel>(view, q, nb, xp, fp, e);
          else
            bond_block<Kernel>(view, q, nb, xp, fp, e);
        }
    };
    run_parts(1, [&](int) {
      if (partition.uniform())
        run(UniformBonds<Params>{partition.ends(), &bonds.front().params});
      else
        run(AllBonds<Params>{bonds.data()});
    });
    return e;
  }
  // Several owners: each walks its segments. A chain run's items are bonds b₀, b₀ + 1, … with
  // both ends owned, so it is read as the one-thread loop reads it — the bonds in order (their
  // ends alone with one set of coefficients) through chain_block — and the other items, those
  // across an owner's boundary among them, through bond_block. Each particle still gets its
  // forces in bond order (chain_block's and bond_block's claim), so the forces keep their bits.
  double* energy = partition.energy_slots();
  const OwnerItems<Params> items{bonds.data(), partition.work()};
  const BondPartition::Work* work = partition.work();
  auto run_owner = [&](int t, const auto& in_order) {
    double e_t = 0.0;
    for (const auto* seg = partition.segments_begin(t); seg < partition.segments_end(t); ++seg) {
      const std::int64_t shift = seg->chain ? work[seg->begin].bond - seg->begin : 0;  // item → bond
      for (std::int64_t q = seg->begin; q < seg->end; q += kBondBlock) {
        const int nb = static_cast<int>(std::min<std::int64_t>(kBondBlock, seg->end - q));
        if (seg->chain)
          chain_block<Kernel>(in_order, q + shift, nb, xp, fp, e_t);
        else
          bond_block<Kernel>(items, q, nb, xp, fp, e_t);
      }
    }
    energy[t] = e_t;
  };
  run_parts(threads, [&](int t) {
    if (partition.uniform())
      run_owner(t, UniformBonds<Params>{partition.ends(), &bonds.front().params});
    else
      run_owner(t, AllBonds<Params>{bonds.data()});
  });
  double sum = 0.0;
  for (int t = 0; t < threads; ++t) sum += energy[t];
  return sum;
}

// The micro steps of a bond term alone on the innermost level (FusedMicroStep, force_term.hpp;
// docs/design.md §3), molecule block by molecule block. A micro step is, for every particle,
//   v += dt_kick M⁻¹ f,  x += dt v,  f = 0,  then f += the bond forces at the new x,
// and a bond joins particles of one molecule, so the new force of a molecule's particles depends on
// that molecule's x alone: `steps` micro steps of a block of whole molecules need no other particle.
// The plan cuts the particles into blocks of whole molecules (kMicroBlockParticles or more
// particles each, about 80 bytes a particle: x, v, f and M⁻¹ stay in L1) and takes every micro step
// of one block before the next block: the particles are read from memory once per `steps` micro
// steps instead of three times per micro step (kick_drift, f = 0, the bond loop: each pass over a
// 256 000-bead melt streams ≈ 20 MB, docs/performance.md, "The 256 000-bead melts").
//
// Same bits as the plain path (kick_drift, f = 0, accumulate_bond_forces per micro step): each
// particle gets the same kick and drift expressions, and its bond forces in the bonds' order,
// starting from 0 — a block's bonds are the term's bonds in their order (a stable sort by block),
// their chain runs (consecutive bonds along consecutive particles) through chain_block and the
// rest through bond_block, which give each particle its forces in bond order (the bond loop's
// claim). The blocks are disjoint in particles, so threads take whole blocks and the bits do not
// depend on the thread count.
//
// A molecule is a range of particle indices: the union of the index intervals [min(i, j),
// max(i, j)] of its bonds. Molecules numbered in ranges (every engine's data) give blocks of a few
// molecules; a bond between far-apart indices (a ring closed across the system, shuffled
// numbering) makes one large block, correct but streamed from memory like the plain path.
inline constexpr std::int64_t kMicroBlockParticles = 256;

template <class Params>
class MicroStepPlan {
 public:
  struct Block {
    std::int64_t first, last;                 // particles first … last − 1
    std::int64_t segment_begin, segment_end;  // its segments of ordered bonds
  };
  struct Segment {
    std::int64_t begin, end;  // ordered bonds
    bool chain;               // a chain run: bond q + k joins particles p + k and p + k + 1
  };

  // Rebuilds when the bonds' count or the particles' count changed (the term's bonds are fixed).
  void prepare(const std::vector<BondInstance<Params>>& bonds, std::int64_t n) {
    if (n == particles_ && bonds.size() == num_bonds_) return;
    particles_ = n;
    num_bonds_ = bonds.size();
    // reach[p]: the highest index a bond from p (its lower end) reaches.
    std::vector<std::int64_t> reach(n);
    for (std::int64_t p = 0; p < n; ++p) reach[p] = p;
    for (const auto& b : bonds) {
      const int lo = std::min(b.i, b.j), hi = std::max(b.i, b.j);
      reach[lo] = std::max<std::int64_t>(reach[lo], hi);
    }
    blocks_.clear();
    const std::vector<std::int64_t> block_of =
        molecule_blocks(reach, kMicroBlockParticles, [&](std::int64_t first, std::int64_t last) {
          blocks_.push_back({first, last, 0, 0});
        });
    // The bonds by block, each block's in the term's order (a stable counting sort).
    std::vector<std::int64_t> start(blocks_.size() + 1, 0);
    for (const auto& b : bonds) ++start[block_of[b.i] + 1];
    for (std::size_t k = 0; k < blocks_.size(); ++k) start[k + 1] += start[k];
    ordered_.resize(bonds.size());
    std::vector<std::int64_t> at(start.begin(), start.end() - 1);
    for (const auto& b : bonds) ordered_[at[block_of[b.i]]++] = b;
    static_assert(std::is_trivially_copyable_v<Params>);
    uniform_ = std::all_of(bonds.begin(), bonds.end(), [&](const BondInstance<Params>& b) {
      return std::memcmp(&b.params, &bonds.front().params, sizeof(Params)) == 0;
    });
    ends_.clear();
    if (uniform_)
      for (const auto& b : ordered_) ends_.insert(ends_.end(), {b.i, b.j});
    // Each block's chain runs (two or more bonds, as BondPartition's segments) and the rest.
    segments_.clear();
    auto links = [&](std::int64_t q) {  // ordered bond q + 1 continues bond q's chain
      const auto &a = ordered_[q], &b = ordered_[q + 1];
      return a.j == a.i + 1 && b.i == a.j && b.j == b.i + 1;
    };
    largest_block_ = 0;
    for (std::size_t k = 0; k < blocks_.size(); ++k) {
      blocks_[k].segment_begin = static_cast<std::int64_t>(segments_.size());
      append_chain_runs(start[k], start[k + 1], links, segments_);
      blocks_[k].segment_end = static_cast<std::int64_t>(segments_.size());
      largest_block_ = std::max(largest_block_, blocks_[k].last - blocks_[k].first);
    }
    threads_ = 0;
  }

  // Thread t's blocks are owned(t) … owned(t + 1) − 1: about the same number of particles each.
  void split(int threads) {
    if (threads == threads_) return;
    threads_ = threads;
    kicks_.assign(static_cast<std::size_t>(threads) * 3 * static_cast<std::size_t>(largest_block_), 0.0);
    owned_.assign(threads + 1, static_cast<std::int64_t>(blocks_.size()));
    owned_[0] = 0;
    std::int64_t b = 0;
    for (int t = 1; t < threads; ++t) {
      const std::int64_t target = particles_ * t / threads;
      while (b < static_cast<std::int64_t>(blocks_.size()) && blocks_[b].last <= target) ++b;
      owned_[t] = b;
    }
  }

  const std::vector<Block>& blocks() const { return blocks_; }
  std::int64_t owned(int t) const { return owned_[t]; }
  // Thread t's scratch of 3 × (the largest block's particles) doubles (after split).
  double* kicks(int t) { return kicks_.data() + static_cast<std::size_t>(t) * 3 * largest_block_; }
  const Segment* segments() const { return segments_.data(); }
  const std::vector<BondInstance<Params>>& ordered() const { return ordered_; }
  bool uniform() const { return uniform_; }
  const int* ends() const { return ends_.data(); }

 private:
  std::int64_t particles_ = -1;
  std::size_t num_bonds_ = 0;
  int threads_ = 0;
  std::vector<Block> blocks_;
  std::vector<Segment> segments_;
  std::vector<BondInstance<Params>> ordered_;
  bool uniform_ = false;
  std::vector<int> ends_;  // i, j of each ordered bond (uniform_)
  std::vector<std::int64_t> owned_;
  std::int64_t largest_block_ = 0;  // particles
  std::vector<double> kicks_;       // per thread: a block's kick factors, one per coordinate
};

// One micro step's kick and drift of `count` coordinates (a block's particles, three each) and
// f = 0: kick_drift's expressions (integrators/primitives.hpp) with its factor c_i = dt_kick m_i⁻¹
// formed beforehand, one copy per coordinate, so that the loop runs over the coordinates without
// the stride of three: v += c f, x += dt v, f = 0. Compiled for AVX2 and the baseline
// (chain_block_forces: element-wise IEEE operations, none contracted, the same bits either way).
template <class Params>
[[gnu::target_clones("avx2", "default")]] void kick_drift_clear(double* __restrict x, double* __restrict v,
                                                                double* __restrict f, const double* __restrict c,
                                                                double dt, std::int64_t count) {
  for (std::int64_t k = 0; k < count; ++k) {
    v[k] += c[k] * f[k];
    x[k] += dt * v[k];
    f[k] = 0.0;
  }
}

// The micro steps of a system of at most kSmallFusedParticles particles take plain passes
// (small_kick_drift_bond_forces): its x, v and f are a few cache lines, and the plan's blocks and
// segments cost more than the bonds themselves (the double pendulum's velocity Verlet step:
// docs/performance.md, "The run loop's cost per step").
inline constexpr std::int64_t kSmallFusedParticles = 16;

// One micro step of a small system: kick_drift and f = 0 for every particle, then each bond in
// order, its force added to both ends (bond_block's operations on few bonds, the energy not
// computed) — the plain path's operations in its order, so its bits. At most kSmallFusedParticles
// particles, so fewer bonds than kParallelMin (one per pair): one thread at any thread count.
// Scalar on purpose: vectorised, its loops of a few particles run through alias checks and
// remainder code longer than themselves (as Gravity::add_forces, forcefields/gravity.cpp).
template <class Kernel, class Params>
#if defined(__GNUC__) && !defined(__clang__)
__attribute__((optimize("no-tree-vectorize", "no-tree-slp-vectorize")))
#endif
void small_kick_drift_bond_forces(const std::vector<BondInstance<Params>>& bonds, Eigen::Matrix3Xd& x,
                                  Eigen::Matrix3Xd& v, const Eigen::VectorXd& inv_mass, Eigen::Matrix3Xd& f,
                                  double dt_kick, double dt) {
  double* __restrict xp = x.data();
  double* __restrict vp = v.data();
  double* __restrict fp = f.data();
  const double* __restrict w_inv = inv_mass.data();
  for (std::int64_t i = 0, n = x.cols(); i < n; ++i) {
    const double s = dt_kick * w_inv[i];
    for (int a = 0; a < 3; ++a) {
      vp[3 * i + a] += s * fp[3 * i + a];
      xp[3 * i + a] += dt * vp[3 * i + a];
      fp[3 * i + a] = 0.0;
    }
  }
  for (const BondInstance<Params>& b : bonds) {
    double d[3] = {xp[3 * b.i] - xp[3 * b.j], xp[3 * b.i + 1] - xp[3 * b.j + 1], xp[3 * b.i + 2] - xp[3 * b.j + 2]};
    double e = 0.0;  // unused: the compiler drops what only the energy needs
    const double scale = bond_force_factor<Kernel>(d[0] * d[0] + d[1] * d[1] + d[2] * d[2], b.params, e);
    check_bond_domain<Kernel>(e);
    for (int a = 0; a < 3; ++a) {
      d[a] *= scale;
      fp[3 * b.i + a] += d[a];
      fp[3 * b.j + a] -= d[a];
    }
  }
}

// `steps` micro steps (MicroStepPlan above): the first kicks by first_kick, the others by dt_kick,
// each drifts by dt and leaves in f the bond forces at the new x. The same bits as `steps` times
// kick_drift, f = 0, accumulate_bond_forces, at any thread count.
template <class Kernel, class Params>
void fused_kick_drift_bond_forces(const std::vector<BondInstance<Params>>& bonds, Eigen::Matrix3Xd& x,
                                  Eigen::Matrix3Xd& v, const Eigen::VectorXd& inv_mass, Eigen::Matrix3Xd& f,
                                  double first_kick, double dt_kick, double dt, int steps,
                                  MicroStepPlan<Params>& plan) {
  const std::int64_t n = x.cols();
  if (n <= kSmallFusedParticles) {
    for (int s = 0; s < steps; ++s)
      small_kick_drift_bond_forces<Kernel>(bonds, x, v, inv_mass, f, s == 0 ? first_kick : dt_kick, dt);
    return;
  }
  plan.prepare(bonds, n);
  const int threads = threads_for(n);
  plan.split(threads);
  double* const xp = x.data();
  double* const vp = v.data();
  double* const fp = f.data();
  const double* const w_inv = inv_mass.data();
  const auto* segments = plan.segments();
  // The micro steps discard the energy: not formed, unless it is the kernel's domain test.
  constexpr bool kEnergy = kSquaredKernel<Kernel>;
  // The first micro step's kick factors differ from the others' unless the kicks are equal, bit for bit.
  const bool same_kicks = std::memcmp(&first_kick, &dt_kick, sizeof(double)) == 0;
  auto run = [&](int t, const auto& view) {
    double e = 0.0;  // not needed by a micro step
    double* const c = plan.kicks(t);
    for (std::int64_t k = plan.owned(t); k < plan.owned(t + 1); ++k) {
      const auto& block = plan.blocks()[k];
      const std::int64_t first = block.first, count = block.last - block.first;
      for (int s = 0; s < steps; ++s) {
        if (s == 0 || (s == 1 && !same_kicks)) {  // c_i = kick m_i⁻¹, kick_drift's factor
          const double kick = s == 0 ? first_kick : dt_kick;
          for (std::int64_t i = 0; i < count; ++i) c[3 * i] = c[3 * i + 1] = c[3 * i + 2] = kick * w_inv[first + i];
        }
        kick_drift_clear<Params>(xp + 3 * first, vp + 3 * first, fp + 3 * first, c, dt, 3 * count);
        for (std::int64_t g = block.segment_begin; g < block.segment_end; ++g) {
          const auto& seg = segments[g];
          for (std::int64_t q = seg.begin; q < seg.end; q += kBondBlock) {
            const int nb = static_cast<int>(std::min<std::int64_t>(kBondBlock, seg.end - q));
            if (seg.chain)
              chain_block<Kernel, kEnergy>(view, q, nb, xp, fp, e);
            else
              bond_block<Kernel>(view, q, nb, xp, fp, e);
          }
        }
      }
    }
  };
  run_parts(threads, [&](int t) {
    if (plan.uniform() && !plan.ordered().empty())
      run(t, UniformBonds<Params>{plan.ends(), &plan.ordered().front().params});
    else
      run(t, AllBonds<Params>{plan.ordered().data()});
  });
}

// Σ_b r_ij · f_ij over the bonds (f_ij = −dE/dr · r_ij/r, so each term is −r dE/dr).
template <class Kernel, class Params>
double accumulate_bond_virial(const std::vector<BondInstance<Params>>& bonds, const Eigen::Matrix3Xd& x,
                              const Box& box) {
  (void)box;
  const std::int64_t n = static_cast<std::int64_t>(bonds.size());
  return parallel_sum(n, threads_for(n), [&](std::int64_t first, std::int64_t last) {  // blocks of bonds
    double w = 0.0;
    for (std::int64_t k = first; k < last; ++k) {
      const auto& b = bonds[k];
      const double r = bond_vector(x, b.i, b.j).norm();
      double e = 0.0, de_dr = 0.0;
      Kernel::eval(r, b.params, e, de_dr);
      w -= r * de_dr;
    }
    return w;
  });
}

}  // namespace stiffmd
