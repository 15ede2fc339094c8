// The pieces of a checkpoint, in process: a neighbour list restored from the positions of its
// last build is the same list (pairs, order, images) and gives bit-identical forces from then on;
// every integrator restored from save_state() on a fresh scene continues bit for bit; the scene
// fingerprint covers what defines the scene and nothing a restart may change.
#include <gtest/gtest.h>

#include <random>

#include "engine/run/checkpoint.hpp"
#include "forcefields/pair_term.hpp"
#include "integrators/methods.hpp"
#include "test_support.hpp"

namespace stiffmd {
namespace {

Box cube(double side) {
  Box b;
  b.periodic = Eigen::Vector3i::Ones();
  b.lengths = Eigen::Vector3d::Constant(side);
  return b;
}

struct ListCase {
  const char* name;
  Box box;
};

void PrintTo(const ListCase& c, std::ostream* os) {
  *os << c.name;
}

class NeighborListState : public ::testing::TestWithParam<ListCase> {};

TEST_P(NeighborListState, RestoredFromItsLastBuildItIsTheSameListFromThenOn) {
  const Box box = GetParam().box;
  const double side = box.any_periodic() ? box.lengths[0] : 8.0;
  const int n = static_cast<int>(0.4 * side * side * side);  // a dilute liquid
  std::mt19937 rng(3);
  std::uniform_real_distribution<double> u(0.0, side), kick(-0.02, 0.02);
  Eigen::Matrix3Xd x(3, n), drift(3, n);
  for (int i = 0; i < n; ++i)
    for (int a = 0; a < 3; ++a) {
      x(a, i) = u(rng);
      drift(a, i) = 0.02 * (u(rng) / side - 0.5);  // particles leave the box: images change
    }
  TypePairMatrix<WeeksChandlerAndersen::Coeffs> coeffs(1);
  coeffs.set(0, 0, {1.0, 0.8});
  const std::vector<int> types(n, 0);
  auto make = [&] { return WcaPair("wca", Level::slow, types, coeffs, {}, SpecialWeights{}, box, 0.3); };
  auto move = [&] {
    for (int i = 0; i < n; ++i)
      for (int a = 0; a < 3; ++a) x(a, i) += drift(a, i) + kick(rng);
  };

  WcaPair a = make();
  Eigen::Matrix3Xd fa(3, n), fb(3, n);
  for (int s = 0; s < 60 || a.rebuilds() < 3; ++s) {  // several rebuilds; the last some updates ago
    move();
    fa.setZero();
    a.add_forces(x, box, fa);
  }
  ASSERT_GE(a.rebuilds(), 3);
  WcaPair b = make();
  b.load_state(a.save_state());
  const NeighborList &la = a.neighbor_list(), &lb = b.neighbor_list();
  EXPECT_EQ(lb.rebuilds(), la.rebuilds());
  EXPECT_TRUE(std::ranges::equal(la.offsets(), lb.offsets()));
  EXPECT_TRUE(std::ranges::equal(la.neighbors(), lb.neighbors())) << "pairs or their order differ";
  EXPECT_TRUE((la.positions_at_build().array() == lb.positions_at_build().array()).all());
  EXPECT_EQ(b.save_state(), a.save_state());

  // From here on both see the same positions: the same forces to the last bit, the same rebuilds.
  // A fresh term (no state) computes the same forces too — rows are sorted and positions wrapped
  // at the call, so a pair force does not depend on when its list was built (docs/parallel.md) —
  // but rebuilds at other updates: the schedule is what the list's state carries.
  bool schedules_differ = false;
  WcaPair fresh = make();
  for (int s = 0; s < 60; ++s) {
    move();
    fa.setZero();
    fb.setZero();
    const long before_a = a.rebuilds(), before_fresh = fresh.rebuilds();
    const double ea = a.add_forces(x, box, fa), eb = b.add_forces(x, box, fb);
    ASSERT_EQ(ea, eb) << "update " << s;
    ASSERT_TRUE((fa.array() == fb.array()).all()) << "update " << s;
    Eigen::Matrix3Xd ff = Eigen::Matrix3Xd::Zero(3, n);
    const double ef = fresh.add_forces(x, box, ff);
    schedules_differ |= (a.rebuilds() > before_a) != (fresh.rebuilds() > before_fresh);
    ASSERT_EQ(ef, ea) << "update " << s;
    ASSERT_TRUE((ff.array() == fa.array()).all()) << "update " << s;
  }
  EXPECT_EQ(a.rebuilds(), b.rebuilds());
  EXPECT_EQ(a.virial(x, box), b.virial(x, box));
  EXPECT_EQ(fresh.virial(x, box), a.virial(x, box));
  if (std::string(GetParam().name) == "periodic") {
    EXPECT_TRUE(schedules_differ) << "this case would not notice a list left out of the checkpoint";
  }
}

INSTANTIATE_TEST_SUITE_P(Boxes, NeighborListState,
                         ::testing::Values(ListCase{"periodic", cube(8.0)},
                                           ListCase{"periodic_fewer_than_3_cells", cube(2.6)}, ListCase{"open", Box{}}),
                         [](const auto& info) { return std::string(info.param.name); });

TEST(NeighborListState, NothingToSaveBeforeTheFirstBuild) {
  TypePairMatrix<WeeksChandlerAndersen::Coeffs> coeffs(1);
  coeffs.set(0, 0, {1.0, 1.0});
  WcaPair t("wca", Level::slow, std::vector<int>(4, 0), coeffs, {}, SpecialWeights{}, cube(5.0), 0.3);
  EXPECT_TRUE(t.save_state().empty());
  EXPECT_NO_THROW(t.load_state({}));
  EXPECT_THROW(t.load_state(std::vector<double>(5, 0.0)), std::invalid_argument);
}

// Every method: k steps, save the integrator's and the force terms' states, load them into a
// fresh scene and integrator, m more steps on each: the same x and v to the last bit.
class IntegratorState : public ::testing::TestWithParam<std::string> {};

TEST_P(IntegratorState, AFreshIntegratorLoadedWithTheStateContinuesBitForBit) {
  const std::string method = GetParam();
  std::vector<std::string> o = {"integrator.method=" + method,
                                method == "velocity-verlet" ? "integrator.h=0.0005" : "integrator.h=0.005"};
  if (find_method(method)->needs_temperature)  // fixman: U_F is a free energy at the thermostat's kT
    o.insert(o.end(), {"thermostat.style=\"langevin\"", "thermostat.temperature=1", "thermostat.friction=1",
                       "thermostat.seed=5"});
  Scene a = test::load("tests/decks/restart_melt.toml", o);
  auto ia = make_integrator(a.integrator, *a.forces, a.state.inv_mass);
  std::ostringstream log;
  ia->prepare(a.state, log);
  test::advance(a, 23, *ia);

  Scene b = test::load("tests/decks/restart_melt.toml", o);  // prepared afresh: another list history
  b.state = a.state;
  for (size_t k = 0; k < a.forces->terms().size(); ++k)
    b.forces->terms()[k]->load_state(a.forces->terms()[k]->save_state());
  auto ib = make_integrator(b.integrator, *b.forces, b.state.inv_mass);
  ib->load_state(ia->save_state());
  EXPECT_EQ(ib->save_state(), ia->save_state());
  EXPECT_EQ(ib->constraint_virial(b.state), ia->constraint_virial(a.state));

  test::advance(a, 31, *ia);
  test::advance(b, 31, *ib);
  EXPECT_TRUE((a.state.x.array() == b.state.x.array()).all()) << "positions differ";
  EXPECT_TRUE((a.state.v.array() == b.state.v.array()).all()) << "velocities differ";
  EXPECT_EQ(ib->save_state(), ia->save_state());
}

INSTANTIATE_TEST_SUITE_P(EveryMethod, IntegratorState, ::testing::ValuesIn(test::kAllMethods), test::method_test_name);

TEST(SceneFingerprint, CoversTheSceneNotTheRunSettings) {
  const std::string deck = "tests/decks/restart_melt.toml";
  const Deck d(test::source_path(deck), {});
  Scene unprepared = load_scene(d);
  const std::uint64_t f = scene_fingerprint(unprepared);
  EXPECT_EQ(scene_fingerprint(test::load(deck)), f) << "[prepare] (which rebuilds the list) changed it";
  for (const char* same : {"integrator.method=rattle", "integrator.h=0.004", "integrator.micro_steps=7", "run.t_end=3",
                           "output.xyz_interval=0.05", "output.checkpoint_interval=0.015", "monitor.energy_error=0.1",
                           "velocities.seed=99", "prepare.relax_steps=5",
                           "build.0.seed=12"})  // the builder's seed: another initial state, the same scene
    EXPECT_EQ(scene_fingerprint(test::load(deck, {same})), f) << same;
  for (const char* other : {"variables.eps=0.02", "forces.excluded_volume.skin=0.25",
                            "forces.bending.angle_types.bend.k=2", "forces.anchor.particles=[0, 28]",
                            "forces.bending.level=\"fast\"", "types.bead.mass=2", "build.0.density=0.69"})
    EXPECT_NE(scene_fingerprint(test::load(deck, {other})), f) << other;
}

}  // namespace
}  // namespace stiffmd
