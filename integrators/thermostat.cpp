#include "integrators/thermostat.hpp"

#include <array>
#include <stdexcept>
#include <string>

#include "core/communicator.hpp"
#include "core/exact_sum.hpp"
#include "core/parallel.hpp"
#include "core/timing.hpp"
#include "forcefields/force_field.hpp"
#include "integrators/constraints.hpp"
#include "integrators/integrator.hpp"
#include "integrators/primitives.hpp"

namespace stiffmd {

std::string_view thermostat_style_name(ThermostatSettings::Style style) {
  switch (style) {
    case ThermostatSettings::Style::langevin:
      return "langevin";
    case ThermostatSettings::Style::csvr:
      return "csvr";
    default:
      return "none";
  }
}

int degrees_of_freedom(const Eigen::VectorXd& inv_mass, bool momentum_conserved, int rigid_constraints) {
  int mobile = 0;
  for (Eigen::Index i = 0; i < inv_mass.size(); ++i) mobile += inv_mass[i] > 0.0;
  return 3 * mobile - (momentum_conserved && mobile == inv_mass.size() ? 3 : 0) - rigid_constraints;
}

bool momentum_conserved(const ForceField& forces, const Eigen::VectorXd& inv_mass, const ThermostatSettings& t) {
  if (t.style == ThermostatSettings::Style::langevin) return false;
  for (Eigen::Index i = 0; i < inv_mass.size(); ++i)
    if (inv_mass[i] == 0.0) return false;
  for (const auto& term : forces.terms())
    if (!term->conserves_momentum()) return false;
  return true;
}

LangevinNoise::LangevinNoise(const ThermostatSettings& settings, const Eigen::VectorXd& inv_mass)
    : kT_(settings.temperature),
      seed_(settings.seed),
      id_(settings.particle_id),
      friction_(settings.friction),
      inv_mass_(inv_mass),
      c_(inv_mass.size()),
      sigma_(inv_mass.size()) {
  if (friction_.size() != inv_mass.size())
    throw std::invalid_argument("Langevin thermostat: " + std::to_string(friction_.size()) + " frictions for " +
                                std::to_string(inv_mass.size()) + " particles");
  if (!(kT_ >= 0.0) || !std::isfinite(kT_)) throw std::invalid_argument("Langevin thermostat: expected kT >= 0");
}

void LangevinNoise::coefficients(double dt) {
  for (Eigen::Index i = 0; i < c_.size(); ++i) {
    c_[i] = std::exp(-friction_[i] * dt);
    // 1 − c² by expm1, accurate when γ dt is small (the micro steps of the impulse family).
    sigma_[i] = std::sqrt(-std::expm1(-2.0 * friction_[i] * dt) * kT_ * inv_mass_[i]);
  }
  dt_ = dt;
}

namespace {

// Particles per run of the O step (o_pass below): its normals, kinetic energies and velocities are
// formed run by run in scratch of a few kB.
constexpr int kNoiseRun = 64;

// The 3m normals of particles b … b + m − 1 into z, each particle's three as particle_noise gives
// them (words 3 id, 3 id + 1, 3 id + 2; id = id[p] or p): first every word (independent hashes),
// then every draw by the ziggurat's fast path u x_i without a branch, then, if any draw fell outside
// the layer below (0.7 % of them), those again by the wedge or the tail — ziggurat_normal's values,
// with the hashes' long chains of multiplies side by side instead of one particle after another.
void run_normals(std::uint64_t key, const std::int64_t* id, std::int64_t b, int m, const ZigguratTable& t,
                 double* __restrict z) {
  std::uint64_t w[3 * kNoiseRun];
  for (int k = 0; k < m; ++k) {
    const std::uint64_t j = 3 * static_cast<std::uint64_t>(id ? id[b + k] : b + k);
    for (int a = 0; a < 3; ++a) w[3 * k + a] = noise_word(key, j + a);
  }
  bool slow = false;
  for (int k = 0; k < 3 * m; ++k) {
    const int layer = ziggurat_layer(w[k]);
    const double u = signed_uniform(w[k]);
    z[k] = u * t.x[layer];
    slow |= !(std::abs(u) < t.ratio[layer]);
  }
  if (!slow) return;
  for (int k = 0; k < 3 * m; ++k) {
    const int layer = ziggurat_layer(w[k]);
    const double u = signed_uniform(w[k]);
    if (!(std::abs(u) < t.ratio[layer])) z[k] = detail::ziggurat_slow(w[k], layer, u, t);
  }
}

}  // namespace

// Run by run (kNoiseRun particles): the normals (run_normals), ½ m|v|² before, the new velocities,
// ½ m|v|² after, then the two sums in particle order — each term the expression of
// kinetic_energy (integrators/primitives.hpp) and each velocity c v + σ ξ as before, so the same
// bits, with no loop carrying a hash's or a division's latency from one particle to the next.
// kDrift: the run's kick and half drift first and its second half drift last (kick_drift_o_drift),
// with kick_drift's and drift's expressions, while the run is in L1.
template <bool kMeasure, bool kDrift>
KineticChange LangevinNoise::o_pass(Eigen::Matrix3Xd* x, Eigen::Matrix3Xd& v, const Eigen::VectorXd* inv_mass,
                                    const Eigen::Matrix3Xd* f, double dt_kick, double half_drift, double dt,
                                    std::int64_t step, std::uint64_t substep) {
  const ScopedPhase phase(Phase::thermostat);
  if (dt != dt_) coefficients(dt);
  const std::uint64_t key = noise_key(seed_, step, substep);
  const ZigguratTable& table = ziggurat_table();
  const int parts = threads_for(v.cols());
  const std::int64_t* id = id_.empty() ? nullptr : id_.data();
  std::array<KineticChange, kMaxParts> sums{};
  parallel_numbered_blocks(v.cols(), parts, [&](int u, std::int64_t b, std::int64_t e) {
    double before = 0.0, after = 0.0;
    alignas(64) double z[3 * kNoiseRun], k0[kNoiseRun], k1[kNoiseRun];
    const double* const w = inv_mass_.data();
    double* __restrict vp = v.data();
    // ½ m|v|² of the run's particles (a fixed one's is not summed)
    auto kinetic = [&](std::int64_t r, int m, double* k) {
      for (int q = 0; q < m; ++q) k[q] = 0.5 * v.col(r + q).squaredNorm() / (w[r + q] > 0.0 ? w[r + q] : 1.0);
    };
    for (std::int64_t r = b; r < e; r += kNoiseRun) {
      const int m = static_cast<int>(std::min<std::int64_t>(kNoiseRun, e - r));
      if constexpr (kDrift) {
        double* __restrict xp = x->data();
        const double* __restrict fp = f->data();
        const double* __restrict wk = inv_mass->data();
        for (std::int64_t i = r; i < r + m; ++i) {
          const double c = dt_kick * wk[i];
          for (int a = 0; a < 3; ++a) {
            vp[3 * i + a] += c * fp[3 * i + a];
            xp[3 * i + a] += half_drift * vp[3 * i + a];
          }
        }
      }
      run_normals(key, id, r, m, table, z);
      if constexpr (kMeasure) kinetic(r, m, k0);
      for (int q = 0; q < m; ++q) {
        const std::int64_t i = r + q;
        if (w[i] == 0.0) continue;  // fixed: stays at rest
        v.col(i) = c_[i] * v.col(i) + sigma_[i] * Eigen::Map<const Eigen::Vector3d>(z + 3 * q);
      }
      if constexpr (kMeasure) {
        kinetic(r, m, k1);
        for (int q = 0; q < m; ++q)
          if (w[r + q] > 0.0) {
            before += k0[q];
            after += k1[q];
          }
      }
      if constexpr (kDrift) {
        double* __restrict xp = x->data();
        for (std::int64_t i = 3 * r; i < 3 * (r + m); ++i) xp[i] += half_drift * vp[i];
      }
    }
    sums[u] = {before, after};
  });
  KineticChange total = sums[0];  // the blocks in order, as parallel_sum adds them
  for (int u = 1; u < parts; ++u) total.before += sums[u].before, total.after += sums[u].after;
  return total;
}

template KineticChange LangevinNoise::o_pass<false, false>(Eigen::Matrix3Xd*, Eigen::Matrix3Xd&, const Eigen::VectorXd*,
                                                           const Eigen::Matrix3Xd*, double, double, double,
                                                           std::int64_t, std::uint64_t);
template KineticChange LangevinNoise::o_pass<true, false>(Eigen::Matrix3Xd*, Eigen::Matrix3Xd&, const Eigen::VectorXd*,
                                                          const Eigen::Matrix3Xd*, double, double, double, std::int64_t,
                                                          std::uint64_t);

double ParticleSum::total(const Eigen::VectorXd& inv_mass) const {
  if (parts_ <= 1) return running_;
  return parallel_sum(n_, parts_, [&](std::int64_t b, std::int64_t e) {
    double k = 0.0;
    for (std::int64_t i = b; i < e; ++i)
      if (inv_mass[i] > 0.0) k += terms_[static_cast<std::size_t>(i)];
    return k;
  });
}

// o_pass's runs on one range: the same normals (a particle's depend on its index only), velocities
// and terms.
void LangevinNoise::apply_range(Eigen::Matrix3Xd& v, std::int64_t step, std::uint64_t substep, std::int64_t first,
                                std::int64_t last, ParticleSum* before, ParticleSum* after) const {
  const std::uint64_t key = noise_key(seed_, step, substep);
  const ZigguratTable& table = ziggurat_table();
  const std::int64_t* id = id_.empty() ? nullptr : id_.data();
  const double* const w = inv_mass_.data();
  alignas(64) double z[3 * kNoiseRun];
  for (std::int64_t r = first; r < last; r += kNoiseRun) {
    const int m = static_cast<int>(std::min<std::int64_t>(kNoiseRun, last - r));
    run_normals(key, id, r, m, table, z);
    if (before)
      for (std::int64_t i = r; i < r + m; ++i)
        if (w[i] > 0.0) before->add(i, 0.5 * v.col(i).squaredNorm() / w[i]);
    for (int q = 0; q < m; ++q) {
      const std::int64_t i = r + q;
      if (w[i] == 0.0) continue;  // fixed: stays at rest
      v.col(i) = c_[i] * v.col(i) + sigma_[i] * Eigen::Map<const Eigen::Vector3d>(z + 3 * q);
    }
    if (after)
      for (std::int64_t i = r; i < r + m; ++i)
        if (w[i] > 0.0) after->add(i, 0.5 * v.col(i).squaredNorm() / w[i]);
  }
}

KineticChange LangevinNoise::kick_drift_o_drift(Eigen::Matrix3Xd& x, Eigen::Matrix3Xd& v,
                                                const Eigen::VectorXd& inv_mass, const Eigen::Matrix3Xd& f,
                                                double dt_kick, double half_drift, double dt, std::int64_t step,
                                                std::uint64_t substep) {
  return o_pass<true, true>(&x, v, &inv_mass, &f, dt_kick, half_drift, dt, step, substep);
}

LangevinForce::LangevinForce(const ThermostatSettings& settings, const Eigen::VectorXd& inv_mass)
    : kT_(settings.temperature),
      seed_(settings.seed),
      id_(settings.particle_id),
      friction_(settings.friction),
      inv_mass_(inv_mass) {
  if (friction_.size() != inv_mass.size())
    throw std::invalid_argument("Langevin force: " + std::to_string(friction_.size()) + " frictions for " +
                                std::to_string(inv_mass.size()) + " particles");
  if (!(kT_ >= 0.0) || !std::isfinite(kT_)) throw std::invalid_argument("Langevin force: expected kT >= 0");
}

void LangevinForce::add(const Eigen::Matrix3Xd& v, double h, std::int64_t step, std::uint64_t substep,
                        Eigen::Matrix3Xd& f, Eigen::Matrix3Xd& part) const {
  const ScopedPhase phase(Phase::thermostat);
  constexpr double kScale = 1.0 / 4294967296.0;
  // (k + ½)/2³² − ½ for the 32-bit halves k of a word: uniform on (−½, ½), variance 1/12.
  const auto centred = [](std::uint64_t k) { return (static_cast<double>(k) + 0.5) * kScale - 0.5; };
  const std::uint64_t key = noise_key(seed_, step, substep);
  parallel_blocks(v.cols(), threads_for(v.cols()), [&](std::int64_t b, std::int64_t e) {
    for (std::int64_t i = b; i < e; ++i) {
      if (inv_mass_[i] == 0.0) {  // fixed
        part.col(i).setZero();
        continue;
      }
      const double m = 1.0 / inv_mass_[i], g = friction_[i];
      const double amplitude = std::sqrt(24.0 * g * m * kT_ / h);
      const auto id = static_cast<std::uint64_t>(id_.empty() ? i : id_[i]);
      const std::uint64_t w0 = noise_word(key, 2 * id);
      const std::uint64_t w1 = noise_word(key, 2 * id + 1);
      const Eigen::Vector3d u(centred(w0 >> 32), centred(w0 & 0xffffffffULL), centred(w1 >> 32));
      part.col(i) = -g * m * v.col(i) + amplitude * u;
      f.col(i) += part.col(i);
    }
  });
}

double LangevinForce::kick_heat(const Eigen::Matrix3Xd& v, const Eigen::Matrix3Xd& part, double dt,
                                bool closing) const {
  const ScopedPhase phase(Phase::thermostat);
  const double half = closing ? -0.5 : 0.5;
  return parallel_sum(v.cols(), threads_for(v.cols()), [&](std::int64_t b, std::int64_t e) {
    double heat = 0.0;
    for (std::int64_t i = b; i < e; ++i) {
      if (inv_mass_[i] == 0.0) continue;                             // fixed
      const Eigen::Vector3d jump = dt * inv_mass_[i] * part.col(i);  // b
      heat += (jump.dot(v.col(i)) + half * jump.squaredNorm()) / inv_mass_[i];
    }
    return heat;
  });
}

namespace {

// The rescaling step's own stream, apart from any Langevin sub-step.
constexpr std::uint64_t kRescalingSubstep = 0xc5f2000000000000ULL;

// Σ_{j<n} R_j² for n independent standard normals: pairs by −2 log u (= z₀² + z₁² of Box–Muller),
// one more square when n is odd. Words 1… of the stream (word 0 gives R₁).
double sum_of_squared_normals(std::uint64_t key, int n) {
  constexpr double kScale = 1.0 / 4294967296.0;
  double sum = 0.0;
  std::uint64_t j = 1;
  for (int k = 0; k + 1 < n; k += 2) {
    const std::uint64_t w = noise_word(key, j++);
    sum += -2.0 * std::log((static_cast<double>(w >> 32) + 0.5) * kScale);
  }
  if (n % 2 == 1) {
    double z0, z1;
    normal_pair(noise_word(key, j), z0, z1);
    sum += z0 * z0;
  }
  return sum;
}

class VelocityRescaled final : public Integrator {
 public:
  VelocityRescaled(std::unique_ptr<Integrator> inner, const ThermostatSettings& t, int dof)
      : inner_(std::move(inner)), kT_(t.temperature), tau_(t.tau), seed_(t.seed), dof_(dof), processes_(t.processes) {
    if (dof_ < 1) throw std::invalid_argument("velocity rescaling needs at least one degree of freedom");
  }
  void prepare(State& s, std::ostream& log) override { inner_->prepare(s, log); }
  void step(State& s, double h) override {
    inner_->step(s, h);
    const ScopedPhase phase(Phase::thermostat);
    double local = 0.0;
    const double kinetic = exact_kinetic_energy(s, local);  // the whole system's K: one α for all
    if (!(kinetic > 0.0)) return;                           // nothing moves: no direction to rescale along
    const double c = tau_ > 0.0 ? std::exp(-h / tau_) : 0.0;
    double r1 = 0.0;
    const double a2 = rescaling_factor_squared(kinetic, 0.5 * dof_ * kT_, dof_, c, seed_, s.step, &r1);
    // The sign of α (Bussi et al., Appendix): negative only when the noise overshoots, which
    // needs a tiny K or a very short τ; it keeps the K process exact.
    const double sign = r1 + std::sqrt(c * dof_ * kinetic / ((1.0 - c) * 0.5 * dof_ * kT_)) < 0.0 ? -1.0 : 1.0;
    const double alpha = sign * std::sqrt(a2);
    parallel_blocks(s.size(), threads_for(s.size()),
                    [&](std::int64_t b, std::int64_t e) { s.v.middleCols(b, e - b) *= alpha; });
    heat_ += (a2 - 1.0) * local;  // this process's particles' K changes by the factor α²
  }
  void reset() override { inner_->reset(); }
  std::string_view method() const override { return inner_->method(); }
  double thermostat_heat() const override { return heat_ + inner_->thermostat_heat(); }
  // ½vᵀMv of the whole system, its terms added exactly (ExactSum): the same bits on any number of
  // threads and processes, so that α, which scales every velocity, is too. `local`: this process's
  // particles' share.
  double exact_kinetic_energy(const State& s, double& local) const {
    const int parts = threads_for(s.size());
    std::array<ExactSum, kMaxParts> part{};
    run_parts(parts, [&](int u) {
      for (std::int64_t i = block_begin(s.size(), parts, u); i < block_begin(s.size(), parts, u + 1); ++i)
        if (s.inv_mass[i] > 0.0) part[u].add(0.5 * s.v.col(i).squaredNorm() / s.inv_mass[i]);
    });
    ExactSum total;
    for (int u = 0; u < parts; ++u) total.add(part[u]);
    local = total.value();
    if (processes_) {
      std::int64_t words[3] = {total.whole, total.high, total.low};
      processes_->sum(words, 3);
      total = {words[0], words[1], words[2]};
    }
    return total.value();
  }
  double model_potential(const Eigen::Matrix3Xd& x) override { return inner_->model_potential(x); }
  double constraint_virial(const State& s) override { return inner_->constraint_virial(s); }
  double kinetic_energy_estimate(const State& s) const override { return inner_->kinetic_energy_estimate(s); }
  std::vector<double> invariants() const override { return inner_->invariants(); }
  void set_invariants(const std::vector<double>& w) override { inner_->set_invariants(w); }
  // The inner method's words, then the rescaling's heat.
  std::vector<double> save_state() const override {
    std::vector<double> w = inner_->save_state();
    w.push_back(heat_);
    return w;
  }
  // The heat is a sum over particles (each process its share): the last of the sums.
  CarriedState carried_state() const override {
    CarriedState c = inner_->carried_state();
    c.sums.push_back(heat_);
    return c;
  }
  void restore_carried_state(CarriedState c) override {
    if (c.sums.empty()) throw std::invalid_argument("velocity rescaling: carried state without its heat");
    heat_ = c.sums.back();
    c.sums.pop_back();
    inner_->restore_carried_state(std::move(c));
  }
  void load_state(const std::vector<double>& s) override {
    if (s.empty()) throw std::invalid_argument("the checkpoint holds no velocity-rescaling state");
    inner_->load_state(std::vector<double>(s.begin(), s.end() - 1));
    heat_ = s.back();
  }

