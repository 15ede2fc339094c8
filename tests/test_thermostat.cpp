// The canonical ensemble (docs/design.md §5): counter-based noise, Langevin dynamics inside
// every method, stochastic velocity rescaling, degrees of freedom, and the freely jointed trimer's
// known bond-angle laws.
//
// Statistical tolerances. Every ensemble average is a time series of per-sample means over many
// independent molecules, cut into 20 blocks each much longer than the correlation time (1/γ = 1
// and the rotational time ~1 at kT = 1); the standard error is the spread of the block means over
// √20. An average passes when it lies within 4 standard errors of the exact value (a Student t
// with 19 degrees of freedom exceeds 4 with probability 8e-4). Where two laws are to be told
// apart the test also asserts that 8 standard errors are below their difference, so the band
// around the right law excludes the wrong one by another 4 standard errors: the test has the
// power to fail. The runs are deterministic (counter-based noise), so a pass is reproducible.
#include <gtest/gtest.h>

#include <Eigen/LU>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <sstream>

#include "cli_support.hpp"
#include "core/errors.hpp"
#include "core/parallel.hpp"
#include "engine/observe/observables.hpp"
#include "engine/run/run.hpp"
#include "forcefields/external_terms.hpp"
#include "integrators/primitives.hpp"
#include "integrators/rattle.hpp"
#include "integrators/thermostat.hpp"
#include "test_support.hpp"

