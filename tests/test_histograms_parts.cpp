// histograms.csv from a decomposed run's parts (write_histograms_parts, engine/observe/histograms.hpp)
// is the whole system's file to the byte: on 1–3 fake ranks (tests/fake_processes.hpp), each with
// the molecules of a random partition, for a melt whose angles are the topology's
// (tests/decks/chains_by_parts.toml), one without angles (inputs/kremer_grest.toml: every pair of
// bonds sharing a bead) and one whose bonds all have one length (the stiff melt after RATTLE's
// projection: the narrow bins of rigid bonds).
#include <gtest/gtest.h>

#include <unistd.h>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <sstream>
#include <string>
#include <vector>

#include "domain_run_support.hpp"
#include "engine/observe/histograms.hpp"
#include "fake_processes.hpp"
#include "test_support.hpp"

namespace stiffmd {
namespace {

namespace fs = std::filesystem;

fs::path scratch(const std::string& name) {
  const fs::path d = fs::temp_directory_path() / ("stiffmd_" + name + "_" + std::to_string(::getpid()));
  fs::create_directories(d);
  return d;
}

std::string bytes(const fs::path& p) {
  std::ifstream in(p, std::ios::binary);
  return {std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
}

struct HistogramCase {
  const char* deck;
  std::vector<std::string> overrides;
  bool prepare = false;  // [prepare] first (the stiff melt's projection onto its bond lengths)
};

class HistogramsByParts : public ::testing::TestWithParam<int> {};

TEST_P(HistogramsByParts, TheFileIsTheWholeSystemsBytes) {
  const int ranks = GetParam();
  const fs::path dir = scratch("histograms_parts_" + std::to_string(ranks));
  for (const HistogramCase& c :
       {HistogramCase{"tests/decks/chains_by_parts.toml", {}}, HistogramCase{"inputs/kremer_grest.toml", {}},
        HistogramCase{"inputs/stiff_melt_nvt.toml", {"integrator.method=rattle"}, true}}) {
    Scene sc = test::load(c.deck, c.overrides);
    if (c.prepare) {
      std::ostringstream log;
      prepare_scene(sc, log);
    }
    const fs::path whole = dir / "whole.csv", parts = dir / "parts.csv";
    write_histograms(whole.string(), sc.state.x, sc.box, sc.topology);
    fs::remove(parts);
    fake::run_ranks(ranks, [&](const fake::FakeCommunicator& comm) {
      const test::Given mine = test::scattered(sc, sc.state, ranks, comm.rank(), 7u + static_cast<unsigned>(ranks));
      EXPECT_TRUE(write_histograms_parts(parts.string(), mine.x, mine.molecules.topology(sc.topology), comm));
    });
    const std::string want = bytes(whole);
    ASSERT_GT(want.size(), 100u) << c.deck;
    EXPECT_TRUE(want == bytes(parts)) << c.deck << " on " << ranks << " ranks";
  }
}

INSTANTIATE_TEST_SUITE_P(Ranks, HistogramsByParts, ::testing::Values(1, 2, 3));

// No rank has a bond: no file, on every rank.
TEST(HistogramsByParts, WithoutBondsNoFile) {
  const fs::path path = scratch("histograms_parts_none") / "h.csv";
  fs::remove(path);
  fake::run_ranks(2, [&](const fake::FakeCommunicator& comm) {
    const Eigen::Matrix3Xd x = Eigen::Matrix3Xd::Random(3, 4);
    EXPECT_FALSE(write_histograms_parts(path.string(), x, Topology{}, comm));
  });
  EXPECT_FALSE(fs::exists(path));
}

}  // namespace
}  // namespace stiffmd
