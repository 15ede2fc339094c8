#include "integrators/minimize.hpp"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <limits>
#include <optional>
#include <sstream>
#include <stdexcept>

#include "core/errors.hpp"
#include "core/timing.hpp"
#include "integrators/constraints.hpp"

namespace stiffmd {
namespace {

// A sum of terms |t| < 2³⁰ whose value does not depend on the order of the terms: each term is
// cut into its integer part and 32 bits of its fraction, t ≈ q + r·2⁻³² (q = trunc t, r =
// trunc((t − q)·2³²): both exact operations, the bits below 2⁻³² dropped), and the q and the r
// are added as integers: exact in any order. Up to 2³¹ terms fit the words. The value, one
// rounding of the total (carried into the normal form q + r·2⁻³², 0 ≤ r < 2³²), is a function of
// the set of terms alone. It is SignedExactSum's idea (core/exact_sum.hpp) at a fraction of its
// cost per term (no branch on the sign, no unsigned conversion): FIRE adds four sums over every
// coordinate at every step, and inputs/melt_by_molecule.toml's set-up took 6.92 G instructions
// with SignedExactSum, 5.88 G with this, 5.06 G with plain sums (docs/design.md §12).
struct FixedSum {
  std::int64_t whole = 0, fraction = 0;
  void add(double t) {
    const auto q = static_cast<std::int64_t>(t);
    whole += q;
    fraction += static_cast<std::int64_t>((t - static_cast<double>(q)) * 4294967296.0);
  }
  double value() const {
    const std::int64_t w = whole + (fraction >> 32);  // floor division: 0 ≤ r < 2³²
    const std::int64_t r = fraction & 0xffffffffLL;
    return static_cast<double>(w) + std::ldexp(static_cast<double>(r), -32);
  }
};

// Sums over the particles of a system that may be held by parts on several ranks, the same bits
// for any order of the terms and any partition (SumRule::exact, docs/design.md §12): a sum's terms
// are scaled by 2^s, s fixed by the largest |term| of the whole system (one max over the ranks)
// so that it lies below 2³⁰, and added as FixedSum: a term is rounded to 2⁻⁶² of the largest,
// below a double's own rounding of a sum of many terms. Scaling by a power of two is exact, so a
// sum of one term is that term, bit for bit. With SumRule::plain each rank adds its terms in
// floating point and the ranks add their sums (tests only).
class GlobalSums {
 public:
  GlobalSums(const Communicator* ranks, SumRule rule)
      : ranks_(ranks && ranks->size() > 1 ? ranks : nullptr), rule_(rule) {}

  bool plain() const { return rule_ == SumRule::plain; }

  // The largest of each value over the ranks, in place.
  void max(double* values, int n) const {
    if (ranks_) ranks_->max(values, n);
  }
  double max(double value) const {
    max(&value, 1);
    return value;
  }

  // The scale 2^s of each sum from the whole system's largest |term| (largest: made the whole
  // system's here unless `reduced`).
  void scales(int count, double* largest, double* scale, bool reduced = false) const {
    if (!reduced) max(largest, count);
    for (int k = 0; k < count; ++k) scale[k] = std::ldexp(1.0, scale_exponent(largest[k]));
  }
  // The sums of the ranks' FixedSums of scaled terms, scaled back: the same on every rank. A sum
  // whose largest term is not finite is NaN.
  void finish(int count, FixedSum* sums, const double* largest, const double* scale, double* out) const {
    constexpr int kMaxSums = 4;
    if (ranks_) {
      std::int64_t words[2 * kMaxSums];
      for (int k = 0; k < count; ++k) words[2 * k] = sums[k].whole, words[2 * k + 1] = sums[k].fraction;
      ranks_->sum(words, 2 * count);
      for (int k = 0; k < count; ++k) sums[k] = {words[2 * k], words[2 * k + 1]};
    }
    for (int k = 0; k < count; ++k) out[k] = std::isfinite(largest[k]) ? sums[k].value() / scale[k] : std::nan("");
  }
  // Plain sums (SumRule::plain): each rank's added over the ranks.
  void finish_plain(int count, double* out) const {
    if (ranks_) ranks_->sum(out, count);
  }

 private:
  // s with largest·2^s < 2³⁰ (0 for 0 or a value that is not finite), at most 1000 so that 2^s
  // is a double (terms below 2⁻⁹⁷⁰ count as the zeros they nearly are).
  static int scale_exponent(double largest) {
    if (!(largest > 0.0) || !std::isfinite(largest)) return 0;
    int e = 0;
    std::frexp(largest, &e);  // largest < 2^e
    return std::min(30 - e, 1000);
  }

