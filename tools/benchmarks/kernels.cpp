// Google Benchmark timings of the engine's kernels, so that a regression shows as a number:
//
//   BM_PairForces/<scene>           the slow level (WCA) at a fixed x, neighbour list already built
//   BM_PairVirialDiagonal/<scene>   the WCA term's forces with the exact virial diagonal at a fixed x
//                                   (PairTerm::add_forces_and_virial_diagonal: the pair pass of a
//                                   barostat's cell move), to set beside BM_PairForces
//   BM_MolecularPressure/<scene>    the whole molecular pressure of a cell move
//                                   (MolecularPressure::pressure: centres of mass, the pass above,
//                                   Σ δ·f and 2K, every sum exact; docs/design.md §5b)
//   BM_NeighborBuild/<scene>        one rebuild of the WCA term's neighbour list at a fixed x
//   BM_CoulLongPairForces/Water     the lj/cut/coul/long term alone (the real-space Ewald pairs,
//                                   erfc per pair) of inputs/spce_water.toml (1 536 atoms, 10 Å
//                                   cutoff, 2 Å skin) at a fixed x, neighbour list already built
//   BM_BondForces/<scene>           the fast level (the stiff bonds)
//   BM_ForceProjection/<scene>      P(x) f (ConstraintToolbox::project_force)
//   BM_Shake/<scene>                SHAKE of a drift over 0.01 from x with S(x) kept (ConstraintToolbox::shake)
//   BM_Mollifier/<scene>            α(x) and α′(x)ᵀ f(α(x)) (ConstraintToolbox::mollified_force),
//                                   without the slow force itself (f(α(x)) is precomputed)
//   BM_MacroStep/<method>/<scene>   one macro step of the factory's integrator: the impulse family at
//                                   h = 0.005 with 20 micro steps (as in the decks), velocity Verlet
//                                   at h = 0.00025, rattle at h = 0.005, fixman (Langevin kT = 1,
//                                   γ = 1) at h = 0.02; impulse-unfused: the plain micro steps
//                                   (kick_drift, then the force field's fast level); rattle and
//                                   fixman -obabo-h<h>: Langevin with the OBABO splitting
//   BM_MicroStepVsFloor/<scene>     one micro step fused and plain against the memory floor (one pass
//                                   reading x, v, f and writing x, v), interleaved, CPU time
//   BM_BondKernelPerBond/<scene>    ns per bond of the stiff harmonic bond force (vs LAMMPS:
//                                   tools/benchmarks/lammps_bond_harmonic.in)
//   BM_PendulumVsHandWritten        velocity Verlet on the double pendulum through the engine vs a
//                                   hand-written loop of the same physics, interleaved, CPU time
//   BM_PendulumRunVsHandWritten     the same through the whole run path (engine/run's Run stepped
//                                   10⁷ steps between outputs) vs the hand loop, the same bits at
//                                   the end (docs/performance.md, "The run loop's cost per step")
//   BM_WaterConstraints/<solver>    the constraint work of one RATTLE step per water of
//                                   inputs/spce_water.toml (512 rigid triangles): SHAKE of a 2 fs
//                                   drift and the velocity projection, by the engine's general
//                                   solver (ConstraintToolbox) or by an analytic SETTLE (settle.hpp)
//
// Scenes: Water — inputs/spce_water.toml (BM_CoulLongPairForces, BM_WaterConstraints); Melt —
// inputs/lammps_chain.toml, LAMMPS's data.chain (32 000 beads, Debian package
// lammps-examples; the Melt benchmarks skip with an error when it is missing); Synthetic — a built
// melt of 16 chains × 64 beads from a deck embedded below, which needs no data file. Each scene is
// loaded and prepared once per process, on first use. Items are particles (bonds for the bond
// force) per iteration; items_per_second is the number to watch. Times are wall-clock (UseRealTime):
// the force loops and constraint solves may run on OpenMP threads, whose work the main thread's
// CPU time would not count; OMP_NUM_THREADS is printed in the context header.
//
//   build/tools/benchmarks/stiffmd_bench --benchmark_min_time=0.2
//   build/tools/benchmarks/stiffmd_bench --benchmark_filter=Synthetic --benchmark_min_time=0.01
#include <benchmark/benchmark.h>
#include <time.h>
#include <unistd.h>

#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <exception>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>
#include <vector>

#include "core/exact_sum.hpp"
#include "core/portable_random.hpp"
#include "core/topology.hpp"
#include "engine/deck/deck.hpp"
#include "engine/run/run.hpp"
#include "engine/scene/scene.hpp"
#include "forcefields/pair_term.hpp"
#include "integrators/barostat.hpp"
#include "integrators/constraints.hpp"
#include "integrators/integrator.hpp"
#include "integrators/multiple_time_stepping.hpp"
#include "integrators/primitives.hpp"
#include "tools/benchmarks/hand_pendulum.hpp"
#include "tools/benchmarks/settle.hpp"

namespace stiffmd {
namespace {

namespace fs = std::filesystem;

// The file inputs/lammps_chain.toml imports; the environment variable STIFFMD_CHAIN_DATA names
// another copy (e.g. examples/COUPLE/multiple/data.chain of a LAMMPS source tree).
constexpr const char* kChainData = "/usr/share/lammps/examples/COUPLE/multiple/data.chain";

// A path as a TOML basic string, for a --set override.
std::string toml_string(const std::string& s) {
  std::string out = "\"";
  for (const char c : s) {
    if (c == '"' || c == '\\') out += '\\';
    out += c;
  }
  return out + "\"";
}

// A built melt (density 0.85, stiff bonds of ε = 0.01 and WCA, as inputs/polymer_melt.toml but
// 1 024 beads and a short relaxation), for machines without lammps-examples.
constexpr const char* kSyntheticDeck = R"toml(
[variables]
eps = 0.01

[types.bead]
mass = 1.0

[[build]]
style = "linear-chains"
type = "bead"
chains = 16
beads = 64
bond_length = 0.97
bond_type = "backbone"
density = 0.85
min_distance = 0.8
seed = 11

[velocities]
temperature = 1.0
seed = 12

[forces.bonds]
style = "stiff-harmonic"
level = "fast"
epsilon = "eps"
bond_types.backbone = { length = 0.97, alpha = 1.0 }

[forces.excluded_volume]
style = "wca"
level = "slow"
epsilon = 1.0
sigma = 1.0
special_bonds = [0.0, 1.0]

[prepare]
project = true
relax_steps = 200
relax_max_displacement = 0.02
vibrational_temperature = 1.0
seed = 13

[integrator]
method = "projected-impulse"
h = 0.005
micro_steps = 20

[run]
t_end = 0.05

[output]
xyz = ""
)toml";

// A loaded, prepared scene and its initial state, which every benchmark starts from.
struct Fixture {
  std::string error;  // non-empty: the scene could not be loaded, the benchmarks skip with this
  Scene scene;
  State initial;

