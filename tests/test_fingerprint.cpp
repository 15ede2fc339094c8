// The scene fingerprint of checkpoints (engine/run/checkpoint.hpp) covers every parameter of
// every force term exactly. tests/decks/every_force_style.toml holds a term of each style of the
// registry with every key its reader asks for given (checked here against the reader, so that a
// new style or key fails this test until the deck gives it). Each key of each term, changed
// through --set in its last bit, by a relative 1e-12 or to another valid value, must make a
// checkpoint of the deck's scene be refused as another scene, unless the change left every force
// bit-identical; the unchanged deck must continue it; the dihedrals' types swapped between two
// dihedrals must be refused too.
#include <gtest/gtest.h>

#include <toml++/toml.h>
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <map>
#include <optional>
#include <set>
#include <sstream>
#include <string>
#include <vector>

#include "cli_support.hpp"
#include "core/errors.hpp"
#include "engine/deck/deck.hpp"
#include "engine/run/checkpoint.hpp"
#include "engine/scene/force_registry.hpp"
#include "engine/scene/scene.hpp"
#include "test_support.hpp"

namespace stiffmd {
namespace {

namespace fs = std::filesystem;

const std::string kDeck = "tests/decks/every_force_style.toml";
// The all-atom styles, whose impropers need an imported data file (and so its periodic box, which
// the first deck's wall cannot have): a second deck, swept the same way.
const std::string kAllAtomDeck = "tests/decks/every_all_atom_style.toml";
const std::string kChargedDeck = "tests/decks/every_charged_style.toml";
const std::string kMeshDeck = "tests/decks/every_mesh_style.toml";

// Keys that no other value loads for, and why: the test checks that none does.
const std::set<std::string> kNoOtherValue = {
    "forces.bonds.level",  // the constraint-defining term must sit on the innermost level
    "forces.wall.side",    // the other side leaves the wall's particles outside its domain: refused at load
    "forces.lj.tail",      // true needs a fully periodic box, which the wall's deck cannot have
    // The Coulomb cutoff of an Ewald sum's real space is one for every type pair: another value of
    // one of them does not load (every_charged_style.toml, every_mesh_style.toml).
    "forces.charmm.pair.0.coulomb_cutoff", "forces.charmm.types.A.coulomb_cutoff",
    "forces.charmm.types.B.coulomb_cutoff", "forces.ljlong.pair.0.coulomb_cutoff",
    "forces.ljlong.types.A.coulomb_cutoff", "forces.ljlong.types.B.coulomb_cutoff", "forces.long.coulomb_cutoff",
    "forces.long.pair.0.coulomb_cutoff",
    // Overridden by every per-type and per-pair table, and some values out of range: the mixing
    // rule, special_bonds under special_lj and special_coul, and which pair the coul/long pair
    // table names (its one key, the cutoff, is the same for every pair).
    "forces.charmm.mix", "forces.ljcut.mix", "forces.ljdebye.mix", "forces.ljlong.mix", "forces.charmm.special_bonds.0",
    "forces.charmm.special_bonds.2", "forces.cut.special_bonds.0", "forces.cut.special_bonds.2",
    "forces.debye.special_bonds.0", "forces.debye.special_bonds.2", "forces.ljcut.special_bonds.0",
    "forces.ljcut.special_bonds.2", "forces.ljdebye.special_bonds.0", "forces.ljdebye.special_bonds.2",
    "forces.ljlong.special_bonds.0", "forces.ljlong.special_bonds.2", "forces.long.special_bonds.0",
    "forces.long.special_bonds.2", "forces.long.pair.0.types.0", "forces.long.pair.0.types.1"};
// Keys a reader asks about that are alternatives: a term selects its particles by `particles` or
// by `type`, never both (the deck gives the tether the one and the wall the other); a bonded term
// takes its coefficients from per-type tables or from the data file (`coefficients = "data"`:
// tests/test_impropers.cpp covers it), never both; the stiff-harmonic term selects its bonds by
// bond_types or also by `masses` (tests/test_force_registry.cpp and tests/test_peptide.cpp cover
// it; what it selects is in the fingerprint as the term's bonds).
const std::map<std::string, std::vector<std::string>> kAlternative = {
    {"particles", {"type"}},
    {"type", {"particles"}},
    {"coefficients", {"bond_types", "angle_types", "dihedral_types", "improper_types"}},
    {"masses", {"bond_types"}}};
// Keys that the deck gives but the scene does not use, so that changing them leaves the same
// scene, whose checkpoint continues (the test checks that no change of them is refused and that
// the forces stay bit-identical): with per-type tables for every type, the term's own
// coefficients are only the defaults of keys those tables leave out.
const std::set<std::string> kUnused = {
    "forces.lj.epsilon", "forces.lj.sigma", "forces.lj.cutoff", "forces.wca.epsilon", "forces.wca.sigma",
    // The rigid methods' SHAKE tolerance: a setting of their solver, not of the forces (and this
    // deck's impulse method solves no SHAKE per step).
    "forces.bonds.shake_tolerance",
    // The charged styles' term-level coefficients under per-type and per-pair tables, and
    // special_bonds under special_lj and special_coul (every_charged_style.toml).
    "forces.charmm.coulomb_cutoff", "forces.charmm.cutoff", "forces.charmm.epsilon", "forces.charmm.epsilon14",
    "forces.charmm.inner", "forces.charmm.sigma", "forces.charmm.sigma14", "forces.ljcut.coulomb_cutoff",
    "forces.ljcut.cutoff", "forces.ljcut.epsilon", "forces.ljcut.shift", "forces.ljcut.sigma",
    "forces.ljdebye.coulomb_cutoff", "forces.ljdebye.cutoff", "forces.ljdebye.epsilon", "forces.ljdebye.kappa",
    "forces.ljdebye.shift", "forces.ljdebye.sigma", "forces.ljlong.coulomb_cutoff", "forces.ljlong.cutoff",
    "forces.ljlong.epsilon", "forces.ljlong.shift", "forces.ljlong.sigma", "forces.charmm.special_bonds.1",
    "forces.cut.special_bonds.1", "forces.debye.special_bonds.1", "forces.ljcut.special_bonds.1",
    "forces.ljdebye.special_bonds.1", "forces.ljlong.special_bonds.1", "forces.long.special_bonds.1"};

// Values a string key may take in this deck: levels, mixing rules, axes, particle types.
const std::vector<std::string> kWords = {"fast", "slow", "geometric", "arithmetic", "x", "y", "z", "A", "B"};

std::string exact(double v) {
  char buf[40];
  std::snprintf(buf, sizeof buf, "%.17g", v);
  std::string s = buf;
  if (s.find_first_of(".en") == std::string::npos) s += ".0";  // stays a TOML float
  return s;
}

// Other values for a deck leaf, as --set text: a number changed in its last bit either way and
// by a relative 1e-12 either way (a zero made ±1e-9), an integer by one or its sign, a string to
// another word of kWords.
std::vector<std::string> other_values(const toml::node& n) {
  std::vector<std::string> out;
  if (const auto d = n.value_exact<double>()) {
    if (*d == 0.0) return {exact(1e-9), exact(-1e-9)};
    return {exact(std::nextafter(*d, INFINITY)), exact(std::nextafter(*d, -INFINITY)), exact(*d * (1 + 1e-12)),
            exact(*d * (1 - 1e-12))};
  }
  if (const auto i = n.value_exact<std::int64_t>()) {
    for (const std::int64_t v : {*i + 1, *i - 1, -*i})
      if (v != *i) out.push_back(std::to_string(v));
    return out;
  }
  if (const auto s = n.value_exact<std::string>()) {
    for (const std::string& w : kWords)
      if (w != *s) out.push_back("\"" + w + "\"");
    return out;
  }
  if (const auto b = n.value_exact<bool>()) return {*b ? "false" : "true"};
  return out;
}

struct Leaf {
  std::string path;  // as --set takes it: forces.lj.pair.0.epsilon, forces.lj.special_bonds.1
  const toml::node* node;
};

// Every value under `n` (tables and arrays entered), and every table holding a value, by path.
void walk(const toml::node& n, const std::string& path, std::vector<Leaf>& leaves,
          std::vector<std::pair<std::string, const toml::table*>>& tables) {
  if (const auto* t = n.as_table()) {
    bool holds_a_value = false;
    for (const auto& [k, v] : *t) {
      holds_a_value |= !v.is_table() && !v.is_array_of_tables();
      walk(v, path + "." + std::string(k.str()), leaves, tables);
    }
    if (holds_a_value) tables.emplace_back(path, t);
  } else if (const auto* a = n.as_array()) {
    for (size_t k = 0; k < a->size(); ++k) walk(*a->get(k), path + "." + std::to_string(k), leaves, tables);
  } else {
    leaves.push_back({path, &n});
  }
}

class SceneFingerprintOfEveryStyle : public ::testing::Test {
 protected:
  static void SetUpTestSuite() { set_up(kDeck); }
  static void set_up(const std::string& deck) {
    deck_ = deck;
    dir_ = test::scratch_dir("fingerprint");
    const auto r = test::cli("run " + test::source_path(deck_) + " -o " + (dir_ / "out").string() + " --no-progress");
    ASSERT_EQ(r.code, 0) << r.err;
    parsed_ = toml::parse_file(test::source_path(deck_));
  }
  static void TearDownTestSuite() { fs::remove_all(dir_); }

