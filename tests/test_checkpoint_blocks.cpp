// A checkpoint written by the ranks of a decomposed run, each its block of particles
// (engine/io/particle_blocks.hpp, engine/run/checkpoint.hpp), on fake ranks (tests/
// fake_processes.hpp): the blocks tile the particles and their owners are the blocks' ranks; the
// exchange brings every owned row to its block whatever the owners; and the file the ranks write
// together — the per-particle arrays at offsets from N, the integrator's carried columns between
// its own words, the crc32 combined from the ranks' pieces — is byte for byte the one process's
// checkpoint of the same state, on 1 to 5 ranks and with ranks that own nothing, whether the ranks
// hand it their blocks or their own particles (brought to the blocks by rounds of rows).
#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <iterator>
#include <random>

#include "engine/run/checkpoint.hpp"
#include "fake_processes.hpp"

namespace stiffmd {
namespace {

namespace fs = std::filesystem;
using fake::run_ranks;

TEST(ParticleBlocks, TileTheParticlesAndTheirOwnersAreTheBlocksRanks) {
  for (std::int64_t n : {0, 1, 2, 5, 7, 100, 1001})
    for (int ranks = 1; ranks <= 9; ++ranks) {
      std::int64_t next = 0;
      for (int r = 0; r < ranks; ++r) {
        const ParticleBlock b = block_of(n, ranks, r);
        EXPECT_EQ(b.first, next) << n << " particles, rank " << r << " of " << ranks;
        EXPECT_GE(b.count, n / ranks);
        EXPECT_LE(b.count, n / ranks + 1);
        for (std::int64_t g = b.first; g < b.first + b.count; ++g) EXPECT_EQ(block_owner(g, n, ranks), r) << g;
        next += b.count;
      }
      EXPECT_EQ(next, n);
    }
}

std::string bytes_of(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  return {std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
}

// n particles owned by `ranks` ranks at random (rank `idle` owns none), in increasing global index.
std::vector<std::vector<int>> scattered(int n, int ranks, int idle, unsigned seed) {
  std::mt19937 rng(seed);
  std::uniform_int_distribution<int> pick(0, ranks - 1);
  std::vector<std::vector<int>> owned(static_cast<size_t>(ranks));
  for (int g = 0; g < n; ++g) {
    int r = pick(rng);
    if (r == idle && ranks > 1) r = (r + 1) % ranks;
    owned[static_cast<size_t>(r)].push_back(g);
  }
  return owned;
}

Eigen::Matrix3Xd columns_of(const Eigen::Matrix3Xd& a, const std::vector<int>& ids) {
  Eigen::Matrix3Xd m(3, static_cast<Eigen::Index>(ids.size()));
  for (size_t k = 0; k < ids.size(); ++k) m.col(static_cast<Eigen::Index>(k)) = a.col(ids[k]);
  return m;
}

class CheckpointBlocks : public ::testing::TestWithParam<int> {};

TEST_P(CheckpointBlocks, TheRanksWriteTheOneProcessCheckpointsBytes) {
  const int ranks = GetParam(), n = 37;
  std::mt19937 rng(11);
  std::normal_distribution<double> g;
  auto random = [&](Eigen::Index rows, Eigen::Index cols) {
    Eigen::MatrixXd m(rows, cols);
    for (Eigen::Index k = 0; k < m.size(); ++k) m.data()[k] = g(rng);
    return m;
  };
  State s;
  s.x = random(3, n);
  s.v = random(3, n);
  s.inv_mass = random(n, 1).cwiseAbs();
  s.step = 123;
  s.t = 1.23;
  // The integrator's words: a flag, column 1, two sums, column 0, a last word (the order an
  // integrator may put them in: not the columns' order).
  const Eigen::Matrix3Xd c0 = random(3, n), c1 = random(3, n);
  const std::vector<WordRun> runs = {{{1.0}, -1}, {{}, 1}, {{0.25, -3.5}, -1}, {{}, 0}, {{7.0}, -1}};
  Checkpoint c;
  c.method = "impulse";
  c.h = 0.01;
  c.stage = 2;
  c.stage_name = "heat";
  c.scene_fingerprint = 0x1234'5678'9abc'def0ull;
  for (const WordRun& r : runs) {
    const Eigen::Matrix3Xd* column = r.column == 0 ? &c0 : r.column == 1 ? &c1 : nullptr;
    if (column)
      c.integrator_state.insert(c.integrator_state.end(), column->data(), column->data() + column->size());
    else
      c.integrator_state.insert(c.integrator_state.end(), r.words.begin(), r.words.end());
  }
  c.force_term_states = {{1.0, 2.0}, {}, {3.0}};
  c.thermo_state = {4.0, 5.0};
  c.monitor_state = {};
  c.run_state = {6.0, 7.0, 8.0, 9.0};
  c.box.origin = Eigen::Vector3d(-1.0, 0.0, 1.0);
  c.box.lengths = Eigen::Vector3d(10.0, 11.0, 12.0);

  const fs::path dir = fs::temp_directory_path() / ("stiffmd_checkpoint_blocks_" + std::to_string(ranks));
  fs::remove_all(dir);
  fs::create_directories(dir);
  const std::string one = (dir / "one.bin").string(), together = (dir / "ranks.bin").string();
  write_checkpoint(one, s, c);

  const auto owned = scattered(n, ranks, ranks - 1, 5);
  run_ranks(ranks, [&](const Communicator& comm) {
    const std::vector<int>& ids = owned[static_cast<size_t>(comm.rank())];
    const Eigen::Matrix3Xd x = columns_of(s.x, ids), v = columns_of(s.v, ids);
    Eigen::Matrix3Xd im3 = Eigen::Matrix3Xd::Zero(3, static_cast<Eigen::Index>(ids.size()));
    Eigen::VectorXd im(static_cast<Eigen::Index>(ids.size()));
    for (size_t k = 0; k < ids.size(); ++k) im[static_cast<Eigen::Index>(k)] = s.inv_mass[ids[k]];
    const Eigen::Matrix3Xd mine0 = columns_of(c0, ids), mine1 = columns_of(c1, ids);
    const ParticleBlock b = block_of(n, comm.size(), comm.rank());
    const auto count = static_cast<Eigen::Index>(b.count);
    Eigen::Matrix3Xd bx(3, count), bv(3, count), b0(3, count), b1(3, count);
    Eigen::VectorXd bim(count);
    BlockExchange().run(comm, n, ids,
                        {{x.data(), bx.data(), 3},
                         {v.data(), bv.data(), 3},
                         {im.data(), bim.data(), 1},
                         {mine0.data(), b0.data(), 3},
                         {mine1.data(), b1.data(), 3}});
    EXPECT_EQ(bx, s.x.middleCols(b.first, count));
    EXPECT_EQ(b1, c1.middleCols(b.first, count));
    // Rank 0 alone knows the tail (thermo, monitor, statistics, box, force terms).
    Checkpoint rest;
    rest.method = c.method;
    rest.h = c.h;
    rest.stage = c.stage;
    rest.stage_name = c.stage_name;
    rest.state.step = s.step;
    rest.state.t = s.t;
    if (comm.root()) {
      rest = c;
      rest.integrator_state.clear();
      rest.state.step = s.step;
      rest.state.t = s.t;
    }
    const CheckpointBlock block{n, b, bx.data(), bv.data(), bim.data(), {b0.data(), b1.data()}, &runs};
    write_checkpoint(together, comm, block, rest);
    // The same exchange by rounds of rows of every block: each round's rows, and the whole block.
    for (const std::int64_t round : {1, 4, 37}) {
      Eigen::Matrix3Xd rx(3, count), r0(3, count);
      BlockExchange exchange;  // kept from one round to the next, as the writer keeps it
      for (std::int64_t from = 0; from < (n + comm.size() - 1) / comm.size(); from += round) {
        const std::int64_t to = from + round, first = std::min<std::int64_t>(from, count);
        exchange.run(comm, n, ids, {{x.data(), rx.data() + 3 * first, 3}, {mine0.data(), r0.data() + 3 * first, 3}},
                     from, to);
      }
      EXPECT_EQ(rx, bx) << "rounds of " << round;
      EXPECT_EQ(r0, b0) << "rounds of " << round;
    }
    // The same file from the ranks' own particles, which the writer brings to the blocks by
    // rounds of 1, 3, 4 and more than a block's rows.
    for (const std::int64_t round : {1, 3, 4, 64}) {
      CheckpointBlock own{n, b, x.data(), v.data(), im.data(), {mine0.data(), mine1.data()}, &runs, &ids, round};
      write_checkpoint(together + ".own" + std::to_string(round), comm, own, rest);
    }
  });
  EXPECT_EQ(bytes_of(together), bytes_of(one)) << ranks << " ranks";
  for (const int round : {1, 3, 4, 64})
    EXPECT_EQ(bytes_of(together + ".own" + std::to_string(round)), bytes_of(one))
        << ranks << " ranks, rounds of " << round << " rows";
  EXPECT_FALSE(fs::exists(together + ".tmp"));
  const Checkpoint back = read_checkpoint(together);
  EXPECT_EQ(back.state.x, s.x);
  EXPECT_EQ(back.integrator_state, c.integrator_state);
  fs::remove_all(dir);
}

INSTANTIATE_TEST_SUITE_P(Ranks, CheckpointBlocks, ::testing::Values(1, 2, 3, 4, 5));

// Rank 0 cannot create the file (its directory is gone): every rank throws the agreed error naming
// the path and none waits for the others in a later collective; no file is left.
TEST(CheckpointBlocks, AFailureOnOneRankEndsEveryRankAlike) {
  const fs::path dir = fs::temp_directory_path() / "stiffmd_checkpoint_blocks_fail";
  fs::remove_all(dir);
  const std::string path = (dir / "ranks.bin").string();
  const int n = 6;
  const Eigen::Matrix3Xd x = Eigen::Matrix3Xd::Ones(3, 2);
  const Eigen::VectorXd im = Eigen::VectorXd::Ones(2);
  const std::vector<WordRun> runs;
  std::vector<std::string> said(3);
  run_ranks(3, [&](const Communicator& comm) {
    Checkpoint rest;
    rest.method = "velocity-verlet";
    rest.h = 0.01;
    rest.run_state = {0.0, 0.0, 0.0, 0.0};
    const CheckpointBlock block{n, block_of(n, 3, comm.rank()), x.data(), x.data(), im.data(), {}, &runs};
    try {
      write_checkpoint(path, comm, block, rest);
    } catch (const AgreedInputError& e) {
      said[static_cast<size_t>(comm.rank())] = e.what();
    }
  });
  for (size_t r = 0; r < said.size(); ++r)
    EXPECT_NE(said[r].find(path + ": cannot create checkpoint"), std::string::npos) << "rank " << r << ": " << said[r];
  EXPECT_FALSE(fs::exists(dir));
}

}  // namespace
}  // namespace stiffmd