  bool ok() const { return error.empty(); }
  ForceField& forces() { return *scene.forces; }
  int particles() const { return initial.size(); }
};

Fixture load_fixture(const std::string& label, const std::string& deck_path,
                     const std::vector<std::string>& overrides = {}) {
  Fixture fx;
  const auto start = std::chrono::steady_clock::now();
  try {
    fx.scene = load_scene(Deck(deck_path, overrides));
    std::ostringstream log;
    prepare_scene(fx.scene, log);
    fx.initial = fx.scene.state;
    if (!fx.scene.forces->stiff_bonds()) fx.error = label + ": the scene has no stiff bonds";
  } catch (const std::exception& e) {
    fx.error = label + ": could not load " + deck_path + ": " + e.what();
  }
  if (fx.ok()) {
    const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
    std::fprintf(stderr, "stiffmd_bench: %s: %d particles, %zu stiff bonds, loaded and prepared in %.2f s\n",
                 label.c_str(), fx.particles(), fx.scene.forces->stiff_bonds()->bonds.size(), seconds);
  }
  return fx;
}

Fixture& melt() {
  static Fixture fx = [] {
    const char* env = std::getenv("STIFFMD_CHAIN_DATA");
    const std::string data = env && *env ? env : kChainData;
    if (!fs::exists(data)) {
      Fixture missing;
      missing.error = "Melt: " + data +
                      " is missing (Debian package lammps-examples, which bash tools/setup.sh installs; or set "
                      "STIFFMD_CHAIN_DATA to a copy of LAMMPS's data.chain)";
      return missing;
    }
    return load_fixture("Melt", std::string(STIFFMD_SOURCE_DIR) + "/inputs/lammps_chain.toml",
                        {"import.lammps_data=" + toml_string(data)});
  }();
  return fx;
}

Fixture& synthetic() {
  static Fixture fx = [] {
    const fs::path path =
        fs::temp_directory_path() / ("stiffmd_bench_synthetic_" + std::to_string(::getpid()) + ".toml");
    {
      std::ofstream out(path);
      out << kSyntheticDeck;
      if (!out) {
        Fixture failed;
        failed.error = "Synthetic: cannot write the deck to " + path.string();
        return failed;
      }
    }
    Fixture loaded = load_fixture("Synthetic", path.string());
    std::error_code ec;
    fs::remove(path, ec);
    return loaded;
  }();
  return fx;
}

using FixtureGetter = Fixture& (*)();

// The fixture, or nullptr after marking the benchmark skipped.
Fixture* fixture_or_skip(benchmark::State& st, FixtureGetter get) {
  Fixture& fx = get();
  if (fx.ok()) return &fx;
  st.SkipWithError(fx.error.c_str());
  return nullptr;
}

const WcaPair* find_wca(const ForceField& ff) {
  for (const auto& term : ff.terms())
    if (const auto* wca = dynamic_cast<const WcaPair*>(term.get())) return wca;
  return nullptr;
}

// The scene's WCA term, or null with the benchmark skipped.
const WcaPair* wca_or_skip(benchmark::State& st, Fixture& fx) {
  const WcaPair* wca = find_wca(fx.forces());
  if (!wca) st.SkipWithError("the scene has no WCA term");
  return wca;
}

long neighbor_rebuilds(const ForceField& ff) {
  long n = 0;
  for (const auto& term : ff.terms()) n += term->neighbor_list_rebuilds();
  return n;
}

void BM_PairForces(benchmark::State& st, FixtureGetter get) {
  Fixture* fx = fixture_or_skip(st, get);
  if (!fx) return;
  ForceField& ff = fx->forces();
  const Eigen::Matrix3Xd& x = fx->initial.x;
  Eigen::Matrix3Xd f(3, x.cols());
  ff.compute(x, {Level::slow}, f);  // builds the neighbour list at x: the loop times the pair loop alone
  const long rebuilds = neighbor_rebuilds(ff);
  for (auto _ : st) {
    benchmark::DoNotOptimize(ff.compute(x, {Level::slow}, f));
    benchmark::ClobberMemory();
  }
  st.SetItemsProcessed(st.iterations() * fx->particles());
  st.counters["particles"] = fx->particles();
  if (const WcaPair* wca = find_wca(ff)) {
    const auto pairs = static_cast<double>(wca->neighbor_list().num_pairs());
    st.counters["listed_pairs"] = pairs;  // within cutoff + skin
    st.counters["pairs_per_second"] = benchmark::Counter(pairs, benchmark::Counter::kIsIterationInvariantRate);
  }
  st.counters["rebuilds"] = static_cast<double>(neighbor_rebuilds(ff) - rebuilds);  // 0: x is fixed
}

Fixture& water() {
  static Fixture fx = load_fixture("Water", std::string(STIFFMD_SOURCE_DIR) + "/inputs/spce_water.toml");
  return fx;
}

// The charged pair kernel of the coul/long family: the scene's lj/cut/coul/long term by itself (not
// the PPPM mesh of the same level), as BM_PairForces times the WCA term.
void BM_CoulLongPairForces(benchmark::State& st, FixtureGetter get) {
  Fixture* fx = fixture_or_skip(st, get);
  if (!fx) return;
  const LjCutCoulLongPair* pair = nullptr;
  for (const auto& term : fx->forces().terms())
    if (const auto* p = dynamic_cast<const LjCutCoulLongPair*>(term.get())) pair = p;
  if (!pair) {
    st.SkipWithError("the scene has no lj/cut/coul/long term");
    return;
  }
  const Box& box = fx->forces().box();
  const Eigen::Matrix3Xd& x = fx->initial.x;
  Eigen::Matrix3Xd f = Eigen::Matrix3Xd::Zero(3, x.cols());
  pair->add_forces(x, box, f);  // builds the neighbour list at x: the loop times the pair loop alone
  const long rebuilds = pair->neighbor_list_rebuilds();
  for (auto _ : st) {
    f.setZero();
    benchmark::DoNotOptimize(pair->add_forces(x, box, f));
    benchmark::ClobberMemory();
  }
  st.SetItemsProcessed(st.iterations() * fx->particles());
  const auto pairs = static_cast<double>(pair->neighbor_list().num_pairs());
  st.counters["particles"] = fx->particles();
  st.counters["listed_pairs"] = pairs;  // within cutoff + skin, every one evaluated (masked beyond the cutoff)
  st.counters["pairs_per_second"] = benchmark::Counter(pairs, benchmark::Counter::kIsIterationInvariantRate);
  st.counters["rebuilds"] = static_cast<double>(pair->neighbor_list_rebuilds() - rebuilds);  // 0: x is fixed
}

// What a barostat's cell move adds to the pair loop: the same WCA forces with the diagonal of the
// pair virial summed exactly (ExactDiagonal), as MolecularPressure evaluates it.
void BM_PairVirialDiagonal(benchmark::State& st, FixtureGetter get) {
  Fixture* fx = fixture_or_skip(st, get);
  const WcaPair* wca = fx ? wca_or_skip(st, *fx) : nullptr;
  if (!wca) return;
  const Eigen::Matrix3Xd& x = fx->initial.x;
  const Box& box = fx->forces().box();
  Eigen::Matrix3Xd f = Eigen::Matrix3Xd::Zero(3, x.cols());
  ExactDiagonal w;
  wca->add_forces_and_virial_diagonal(x, box, f, w);  // builds the neighbour list at x
  for (auto _ : st) {
    f.setZero();
    ExactDiagonal sum;
    wca->add_forces_and_virial_diagonal(x, box, f, sum);
    benchmark::DoNotOptimize(sum);
    benchmark::ClobberMemory();
  }
  st.SetItemsProcessed(st.iterations() * fx->particles());
  st.counters["listed_pairs"] = static_cast<double>(wca->neighbor_list().num_pairs());
}

// The molecular pressure of a cell move (MolecularPressure::pressure), molecules as the barostat
// takes them (bonded_molecules).
void BM_MolecularPressure(benchmark::State& st, FixtureGetter get) {
  Fixture* fx = fixture_or_skip(st, get);
  if (!fx) return;
  MolecularPressure pressure(bonded_molecules(fx->scene.topology, fx->particles()), fx->initial.inv_mass);
  Eigen::Matrix3Xd scratch;
  pressure.pressure(fx->initial, fx->forces(), scratch);  // builds the neighbour list at x
  for (auto _ : st) {
    benchmark::DoNotOptimize(pressure.pressure(fx->initial, fx->forces(), scratch));
    benchmark::ClobberMemory();
  }
  st.SetItemsProcessed(st.iterations() * fx->particles());
  st.counters["molecules"] = pressure.molecules();
}

// A rebuild of the WCA term's neighbour list (the term's cutoff, skin and special-bond weights: its
// pairs of weight ≠ 1 left out, as the term lists them) at the fixed initial x: binning, the
// half-stencil search and the sort into rows. Counter: the listed pairs.
void BM_NeighborBuild(benchmark::State& st, FixtureGetter get) {
  Fixture* fx = fixture_or_skip(st, get);
  const WcaPair* wca = fx ? wca_or_skip(st, *fx) : nullptr;
  if (!wca) return;
  NeighborList list(wca->neighbor_list().cutoff(), wca->skin());
  list.set_exclusions(fx->particles(), special_pairs(fx->particles(), fx->scene.topology.bonds, wca->weights()));
  const Eigen::Matrix3Xd& x = fx->initial.x;
  for (auto _ : st) {
    list.build(x, fx->forces().box());
    benchmark::ClobberMemory();
  }
  st.SetItemsProcessed(st.iterations() * fx->particles());
  st.counters["listed_pairs"] = static_cast<double>(list.num_pairs());
}

void BM_BondForces(benchmark::State& st, FixtureGetter get) {
  Fixture* fx = fixture_or_skip(st, get);
  if (!fx) return;
  ForceField& ff = fx->forces();
  const Eigen::Matrix3Xd& x = fx->initial.x;
  const auto bonds = static_cast<std::int64_t>(ff.stiff_bonds()->bonds.size());
  Eigen::Matrix3Xd f(3, x.cols());
  for (auto _ : st) {
    benchmark::DoNotOptimize(ff.compute(x, {Level::fast}, f));
    benchmark::ClobberMemory();
  }
  st.SetItemsProcessed(st.iterations() * bonds);
  st.counters["bonds"] = static_cast<double>(bonds);
}

void BM_ForceProjection(benchmark::State& st, FixtureGetter get) {
  Fixture* fx = fixture_or_skip(st, get);
  if (!fx) return;
  ForceField& ff = fx->forces();
  const State& s = fx->initial;
  ConstraintToolbox toolbox(ff.stiff_bonds()->bonds, s.inv_mass);
  Eigen::Matrix3Xd f(3, s.size());
  ff.compute(s.x, {Level::slow}, f);
  // P(x) is a projection, so projecting the same f again costs the same (one S λ = G M⁻¹ f solve
  // per cluster) and leaves it unchanged: no copy of the force inside the loop.
  for (auto _ : st) {
    toolbox.project_force(s.x, f);
    benchmark::ClobberMemory();
  }
  st.SetItemsProcessed(st.iterations() * s.size());
  st.counters["particles"] = s.size();
  st.counters["bonds"] = toolbox.num_bonds();
  st.counters["clusters"] = static_cast<double>(toolbox.clusters().size());
}

void BM_Mollifier(benchmark::State& st, FixtureGetter get) {
  Fixture* fx = fixture_or_skip(st, get);
  if (!fx) return;
  ForceField& ff = fx->forces();
  const State& s = fx->initial;
  ConstraintToolbox toolbox(ff.stiff_bonds()->bonds, s.inv_mass);
  Eigen::Matrix3Xd X(3, s.size()), out(3, s.size()), f_at_X(3, s.size());
  // Once with the real slow force, to get f(α(x)); x is fixed, so α(x) is too, and the timed calls
  // get f(α(x)) as a copy: the loop times SHAKE for α(x), the Jᵀμ solves and H_λ M⁻¹ r, not WCA.
  toolbox.mollified_force(
      s.x, [&](const Eigen::Matrix3Xd& y, Eigen::Matrix3Xd& f) { ff.compute(y, {Level::slow}, f); }, X, out);
  ff.compute(X, {Level::slow}, f_at_X);
  const ForceFunction cached = [&](const Eigen::Matrix3Xd&, Eigen::Matrix3Xd& f) { f = f_at_X; };
  for (auto _ : st) {
    toolbox.mollified_force(s.x, cached, X, out);
    benchmark::ClobberMemory();
  }
  st.SetItemsProcessed(st.iterations() * s.size());
  st.counters["particles"] = s.size();
  st.counters["max_violation_x"] = toolbox.max_violation(s.x);  // how far α has to move x
}

// SHAKE of a drift over τ = 0.01 (half of fixman's step in the cost-against-ε figure) from the
// initial x, on the manifold, with the initial velocities made tangent: y = x + τ v, then y ← y + M⁻¹G(x)ᵀλ,
// g(y) = 0. The converged y becomes the toolbox's kept configuration (for the velocity
// projection that follows SHAKE in a step), so every call measures x and factors S(x) again:
// one call is one SHAKE and one factorization of S, as a constrained step has per drift.
// Counters: the residual max |g(x + τv)|, factorizations per call (of S, and of J when Newton).
void BM_Shake(benchmark::State& st, FixtureGetter get) {
  Fixture* fx = fixture_or_skip(st, get);
  if (!fx) return;
  const State& s = fx->initial;
  ConstraintToolbox toolbox(fx->forces().stiff_bonds()->bonds, s.inv_mass);
  Eigen::Matrix3Xd x = s.x;
  toolbox.shake(x, x);  // exactly on the manifold, with tangent velocities (as in a constrained run)
  Eigen::Matrix3Xd v = s.v;
  toolbox.project_velocity(x, v);
  const double tau = 0.01;
  const Eigen::Matrix3Xd drifted = x + tau * v;
  Eigen::Matrix3Xd y = drifted;
  toolbox.shake(x, y);  // factors S(x)
  for (auto _ : st) {
    y = drifted;
    toolbox.shake(x, y);
    benchmark::ClobberMemory();
  }
  st.SetItemsProcessed(st.iterations() * toolbox.num_bonds());
  st.counters["bonds"] = toolbox.num_bonds();
  st.counters["initial_violation"] = toolbox.max_violation(drifted);
  st.counters["factorizations_per_call"] =
      static_cast<double>(toolbox.factorizations()) / static_cast<double>(st.iterations() + 2);
}

struct MacroStepCase {
  const char* method;
  double h;
  int micro_steps;
  bool fused = true;       // false: the plain micro steps (MultipleTimeStepping::use_fused_micro_step)
  bool langevin = false;   // BAOAB Langevin, kT = 1, γ = 1 (fixman needs a thermostat)
  bool obabo = false;      // with langevin: the splitting "obabo" instead
  const char* label = "";  // appended to the benchmark's name
};

constexpr MacroStepCase kMacroSteps[] = {
    {"impulse", 0.005, 20},
    {"impulse", 0.005, 20, false},
    {"projected-impulse", 0.005, 20},
    {"mollified-impulse", 0.005, 20},
    {"velocity-verlet", 0.00025, 1},
    {"rattle", 0.005, 1},
    {"fixman", 0.02, 1, true, true},
    // The constrained methods under OBABO (one SHAKE, one velocity projection per step) at the
    // steps of the cost study: fixman against rattle, interleave them with
    // --benchmark_enable_random_interleaving=true --benchmark_repetitions=N.
    {"rattle", 0.005, 1, true, true, true, "-obabo-h0.005"},
    {"fixman", 0.005, 1, true, true, true, "-obabo-h0.005"},
    {"rattle", 0.02, 1, true, true, true, "-obabo-h0.02"},
    {"fixman", 0.02, 1, true, true, true, "-obabo-h0.02"},
};

void BM_MacroStep(benchmark::State& st, FixtureGetter get, MacroStepCase c) {
  Fixture* fx = fixture_or_skip(st, get);
  if (!fx) return;
  ForceField& ff = fx->forces();
  // A fresh copy of the initial state per run; the iterations keep stepping it (a physical
  // trajectory, t = iterations × h).
  State s = fx->initial;
  IntegratorSettings settings = fx->scene.integrator;
  settings.method = c.method;
  settings.h = c.h;
  settings.micro_steps = c.micro_steps;
  if (c.langevin) {
    settings.thermostat.style = ThermostatSettings::Style::langevin;
    settings.thermostat.temperature = 1.0;
    settings.thermostat.friction = Eigen::VectorXd::Ones(s.size());
    settings.thermostat.seed = 3;
    if (c.obabo) settings.thermostat.splitting = ThermostatSettings::Splitting::obabo;
  }
  std::unique_ptr<Integrator> integrator;
  try {
    integrator = make_integrator(settings, ff, s.inv_mass);
    if (auto* mts = dynamic_cast<MultipleTimeStepping*>(integrator.get())) mts->use_fused_micro_step(c.fused);
    std::ostringstream log;
    integrator->prepare(s, log);
  } catch (const std::exception& e) {
    st.SkipWithError((std::string(c.method) + ": " + e.what()).c_str());
    return;
  }
  integrator->step(s, c.h);  // untimed: fills the cached forces and rebuilds the neighbour list
  const std::int64_t slow0 = ff.evaluations(Level::slow), fast0 = ff.evaluations(Level::fast);
  const long rebuilds0 = neighbor_rebuilds(ff);
  for (auto _ : st) {
    integrator->step(s, c.h);
    ++s.step;  // the Langevin noise's stream is keyed by the step number
    benchmark::ClobberMemory();
  }
  if (!s.x.allFinite() || !s.v.allFinite()) {
    st.SkipWithError((std::string(c.method) + ": the state became non-finite").c_str());
    return;
  }
  const auto steps = static_cast<double>(st.iterations());
  st.SetItemsProcessed(st.iterations() * s.size());
  st.counters["particles"] = s.size();
  st.counters["h"] = c.h;
  st.counters["slow_evals_per_step"] = static_cast<double>(ff.evaluations(Level::slow) - slow0) / steps;
  st.counters["fast_evals_per_step"] = static_cast<double>(ff.evaluations(Level::fast) - fast0) / steps;
  st.counters["rebuilds_per_step"] = static_cast<double>(neighbor_rebuilds(ff) - rebuilds0) / steps;
}

// CPU seconds of the process (all its threads): on a machine shared with other jobs, wall time
// includes the time the process waited for a core; CPU time does not (OMP_WAIT_POLICY=passive:
// idle OpenMP threads sleep instead of spinning).
double cpu_seconds() {
  timespec ts{};
  clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &ts);
  return static_cast<double>(ts.tv_sec) + 1e-9 * static_cast<double>(ts.tv_nsec);
}

