// A decomposed restart by parts (engine/run/checkpoint.hpp CheckpointParts; docs/parallel.md, "A
// restart by parts"): the by-molecule chains deck (tests/decks/chains_by_parts.toml: Langevin,
// whose integrator carries per-particle columns) runs 40 steps on fake ranks
// (tests/fake_processes.hpp) with a checkpoint at step 20; restarted from that checkpoint on 2 and 3
// ranks from the scene's description (load_scene's SceneContent::description: no particle on any
// rank), each rank its molecules' rows read from the file, it writes the uninterrupted run's
// thermo.csv and positions and velocities, and the checkpoint.bin bytes of the restart from the
// whole scene on as many ranks. A damaged
// checkpoint (one flipped byte in one rank's rows) or a truncated one is refused on every rank with
// read_checkpoint's one line. A rank reads its rows and the blocks that are not per particle, and
// its byte range for the crc32: counted, not the whole file.
#include <gtest/gtest.h>

#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <iterator>
#include <mutex>
#include <sstream>
#include <string>
#include <vector>

#include "domain_run_support.hpp"
#include "engine/domain/domain_integrator.hpp"
#include "engine/domain/part_load.hpp"
#include "engine/io/particle_blocks.hpp"
#include "engine/run/checkpoint.hpp"
#include "engine/run/run.hpp"
#include "fake_processes.hpp"
#include "integrators/methods.hpp"