namespace stiffmd {
namespace {

namespace fs = std::filesystem;

struct Estimate {
  double mean = 0.0, se = 0.0;
};

Estimate block_estimate(const std::vector<double>& series, int blocks = 20) {
  const size_t per = series.size() / blocks;
  std::vector<double> means(blocks, 0.0);
  for (int b = 0; b < blocks; ++b) {
    for (size_t k = 0; k < per; ++k) means[b] += series[b * per + k];
    means[b] /= static_cast<double>(per);
  }
  Estimate e;
  for (double m : means) e.mean += m / blocks;
  double var = 0.0;
  for (double m : means) var += (m - e.mean) * (m - e.mean) / (blocks - 1);
  e.se = std::sqrt(var / blocks);
  return e;
}

// ⟨c²⟩ for a density ∝ w(c) on [−1, 1], by Simpson's rule.
template <class W>
double mean_c2(W w) {
  const int n = 20000;
  double num = 0.0, den = 0.0;
  for (int k = 0; k <= n; ++k) {
    const double c = -1.0 + 2.0 * k / n, weight = (k == 0 || k == n) ? 1.0 : (k % 2 ? 4.0 : 2.0);
    num += weight * c * c * w(c);
    den += weight * w(c);
  }
  return num / den;
}

// Kolmogorov–Smirnov test of standard-normal samples: the p-value (asymptotic distribution with
// Stephens' small-sample correction).
double ks_normal_p_value(std::vector<double> z) {
  std::sort(z.begin(), z.end());
  const double n = static_cast<double>(z.size());
  double d = 0.0;
  for (size_t k = 0; k < z.size(); ++k) {
    const double f = 0.5 * std::erfc(-z[k] / std::sqrt(2.0));
    d = std::max({d, f - k / n, (k + 1) / n - f});
  }
  const double lambda = (std::sqrt(n) + 0.12 + 0.11 / std::sqrt(n)) * d;
  double p = 0.0;
  for (int j = 1; j <= 100; ++j) p += 2.0 * (j % 2 ? 1.0 : -1.0) * std::exp(-2.0 * j * j * lambda * lambda);
  return std::clamp(p, 0.0, 1.0);
}

// A gas of `trimers` freely jointed trimers (beads 3t, 3t+1, 3t+2; two stiff springs of length 1,
// α = 1, ε = 0.1), no other forces, and a thermostat at kT = 1.
std::string trimer_deck(int trimers, const std::string& thermostat, double eps = 0.1) {
  std::ostringstream d;
  d << "[box]\nlengths = [60, 60, 60]\nperiodic = true\n[types.bead]\nmass = 1.0\n"
    << "[[build]]\nstyle = \"linear-chains\"\ntype = \"bead\"\nchains = " << trimers
    << "\nbeads = 3\nbond_length = 1.0\nbond_type = \"b\"\nmin_distance = 0.0\nseed = 3\n"
    << "[velocities]\ntemperature = 1.0\nseed = 4\n"
    << "[forces.bonds]\nstyle = \"stiff-harmonic\"\nlevel = \"fast\"\nepsilon = " << eps << "\n"
    << "bond_types.b = { length = 1.0, alpha = 1.0 }\n"
    << thermostat << "[integrator]\nmethod = \"velocity-verlet\"\nh = 0.01\n[run]\nt_end = 1\n";
  return d.str();
}

const std::string kLangevin = "[thermostat]\nstyle = \"langevin\"\ntemperature = 1.0\ndamp = 1.0\nseed = 5\n";

Scene load_text(const std::string& text, const std::vector<std::string>& overrides) {
  static int counter = 0;
  const fs::path d = test::scratch_dir("thermostat_" + std::to_string(counter++));
  std::ofstream(d / "deck.toml") << text;
  const Deck deck((d / "deck.toml").string(), overrides);
  Scene sc = load_scene(deck);
  fs::remove_all(d);
  return sc;
}

struct TrimerRun {
  std::vector<double> c2;                   // per sample: mean over trimers of cos²θ
  std::vector<double> temperature;          // per sample: the thermo column (the integrator's kinetic estimate)
  std::vector<double> on_step_temperature;  // per sample: 2K/dof of the state's (on-step) velocities
  std::vector<double> pressure;             // per sample: the thermo column
  double volume = 0.0;
  std::vector<double> cm_velocity;    // centre-of-mass velocity components / √(kT/M), every 5th sample
  std::vector<double> atom_velocity;  // bead velocity components / √(kT/m), every 5th sample
  int dof = 0;
};

// Runs `method` with the given step (and micro step) on the trimer gas, end beads of mass m_end
// and middle beads of mass 1: 10 time units to equilibrate, then `t_run` sampled every 0.5.
TrimerRun run_trimers(const std::string& method, double h, int micro_steps, double m_end, double t_run,
                      const std::string& thermostat = kLangevin, int trimers = 200, double eps = 0.1) {
  // run.t_end only has to be a whole number of steps: this loop steps the integrator itself.
  std::vector<std::string> o = {"integrator.method=" + method, "integrator.h=" + test::exact(h),
                                "run.t_end=" + test::exact(100 * h)};
  if (micro_steps > 1) o.push_back("integrator.micro_steps=" + std::to_string(micro_steps));
  Scene sc = load_text(trimer_deck(trimers, thermostat, eps), o);
  State& s = sc.state;
  for (int t = 0; t < trimers; ++t) s.inv_mass[3 * t] = s.inv_mass[3 * t + 2] = 1.0 / m_end;
  auto integ = make_integrator(sc.integrator, *sc.forces, s.inv_mass);
  std::ostringstream log;
  integ->prepare(s, log);
  ObservableSettings obs;
  obs.thermostat = sc.integrator.thermostat.style;
  if (find_method(method)->rigid_constraints) obs.rigid_constraints = 2 * trimers;
  Thermo thermo(*sc.forces, s.inv_mass, obs);
  const int temperature = thermo.column("temperature"), pressure = thermo.column("pressure");
  EXPECT_GE(pressure, 0) << "the trimer box is periodic: a pressure column";
  TrimerRun r;
  r.volume = sc.forces->box().lengths.prod();
  r.dof = thermo.degrees_of_freedom();
  const auto every = static_cast<std::int64_t>(std::llround(0.5 / h));
  const auto burn_in = static_cast<std::int64_t>(std::llround(10.0 / h));
  const auto total = burn_in + static_cast<std::int64_t>(std::llround(t_run / h));
  const double kT = sc.integrator.thermostat.temperature;
  for (std::int64_t k = 1; k <= total; ++k) {
    integ->step(s, h);
    s.step = k;
    if (k <= burn_in || (k - burn_in) % every != 0) continue;
    double c2 = 0.0;
    for (int t = 0; t < trimers; ++t) {
      const Eigen::Vector3d a = s.x.col(3 * t) - s.x.col(3 * t + 1), b = s.x.col(3 * t + 2) - s.x.col(3 * t + 1);
      const double c = a.dot(b) / (a.norm() * b.norm());
      c2 += c * c / trimers;
    }
    r.c2.push_back(c2);
    const auto& row =
        thermo.sample(s, integ->model_potential(s.x), integ->constraint_virial(s), integ->kinetic_energy_estimate(s));
    r.temperature.push_back(row[temperature]);
    r.pressure.push_back(row[pressure]);
    r.on_step_temperature.push_back(2.0 * s.kinetic_energy() / r.dof);
    if (r.c2.size() % 5 != 0) continue;  // velocities: samples 2.5 time units (2.5/γ) apart
    for (int t = 0; t < trimers; ++t) {
      const double mass = 2 * m_end + 1;
      const Eigen::Vector3d p = m_end * (s.v.col(3 * t) + s.v.col(3 * t + 2)) + s.v.col(3 * t + 1);
      for (int a = 0; a < 3; ++a) r.cm_velocity.push_back(p[a] / std::sqrt(kT * mass));
      for (int i = 3 * t; i < 3 * t + 3; ++i)
        for (int a = 0; a < 3; ++a) r.atom_velocity.push_back(s.v(a, i) * std::sqrt(1.0 / (s.inv_mass[i] * kT)));
    }
  }
  return r;
}

// The two laws of the bond angle c = cos θ (docs/design.md §5) for end masses m_end, middle mass 1:
// stiff springs uniform in c (any masses, any ε), rigid bonds ∝ √det S(c) with
// S = [[1/m_end + 1, c], [c, 1 + 1/m_end]].
const double kStiffC2 = 1.0 / 3.0;
double rigid_c2(double m_end) {
  const double d = 1.0 / m_end + 1.0;
  return mean_c2([&](double c) { return std::sqrt(d * d - c * c); });
}

void expect_law(const std::string& what, const Estimate& e, double expected, double other) {
  ::testing::Test::RecordProperty(what, std::to_string(e.mean) + " +- " + std::to_string(e.se));
  EXPECT_NEAR(e.mean, expected, 4 * e.se) << what << ": <cos^2> = " << e.mean << " +- " << e.se;
  EXPECT_LT(8 * e.se, std::abs(expected - other)) << what << ": the run cannot tell the two laws apart";
}

void expect_temperature(const std::string& what, const TrimerRun& r) {
  const Estimate t = block_estimate(r.temperature);
  ::testing::Test::RecordProperty(what + "_T", std::to_string(t.mean) + " +- " + std::to_string(t.se));
  EXPECT_NEAR(t.mean, 1.0, 4 * t.se) << what << ": T = " << t.mean << " +- " << t.se << " (dof " << r.dof << ")";
}

// ---- counter-based noise ----------------------------------------------------------------------

TEST(CounterNoise, IsStandardNormalAndIndependentOfNeighbouringCounters) {
  // Normals of consecutive particles, steps and sub-steps: mean 0, variance 1, no correlation
  // between neighbours in any counter, and a Kolmogorov–Smirnov p-value above 1e-3.
  std::vector<double> z;
  double lag_particle = 0.0, lag_step = 0.0;
  const int n = 20000;
  for (int i = 0; i < n; ++i) {
    const Eigen::Vector3d a = particle_noise(noise_key(7, 3, 0), i), b = particle_noise(noise_key(7, 3, 0), i + 1);
    const Eigen::Vector3d c = particle_noise(noise_key(7, 4, 0), i);
    z.insert(z.end(), {a[0], a[1], a[2]});
    lag_particle += a.dot(b) / (3.0 * n);
    lag_step += a.dot(c) / (3.0 * n);
  }
  double mean = 0.0, var = 0.0;
  for (double v : z) mean += v / z.size();
  for (double v : z) var += (v - mean) * (v - mean) / (z.size() - 1);
  const double se = 1.0 / std::sqrt(static_cast<double>(z.size()));
  EXPECT_NEAR(mean, 0.0, 4 * se);
  EXPECT_NEAR(var, 1.0, 4 * std::sqrt(2.0) * se);
  EXPECT_NEAR(lag_particle, 0.0, 4 / std::sqrt(3.0 * n));
  EXPECT_NEAR(lag_step, 0.0, 4 / std::sqrt(3.0 * n));
  const double p = ks_normal_p_value(z);
  RecordProperty("ks_p", std::to_string(p));
  EXPECT_GT(p, 1e-3);
  EXPECT_NE(noise_key(7, 3, 0), noise_key(8, 3, 0));
  EXPECT_NE(noise_key(7, 3, 1), noise_key(7, 4, 0));
}

TEST(CounterNoise, ZigguratFollowsTheNormalLawOnEveryLayerAndInTheTail) {
  // 3·10⁶ normals of consecutive particles, binned by sign and by |z| between consecutive layer
  // edges x_i (255 bins: where each layer's rectangle ends and its wedge begins) and in the tail
  // (R ≤ |z| < 4, |z| ≥ 4: the tail algorithm), 514 bins against the normal law by χ² (mean 513,
  // sd 32; fails at 5 sd); and ⟨z⁴⟩ = 3.
  const ZigguratTable& t = ziggurat_table();
  const int particles = 1000000, per_sign = ZigguratTable::kLayers + 1, bins = 2 * per_sign;
  const int n = 3 * particles;
  std::vector<double> count(bins, 0.0);
  double fourth = 0.0;
  for (int i = 0; i < particles; ++i) {
    const Eigen::Vector3d z = particle_noise(noise_key(11, 5, 0), i, t);
    for (int a = 0; a < 3; ++a) {
      const double m = std::abs(z[a]);
      int lo = 1, hi = ZigguratTable::kLayers;  // the first k ≥ 1 with x_k ≤ |z| (x decreasing, x_256 = 0)
      while (lo < hi) {
        const int mid = (lo + hi) / 2;
        if (t.x[mid] <= m)
          hi = mid;
        else
          lo = mid + 1;
      }
      // bin k − 1: x_k ≤ |z| < x_{k−1}; bin 0: R ≤ |z| < 4; bin 256: |z| ≥ 4.
      const int k = lo == 1 && m >= 4.0 ? ZigguratTable::kLayers : lo - 1;
      count[(z[a] < 0.0 ? per_sign : 0) + k] += 1.0;
      fourth += std::pow(z[a], 4) / n;
    }
  }
  auto beyond = [](double x) { return 0.5 * std::erfc(x / std::sqrt(2.0)); };  // P(z > x)
  double chi2 = 0.0, min_expected = 1e300;
  for (int b = 0; b < bins; ++b) {
    const int k = b % per_sign;
    const double p = k == ZigguratTable::kLayers ? beyond(4.0)
                     : k == 0                    ? beyond(t.x[1]) - beyond(4.0)
                                                 : beyond(t.x[k + 1]) - beyond(t.x[k]);
    const double expected = n * p;
    min_expected = std::min(min_expected, expected);
    chi2 += (count[b] - expected) * (count[b] - expected) / expected;
    if (k == 0 || k == ZigguratTable::kLayers) {  // the tail on each side, on its own (≈ 290 and 95 expected)
      EXPECT_NEAR(count[b], expected, 5 * std::sqrt(expected)) << "tail bin " << b;
    }
  }
  RecordProperty("chi2_514_bins", std::to_string(chi2));
  EXPECT_GT(min_expected, 50.0);  // every bin well filled: the statistic is χ²-distributed
  EXPECT_LT(chi2, 513.0 + 5 * std::sqrt(2.0 * 513.0))
      << "counts per sign and ziggurat layer differ from the normal law";
  EXPECT_NEAR(fourth, 3.0, 5 * std::sqrt(96.0 / n));
}

TEST(CounterNoise, LangevinStepDoesNotDependOnTheThreadCount) {
  const int n = 3 * 4096;
  ThermostatSettings t;
  t.style = ThermostatSettings::Style::langevin;
  t.temperature = 1.5;
  t.friction = Eigen::VectorXd::LinSpaced(n, 0.5, 2.0);
  Eigen::VectorXd inv_mass = Eigen::VectorXd::Constant(n, 0.5);
  inv_mass[17] = 0.0;  // fixed: stays at rest
  const Eigen::Matrix3Xd v0 = Eigen::Matrix3Xd::Random(3, n);
  auto run = [&](int threads) {
    set_max_threads(threads);
    LangevinNoise o(t, inv_mass);
    Eigen::Matrix3Xd v = v0;
    v.col(17).setZero();
    for (int k = 0; k < 3; ++k) o.apply(v, 0.01, 42 + k, 0);
    return v;
  };
  const int restore = max_threads();
  const Eigen::Matrix3Xd serial = run(1), two = run(2), three = run(3);
  set_max_threads(restore);
  EXPECT_EQ(serial, two);  // bit for bit
  EXPECT_EQ(serial, three);
  EXPECT_TRUE(serial.col(17).isZero());
}

// The O step as written per particle — v ← c v + σ ξ with ξ = particle_noise(key, id) and
// c, σ of its γ, m and dt, and ½ m|v|² before and after summed in particle order as
// kinetic_energy sums it — against LangevinNoise's runs of particles (normals of a run first,
// the rare wedge and tail draws after): the same bits of v and of both sums, with a fixed particle,
// uneven frictions and masses, and particle ids (a decomposed run's part). One thread (the sums of
// several threads are blocks added in order: LangevinStepDoesNotDependOnTheThreadCount).
TEST(CounterNoise, LangevinStepGivesTheBitsOfTheParticleByParticleFormula) {
  const int n = 3 * 4096 + 37;
  for (bool ids : {false, true}) {
    SCOPED_TRACE(ids ? "particle ids" : "indices");
    ThermostatSettings t;
    t.style = ThermostatSettings::Style::langevin;
    t.temperature = 1.5;
    t.seed = 11;
    t.friction = Eigen::VectorXd::LinSpaced(n, 0.5, 2.0);
    if (ids)
      for (int i = 0; i < n; ++i) t.particle_id.push_back(7 * static_cast<std::int64_t>(i) + 3);
    Eigen::VectorXd inv_mass = Eigen::VectorXd::LinSpaced(n, 0.25, 2.0);
    inv_mass[17] = 0.0;
    Eigen::Matrix3Xd v = Eigen::Matrix3Xd::Random(3, n);
    v.col(17).setZero();
    const double dt = 0.01;
    const std::int64_t step = 42;
    Eigen::Matrix3Xd want = v;
    double before = 0.0, after = 0.0;
    const std::uint64_t key = noise_key(t.seed, step, 1);
    for (int i = 0; i < n; ++i) {
      if (inv_mass[i] == 0.0) continue;
      const double c = std::exp(-t.friction[i] * dt);
      const double sigma = std::sqrt(-std::expm1(-2.0 * t.friction[i] * dt) * t.temperature * inv_mass[i]);
      before += 0.5 * want.col(i).squaredNorm() / inv_mass[i];
      want.col(i) = c * want.col(i) + sigma * particle_noise(key, ids ? t.particle_id[i] : i);
      after += 0.5 * want.col(i).squaredNorm() / inv_mass[i];
    }
    const test::ThreadCount tc(1);
    LangevinNoise o(t, inv_mass);
    const KineticChange got = o.apply_and_measure(v, dt, step, 1);
    EXPECT_EQ(v, want);
    EXPECT_EQ(got.before, before);
    EXPECT_EQ(got.after, after);
    EXPECT_TRUE(v.col(17).isZero());
  }
}

// The micro step whose drift holds the O step in one pass (LangevinNoise::kick_drift_o_drift, used
// by velocity Verlet with BAOAB and the impulse family's middle micro step) against its three passes
// kick_drift, the O step, drift: the same bits of x, v and the kinetic energies, 1 to 3 threads.
TEST(CounterNoise, KickDriftODriftGivesTheBitsOfItsThreePasses) {
  const int n = 3 * 4096 + 5;
  ThermostatSettings t;
  t.style = ThermostatSettings::Style::langevin;
  t.temperature = 1.2;
  t.seed = 4;
  t.friction = Eigen::VectorXd::LinSpaced(n, 0.5, 2.0);
  Eigen::VectorXd inv_mass = Eigen::VectorXd::LinSpaced(n, 0.5, 1.5);
  inv_mass[23] = 0.0;
  const Eigen::Matrix3Xd x0 = Eigen::Matrix3Xd::Random(3, n), f = 50.0 * Eigen::Matrix3Xd::Random(3, n);
  Eigen::Matrix3Xd v0 = Eigen::Matrix3Xd::Random(3, n);
  v0.col(23).setZero();
  for (int threads : {1, 2, 3}) {
    SCOPED_TRACE(testing::Message() << threads << " threads");
    const test::ThreadCount tc(threads);
    LangevinNoise plain(t, inv_mass), fused(t, inv_mass);
    Eigen::Matrix3Xd x1 = x0, v1 = v0, x2 = x0, v2 = v0;
    kick_drift(x1, v1, inv_mass, f, 0.003, 0.0025);
    const KineticChange k1 = plain.apply_and_measure(v1, 0.005, 9, 2);
    drift(x1, v1, 0.0025);
    const KineticChange k2 = fused.kick_drift_o_drift(x2, v2, inv_mass, f, 0.003, 0.0025, 0.005, 9, 2);
    EXPECT_EQ(x1, x2);
    EXPECT_EQ(v1, v2);
    EXPECT_EQ(k1.before, k2.before);
    EXPECT_EQ(k1.after, k2.after);
    EXPECT_EQ(x2.col(23), x0.col(23));  // the fixed particle stayed
    EXPECT_GT((x2 - x0).cwiseAbs().maxCoeff(), 1e-3);
  }
}

// The O step alone is an exact Ornstein–Uhlenbeck update: from v = 0, after time t the velocity
// variance is (1 − e^{−2γt}) kT/m, whatever the step it is taken in.
TEST(CounterNoise, OrnsteinUhlenbeckStepIsExactForAnyStep) {
  const int n = 20000;
  ThermostatSettings t;
  t.style = ThermostatSettings::Style::langevin;
  t.temperature = 2.0;
  t.friction = Eigen::VectorXd::Constant(n, 0.7);
  const Eigen::VectorXd inv_mass = Eigen::VectorXd::Constant(n, 0.25);
  for (int steps : {1, 10}) {
    LangevinNoise o(t, inv_mass);
    Eigen::Matrix3Xd v = Eigen::Matrix3Xd::Zero(3, n);
    for (int k = 0; k < steps; ++k) o.apply(v, 1.0 / steps, k, 0);
    const double var = v.squaredNorm() / (3.0 * n), expected = -std::expm1(-2 * 0.7) * 2.0 * 0.25;
    EXPECT_NEAR(var, expected, 4 * std::sqrt(2.0 / (3.0 * n)) * expected) << steps << " steps";
  }
}

// ---- stochastic velocity rescaling --------------------------------------------------------------

// With τ = 0 (c = 0) one rescaling draws K' = K̄ χ²_{N_f}/N_f, whatever K was: mean K̄, variance
// 2K̄²/N_f (Bussi et al. 2007, eq. (A7)).
TEST(VelocityRescaling, FactorDrawsTheCanonicalKineticEnergy) {
  const int dof = 7, n = 40000;
  const double target = 0.5 * dof * 1.3, kinetic = 5.0;
  double mean = 0.0, sq = 0.0;
  for (int k = 0; k < n; ++k) {
    const double kp = kinetic * rescaling_factor_squared(kinetic, target, dof, 0.0, 9, k);
    mean += kp / n;
    sq += kp * kp / n;
  }
  const double var = sq - mean * mean, expected_var = 2 * target * target / dof;
  EXPECT_NEAR(mean, target, 4 * std::sqrt(expected_var / n));
  EXPECT_NEAR(var, expected_var, 0.05 * expected_var);
  // c → 1 (τ ≫ h): the kinetic energy barely moves.
  EXPECT_NEAR(rescaling_factor_squared(kinetic, target, dof, 1.0 - 1e-12, 9, 3), 1.0, 1e-5);
}

// Rigid trimers without forces keep their kinetic energy between rescalings, so the rescaling
// chain alone sets K: ⟨T⟩ = 1 only if N_f is right — 3N − 3 (momentum conserved) − 2 per trimer.
// Ten trimers make the count matter: N_f = 67, and 70 (momentum not removed) would read T = 0.957.
TEST(VelocityRescaling, RigidTrimersReachTheTemperatureWithTheirDegreesOfFreedom) {
  const std::string csvr = "[thermostat]\nstyle = \"csvr\"\ntemperature = 1.0\ntau = 0.1\nseed = 6\n";
  const TrimerRun r = run_trimers("rattle", 0.02, 1, 1.0, 1000, csvr, 10);
  EXPECT_EQ(r.dof, 3 * 30 - 3 - 20);
  const Estimate t = block_estimate(r.temperature);
  RecordProperty("T", std::to_string(t.mean) + " +- " + std::to_string(t.se));
  EXPECT_NEAR(t.mean, 1.0, 4 * t.se);
  EXPECT_LT(8 * t.se, 1.0 - 67.0 / 70.0);
  // Canonical fluctuations of K: var(T) = 2T²/N_f.
  double var = 0.0;
  for (double v : r.temperature) var += (v - t.mean) * (v - t.mean) / (r.temperature.size() - 1);
  EXPECT_NEAR(var, 2.0 / r.dof, 0.25 * 2.0 / r.dof);
}

// ---- the freely jointed trimer: every method's law -----------------------------------------------

struct LawCase {
  std::string method;
  double h;
  int micro_steps;
  bool stiff_law;  // else the rigid law
  double eps = 0.1;
  std::string splitting = "baoab";
};

class TrimerLaw : public ::testing::TestWithParam<LawCase> {};

// End masses 4, middle 1: the rigid law ∝ √(1.5625 − c²) has ⟨c²⟩ = 0.2947, far enough from the
// stiff law's 1/3 for a short run to tell them apart. Velocity Verlet at h = 0.005 resolves the
// bond vibrations (hω ≤ 0.08); the impulse methods take micro steps of 0.005 (hω ≤ 0.08), an odd
// and an even number of them (the O step sits inside the middle drift or between two kicks). The
// mollifier α(x) is an O(ε) construction: at ε = 0.1 the thermal bond stretches (0.1 rms, 0.4 in
// the tails) are too large for its SHAKE projection to converge in every configuration, so the
// mollified method runs at ε = 0.05 (the stiff law holds at every ε).
TEST_P(TrimerLaw, BondAngleFollowsItsCanonicalLaw) {
  const LawCase& c = GetParam();
  const TrimerRun r = run_trimers(c.method, c.h, c.micro_steps, 4.0, 100,
                                  kLangevin + "splitting = \"" + c.splitting + "\"\n", 200, c.eps);
  const double stiff = kStiffC2, rigid = rigid_c2(4.0);
  expect_law("cos2", block_estimate(r.c2), c.stiff_law ? stiff : rigid, c.stiff_law ? rigid : stiff);
  expect_temperature(c.method, r);
  // The centre of mass moves freely under every method: Maxwell at kT/M.
  const double p_cm = ks_normal_p_value(r.cm_velocity);
  RecordProperty("ks_p_cm", std::to_string(p_cm));
  EXPECT_GT(p_cm, 1e-3);
  if (!find_method(c.method)->rigid_constraints) {  // unconstrained: each bead's velocity is Maxwell at kT/m
    const double p = ks_normal_p_value(r.atom_velocity);
    RecordProperty("ks_p_atoms", std::to_string(p));
    EXPECT_GT(p, 1e-3);
  }
}

INSTANTIATE_TEST_SUITE_P(
    Methods, TrimerLaw,
    ::testing::Values(LawCase{"velocity-verlet", 0.005, 1, true},
                      LawCase{"projected-impulse", 0.045, 9, true},  // odd n: O inside the middle drift
                      LawCase{"mollified-impulse", 0.05, 20, true, 0.05}, LawCase{"rattle", 0.02, 1, false},
                      LawCase{"fixman", 0.02, 1, true}, LawCase{"velocity-verlet", 0.005, 1, true, 0.1, "obabo"},
                      LawCase{"projected-impulse", 0.045, 9, true, 0.1, "obabo"},
                      LawCase{"rattle", 0.02, 1, false, 0.1, "obabo"}, LawCase{"fixman", 0.02, 1, true, 0.1, "obabo"}),
    [](const auto& info) {
      std::string n = info.param.method + (info.param.splitting == "baoab" ? "" : "_obabo");
      std::replace(n.begin(), n.end(), '-', '_');
      return n;
    });

// Equal masses: RATTLE's law ∝ √(1 − c²/4), ⟨c²⟩ = 0.3210 (docs/design.md §5). The laws differ by only
// 0.012 here, so this run checks the value, not the power (4 standard errors ≈ 0.006).
TEST(TrimerLaw, RattleWithEqualMassesGivesTheRigidValue) {
  const TrimerRun r = run_trimers("rattle", 0.02, 1, 1.0, 100);
  const Estimate e = block_estimate(r.c2);
  RecordProperty("cos2", std::to_string(e.mean) + " +- " + std::to_string(e.se));
  EXPECT_NEAR(rigid_c2(1.0), 0.3210, 5e-5);
  EXPECT_NEAR(e.mean, rigid_c2(1.0), 4 * e.se);
}

// Every method of the table holds kT with its own degrees of freedom (3N with stiff springs,
// 3N − bonds with rigid ones; Langevin noise does not conserve momentum), and the ideal-gas pressure.
class NvtTemperature : public ::testing::TestWithParam<std::string> {};

// The trimer gas under `thermostat` (kLangevin plus a splitting): kT over each method's degrees
// of freedom and the ideal-gas pressure. An ideal gas of 200 molecules: P = 200 kT / V whatever
// holds them together (stiff springs' virial, or the rigid constraints' with the centrifugal
// force). Missing kT per bond in the virial (e.g. half the centrifugal force) would read
// 400 kT / 3V more; the run must tell.
void expect_temperature_and_ideal_gas(const std::string& method, const std::string& splitting) {
  const MethodInfo& m = *find_method(method);
  const std::string thermostat = kLangevin + "splitting = \"" + splitting + "\"\n", what = method + "_" + splitting;
  const TrimerRun r = m.micro_steps ? run_trimers(method, 0.05, 10, 1.0, 30, thermostat)
                                    : run_trimers(method, m.rigid_constraints ? 0.02 : 0.005, 1, 1.0, 30, thermostat);
  EXPECT_EQ(r.dof, 3 * 600 - (m.rigid_constraints ? 400 : 0));
  expect_temperature(what, r);
  const Estimate p = block_estimate(r.pressure);
  const double ideal = 200.0 / r.volume, bond_kT = 400.0 / (3.0 * r.volume);
  ::testing::Test::RecordProperty(what + "_P_over_ideal",
                                  std::to_string(p.mean / ideal) + " +- " + std::to_string(p.se / ideal));
  EXPECT_NEAR(p.mean, ideal, 4 * p.se) << what << ": P V / (M kT) = " << p.mean / ideal << " +- " << p.se / ideal;
  EXPECT_LT(8 * p.se, bond_kT) << what << ": the run cannot tell a missing kT per bond";
}

TEST_P(NvtTemperature, KineticTemperatureIsT) {
  expect_temperature_and_ideal_gas(GetParam(), "baoab");
}

INSTANTIATE_TEST_SUITE_P(AllMethods, NvtTemperature, ::testing::ValuesIn(test::kAllMethods), test::method_test_name);

// The same with the OBABO splitting: the temperature (on-step velocities after the closing O step,
// projected for the constrained methods) and the ideal-gas pressure, whose constraint virial is
// the Hamiltonian step's (the projections after the O steps are not constraint forces).
TEST(NvtTemperature, ObaboHoldsTheTemperatureAndTheIdealGasPressure) {
  for (const std::string& method : test::kAllMethods) {
    SCOPED_TRACE(method);
    expect_temperature_and_ideal_gas(method, "obabo");
  }
}

// The temperature reads BAOAB's velocities at the O step (Integrator::kinetic_energy_estimate).
// At h = 0.05 the bond vibrations (ε = 0.1, hω ≈ 0.7) make the on-step velocities read
// kT(1 − (hω)²/4) in those modes (T ≈ 0.96-0.97 overall), the O-step ones kT (exactly for
// harmonic forces): the estimate holds T = 1, and the on-step reading is told apart from it.
TEST(NvtTemperature, BaoabReadsTheTemperatureAtTheOStepAtACoarseStep) {
  const TrimerRun r = run_trimers("velocity-verlet", 0.05, 1, 1.0, 400);
  expect_temperature("velocity-verlet_h0.05", r);
  const Estimate on_step = block_estimate(r.on_step_temperature);
  RecordProperty("on_step_T", std::to_string(on_step.mean) + " +- " + std::to_string(on_step.se));
  EXPECT_LT(on_step.mean + 8 * on_step.se, 1.0) << "on-step T = " << on_step.mean << " +- " << on_step.se;
}

// RATTLE plus Fixman's potential, with equal masses too (docs/design.md §5's trimer): uniform in c.
TEST(TrimerLaw, FixmanWithEqualMassesGivesTheStiffValue) {
  const TrimerRun r = run_trimers("fixman", 0.02, 1, 1.0, 100);
  const Estimate e = block_estimate(r.c2);
  RecordProperty("cos2", std::to_string(e.mean) + " +- " + std::to_string(e.se));
  EXPECT_NEAR(e.mean, kStiffC2, 4 * e.se);
}

TEST(ThermostatDeck, FixmanWithoutAThermostatIsRefusedAtTheMethodKey) {
  std::string deck = trimer_deck(2, "");
  try {
    load_text(deck, {"integrator.method=fixman"});
    ADD_FAILURE() << "fixman without [thermostat] accepted";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("integrator.method"), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("[thermostat]"), std::string::npos) << e.what();
  }
}

// ---- determinism and restarts ---------------------------------------------------------------------

// Two runs of n steps from the same state, one interrupted after n/2 steps and continued by a
// fresh integrator with the saved state (as `run --restart` does): bit for bit the same.
class NvtRestart : public ::testing::TestWithParam<std::string> {};

TEST_P(NvtRestart, ContinuesBitForBit) {
  // The force form of Langevin (splitting "lammps") carries its force in the cached kick force.
  const bool force_form = !find_method(GetParam())->rigid_constraints;
  // OBABO (splitting "obabo"): O steps around the Hamiltonian step, every method.
  for (const char* style : {"langevin", "csvr", "langevin-force", "langevin-obabo"}) {
    if (style == std::string("langevin-force") && !force_form) continue;
    SCOPED_TRACE(style);
    const std::string thermostat = std::string("[thermostat]\nstyle = \"") + (style[0] == 'l' ? "langevin" : style) +
                                   "\"\ntemperature = 1.0\n" + (style[0] == 'l' ? "damp = 1.0\n" : "tau = 0.1\n") +
                                   "seed = 5\n" +
                                   (style == std::string("langevin-force")   ? "splitting = \"lammps\"\n"
                                    : style == std::string("langevin-obabo") ? "splitting = \"obabo\"\n"
                                                                             : "");
    Scene sc = load_text(trimer_deck(20, thermostat),
                         {"integrator.method=" + GetParam(), "integrator.h=0.01", "integrator.micro_steps=3"});
    auto first = make_integrator(sc.integrator, *sc.forces, sc.state.inv_mass);
    std::ostringstream log;
    State a = sc.state, b = sc.state;
    first->prepare(a, log);
    for (std::int64_t k = 1; k <= 40; ++k) first->step(a, 0.01), a.step = k;
    auto integ = make_integrator(sc.integrator, *sc.forces, sc.state.inv_mass);
    integ->prepare(b, log);
    for (std::int64_t k = 1; k <= 20; ++k) integ->step(b, 0.01), b.step = k;
    auto resumed = make_integrator(sc.integrator, *sc.forces, sc.state.inv_mass);
    resumed->load_state(integ->save_state());
    for (std::int64_t k = 21; k <= 40; ++k) resumed->step(b, 0.01), b.step = k;
    EXPECT_EQ(a.x, b.x);
    EXPECT_EQ(a.v, b.v);
    EXPECT_NE(a.v, sc.state.v);
    // The temperature's kinetic energy (the O step's under Langevin) is part of the saved state,
    // and so is the thermostat's heat.
    EXPECT_EQ(first->kinetic_energy_estimate(a), resumed->kinetic_energy_estimate(b));
    EXPECT_EQ(first->thermostat_heat(), resumed->thermostat_heat());
    EXPECT_NE(first->thermostat_heat(), 0.0);
    auto fresh = make_integrator(sc.integrator, *sc.forces, sc.state.inv_mass);
    fresh->load_state(resumed->save_state());
    EXPECT_EQ(fresh->kinetic_energy_estimate(b), resumed->kinetic_energy_estimate(b));
  }
}

INSTANTIATE_TEST_SUITE_P(AllMethods, NvtRestart, ::testing::ValuesIn(test::kAllMethods), test::method_test_name);

// ---- the energy conserved with the thermostat's heat (docs/design.md §5) ---------------------------

// E_c = E + ecouple, ecouple = −(the heat the thermostat put in), changes only by the Hamiltonian
// step's error: its excursion max_t |E_c(t) − E_c(0)| falls like h² for a second-order method (its
// mean drift like h², its random walk like h^{3/2}), while E itself moves with the heat. A heat
// measured off the velocities the step continues from (under constraints: K of the chord velocity
// itself, not of its projection) leaves an error of O(h²) per step, which falls only like h (and
// OBABO's unprojected O step an error that does not fall at all).
struct ConservedCase {
  const char* name;
  const char* method;
  double h, micro_dt;  // micro_dt 0: none (the impulse family: halved with h)
  const char* thermostat;
};

void PrintTo(const ConservedCase& c, std::ostream* os) {
  *os << c.name;
}

std::string langevin_splitting(const char* splitting) {
  return kLangevin + "splitting = \"" + splitting + "\"\n";
}

struct ConservedEnergy {
  double error = 0.0;   // max |E_c(t) − E_c(0)| over the thermo samples
  double spread = 0.0;  // the standard deviation of E over them
};

// 200 trimers (stiff springs, ε = 0.1, no other force) for 20 time units, a sample every 0.2.
ConservedEnergy conserved_energy(const ConservedCase& c, double h, double micro_dt, const std::string& name) {
  std::vector<std::string> o = {std::string("integrator.method=") + c.method, "integrator.h=" + test::exact(h),
                                "run.t_end=20"};
  if (micro_dt > 0.0) o.push_back("integrator.micro_dt=" + test::exact(micro_dt));
  const std::string thermostat = c.thermostat == std::string("csvr")
                                     ? "[thermostat]\nstyle = \"csvr\"\ntemperature = 1.0\ntau = 0.5\nseed = 5\n"
                                     : langevin_splitting(c.thermostat);
  Scene sc = load_text(trimer_deck(200, thermostat) + "[output]\nxyz = \"\"\nthermo_interval = 0.2\n", o);
  const fs::path dir = test::scratch_dir("conserved_" + name);
  std::ostringstream log;
  RunOptions options;
  options.out_dir = dir.string();
  options.handle_signals = false;
  run_simulation(sc, options, log);
  const test::CsvTable t = test::read_csv((dir / "thermo.csv").string());
  fs::remove_all(dir);
  const size_t ec = t.col("econserve"), total = t.col("total"), ecouple = t.col("ecouple");
  ConservedEnergy r;
  double mean = 0.0, square = 0.0;
  for (const auto& row : t.rows) {
    EXPECT_NEAR(row[ec], row[total] + row[ecouple], 1e-10 * std::abs(row[total]));  // the CSV's 12 digits
    r.error = std::max(r.error, std::abs(row[ec] - t.rows.front()[ec]));
    mean += row[total] / t.rows.size();
    square += row[total] * row[total] / t.rows.size();
  }
  r.spread = std::sqrt(std::max(square - mean * mean, 0.0));
  return r;
}

class ConservedEnergyDrift : public ::testing::TestWithParam<ConservedCase> {};

TEST_P(ConservedEnergyDrift, IsTheStepsErrorAndFallsLikeHSquared) {
  const ConservedCase& c = GetParam();
  const ConservedEnergy coarse = conserved_energy(c, c.h, c.micro_dt, std::string(c.name) + "_h");
  const ConservedEnergy fine = conserved_energy(c, c.h / 2, c.micro_dt / 2, std::string(c.name) + "_h2");
  ::testing::Test::RecordProperty("error_h", std::to_string(coarse.error));
  ::testing::Test::RecordProperty("error_h2", std::to_string(fine.error));
  // h² gives 4, its random walk 2^{3/2} = 2.8 (measured 3.6–6.6); a heat off by O(h²) per step, 2.
  EXPECT_GT(coarse.error, 3.0 * fine.error) << "h = " << c.h << ": " << coarse.error << ", h/2: " << fine.error;
  // The thermostat's heat moves E by hundreds of times more (measured 200–2000).
  EXPECT_LT(fine.error, 0.01 * fine.spread) << "spread of E " << fine.spread;
}

// Every way a thermostat changes velocities: the O step of BAOAB (velocity Verlet, BAOAB-RESPA,
// constrained BAOAB), of OBABO (unprojected before SHAKE under constraints), the Langevin force of
// the lammps splitting, csvr's rescaling. Not the effective dynamics: its W = Σ I_k ω_k has a kink
// where a trimer's two frequencies cross (cos θ = 0), so its energy error is O(h) even without a
// thermostat (ratio 2.9 per halving in NVE).
INSTANTIATE_TEST_SUITE_P(Trimers, ConservedEnergyDrift,
                         ::testing::Values(ConservedCase{"vv_baoab", "velocity-verlet", 0.01, 0.0, "baoab"},
                                           ConservedCase{"vv_lammps", "velocity-verlet", 0.01, 0.0, "lammps"},
                                           ConservedCase{"vv_obabo", "velocity-verlet", 0.01, 0.0, "obabo"},
                                           ConservedCase{"vv_csvr", "velocity-verlet", 0.01, 0.0, "csvr"},
                                           ConservedCase{"impulse_baoab", "impulse", 0.05, 0.005, "baoab"},
                                           ConservedCase{"impulse_lammps", "impulse", 0.05, 0.005, "lammps"},
                                           ConservedCase{"projected_obabo", "projected-impulse", 0.05, 0.005, "obabo"},
                                           ConservedCase{"rattle_baoab", "rattle", 0.05, 0.0, "baoab"},
                                           ConservedCase{"rattle_obabo", "rattle", 0.05, 0.0, "obabo"},
                                           ConservedCase{"rattle_csvr", "rattle", 0.05, 0.0, "csvr"},
                                           ConservedCase{"fixman_baoab", "fixman", 0.05, 0.0, "baoab"},
                                           ConservedCase{"fixman_obabo", "fixman", 0.05, 0.0, "obabo"},
                                           ConservedCase{"fixman_csvr", "fixman", 0.05, 0.0, "csvr"}),
                         [](const ::testing::TestParamInfo<ConservedCase>& info) {
                           return std::string(info.param.name);
                         });

// ---- the Langevin splittings on harmonic oscillators -----------------------------------------------

// Any linear splitting of Langevin dynamics for a harmonic force f = −k x is a linear map of its
// state z plus noise, z' = A z + b ξ, so its stationary covariance solves the discrete Lyapunov
// equation Σ = A Σ Aᵀ + b bᵀ exactly at any h (solved here by iterating it: A is a contraction).
// The map is composed from the sub-steps, each a matrix on the state extended by the step's ξ.
// Mass m, spring k, friction γ, step h, kT; returns (⟨x²⟩ k/kT, ⟨v²⟩ m/kT) on step.
struct Oscillator {
  double m, k, gamma, h, kT;
};

template <int N>
Eigen::Vector2d stationary_variances(const Eigen::Matrix<double, N + 1, N + 1>& one_step, const Oscillator& o) {
  const Eigen::Matrix<double, N, N> A = one_step.template topLeftCorner<N, N>();
  const Eigen::Matrix<double, N, 1> b = one_step.template topRightCorner<N, 1>();
  Eigen::Matrix<double, N, N> sigma = Eigen::Matrix<double, N, N>::Zero();
  for (int it = 0; it < 100000; ++it) {
    const Eigen::Matrix<double, N, N> next = A * sigma * A.transpose() + b * b.transpose();
    const bool converged = (next - sigma).cwiseAbs().maxCoeff() < 1e-15;
    sigma = next;
    if (converged) break;
  }
  return {sigma(0, 0) * o.k / o.kT, sigma(1, 1) * o.m / o.kT};
}

// The Langevin force inside velocity Verlet (LAMMPS's fix nve + fix langevin) on (x, v, F | ξ):
// v += ½h F/m; x += h v; F = −k x − γ m v + √(2γ m kT/h) ξ; v += ½h F/m. Only ξ's variance enters
// (uniform or Gaussian alike).
Eigen::Vector2d force_form_variances(const Oscillator& o) {
  using M4 = Eigen::Matrix4d;
  M4 half_kick = M4::Identity(), drift = M4::Identity(), force = M4::Identity();
  half_kick(1, 2) = 0.5 * o.h / o.m;
  drift(0, 1) = o.h;
  force.row(2) << -o.k, -o.gamma * o.m, 0.0, std::sqrt(2.0 * o.gamma * o.m * o.kT / o.h);
  return stationary_variances<3>(half_kick * force * drift * half_kick, o);
}

// (⟨x²⟩ k/kT, ⟨v²⟩ m/kT, ⟨v_{n+1} v_n⟩ m/kT) on step for the splitting `obabo` (else BAOAB) of an
// oscillator of mass m, spring k. The lag-one covariance (A Σ)_vv depends on the friction and on where the O
// steps sit, which the stationary law alone does not tell.
Eigen::Vector3d oscillator_variances(const Oscillator& o, bool obabo) {
  using M2 = Eigen::Matrix2d;
  auto half_kick = [&](double dt) {
    M2 B = M2::Identity();
    B(1, 0) = -dt * o.k / o.m;
    return B;
  };
  auto drift = [&](double dt) {
    M2 A = M2::Identity();
    A(0, 1) = dt;
    return A;
  };
  auto o_step = [&](double dt, M2& map, Eigen::Vector2d& noise) {
    const double c = std::exp(-o.gamma * dt);
    map = M2::Identity();
    map(1, 1) = c;
    noise = Eigen::Vector2d(0.0, std::sqrt((1.0 - c * c) * o.kT / o.m));
  };
  M2 step, O1, O2;
  Eigen::Vector2d b1, b2;
  M2 noise_cov;
  if (obabo) {
    o_step(0.5 * o.h, O1, b1);
    o_step(0.5 * o.h, O2, b2);
    const M2 after_first = O2 * half_kick(0.5 * o.h) * drift(o.h) * half_kick(0.5 * o.h);
    step = after_first * O1;
    noise_cov = (after_first * b1) * (after_first * b1).transpose() + b2 * b2.transpose();
  } else {
    o_step(o.h, O1, b1);
    const M2 after = half_kick(0.5 * o.h) * drift(0.5 * o.h);
    step = after * O1 * drift(0.5 * o.h) * half_kick(0.5 * o.h);
    noise_cov = (after * b1) * (after * b1).transpose();
  }
  // Σ = A Σ Aᵀ + Q solved directly: (I − A ⊗ A) vec Σ = vec Q.
  Eigen::Matrix4d kron;
  for (int i = 0; i < 2; ++i)
    for (int j = 0; j < 2; ++j) kron.block<2, 2>(2 * j, 2 * i) = step(j, i) * step;
  const Eigen::Vector4d vec_q(noise_cov(0, 0), noise_cov(1, 0), noise_cov(0, 1), noise_cov(1, 1));
  const Eigen::Vector4d vec_sigma = (Eigen::Matrix4d::Identity() - kron).partialPivLu().solve(vec_q);
  const M2 sigma = Eigen::Map<const M2>(vec_sigma.data());
  return {sigma(0, 0) * o.k / o.kT, sigma(1, 1) * o.m / o.kT, (step * sigma)(1, 1) * o.m / o.kT};
}

// 1000 particles of mass 2, each tied by a harmonic tether (k = 50: ω = 5) to its own point — 3000
// independent oscillators —, Langevin γ = 1, kT = 1, h = 0.1 (hω = 0.5, γh = 0.1). The averages of
// x² and v² over the oscillators, sampled every step over 100 time units after 20, are compared
// with the exact finite-h values of the splitting the engine runs. At this step BAOAB's ⟨x²⟩ is
// kT/k (exactly, for any h) and its on-step ⟨v²⟩ kT/m (1 − (hω)²/4) = 0.9375, while the force
// form's ⟨v²⟩ is kT/m and its ⟨x²⟩ is ≈ 1.1 kT/k: the test also asserts that both differences are
// above 8 standard errors, so each splitting's run excludes the other's exact values.
class LangevinSplitting : public ::testing::TestWithParam<std::string> {};

TEST_P(LangevinSplitting, HarmonicOscillatorsSampleTheirExactFiniteStepVariances) {
  const Oscillator o{2.0, 50.0, 1.0, 0.1, 1.0};
  const int n = 1000;
  Box box;  // open: the tethers' separations are plain differences
  ForceField forces(box, n);
  std::vector<int> all(n);
  for (int i = 0; i < n; ++i) all[i] = i;
  forces.add(std::make_unique<HarmonicTether>("tether", Level::slow, all, Eigen::Vector3d::Zero(), o.k));
  State s;
  s.x = Eigen::Matrix3Xd::Zero(3, n);
  s.v = Eigen::Matrix3Xd::Zero(3, n);
  s.inv_mass = Eigen::VectorXd::Constant(n, 1.0 / o.m);
  IntegratorSettings settings;
  settings.h = o.h;
  settings.thermostat.style = ThermostatSettings::Style::langevin;
  settings.thermostat.temperature = o.kT;
  settings.thermostat.friction = Eigen::VectorXd::Constant(n, o.gamma);
  settings.thermostat.seed = 17;
  const bool lammps = GetParam() == "lammps", obabo = GetParam() == "obabo";
  settings.thermostat.splitting = lammps  ? ThermostatSettings::Splitting::lammps
                                  : obabo ? ThermostatSettings::Splitting::obabo
                                          : ThermostatSettings::Splitting::baoab;
  auto integ = make_integrator(settings, forces, s.inv_mass);
  std::vector<double> x2, v2, v_lag;
  Eigen::Matrix3Xd v_before = s.v;
  for (std::int64_t k = 1; k <= 1200; ++k) {
    integ->step(s, o.h);
    s.step = k;
    const double lag = (s.v.array() * v_before.array()).sum();
    v_before = s.v;
    if (k <= 200) continue;
    x2.push_back(s.x.squaredNorm() * o.k / (3.0 * n * o.kT));
    v2.push_back(s.v.squaredNorm() * o.m / (3.0 * n * o.kT));
    v_lag.push_back(lag * o.m / (3.0 * n * o.kT));
    // The thermo's temperature reads the on-step velocities in the force form (no O step) and
    // in OBABO (after its closing O step).
    if (lammps || obabo) {
      ASSERT_EQ(integ->kinetic_energy_estimate(s), s.kinetic_energy());
    }
  }
  const Estimate ex = block_estimate(x2), ev = block_estimate(v2);
  const Eigen::Vector2d baoab = oscillator_variances(o, false).head<2>(), force = force_form_variances(o);
  const Eigen::Vector2d obabo_exact = oscillator_variances(o, true).head<2>();
  const Eigen::Vector2d exact = lammps ? force : obabo ? obabo_exact : baoab;
  EXPECT_NEAR(baoab[0], 1.0, 1e-12) << "BAOAB samples x exactly for harmonic forces";
  EXPECT_NEAR(baoab[1], 1.0 - 0.25 * o.h * o.h * o.k / o.m, 1e-12);
  RecordProperty("x2", std::to_string(ex.mean) + " +- " + std::to_string(ex.se) + " exact " + std::to_string(exact[0]));
  RecordProperty("v2", std::to_string(ev.mean) + " +- " + std::to_string(ev.se) + " exact " + std::to_string(exact[1]));
  EXPECT_NEAR(ex.mean, exact[0], 4 * ex.se) << "k<x^2>/kT = " << ex.mean << " +- " << ex.se;
  EXPECT_NEAR(ev.mean, exact[1], 4 * ev.se) << "m<v^2>/kT = " << ev.mean << " +- " << ev.se;
  EXPECT_LT(8 * ex.se, std::abs(force[0] - baoab[0])) << "the run cannot tell the splittings' <x^2> apart";
  EXPECT_LT(8 * ev.se, std::abs(force[1] - baoab[1])) << "the run cannot tell the splittings' <v^2> apart";
  EXPECT_LT(8 * ex.se, std::abs(obabo_exact[0] - baoab[0])) << "the run cannot tell BAOAB's <x^2> from OBABO's";
  // The O steps' splittings: the lag-one covariance of v, which the friction and the O steps'
  // places set (the stationary law does not tell a wrong friction).
  if (!lammps) {
    const Estimate el = block_estimate(v_lag);
    const double lag_exact = oscillator_variances(o, obabo)[2];
    Oscillator half = o;
    half.gamma *= 0.5;
    RecordProperty("v_lag",
                   std::to_string(el.mean) + " +- " + std::to_string(el.se) + " exact " + std::to_string(lag_exact));
    EXPECT_NEAR(el.mean, lag_exact, 4 * el.se) << "m<v_n+1 v_n>/kT = " << el.mean << " +- " << el.se;
    EXPECT_LT(8 * el.se, std::abs(lag_exact - oscillator_variances(half, obabo)[2]))
        << "the run cannot tell the friction apart";
  }
}

INSTANTIATE_TEST_SUITE_P(Splittings, LangevinSplitting, ::testing::Values("baoab", "lammps", "obabo"));

const std::string kLangevinForce =
    "[thermostat]\nstyle = \"langevin\"\ntemperature = 1.0\ndamp = 1.0\nseed = 5\nsplitting = \"lammps\"\n";

// The force form holds T (on-step velocities) on the trimer gas, with velocity Verlet and with the
// impulse family (the force on the slow kick, as LAMMPS's on the outermost r-RESPA level), and
// velocity Verlet at a small step samples the stiff law of the bond angle.
TEST(LangevinSplitting, ForceFormHoldsTheTemperatureAndTheStiffLaw) {
  const TrimerRun vv = run_trimers("velocity-verlet", 0.005, 1, 4.0, 100, kLangevinForce);
  expect_temperature("velocity-verlet_lammps", vv);
  expect_law("velocity-verlet_lammps", block_estimate(vv.c2), kStiffC2, rigid_c2(4.0));
  for (const char* method : {"impulse", "projected-impulse"}) {
    SCOPED_TRACE(method);
    expect_temperature(std::string(method) + "_lammps", run_trimers(method, 0.05, 10, 1.0, 30, kLangevinForce));
  }
}

// A small Kremer–Grest melt (20 chains of 20, density 0.85, FENE + WCA as in.chain) at in.chain's
// step under the force form: the thermo's temperature (on-step velocities, 3N) is T.
TEST(LangevinSplitting, ForceFormHoldsTheTemperatureOfAKremerGrestMelt) {
  const std::string deck =
      "[types.bead]\nmass = 1.0\n"
      "[[build]]\nstyle = \"linear-chains\"\ntype = \"bead\"\nchains = 20\nbeads = 20\nbond_length = 0.97\n"
      "bond_type = \"fene\"\ndensity = 0.85\nmin_distance = 0.9\nseed = 3\n"
      "[velocities]\ntemperature = 1.0\nseed = 4\n"
      "[forces.fene]\nstyle = \"fene\"\nbond_types.fene = { K = 30.0, R0 = 1.5, epsilon = 1.0, sigma = 1.0 }\n"
      "[forces.lj]\nstyle = \"lj\"\nepsilon = 1.0\nsigma = 1.0\ncutoff = 1.12\nspecial_bonds = [0.0, 1.0]\n"
      "skin = 0.4\n" +
      kLangevinForce + "[integrator]\nmethod = \"velocity-verlet\"\nh = 0.012\n[run]\nt_end = 1.2\n";
  Scene sc = load_text(deck, {});
  State& s = sc.state;
  auto integ = make_integrator(sc.integrator, *sc.forces, s.inv_mass);
  ObservableSettings obs;
  obs.thermostat = sc.integrator.thermostat.style;
  Thermo thermo(*sc.forces, s.inv_mass, obs);
  const int temperature = thermo.column("temperature");
  EXPECT_EQ(thermo.degrees_of_freedom(), 3 * 400);
  std::vector<double> t;
  for (std::int64_t k = 1; k <= 6000; ++k) {  // 12 time units (12/γ) to equilibrate, then 60 sampled
    integ->step(s, 0.012);
    s.step = k;
    if (k <= 1000 || k % 10 != 0) continue;
    t.push_back(thermo.sample(s, 0.0, 0.0, integ->kinetic_energy_estimate(s))[temperature]);
  }
  const Estimate e = block_estimate(t);
  RecordProperty("T", std::to_string(e.mean) + " +- " + std::to_string(e.se));
  EXPECT_NEAR(e.mean, 1.0, 4 * e.se) << "T = " << e.mean << " +- " << e.se;
  EXPECT_LT(e.se, 0.01);
}

// ---- the deck -------------------------------------------------------------------------------------

TEST(ThermostatDeck, DampIsOneOverFrictionAndScalesPerType) {
  std::string deck = trimer_deck(2,
                                 "[thermostat]\nstyle = \"langevin\"\ntemperature = 1.5\ndamp = 4.0\nseed = 5\n"
                                 "[thermostat.scale]\nbead = 2.0\n");
  const Scene sc = load_text(deck, {});
  ASSERT_TRUE(sc.thermostatted());
  EXPECT_EQ(sc.integrator.thermostat.style, ThermostatSettings::Style::langevin);
  EXPECT_EQ(sc.integrator.thermostat.temperature, 1.5);
  ASSERT_EQ(sc.integrator.thermostat.friction.size(), 6);
  // LAMMPS's scale TYPE 2.0: that type's damp doubled (4 -> 8), its friction halved.
  EXPECT_EQ(sc.integrator.thermostat.friction[3], 0.125);
  EXPECT_FALSE(load_text(trimer_deck(2, ""), {}).thermostatted());
  EXPECT_EQ(sc.integrator.thermostat.splitting, ThermostatSettings::Splitting::baoab) << "the default";
}

TEST(ThermostatDeck, LammpsSplittingIsReadAndRefusedForTheConstrainedMethods) {
  const std::string deck = trimer_deck(2, kLangevinForce);
  EXPECT_EQ(load_text(deck, {}).integrator.thermostat.splitting, ThermostatSettings::Splitting::lammps);
  EXPECT_EQ(load_text(deck, {"integrator.method=impulse"}).integrator.thermostat.splitting,
            ThermostatSettings::Splitting::lammps);
  for (const std::string& method : test::kAllMethods) {
    if (!find_method(method)->rigid_constraints) continue;
    SCOPED_TRACE(method);
    try {
      load_text(deck, {"integrator.method=" + method});
      ADD_FAILURE() << "splitting = \"lammps\" accepted for " << method;
    } catch (const InputError& e) {
      EXPECT_NE(std::string(e.what()).find("thermostat.splitting"), std::string::npos) << e.what();
    }
  }
  try {
    load_text(trimer_deck(2, kLangevin + "splitting = \"baoa\"\n"), {});
    ADD_FAILURE() << "an unknown splitting accepted";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("thermostat.splitting"), std::string::npos) << e.what();
  }
}