  static std::string checkpoint() { return (dir_ / "out" / "checkpoint.bin").string(); }

  enum class Outcome { bad_deck, refused, continued };
  struct Restart {
    Outcome outcome;
    std::string what;            // the error
    std::optional<Scene> scene;  // the deck's scene, when it loads
  };
  // Loads the deck with `overrides` (and a later run.t_end) and offers it the checkpoint.
  static Restart restart(std::vector<std::string> overrides) {
    overrides.push_back("run.t_end=1");
    Restart r{Outcome::continued, "", std::nullopt};
    try {
      r.scene.emplace(load_scene(Deck(test::source_path(deck_), overrides)));
    } catch (const InputError& e) {
      return {Outcome::bad_deck, e.what(), std::nullopt};
    }
    try {
      read_checkpoint_for(*r.scene, checkpoint());
    } catch (const InputError& e) {
      r.outcome = Outcome::refused;
      r.what = e.what();
    }
    return r;
  }

  // Whether every term of `a` and `b` gives the same energy and forces, bit for bit, at the
  // checkpoint's positions.
  static bool same_forces(const Scene& a, const Scene& b) {
    const Eigen::Matrix3Xd x = read_checkpoint(checkpoint()).state.x;
    const auto &ta = a.forces->terms(), &tb = b.forces->terms();
    if (ta.size() != tb.size()) return false;
    for (size_t k = 0; k < ta.size(); ++k) {
      Eigen::Matrix3Xd fa = Eigen::Matrix3Xd::Zero(3, x.cols()), fb = fa;
      if (ta[k]->add_forces(x, a.box, fa) != tb[k]->add_forces(x, b.box, fb) || !(fa.array() == fb.array()).all())
        return false;
    }
    return true;
  }

