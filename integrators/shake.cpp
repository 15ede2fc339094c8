// SHAKE in the constraint toolbox (integrators/constraints.hpp): the position projection
// y ← y + M⁻¹ G(x_ref)ᵀ λ with g(y) = 0, by chord steps on S(x_ref) for open chains near x_ref and
// Newton on J = G(y) M⁻¹ G(x_ref)ᵀ otherwise.
#include "integrators/constraint_toolbox_impl.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <exception>
#include <limits>
#include <string>
#include <type_traits>
#include <utility>

#include "core/errors.hpp"
#include "core/timing.hpp"

#if defined(__SSE2__)
#include <emmintrin.h>
#endif

namespace stiffmd {
using namespace constraint_detail;  // the toolbox's private types (constraint_toolbox_impl.hpp)
namespace {

// SHAKE starts with chord iterations on S(x_ref) when every |h_b(y)| ≤ this × ℓ_b (h ≈ g near the
// manifold, Impl::chain_gap; a drift of one step: |g| ~ (h|v_rel|)²/(2ℓ), 1e-4 ℓ typical on the
// stiff melt), and switches to Newton on J = G(y) M⁻¹ G(x_ref)ᵀ as soon as an iteration reduces
// the largest residual by less than kChordContraction. The chord's rate is about |G(y) − G(x_ref)|
// (the bonds' rotation since x_ref): ≈ 0.01 for a melt's step. The start bound admits a full drift
// of h = 0.02 (fixman's OBABO step) on LAMMPS's data.chain, whose fastest pairs reach
// |g| ≈ (0.02 · 8)²/2 ≈ 0.013 ℓ: the chords still contract there, and Newton from the start would
// cost a measure, a factorization of J and a solve per iteration where a chord step is one solve
// with S's kept factors. Where the chord does contract slowly, the contraction test switches.
constexpr double kChordStart = 5e-2;
constexpr double kChordContraction = 0.25;

std::string format_g(double value) {
  char buffer[32];
  std::snprintf(buffer, sizeof buffer, "%.1e", value);
  return buffer;
}

// −h_k = (ℓ_k² − |d_k|²) / (2ℓ_k) of an open chain's bonds, fed the particles along its path in
// order (particle path[k] closes bond k − 1): SHAKE's chord residual (Impl::chain_gap,
// Impl::chain_displace). result(): max |h|, NaN when a length is not finite.
struct PathGap {
  const double* length2;
  const double* half_inv_length;
  double* minus_h;
  double px = 0.0, py = 0.0, pz = 0.0;  // the previous particle
  double worst = 0.0;
  bool finite = true;

