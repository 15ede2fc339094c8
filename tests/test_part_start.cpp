// The decomposed run's start from parts (engine/domain/decomposition.hpp `Decomposition::start`,
// engine/domain/domain_integrator.hpp `DomainIntegrator::distribute`; docs/parallel.md, "The
// design"): each rank gives any set of whole molecules, and the start sends each to the rank of
// its anchor's domain, keeping no table of the whole system's size. What must hold, on 1–4 fake
// ranks (tests/fake_processes.hpp):
//   - for every partition of the molecules (all on one rank, scattered at random, the whole
//     path's blocks) the grid, its load-balance cuts and each rank's owned ids, x, v and
//     PartMolecules are the ones the whole system's molecules cut by anchor give, bit for bit;
//   - a run started from scattered partitions is one process's trajectory bit for bit;
//   - the whole system's numbers the start sums from the parts (csvr's degrees of freedom,
//     whether the topology's molecule ids lie within bonded molecules, the effective dynamics'
//     clusters and their modes' numbering) are those one process computes from the whole scene:
//     pinned beads (a molecule of two clusters, listed apart), rigid bonds with csvr, a molecule
//     id spanning two bonded molecules.
#include <gtest/gtest.h>

#include <algorithm>
#include <memory>
#include <random>
#include <sstream>
#include <string>
#include <vector>

#include "core/molecule_anchor.hpp"
#include "decomposition_fixtures.hpp"
#include "domain_run_support.hpp"
#include "engine/domain/decomposition.hpp"
#include "engine/domain/domain_integrator.hpp"
#include "engine/domain/part_molecules.hpp"
#include "engine/run/run.hpp"
#include "fake_processes.hpp"
#include "integrators/clusters.hpp"
#include "integrators/methods.hpp"
#include "integrators/thermostat.hpp"
#include "test_support.hpp"