// The micro step at the memory limit. Per iteration, interleaved so that the machine's
// load hits all three alike: the floor — one pass that reads x, v, f and writes x, v (a kick and a
// drift written as one loop over the 3N numbers, on the same threads) — then one fused micro step
// (FusedMicroStep: kick, drift and the stiff-bond force in one pass), then one plain micro step
// (kick_drift, then the force field's fast level: f = 0 and the bond loop). Counters: each one's
// mean CPU µs and the ratios to the floor (target: fused ≤ 2 × floor). x, v evolve (a physical
// trajectory of the bond vibrations at δ = h / micro_steps of the deck); the plain and fused
// steps run on separate copies of the state.
void BM_MicroStepVsFloor(benchmark::State& st, FixtureGetter get) {
  Fixture* fx = fixture_or_skip(st, get);
  if (!fx) return;
  ForceField& ff = fx->forces();
  const FusedMicroStep* fused = nullptr;
  for (const auto& term : ff.terms())
    if (term->level() == Level::fast) fused = term->fused_micro_step();
  if (!fused) {
    st.SkipWithError("the fast level has no fused micro step");
    return;
  }
  const IntegratorSettings& is = fx->scene.integrator;
  const double delta = is.micro_steps > 0 ? is.h / is.micro_steps : 0.00025;
  State a = fx->initial, b = fx->initial, c = fx->initial;
  Eigen::Matrix3Xd fa(3, a.size()), fb(3, b.size()), fc(3, c.size());
  ff.compute(a.x, {Level::fast}, fa);
  fb = fa;
  fc = fa;
  const std::int64_t n3 = 3 * static_cast<std::int64_t>(c.size());
  const int threads = threads_for(c.size());
  double t_floor = 0.0, t_fused = 0.0, t_plain = 0.0;
  for (auto _ : st) {
    const double t0 = cpu_seconds();
    parallel_blocks(n3, threads, [&](std::int64_t lo, std::int64_t hi) {
      double* __restrict xp = c.x.data();  // distinct arrays: the fastest such pass is the floor
      double* __restrict vp = c.v.data();
      const double* __restrict fp = fc.data();
      for (std::int64_t i = lo; i < hi; ++i) {
        vp[i] += delta * fp[i];
        xp[i] += delta * vp[i];
      }
    });
    benchmark::ClobberMemory();
    const double t1 = cpu_seconds();
    fused->kick_drift_force(a.x, a.v, a.inv_mass, fa, delta, delta);
    benchmark::ClobberMemory();
    const double t2 = cpu_seconds();
    kick_drift(b.x, b.v, b.inv_mass, fb, delta, delta);
    ff.compute(b.x, {Level::fast}, fb);
    benchmark::ClobberMemory();
    const double t3 = cpu_seconds();
    t_floor += t1 - t0;
    t_fused += t2 - t1;
    t_plain += t3 - t2;
  }
  if (a.x != b.x || a.v != b.v || fa != fb) {
    st.SkipWithError("the fused and plain micro steps gave different bits");
    return;
  }
  const double it = static_cast<double>(st.iterations());
  st.SetItemsProcessed(st.iterations() * a.size());
  st.counters["particles"] = a.size();
  st.counters["floor_us"] = 1e6 * t_floor / it;
  st.counters["fused_us"] = 1e6 * t_fused / it;
  st.counters["plain_us"] = 1e6 * t_plain / it;
  st.counters["fused_over_floor"] = t_fused / t_floor;
  st.counters["plain_over_floor"] = t_plain / t_floor;
}

