// The trajectories' time-independent data written from the ranks' parts of a decomposed run
// (engine/run/topology_parts.hpp, engine/run/h5md_static_parts.hpp, engine/io/rows_to_root.hpp):
// for any partition of the molecules on 1–3 fake ranks (tests/fake_processes.hpp), topology.data
// is the bytes write_scene_lammps_data writes from the whole scene, and the H5MD file's
// time-independent datasets are those a setup given per particle writes — with the scene's
// particles taken away before the parts write, so that nothing of them is read but the parts.
// RunOutputs given the parts (StaticParts) writes the same topology.data and XYZ frame as from the
// whole scene.
#include <gtest/gtest.h>
#include <hdf5.h>

#include <algorithm>
#include <filesystem>
#include <fstream>
#include <map>
#include <numeric>
#include <random>
#include <span>
#include <sstream>
#include <string>
#include <system_error>
#include <vector>

#include "core/errors.hpp"
#include "engine/deck/deck.hpp"
#include "engine/domain/part_load.hpp"
#include "engine/domain/part_molecules.hpp"
#include "engine/io/h5md_writer.hpp"
#include "engine/io/rows_to_root.hpp"
#include "engine/observe/observables.hpp"
#include "engine/run/h5md_static_parts.hpp"
#include "engine/run/outputs.hpp"
#include "engine/run/topology_parts.hpp"
#include "engine/scene/scene.hpp"
#include "fake_processes.hpp"
#include "test_support.hpp"

