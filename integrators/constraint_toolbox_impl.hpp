// The constraint toolbox's private state (ConstraintToolbox::Impl) and the helpers its sources
// share; included only by them:
//   constraints.cpp             building the toolbox (clusters, solve orders, back ends); accessors
//   constraint_factors.cpp      G(x) measured and K factored; the kept configuration (S(x) once per x);
//                               the band of S⁻¹ for Fixman's potential
//   constraint_projections.cpp  P(x)f and RATTLE's velocity projection
//   shake.cpp                   SHAKE: chord steps on S(x_ref), Newton on J
//   mollifier.cpp               the exact mollified force
//   constraint_blocks.cpp       the molecule blocks: SHAKE and the projections block by block
//   constraint_solvers.*        the per-cluster solvers of K
// and the thread schedule over clusters (for_each_cluster, for_each_group) below.
#pragma once

#include <Eigen/Core>
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <limits>
#include <memory>
#include <stdexcept>
#include <string>
#include <type_traits>
#include <vector>

#include "core/parallel.hpp"
#include "integrators/constraint_solvers.hpp"
#include "integrators/constraints.hpp"

namespace stiffmd {
namespace constraint_detail {

// u_a · v_b for the columns a of u and b of v (3 × n arrays, column-major): the couplings of S and J.
inline double column_dot(const double* u, int a, const double* v, int b) {
  const double* p = u + 3 * a;
  const double* q = v + 3 * b;
  return p[0] * q[0] + p[1] * q[1] + p[2] * q[2];
}

// Open chains of one length whose solves run in lockstep (Impl::for_each_group): enough
// independent recurrences to hide the latency of each chain's multiply–subtract and division.
constexpr int kChainGroup = 4;

// Calls f(std::integral_constant<int, k>()) for a group of 1 ≤ k ≤ kChainGroup chains (the
// lockstep templates take the group size as a template argument); nothing for k = 0.
template <class F>
void for_group_size(int k, F&& f) {
  static_assert(kChainGroup == 4, "one case per group size");
  switch (k) {
    case 0:
      return;
    case 1:
      f(std::integral_constant<int, 1>());
      return;
    case 2:
      f(std::integral_constant<int, 2>());
      return;
    case 3:
      f(std::integral_constant<int, 3>());
      return;
    default:
      f(std::integral_constant<int, 4>());
      return;
  }
}

// Unit vectors and lengths of all bonds at one configuration: the rows of G are ±u_b.
struct BondFrame {
  Eigen::Matrix3Xd u;
  Eigen::VectorXd length;
};

inline void require_columns(const Eigen::Matrix3Xd& a, Eigen::Index n, const char* what) {
  if (a.cols() != n)
    throw std::invalid_argument(std::string(what) + ": expected " + std::to_string(n) + " particles, got " +
                                std::to_string(a.cols()));
}

// Per-cluster data: the solve order of its bonds, the pattern of K, the solver and scratch.
struct ClusterData {
  std::vector<int> bonds;           // position in K → bond index (chain order for chains)
  std::vector<Coupling> couplings;  // the pattern of K, shared by S, J and Jᵀ
  std::unique_ptr<ClusterSolver> solver;
  Eigen::VectorXd values;  // K entries, one per coupling
  // Open chains assemble K's bands directly: K(k,k) = diag_w[k] u_k(a)·u_k(b) and
  // K(k,k+1), K(k+1,k) = off_w[k] u_k(a)·u_{k+1}(b), u_{k+1}(a)·u_k(b) (the couplings summed).
  TridiagonalSolver* chain = nullptr;  // = solver, for chains (J)
  std::unique_ptr<ChainLdlt> spd;      // chains: S
  Eigen::VectorXd diag_w, off_w;
  Eigen::VectorXd rhs, sol;
  double normal_energy = 0.0;       // ½ rhsᵀ sol of the last normal_kinetic_energy
  Eigen::VectorXd lambda;           // SHAKE multipliers, accumulated over Newton steps
  Eigen::VectorXd half_inv_length;  // 1 / (2ℓ_b), local order: SHAKE's chord residual (Impl::chain_gap)
  // Open chains, for SHAKE's chord (Impl::chain_gap, Impl::chain_displace): the particles along
  // the chain, path[k] and path[k + 1] the ends of local bond k (n + 1 of them), their inverse
  // masses, ℓ_k², and σ_k u_k at the kept configuration (σ_k = +1 when bond k's i is path[k],
  // −1 when it is path[k + 1]: σ_k u_k points from path[k + 1] to path[k]).
  std::vector<int> path;
  Eigen::VectorXd path_inv_mass, length2, orientation;
  Eigen::Matrix3Xd e_kept;
  // What is known at the toolbox's kept configuration (Impl::keep): G there (in at_kept) and
  // S's factors (spd for chains, else solver until SHAKE's Newton factors J in it).
  bool frame_kept = false;
  bool s_factored = false;
  std::int64_t factorizations = 0;  // of S and of SHAKE's and the mollifier's J, for tests
  // Open chains, for Fixman's potential: the band of S⁻¹ at the kept configuration (z_diag is the
  // recurrence's own, z_off what chain_inverse_band hands out), formed from
  // the factors of S of factorization number band_at (current while s_factored and no
  // factorization came since: Impl::band_current).
  Eigen::VectorXd z_diag, z_off;
  std::int64_t band_at = -1;
};

// a += sign · M⁻¹Gᵀ coef (kMassWeighted) or sign · Gᵀ coef on an open chain, with G at the kept
// configuration, walking its path so that each particle is read and written once:
// a_p += s_p (σ_k u_k coef_k − σ_{k−1} u_{k−1} coef_{k−1}) for p = path[k] (no term past either
// end), s_p = sign · m_p⁻¹ or sign; then visit(k, a_p) with the particle's new value. If b is
// given, also b_p += b_sign (…) at the mobile particles (m_p⁻¹ > 0) in the same pass.
template <bool kMassWeighted, class Visit>
void walk_chain(const ClusterData& d, double* a, const double* coef, double sign, Visit&& visit, double* b = nullptr,
                double b_sign = 0.0) {
  const int n = static_cast<int>(d.bonds.size());
  const int* path = d.path.data();
  const double* w = d.path_inv_mass.data();
  const double* e = d.e_kept.data();
  double ex = 0.0, ey = 0.0, ez = 0.0;  // σ_{k−1} u_{k−1} coef_{k−1}
  // The path's particles; kBond: bond k's term (k < n). The first and the last particle are taken
  // apart, so that the loop (and a visit that tests k > 0) has no branch on k.
  auto particle = [&](int k, auto bond) {
    double fx = 0.0, fy = 0.0, fz = 0.0;  // σ_k u_k coef_k
    if constexpr (decltype(bond)::value) {
      fx = e[3 * k] * coef[k];
      fy = e[3 * k + 1] * coef[k];
      fz = e[3 * k + 2] * coef[k];
    }
    double* q = a + 3 * path[k];
    const double s = kMassWeighted ? sign * w[k] : sign;
    q[0] += s * (fx - ex);
    q[1] += s * (fy - ey);
    q[2] += s * (fz - ez);
    visit(k, q[0], q[1], q[2]);
    if (b != nullptr && w[k] > 0.0) {  // not at a fixed particle, which clusters may share
      double* r = b + 3 * path[k];
      r[0] += b_sign * (fx - ex);
      r[1] += b_sign * (fy - ey);
      r[2] += b_sign * (fz - ez);
    }
    ex = fx;
    ey = fy;
    ez = fz;
  };
  if (n > 0) particle(0, std::true_type());
  for (int k = 1; k < n; ++k) particle(k, std::true_type());
  particle(n, std::false_type());
}

}  // namespace constraint_detail

struct ConstraintToolbox::Impl {
  using BondFrame = constraint_detail::BondFrame;
  using ClusterData = constraint_detail::ClusterData;