// Per-bond time of the stiff harmonic bond force, to compare with LAMMPS's `bond_style harmonic`
// (tools/benchmarks/lammps_bond_harmonic.in: the "Bond" row of its timing breakdown × its %CPU ÷
// (steps × bonds), with `timer full`). Like LAMMPS's bond compute, the timed call adds the forces
// into f (ForceTerm::add_forces; f is not cleared, which LAMMPS does outside its Bond row); unlike
// it, every call also sums the energy. Counters ns_per_bond (wall), cpu_ns_per_bond, and
// with_clear_cpu_ns_per_bond: the force field's fast level (f = 0, then the bonds), as a micro step
// of the plain path evaluates it.
void BM_BondKernelPerBond(benchmark::State& st, FixtureGetter get) {
  Fixture* fx = fixture_or_skip(st, get);
  if (!fx) return;
  ForceField& ff = fx->forces();
  const ForceTerm* stiff = nullptr;
  for (const auto& term : ff.terms())
    if (term->stiff_bonds()) stiff = term.get();
  const Eigen::Matrix3Xd& x = fx->initial.x;
  const auto bonds = static_cast<double>(ff.stiff_bonds()->bonds.size());
  Eigen::Matrix3Xd f = Eigen::Matrix3Xd::Zero(3, x.cols());
  const auto t0 = std::chrono::steady_clock::now();
  const double c0 = cpu_seconds();
  for (auto _ : st) {
    benchmark::DoNotOptimize(stiff->add_forces(x, ff.box(), f));
    benchmark::ClobberMemory();
  }
  const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  const double cpu = cpu_seconds() - c0;
  const double evaluations = static_cast<double>(st.iterations()) * bonds;
  const int clears = std::max<int>(10, static_cast<int>(st.iterations()));
  const double c1 = cpu_seconds();
  for (int k = 0; k < clears; ++k) {
    benchmark::DoNotOptimize(ff.compute(x, {Level::fast}, f));
    benchmark::ClobberMemory();
  }
  const double cpu_clear = cpu_seconds() - c1;
  st.counters["bonds"] = bonds;
  st.counters["ns_per_bond"] = 1e9 * seconds / evaluations;
  st.counters["cpu_ns_per_bond"] = 1e9 * cpu / evaluations;
  st.counters["with_clear_cpu_ns_per_bond"] = 1e9 * cpu_clear / (clears * bonds);
}

