// What the pair sets read of a bead besides its position — its type, its charge and its special
// partners — carried with the bead from its owner at each selection (Decomposition::
// set_owned_pair_data, select_pair_set, pair_data; docs/parallel.md "The design"), never read from
// arrays of the whole system. On tests/decks/charged_butane.toml (two types with opposite charges,
// a charged pair term with 1-2, 1-3 and 1-4 weights apart for its van der Waals and Coulomb parts,
// an uncharged one with other weights):
// - a part's pair terms give its beads' special partners (special_partners of the part's term,
//   made from the part's bonds with the term's weights) as the whole system's term gives those
//   beads' rows, weights included, for parts of 1–4 ranks;
// - on 1–4 fake ranks (tests/fake_processes.hpp) every slot of every pair set holds its bead's
//   type, charge and rows of the whole system, and pair_slot and pair_slot_near find every global
//   index's slot;
// - a decomposed run with the whole scene's types swapped, its charges NaN and its pair terms moved
//   onto swapped types, NaN charges and no special pairs after the start is one process's
//   trajectory bit for bit, which fails if a pair set reads any of them.
#include <gtest/gtest.h>

#include <algorithm>
#include <functional>
#include <limits>
#include <memory>
#include <random>
#include <sstream>
#include <string>
#include <vector>

#include "core/parallel.hpp"
#include "domain_run_support.hpp"
#include "engine/domain/decomposition.hpp"
#include "engine/domain/domain_integrator.hpp"
#include "engine/domain/ghosted_pairs.hpp"
#include "engine/domain/part_molecules.hpp"
#include "engine/run/run.hpp"
#include "fake_processes.hpp"
#include "forcefields/pair_term.hpp"
#include "forcefields/particle_subset.hpp"
#include "integrators/methods.hpp"
#include "test_support.hpp"