TEST(ThermostatDeck, ObaboSplittingIsReadForEveryMethod) {
  const std::string deck = trimer_deck(2, kLangevin + "splitting = \"obabo\"\n");
  for (const std::string& method : test::kAllMethods) {
    SCOPED_TRACE(method);
    EXPECT_EQ(load_text(deck, {"integrator.method=" + method}).integrator.thermostat.splitting,
              ThermostatSettings::Splitting::obabo);
  }
}

// ---- the constrained splittings on an exactly solvable system ---------------------------------------

// Rigid dimers (two beads of mass m, bond ℓ = 1) whose beads are tethered to one point c with
// springs k: U = ½k(|x₁ − c|² + |x₂ − c|²) = k|X − c|² + kℓ²/4, so the centre of mass X is a
// harmonic oscillator of mass 2m and spring 2k (ω² = k/m), decoupled from the rotation. RATTLE's
// constraint forces sum to zero on each dimer, and the M-orthogonal projection of velocities
// (equal masses) leaves V = (v₁ + v₂)/2 alone, so X and V follow the splitting's linear map with
// the O step's noise on V of variance (1 − c²) kT/(2m). Their stationary variances at finite h
// are then exact (the Lyapunov equation, as for LangevinSplitting above): BAOAB's ⟨X²⟩ is kT/2k
// at any h, OBABO's (velocity Verlet's map with O(h) between steps) is larger by 1/(1 − (hω)²/4).
// Both differences are asserted to be above 8 standard errors, so each splitting's run excludes
// the other's value: a step that put OBABO's O steps elsewhere (or ran BAOAB) fails.
class ConstrainedLangevinSplitting : public ::testing::TestWithParam<std::string> {};