// Small systems: velocity Verlet on the double pendulum (inputs/double_pendulum.toml,
// 3 particles, the pivot fixed, two stiff springs at ε = 1e-3 and gravity) through the engine's
// integrator, against a hand-written loop of the same physics (tools/benchmarks/hand_pendulum.hpp):
// kick ½h, drift h, the spring forces and gravity, kick ½h. Per iteration both run kBatch steps
// from the same state, interleaved; counters: CPU ns per step of each, their ratio, and the
// largest difference of the positions after the batch (0: the same operations, the same bits).
// The engine's time is Integrator::step alone (no observers, as in a run between outputs; with the
// finiteness check its closing kick makes for the run, Integrator::checked_finite).
constexpr int kPendulumBatch = 10000;
const std::vector<std::string> kPendulumVerlet = {"integrator.method=\"velocity-verlet\"", "integrator.h=1e-4"};

// CPU seconds of kPendulumBatch steps of the hand-written loop: the floor both pendulum benchmarks
// compare the engine against.
double hand_batch_seconds(HandPendulum& hand, double h) {
  const double t0 = cpu_seconds();
  for (int i = 0; i < kPendulumBatch; ++i) {
    hand.step(h);
    benchmark::DoNotOptimize(hand.positions());
  }
  benchmark::ClobberMemory();
  return cpu_seconds() - t0;
}