  // Building (constraints.cpp).
  Impl(std::vector<StiffBond> bonds_in, Eigen::VectorXd inv_mass_in);
  void set_path(ClusterData& d) const;  // open chains, at construction

  int num_particles() const { return static_cast<int>(inv_mass.size()); }

  // G and K, the kept configuration (constraint_factors.cpp).
  // minus_g (size of the cluster, local order), if given, receives −g_b(x); returns max_b |g_b(x)| then.
  double measure(int c, const Eigen::Matrix3Xd& x, BondFrame& frame, const char* what, int iteration = -1,
                 double* minus_g = nullptr);
  void factorize(int c, const BondFrame& rows, const BondFrame& cols, bool symmetric, const char* what);
  // Makes x the kept configuration (a copy), forgetting G and S of the last one unless x is it, bit
  // for bit. Serial; before the clusters' loop.
  void keep(const Eigen::Matrix3Xd& x);
  void copy_configuration(const Eigen::Matrix3Xd& x);  // kept_x = x, on the threads
  // G and the factors of S at the kept configuration on cluster c, computed if not known yet.
  void factor_kept_s(int c, const char* what);
  void chain_s_bands(int c, const char* what);
  void chain_s_factored(int c, bool regular, const char* what);
  // Factorizes S at the kept configuration for the chains first … first + count − 1 that are not
  // factored yet, in lockstep (factor_kept_s for each, with one factorization pass).
  void factor_kept_group(int first, int count, const char* what);
  void solve_chains(const int* cs, int k);
  // sol = S⁻¹ rhs at the kept configuration (after factor_kept_s).
  void solve_kept_s(int c);
  [[noreturn]] void singular(int c, bool symmetric, const char* what) const;
  // Factors S (factor_kept_group) and forms the band of S⁻¹ for the open chains first … first +
  // count − 1 (of one length) where it is not current, in lockstep.
  void chain_inverse_band_group(int first, int count);
  bool band_current(const ClusterData& d) const { return d.s_factored && d.band_at == d.factorizations; }