TEST_P(ConstrainedLangevinSplitting, TetheredRigidDimersSampleTheirExactFiniteStepVariances) {
  // The COM oscillator: mass 2m = 2, spring 2k = 200 (ω = 10), γ = 1, h = 0.05 (hω = 0.5).
  const Oscillator com{2.0, 200.0, 1.0, 0.05, 1.0};
  const int dimers = 1000;
  const std::string deck =
      "[box]\nlengths = [60, 60, 60]\nperiodic = true\n[types.bead]\nmass = 1.0\n"
      "[[build]]\nstyle = \"linear-chains\"\ntype = \"bead\"\nchains = " +
      std::to_string(dimers) +
      "\nbeads = 2\nbond_length = 1.0\nbond_type = \"b\"\nmin_distance = 0.0\nseed = 3\n"
      "[velocities]\ntemperature = 1.0\nseed = 4\n"
      "[forces.bonds]\nstyle = \"stiff-harmonic\"\nlevel = \"fast\"\nepsilon = 0.1\n"
      "bond_types.b = { length = 1.0, alpha = 1.0 }\n"
      "[forces.tether]\nstyle = \"harmonic-tether\"\nk = 100.0\ncenter = [30.0, 30.0, 30.0]\n" +
      kLangevin + "splitting = \"" + GetParam() + "\"\n[integrator]\nmethod = \"rattle\"\nh = 0.05\n[run]\nt_end = 1\n";
  Scene sc = load_text(deck, {});
  State& s = sc.state;
  const Eigen::Vector3d c(30.0, 30.0, 30.0);
  for (int d = 0; d < dimers; ++d) {  // each dimer centred on the tether point, its orientation kept
    const Eigen::Vector3d r = sc.forces->box().min_image(s.x.col(2 * d) - s.x.col(2 * d + 1));
    s.x.col(2 * d) = c + 0.5 * r;
    s.x.col(2 * d + 1) = c - 0.5 * r;
  }
  auto integ = make_integrator(sc.integrator, *sc.forces, s.inv_mass);
  std::ostringstream log;
  integ->prepare(s, log);
  std::vector<double> x2, v2, v_lag;
  Eigen::Matrix3Xd v_before(3, dimers);
  for (std::int64_t k = 1; k <= 2200; ++k) {  // 10 time units (10/γ), then 100 sampled every step
    integ->step(s, com.h);
    s.step = k;
    double sx = 0.0, sv = 0.0, sl = 0.0;
    for (int d = 0; d < dimers; ++d) {
      const Eigen::Vector3d v = 0.5 * (s.v.col(2 * d) + s.v.col(2 * d + 1));
      sx += (0.5 * (s.x.col(2 * d) + s.x.col(2 * d + 1)) - c).squaredNorm();
      sv += v.squaredNorm();
      sl += v.dot(v_before.col(d));
      v_before.col(d) = v;
    }
    if (k <= 200) continue;
    x2.push_back(sx * com.k / (3.0 * dimers * com.kT));
    v2.push_back(sv * com.m / (3.0 * dimers * com.kT));
    v_lag.push_back(sl * com.m / (3.0 * dimers * com.kT));
  }
  const bool obabo = GetParam() == "obabo";
  const Eigen::Vector3d baoab = oscillator_variances(com, false), other = oscillator_variances(com, true);
  EXPECT_NEAR(baoab[0], 1.0, 1e-12) << "BAOAB samples the oscillator's x exactly";
  EXPECT_NEAR(other[0], 1.0 / (1.0 - 0.25 * com.h * com.h * com.k / com.m), 1e-12) << "OBABO: velocity Verlet's x law";
  const Eigen::Vector3d exact = obabo ? other : baoab, wrong = obabo ? baoab : other;
  const Estimate ex = block_estimate(x2), ev = block_estimate(v2), el = block_estimate(v_lag);
  RecordProperty("v_lag",
                 std::to_string(el.mean) + " +- " + std::to_string(el.se) + " exact " + std::to_string(exact[2]));
  EXPECT_NEAR(el.mean, exact[2], 4 * el.se) << "m<V_n+1 V_n>/kT = " << el.mean << " +- " << el.se;
  // The same map with half the friction (one O(½h) per step) must be excluded too.
  Oscillator half_friction = com;
  half_friction.gamma *= 0.5;
  const double lag_half = oscillator_variances(half_friction, obabo)[2];
  EXPECT_LT(8 * el.se, std::abs(exact[2] - lag_half)) << "the run cannot tell the friction apart";
  RecordProperty("x2", std::to_string(ex.mean) + " +- " + std::to_string(ex.se) + " exact " + std::to_string(exact[0]));
  RecordProperty("v2", std::to_string(ev.mean) + " +- " + std::to_string(ev.se) + " exact " + std::to_string(exact[1]));
  EXPECT_NEAR(ex.mean, exact[0], 4 * ex.se) << "k<X^2>/kT = " << ex.mean << " +- " << ex.se;
  EXPECT_NEAR(ev.mean, exact[1], 4 * ev.se) << "m<V^2>/kT = " << ev.mean << " +- " << ev.se;
  EXPECT_LT(8 * ex.se, std::abs(exact[0] - wrong[0])) << "the run cannot tell the splittings' <X^2> apart";
  EXPECT_EQ(integ->kinetic_energy_estimate(s) == s.kinetic_energy(), obabo)
      << "OBABO's temperature reads the on-step velocities, BAOAB's those at its O step";
}