void BM_PendulumVsHandWritten(benchmark::State& st) {
  static Fixture fx =
      load_fixture("Pendulum", std::string(STIFFMD_SOURCE_DIR) + "/inputs/double_pendulum.toml", kPendulumVerlet);
  if (!fx.ok()) {
    st.SkipWithError(fx.error.c_str());
    return;
  }
  const double h = 1e-4;
  State s = fx.initial;
  std::unique_ptr<Integrator> integrator = make_integrator(fx.scene.integrator, fx.forces(), s.inv_mass);
  std::ostringstream log;
  integrator->prepare(s, log);
  integrator->step(s, h);  // fills the integrator's cached force
  HandPendulum hand(*fx.forces().stiff_bonds(), s);
  double t_engine = 0.0, t_hand = 0.0, max_diff = 0.0;
  for (auto _ : st) {
    const double t0 = cpu_seconds();
    for (int i = 0; i < kPendulumBatch; ++i) integrator->step(s, h);
    benchmark::ClobberMemory();
    t_engine += cpu_seconds() - t0;
    t_hand += hand_batch_seconds(hand, h);
    for (int p = 0; p < 3; ++p)
      for (int a = 0; a < 3; ++a) max_diff = std::max(max_diff, std::abs(hand.x(a, p) - s.x(a, p)));
    hand.load(s);  // restart the hand loop from the engine's state: the batches follow one trajectory
  }
  const double steps = static_cast<double>(st.iterations()) * kPendulumBatch;
  st.counters["engine_ns_per_step"] = 1e9 * t_engine / steps;
  st.counters["hand_ns_per_step"] = 1e9 * t_hand / steps;
  st.counters["engine_over_hand"] = t_engine / t_hand;
  st.counters["max_position_difference"] = max_diff;
}

// The same against the whole run path: engine/run's Run, as `stiffmd run` drives it (signal
// handlers installed, no screen, no progress bar, no output directory), stepped by step_to in
// batches of kBatch steps, the thermo sample (and with it the monitor) at an interval longer than
// the run: every step pays for what a step between outputs costs — the integrator, the
// finiteness check, the output schedule, the signal poll. Each side follows its own trajectory
// from the same initial state for kPendulumRunSteps steps (10⁷), interleaved by batches; at the
// end their positions and velocities must be the same bits, or the benchmark fails. Counters:
// CPU ns per step of the run path and of the hand loop, and run_over_hand (target ≤ 1.5).
constexpr std::int64_t kPendulumRunSteps = 10'000'000;

