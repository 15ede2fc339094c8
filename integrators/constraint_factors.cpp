// The constraint toolbox's G(x) and factors of K (integrators/constraints.hpp): measuring the bond
// directions, assembling and factorizing K(a, b) = G(a) M⁻¹ G(b)ᵀ on a cluster, and the kept
// configuration: the last x the toolbox was handed (compared bit for bit) with G there and S's
// factors, so that S(x) is measured and factored once per configuration. Also the band of S⁻¹
// that Fixman's potential reads (integrators/fixman.cpp).
#include "integrators/constraint_toolbox_impl.hpp"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstring>
#include <exception>
#include <limits>
#include <string>

#include "core/errors.hpp"
#include "core/parallel.hpp"
#include "core/timing.hpp"

namespace stiffmd {
using namespace constraint_detail;  // the toolbox's private types (constraint_toolbox_impl.hpp)

// Unit vectors u_b and lengths of cluster c's bonds at x. G(x) does not exist where a bond
// has zero length, so that is an error, as is any non-finite coordinate.
double ConstraintToolbox::Impl::measure(int c, const Eigen::Matrix3Xd& x, BondFrame& frame, const char* what,
                                        int iteration, double* minus_g) {
  // One pass without branches (u = d / |d| for every bond; SHAKE's residual in the same pass),
  // then the check: called several times per macro step by SHAKE and the mollifier, so it is
  // kept tight.
  double* u = frame.u.data();
  double* len = frame.length.data();
  const StiffBond* bond = bonds.data();
  const std::vector<int>& order = data[c].bonds;
  const int n = static_cast<int>(order.size());
  bool ok = true;
  double worst = 0.0;
  for (int k = 0; k < n; ++k) {
    const int b = order[k];
    const Eigen::Vector3d d = bond_vector(x, bond[b].i, bond[b].j);
    const double dx = d[0], dy = d[1], dz = d[2];
    const double length = std::sqrt(dx * dx + dy * dy + dz * dz);
    const double inv = 1.0 / length;
    u[3 * b] = dx * inv;
    u[3 * b + 1] = dy * inv;
    u[3 * b + 2] = dz * inv;
    len[b] = length;
    ok &= length > 0.0 && length <= std::numeric_limits<double>::max();  // false for 0, ∞, NaN
    if (minus_g != nullptr) {                                            // loop-invariant: the compiler splits the loop
      minus_g[k] = bond[b].length - length;
      worst = std::max(worst, std::abs(minus_g[k]));
    }
  }
  if (ok) return worst;
  for (const int b : data[c].bonds) {
    const double length = len[b];
    if (length > 0.0 && std::isfinite(length)) continue;
    std::string where = std::string(what) + " failed in cluster " + std::to_string(c);
    if (iteration >= 0) where += " at iteration " + std::to_string(iteration);
    throw NumericalError(where + ": " + describe_bond(b, bonds[b]) +
                         (length == 0.0 ? " has zero length" : " has a non-finite length"));
  }
  return worst;
}

// Factorizes K = G(rows) M⁻¹ G(cols)ᵀ on cluster c (see Coupling).
void ConstraintToolbox::Impl::factorize(int c, const BondFrame& rows, const BondFrame& cols, bool symmetric,
                                        const char* what) {
  ClusterData& d = data[c];
  const double* ur = rows.u.data();
  const double* uc = cols.u.data();
  auto dot = [&](int a, int b) { return column_dot(ur, a, uc, b); };
  if (d.chain) {
    const int n = static_cast<int>(d.bonds.size());
    const int* bond = d.bonds.data();
    double* sub = d.chain->sub();
    double* diagonal = d.chain->diagonal();
    double* super = d.chain->super();
    for (int k = 0; k < n; ++k) diagonal[k] = d.diag_w[k] * dot(bond[k], bond[k]);
    for (int k = 0; k + 1 < n; ++k) {
      super[k] = d.off_w[k] * dot(bond[k], bond[k + 1]);
      sub[k] = d.off_w[k] * dot(bond[k + 1], bond[k]);
    }
    if (!d.chain->factorize_bands()) singular(c, symmetric, what);
    return;
  }
  const double* w = inv_mass.data();
  double* values = d.values.data();
  const Coupling* cp = d.couplings.data();
  for (std::size_t k = 0, n = d.couplings.size(); k < n; ++k) {
    values[k] = cp[k].sign * w[cp[k].particle] * column_dot(ur, cp[k].row_bond, uc, cp[k].col_bond);
  }
  if (!d.solver->factorize(d.values, symmetric)) singular(c, symmetric, what);
}

void ConstraintToolbox::Impl::keep(const Eigen::Matrix3Xd& x) {
  if (kept && kept_x.cols() == x.cols()) {
    // Bit for bit, in the particle blocks of the threads (a hit reads all of x).
    const int parts = threads_for(x.cols());
    std::array<char, kMaxParts> same{};
    run_parts(parts, [&](int u) {
      const std::int64_t b = block_begin(x.cols(), parts, u), e = block_begin(x.cols(), parts, u + 1);
      same[u] = std::memcmp(kept_x.data() + 3 * b, x.data() + 3 * b, sizeof(double) * 3 * (e - b)) == 0;
    });
    if (std::all_of(same.begin(), same.begin() + parts, [](char s) { return s != 0; })) return;
  }
  copy_configuration(x);
  for (ClusterData& d : data) d.frame_kept = d.s_factored = false;
}

void ConstraintToolbox::Impl::copy_configuration(const Eigen::Matrix3Xd& x) {
  if (kept_x.cols() != x.cols()) kept_x.resize(3, x.cols());  // once
  parallel_blocks(x.cols(), threads_for(x.cols()),
                  [&](std::int64_t b, std::int64_t e) { kept_x.middleCols(b, e - b) = x.middleCols(b, e - b); });
  kept = true;
}

// An open chain's bands of S at the kept configuration (measured first if need be), and σ_k u_k
// along the path (SHAKE's chord, the projections: used once S is factored) in the same pass: one
// walk over the chain's directions instead of two.
void ConstraintToolbox::Impl::chain_s_bands(int c, const char* what) {
  ClusterData& d = data[c];
  if (!d.frame_kept) {
    measure(c, kept_x, at_kept, what);
    d.frame_kept = true;
  }
  const double* u = at_kept.u.data();
  const int n = static_cast<int>(d.bonds.size());
  const int* bond = d.bonds.data();
  double* diagonal = d.spd->diagonal();
  double* off = d.spd->off();
  double* e = d.e_kept.data();
  const double* sigma = d.orientation.data();
  for (int k = 0; k < n; ++k) {
    const double* uk = u + 3 * bond[k];
    diagonal[k] = d.diag_w[k] * column_dot(u, bond[k], u, bond[k]);
    if (k + 1 < n) off[k] = d.off_w[k] * column_dot(u, bond[k], u, bond[k + 1]);
    e[3 * k] = sigma[k] * uk[0];
    e[3 * k + 1] = sigma[k] * uk[1];
    e[3 * k + 2] = sigma[k] * uk[2];
  }
}

// After an open chain's factorization (chain_s_bands wrote σ_k u_k).
void ConstraintToolbox::Impl::chain_s_factored(int c, bool regular, const char* what) {
  ClusterData& d = data[c];
  if (!regular) singular(c, true, what);
  d.s_factored = true;
  ++d.factorizations;
}

void ConstraintToolbox::Impl::factor_kept_s(int c, const char* what) {
  ClusterData& d = data[c];
  if (!d.frame_kept) {
    measure(c, kept_x, at_kept, what);
    d.frame_kept = true;
  }
  if (d.s_factored) return;
  if (d.spd) {
    chain_s_bands(c, what);
    chain_s_factored(c, d.spd->factorize(), what);
    return;
  }
  factorize(c, at_kept, at_kept, true, what);
  d.s_factored = true;
  ++d.factorizations;
}

void ConstraintToolbox::Impl::factor_kept_group(int first, int count, const char* what) {
  int todo[kChainGroup];
  int k = 0;
  // A bond of zero or non-finite length is reported as alone: after the clusters before it are
  // factored (one of them may be singular: that is then the error).
  std::exception_ptr failed;
  for (int c = first; c < first + count && !failed; ++c) {
    if (data[c].s_factored) continue;
    try {
      chain_s_bands(c, what);
      todo[k++] = c;
    } catch (const NumericalError&) {
      failed = std::current_exception();
    }
  }
  ChainLdlt* chain[kChainGroup];
  bool regular[kChainGroup];
  for (int j = 0; j < k; ++j) chain[j] = data[todo[j]].spd.get();
  for_group_size(k, [&](auto size) { ChainLdlt::factorize_group<decltype(size)::value>(chain, regular); });
  for (int j = 0; j < k; ++j) chain_s_factored(todo[j], regular[j], what);  // the first singular one throws
  if (failed) std::rethrow_exception(failed);
}

// sol = S⁻¹ rhs for the given open chains (of one length) in lockstep.
void ConstraintToolbox::Impl::solve_chains(const int* cs, int k) {
  const ChainLdlt* chain[kChainGroup];
  const double* rhs[kChainGroup];
  double* sol[kChainGroup];
  for (int j = 0; j < k; ++j) {
    chain[j] = data[cs[j]].spd.get();
    rhs[j] = data[cs[j]].rhs.data();
    sol[j] = data[cs[j]].sol.data();
  }
  for_group_size(k, [&](auto size) { ChainLdlt::solve_group<decltype(size)::value>(chain, rhs, sol); });
}

void ConstraintToolbox::Impl::solve_kept_s(int c) {
  ClusterData& d = data[c];
  if (d.spd)
    d.spd->solve(d.rhs.data(), d.sol.data());
  else
    d.solver->solve(d.rhs, d.sol);
}

void ConstraintToolbox::Impl::singular(int c, bool symmetric, const char* what) const {
  throw NumericalError(std::string(what) + " failed in cluster " + std::to_string(c) +
                       (symmetric ? ": S = G M⁻¹ Gᵀ is singular (the bond directions are linearly dependent)"
                                  : ": the Newton matrix G(y) M⁻¹ G(x_ref)ᵀ is singular (too far from the reference)"));
}

void ConstraintToolbox::keep(const Eigen::Matrix3Xd& x) {
  require_columns(x, impl_->num_particles(), "keep");
  impl_->keep(x);
}

void ConstraintToolbox::Impl::chain_inverse_band_group(int first, int count) {
  factor_kept_group(first, count, "Fixman potential");
  const ChainLdlt* chain[kChainGroup];
  double* z_diag[kChainGroup];
  double* z_off[kChainGroup];
  int k = 0;
  for (int c = first; c < first + count; ++c) {
    ClusterData& d = data[c];
    if (band_current(d)) continue;
    chain[k] = d.spd.get();
    z_diag[k] = d.z_diag.data();
    z_off[k++] = d.z_off.data();
    d.band_at = d.factorizations;
  }
  for_group_size(k, [&](auto size) { ChainLdlt::inverse_band_group<decltype(size)::value>(chain, z_diag, z_off); });
}

void ConstraintToolbox::inverse_bands(const Eigen::Matrix3Xd& x) {
  const ScopedPhase phase(Phase::constraints);
  require_columns(x, impl_->num_particles(), "inverse_bands");
  Impl& d = *impl_;
  d.keep(x);
  d.for_each_group([&](int c, int count) {
    if (d.data[c].spd) d.chain_inverse_band_group(c, count);
  });
}

ConstraintToolbox::ChainInverseBand ConstraintToolbox::chain_inverse_band(int c) {
  ClusterData& d = impl_->data.at(static_cast<std::size_t>(c));
  if (!d.spd) return {};
  impl_->chain_inverse_band_group(c, 1);
  return {d.z_off.data(), d.spd->inverse_pivots(), static_cast<int>(d.bonds.size())};
}

const Eigen::Matrix3Xd& ConstraintToolbox::kept_directions() const {
  return impl_->at_kept.u;
}
const Eigen::VectorXd& ConstraintToolbox::kept_lengths() const {
  return impl_->at_kept.length;
}

}  // namespace stiffmd
