#include "engine/scene/stage_deck.hpp"

#include <algorithm>
#include <cctype>
#include <cmath>
#include <set>

#include "core/errors.hpp"
#include "integrators/thermostat.hpp"

namespace stiffmd {

namespace {

// What a stage may not change, with why: the state passed from stage to stage is of one scene.
constexpr const char* kSceneKeys[] = {"types", "build",     "import",     "forces",  "particles", "bonds",    "box",
                                      "units", "variables", "velocities", "prepare", "parallel",  "ensemble", "stage"};

std::string allowed_keys() {
  std::string s = "name, steps or t_end";
  for (const char* t : kStageTables) s += std::string(", ") + t;
  return s;
}

}  // namespace

std::vector<StageSpec> read_stages(DeckTable& root) {
  if (!root.has_retired("stage")) return {};
  std::vector<DeckTable> tables = root.array_of_tables("stage");
  if (tables.empty()) root.fail("stage", "expected one [[stage]] table or more, got an empty array");
  // The tables a protocol's stages own.
  if (root.has_retired("run"))
    root.fail("run",
              "a staged deck's stages give their lengths (steps or t_end in each [[stage]]): expected no [run] "
              "table");
  if (root.has_retired("minimize"))
    root.fail("minimize",
              "in a staged deck a minimisation is a stage's, run at that stage's start: move this table into "
              "the stage that minimises as [stage.minimize] (a stage with steps = 0 only minimises)");
  if (root.has_retired("ensemble"))
    root.fail("ensemble",
              "an [ensemble] of staged protocols is not built yet: expected [ensemble] or [[stage]], not both");
  std::vector<StageSpec> stages;
  std::set<std::string> names;
  for (std::size_t k = 0; k < tables.size(); ++k) {
    DeckTable& st = tables[k];
    StageSpec spec;
    spec.index = k;
    spec.where = st.where();
    spec.identity.number = static_cast<int>(k) + 1;
    spec.identity.count = static_cast<int>(tables.size());
    for (const char* key : kSceneKeys)
      if (st.has_retired(key))
        st.fail(key, std::string(key) == "stage"
                         ? "stages do not nest: expected the stage's own tables (" + allowed_keys() + ")"
                         : "a stage changes how the scene is run, not the scene: the particles, topology, force "
                           "field, box, units and variables are the base deck's (the state passed from stage to "
                           "stage is of one scene); expected " +
                               allowed_keys());
    if (st.has_retired("run"))
      st.fail("run", "a stage's length is its steps or t_end, at the stage's top level: expected no [stage.run]");
    spec.identity.name = st.name("name");
    const std::string& name = spec.identity.name;
    const bool plain = name.size() <= 64 && std::all_of(name.begin(), name.end(), [](char c) {
                         return std::isalnum(static_cast<unsigned char>(c)) || c == '_' || c == '-';
                       });
    if (!plain)
      st.fail("name",
              "expected a name of at most 64 letters, digits, '_' and '-' (it names the stage's output "
              "directory), got \"" +
                  name + "\"");
    if (!names.insert(name).second)
      st.fail("name", "\"" + name + "\" names an earlier stage too; expected a name of its own");
    const auto steps = st.maybe_integer("steps");
    const auto t_end = st.maybe_number("t_end");
    if (steps && t_end) st.fail("t_end", "steps is given too; expected either steps (macro steps) or t_end (a time)");
    if (!steps && !t_end)
      st.fail_here("missing the stage's length: expected steps (a number of macro steps, 0: none) or t_end (a time)");
    if (steps)
      st.require(*steps >= 0 && *steps <= 1'000'000'000'000L, "steps",
                 "expected a number of macro steps 0 .. 1e12 (0: a stage that only minimises)");
    if (t_end) st.require(*t_end > 0.0, "t_end", "expected an end time > 0 (the stage's own time, from 0)");
    for (const char* key : kStageTables) {
      auto t = st.table(key);
      if (t && std::string(key) == "integrator" && t->has_retired("levels"))
        t->fail("levels",
                "the levels are the force field's (its terms name them): a stage cannot change them; expected "
                "[[integrator.levels]] in the base deck only");
    }
    st.finish();
    stages.push_back(std::move(spec));
  }
  return stages;
}

std::unique_ptr<Deck> stage_deck(const Deck& base, const StageSpec& stage) {
  return std::make_unique<Deck>(base, Deck::Merge{"stage", stage.index, {"steps", "t_end"}, "run"});
}

std::uint64_t stage_seed(std::uint64_t seed, int number) {
  if (number <= 1) return seed;
  return mix64(seed + static_cast<std::uint64_t>(number) * kGolden);
}

Scene load_stage_scene(const Deck& deck, const StageSpec& stage) {
  try {
    Scene sc = load_scene(deck, stage.identity);
    sc.integrator.thermostat.seed = stage_seed(sc.integrator.thermostat.seed, stage.identity.number);
    return sc;
  } catch (const InputError& e) {
    throw InputError(stage_label(stage.identity) + ": " + e.what());
  }
}

std::string stage_label(const StageIdentity& stage) {
  return "stage " + std::to_string(stage.number) + " (" + stage.name + ")";
}

std::string stage_directory(const StageIdentity& stage) {
  const std::string digits = std::to_string(stage.count);
  std::string number = std::to_string(stage.number);
  number.insert(0, digits.size() - std::min(digits.size(), number.size()), '0');
  return number + "_" + stage.name;
}

}  // namespace stiffmd