void BM_PendulumRunVsHandWritten(benchmark::State& st) {
  std::vector<std::string> sets = kPendulumVerlet;
  sets.insert(sets.end(), {"run.steps=" + std::to_string(kPendulumRunSteps), "output.thermo_interval=1e4",
                           "output.xyz=\"\"", "output.h5md=\"\""});
  Fixture fx = load_fixture("Pendulum", std::string(STIFFMD_SOURCE_DIR) + "/inputs/double_pendulum.toml", sets);
  if (!fx.ok()) {
    st.SkipWithError(fx.error.c_str());
    return;
  }
  const double h = fx.scene.integrator.h;
  RunOptions options;  // as `stiffmd run -q --no-progress` without -o: no files
  std::ostringstream log;
  Run run(fx.scene, options, log);
  HandPendulum hand(*fx.forces().stiff_bonds(), fx.initial);
  const State& s = fx.scene.state;
  double t_run = 0.0, t_hand = 0.0;
  for (auto _ : st) {
    const double t0 = cpu_seconds();
    run.step_to(s.step + kPendulumBatch);
    benchmark::ClobberMemory();
    t_run += cpu_seconds() - t0;
    t_hand += hand_batch_seconds(hand, h);
  }
  bool same = s.step == kPendulumRunSteps;
  for (int p = 0; p < 3; ++p)
    for (int a = 0; a < 3; ++a) same = same && hand.x(a, p) == s.x(a, p) && hand.v(a, p) == s.v(a, p);
  if (!same) st.SkipWithError("the run and the hand-written loop did not end on the same bits");
  const double steps = static_cast<double>(st.iterations()) * kPendulumBatch;
  st.counters["run_ns_per_step"] = 1e9 * t_run / steps;
  st.counters["hand_ns_per_step"] = 1e9 * t_hand / steps;
  st.counters["run_over_hand"] = t_run / t_hand;
}

// The constraint work of a RATTLE step on rigid water, per water: from x on the manifold with
// tangent velocities (Maxwell–Boltzmann at 300 K, projected), free flight at the deck's h (2 fs):
// x ← x + h v, SHAKE back onto the manifold from x_old, v ← (x − x_old)/h (the chord velocity),
// the velocity projection at x — what `rattle` does per step without forces (NVE; constrained
// BAOAB does the position half twice). Only the two constraint calls are timed, in process CPU
// time (ns_per_water_*: run it on one thread, OMP_NUM_THREADS=1, as a shared machine's wall time
// is not the work); the step follows one trajectory. `general`: the engine's ConstraintToolbox
// (each triangle a cluster of 3 bonds, SHAKE to max |g| ≤ 1e-12 Å); `settle`: the analytic SETTLE
// of settle.hpp.
// Counters: max_violation of the last step; difference_100_steps, the largest coordinate
// difference between the two solvers after 100 steps from the same start (both solve the same
// equations: SHAKE's tolerance and round-off apart).
struct WaterConstraintCase {
  std::vector<bench::SettleWater> waters;
  double m_o = 0.0, m_h = 0.0, d_oh = 0.0, d_hh = 0.0;
  std::string error;  // non-empty: the scene's stiff bonds are not rigid water triangles
};

WaterConstraintCase water_triangles(const Fixture& fx) {
  WaterConstraintCase c;
  const std::vector<StiffBond>& bonds = fx.scene.forces->stiff_bonds()->bonds;
  const Eigen::VectorXd& w = fx.initial.inv_mass;
  for (const ConstraintCluster& cl : find_clusters(bonds, w)) {
    if (cl.bonds.size() != 3 || cl.particles.size() != 3) {
      c.error = "a constraint cluster is not a triangle";
      return c;
    }
    // The apex: the particle opposite the bond whose two neighbours have equal lengths.
    const size_t found = c.waters.size();
    for (int k = 0; k < 3; ++k) {
      const StiffBond& base = bonds[static_cast<size_t>(cl.bonds[k])];
      const StiffBond& a = bonds[static_cast<size_t>(cl.bonds[(k + 1) % 3])];
      const StiffBond& b = bonds[static_cast<size_t>(cl.bonds[(k + 2) % 3])];
      if (a.length != b.length) continue;
      int apex = -1;
      for (const int p : cl.particles)
        if (p != base.i && p != base.j) apex = p;
      c.waters.push_back({apex, base.i, base.j});
      c.d_oh = a.length, c.d_hh = base.length;
      break;
    }
    if (c.waters.size() == found) {
      c.error = "a triangle has no two sides of equal length (no apex for SETTLE)";
      return c;
    }
    const bench::SettleWater& s = c.waters.back();
    c.m_o = 1.0 / w[s.o], c.m_h = 1.0 / w[s.h1];
    if (w[s.h1] != w[s.h2]) c.error = "a triangle's base masses differ";
  }
  return c;
}

// One solver's step: position and velocity halves, by the toolbox or by SETTLE.
struct WaterSolver {
  virtual ~WaterSolver() = default;
  virtual void positions(const Eigen::Matrix3Xd& x_old, Eigen::Matrix3Xd& x) = 0;
  virtual void velocities(const Eigen::Matrix3Xd& x, Eigen::Matrix3Xd& v) = 0;
};
struct GeneralSolver final : WaterSolver {
  ConstraintToolbox toolbox;
  GeneralSolver(const std::vector<StiffBond>& bonds, const Eigen::VectorXd& w) : toolbox(bonds, w) {}
  void positions(const Eigen::Matrix3Xd& x_old, Eigen::Matrix3Xd& x) override { toolbox.shake(x_old, x); }
  void velocities(const Eigen::Matrix3Xd& x, Eigen::Matrix3Xd& v) override { toolbox.project_velocity(x, v); }
};
struct SettleSolver final : WaterSolver {
  const WaterConstraintCase& c;
  bench::SettleGeometry g;
  explicit SettleSolver(const WaterConstraintCase& wc) : c(wc), g(wc.m_o, wc.m_h, wc.d_oh, wc.d_hh) {}
  void positions(const Eigen::Matrix3Xd& x_old, Eigen::Matrix3Xd& x) override {
    for (const bench::SettleWater& w : c.waters) bench::settle_positions(g, w, x_old, x);
  }
  void velocities(const Eigen::Matrix3Xd& x, Eigen::Matrix3Xd& v) override {
    for (const bench::SettleWater& w : c.waters) bench::settle_velocities(g, w, x, v);
  }
};