namespace stiffmd {
namespace {

namespace fs = std::filesystem;
using fake::FakeCommunicator;
using fake::run_ranks;

std::string tree_path(const std::string& rel) {
  return std::string(STIFFMD_SOURCE_DIR) + "/" + rel;
}

const std::string kDeck = "tests/decks/chains_by_parts.toml";
// 40 steps of h = 0.005, a checkpoint every 0.1 (steps 20 and 40), a thermo row every 0.01.
const std::vector<std::string> kOverrides = {"run.steps=40", "output.checkpoint_interval=0.1",
                                             "output.thermo_interval=0.01"};

std::string bytes(const fs::path& p) {
  std::ifstream in(p, std::ios::binary);
  return {std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
}

fs::path test_root(const std::string& what) {
  return fs::temp_directory_path() / ("stiffmd_restart_parts_" + what + "_" + std::to_string(::getpid()));
}

// How a rank's scene is made and started: the whole scene cut by the run, or the scene's
// description whose molecules the source makes (chains_part).
enum class Start { whole, described };

RunOptions options(const fs::path& dir, const FakeCommunicator& comm) {
  RunOptions opt;
  opt.out_dir = dir.string();
  opt.handle_signals = false;
  opt.processes = &comm;
  return opt;
}

// The uninterrupted run into `dir` on `ranks`, its checkpoint of step 20 copied to `at_20`.
void run_uninterrupted(int ranks, const fs::path& dir, const fs::path& at_20) {
  fs::remove_all(dir);
  run_ranks(
      ranks,
      [&](const FakeCommunicator& comm) {
        const test::OneThread rank_thread;
        const Deck deck(tree_path(kDeck), kOverrides);
        Scene sc = load_scene(deck);
        std::ostringstream log;
        prepare_scene(sc, log);
        Run run(sc, options(dir, comm), log);
        run.step_to(21);  // step 20's checkpoint is written before step 21
        if (comm.root()) fs::copy_file(dir / "checkpoint.bin", at_20, fs::copy_options::overwrite_existing);
        run.step_to(run.final_step());
        run.finish();
      },
      std::chrono::seconds(300));
}

// A restart from `checkpoint` into `dir` (a copy of the uninterrupted run's outputs, cut back by
// the restart) on `ranks`. Each rank's AgreedInputError message, if any, in `refused`.
void run_restart(int ranks, Start start, const fs::path& from, const fs::path& dir, const fs::path& checkpoint,
                 std::vector<std::string>* refused = nullptr) {
  fs::remove_all(dir);
  fs::copy(from, dir, fs::copy_options::recursive);
  if (refused) refused->assign(static_cast<size_t>(ranks), "");
  run_ranks(
      ranks,
      [&](const FakeCommunicator& comm) {
        const test::OneThread rank_thread;
        const Deck deck(tree_path(kDeck), kOverrides);
        Scene sc = load_scene(deck, {}, start == Start::described ? SceneContent::description : SceneContent::whole);
        if (start == Start::described) {
          ASSERT_EQ(sc.state.size(), 0) << "the deck's description holds particles";
        }
        RunOptions opt = options(dir, comm);
        opt.restart = checkpoint.string();
        if (start == Start::described) opt.part = [&] { return chains_part(deck, sc, comm); };
        std::ostringstream log;
        try {
          run_simulation(sc, opt, log);
        } catch (const AgreedInputError& e) {
          if (!refused) throw;
          (*refused)[static_cast<size_t>(comm.rank())] = e.what();
        }
      },
      std::chrono::seconds(300));
}

TEST(RestartParts, FromTheDescriptionOnTwoAndThreeRanksTheFilesAreTheWholePathRestartsBytes) {
  const fs::path root = test_root("bits");
  fs::remove_all(root);
  fs::create_directories(root);
  const fs::path full = root / "full", at_20 = root / "at_20.bin";
  run_uninterrupted(2, full, at_20);
  ASSERT_TRUE(fs::exists(at_20));
  EXPECT_EQ(read_checkpoint(at_20.string()).state.step, 20);
  for (const int ranks : {2, 3}) {
    const fs::path parts = root / ("parts_" + std::to_string(ranks)), whole = root / ("whole_" + std::to_string(ranks));
    run_restart(ranks, Start::whole, full, whole, at_20);
    run_restart(ranks, Start::described, full, parts, at_20);
    // thermo.csv: the uninterrupted run's bytes. checkpoint.bin: the bytes of the restart from the
    // whole scene on as many ranks, with the uninterrupted run's positions and velocities. (Its
    // run statistics count one more neighbour-list build, the restart's, and on another number of
    // ranks the sums over particles in its words — the thermostat's heat — add in another order.)
    const std::string thermo = bytes(full / "thermo.csv");
    ASSERT_FALSE(thermo.empty());
    EXPECT_TRUE(thermo == bytes(parts / "thermo.csv")) << "thermo.csv of the restart by parts on " << ranks;
    EXPECT_TRUE(thermo == bytes(whole / "thermo.csv")) << "thermo.csv of the restart from the whole scene";
    const std::string checkpoint = bytes(whole / "checkpoint.bin");
    ASSERT_FALSE(checkpoint.empty());
    EXPECT_TRUE(checkpoint == bytes(parts / "checkpoint.bin")) << "checkpoint.bin of the restart by parts on " << ranks;
    const Checkpoint want = read_checkpoint((full / "checkpoint.bin").string());
    const Checkpoint got = read_checkpoint((parts / "checkpoint.bin").string());
    EXPECT_TRUE(got.state.x == want.state.x && got.state.v == want.state.v && got.state.step == 40);
    EXPECT_EQ(got.scene_fingerprint, want.scene_fingerprint);
    EXPECT_NE(bytes(parts / "summary.json").find("\"setup\": \"parts\""), std::string::npos);
  }
  fs::remove_all(root);
}

// One byte of x flipped in the rows rank 1 reads (its block of particles), and the file cut short:
// every rank refuses with the same line, read_checkpoint's (one process reading the whole file).
TEST(RestartParts, ADamagedOrTruncatedCheckpointIsRefusedOnEveryRankWithOneLine) {
  const fs::path root = test_root("damaged");
  fs::remove_all(root);
  fs::create_directories(root);
  const fs::path full = root / "full", at_20 = root / "at_20.bin";
  run_uninterrupted(2, full, at_20);
  const std::string good = bytes(at_20);
  const Checkpoint c = read_checkpoint(at_20.string());
  const int n = c.state.size();
  // x's first value: after the header, count, step, t, h, the method and the stage, x's count.
  const std::size_t x0 = 40 + 4 * 8 + 8 + c.method.size() + 8 + 8 + c.stage_name.size() + 8;
  const ParticleBlock rank1 = block_of(n, 3, 1);
  std::string flipped = good;
  flipped[x0 + 24 * static_cast<std::size_t>(rank1.first) + 5] ^= 0x10;
  const std::string truncated = good.substr(0, good.size() - 100);
  for (const auto& [name, text] : {std::pair{"flipped", flipped}, std::pair{"truncated", truncated}}) {
    const fs::path bad = root / (std::string(name) + ".bin");
    std::ofstream(bad, std::ios::binary) << text;
    std::string expected;
    try {
      read_checkpoint(bad.string());
    } catch (const InputError& e) {
      expected = e.what();
    }
    ASSERT_FALSE(expected.empty()) << name;
    EXPECT_NE(expected.find(bad.string()), std::string::npos) << expected;
    EXPECT_NE(expected.find(std::string(name) == "flipped" ? "damaged checkpoint" : "truncated checkpoint"),
              std::string::npos)
        << expected;
    std::vector<std::string> refused;
    const fs::path dir = root / ("restart_" + std::string(name));
    run_restart(3, Start::described, full, dir, bad, &refused);
    for (int r = 0; r < 3; ++r) EXPECT_EQ(refused[static_cast<size_t>(r)], expected) << name << ", rank " << r;
    // Refused before any output was touched: the outputs are the uninterrupted run's.
    EXPECT_TRUE(bytes(full / "thermo.csv") == bytes(dir / "thermo.csv")) << name;
  }
  fs::remove_all(root);
}

// The reader on 3 ranks, each given its block of particles: the rows, the integrator's words but
// its columns and the other blocks are read_checkpoint's; a rank reads its rows (x, v, masses,
// carried columns) and the blocks that are not per particle, less than twice its share of the
// per-particle blocks plus the rest; its crc32 range is its share of the file.
TEST(RestartParts, ARankReadsItsRowsAndTheBlocksThatAreNotPerParticle) {
  const fs::path root = test_root("reader");
  fs::remove_all(root);
  fs::create_directories(root);
  const fs::path full = root / "full", at_20 = root / "at_20.bin";
  run_uninterrupted(2, full, at_20);
  const Checkpoint whole = read_checkpoint(at_20.string());
  const int n = whole.state.size();
  const auto file = static_cast<double>(fs::file_size(at_20));
  const int ranks = 3;
  std::mutex lock;
  std::vector<std::string> failures;
  run_ranks(
      ranks,
      [&](const FakeCommunicator& comm) {
        const test::OneThread rank_thread;
        const Deck deck(tree_path(kDeck), kOverrides);
        Scene sc = load_scene(deck, {}, SceneContent::description);
        DomainIntegrator domain(sc, comm, make_integrator(sc.integrator, *sc.forces, sc.state.inv_mass));
        const std::vector<WordRun> layout = domain.word_layout();
        const CheckpointParts reader(at_20.string(), comm, layout, sc.integrator.method);
        const ParticleBlock b = block_of(n, ranks, comm.rank());
        std::vector<int> ids;
        for (std::int64_t k = 0; k < b.count; ++k) ids.push_back(static_cast<int>(b.first + k));
        Eigen::Matrix3Xd x, v;
        Eigen::VectorXd inv_mass;
        reader.particles(ids, x, v, inv_mass);
        const std::vector<Eigen::Matrix3Xd> columns = reader.columns(ids);
        std::vector<std::string> bad;
        auto check = [&](bool ok, const std::string& what) {
          if (!ok) bad.push_back("rank " + std::to_string(comm.rank()) + ": " + what);
        };
        const auto first = static_cast<Eigen::Index>(b.first), count = static_cast<Eigen::Index>(b.count);
        check(x == whole.state.x.middleCols(first, count), "x rows");
        check(v == whole.state.v.middleCols(first, count), "v rows");
        check(inv_mass == whole.state.inv_mass.segment(first, count), "inverse masses");
        check(reader.num_particles() == n, "particle count");
        // The whole words: the runs, each column's 3 N words where it stands.
        std::size_t column_count = 0;
        std::vector<double> rest_words;
        std::size_t at = 0;
        bool columns_match = true;
        for (const WordRun& run : layout) {
          if (run.column < 0) {
            rest_words.insert(rest_words.end(), whole.integrator_state.begin() + static_cast<std::ptrdiff_t>(at),
                              whole.integrator_state.begin() + static_cast<std::ptrdiff_t>(at + run.words.size()));
            at += run.words.size();
            continue;
          }
          ++column_count;
          const Eigen::Map<const Eigen::Matrix3Xd> all(whole.integrator_state.data() + at, 3, n);
          columns_match &= columns.at(static_cast<size_t>(run.column)) == all.middleCols(first, count);
          at += 3 * static_cast<std::size_t>(n);
        }
        check(at == whole.integrator_state.size(), "the layout covers the integrator's words");
        check(column_count > 0, "Langevin carries columns");
        check(columns_match, "carried columns' rows");
        const Checkpoint& rest = reader.rest();
        check(rest.integrator_state == rest_words, "the integrator's words but its columns");
        check(rest.thermo_state == whole.thermo_state && rest.monitor_state == whole.monitor_state &&
                  rest.run_state == whole.run_state && rest.force_term_states == whole.force_term_states,
              "the blocks that are not per particle");
        check(rest.state.step == 20 && rest.state.t == whole.state.t && rest.method == whole.method &&
                  rest.scene_fingerprint == whole.scene_fingerprint,
              "the prefix");
        // Per particle: x, v (3 each), the inverse mass, 3 per carried column, 8 bytes a word.
        const double per_particle = 8.0 * n * (7.0 + 3.0 * static_cast<double>(column_count));
        const double share = per_particle / ranks, rest_bytes = file - per_particle;
        const auto read = static_cast<double>(reader.bytes_read());
        check(read < 2.0 * share + rest_bytes, "read " + std::to_string(read) + " bytes, share " +
                                                   std::to_string(share) + " + rest " + std::to_string(rest_bytes));
        check(read >= share, "read fewer bytes than its rows");
        check(static_cast<double>(reader.crc_bytes_read()) <= (file - 12) / ranks + 1, "crc32 range");
        const std::lock_guard<std::mutex> guard(lock);
        failures.insert(failures.end(), bad.begin(), bad.end());
      },
      std::chrono::seconds(300));
  for (const std::string& f : failures) ADD_FAILURE() << f;
  fs::remove_all(root);
}

}  // namespace
}  // namespace stiffmd