INSTANTIATE_TEST_SUITE_P(Splittings, ConstrainedLangevinSplitting, ::testing::Values("baoab", "obabo"));

// ---- the merged closing projections -------------------------------------------------------------

// With Langevin, RATTLE's velocity projections at x_{n+1} are merged (integrators/rattle.cpp):
// under OBABO the closing kick's and the O step's (P(c·Pw + σξ) = P(c·w + σξ) when c is one
// number on each cluster), under constrained BAOAB the chord velocity's and the closing kick's
// (P(Pq + k) = P(q + k)); the constraint force is formed from the kept velocities when the
// pressure asks for it. Against the projections as written, from the same state: the same
// positions, velocities, temperature estimate and constraint virial to round-off over 150 steps of
// trimers (rattle and fixman, whose U_F force reads the toolbox the lazy projection also uses),
// the virial asked for at some steps only. A friction that differs within the trimers is refused.
// Two runs a and b of one deck from the same state: a with the closing projections as the
// integrator chose them, b merged or not as asked; each side on its own thread count.
struct Comparison {
  bool b_merged = false;
  int steps = 150;
  double h = 0.02;
  int a_threads = 1, b_threads = 1;
};
struct Differences {
  double x = 0.0, v = 0.0, kinetic = 0.0, virial = 0.0;  // largest |a − b| (virial: relative)
  bool a_merged = false;
};

