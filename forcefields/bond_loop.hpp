// The loop over two-body bonds, written once and shared by every bond style (style.md §1,
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
#include <vector>

#include "engine/core/box.hpp"
#include "engine/core/parallel.hpp"
#include "engine/core/state.hpp"
#include "forcefields/neighbor_list.hpp"

namespace stiffmd {

template <class Params>
struct BondInstance {
  int i;
  int j;
  Params params;
};

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
    if (threads == 1) {  // every bond, both ends, in order
      for (std::size_t k = 0; k < bonds.size(); ++k) work_.push_back({static_cast<int>(k), true, true});
      start_[1] = static_cast<std::int64_t>(work_.size());
      return;
    }
    int n = 0;
    for (const auto& b : bonds) n = std::max({n, b.i + 1, b.j + 1});
    std::vector<std::int64_t> ends(n + 1, 0);  // ends[p + 1]: bond ends at particles ≤ p
    for (const auto& b : bonds) {
      ++ends[b.i + 1];
      ++ends[b.j + 1];
    }
    for (int p = 0; p < n; ++p) ends[p + 1] += ends[p];
    std::vector<int> first(threads + 1, n);  // owner t: particles first[t] … first[t+1] − 1
    for (int t = 0; t < threads; ++t)
      first[t] = static_cast<int>(std::lower_bound(ends.begin(), ends.end(), ends[n] * t / threads) - ends.begin());
    first[0] = 0;
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
  }

  int threads() const { return threads_; }
  const Work* begin(int t) const { return work_.data() + start_[t]; }
  const Work* end(int t) const { return work_.data() + start_[t + 1]; }
  double* energy_slots() { return energy_.data(); }  // one per owner

 private:
  int threads_ = 0;
  std::size_t num_bonds_ = 0;
  std::vector<std::int64_t> start_;
  std::vector<Work> work_;
  std::vector<double> energy_ = std::vector<double>(kMaxParts, 0.0);
};

// Adds −∇E into f for every bond and returns Σ E. The bond vector is x_i − x_j of the unwrapped
// positions (bond_vector, engine/core/state.hpp): molecules are whole, so it is the minimum image
// without computing one, and `box` is not needed. `partition` is the per-term thread plan
// (rebuilt when the thread count changes).
//
// Each owner works in blocks of kBlock bonds: gather the separations, compute every force of
// the block in a loop without branches or memory dependences (which the compiler vectorises:
// two square roots and divisions per instruction), then add the forces into f. Adding each
// force as soon as it is known was measured at the latency of sqrt + div per bond: in a chain,
// bond k + 1 adds into the particle bond k has just written.
template <class Kernel, class Params>
double accumulate_bond_forces(const std::vector<BondInstance<Params>>& bonds, const Eigen::Matrix3Xd& x, const Box& box,
                              Eigen::Matrix3Xd& f, BondPartition& partition) {
  (void)box;
  constexpr int kBlock = 64;
  double* fp = f.data();
  const int threads = threads_for(static_cast<std::int64_t>(bonds.size()));
  partition.prepare(bonds, threads);
  double* energy = partition.energy_slots();
  auto run_owner = [&](int t) {
    double e_t = 0.0;
    alignas(64) double d[3][kBlock], counted[kBlock];
    Params p[kBlock];
    for (const BondPartition::Work* w = partition.begin(t); w < partition.end(t); w += kBlock) {
      const int nb = static_cast<int>(std::min<std::ptrdiff_t>(kBlock, partition.end(t) - w));
      for (int k = 0; k < nb; ++k) {
        const auto& b = bonds[w[k].bond];
        const Eigen::Vector3d r_ij = bond_vector(x, b.i, b.j);
        for (int a = 0; a < 3; ++a) d[a][k] = r_ij[a];
        p[k] = b.params;
        counted[k] = w[k].add_i ? 1.0 : 0.0;  // the energy is counted once, by the owner of i
      }
      for (int k = 0; k < nb; ++k) {
        const double r = std::sqrt(d[0][k] * d[0][k] + d[1][k] * d[1][k] + d[2][k] * d[2][k]);
        double e = 0.0, de_dr = 0.0;
        Kernel::eval(r, p[k], e, de_dr);
        e_t += counted[k] * e;
        const double scale = -de_dr / r;  // −∂E/∂x_i = scale · d; x_j gets its negative
        for (int a = 0; a < 3; ++a) d[a][k] *= scale;
      }
      for (int k = 0; k < nb; ++k) {
        const auto& b = bonds[w[k].bond];
        if (w[k].add_i)
          for (int a = 0; a < 3; ++a) fp[3 * b.i + a] += d[a][k];
        if (w[k].add_j)
          for (int a = 0; a < 3; ++a) fp[3 * b.j + a] -= d[a][k];
      }
    }
    energy[t] = e_t;
  };
  run_parts(threads, run_owner);
  double sum = 0.0;
  for (int t = 0; t < threads; ++t) sum += energy[t];
  return sum;
}

// Σ_b r_ij · f_ij over the bonds (f_ij = −dE/dr · r_ij/r, so each term is −r dE/dr).
template <class Kernel, class Params>
double accumulate_bond_virial(const std::vector<BondInstance<Params>>& bonds, const Eigen::Matrix3Xd& x,
                              const Box& box) {
  (void)box;
  double w = 0.0;
  for (const auto& b : bonds) {
    const double r = bond_vector(x, b.i, b.j).norm();
    double e = 0.0, de_dr = 0.0;
    Kernel::eval(r, b.params, e, de_dr);
    w -= r * de_dr;
  }
  return w;
}

}  // namespace stiffmd