  // Gᵀ and M⁻¹Gᵀ applied, the projections (constraint_projections.cpp).
  Eigen::Vector3d inv_mass_difference(int b, const Eigen::Matrix3Xd& w) const;
  // mobile_only: nothing at fixed particles (a velocity projection's constraint force: their v stays).
  void add_constraint_force(int c, const BondFrame& frame, const Eigen::VectorXd& coef, double sign,
                            Eigen::Matrix3Xd& f, bool mobile_only = false) const;
  void add_constraint_displacement(int c, const BondFrame& frame, const Eigen::VectorXd& coef, double sign,
                                   Eigen::Matrix3Xd& y) const;
  template <bool kForce>
  void chain_project_rhs(int c, const Eigen::Matrix3Xd& a);
  // With force (velocity only): force −= rate · Gᵀμ at the mobile particles as well.
  template <bool kForce>
  void chain_project_update(int c, Eigen::Matrix3Xd& a, Eigen::Matrix3Xd* force = nullptr, double rate = 0.0);
  void project_force_cluster(int c, Eigen::Matrix3Xd& f);
  void solve_velocity_normal(int c, const Eigen::Matrix3Xd& v);
  void project_velocity_cluster(int c, Eigen::Matrix3Xd& v, Eigen::Matrix3Xd* force, double rate);
  template <bool kForce>
  void project_group(int first, int count, Eigen::Matrix3Xd& a, Eigen::Matrix3Xd* force = nullptr, double rate = 0.0);
  // ½ (Gv)ᵀ S⁻¹ (Gv) on each cluster of the group into its normal_energy.
  void normal_energy_group(int first, int count, const Eigen::Matrix3Xd& v);