Differences merged_against_written(const std::string& deck, const std::vector<std::string>& o, const Comparison& c) {
  Scene a = load_text(deck, o), b = load_text(deck, o);
  const int restore = max_threads();
  auto ia = make_integrator(a.integrator, *a.forces, a.state.inv_mass);
  auto ib = make_integrator(b.integrator, *b.forces, b.state.inv_mass);
  Differences d;
  d.a_merged = dynamic_cast<Rattle&>(*ia).merged_projection();
  dynamic_cast<Rattle&>(*ib).set_merged_projection(c.b_merged);
  std::ostringstream log;
  ia->prepare(a.state, log);
  ib->prepare(b.state, log);
  for (int k = 0; k < c.steps; ++k) {
    a.state.step = b.state.step = k;
    set_max_threads(c.a_threads);
    ia->step(a.state, c.h);
    const double ka = ia->kinetic_energy_estimate(a.state);
    const double wa = k % 7 == 3 ? ia->constraint_virial(a.state) : 0.0;
    if (k % 7 == 3) {
      EXPECT_EQ(wa, ia->constraint_virial(a.state));  // formed once, then kept
    }
    set_max_threads(c.b_threads);
    ib->step(b.state, c.h);
    d.x = std::max(d.x, (a.state.x - b.state.x).cwiseAbs().maxCoeff());
    d.v = std::max(d.v, (a.state.v - b.state.v).cwiseAbs().maxCoeff());
    d.kinetic = std::max(d.kinetic, std::abs(ka - ib->kinetic_energy_estimate(b.state)));
    if (k % 7 == 3) {
      const double wb = ib->constraint_virial(b.state);
      EXPECT_GT(std::abs(wb), 1.0);  // the constraint forces of ≥ 120 bonds at kT = 1
      d.virial = std::max(d.virial, std::abs(wa - wb) / std::abs(wb));
    }
  }
  set_max_threads(restore);
  return d;
}