  const Communicator* ranks_;
  SumRule rule_;
};

double local_max_abs(const Eigen::Matrix3Xd& a) {
  double m = 0.0;
  for (Eigen::Index k = 0; k < a.size(); ++k) m = std::max(m, std::abs(a.data()[k]));
  return m;
}

// What every method shares: E(x) with the true force f and the force that moves fmove (f, or the
// soft start's capped force), both projected onto the tangent space under rigid bonds and zero at
// fixed particles (inverse mass 0: they never move, and the stopping rules do not see them);
// SHAKE back onto g = 0 after a move; progress lines; the report's closing numbers.
// `metric`: the inverse masses of the projection and SHAKE — the particles' own for FIRE's
// dynamics, 1 (0 at fixed particles) for the line searches, which move x by αh (docs/design.md §12).
// On parts (MinimizeParts: FIRE only, in the particles' own metric) the force field and state are
// this rank's part's, the energy its share, and the sums are added over the ranks.
class Descent {
 public:
  Descent(ForceField& forces, const StiffBonds* stiff, State& s, const MinimizeSettings& p,
          const Eigen::VectorXd& metric, std::ostream* progress, const Communicator* ranks = nullptr,
          SumRule rule = SumRule::exact)
      : sums(ranks, rule),
        forces_(&forces),
        s_(&s),
        p_(p),
        progress_(progress),
        levels_(forces.all_levels()),
        own_metric_(metric == s.inv_mass),
        shares_(ranks != nullptr) {
    bind(forces, stiff, s, metric);
    report.style = p.style;
    report.rigid = toolbox_.has_value();
  }

  // A new part (FIRE on parts, after molecules moved between ranks): its force field, stiff bonds
  // and state; FIRE's own columns (f, fmove among them) came with the particles.
  void bind(ForceField& forces, const StiffBonds* stiff, State& s, const Eigen::VectorXd& metric) {
    forces_ = &forces;
    s_ = &s;
    const Eigen::Index n = s.x.cols();
    raw_.resize(3, n);
    scratch_.resize(3, n);
    f.resize(3, n);
    fmove.resize(3, n);
    bonds_ = nullptr;
    toolbox_.reset();
    if (p_.rigid && stiff && !stiff->bonds.empty()) {
      bonds_ = &stiff->bonds;
      toolbox_.emplace(stiff->bonds, metric);
    }
  }

  bool rigid() const { return toolbox_.has_value(); }
  Eigen::Index size() const { return s_->x.cols(); }
  bool fixed(Eigen::Index i) const { return s_->inv_mass[i] == 0.0; }
  State& state() { return *s_; }

  // E(x); sets f and fmove, capped (whether the cap changed any particle's force, on any rank)
  // and fsq = ‖f‖₂² (the whole system's, summed exactly).
  double evaluate() {
    const Eigen::Matrix3Xd& x = s_->x;
    double e = 0.0;
    if (shares_) {
      e = share_of_energy(x);
    } else {
      e = toolbox_ ? forces_->compute_unconstrained(x, raw_) : forces_->compute(x, levels_, raw_);
    }
    ++report.evaluations;
    if (!shares_ && !std::isfinite(e)) throw not_finite(e);
    for (Eigen::Index i = 0; i < size(); ++i)
      if (fixed(i)) raw_.col(i).setZero();
    f = raw_;
    project(f);
    capped = false;
    if (p_.max_force > 0.0) {
      for (Eigen::Index i = 0; i < size(); ++i) {
        const double m = raw_.col(i).norm();
        if (m > p_.max_force) {
          raw_.col(i) *= p_.max_force / m;
          capped = true;
        }
      }
    }
    if (capped) {
      fmove = raw_;
      project(fmove);
    } else {
      fmove = f;
    }
    // Over the system: whether any force was capped, the energy from the ranks' shares and ‖f‖₂².
    constexpr double kInf = std::numeric_limits<double>::infinity();
    const double* fd = f.data();
    const Eigen::Index m = f.size();
    // The largest |e| and a bound on the largest f_ic² (fl(max|f_ic|)², as in dot_sums).
    double largest[3] = {std::isfinite(e) ? std::abs(e) : kInf, 0.0, capped ? 1.0 : 0.0};
    if (!f.allFinite()) {
      largest[1] = kInf;
    } else if (m > 0) {
      const double fabs = f.cwiseAbs().maxCoeff();
      largest[1] = fabs * fabs;
    }
    sums.max(largest, 3);  // one reduction for the three
    capped = largest[2] > 0.0;
    double out[2];
    if (sums.plain()) {
      out[0] = e;
      out[1] = f.squaredNorm();
      sums.finish_plain(2, out);
    } else {
      double scale[2];
      sums.scales(2, largest, scale, true);
      FixedSum total[2];
      if (std::isfinite(largest[0])) total[0].add(e * scale[0]);
      if (std::isfinite(largest[1]))
        for (Eigen::Index k = 0; k < m; ++k) total[1].add(fd[k] * fd[k] * scale[1]);
      sums.finish(2, total, largest, scale, out);
    }
    fsq = out[1];
    if (!std::isfinite(out[0])) throw not_finite(out[0]);
    return out[0];
  }