namespace stiffmd {
namespace {

using fake::FakeCommunicator;
using fake::run_ranks;

constexpr int kSteps = 150;
constexpr double kDrift = 8.0;  // along the box's diagonal: molecules cross the domains' faces

Scene charged_butane() {
  Scene sc = test::load("tests/decks/charged_butane.toml");
  sc.state.v.array() += kDrift;
  return sc;
}

// The whole scene's pair terms (neighbour-list terms), in the force field's order.
std::vector<const PairsOnParticles*> pair_terms(const Scene& sc) {
  std::vector<const PairsOnParticles*> out;
  for (const auto& t : sc.forces->terms())
    if (t->uses_neighbor_list()) out.push_back(dynamic_cast<const PairsOnParticles*>(t.get()));
  return out;
}

// The rows of the whole system's special partners of each term (special_partners over 0 … N − 1):
// what the pair sets should hold.
std::vector<SpecialPartners> whole_rows(const Scene& sc) {
  std::vector<int> every(static_cast<size_t>(sc.state.size()));
  for (size_t g = 0; g < every.size(); ++g) every[g] = static_cast<int>(g);
  std::vector<SpecialPartners> rows;
  for (const PairsOnParticles* t : pair_terms(sc)) rows.push_back(special_partners(t->special_pairs(), every));
  return rows;
}

// Row k of `got` is row g of `want`: the same partners by global index, in the same order, with
// the same weights.
void expect_row(const SpecialPartners& got, int k, const SpecialPartners& want, int g, const std::string& where) {
  const int n = got.start[k + 1] - got.start[k];
  ASSERT_EQ(n, want.start[g + 1] - want.start[g]) << where;
  for (int q = 0; q < n; ++q) {
    EXPECT_EQ(got.partner[got.start[k] + q], want.partner[want.start[g] + q]) << where;
    EXPECT_EQ(got.weight[got.start[k] + q], want.weight[want.start[g] + q]) << where;
    EXPECT_EQ(got.weight_coul[got.start[k] + q], want.weight_coul[want.start[g] + q]) << where;
  }
}

// A part of the molecules `global` (increasing, whole molecules) with the scene's pair terms on it,
// as DomainIntegrator::build_part makes them: what its beads carry to the pair sets.
PairBeadData carried_by_part(const Scene& sc, const std::vector<int>& global) {
  const PartMolecules part = cut_part({std::span<const double>(sc.state.inv_mass.data(), sc.state.inv_mass.size()),
                                       sc.particle_type,
                                       sc.charge,
                                       sc.topology.molecule,
                                       {},
                                       sc.topology},
                                      global);
  const Topology t = part.topology(sc.topology);
  const auto on_part = sc.forces->on_subset({part.global, part.type, t, part.charge});
  PairBeadData d;
  d.charged = true;
  d.type = part.type;
  d.charge = part.charge;
  for (const auto& term : on_part->terms())
    if (term->uses_neighbor_list())
      d.special.push_back(special_partners(dynamic_cast<const PairsOnParticles&>(*term).special_pairs(), part.global));
  return d;
}

TEST(PairSetData, APartsSpecialPartnersAreTheWholeTermsRowsOfItsBeads) {
  const Scene sc = charged_butane();
  const int n = sc.state.size();
  const std::vector<SpecialPartners> want = whole_rows(sc);
  ASSERT_EQ(want.size(), 2u);
  // The deck's weights: 1-2 pairs both excluded, 1-3 and 1-4 scaled by the charged term, 1-3
  // excluded by the soft one (its 1-4 weight is 1: no 1-4 pairs).
  EXPECT_EQ(want[0].partner.size(), static_cast<size_t>(2 * (3 + 2 + 1) * 80));
  EXPECT_EQ(want[1].partner.size(), static_cast<size_t>(2 * (3 + 2) * 80));
  const std::vector<int> molecule = bonded_molecules(sc.topology, n);
  std::mt19937 rng(11);
  for (int parts = 1; parts <= 4; ++parts) {
    std::uniform_int_distribution<int> pick(0, parts - 1);
    std::vector<int> part_of(static_cast<size_t>(n));
    for (int m = 0; m < n; ++m) part_of[m] = pick(rng);
    for (int r = 0; r < parts; ++r) {
      std::vector<int> global;
      for (int g = 0; g < n; ++g)
        if (part_of[molecule[g]] == r) global.push_back(g);
      const PairBeadData d = carried_by_part(sc, global);
      ASSERT_EQ(d.special.size(), want.size());
      for (size_t t = 0; t < want.size(); ++t) {
        ASSERT_EQ(d.special[t].size(), static_cast<int>(global.size()));
        for (size_t k = 0; k < global.size(); ++k)
          expect_row(d.special[t], static_cast<int>(k), want[t], global[k],
                     "term " + std::to_string(t) + ", particle " + std::to_string(global[k]));
      }
    }
  }
}

class PairSetDataOnFakeRanks : public ::testing::TestWithParam<int> {};

// Each slot of each rank's pair set holds what the whole system gives its bead.
TEST_P(PairSetDataOnFakeRanks, EverySlotHoldsItsBeadsTypeChargeAndSpecialPartners) {
  const int ranks = GetParam();
  const Scene sc = charged_butane();
  const int n = sc.state.size();
  const std::vector<SpecialPartners> want = whole_rows(sc);
  double cutoff = 0.0;
  for (const auto& t : sc.forces->terms())
    if (t->uses_neighbor_list()) cutoff = std::max(cutoff, t->pair_cutoff());
  std::vector<long> held(static_cast<size_t>(ranks), 0);  // per rank, the beads another rank owns
  run_ranks(ranks, [&](const FakeCommunicator& comm) {
    Decomposition d(sc.box, comm, cutoff, 0.45, nullptr);
    Eigen::Matrix3Xd x, v;
    d.distribute(sc.topology, sc.state, x, v);
    d.set_owned_pair_data(carried_by_part(sc, d.owned_ids()));
    // Twice: the second selection reuses the pair set's buffers.
    for (int selection = 0; selection < 2; ++selection) {
      if (selection == 1) x.array() += 0.3;
      d.select_pair_set(x);
      const std::vector<int>& ids = d.pair_ids();
      const PairBeadData& p = d.pair_data();
      // Increasing global indices, each once: what pair_slot's search needs.
      ASSERT_TRUE(std::adjacent_find(ids.begin(), ids.end(), std::greater_equal<int>()) == ids.end());
      ASSERT_TRUE(p.charged);
      ASSERT_EQ(p.type.size(), ids.size());
      ASSERT_EQ(p.charge.size(), ids.size());
      ASSERT_EQ(p.special.size(), want.size());
      for (size_t e = 0; e < ids.size(); ++e) {
        const int g = ids[e];
        EXPECT_EQ(p.type[e], sc.particle_type[g]) << "particle " << g;
        EXPECT_EQ(p.charge[e], sc.charge[g]) << "particle " << g;
        for (size_t t = 0; t < want.size(); ++t)
          expect_row(p.special[t], static_cast<int>(e), want[t], g,
                     "rank " + std::to_string(comm.rank()) + ", term " + std::to_string(t) + ", particle " +
                         std::to_string(g));
      }
      // Every global index's slot, from any slot.
      std::vector<int> slot_of(static_cast<size_t>(n), -1);
      for (size_t e = 0; e < ids.size(); ++e) slot_of[ids[e]] = static_cast<int>(e);
      const int m = static_cast<int>(ids.size());
      for (int g = 0; g < n; ++g) {
        EXPECT_EQ(d.pair_slot(g), slot_of[g]) << "particle " << g;
        for (const int near : {0, m / 3, m / 2, m - 1, slot_of[g] - 1, slot_of[g] + 2})
          EXPECT_EQ(d.pair_slot_near(g, near), slot_of[g]) << "particle " << g << " from slot " << near;
      }
      // The beads that arrived from other owners (the ones whose data came in a message).
      long arrived = 0;
      for (const int g : ids) arrived += !std::binary_search(d.owned_ids().begin(), d.owned_ids().end(), g);
      held[comm.rank()] = arrived;
    }
  });
  if (ranks > 1) {
    for (int r = 0; r < ranks; ++r) EXPECT_GT(held[r], 0) << "rank " << r << ": no bead came from another owner";
  }
}

// The whole scene's types, charges and pair terms made useless after the start: types A and B
// swapped (other coefficients, other masses' types), charges NaN, and each whole pair term moved
// onto those with no special pairs.
void poison(Scene& sc) {
  for (int& t : sc.particle_type) t = 1 - t;
  std::fill(sc.charge.begin(), sc.charge.end(), std::numeric_limits<double>::quiet_NaN());
  for (const auto& t : sc.forces->terms())
    if (auto* pairs = dynamic_cast<PairsOnParticles*>(t.get()))
      pairs->move_to(sc.particle_type,
                     t->uses_charges() ? std::span<const double>(sc.charge) : std::span<const double>(),
                     std::span<const SpecialPair>(), {});
}

TEST_P(PairSetDataOnFakeRanks, TheRunIsOneProcesssWithTheWholeTypesChargesAndSpecialPairsPoisoned) {
  const int ranks = GetParam();
  const test::OneThread one_thread;  // the scenes' [prepare] too: one thread, as on the ranks
  Scene serial = charged_butane();
  test::run_one_process(serial, kSteps);
  const test::DomainRun run = test::run_on_fake_ranks(
      ranks, kSteps, charged_butane, [](int, const DomainIntegrator&, Scene& sc, State&) { poison(sc); });
  if (ranks > 1) {
    EXPECT_GE(run.selections, 3.0) << "the pair sets should be selected again within the run";
    EXPECT_GE(run.migrated, 5.0) << "molecules should migrate within the run";
  }
  EXPECT_TRUE(run.x == serial.state.x);
  EXPECT_TRUE(run.v == serial.state.v);
}

INSTANTIATE_TEST_SUITE_P(Ranks, PairSetDataOnFakeRanks, ::testing::Values(1, 2, 3, 4));

}  // namespace
}  // namespace stiffmd