 private:
  std::unique_ptr<Integrator> inner_;
  double heat_ = 0.0;  // Σ (α² − 1) K of this process's particles over the steps: the heat put in
  double kT_, tau_;
  std::uint64_t seed_;
  int dof_;
  const Communicator* processes_;
};

}  // namespace

double rescaling_factor_squared(double kinetic, double target_kinetic, int dof, double c, std::uint64_t seed,
                                std::int64_t step, double* r1_out) {
  const std::uint64_t key = noise_key(seed, step, kRescalingSubstep);
  double r1, unused;
  normal_pair(noise_word(key, 0), r1, unused);
  if (r1_out) *r1_out = r1;
  const double ratio = target_kinetic / (dof * kinetic);
  // Bussi et al. (A7): α² = c + (1−c)(R₁² + Σ_{i=2}^{N_f} R_i²) K̄/(N_f K) + 2 R₁ √(c(1−c) K̄/(N_f K)).
  return c + (1.0 - c) * (r1 * r1 + sum_of_squared_normals(key, dof - 1)) * ratio +
         2.0 * r1 * std::sqrt(c * (1.0 - c) * ratio);
}

std::unique_ptr<Integrator> with_velocity_rescaling(std::unique_ptr<Integrator> inner,
                                                    const ThermostatSettings& settings, int dof) {
  return std::make_unique<VelocityRescaled>(std::move(inner), settings, dof);
}

std::optional<UnevenFriction> uneven_friction_in_cluster(const std::vector<ConstraintCluster>& clusters,
                                                         const Eigen::VectorXd& inv_mass,
                                                         const Eigen::VectorXd& friction) {
  std::optional<UnevenFriction> first;
  for (const ConstraintCluster& c : clusters) {
    int a = -1;  // a fixed particle never moves: its friction has no effect
    for (int p : c.particles) {
      if (inv_mass[p] == 0.0) continue;
      if (a < 0) {
        a = p;
      } else if (friction[p] != friction[a] && (!first || a < first->a)) {
        first = UnevenFriction{a, p, c.particles};
        break;
      }
    }
  }
  return first;
}

}  // namespace stiffmd