class MergedProjection : public ::testing::TestWithParam<std::string> {};

TEST_P(MergedProjection, GivesTheWrittenProjectionsTrajectoryAndPressure) {
  const std::string deck = trimer_deck(60, kLangevin + "splitting = \"" + GetParam() + "\"\n");
  for (const std::string method : {"rattle", "fixman"}) {
    SCOPED_TRACE(method);
    const std::vector<std::string> o = {"integrator.method=" + method, "integrator.h=0.02"};
    const Differences d = merged_against_written(deck, o, {});
    EXPECT_TRUE(d.a_merged);  // one friction everywhere: merged by default
    EXPECT_LT(d.x, 1e-11);
    EXPECT_LT(d.v, 1e-10);
    EXPECT_LT(d.kinetic, 1e-10);
    EXPECT_LT(d.virial, 1e-10);
    EXPECT_GT(d.v, 0.0);  // two paths, not one

    // The middle beads with twice the friction: the constrained O step keeps the Maxwell law only
    // with one friction per cluster (integrators/thermostat.hpp), so the integrator refuses it.
    Scene twice = load_text(deck, o);
    for (int i = 1; i < twice.state.size(); i += 3) twice.integrator.thermostat.friction[i] *= 2.0;
    EXPECT_THROW(make_integrator(twice.integrator, *twice.forces, twice.state.inv_mass), std::invalid_argument);
  }
}