namespace stiffmd {
namespace {

namespace fs = std::filesystem;
using fake::FakeCommunicator;
using fake::run_ranks;

std::string slurp(const fs::path& p) {
  std::ifstream f(p, std::ios::binary);
  std::ostringstream s;
  s << f.rdbuf();
  return s.str();
}

// This process's scratch directory, removed when the tests end.
struct Scratch {
  fs::path dir = fs::temp_directory_path() / ("stiffmd_static_by_parts_" + std::to_string(::getpid()));
  ~Scratch() {
    std::error_code ec;
    fs::remove_all(dir, ec);
  }
};
fs::path scratch(const std::string& name) {
  static const Scratch files;
  fs::create_directories(files.dir);
  return files.dir / name;
}

// One rank's part of a random partition of the molecules (molecule m to rank pick(m), alike on
// every rank), with its positions and velocities.
struct Part {
  PartMolecules molecules;
  Eigen::Matrix3Xd x, v;
};
Part part_of(const Scene& sc, int ranks, int rank, unsigned seed) {
  const int n = sc.state.size();
  const std::vector<int> molecule = bonded_molecules(sc.topology, n);
  const int molecules = n ? *std::max_element(molecule.begin(), molecule.end()) + 1 : 0;
  std::mt19937 draw(seed);
  std::uniform_int_distribution<int> pick(0, ranks - 1);
  std::vector<int> to(static_cast<size_t>(molecules));
  for (int& r : to) r = pick(draw);
  std::vector<int> mine;
  for (int g = 0; g < n; ++g)
    if (to[static_cast<size_t>(molecule[static_cast<size_t>(g)])] == rank) mine.push_back(g);
  Part out;
  out.molecules = cut_part({std::span<const double>(sc.state.inv_mass.data(), static_cast<size_t>(n)),
                            sc.particle_type,
                            sc.charge,
                            sc.topology.molecule,
                            {},
                            sc.topology},
                           mine);
  out.x.resize(3, static_cast<Eigen::Index>(mine.size()));
  out.v.resize(3, static_cast<Eigen::Index>(mine.size()));
  for (size_t k = 0; k < mine.size(); ++k)
    out.x.col(k) = sc.state.x.col(mine[k]), out.v.col(k) = sc.state.v.col(mine[k]);
  return out;
}

// Every rank's part, cut before the scene loses its particles.
std::vector<Part> parts_of(const Scene& sc, int ranks, unsigned seed) {
  std::vector<Part> parts;
  for (int r = 0; r < ranks; ++r) parts.push_back(part_of(sc, ranks, r, seed));
  return parts;
}

// The scene without its particles and bonded items (what a scene's description holds): the
// writers from the parts must read none of them.
void take_particles_away(Scene& sc) {
  sc.state.x.resize(3, 0);
  sc.state.v.resize(3, 0);
  sc.state.inv_mass.resize(0);
  sc.particle_type.clear();
  sc.charge.clear();
  sc.topology.bonds.clear();
  sc.topology.angles.clear();
  sc.topology.dihedrals.clear();
  sc.topology.impropers.clear();
  sc.topology.molecule.clear();
}

// Decks with bonds, angles, dihedrals, charges, molecule ids, and chains built by molecule.
const char* const kDecks[] = {"inputs/kremer_grest.toml", "inputs/peptide.toml", "tests/decks/chains_by_parts.toml"};

const std::string kTitle = "stiffmd topology of a deck (positions at t = 0)";

void expect_topology_by_parts(const char* deck, bool open_box) {
  for (int ranks = 1; ranks <= 3; ++ranks)
    for (unsigned seed = 1; seed <= 2; ++seed) {
      SCOPED_TRACE(std::string(deck) + ", " + std::to_string(ranks) + " ranks, seed " + std::to_string(seed));
      Scene sc = test::load(deck);
      if (open_box) sc.box.periodic = {false, false, false};
      const fs::path whole = scratch("whole.data"), by_parts = scratch("parts.data");
      write_scene_lammps_data(sc, whole.string(), kTitle, false);
      const std::int64_t n = sc.state.size();
      const std::vector<Part> parts = parts_of(sc, ranks, seed);
      take_particles_away(sc);
      run_ranks(ranks, [&](const FakeCommunicator& comm) {
        const Part& mine = parts[static_cast<size_t>(comm.rank())];
        write_topology_parts(sc, mine.molecules, mine.x, mine.v, n, comm, by_parts.string(), kTitle);
      });
      const std::string expected = slurp(whole);
      ASSERT_FALSE(expected.empty());
      EXPECT_TRUE(slurp(by_parts) == expected) << "topology.data from the parts differs from the whole scene's";
    }
}

TEST(StaticByParts, TopologyDataFromThePartsIsTheWholeScenesBytes) {
  for (const char* deck : kDecks) expect_topology_by_parts(deck, false);
}

// An open box is the particles' bounding box ± 1: a reduction over the parts.
TEST(StaticByParts, TopologyDataOfAnOpenBoxFromTheParts) {
  expect_topology_by_parts("inputs/peptide.toml", true);
}

TEST(StaticByParts, ANonFinitePositionIsRefusedOnEveryRankNamingTheFirstAtom) {
  Scene sc = test::load("inputs/kremer_grest.toml");
  sc.state.x(1, 57) = std::nan("");
  sc.state.v(0, 12) = std::numeric_limits<double>::infinity();
  const fs::path path = scratch("bad.data");
  fs::remove(path);
  std::string expected;
  try {
    write_scene_lammps_data(sc, path.string(), kTitle, false);
  } catch (const NumericalError& e) {
    expected = e.what();
  }
  ASSERT_NE(expected, "");
  const std::int64_t n = sc.state.size();
  const std::vector<Part> parts = parts_of(sc, 3, 5);
  std::vector<std::string> said(3);
  run_ranks(3, [&](const FakeCommunicator& comm) {
    const Part& mine = parts[static_cast<size_t>(comm.rank())];
    try {
      write_topology_parts(sc, mine.molecules, mine.x, mine.v, n, comm, path.string(), kTitle);
    } catch (const AgreedStop& e) {
      said[static_cast<size_t>(comm.rank())] = e.what();
    }
  });
  for (const std::string& s : said) EXPECT_EQ(s, expected);
  EXPECT_FALSE(fs::exists(path)) << "refused before the file is opened";
}

// Every dataset of an HDF5 file by path (shape and the bytes of its native type), and the
// species' `elements` attribute.
std::map<std::string, std::string> h5_datasets(const fs::path& file) {
  std::map<std::string, std::string> out;
  const hid_t f = H5Fopen(file.c_str(), H5F_ACC_RDONLY, H5P_DEFAULT);
  if (f < 0) return out;
  auto visit = [](hid_t obj, const char* name, const H5O_info_t* info, void* data) -> herr_t {
    if (info->type != H5O_TYPE_DATASET) return 0;
    auto& into = *static_cast<std::map<std::string, std::string>*>(data);
    const hid_t d = H5Dopen2(obj, name, H5P_DEFAULT);
    const hid_t space = H5Dget_space(d);
    const int rank = H5Sget_simple_extent_ndims(space);
    std::vector<hsize_t> dims(static_cast<size_t>(std::max(rank, 0)));
    H5Sget_simple_extent_dims(space, dims.data(), nullptr);
    const auto points = static_cast<size_t>(H5Sget_simple_extent_npoints(space));
    std::string value = "dims";
    for (hsize_t n : dims) value += " " + std::to_string(n);
    value += ":";
    const hid_t file_type = H5Dget_type(d);
    const hid_t t = H5Tget_native_type(file_type, H5T_DIR_ASCEND);
    std::string bytes(points * H5Tget_size(t), '\0');
    if (points > 0) H5Dread(d, t, H5S_ALL, H5S_ALL, H5P_DEFAULT, bytes.data());
    into[name] = value + bytes;
    H5Tclose(t);
    H5Tclose(file_type);
    H5Sclose(space);
    H5Dclose(d);
    return 0;
  };
  H5Ovisit2(f, H5_INDEX_NAME, H5_ITER_NATIVE, visit, &out, H5O_INFO_BASIC);
  const hid_t a = H5Aopen_by_name(f, "particles/all/species", "elements", H5P_DEFAULT, H5P_DEFAULT);
  const hid_t type = H5Aget_type(a), space = H5Aget_space(a);
  std::string elements(static_cast<size_t>(H5Sget_simple_extent_npoints(space)) * H5Tget_size(type), '\0');
  H5Aread(a, type, elements.data());
  out["particles/all/species@elements"] = std::to_string(H5Tget_size(type)) + ":" + elements;
  H5Sclose(space);
  H5Tclose(type);
  H5Aclose(a);
  H5Fclose(f);
  return out;
}

// What RunOutputs gave the writer before the parts: every time-independent array per particle.
H5mdSetup per_particle_setup(const Scene& sc) {
  H5mdSetup setup;
  setup.num_particles = sc.state.size();
  setup.mass.resize(sc.state.size());
  for (int i = 0; i < sc.state.size(); ++i) {
    setup.species.push_back(sc.types[static_cast<size_t>(sc.particle_type[i])].element);
    setup.mass[i] = sc.types[static_cast<size_t>(sc.particle_type[i])].mass;
  }
  if (sc.charged()) setup.charge = sc.charge;
  for (const Bond& b : sc.topology.bonds) setup.bonds.emplace_back(b.i, b.j);
  setup.box = sc.box;
  setup.author = "a";
  setup.creator_version = "v";
  return setup;
}

TEST(StaticByParts, H5mdTimeIndependentDatasetsFromThePartsAreTheWholeScenes) {
  for (const char* deck : kDecks)
    for (int ranks = 1; ranks <= 3; ++ranks) {
      SCOPED_TRACE(std::string(deck) + ", " + std::to_string(ranks) + " ranks");
      Scene sc = test::load(deck);
      const fs::path whole = scratch("whole.h5"), by_parts = scratch("parts.h5");
      H5mdSetup setup = per_particle_setup(sc);
      { H5mdWriter(whole.string(), setup, false); }
      const std::vector<Part> parts = parts_of(sc, ranks, 11 + static_cast<unsigned>(ranks));
      take_particles_away(sc);
      run_ranks(ranks, [&](const FakeCommunicator& comm) {
        const Part& mine = parts[static_cast<size_t>(comm.rank())];
        H5mdSetup rows;
        rows.num_particles = setup.num_particles;
        rows.box = setup.box;
        rows.author = setup.author;
        rows.creator_version = setup.creator_version;
        describe_h5md_static(sc, mine.molecules, comm, rows);
        std::unique_ptr<H5mdWriter> writer;
        if (comm.root()) writer = std::make_unique<H5mdWriter>(by_parts.string(), rows, false);
        write_h5md_static_parts(writer.get(), rows, sc, mine.molecules, comm);
      });
      const auto expected = h5_datasets(whole), got = h5_datasets(by_parts);
      ASSERT_GT(expected.size(), 10u);
      EXPECT_EQ(got.size(), expected.size());
      for (const auto& [name, value] : expected) {
        const auto it = got.find(name);
        ASSERT_NE(it, got.end()) << name;
        EXPECT_TRUE(it->second == value) << name << " differs";
      }
    }
}

// Rows at random on 1–3 ranks reach rank 0 in order, block by block, each once; a row on two
// ranks or on none is refused.
TEST(StaticByParts, RowsReachRankZeroInOrderBlockByBlock) {
  const std::int64_t n = 1000;
  for (int ranks = 1; ranks <= 3; ++ranks)
    for (const std::int64_t block : {1, 7, 64, 1000, 5000}) {
      std::vector<std::vector<std::int64_t>> keys(static_cast<size_t>(ranks));
      std::mt19937 draw(static_cast<unsigned>(block + ranks));
      for (std::int64_t g = 0; g < n; ++g) keys[draw() % static_cast<unsigned>(ranks)].push_back(g);
      std::vector<double> seen;
      std::int64_t blocks = 0;
      run_ranks(ranks, [&](const FakeCommunicator& comm) {
        const auto& mine = keys[static_cast<size_t>(comm.rank())];
        stream_rows_to_root(
            comm, {n, 2, block}, mine.size(), [&](std::size_t k) { return mine[k]; },
            [&](std::size_t k, double* row) { row[0] = static_cast<double>(mine[k]), row[1] = -0.5 * mine[k]; },
            [&](std::int64_t first, std::int64_t count, const double* rows) {
              EXPECT_EQ(first, static_cast<std::int64_t>(seen.size() / 2));
              EXPECT_LE(count, block);
              seen.insert(seen.end(), rows, rows + 2 * count);
              ++blocks;
            });
      });
      ASSERT_EQ(seen.size(), 2u * n);
      for (std::int64_t g = 0; g < n; ++g) {
        EXPECT_EQ(seen[static_cast<size_t>(2 * g)], static_cast<double>(g));
        EXPECT_EQ(seen[static_cast<size_t>(2 * g + 1)], -0.5 * static_cast<double>(g));
      }
      EXPECT_EQ(blocks, (n + block - 1) / block);
    }
  const auto refused = [](std::vector<std::vector<std::int64_t>> keys) {
    EXPECT_THROW(run_ranks(2,
                           [&](const FakeCommunicator& comm) {
                             const auto& mine = keys[static_cast<size_t>(comm.rank())];
                             stream_rows_to_root(
                                 comm, {4, 1, 2}, mine.size(), [&](std::size_t k) { return mine[k]; },
                                 [](std::size_t, double* row) { row[0] = 1; },
                                 [](std::int64_t, std::int64_t, const double*) {});
                           }),
                 std::logic_error);
  };
  refused({{0, 1, 2}, {2, 3}});  // 2 twice
  refused({{0, 1}, {3}});        // 2 on none
  refused({{0, 1, 2, 3}, {4}});  // 4 out of range
}

// RunOutputs given the parts (and a scene without particles) writes topology.data and, by blocks
// with the rows' types, an XYZ frame identical to those it writes from the whole scene.
TEST(StaticByParts, RunOutputsFromThePartsWriteTheWholeScenesTopologyAndXyz) {
  for (const char* deck : {"inputs/peptide.toml", "tests/decks/chains_by_parts.toml"})
    for (int ranks = 1; ranks <= 3; ++ranks) {
      SCOPED_TRACE(std::string(deck) + ", " + std::to_string(ranks) + " ranks");
      Scene sc = test::load(deck);
      sc.output.xyz = "t.xyz";
      sc.output.h5md.clear();  // a shared H5MD file needs MPI (fake ranks have none): the test above
      sc.output.state.clear();
      sc.output.thermo.clear();
      sc.output.lammps_data.clear();
      const fs::path whole_dir = scratch("whole_run"), parts_dir = scratch("parts_run");
      fs::remove_all(whole_dir), fs::remove_all(parts_dir);
      fs::create_directories(whole_dir), fs::create_directories(parts_dir);
      const int n = sc.state.size();
      const Thermo thermo(*sc.forces, sc.state.inv_mass, sc.observables, &sc.topology);
      const std::vector<double> row(thermo.columns().size(), 0.0);
      {
        std::vector<std::string> files;
        std::ostringstream log;
        RunOutputs out(sc, n, whole_dir.string(), thermo, nullptr, files, log);
        out.due(sc.state.t, true);
        out.write(sc.state, row);
        out.close();
      }
      const std::vector<Part> parts = parts_of(sc, ranks, 3);
      State frame;  // what RunOutputs::write is given besides the rows: the frame's size, time, step
      frame.x.resize(3, n);
      frame.t = sc.state.t, frame.step = sc.state.step;
      take_particles_away(sc);
      run_ranks(ranks, [&](const FakeCommunicator& comm) {
        const Part& mine = parts[static_cast<size_t>(comm.rank())];
        const StaticParts static_parts{mine.molecules, mine.x, mine.v};
        std::vector<std::string> files;
        std::ostringstream log;
        RunOutputs out(sc, n, parts_dir.string(), thermo, nullptr, files, log, &comm, &static_parts);
        out.due(frame.t, true);
        const ProcessRows rows{mine.molecules.global, mine.x, mine.v, nullptr, &mine.molecules.type};
        out.write(frame, row, &rows, true);
        out.close();
      });
      for (const char* file : {"topology.data", "t.xyz"}) {
        const std::string expected = slurp(whole_dir / file);
        ASSERT_FALSE(expected.empty()) << file;
        EXPECT_TRUE(slurp(parts_dir / file) == expected) << file << " differs";
      }
    }
}

}  // namespace
}  // namespace stiffmd