  PathGap(const ClusterData& d, double* out)
      : length2(d.length2.data()), half_inv_length(d.half_inv_length.data()), minus_h(out) {}
  void operator()(int k, double x, double y, double z) {
    if (k > 0) {
      const double dx = px - x, dy = py - y, dz = pz - z;
      const double r2 = dx * dx + dy * dy + dz * dz;
      minus_h[k - 1] = (length2[k - 1] - r2) * half_inv_length[k - 1];
      worst = std::max(worst, std::abs(minus_h[k - 1]));
      finite &= r2 <= std::numeric_limits<double>::max();  // false for ∞ and NaN
    }
    px = x;
    py = y;
    pz = z;
  }
  double result() const { return finite ? worst : std::numeric_limits<double>::quiet_NaN(); }
};

}  // namespace

double ConstraintToolbox::Impl::chain_gap(int c, const Eigen::Matrix3Xd& y, double* minus_h) const {
  const ClusterData& d = data[c];
  const int* path = d.path.data();
  const double* yp = y.data();
  PathGap gap(d, minus_h);
  for (int k = 0, n = static_cast<int>(d.bonds.size()); k <= n; ++k) {
    const double* q = yp + 3 * path[k];
    gap(k, q[0], q[1], q[2]);
  }
  return gap.result();
}

double ConstraintToolbox::Impl::chain_displace(int c, Eigen::Matrix3Xd& y, const double* delta, double* minus_h) {
  ClusterData& d = data[c];
  d.lambda += Eigen::Map<const Eigen::VectorXd>(delta, d.lambda.size());
  PathGap gap(d, minus_h);
  walk_chain<true>(d, y.data(), delta, 1.0, gap);
  return gap.result();
}

#if defined(__SSE2__)
// Two chains' chord updates in the lanes of SSE2 registers (lane j: chain c[j]): chain_displace's
// walk_chain<true> with sign 1 and its PathGap, operation for operation — the kept σ_k u_k times
// δ_k, y_p += m_p⁻¹ (σ_k u_k δ_k − σ_{k−1} u_{k−1} δ_{k−1}) (0 past either end, as walk_chain's
// zeros), then −h_{k−1} = (ℓ² − |d|²) / (2ℓ) of the bond just closed, its running max |h| and the
// finiteness of |d|² — each an IEEE operation on one lane, so each chain's bits are its own walk's.
// A chain is one dependent sweep along its path; two side by side take one instruction for two
// chains' arithmetic, the loads and stores of the scattered particles staying one per lane.
void ConstraintToolbox::Impl::chain_displace_pair(const int* c, Eigen::Matrix3Xd& y, double* result) {
  ClusterData& d0 = data[c[0]];
  ClusterData& d1 = data[c[1]];
  const int n = static_cast<int>(d0.bonds.size());
  if (n == 0) {  // no bond (not a chain the toolbox makes): chain_displace's walk
    for (int j = 0; j < 2; ++j) result[j] = chain_displace(c[j], y, data[c[j]].sol.data(), data[c[j]].rhs.data());
    return;
  }
  d0.lambda += d0.sol;
  d1.lambda += d1.sol;
  const int *path0 = d0.path.data(), *path1 = d1.path.data();
  const double *w0 = d0.path_inv_mass.data(), *w1 = d1.path_inv_mass.data();
  const double *e0 = d0.e_kept.data(), *e1 = d1.e_kept.data();
  const double *delta0 = d0.sol.data(), *delta1 = d1.sol.data();
  const double *length2_0 = d0.length2.data(), *length2_1 = d1.length2.data();
  const double *half0 = d0.half_inv_length.data(), *half1 = d1.half_inv_length.data();
  double *out0 = d0.rhs.data(), *out1 = d1.rhs.data();
  double* yp = y.data();
  auto pair = [](double a, double b) { return _mm_set_pd(b, a); };  // lane 0: a, lane 1: b
  const __m128d zero = _mm_setzero_pd();
  const __m128d magnitude = _mm_castsi128_pd(_mm_set1_epi64x(0x7fffffffffffffffLL));
  const __m128d largest = _mm_set1_pd(std::numeric_limits<double>::max());
  __m128d ex = zero, ey = zero, ez = zero;  // σ_{k−1} u_{k−1} δ_{k−1}
  __m128d px = zero, py = zero, pz = zero;  // the previous particle
  __m128d worst = zero;
  __m128d finite = _mm_cmpeq_pd(zero, zero);  // all bits set
  // Particle path[k]: kBond, bond k's term (k < n); kGap, bond k − 1's residual (k > 0).
  auto visit = [&](int k, auto bond, auto gap) {
    __m128d fx = zero, fy = zero, fz = zero;  // σ_k u_k δ_k
    if constexpr (decltype(bond)::value) {
      const __m128d coef = pair(delta0[k], delta1[k]);
      fx = _mm_mul_pd(pair(e0[3 * k], e1[3 * k]), coef);
      fy = _mm_mul_pd(pair(e0[3 * k + 1], e1[3 * k + 1]), coef);
      fz = _mm_mul_pd(pair(e0[3 * k + 2], e1[3 * k + 2]), coef);
    }
    double* q0 = yp + 3 * path0[k];
    double* q1 = yp + 3 * path1[k];
    const __m128d s = pair(w0[k], w1[k]);
    const __m128d x = _mm_add_pd(pair(q0[0], q1[0]), _mm_mul_pd(s, _mm_sub_pd(fx, ex)));
    const __m128d yy = _mm_add_pd(pair(q0[1], q1[1]), _mm_mul_pd(s, _mm_sub_pd(fy, ey)));
    const __m128d z = _mm_add_pd(pair(q0[2], q1[2]), _mm_mul_pd(s, _mm_sub_pd(fz, ez)));
    _mm_storel_pd(q0, x);
    _mm_storeh_pd(q1, x);
    _mm_storel_pd(q0 + 1, yy);
    _mm_storeh_pd(q1 + 1, yy);
    _mm_storel_pd(q0 + 2, z);
    _mm_storeh_pd(q1 + 2, z);
    if constexpr (decltype(gap)::value) {
      const __m128d dx = _mm_sub_pd(px, x), dy = _mm_sub_pd(py, yy), dz = _mm_sub_pd(pz, z);
      const __m128d r2 = _mm_add_pd(_mm_add_pd(_mm_mul_pd(dx, dx), _mm_mul_pd(dy, dy)), _mm_mul_pd(dz, dz));
      const __m128d minus_h =
          _mm_mul_pd(_mm_sub_pd(pair(length2_0[k - 1], length2_1[k - 1]), r2), pair(half0[k - 1], half1[k - 1]));
      _mm_storel_pd(out0 + k - 1, minus_h);
      _mm_storeh_pd(out1 + k - 1, minus_h);
      // std::max(worst, |−h|): |−h| where worst < |−h|, else worst (a NaN never taken).
      worst = _mm_max_pd(_mm_and_pd(minus_h, magnitude), worst);
      finite = _mm_and_pd(finite, _mm_cmple_pd(r2, largest));  // false for ∞ and NaN
    }
    px = x;
    py = yy;
    pz = z;
    ex = fx;
    ey = fy;
    ez = fz;
  };
  using yes = std::true_type;
  using no = std::false_type;
  visit(0, yes(), no());
  for (int k = 1; k < n; ++k) visit(k, yes(), yes());
  visit(n, no(), yes());
  double w[2];
  _mm_storeu_pd(w, worst);
  const int ok = _mm_movemask_pd(finite);
  result[0] = (ok & 1) != 0 ? w[0] : std::numeric_limits<double>::quiet_NaN();
  result[1] = (ok & 2) != 0 ? w[1] : std::numeric_limits<double>::quiet_NaN();
}
#else
void ConstraintToolbox::Impl::chain_displace_pair(const int* c, Eigen::Matrix3Xd& y, double* result) {
  for (int j = 0; j < 2; ++j) result[j] = chain_displace(c[j], y, data[c[j]].sol.data(), data[c[j]].rhs.data());
}
#endif

// y = y0 + M⁻¹G(x_ref)ᵀλ with g(y) = 0 (paper eq. (ProMol) when y0 = x_ref), x_ref the kept
// configuration: g(y + M⁻¹G(x_ref)ᵀδ) ≈ g(y) + J δ with J = G(y) M⁻¹ G(x_ref)ᵀ. Open chains near
// x_ref take chord steps S(x_ref) δ = −g(y) (SHAKE's quasi-Newton: S is J at y = x_ref, and its
// factors are usually kept from the velocity projection that ended the last step); otherwise, or
// as soon as the chord contracts slowly, full Newton on J (quadratic convergence, and λ accurate
// enough for the mollified force's H_λ).
void ConstraintToolbox::Impl::shake_start(ShakeState& st, int c, double multiplier_tol) {
  ClusterData& d = data[c];
  if (!d.frame_kept) {
    measure(c, kept_x, at_kept, "SHAKE (reference configuration)");
    d.frame_kept = true;
  }
  st = ShakeState{};
  st.c = c;
  st.chord = d.spd != nullptr;
  st.multiplier_tol = multiplier_tol;
  d.lambda.setZero();
}

// LAMMPS's fix shake moves particle i by m_i⁻¹ λ_L r_b with r_b = x_i − x_j at the reference
// configuration (not a unit vector) and stops when no λ_L changed by more than its tolerance in
// the last iteration; here the move is m_i⁻¹ λ_b u_b, so λ_L = λ_b / |r_b(x_ref)|, and an update δ
// (sol) meets that tolerance when every |δ_b| ≤ tol · |r_b(x_ref)|.
bool ConstraintToolbox::Impl::within_multiplier_tol(const ClusterData& d, double tol) const {
  const int n = static_cast<int>(d.bonds.size());
  const double* len = at_kept.length.data();
  for (int k = 0; k < n; ++k)
    if (!(std::abs(d.sol[k]) <= tol * len[d.bonds[k]])) return false;  // false for NaN too
  return true;
}

ConstraintToolbox::Impl::ShakeNext ConstraintToolbox::Impl::shake_iterate(ShakeState& st, Eigen::Matrix3Xd& y,
                                                                          double tol, int max_iter) {
  const int c = st.c;
  ClusterData& d = data[c];
  const int n = static_cast<int>(d.bonds.size());
  const int* bond = d.bonds.data();
  const int iteration = st.iteration;
  // The chord needs only the residual, −h(y) (gap: no square root; after a chord update it was
  // computed in the update's pass); G(y), a full measure with rhs = −g(y), only to confirm
  // convergence (it is then kept for the velocity projection), for a Newton step, or to name a
  // bond whose length is not finite.
  double residual = !st.chord ? 0.0 : st.have_chord_residual ? st.chord_residual : chain_gap(c, y, d.rhs.data());
  st.have_chord_residual = false;
  bool measured = false;
  auto measure_y = [&] {
    residual = measure(c, y, at_cur, "SHAKE", iteration, d.rhs.data());
    measured = true;
  };
  if (st.accepted) {  // the last update met the multiplier tolerance: G(y) kept, as at convergence
    measure_y();
    return ShakeNext::converged;
  }
  if (!st.chord || !(residual > tol)) {  // Newton, converged by h, or not finite
    measure_y();
    if (residual <= tol) return ShakeNext::converged;
  }
  if (iteration == max_iter) {
    if (!measured) measure_y();  // report g, not h
    int worst = 0;
    d.rhs.cwiseAbs().maxCoeff(&worst);
    const int b = bond[worst];
    throw NumericalError("SHAKE did not converge in cluster " + std::to_string(c) + " after " +
                         std::to_string(max_iter) + " iterations: worst " + describe_bond(b, bonds[b]) +
                         ", |g| = " + format_g(residual));
  }
  if (iteration == 0 && st.chord)
    for (int k = 0; k < n; ++k) st.chord &= std::abs(d.rhs[k]) <= kChordStart * bonds[bond[k]].length;
  st.chord &= !(residual > kChordContraction * st.previous);  // false for NaN too
  st.previous = residual;
  if (!st.chord && !measured) measure_y();  // Newton from here: J needs G(y)
  if (st.chord) return ShakeNext::chord_solve;
  factorize(c, at_cur, at_kept, false, "SHAKE");
  ++d.factorizations;
  if (!d.spd) d.s_factored = false;  // J took S's place in the solver
  d.solver->solve(d.rhs, d.sol);
  st.accepted = st.multiplier_tol > 0.0 && within_multiplier_tol(d, st.multiplier_tol);
  d.lambda += d.sol;
  add_constraint_displacement(c, at_kept, d.sol, +1.0, y);
  ++st.iteration;
  return ShakeNext::newton_done;
}

// After S(x_ref) δ = −h(y) (or −g(y) after a full measure) into sol: in one pass along the
// chain, λ += δ, y += M⁻¹G(x_ref)ᵀδ and the new −h(y).
void ConstraintToolbox::Impl::shake_chord_update(ShakeState& st, Eigen::Matrix3Xd& y) {
  ClusterData& d = data[st.c];
  st.accepted = st.multiplier_tol > 0.0 && within_multiplier_tol(d, st.multiplier_tol);
  st.chord_residual = chain_displace(st.c, y, d.sol.data(), d.rhs.data());
  st.have_chord_residual = true;
  ++st.iteration;
}

void ConstraintToolbox::Impl::shake_chord_update_pair(ShakeState& a, ShakeState& b, Eigen::Matrix3Xd& y) {
  ShakeState* st[2] = {&a, &b};
  for (ShakeState* s : st)
    s->accepted = s->multiplier_tol > 0.0 && within_multiplier_tol(data[s->c], s->multiplier_tol);
  const int c[2] = {a.c, b.c};
  double residual[2];
  chain_displace_pair(c, y, residual);
  for (int j = 0; j < 2; ++j) {
    st[j]->chord_residual = residual[j];
    st[j]->have_chord_residual = true;
    ++st[j]->iteration;
  }
}

// y = y0 + M⁻¹G(x_ref)ᵀλ with g(y) = 0 (paper eq. (ProMol) when y0 = x_ref), x_ref the kept
// configuration: g(y + M⁻¹G(x_ref)ᵀδ) ≈ g(y) + J δ with J = G(y) M⁻¹ G(x_ref)ᵀ. Open chains near
// x_ref take chord steps S(x_ref) δ = −g(y) (SHAKE's quasi-Newton: S is J at y = x_ref, and its
// factors are usually kept from the velocity projection that ended the last step); otherwise, or
// as soon as the chord contracts slowly, full Newton on J (quadratic convergence, and λ accurate
// enough for the mollified force's H_λ).
void ConstraintToolbox::Impl::shake_cluster(int c, Eigen::Matrix3Xd& y, double tol, int max_iter,
                                            double multiplier_tol) {
  shake_group(c, 1, y, tol, max_iter, multiplier_tol);
}

// SHAKE on each cluster of a group (for_each_group: open chains of one length, or any cluster
// alone), the chord solves of the group in lockstep. Each cluster goes through its own iterations
// exactly as alone; a failure is held until the group is done and the first failing cluster's
// rethrown.
void ConstraintToolbox::Impl::shake_group(int first, int count, Eigen::Matrix3Xd& y, double tol, int max_iter,
                                          double multiplier_tol) {
  ShakeState st[kChainGroup];
  bool active[kChainGroup];
  std::exception_ptr error[kChainGroup];
  auto guard = [&](int j, auto&& work) {
    try {
      work();
    } catch (const NumericalError&) {
      error[j] = std::current_exception();
      active[j] = false;
    }
  };
  for (int j = 0; j < count; ++j) {
    active[j] = true;
    guard(j, [&] { shake_start(st[j], first + j, multiplier_tol); });
  }
  for (;;) {
    int solving[kChainGroup], cs[kChainGroup];
    int k = 0;
    for (int j = 0; j < count; ++j) {
      if (!active[j]) continue;
      guard(j, [&] {
        const ShakeNext next = shake_iterate(st[j], y, tol, max_iter);
        if (next == ShakeNext::converged) active[j] = false;
        if (next != ShakeNext::chord_solve) return;
        factor_kept_s(first + j, "SHAKE (reference configuration)");
        solving[k] = j;
        cs[k++] = first + j;
      });
    }
    if (k == 0 && std::none_of(active, active + count, [](bool a) { return a; })) break;
    solve_chains(cs, k);
    // The chord updates two chains at a time (chain_displace_pair: a group's chains have one
    // length) unless a fixed particle is shared, the last of an odd number alone. Each chain gets
    // its own operations either way.
    int q = 0;
    if (!clusters_share_particles)
      for (; q + 1 < k; q += 2) shake_chord_update_pair(st[solving[q]], st[solving[q + 1]], y);
    for (; q < k; ++q) shake_chord_update(st[solving[q]], y);
  }
  for (int j = 0; j < count; ++j)
    if (error[j]) std::rethrow_exception(error[j]);
}

void ConstraintToolbox::shake(const Eigen::Matrix3Xd& x_ref, Eigen::Matrix3Xd& y, Eigen::VectorXd* lambda, double tol,
                              int max_iter, double multiplier_tol) {
  const ScopedPhase phase(Phase::constraints);
  require_columns(x_ref, impl_->num_particles(), "shake");
  require_columns(y, impl_->num_particles(), "shake");
  Impl& d = *impl_;
  d.keep(x_ref);  // a copy: y may be x_ref itself
  d.for_each_group([&](int c, int count) { d.shake_group(c, count, y, tol, max_iter, multiplier_tol); });
  // Every cluster's last measure was of the converged y: keep y with G there, for the velocity
  // projection that follows in RATTLE (S at y is factored when first asked for).
  d.copy_configuration(y);
  std::swap(d.at_kept, d.at_cur);
  for (ClusterData& c : d.data) {
    c.frame_kept = true;
    c.s_factored = false;
  }
  if (lambda == nullptr) return;
  lambda->resize(num_bonds());  // a no-op when the caller keeps the vector
  for (const ClusterData& c : d.data)
    for (int k = 0; k < c.lambda.size(); ++k) (*lambda)[c.bonds[k]] = c.lambda[k];
}

// shake on block b (constraints.hpp): its particles of x_ref kept, its clusters shaken, then its
// particles of y kept with G there. shake swaps the whole frames; a block copies its bonds' columns
// of G(y) (the same values).
void ConstraintToolbox::shake_block(int b, const Eigen::Matrix3Xd& x_ref, Eigen::Matrix3Xd& y, double tol, int max_iter,
                                    double multiplier_tol) {
  Impl& d = *impl_;
  const Impl::Block& k = d.blocks[b];
  d.keep_block(k, x_ref);
  d.run_groups(k.cluster_begin, k.cluster_end,
               [&](int c, int count) { d.shake_group(c, count, y, tol, max_iter, multiplier_tol); });
  d.kept_x.middleCols(k.first, k.last - k.first) = y.middleCols(k.first, k.last - k.first);
  double* u_kept = d.at_kept.u.data();
  double* length_kept = d.at_kept.length.data();
  const double* u_cur = d.at_cur.u.data();
  const double* length_cur = d.at_cur.length.data();
  for (int c = k.cluster_begin; c < k.cluster_end; ++c) {
    ClusterData& cd = d.data[c];
    for (const int bond : cd.bonds) {
      for (int a = 0; a < 3; ++a) u_kept[3 * bond + a] = u_cur[3 * bond + a];
      length_kept[bond] = length_cur[bond];
    }
    cd.frame_kept = true;
    cd.s_factored = false;
  }
}

}  // namespace stiffmd