namespace stiffmd {
namespace {

using fake::FakeCommunicator;
using fake::run_ranks;

// Per particle of the straddling melt (tests/decomposition_fixtures.hpp): types, charges, molecule
// ids and frictions distinct by particle, so that a misplaced particle shows.
struct System {
  fake::Melt melt = fake::straddling_melt();
  std::vector<int> type, molecule_id;
  std::vector<double> charge, friction;
  System() {
    for (int g = 0; g < melt.size(); ++g) {
      type.push_back(g % 3);
      molecule_id.push_back(melt.label[static_cast<size_t>(g)]);
      charge.push_back(0.25 * (g % 5) - 0.5);
      friction.push_back(1.0 + 0.125 * g);
    }
  }
  WholeParticles whole() const {
    return {std::span<const double>(melt.state.inv_mass.data(), static_cast<size_t>(melt.size())),
            type,
            charge,
            molecule_id,
            friction,
            melt.topology};
  }
};

// What a rank holds after the start.
struct Started {
  DomainGrid grid;
  double imbalance_before = 0.0;
  long recuts = 0;
  std::vector<int> ids, names;
  Eigen::Matrix3Xd x, v;
  PartMolecules molecules;
};

// The particles of the molecules (the melt's labels) with part[label] == rank, increasing.
std::vector<int> particles_of(const fake::Melt& melt, const std::vector<int>& part, int rank) {
  std::vector<int> out;
  for (int g = 0; g < melt.size(); ++g)
    if (part[static_cast<size_t>(melt.label[g])] == rank) out.push_back(g);
  return out;
}

// The start on `ranks` ranks, each giving the molecules `part` assigns it (empty: the whole path's
// blocks, Decomposition::distribute).
std::vector<Started> start_on(const System& s, int ranks, const std::vector<int>& part, bool balanced) {
  std::vector<Started> out(static_cast<size_t>(ranks));
  run_ranks(ranks, [&](const FakeCommunicator& comm) {
    Decomposition d(s.melt.box, comm, 2.5, 0.8, nullptr);
    if (balanced) d.set_balance({BalanceSettings::When::start, 1.0});
    Started& o = out[static_cast<size_t>(comm.rank())];
    if (part.empty()) {
      d.distribute(s.melt.topology, s.melt.state, o.x, o.v);
    } else {
      const std::vector<int> mine = particles_of(s.melt, part, comm.rank());
      o.molecules = cut_part(s.whole(), mine);
      o.x.resize(3, static_cast<Eigen::Index>(mine.size()));
      o.v.resize(3, static_cast<Eigen::Index>(mine.size()));
      for (size_t k = 0; k < mine.size(); ++k)
        o.x.col(k) = s.melt.state.x.col(mine[k]), o.v.col(k) = s.melt.state.v.col(mine[k]);
      d.start(o.molecules, o.x, o.v);
    }
    o.grid = d.grid();
    o.imbalance_before = d.imbalance_before();
    o.recuts = d.recuts();
    o.ids = d.owned_ids();
    for (int k = 0; k < d.num_owned(); ++k) o.names.push_back(d.owned_molecule(k));
  });
  return out;
}

bool same_grid(const DomainGrid& a, const DomainGrid& b) {
  return a.dims == b.dims && a.origin == b.origin && a.length == b.length && a.periodic == b.periodic && a.cut == b.cut;
}

// The owned particles the whole system's molecules give each rank on `grid`: each molecule's
// anchor (its centre of mass summed by increasing global index, MoleculeAnchor) in the domain.
std::vector<std::vector<int>> owned_by_anchor(const fake::Melt& melt, const DomainGrid& grid) {
  std::vector<std::vector<int>> owned(static_cast<size_t>(grid.size()));
  for (int m = 0; m < melt.molecules; ++m) {
    MoleculeAnchor anchor;
    const std::vector<int> members = melt.members(m);
    for (int g : members) anchor.add(anchor_mass(melt.state.inv_mass[g]), melt.state.x.col(g));
    const int r = fake::rank_of_point(grid, anchor.value());
    owned[r].insert(owned[r].end(), members.begin(), members.end());
  }
  for (auto& o : owned) std::sort(o.begin(), o.end());
  return owned;
}

class PartStartOnFakeRanks : public ::testing::TestWithParam<std::tuple<int, bool>> {};

TEST_P(PartStartOnFakeRanks, AnyPartitionOfTheMoleculesGivesTheWholeCutByAnchorBitForBit) {
  const auto [ranks, balanced] = GetParam();
  const System s;
  const fake::Melt& melt = s.melt;
  // The whole path's blocks first: the grid every other partition must reproduce.
  const std::vector<Started> blocks = start_on(s, ranks, {}, balanced);
  const DomainGrid& grid = blocks[0].grid;
  if (balanced && ranks > 1) {
    EXPECT_GE(blocks[0].recuts, 1) << "the start's recut is not tested";
  }
  const std::vector<std::vector<int>> want = owned_by_anchor(melt, grid);
  std::vector<std::vector<int>> partitions;
  partitions.push_back(std::vector<int>(static_cast<size_t>(melt.molecules), 0));  // all on rank 0
  partitions.push_back(std::vector<int>(static_cast<size_t>(melt.molecules), ranks - 1));
  std::mt19937 rng(17);
  for (int k = 0; k < 3; ++k) {
    std::uniform_int_distribution<int> pick(0, ranks - 1);
    std::vector<int> p;
    for (int m = 0; m < melt.molecules; ++m) p.push_back(pick(rng));
    partitions.push_back(p);
  }
  int moved_somewhere = 0;
  for (size_t q = 0; q <= partitions.size(); ++q) {
    const std::vector<Started> got = q == 0 ? blocks : start_on(s, ranks, partitions[q - 1], balanced);
    int total = 0;
    for (int r = 0; r < ranks; ++r) {
      const Started& o = got[static_cast<size_t>(r)];
      SCOPED_TRACE("partition " + std::to_string(q) + ", rank " + std::to_string(r));
      EXPECT_TRUE(same_grid(o.grid, grid));
      EXPECT_EQ(o.imbalance_before, blocks[0].imbalance_before);
      EXPECT_EQ(o.recuts, blocks[0].recuts);
      ASSERT_EQ(o.ids, want[static_cast<size_t>(r)]);
      total += static_cast<int>(o.ids.size());
      Eigen::Matrix3Xd x(3, static_cast<Eigen::Index>(o.ids.size())), v = x;
      for (size_t k = 0; k < o.ids.size(); ++k)
        x.col(k) = melt.state.x.col(o.ids[k]), v.col(k) = melt.state.v.col(o.ids[k]);
      EXPECT_TRUE(o.x == x);
      EXPECT_TRUE(o.v == v);
      // Each particle's molecule named by the molecule's first particle.
      for (size_t k = 0; k < o.ids.size(); ++k)
        EXPECT_EQ(o.names[k], melt.members(melt.label[o.ids[k]]).front()) << "particle " << o.ids[k];
      if (q == 0) continue;
      const PartMolecules cut = cut_part(s.whole(), o.ids);
      EXPECT_EQ(o.molecules.global, cut.global);
      EXPECT_EQ(o.molecules.inv_mass, cut.inv_mass);
      EXPECT_EQ(o.molecules.type, cut.type);
      EXPECT_EQ(o.molecules.charge, cut.charge);
      EXPECT_EQ(o.molecules.molecule_id, cut.molecule_id);
      EXPECT_EQ(o.molecules.friction, cut.friction);
      const Topology a = o.molecules.topology(melt.topology), b = cut.topology(melt.topology);
      ASSERT_EQ(a.bonds.size(), b.bonds.size());
      ASSERT_EQ(a.angles.size(), b.angles.size());
      for (size_t e = 0; e < a.bonds.size(); ++e) {
        EXPECT_EQ(o.molecules.bonds[e].place, cut.bonds[e].place);
        EXPECT_EQ(a.bonds[e].i, b.bonds[e].i);
        EXPECT_EQ(a.bonds[e].j, b.bonds[e].j);
      }
      for (size_t e = 0; e < a.angles.size(); ++e) EXPECT_EQ(o.molecules.angles[e].place, cut.angles[e].place);
      moved_somewhere += o.ids != particles_of(melt, partitions[q - 1], r);
    }
    EXPECT_EQ(total, melt.size());
  }
  if (ranks > 1) {
    EXPECT_GT(moved_somewhere, 0) << "no molecule was sent: the start's exchange is not tested";
  }
}

INSTANTIATE_TEST_SUITE_P(Ranks, PartStartOnFakeRanks,
                         ::testing::Combine(::testing::Values(1, 2, 3, 4), ::testing::Bool()),
                         [](const ::testing::TestParamInfo<std::tuple<int, bool>>& info) {
                           return std::to_string(std::get<0>(info.param)) + "_ranks" +
                                  (std::get<1>(info.param) ? "_balanced" : "");
                         });

// The butane fluid with a drift (molecules migrate within the run), as tests/test_part_molecules.cpp.
constexpr int kSteps = 60;
const std::vector<std::string> kButane = {"variables.eps=0.1",          "integrator.method=velocity-verlet",
                                          "integrator.h=0.002",         "thermostat.style=langevin",
                                          "thermostat.temperature=1.0", "thermostat.damp=20.0",
                                          "thermostat.seed=3",          "prepare.relax_steps=20"};

Scene butane() {
  Scene sc = test::load("inputs/butane_torsions.toml", kButane);
  sc.state.v.array() += 12.0;
  return sc;
}

class PartStartRuns : public ::testing::TestWithParam<int> {};

TEST_P(PartStartRuns, ARunStartedFromScatteredMoleculesIsOneProcesssBitForBit) {
  const int ranks = GetParam();
  const test::OneThread one_thread;
  Scene serial = butane();
  test::run_one_process(serial, kSteps);
  for (const unsigned seed : {1u, 2u}) {
    std::vector<Eigen::Matrix3Xd> x(static_cast<size_t>(ranks)), v(x);
    std::vector<double> migrated(static_cast<size_t>(ranks), 0.0);
    run_ranks(
        ranks,
        [&](const FakeCommunicator& comm) {
          const test::OneThread rank_thread;
          Scene sc = butane();
          State s = sc.state;
          const double h = sc.integrator.h;
          auto d = std::make_unique<DomainIntegrator>(sc, comm,
                                                      make_integrator(sc.integrator, *sc.forces, sc.state.inv_mass));
          std::ostringstream log;
          d->prepare(s, log);
          test::Given given = test::scattered(sc, s, comm.size(), comm.rank(), seed);
          d->distribute(std::move(given.molecules), std::move(given.x), std::move(given.v), s);
          for (int k = 1; k <= kSteps; ++k) take_step(*d, s, h, k, k * h, false);
          migrated[comm.rank()] = static_cast<double>(d->report().migrated_molecules);
          d->gather(s);
          if (comm.root()) x[0] = s.x, v[0] = s.v;
        },
        std::chrono::seconds(120));
    if (ranks > 1) {
      EXPECT_GE(migrated[0], 1.0) << "no molecule migrated within the run";
    }
    EXPECT_TRUE(x[0] == serial.state.x) << "seed " << seed;
    EXPECT_TRUE(v[0] == serial.state.v) << "seed " << seed;
  }
}

INSTANTIATE_TEST_SUITE_P(Ranks, PartStartRuns, ::testing::Values(1, 2, 3, 4));

// The whole system's numbers as one process computes them from the whole scene (the
// DomainIntegrator's constructor did so before the start summed them from the parts).
struct WholeNumbers {
  int dof = 0;
  bool molecules_whole = true;
  std::vector<std::array<int, 3>> clusters;  // molecule (its first particle), first mode, modes
  ThermoNumbers thermo;                      // the whole Thermo's degrees of freedom and rg, end_to_end columns
};

WholeNumbers from_whole_scene(const Scene& sc) {
  WholeNumbers w;
  const int n = sc.state.size();
  const std::vector<int> molecule = bonded_molecules(sc.topology, n);
  std::vector<int> first(static_cast<size_t>(n), -1);  // per molecule, its first particle
  for (int g = n - 1; g >= 0; --g) first[molecule[g]] = g;
  const std::vector<int>& id = sc.topology.molecule;
  std::vector<int> bonded_of_id;
  for (size_t i = 0; i < id.size(); ++i) {
    if (id[i] < 0) continue;
    if (static_cast<size_t>(id[i]) >= bonded_of_id.size()) bonded_of_id.resize(id[i] + 1, -1);
    int& b = bonded_of_id[id[i]];
    if (b < 0) b = molecule[i];
    if (b != molecule[i]) w.molecules_whole = false;
  }
  const MethodInfo* m = find_method(sc.integrator.method);
  const StiffBonds* stiff = sc.forces->stiff_bonds();
  const int rigid = m->rigid_constraints && stiff ? static_cast<int>(stiff->bonds.size()) : 0;
  const Eigen::VectorXd& im = sc.state.inv_mass;
  w.dof = degrees_of_freedom(im, momentum_conserved(*sc.forces, im, sc.integrator.thermostat), rigid);
  // The thermo row's columns as the whole scene's masses and topology make them (the Run's
  // observables: one degree of freedom less per rigid constraint).
  ObservableSettings observables = sc.observables;
  observables.rigid_constraints = m->rigid_constraints ? rigid : 0;
  const Thermo thermo(*sc.forces, im, observables, &sc.topology);
  w.thermo = {thermo.degrees_of_freedom(), thermo.column("rg") >= 0, thermo.column("end_to_end") >= 0};
  if (m->effective && stiff) {
    int mode = 0;
    for (const ConstraintCluster& c : find_clusters(stiff->bonds, im)) {
      w.clusters.push_back({first[molecule[stiff->bonds[c.bonds[0]].i]], mode, static_cast<int>(c.bonds.size())});
      mode += static_cast<int>(c.bonds.size());
    }
  }
  return w;
}

struct NumbersCase {
  std::string name, deck;
  std::vector<std::string> overrides;
  bool join_two_molecules = false;  // give the first two bonded molecules one molecule id
  std::vector<int> ranks = {1, 2, 3, 4};
};

void PrintTo(const NumbersCase& c, std::ostream* os) {
  *os << c.name;
}

Scene load_case(const NumbersCase& c) {
  Scene sc = test::load(c.deck, c.overrides);
  if (c.join_two_molecules) {
    const int n = sc.state.size();
    const std::vector<int> molecule = bonded_molecules(sc.topology, n);
    sc.topology.molecule.assign(molecule.begin(), molecule.end());
    for (int& id : sc.topology.molecule) id = id == 1 ? 0 : id;
  }
  return sc;
}

class WholeNumbersFromParts : public ::testing::TestWithParam<NumbersCase> {};

TEST_P(WholeNumbersFromParts, AreTheWholeScenesOnAnyRanksAndPartition) {
  const NumbersCase& c = GetParam();
  const Scene reference = load_case(c);
  const WholeNumbers want = from_whole_scene(reference);
  if (c.join_two_molecules) {
    EXPECT_FALSE(want.molecules_whole);
  }
  for (const int ranks : c.ranks)
    for (const bool scatter : {false, true}) {
      std::vector<WholeNumbers> got(static_cast<size_t>(ranks));
      run_ranks(
          ranks,
          [&](const FakeCommunicator& comm) {
            const test::OneThread rank_thread;
            Scene sc = load_case(c);
            State s = sc.state;
            auto d = std::make_unique<DomainIntegrator>(sc, comm,
                                                        make_integrator(sc.integrator, *sc.forces, sc.state.inv_mass));
            if (scatter) {
              test::Given given = test::scattered(sc, s, comm.size(), comm.rank(), 7u + static_cast<unsigned>(ranks));
              d->distribute(std::move(given.molecules), std::move(given.x), std::move(given.v), s);
            } else {
              d->distribute(s);
            }
            WholeNumbers& w = got[static_cast<size_t>(comm.rank())];
            w.dof = d->whole_degrees_of_freedom();
            w.thermo = d->thermo_numbers();
            w.molecules_whole = d->molecules_whole();
            for (const DomainIntegrator::Cluster& k : d->clusters())
              w.clusters.push_back({k.molecule, k.first, k.modes});
          },
          std::chrono::seconds(120));
      for (int r = 0; r < ranks; ++r) {
        SCOPED_TRACE(std::to_string(ranks) + " ranks, rank " + std::to_string(r) + (scatter ? ", scattered" : ""));
        EXPECT_EQ(got[r].dof, want.dof);
        EXPECT_EQ(got[r].molecules_whole, want.molecules_whole);
        EXPECT_EQ(got[r].clusters, want.clusters);
        // The thermo row's numbers, and the columns they make, are the whole scene's when every
        // topology molecule lies within one bonded molecule (the rows are then summed by parts).
        if (want.molecules_whole) {
          EXPECT_EQ(got[r].thermo.degrees_of_freedom, want.thermo.degrees_of_freedom);
          EXPECT_EQ(got[r].thermo.rg, want.thermo.rg);
          EXPECT_EQ(got[r].thermo.end_to_end, want.thermo.end_to_end);
          const ObservableSettings& observables = reference.observables;
          const Thermo from_parts(*reference.forces, got[r].thermo, observables);
          const Thermo whole(*reference.forces, reference.state.inv_mass, observables, &reference.topology);
          EXPECT_EQ(from_parts.columns(), whole.columns());
        }
      }
    }
}

TEST(ThermoFromNumbers, MakesTheWholeScenesColumnsAndRefusesWholeStateColumns) {
  // A chain melt: rg and end_to_end columns from the numbers, none without them.
  const Scene sc = test::load("inputs/stiff_melt_nvt.toml", {});
  ObservableSettings o = sc.observables;
  const Thermo whole(*sc.forces, sc.state.inv_mass, o, &sc.topology);
  ASSERT_GE(whole.column("rg"), 0);
  ASSERT_GE(whole.column("end_to_end"), 0);
  const Thermo numbers(*sc.forces, ThermoNumbers{whole.degrees_of_freedom(), true, true}, o);
  EXPECT_EQ(numbers.columns(), whole.columns());
  EXPECT_EQ(numbers.degrees_of_freedom(), whole.degrees_of_freedom());
  const Thermo no_polymers(*sc.forces, ThermoNumbers{whole.degrees_of_freedom(), false, false}, o);
  EXPECT_LT(no_polymers.column("rg"), 0);
  EXPECT_LT(no_polymers.column("end_to_end"), 0);
  // Rows from sums only: sums(s) of the whole state is refused (it would have no polymer sums).
  EXPECT_THROW((void)numbers.sums(sc.state), std::logic_error);
  ObservableSettings actions = o;
  actions.actions = true;
  EXPECT_THROW(Thermo(*sc.forces, ThermoNumbers{}, actions), std::logic_error);
}

INSTANTIATE_TEST_SUITE_P(
    Decks, WholeNumbersFromParts,
    ::testing::Values(
        // Pinned cores: a molecule of two clusters, its arms listed apart; no momentum conserved.
        NumbersCase{"pinned_cores", "tests/decks/pinned_cores.toml", {"integrator.method=effective"}},
        // 3 000 beads: their [prepare] on each fake rank is the test's time, so two rank counts.
        NumbersCase{"stiff_melt_effective",
                    "inputs/stiff_melt_nvt.toml",
                    {"integrator.method=effective", "integrator.h=0.02"},
                    false,
                    {1, 3}},
        // Rigid bonds and csvr: 3 N − 3 − bonds.
        NumbersCase{"stiff_melt_rattle_csvr",
                    "inputs/stiff_melt_nvt.toml",
                    {"integrator.method=rattle", "integrator.h=0.005",
                     "thermostat={ style = \"csvr\", temperature = 1.0, tau = 0.5, seed = 14 }"},
                    false,
                    {2, 4}},
        NumbersCase{"butane", "inputs/butane_torsions.toml", kButane},
        NumbersCase{"butane_one_id_over_two_molecules", "inputs/butane_torsions.toml", kButane, true}),
    [](const ::testing::TestParamInfo<NumbersCase>& info) { return info.param.name; });

}  // namespace
}  // namespace stiffmd