  // Σ a∘b, Σ a∘a, Σ b∘b over the system, exactly (FIRE's P = F·v, |F|², |v|²).
  void dot_sums(const Eigen::Matrix3Xd& a, const Eigen::Matrix3Xd& b, double out[3]) const {
    const double *u = a.data(), *w = b.data();
    const Eigen::Index m = a.size();
    if (sums.plain()) {
      out[0] = (a.array() * b.array()).sum();
      out[1] = a.squaredNorm();
      out[2] = b.squaredNorm();
      sums.finish_plain(3, out);
      return;
    }
    // Bounds on the largest terms from the largest components over the system (exact maxima): a
    // product's rounding is monotonic, so fl(|u_k w_k|) ≤ fl(max|u| max|w|). A pass Eigen
    // vectorises, where the terms' own maxima took a second scalar pass as long as the sums'.
    constexpr double kInf = std::numeric_limits<double>::infinity();
    double top[2] = {0.0, 0.0};  // max |u|, max |w| (∞: a component is not finite)
    if (m > 0) {
      top[0] = a.allFinite() ? a.cwiseAbs().maxCoeff() : kInf;
      top[1] = b.allFinite() ? b.cwiseAbs().maxCoeff() : kInf;
    }
    sums.max(top, 2);
    double largest[3] = {top[0] * top[1], top[0] * top[0], top[1] * top[1]};
    if (!std::isfinite(largest[0])) std::fill_n(largest, 3, kInf);  // ∞·0 is NaN
    double scale[3];
    sums.scales(3, largest, scale, true);
    FixedSum total[3];
    if (std::isfinite(largest[0]) && std::isfinite(largest[1]) && std::isfinite(largest[2])) {
      for (Eigen::Index k = 0; k < m; ++k) {
        total[0].add(u[k] * w[k] * scale[0]);
        total[1].add(u[k] * u[k] * scale[1]);
        total[2].add(w[k] * w[k] * scale[2]);
      }
    }
    sums.finish(3, total, largest, scale, out);
  }

  // Σ a∘b over the system, exactly (dot_sums' first sum).
  double dot(const Eigen::Matrix3Xd& a, const Eigen::Matrix3Xd& b) const {
    double out[3];
    dot_sums(a, b, out);
    return out[0];
  }

  // v ← P(x) v at the current positions (unchanged without rigid bonds), zero at fixed particles.
  void project(Eigen::Matrix3Xd& v) {
    if (!toolbox_) return;
    toolbox_->project_force(s_->x, v);
    for (Eigen::Index i = 0; i < size(); ++i)
      if (fixed(i)) v.col(i).setZero();
  }
  // v ← v − M⁻¹Gᵀμ with G v = 0 (RATTLE's velocity projection): FIRE's velocities, whose metric
  // is the particles' own.
  void project_velocity(Eigen::Matrix3Xd& v) {
    if (toolbox_) toolbox_->project_velocity(s_->x, v);
  }
  // x ← SHAKE(x) along the constraint directions at `from` (the positions before the move).
  void shake_from(const Eigen::Matrix3Xd& from) {
    if (toolbox_) toolbox_->shake(from, s_->x, nullptr, p_.shake_tolerance, 200);
  }

  template <typename... What>
  void say(const What&... what) {
    if (!progress_) return;
    const auto old = progress_->precision(6);
    ((*progress_) << ... << what) << std::endl;
    progress_->precision(old);
  }

  // The closing numbers (over the system), the deck's velocities (never moved by the methods)
  // projected onto the tangent space at the minimum, in the particles' own metric: RATTLE's
  // projection.
  MinimizeReport finish(double e) {
    report.energy = e;
    double largest[2] = {0.0, 0.0};
    for (Eigen::Index i = 0; i < size(); ++i) largest[0] = std::max(largest[0], f.col(i).norm());
    if (toolbox_) largest[1] = toolbox_->max_violation(s_->x);
    sums.max(largest, 2);
    report.fmax = largest[0];
    report.fnorm = std::sqrt(fsq);
    if (toolbox_) {
      report.max_violation = largest[1];
      if (own_metric_) {
        toolbox_->project_velocity(s_->x, s_->v);
      } else {
        ConstraintToolbox velocities(*bonds_, s_->inv_mass);
        velocities.project_velocity(s_->x, s_->v);
      }
    }
    return report;
  }

