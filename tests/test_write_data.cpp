// `stiffmd check DECK --write-data FILE`: the prepared initial state (after [prepare]) as a LAMMPS
// data file — what tools/bench_lammps.py hands to LAMMPS so that both codes start from one state.
#include <gtest/gtest.h>
#include <sstream>

#include <filesystem>

#include "engine/deck/deck.hpp"
#include "engine/io/lammps_data.hpp"
#include "engine/scene/scene.hpp"
#include "tests/cli_support.hpp"

namespace stiffmd {
namespace {

namespace fs = std::filesystem;
using namespace test;

TEST(WriteData, CheckWritesThePreparedInitialState) {
  // A built, projected and thermalised melt: [prepare] changes the state, so a file written
  // before it (or after a step) would differ from load_scene's.
  const std::string deck = std::string(STIFFMD_SOURCE_DIR) + "/inputs/hard/stiff_chain_melt.toml";
  const fs::path out = scratch_dir("write_data") / "state.data";
  const CliResult r = cli("check " + deck + " --write-data " + out.string());
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_NE(r.out.find("initial state written to"), std::string::npos) << r.out;

  Scene scene = load_scene(Deck(deck, {}));
  std::ostringstream log;
  prepare_scene(scene, log);
  const ImportedSystem data = read_lammps_data(out.string());
  ASSERT_EQ(data.x.cols(), scene.state.x.cols());
  EXPECT_EQ(data.bonds.size(), scene.topology.bonds.size());
  // Written at full precision: the same state back, to round-off.
  EXPECT_LE((data.x - scene.state.x).cwiseAbs().maxCoeff(), 1e-12);
  EXPECT_LE((data.v - scene.state.v).cwiseAbs().maxCoeff(), 1e-12);
  EXPECT_GT(scene.state.v.norm(), 0.0);
}

TEST(WriteData, AnUnwritablePathIsAnInputError) {
  const CliResult r = cli("check " + std::string(STIFFMD_SOURCE_DIR) +
                          "/inputs/double_pendulum.toml --write-data /nonexistent_dir/state.data");
  EXPECT_EQ(r.code, 2) << r.err;
  EXPECT_NE(r.err.find("/nonexistent_dir/state.data"), std::string::npos) << r.err;
}

}  // namespace
}  // namespace stiffmd