// The same on a melt above the threads' threshold (4 200 beads, WCA through the neighbour list,
// periodic), fixman on two threads: merged against written to round-off; and the merged run on one
// thread against two (the pair sums' order differs with the thread count: round-off, not bits)
// and on two threads against itself, bit for bit.
TEST_P(MergedProjection, HoldsOnAMeltWithPairForcesOnTwoThreads) {
  const std::string deck =
      "[types.bead]\nmass = 1.0\n[[build]]\nstyle = \"linear-chains\"\ntype = \"bead\"\nchains = 84\nbeads = 50\n"
      "bond_length = 0.97\nbond_type = \"b\"\ndensity = 0.6\nmin_distance = 0.8\nseed = 3\n"
      "[velocities]\ntemperature = 1.0\nseed = 4\n"
      "[forces.bonds]\nstyle = \"stiff-harmonic\"\nlevel = \"fast\"\nepsilon = 0.01\n"
      "bond_types.b = { length = 0.97, alpha = 1.0 }\n"
      "[forces.excluded_volume]\nstyle = \"wca\"\nspecial_bonds = [0.0, 1.0]\nskin = 0.3\n"
      "[prepare]\nproject = true\nrelax_steps = 200\nseed = 6\n" +
      kLangevin + "splitting = \"" + GetParam() +
      "\"\n[integrator]\nmethod = \"fixman\"\nh = 0.005\n[run]\nt_end = 1\n";
  const std::vector<std::string> o;
  ASSERT_GE(load_text(deck, o).state.size(), kParallelMin);
  Comparison c;
  c.steps = 15;
  c.h = 0.005;
  c.a_threads = c.b_threads = 2;
  const Differences written = merged_against_written(deck, o, c);
  EXPECT_TRUE(written.a_merged);
  EXPECT_LT(written.x, 1e-11);
  EXPECT_LT(written.v, 1e-10);
  EXPECT_LT(written.kinetic, 1e-8);  // of ≈ 6 000: 2e-12 relative
  EXPECT_LT(written.virial, 1e-10);
  c.b_merged = true;
  const Differences same = merged_against_written(deck, o, c);
  EXPECT_EQ(same.x, 0.0);
  EXPECT_EQ(same.v, 0.0);
  EXPECT_EQ(same.virial, 0.0);
  c.a_threads = 1;
  const Differences threads = merged_against_written(deck, o, c);
  EXPECT_LT(threads.x, 1e-11);
  EXPECT_LT(threads.virial, 1e-10);
  EXPECT_GT(threads.x, 0.0);  // the thread counts sum the pairs in another order
}

INSTANTIATE_TEST_SUITE_P(Splittings, MergedProjection, ::testing::Values("baoab", "obabo"));

}  // namespace
}  // namespace stiffmd