  // SHAKE (shake.cpp).
  // An open chain's −h_b(y) = (ℓ_b² − |d_b|²) / (2ℓ_b) into minus_h (local order), along its path
  // (contiguous particles on a melt read in order); max |h_b| returned, NaN when a length is not
  // finite. h = 0 is the manifold g = 0 and h_b = g_b (1 + g_b / (2ℓ_b)): SHAKE's chord iterates
  // on it without a square root or a division per bond.
  double chain_gap(int c, const Eigen::Matrix3Xd& y, double* minus_h) const;
  // An open chain's chord update and its new residual in one pass along the path: λ += δ,
  // y += M⁻¹G(x_ref)ᵀδ (each particle once: y_p += m_p⁻¹(σ_k u_k δ_k − σ_{k−1} u_{k−1} δ_{k−1}) for
  // p = path[k]), then −h(y) into minus_h as soon as both ends of a bond have moved; returns max |h|
  // (NaN when a length is not finite).
  double chain_displace(int c, Eigen::Matrix3Xd& y, const double* delta, double* minus_h);
  // chain_displace on two open chains of one length with no particle in common (c[0], c[1]; δ in
  // their sol, −h into their rhs, max |h| into result), the two walks side by side in the two
  // lanes of one SSE2 register: each chain gets chain_displace's operations, so the same bits.
  void chain_displace_pair(const int* c, Eigen::Matrix3Xd& y, double* result);
  // SHAKE on one cluster, as a sequence of iterations (shake_group interleaves several).
  struct ShakeState {
    int c = 0;
    int iteration = 0;
    bool chord = false;  // chord steps on S(x_ref); false: Newton on J
    double previous = std::numeric_limits<double>::infinity();
    double chord_residual = 0.0;  // max |h| of the last chord update, with −h in rhs
    bool have_chord_residual = false;
    // LAMMPS's fix shake tolerance (ConstraintToolbox::shake; 0: off) and whether the last update's
    // multipliers changed by no more than it (the iterate is then accepted, once G there is measured).
    double multiplier_tol = 0.0;
    bool accepted = false;
  };
  enum class ShakeNext { converged, chord_solve, newton_done };
  void shake_start(ShakeState& st, int c, double multiplier_tol);
  // Whether an update δ (sol, local order) meets LAMMPS's tolerance: max_b |δ_b| / |d_b(x_ref)| ≤ tol.
  bool within_multiplier_tol(const ClusterData& d, double tol) const;
  // One iteration up to the chord's solve: converged; chord_solve (−h or −g in rhs: solve S(x_ref)
  // into sol, then shake_chord_update); or a Newton step done. Throws NumericalError.
  ShakeNext shake_iterate(ShakeState& st, Eigen::Matrix3Xd& y, double tol, int max_iter);
  void shake_chord_update(ShakeState& st, Eigen::Matrix3Xd& y);
  // shake_chord_update on two chains of a group at once (chain_displace_pair).
  void shake_chord_update_pair(ShakeState& a, ShakeState& b, Eigen::Matrix3Xd& y);
  void shake_cluster(int c, Eigen::Matrix3Xd& y, double tol, int max_iter, double multiplier_tol = 0.0);
  // SHAKE on a group of clusters (shake_group: their chord solves in lockstep).
  void shake_group(int first, int count, Eigen::Matrix3Xd& y, double tol, int max_iter, double multiplier_tol);

  // The mollified force (mollifier.cpp).
  void mollify_cluster(int c, Eigen::Matrix3Xd& f);

  // The thread schedule over clusters.
  // Runs f(c) for every cluster c. Clusters are independent solves touching their own bonds'
  // scratch and their own particles, so they run on the OpenMP threads in contiguous blocks of
  // about equal bond count (parallel.hpp) — unless a fixed particle is shared by two clusters:
  // both add its reaction force, and that sum must stay in cluster order. A NumericalError is
  // rethrown for the first failing cluster in cluster order, as in a serial loop.
  template <class F>
  void for_each_cluster(F&& f) {
    const int nc = static_cast<int>(data.size());
    const int parts = clusters_share_particles ? 1 : std::min(threads_for(static_cast<std::int64_t>(bonds.size())), nc);
    if (parts <= 1) {
      run_as_one_part(serial_everywhere() ? 0 : static_cast<std::int64_t>(bonds.size()), [&] {
        for (int c = 0; c < nc; ++c) f(c);
      });
      return;
    }
    run_parts(parts, [&](int u) {
      const int end = u + 1 == parts ? nc : first_cluster_of_block(parts, u + 1);
      for (int c = first_cluster_of_block(parts, u); c < end; ++c) f(c);
    });
  }
  // The first cluster of block v of `parts` (blocks of about equal bond count).
  int first_cluster_of_block(int parts, int v) const {
    return static_cast<int>(
        std::lower_bound(bonds_before.begin(), bonds_before.end() - 1, block_begin(bonds_before.back(), parts, v)) -
        bonds_before.begin());
  }