  GlobalSums sums;
  Eigen::Matrix3Xd f, fmove;
  bool capped = false;
  double fsq = 0.0;  // ‖f‖₂² over the system
  MinimizeReport report;

 private:
  // A part's forces at x into raw_ and its share of the energy: the terms in the force field's
  // order (the forces the bits of ForceField::compute), a pair term's share from
  // energy_and_virial (a pair with a halo bead counts half: the ranks' shares add up to the
  // whole energy), the other terms' energies their own particles' (ForceTerm::add_forces).
  double share_of_energy(const Eigen::Matrix3Xd& x) {
    const double e = part_energy_share(*forces_, x, raw_, scratch_, toolbox_.has_value());
    if (toolbox_) {
      const Level outer = forces_->outermost();
      forces_->count_evaluations(std::span<const Level>(&outer, 1));
    } else {
      forces_->count_evaluations(levels_);
    }
    return e;
  }

  static NumericalError not_finite(double e) {
    return NumericalError("minimize: the potential energy is not finite (" + std::to_string(e) +
                          "): beads on top of each other?");
  }

  ForceField* forces_;
  State* s_;
  const MinimizeSettings& p_;
  std::ostream* progress_;
  const std::vector<Level> levels_;
  const bool own_metric_;
  const bool shares_;  // on parts: the energy is this rank's share
  const std::vector<StiffBond>* bonds_ = nullptr;
  std::optional<ConstraintToolbox> toolbox_;
  Eigen::Matrix3Xd raw_, scratch_;
};

// LAMMPS's relative energy change (EPS_ENERGY = 1e-8): etol's rule.
bool energy_converged(double etol, double e, double e_prev) {
  return etol > 0.0 && std::abs(e - e_prev) < etol * 0.5 * (std::abs(e) + std::abs(e_prev) + 1e-8);
}

}  // namespace

double part_energy_share(ForceField& forces, const Eigen::Matrix3Xd& x, Eigen::Matrix3Xd& f, Eigen::Matrix3Xd& scratch,
                         bool unconstrained) {
  const Box& box = forces.box();
  f.setZero(3, x.cols());
  double e = 0.0;
  for (const ForceTerm* term : forces.evaluation_order()) {
    if (unconstrained && term->stiff_bonds()) continue;  // compute_unconstrained's terms
    const ScopedPhase phase(term->phase());
    if (term->uses_neighbor_list()) {
      term->add_forces_only(x, box, f);
      e += term->energy_and_virial(x, box, scratch).energy;
    } else {
      e += term->add_forces(x, box, f);
    }
  }
  return e;
}

const char* style_name(MinimizeStyle style) {
  switch (style) {
    case MinimizeStyle::fire:
      return "fire";
    case MinimizeStyle::cg:
      return "cg";
    case MinimizeStyle::sd:
      return "sd";
  }
  return "?";
}

// FIRE 2.0 as LAMMPS's MinFire::iterate with its defaults (integrator eulerimplicit,
// halfstepback yes, initialdelay yes, vdfmax 2000: more than 2000 steps with P ≤ 0 stop it,
// reported as "vdfmax"), step k = 1, 2, …:
//   P = F·v.  P > 0: mixing factors c1 = 1 − α, c2 = α |v|/|F|; after more than delaystep steps
//     since the last P ≤ 0, dt ← min(dt·dtgrow, tmax·dt0) and α ← α·alphashrink.
//   P ≤ 0: (not within the first delaystep steps) α ← α0 and dt ← dt·dtshrink if that stays
//     ≥ tmin·dt0; x ← x − ½ dt_v v (the half step back); v ← 0.
//   dt_v = dt, reduced so that dt_v · max_{i,c} |v_ic| ≤ dmax (from v = dt M⁻¹F when v was reset);
//   v ← v + dt_v M⁻¹F; if P > 0: v ← c1 v + c2 F; x ← x + dt_v v (semi-implicit Euler), the
//   move scaled down where a coordinate would move further than dmax (below).
// Under rigid bonds F is P(x) f = f − Gᵀλ (G M⁻¹ F = 0: M⁻¹F is a tangent velocity), v is
// projected onto G v = 0 before each move and at the new positions, and every move of x
// (the step and the half step back) is followed by SHAKE (y ← y + M⁻¹G(x_old)ᵀλ, g(y) = 0).
namespace {

// FIRE on one process (parts null) or on a rank's part (the sums over the ranks; after each move
// the particles may move between ranks, with FIRE's columns).
MinimizeReport fire(ForceField& forces, const StiffBonds* stiff, State& state, const MinimizeSettings& p,
                    std::ostream* progress, const MinimizeObserver& after_move, MinimizeParts* parts, SumRule rule) {
  Descent d(forces, stiff, state, p, state.inv_mass, progress, parts ? &parts->ranks() : nullptr, rule);
  State* s = &state;
  const Eigen::Matrix3Xd& fmove = d.fmove;
  const Eigen::Index n0 = s->x.cols();
  Eigen::Matrix3Xd v = Eigen::Matrix3Xd::Zero(3, n0), last_move = Eigen::Matrix3Xd::Zero(3, n0), x_old;
  MinimizeReport& r = d.report;

  d.shake_from(s->x);  // start on g = 0
  double e = d.evaluate(), e_prev = e;
  r.initial_energy = e;
  std::int64_t particles = n0;
  if (parts) parts->ranks().sum(&particles, 1);
  d.say("minimize: FIRE on ", particles, " particles (potential energy ", e, ", force 2-norm ", std::sqrt(d.fsq),
        ") ...");

  const double dtmax = p.tmax * p.dt, dtmin = p.tmin * p.dt;
  double dt = p.dt, dtv = p.dt, alpha = p.alpha0;  // dt_v: the last step's, for the dmax limit
  long last_negative = 0, uphill = 0;
  constexpr long kMaxUphill = 2000;  // LAMMPS's min_modify vdfmax default
  bool v_reset = true;
  r.stopped_by = "maxiter";
  for (long k = 1; k <= p.maxiter; ++k) {
    Eigen::Matrix3Xd& x = s->x;
    double dots[3];  // P = F·v, |F|², |v|² over the system
    d.dot_sums(fmove, v, dots);
    const double power = dots[0];
    double scale1 = 1.0, scale2 = 0.0;
    if (power > 0.0) {
      const double ff = dots[1];
      scale1 = 1.0 - alpha;
      scale2 = ff <= 1e-20 ? 0.0 : alpha * std::sqrt(dots[2] / ff);
      if (k - last_negative > p.delaystep) {
        dt = std::min(dt * p.dtgrow, dtmax);
        alpha *= p.alphashrink;
      }
    } else {
      last_negative = k;
      if (++uphill > kMaxUphill) {
        r.stopped_by = "vdfmax";
        break;
      }
      if (k >= p.delaystep) {  // delaystep_start: no reset in the first delaystep steps
        alpha = p.alpha0;
        if (dt * p.dtshrink >= dtmin) dt *= p.dtshrink;
      }
      if (p.halfstepback && !v_reset) {
        x_old = x;
        x -= 0.5 * last_move;  // −½ dt_v v, the half of the last move (as capped by dmax)
        d.shake_from(x_old);
        e = d.evaluate();
      }
      v.setZero();
      v_reset = true;
    }

    // The step dt_v: no coordinate moves more than dmax (from the velocity a reset one gets).
    // max |dt a_ic| = dt max |a_ic| to the bit (rounding is monotonic), over the ranks.
    double vmax = 0.0;
    if (v_reset) {
      for (Eigen::Index i = 0; i < x.cols(); ++i)
        for (int c = 0; c < 3; ++c) vmax = std::max(vmax, std::abs(fmove(c, i) * s->inv_mass[i]));
      vmax = dt * d.sums.max(vmax);
    } else {
      vmax = d.sums.max(local_max_abs(v));
    }
    dtv = dt * vmax > p.dmax ? p.dmax / vmax : dt;

    v += dtv * (fmove * s->inv_mass.asDiagonal());
    if (power > 0.0) v = scale1 * v + scale2 * fmove;
    d.project_velocity(v);
    // dmax is a hard cap on the move: LAMMPS sizes dt_v by the velocity before the kick, so a
    // large force (an overlap) could still carry a particle far past dmax, and SHAKE with it.
    const double reach = dtv * d.sums.max(local_max_abs(v));
    x_old = x;
    last_move = (reach > p.dmax ? p.dmax / reach : 1.0) * dtv * v;
    x += last_move;
    d.shake_from(x_old);
    d.project_velocity(v);
    e_prev = e;
    e = d.evaluate();
    v_reset = false;
    r.iterations = k;
    if (after_move) after_move(x, e);
    if (k % 1000 == 0) d.say("minimize: iteration ", k, ": potential energy ", e, ", force 2-norm ", std::sqrt(d.fsq));

    if (k - last_negative > p.delaystep && energy_converged(p.etol, e, e_prev)) {
      r.stopped_by = "etol";
      break;
    }
    if (p.ftol > 0.0 && d.fsq < p.ftol * p.ftol) {
      r.stopped_by = "ftol";
      break;
    }
    if (r.evaluations >= p.maxeval) {
      r.stopped_by = "maxeval";
      break;
    }
    // On parts: molecules may move to other ranks with FIRE's columns (the forces at x among
    // them, so no evaluation is repeated).
    if (parts && parts->redistribute({&v, &last_move, &d.f, &d.fmove})) {
      s = &parts->state();
      d.bind(parts->forces(), parts->stiff(), *s, s->inv_mass);
    }
  }
  return d.finish(e);
}

}  // namespace

// FIRE 2.0 as LAMMPS's MinFire::iterate with its defaults (integrator eulerimplicit,
// halfstepback yes, initialdelay yes, vdfmax 2000: more than 2000 steps with P ≤ 0 stop it,
// reported as "vdfmax"), step k = 1, 2, …:
//   P = F·v.  P > 0: mixing factors c1 = 1 − α, c2 = α |v|/|F|; after more than delaystep steps
//     since the last P ≤ 0, dt ← min(dt·dtgrow, tmax·dt0) and α ← α·alphashrink.
//   P ≤ 0: (not within the first delaystep steps) α ← α0 and dt ← dt·dtshrink if that stays
//     ≥ tmin·dt0; x ← x − ½ dt_v v (the half step back); v ← 0.
//   dt_v = dt, reduced so that dt_v · max_{i,c} |v_ic| ≤ dmax (from v = dt M⁻¹F when v was reset);
//   v ← v + dt_v M⁻¹F; if P > 0: v ← c1 v + c2 F; x ← x + dt_v v (semi-implicit Euler), the
//   move scaled down where a coordinate would move further than dmax (below).
// Under rigid bonds F is P(x) f = f − Gᵀλ (G M⁻¹ F = 0: M⁻¹F is a tangent velocity), v is
// projected onto G v = 0 before each move and at the new positions, and every move of x
// (the step and the half step back) is followed by SHAKE (y ← y + M⁻¹G(x_old)ᵀλ, g(y) = 0).
// P, |F|², |v|² and ‖f‖₂² are exact sums (GlobalSums), the energy an exact sum of the ranks'
// shares: the same bits on one process and on parts (docs/design.md §12).
MinimizeReport minimize_fire(ForceField& forces, const StiffBonds* stiff, State& s, const MinimizeSettings& p,
                             std::ostream* progress, const MinimizeObserver& after_move) {
  return fire(forces, stiff, s, p, progress, after_move, nullptr, SumRule::exact);
}

MinimizeReport minimize_fire(MinimizeParts& parts, const MinimizeSettings& p, std::ostream* progress,
                             const MinimizeObserver& after_move, SumRule rule) {
  if (p.style != MinimizeStyle::fire)
    throw std::invalid_argument("minimize_fire on parts: style " + std::string(style_name(p.style)));
  return fire(parts.forces(), parts.stiff(), parts.state(), p, progress, after_move, &parts, rule);
}

// The quadratic line search of LAMMPS's MinLineSearch::linemin_quadratic (after Dennis and
// Schnabel), from x0 = x along h with E0 = e, the slope E'(0) = −f·h < 0:
//   α_max = min(1, dmax / max_ic |h_ic|); α = α_max.
//   Repeat: x = x0 + αh (then SHAKE), E(α), fh = f(α)·h.
//     |fh| or |fh − fh_prev| < 1e-28: back to x0, "zero-quadratic".
//     If the quadratic model through the previous point holds, relerr = |1 − (½(α − α_prev)(fh +
//     fh_prev) + E(α)) / E_prev| ≤ 0.1, take the secant step to fh = 0, α₀ = α − (α − α_prev)
//     fh / (fh − fh_prev), when 0 < α₀ < α_max: accepted if E(α₀) − E0 < EMACH = 1e-8 (near the
//     minimum the energy changes by less than its round-off, and the force decides).
//     Otherwise accept the point reached if E − E0 ≤ −0.4 α f0·h (Armijo, Nocedal & Wright
//     Proc. 3.1); else α ← α/2, and back to x0 with "zero-alpha" once 0.4 α f0·h ≤ EMACH.
// After a rejected secant step the previous point's energy is E(α₀), its slope α's, as in LAMMPS,
// whose iterates these then are up to round-off (docs/decks.md [minimize]). Under rigid bonds
// every trial point is SHAKEn from x0 and the slope is f(α)·h with f projected at x(α): the
// derivative of E along the retracted path to first order in α (docs/design.md §12).
namespace {

enum class LineSearch { accepted, zero_alpha, zero_quadratic, zero_force };

LineSearch quadratic_line_search(Descent& d, Eigen::Matrix3Xd& x, const Eigen::Matrix3Xd& h, double dmax, double& e) {
  constexpr double kAlphaMax = 1.0, kAlphaReduce = 0.5, kBacktrackSlope = 0.4, kQuadraticTol = 0.1;
  constexpr double kEmach = 1e-8, kEpsQuad = 1e-28;
  const double hmax = d.sums.max(local_max_abs(h));
  if (hmax == 0.0) return LineSearch::zero_force;
  const double fh0 = d.dot(d.f, h);
  const double alpha_max = std::min(kAlphaMax, dmax / hmax);
  const Eigen::Matrix3Xd x0 = x;
  const double e0 = e;
  auto step = [&](double alpha) {
    x = x0;
    if (alpha > 0.0) {
      x += alpha * h;
      d.shake_from(x0);
    }
    return d.evaluate();
  };
  double alpha = alpha_max, alpha_prev = 0.0, fh_prev = fh0, e_prev = e0;
  for (;;) {
    e = step(alpha);
    const double fh = d.dot(d.f, h);
    const double dfh = fh - fh_prev;
    if (std::abs(fh) < kEpsQuad || std::abs(dfh) < kEpsQuad) {
      e = step(0.0);
      return LineSearch::zero_quadratic;
    }
    const double relerr = std::abs(1.0 - (0.5 * (alpha - alpha_prev) * (fh + fh_prev) + e) / e_prev);
    const double alpha0 = alpha - (alpha - alpha_prev) * fh / dfh;
    double e_at = e;  // the energy where x is
    if (relerr <= kQuadraticTol && alpha0 > 0.0 && alpha0 < alpha_max) {
      e_at = step(alpha0);
      if (e_at - e0 < kEmach) {
        e = e_at;
        return LineSearch::accepted;
      }
    }
    const double de_ideal = -kBacktrackSlope * alpha * fh0;
    if (e_at - e0 <= de_ideal) {
      e = e_at;
      return LineSearch::accepted;
    }
    fh_prev = fh;
    e_prev = e_at;
    alpha_prev = alpha;
    alpha *= kAlphaReduce;
    if (alpha <= 0.0 || de_ideal >= -kEmach) {
      e = step(0.0);
      return LineSearch::zero_alpha;
    }
  }
}

}  // namespace

// LAMMPS's MinCG::iterate (Polak–Ribière; Shewchuk, "An introduction to the conjugate gradient
// method without the agonizing pain" (1994), §14.1) and MinSD, on the force that moves (fmove):
//   g = h = F(x_0); each iteration: a line search along h; the stopping rules; then
//   β = max(0, (F·F − F·g) / g·g) (cg; 0 for sd, on a soft-start step, every 3N − m iterations),
//   g ← F, h ← F + β P(x) h, and h ← F when F_true·h ≤ 0 (not downhill), h ← F_true when even F
//   is not (a capped force can point against the true one after the projection).
namespace {

// The unit metric of the line searches: 1, 0 at fixed particles.
Eigen::VectorXd unit_metric_of(const Eigen::VectorXd& inv_mass) {
  Eigen::VectorXd unit = Eigen::VectorXd::Ones(inv_mass.size());
  for (Eigen::Index i = 0; i < unit.size(); ++i)
    if (inv_mass[i] == 0.0) unit[i] = 0.0;
  return unit;
}

// CG or SD on one process (parts null) or on a rank's part: every sum over the system exact
// (Descent's, added over the ranks), the largest |h| a max; between iterations the particles may
// move between ranks with the method's columns (g, h and the forces).
MinimizeReport linesearch(ForceField& forces, const StiffBonds* stiff, State& state, const MinimizeSettings& p,
                          std::ostream* progress, const MinimizeObserver& after_move, MinimizeParts* parts,
                          SumRule rule) {
  const Communicator* ranks = parts ? &parts->ranks() : nullptr;
  Eigen::VectorXd unit_metric = unit_metric_of(state.inv_mass);
  Descent d(forces, stiff, state, p, unit_metric, progress, ranks, rule);
  State* s = &state;
  MinimizeReport& r = d.report;
  const char* name = p.style == MinimizeStyle::cg ? "CG" : "SD";

  d.shake_from(s->x);  // start on g = 0
  double e = d.evaluate();
  r.initial_energy = e;
  // Degrees of freedom: the conjugate directions run out after this many iterations.
  std::int64_t counts[3] = {s->x.cols(), static_cast<std::int64_t>(unit_metric.sum()),
                            d.rigid() ? static_cast<std::int64_t>(stiff->bonds.size()) : 0};
  if (ranks && ranks->size() > 1) ranks->sum(counts, 3);
  d.say("minimize: ", name, " on ", counts[0], " particles (potential energy ", e, ", force 2-norm ", std::sqrt(d.fsq),
        ") ...");
  const long dof = 3 * counts[1] - counts[2];
  const long restart_every = std::max(1L, dof);

  Eigen::Matrix3Xd g = d.fmove, h = d.fmove;
  double gg = d.dot(g, g);
  bool was_capped = d.capped;
  r.stopped_by = "maxiter";
  for (long k = 1; k <= p.maxiter; ++k) {
    Eigen::Matrix3Xd& x = s->x;
    const double e_prev = e;
    const LineSearch result = quadratic_line_search(d, x, h, p.dmax, e);
    r.iterations = k;
    if (result != LineSearch::accepted) {
      r.stopped_by = result == LineSearch::zero_alpha       ? "zero-alpha"
                     : result == LineSearch::zero_quadratic ? "zero-quadratic"
                                                            : "zero-force";
      break;
    }
    if (after_move) after_move(x, e);
    if (k % 1000 == 0) d.say("minimize: iteration ", k, ": potential energy ", e, ", force 2-norm ", std::sqrt(d.fsq));

    if (energy_converged(p.etol, e, e_prev)) {
      r.stopped_by = "etol";
      break;
    }
    if (p.ftol > 0.0 && d.fsq < p.ftol * p.ftol) {
      r.stopped_by = "ftol";
      break;
    }
    if (r.evaluations >= p.maxeval) {
      r.stopped_by = "maxeval";
      break;
    }

    const Eigen::Matrix3Xd& fm = d.fmove;
    double dots[3];  // F·g, F·F, g·g over the system
    d.dot_sums(fm, g, dots);
    const double ff = dots[1], fg = dots[0];
    const bool conjugate =
        p.style == MinimizeStyle::cg && !d.capped && !was_capped && (k + 1) % restart_every != 0 && gg > 0.0;
    const double beta = conjugate ? std::max(0.0, (ff - fg) / gg) : 0.0;
    gg = ff;
    g = fm;
    was_capped = d.capped;
    if (beta > 0.0) {
      d.project(h);  // onto the tangent space at the new x
      h = g + beta * h;
    } else {
      h = g;
    }
    if (d.dot(d.f, h) <= 0.0) h = g;
    if (d.dot(d.f, h) <= 0.0) h = d.f;
    // On parts: molecules may move to other ranks with the method's columns (the forces at x
    // among them, so no evaluation is repeated).
    if (parts && parts->redistribute({&g, &h, &d.f, &d.fmove})) {
      s = &parts->state();
      unit_metric = unit_metric_of(s->inv_mass);
      d.bind(parts->forces(), parts->stiff(), *s, unit_metric);
    }
  }
  return d.finish(e);
}

}  // namespace

MinimizeReport minimize_linesearch(ForceField& forces, const StiffBonds* stiff, State& s, const MinimizeSettings& p,
                                   std::ostream* progress, const MinimizeObserver& after_move) {
  return linesearch(forces, stiff, s, p, progress, after_move, nullptr, SumRule::exact);
}

MinimizeReport minimize_linesearch(MinimizeParts& parts, const MinimizeSettings& p, std::ostream* progress,
                                   const MinimizeObserver& after_move, SumRule rule) {
  if (p.style == MinimizeStyle::fire) throw std::invalid_argument("minimize_linesearch on parts: style fire");
  return linesearch(parts.forces(), parts.stiff(), parts.state(), p, progress, after_move, &parts, rule);
}

MinimizeReport minimize(MinimizeParts& parts, const MinimizeSettings& p, std::ostream* progress,
                        const MinimizeObserver& after_move, SumRule rule) {
  if (p.style == MinimizeStyle::fire) return minimize_fire(parts, p, progress, after_move, rule);
  return minimize_linesearch(parts, p, progress, after_move, rule);
}

MinimizeReport minimize(ForceField& forces, const StiffBonds* stiff, State& s, const MinimizeSettings& p,
                        std::ostream* progress, const MinimizeObserver& after_move) {
  if (p.style == MinimizeStyle::fire) return minimize_fire(forces, stiff, s, p, progress, after_move);
  return minimize_linesearch(forces, stiff, s, p, progress, after_move);
}

std::string describe(const MinimizeReport& r) {
  std::ostringstream o;
  o.precision(10);
  const char* name = r.style == MinimizeStyle::fire ? "FIRE" : r.style == MinimizeStyle::cg ? "CG" : "SD";
  o << "minimize: " << name << " stopped by " << r.stopped_by << " after " << r.iterations << " iterations ("
    << r.evaluations << " force evaluations): E0 " << r.initial_energy << " -> E " << r.energy
    << ", largest force |f|max = " << r.fmax << ", force 2-norm " << r.fnorm;
  if (r.rigid) o << ", max |g| = " << r.max_violation;
  return o.str();
}

}  // namespace stiffmd