void BM_WaterConstraints(benchmark::State& st, FixtureGetter get, bool settle) {
  Fixture* fx = fixture_or_skip(st, get);
  if (!fx) return;
  const WaterConstraintCase wc = water_triangles(*fx);
  if (!wc.error.empty()) {
    st.SkipWithError(wc.error.c_str());
    return;
  }
  const std::vector<StiffBond>& bonds = fx->forces().stiff_bonds()->bonds;
  const Eigen::VectorXd& inv_mass = fx->initial.inv_mass;
  const double h = fx->scene.integrator.h;
  // The start: x on the manifold, tangent Maxwell–Boltzmann velocities at 300 K.
  ConstraintToolbox start(bonds, inv_mass);
  Eigen::Matrix3Xd x0 = fx->initial.x;
  start.shake(x0, x0, nullptr, 1e-12, 200);
  Eigen::Matrix3Xd v0 = maxwell_boltzmann(inv_mass, fx->scene.units.kT(300.0), 7);
  start.project_velocity(x0, v0);
  const auto step = [h](WaterSolver& s, Eigen::Matrix3Xd& x, Eigen::Matrix3Xd& v, Eigen::Matrix3Xd& x_old,
                        double* t_pos, double* t_vel) {
    x_old = x;
    x += h * v;
    const double t0 = cpu_seconds();
    s.positions(x_old, x);
    const double t1 = cpu_seconds();
    v = (x - x_old) / h;
    const double t2 = cpu_seconds();
    s.velocities(x, v);
    const double t3 = cpu_seconds();
    if (t_pos) *t_pos += t1 - t0;
    if (t_vel) *t_vel += t3 - t2;
  };
  // The two solvers side by side from the same start: the same trajectory.
  GeneralSolver general(bonds, inv_mass);
  SettleSolver analytic(wc);
  {
    Eigen::Matrix3Xd xa = x0, va = v0, xb = x0, vb = v0, old;
    for (int k = 0; k < 100; ++k) {
      step(general, xa, va, old, nullptr, nullptr);
      step(analytic, xb, vb, old, nullptr, nullptr);
    }
    st.counters["difference_100_steps"] = (xa - xb).cwiseAbs().maxCoeff();
  }
  WaterSolver& solver = settle ? static_cast<WaterSolver&>(analytic) : general;
  Eigen::Matrix3Xd x = x0, v = v0, x_old;
  double t_pos = 0.0, t_vel = 0.0;
  for (auto _ : st) {
    step(solver, x, v, x_old, &t_pos, &t_vel);
    benchmark::ClobberMemory();
  }
  const double per_water = 1e9 / (static_cast<double>(st.iterations()) * static_cast<double>(wc.waters.size()));
  st.SetItemsProcessed(st.iterations() * static_cast<std::int64_t>(wc.waters.size()));
  st.counters["waters"] = static_cast<double>(wc.waters.size());
  st.counters["ns_per_water_positions"] = t_pos * per_water;
  st.counters["ns_per_water_velocities"] = t_vel * per_water;
  st.counters["ns_per_water_constraints"] = (t_pos + t_vel) * per_water;
  st.counters["max_violation"] = start.max_violation(x);
}

bool register_benchmarks() {
  const char* omp_threads = std::getenv("OMP_NUM_THREADS");
  benchmark::AddCustomContext("OMP_NUM_THREADS", omp_threads ? omp_threads : "(unset)");
  struct SceneCase {
    const char* name;
    FixtureGetter get;
    benchmark::TimeUnit unit;
  };
  for (const SceneCase sc : {SceneCase{"Synthetic", &synthetic, benchmark::kMicrosecond},
                             SceneCase{"Melt", &melt, benchmark::kMillisecond}}) {
    const std::string suffix = std::string("/") + sc.name;
    auto add = [&](const std::string& name, auto fn, auto... args) {
      benchmark::RegisterBenchmark((name + suffix).c_str(), fn, sc.get, args...)->Unit(sc.unit)->UseRealTime();
    };
    add("BM_PairForces", BM_PairForces);
    add("BM_PairVirialDiagonal", BM_PairVirialDiagonal);
    add("BM_MolecularPressure", BM_MolecularPressure);
    add("BM_NeighborBuild", BM_NeighborBuild);
    add("BM_BondForces", BM_BondForces);
    add("BM_ForceProjection", BM_ForceProjection);
    add("BM_Mollifier", BM_Mollifier);
    add("BM_Shake", BM_Shake);
    for (const MacroStepCase& c : kMacroSteps)
      add("BM_MacroStep/" + std::string(c.method) + (c.fused ? "" : "-unfused") + c.label, BM_MacroStep, c);
    add("BM_MicroStepVsFloor", BM_MicroStepVsFloor);
    add("BM_BondKernelPerBond", BM_BondKernelPerBond);
  }
  benchmark::RegisterBenchmark("BM_CoulLongPairForces/Water", BM_CoulLongPairForces, &water)
      ->Unit(benchmark::kMicrosecond)
      ->UseRealTime();
  for (const bool settle : {false, true})
    benchmark::RegisterBenchmark(settle ? "BM_WaterConstraints/settle" : "BM_WaterConstraints/general",
                                 BM_WaterConstraints, &water, settle)
        ->Unit(benchmark::kMicrosecond)
        ->UseRealTime();
  benchmark::RegisterBenchmark("BM_PendulumVsHandWritten", BM_PendulumVsHandWritten)
      ->Unit(benchmark::kMicrosecond)
      ->UseRealTime();
  benchmark::RegisterBenchmark("BM_PendulumRunVsHandWritten", BM_PendulumRunVsHandWritten)
      ->Iterations(kPendulumRunSteps / kPendulumBatch)
      ->Unit(benchmark::kMicrosecond)
      ->UseRealTime();
  return true;
}

[[maybe_unused]] const bool registered = register_benchmarks();

}  // namespace
}  // namespace stiffmd