  // Runs f(first, count) over the clusters in groups: up to kChainGroup consecutive open chains of
  // one length (their solves run in lockstep: ChainLdlt::solve_group), any other cluster alone; on
  // the threads in the blocks of for_each_cluster, groups never crossing a block. Each cluster gets
  // the operations it would get alone, so the result does not depend on the grouping (nor on the
  // thread count); a NumericalError is rethrown for the first failing cluster in cluster order.
  template <class F>
  void for_each_group(F&& f) {
    const int nc = static_cast<int>(data.size());
    auto run_block = [&](int begin, int end) { run_groups(begin, end, f); };
    const int parts = clusters_share_particles ? 1 : std::min(threads_for(static_cast<std::int64_t>(bonds.size())), nc);
    if (parts <= 1) {
      run_as_one_part(serial_everywhere() ? 0 : static_cast<std::int64_t>(bonds.size()), [&] { run_block(0, nc); });
      return;
    }
    run_parts(parts, [&](int u) {
      run_block(first_cluster_of_block(parts, u), u + 1 == parts ? nc : first_cluster_of_block(parts, u + 1));
    });
  }

  // The groups of clusters begin … end − 1 (for_each_group's, within one block of threads or of
  // molecules), in order.
  template <class F>
  void run_groups(int begin, int end, F&& f) {
    for (int c = begin; c < end;) {
      int count = 1;
      if (data[c].spd)
        while (count < constraint_detail::kChainGroup && c + count < end && data[c + count].spd &&
               data[c + count].bonds.size() == data[c].bonds.size())
          ++count;
      f(c, count);
      c += count;
    }
  }

  // Molecule blocks (ConstraintToolbox::blocks_available; constraint_blocks.cpp).
  struct Block {
    std::int64_t first, last;        // particles
    int cluster_begin, cluster_end;  // clusters
  };
  void plan_blocks();
  // Block b's particles of x against the kept configuration, bit for bit; on a difference the
  // block's particles are copied and its clusters forget G and S there.
  void keep_block(const Block& b, const Eigen::Matrix3Xd& x);
  // At least 400 particles (≈ 48 kB of the step's data: L2): on a melt of 100-bead chains a
  // block holds four, one lockstep group whose chord updates all go in pairs (chain_displace_pair);
  // blocks of three chains (256 particles) left one chain of each to the scalar walk.
  std::int64_t min_block_particles = 400;
  bool blocks_ok = false;
  std::vector<Block> blocks;
  int blocks_split_parts = 0;     // owned_blocks is for this many parts
  std::vector<int> owned_blocks;  // part u's blocks: owned_blocks[u] … owned_blocks[u + 1] − 1

  std::vector<StiffBond> bonds;
  Eigen::VectorXd inv_mass;
  std::vector<ConstraintCluster> clusters;
  std::vector<ClusterData> data;           // parallel to clusters
  std::vector<std::int64_t> bonds_before;  // bonds in clusters 0 … c − 1; size clusters + 1
  bool clusters_share_particles = false;   // through a fixed particle
  // One block at any thread count: run_as_one_part must not count it as parallel work.
  bool serial_everywhere() const { return clusters_share_particles || data.size() <= 1; }
  Eigen::Matrix3Xd kept_x;  // the kept configuration (x_ref of SHAKE, x of P(x))
  bool kept = false;
  BondFrame at_kept;           // G at kept_x, for the clusters with frame_kept
  BondFrame at_cur;            // G at y (or X = α(x))
  Eigen::Matrix3Xd curvature;  // per bond: λ_b A_b ((M⁻¹r)_i − (M⁻¹r)_j), mollified force step 4
};

}  // namespace stiffmd