  static const toml::table& forces() { return *parsed_["forces"].as_table(); }
  static void expect_every_key_given();
  static void expect_every_key_changed_refused(int min_changes);

  static inline std::string deck_;
  static inline fs::path dir_;
  static inline toml::table parsed_;
};

TEST_F(SceneFingerprintOfEveryStyle, TheDeckHasATermOfEveryStyleAndTheUnchangedDeckContinues) {
  std::set<std::string> styles;
  for (const std::string& deck : {kDeck, kAllAtomDeck, kChargedDeck, kMeshDeck}) {
    const toml::table parsed = toml::parse_file(test::source_path(deck));
    for (const auto& [name, t] : *parsed["forces"].as_table())
      styles.insert(std::string(*t.as_table()->get("style")->value<std::string>()));
  }
  for (const ForceStyle& s : force_styles()) EXPECT_TRUE(styles.count(s.name)) << "no term of style " << s.name;
  const Restart same = restart({});
  EXPECT_EQ(same.outcome, Outcome::continued) << same.what;
  // Through the command line too.
  fs::copy(dir_ / "out", dir_ / "copy");
  const auto r =
      test::cli("run " + test::source_path(kDeck) + " -o " + (dir_ / "copy").string() +
                " --no-progress --set run.t_end=0.02 --restart " + (dir_ / "copy" / "checkpoint.bin").string());
  EXPECT_EQ(r.code, 0) << r.err;
  fs::remove_all(dir_ / "copy");
}

// Every key a style's reader asks for is given in the deck: a key added to a reader, or a style
// added to the registry, fails here until the deck gives it (and the sweep below changes it).
void SceneFingerprintOfEveryStyle::expect_every_key_given() {
  std::vector<Leaf> leaves;
  std::vector<std::pair<std::string, const toml::table*>> tables;
  for (const auto& [name, t] : forces()) walk(t, "forces." + std::string(name.str()), leaves, tables);
  for (const auto& [path, table] : tables) {
    // An unknown key makes the reader list the keys it asked for (DeckTable::finish).
    const std::string what = restart({path + ".zz_probe=1"}).what;
    const std::string marker = "zz_probe: unknown key (expected one of: ";
    const size_t at = what.find(marker);
    ASSERT_NE(at, std::string::npos) << path << ": " << what;
    const size_t from = at + marker.size(), to = what.find(')', from);
    std::stringstream asked(what.substr(from, to - from));
    for (std::string key; std::getline(asked, key, ',');) {
      key.erase(0, key.find_first_not_of(' '));
      if (const auto alt = kAlternative.find(key);
          alt != kAlternative.end() &&
          std::any_of(alt->second.begin(), alt->second.end(), [&](const std::string& k) { return table->contains(k); }))
        continue;
      EXPECT_TRUE(table->contains(key)) << "the reader asks for " << path << "." << key << ", which " << deck_
                                        << " does not give";
    }
  }
}

// Each key of each term changed on its own (other_values): a valid deck it gives is another
// scene, refused. A change in the last bit may round away where the scene computes the coefficient
// it uses from the deck's values (θ₀ from degrees, ε_AB = √(ε_A ε_B) by the mixing rule): the
// scene is then the same and its restart continues, which is accepted when every term's energy and
// forces at the checkpoint are bit-identical — and some change of the key must still be refused.
void SceneFingerprintOfEveryStyle::expect_every_key_changed_refused(int min_changes) {
  std::vector<Leaf> leaves;
  std::vector<std::pair<std::string, const toml::table*>> tables;
  for (const auto& [name, t] : forces()) walk(t, "forces." + std::string(name.str()), leaves, tables);
  const Restart base = restart({});
  ASSERT_TRUE(base.scene);
  int changes = 0;
  for (const Leaf& leaf : leaves) {
    if (leaf.path.ends_with(".style")) continue;  // what the table is, not a parameter of it
    std::string loads_not;
    bool another_scene = false;
    for (const std::string& value : other_values(*leaf.node)) {
      const std::string set = leaf.path + "=" + value;
      const Restart r = restart({set});
      if (r.outcome == Outcome::bad_deck) {
        loads_not += "\n  " + r.what;
        continue;
      }
      ++changes;
      if (r.outcome == Outcome::continued) {
        EXPECT_TRUE(same_forces(*base.scene, *r.scene)) << set << " continues the checkpoint but changes the forces";
        continue;
      }
      EXPECT_NE(r.what.find("checkpoint of another scene"), std::string::npos) << set << ": " << r.what;
      another_scene = true;
    }
    if (kUnused.count(leaf.path))
      EXPECT_FALSE(another_scene) << leaf.path << " is refused: take it out of kUnused";
    else if (kNoOtherValue.count(leaf.path))
      EXPECT_FALSE(another_scene) << leaf.path << " loads with another value: take it out of kNoOtherValue";
    else
      EXPECT_TRUE(another_scene) << "no other value of " << leaf.path
                                 << " is refused; those that do not load:" << loads_not;
  }
  EXPECT_GT(changes, min_changes);  // the deck's keys, most changed both ways
}

TEST_F(SceneFingerprintOfEveryStyle, TheDeckGivesEveryKeyTheReadersAskFor) {
  expect_every_key_given();
}
TEST_F(SceneFingerprintOfEveryStyle, EveryKeyOfEveryTermChangedIsAnotherScene) {
  expect_every_key_changed_refused(100);
}

class SceneFingerprintOfEveryAllAtomStyle : public SceneFingerprintOfEveryStyle {
 protected:
  static void SetUpTestSuite() { set_up(kAllAtomDeck); }
};
TEST_F(SceneFingerprintOfEveryAllAtomStyle, TheUnchangedDeckContinues) {
  EXPECT_EQ(restart({}).outcome, Outcome::continued);
}
TEST_F(SceneFingerprintOfEveryAllAtomStyle, TheDeckGivesEveryKeyTheReadersAskFor) {
  expect_every_key_given();
}
TEST_F(SceneFingerprintOfEveryAllAtomStyle, EveryKeyOfEveryTermChangedIsAnotherScene) {
  expect_every_key_changed_refused(40);
}
// The charged pair styles and an Ewald sum (one k-space term per deck), and the mesh.
class SceneFingerprintOfEveryChargedStyle : public SceneFingerprintOfEveryStyle {
 protected:
  static void SetUpTestSuite() { set_up(kChargedDeck); }
};
TEST_F(SceneFingerprintOfEveryChargedStyle, TheUnchangedDeckContinues) {
  EXPECT_EQ(restart({}).outcome, Outcome::continued);
}
TEST_F(SceneFingerprintOfEveryChargedStyle, TheDeckGivesEveryKeyTheReadersAskFor) {
  expect_every_key_given();
}
TEST_F(SceneFingerprintOfEveryChargedStyle, EveryKeyOfEveryTermChangedIsAnotherScene) {
  expect_every_key_changed_refused(60);
}
// The particles' charges are part of the scene: one charge changed in its last bit is another.
TEST_F(SceneFingerprintOfEveryChargedStyle, ChargesArePartOfTheScene) {
  Scene sc = load_scene(Deck(test::source_path(deck_), {}));
  const std::uint64_t before = scene_fingerprint(sc);
  sc.charge[3] = std::nextafter(sc.charge[3], 1.0);
  EXPECT_NE(scene_fingerprint(sc), before);
}
class SceneFingerprintOfEveryMeshStyle : public SceneFingerprintOfEveryStyle {
 protected:
  static void SetUpTestSuite() { set_up(kMeshDeck); }
};
TEST_F(SceneFingerprintOfEveryMeshStyle, TheUnchangedDeckContinues) {
  EXPECT_EQ(restart({}).outcome, Outcome::continued);
}
TEST_F(SceneFingerprintOfEveryMeshStyle, TheDeckGivesEveryKeyTheReadersAskFor) {
  expect_every_key_given();
}
TEST_F(SceneFingerprintOfEveryMeshStyle, EveryKeyOfEveryTermChangedIsAnotherScene) {
  expect_every_key_changed_refused(15);
}

// The impropers of two types swapped between their terms: the same lists and coefficients, but
// each improper under the other's term.
TEST_F(SceneFingerprintOfEveryAllAtomStyle, ImproperTypesSwappedAreAnotherScene) {
  const Restart r = restart({"import.improper_types.1=cvff", "import.improper_types.2=flat"});
  ASSERT_TRUE(r.scene) << r.what;
  EXPECT_EQ(r.scene->topology.impropers.size(), 3u);
  EXPECT_EQ(r.outcome, Outcome::refused);
  EXPECT_NE(r.what.find("checkpoint of another scene"), std::string::npos) << r.what;
}

// The same dihedrals with their two harmonic types swapped: the same topology lists and the same
// coefficients, but each dihedral turns with the other's.
TEST_F(SceneFingerprintOfEveryStyle, DihedralTypesSwappedAreAnotherScene) {
  const Restart r = restart({"build.0.dihedral_type=h2", "build.1.dihedral_type=h1"});
  ASSERT_TRUE(r.scene) << r.what;
  EXPECT_EQ(r.scene->topology.dihedrals.size(), 6u);
  EXPECT_EQ(r.outcome, Outcome::refused);
  EXPECT_NE(r.what.find("checkpoint of another scene"), std::string::npos) << r.what;
}

// The command line refuses a restart with another pair ε: exit 2, one line, nothing run.
TEST_F(SceneFingerprintOfEveryStyle, ARestartWithAnotherPairEpsilonExitsWith2) {
  fs::copy(dir_ / "out", dir_ / "eps");
  const auto r = test::cli("run " + test::source_path(kDeck) + " -o " + (dir_ / "eps").string() +
                           " --no-progress --set run.t_end=0.02 --set forces.wca.types.A.epsilon=2.5 --restart " +
                           (dir_ / "eps" / "checkpoint.bin").string());
  EXPECT_EQ(r.code, 2) << r.err;
  EXPECT_NE(r.err.find("checkpoint of another scene"), std::string::npos) << r.err;
  EXPECT_EQ(r.out, "");
  fs::remove_all(dir_ / "eps");
}

}  // namespace
}  // namespace stiffmd
