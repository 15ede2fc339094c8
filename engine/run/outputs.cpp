#include "engine/run/outputs.hpp"

#include <filesystem>
#include <fstream>
#include <map>
#include <numeric>
#include <optional>
#include <stdexcept>
#include <system_error>

#include "core/communicator.hpp"
#include "core/errors.hpp"
#include "engine/io/lammps_data.hpp"
#include "engine/observe/histograms.hpp"
#include "engine/observe/polymer_observables.hpp"
#include "engine/run/h5md_static_parts.hpp"
#include "engine/run/lammps_type_numbers.hpp"
#include "engine/run/topology_parts.hpp"

namespace stiffmd {
namespace fs = std::filesystem;

namespace {

std::vector<std::string> state_columns(int n) {
  std::vector<std::string> c = {"time"};
  for (const char* what : {"", "p"})
    for (int i = 0; i < n; ++i)
      for (const char* a : {"x", "y", "z"}) c.push_back(std::string(what) + a + "_" + std::to_string(i));
  return c;
}

// A force-field section in LAMMPS's numbering, when the scene's terms give every type of the kind
// (1 .. `types`) a row of one LAMMPS style; else nothing (a partial section would not read).
void add_coeffs(ImportedSystem& out, const char* name, const LammpsCoeffs::Section& section,
                const std::vector<int>& number, int types) {
  if (!section.representable || section.style.empty() || types == 0) return;
  ImportedSystem::CoeffSection c{name, section.style, {}};
  std::map<std::pair<int, int>, std::string> rows;  // by LAMMPS numbers
  for (const auto& [key, row] : section.rows) {
    const auto [a, b] = key;
    if (b < 0) {
      rows[{number[static_cast<size_t>(a)], 0}] = std::to_string(number[static_cast<size_t>(a)]) + " " + row;
    } else {
      const int i = std::min(number[static_cast<size_t>(a)], number[static_cast<size_t>(b)]);
      const int j = std::max(number[static_cast<size_t>(a)], number[static_cast<size_t>(b)]);
      const bool diagonal_section = std::string_view(name) == "Pair Coeffs";  // rows "I coeffs"
      if (diagonal_section && i != j) return;
      rows[{i, j}] = std::to_string(i) + (diagonal_section ? "" : " " + std::to_string(j)) + " " + row;
    }
  }
  const size_t expected = section.pairwise ? static_cast<size_t>(types) * (types + 1) / 2 : static_cast<size_t>(types);
  if (rows.size() != expected) return;
  for (const auto& [key, row] : rows) c.rows.push_back(row);
  out.coeffs.push_back(std::move(c));
}

// The scene's state as a LAMMPS data file's content: the type numbers of an imported data file
// kept (Scene::lammps_types), every other particle/bond/angle/dihedral type numbered after them in
// deck order; Masses, and with `force_field` the Coeffs sections where LAMMPS has the same forms
// (Scene::lammps_coeffs); an open box gets the particles' bounding box.
ImportedSystem to_lammps(const Scene& sc, bool force_field) {
  ImportedSystem out;
  const State& s = sc.state;
  const Topology& top = sc.topology;
  const LammpsTypes numbers = lammps_types(sc);
  const std::vector<int>& atom = numbers.atom;
  const std::vector<int>& bond = numbers.bond;
  const std::vector<int>& angle = numbers.angle;
  const std::vector<int>& dihedral = numbers.dihedral;
  const std::vector<int>& improper = numbers.improper;
  out.x = s.x;
  out.v = s.v * sc.units.out(Dimension::velocity);  // LAMMPS's velocity unit (real: Å/fs)
  for (int i = 0; i < s.size(); ++i) {
    out.type.push_back(atom[static_cast<size_t>(sc.particle_type[i])]);
    out.molecule.push_back(top.molecule.empty() ? 0 : top.molecule[i] + 1);
    out.id.push_back(i + 1);
  }
  if (sc.charged()) out.charge = sc.charge;
  out.num_atom_types = numbers.atom_types;
  out.type_mass = numbers.type_mass;
  for (const Bond& b : top.bonds) out.bonds.push_back({bond[static_cast<size_t>(b.type)], b.i, b.j});
  for (const Angle& a : top.angles) out.angles.push_back({angle[static_cast<size_t>(a.type)], a.i, a.j, a.k});
  for (const Dihedral& d : top.dihedrals)
    out.dihedrals.push_back({dihedral[static_cast<size_t>(d.type)], d.i, d.j, d.k, d.l});
  out.num_bond_types = numbers.bond_types;
  out.num_angle_types = numbers.angle_types;
  out.num_dihedral_types = numbers.dihedral_types;
  for (const Improper& d : top.impropers)
    out.impropers.push_back({improper[static_cast<size_t>(d.type)], d.i, d.j, d.k, d.l});
  out.num_improper_types = numbers.improper_types;
  const LammpsCoeffs& ff = sc.lammps_coeffs;
  // One atom type: its one pair is the diagonal, "Pair Coeffs" (which more readers know).
  if (force_field) {
    add_coeffs(out, out.num_atom_types == 1 ? "Pair Coeffs" : "PairIJ Coeffs", ff.pair, atom, out.num_atom_types);
    if (!top.bonds.empty()) add_coeffs(out, "Bond Coeffs", ff.bond, bond, out.num_bond_types);
    if (!top.angles.empty()) add_coeffs(out, "Angle Coeffs", ff.angle, angle, out.num_angle_types);
    if (!top.dihedrals.empty()) add_coeffs(out, "Dihedral Coeffs", ff.dihedral, dihedral, out.num_dihedral_types);
    if (!top.impropers.empty()) add_coeffs(out, "Improper Coeffs", ff.improper, improper, out.num_improper_types);
  }
  if (sc.box.periodic.all()) {  // the box now (a barostat moves it)
    out.lo = sc.forces->box().origin;
    out.hi = sc.forces->box().origin + sc.forces->box().lengths;
  } else {
    out.lo = s.x.rowwise().minCoeff().array() - 1.0;
    out.hi = s.x.rowwise().maxCoeff().array() + 1.0;
  }
  return out;
}

std::string topology_title(const Scene& sc) {
  return "stiffmd topology of " + sc.deck_path + " (positions at t = 0)";
}

// The whole scene's particles as one part (engine/domain/part_molecules.hpp).
PartMolecules whole_part(const Scene& sc) {
  std::vector<int> all(static_cast<std::size_t>(sc.state.size()));
  std::iota(all.begin(), all.end(), 0);
  return cut_part({std::span<const double>(sc.state.inv_mass.data(), all.size()),
                   sc.particle_type,
                   sc.charge,
                   sc.topology.molecule,
                   {},
                   sc.topology},
                  all);
}

}  // namespace

void prepare_output_directory(const Scene& sc, const std::string& out_dir) {
  const fs::path dir(out_dir);
  std::error_code ec;
  if (fs::exists(dir, ec) && !fs::is_directory(dir, ec))
    throw InputError(out_dir + ": output path exists and is not a directory");
  fs::create_directories(dir, ec);
  if (ec || !fs::is_directory(dir, ec)) throw InputError(out_dir + ": cannot create output directory: " + ec.message());
  check_output_paths(sc, out_dir);       // before any step: an output that cannot be written fails now
  fs::remove(dir / "summary.json", ec);  // a summary only ever describes a finished run
}

void check_rank_directory(const std::string& dir, int rank) {
  const fs::path probe = fs::path(dir) / (".stiffmd_write_test." + std::to_string(rank));
  std::error_code ec;
  if (!fs::is_directory(dir, ec))
    throw InputError(dir + ": the output directory rank 0 created is not there for rank " + std::to_string(rank) +
                     " (every rank writes its rows of the H5MD file: give a directory that all of them see)");
  if (!std::ofstream(probe))
    throw InputError(dir + ": output directory is not writable by rank " + std::to_string(rank) +
                     " (every rank writes its rows of the H5MD file)");
  fs::remove(probe, ec);
}

void write_scene_lammps_data(const Scene& scene, const std::string& path, const std::string& title, bool force_field) {
  const Topology& t = scene.topology;
  write_lammps_data(path, to_lammps(scene, force_field),
                    scene.charged()                                ? "full"
                    : !t.dihedrals.empty() || !t.impropers.empty() ? "molecular"
                    : t.angles.empty()                             ? "bond"
                                                                   : "angle",
                    title);
}

RunOutputs::RunOutputs(Scene& sc, int num_particles, const std::string& out_dir, const Thermo& thermo,
                       const double* restart_cut, std::vector<std::string>& files, std::ostream& log,
                       const Communicator* processes, const StaticParts* parts)
    : sc_(sc),
      dir_(out_dir),
      processes_(processes),
      num_particles_(num_particles),
      root_(!processes || processes->root()),
      shared_h5md_(processes && processes->size() > 1 && H5mdWriter::shared_files()),
      xyz_due_(sc.output.xyz_interval),
      thermo_due_(sc.output.thermo_interval),
      state_due_(sc.output.state_interval),
      h5md_due_(sc.output.h5md_interval),
      table_(thermo, num_particles, sc.output.thermo_norm, sc.units) {
  const fs::path dir(out_dir);
  const State& s = sc.state;
  const bool restarting = restart_cut != nullptr;
  const double cut = restarting ? *restart_cut : 0.0;
  const double tol = 1e-9 * sc.integrator.h;
  // The files hold times in the deck's units (real: fs), the engine's grids in its own.
  const double time_out = sc.units.out(Dimension::time);
  const double file_cut = cut * time_out, file_tol = tol * time_out;
  velocity_scale_ = sc.units.out(Dimension::velocity);
  auto open_output = [&](const std::string& name, auto truncate) {
    const fs::path p = dir / name;
    files.push_back(p.string());
    if (restarting) return truncate(p.string());  // true: continue (append)
    if (fs::exists(p)) log << "note: overwriting " << p.string() << " from a previous run\n";
    return false;
  };
  // The collectives of the time-independent data written from the parts: every rank's, or one.
  const OneProcess one;
  const Communicator& all_ranks = processes ? *processes : static_cast<const Communicator&>(one);
  // The topology of the trajectories (bonds, masses, molecule ids) as a LAMMPS data file, the one
  // format MDAnalysis, VMD and OVITO all read with bonds (README, "Outputs"); a restart keeps it.
  // Empty: no files (check, Python without an output directory); a decomposed run's rank 0 writes
  // them (all ranks the shared H5MD file).
  const bool writing = !out_dir.empty() && root_;
  const bool h5md_here = !out_dir.empty() && (root_ || shared_h5md_) && !sc.output.h5md.empty();
  const fs::path h5md_path = dir / sc.output.h5md;
  // Rank 0's files, and each rank's check of the directory it writes the shared H5MD file in,
  // are this rank's alone: their outcome is agreed before the H5MD file is opened, which every
  // rank of a shared file does together (a rank that failed alone would leave the others waiting
  // in MPI_File_open).
  const Communicator* ranks = processes && processes->size() > 1 ? processes : nullptr;
  bool h5md_exists = false;
  agree(ranks, [&] {
    if (h5md_here && !root_) check_rank_directory(out_dir, processes->rank());
    if (h5md_here && root_) h5md_exists = fs::exists(h5md_path);
    if (writing && (!sc.output.xyz.empty() || !sc.output.h5md.empty())) {
      const fs::path p = dir / kTopologyFile;
      if (!restarting && !parts)  // from the parts: below, every rank
        write_scene_lammps_data(sc, p.string(), topology_title(sc), false);
      files.push_back(p.string());
    }
    if (writing && !sc.output.xyz.empty()) {
      // Each type's symbol and mass: a row names its particle's type.
      std::vector<std::string> species;
      std::vector<double> masses;
      for (const ParticleType& t : sc.types) species.push_back(t.element), masses.push_back(t.mass);
      if (num_particles == 0) masses.clear();
      const bool append =
          open_output(sc.output.xyz, [&](const std::string& p) { return truncate_xyz_after(p, file_cut, file_tol); });
      xyz_ = std::make_unique<XyzWriter>((dir / sc.output.xyz).string(), std::move(species), sc.box,
                                         sc.output.xyz_velocities, append, std::move(masses));
      xyz_->set_units(time_out, velocity_scale_);
    }
    if (writing && !sc.output.thermo.empty()) {
      const bool append = open_output(sc.output.thermo, [&](const std::string& p) {
        return truncate_csv_after(p, file_cut, file_tol, table_.columns());
      });
      thermo_ = std::make_unique<CsvWriter>((dir / sc.output.thermo).string(), table_.columns(), append);
    }
    if (writing && !sc.output.state.empty()) {
      const auto scols = state_columns(s.size());  // 6N names: only when asked for (8 MB at N = 32 000)
      const bool append = open_output(
          sc.output.state, [&](const std::string& p) { return truncate_csv_after(p, file_cut, file_tol, scols); });
      state_ = std::make_unique<CsvWriter>((dir / sc.output.state).string(), scols, append);
      projected_ = std::make_unique<ProjectedMomenta>(*sc.forces->stiff_bonds(), s.inv_mass);
    }
  });
  const bool trajectories = !out_dir.empty() && (!sc.output.xyz.empty() || !sc.output.h5md.empty());
  if (parts && trajectories && !restarting)
    write_topology_parts(sc, parts->mine, parts->x, parts->v, num_particles, all_ranks, (dir / kTopologyFile).string(),
                         topology_title(sc));
  for (int c = 0; c < static_cast<int>(thermo.columns().size()); ++c)
    if (c != thermo.column("time") && c != thermo.column("step")) h5md_columns_.push_back(c);
  h5md_values_.resize(h5md_columns_.size());
  // The whole scene as one part (its time-independent H5MD data are written by rows alike), on the
  // processes that write them; from the parts, every rank takes part.
  std::optional<PartMolecules> whole;
  const bool h5md_parts = parts && !out_dir.empty() && !sc.output.h5md.empty();
  H5mdSetup setup;
  if (h5md_parts) {
    describe_h5md_static(sc, parts->mine, all_ranks, setup);
  } else if (h5md_here) {
    whole = whole_part(sc);
    describe_h5md_static(sc, *whole, one, setup);
  }
  if (h5md_parts && !shared_h5md_ && all_ranks.size() > 1) {  // whether rank 0 creates the file, on every rank
    std::int64_t seen = h5md_exists ? 1 : 0;
    all_ranks.broadcast(&seen, 1);
    h5md_exists = seen != 0;
  }
  if (h5md_here) {
    setup.num_particles = parts ? num_particles : s.size();
    setup.box = sc.box;
    setup.author = sc.output.author;
    setup.creator_version = STIFFMD_VERSION;
    setup.velocity = sc.output.h5md_velocity;
    setup.force = sc.output.h5md_force;
    setup.gzip = sc.output.h5md_gzip;
    // Observables on the frame grid: every thermo column but time and step.
    for (int c : h5md_columns_) setup.observables.push_back(table_.columns()[c]);
    const Units& u = sc.units;
    setup.length_unit = u.h5md_unit(Dimension::length);
    setup.time_unit = u.h5md_unit(Dimension::time);
    setup.velocity_unit = u.h5md_unit(Dimension::velocity);
    setup.force_unit = u.h5md_unit(Dimension::force);
    if (!u.reduced())
      for (int c : h5md_columns_)
        setup.observable_units.push_back(u.h5md_unit(thermo_column_dimension(thermo.columns()[c])));
    if (shared_h5md_) setup.processes = processes;
    h5md_writers_ = shared_h5md_ ? processes->size() : 1;
    const std::string path = h5md_path.string();
    files.push_back(path);
    // Whether the file is there, as rank 0 sees it: every rank of a shared file creates it or
    // appends to it alike.
    if (shared_h5md_) {
      std::int64_t seen = h5md_exists ? 1 : 0;
      processes->broadcast(&seen, 1);
      h5md_exists = seen != 0;
    }
    const bool append = restarting && h5md_exists;
    if (!restarting && h5md_exists) log << "note: overwriting " << path << " from a previous run\n";
    h5md_ = std::make_unique<H5mdWriter>(path, setup, append, s.step);
    if (!append && whole && root_) write_h5md_static_parts(h5md_.get(), setup, sc, *whole, one);
  }
  if (h5md_parts && !(restarting && h5md_exists))
    write_h5md_static_parts(root_ ? h5md_.get() : nullptr, setup, sc, parts->mine, all_ranks);
  if (writing) {
    checkpoint_path_ = (dir / sc.output.checkpoint).string();
    files.push_back(checkpoint_path_);
  }
  if (restarting) {
    xyz_due_.served_until(cut);
    thermo_due_.served_until(cut);
    state_due_.served_until(cut);
    h5md_due_.served_until(cut);
  }
  if (state_) state_row_.resize(1 + 6 * s.size());  // 6 N values: only with a state CSV
}

bool RunOutputs::due(double t, bool final) {
  // The thermo grid drives the samples (and so the [monitor] checks) even without a thermo file.
  thermo_now_ = thermo_due_.due(t) || final;
  const bool h5md = h5md_due_.due(t), xyz = xyz_due_.due(t), state = state_due_.due(t);
  h5md_now_ = h5md_ && (h5md || final);
  xyz_now_ = xyz_ && (xyz || final);
  state_now_ = state_ && (state || final);
  return thermo_now_ || h5md_now_;
}

void RunOutputs::write(const State& s, const std::vector<double>& row, const ProcessRows* mine, bool xyz_by_blocks) {
  // The row in the output's units (README "Units"), for the files and the terminal alike.
  if (root_ && (thermo_now_ || h5md_now_)) written_ = table_(row);
  if (thermo_now_ && thermo_) thermo_->write(written_);
  if (sc_.integrator.barostat.on) {  // the box of this frame (a barostat moves it)
    const Box& box = sc_.forces->box();
    if (h5md_) h5md_->set_box_lengths(box.lengths);
    if (xyz_) xyz_->set_box(box);
  }
  if (h5md_now_ && h5md_) write_h5md(s, mine);
  if (xyz_by_blocks)
    write_xyz_by_blocks(s, *mine);
  else if (xyz_now_)
    xyz_->write(s, sc_.particle_type.data());
  if (state_now_) write_state(s);
}

// Rank 0 writes the frame as it gets it: for each block of kBlock consecutive global indices, every
// rank's rows in it (its ids increase: one pass over them for the whole frame) in one gather. Rank
// 0 holds one block's rows, the other ranks theirs; a frame of N particles costs N / kBlock
// gathers.
void RunOutputs::write_xyz_by_blocks(const State& s, const ProcessRows& mine) {
  constexpr int kBlock = 1024;  // 57 kB of rows per gather
  const Communicator& comm = *processes_;
  const int n = num_particles_;  // the whole system's: the state s may hold none (a scene's description)
  const int record = 8;          // global index, type, x, v
  if (!mine.type && sc_.particle_type.size() != static_cast<std::size_t>(n))
    throw std::logic_error(
        "RunOutputs::write: the XYZ rows need their types (ProcessRows::type) when the scene "
        "does not hold the particles");
  if (root_) xyz_->begin_frame(n, s.t, s.step);
  std::vector<double> rows;
  std::vector<std::vector<double>> all;
  Eigen::Matrix3Xd x, v;
  std::vector<int> type;
  std::size_t k = 0;
  for (int first = 0; first < n; first += kBlock) {
    const int end = std::min(n, first + kBlock);
    rows.clear();
    for (; k < mine.ids.size() && mine.ids[k] < end; ++k) {
      const auto c = static_cast<Eigen::Index>(k);
      const int t = mine.type ? (*mine.type)[k] : sc_.particle_type[static_cast<std::size_t>(mine.ids[k])];
      rows.insert(rows.end(), {static_cast<double>(mine.ids[k]), static_cast<double>(t), mine.x(0, c), mine.x(1, c),
                               mine.x(2, c), mine.v(0, c), mine.v(1, c), mine.v(2, c)});
    }
    comm.gather(rows, all);
    if (!root_) continue;
    x.resize(3, end - first);
    v.resize(3, end - first);
    type.resize(static_cast<std::size_t>(end - first));
    for (const std::vector<double>& b : all)
      for (std::size_t at = 0; at + record <= b.size(); at += record) {
        const auto col = static_cast<Eigen::Index>(b[at]) - first;
        type[static_cast<std::size_t>(col)] = static_cast<int>(b[at + 1]);
        x.col(col) = Eigen::Vector3d(b[at + 2], b[at + 3], b[at + 4]);
        v.col(col) = Eigen::Vector3d(b[at + 5], b[at + 6], b[at + 7]);
      }
    xyz_->write_rows(end - first, x.data(), v.data(), type.data());
  }
}

// Rank 0's observables; the particles' rows from `mine` (a shared file), else the whole state s
// (rank 0; the other ranks of a shared file then write no rows).
void RunOutputs::write_h5md(const State& s, const ProcessRows* mine) {
  if (root_)
    for (size_t k = 0; k < h5md_columns_.size(); ++k) h5md_values_[k] = written_[h5md_columns_[k]];
  const bool whole = !mine && root_;
  static const Eigen::Matrix3Xd none(3, 0);
  const Eigen::Matrix3Xd& x = mine ? mine->x : whole ? s.x : none;
  const Eigen::Matrix3Xd* v = mine ? &mine->v : whole ? &s.v : &none;
  const Eigen::Matrix3Xd* f = &none;
  if (sc_.output.h5md_force) {
    if (mine) {
      f = mine->f;
    } else if (whole) {
      sc_.forces->total_force(s.x, h5md_force_);
      f = &h5md_force_;
    }
  }
  if (const double scale = sc_.units.h5md_scale(Dimension::velocity); scale != 1.0 && sc_.output.h5md_velocity) {
    h5md_velocity_ = *v * scale;
    v = &h5md_velocity_;
  }
  const std::vector<int>* ids = nullptr;  // one process: all rows
  if (shared_h5md_) {                     // every rank passes its rows (rank 0 all before the parts)
    if (whole && all_rows_.empty()) {
      all_rows_.resize(s.size());
      std::iota(all_rows_.begin(), all_rows_.end(), 0);
    }
    ids = mine ? &mine->ids : whole ? &all_rows_ : &no_rows_;
  }
  h5md_->write_frame(s.step, s.t * sc_.units.out(Dimension::time), x, v, f, h5md_values_, ids);
}

void RunOutputs::write_state(const State& s) {
  const Eigen::Matrix3Xd& pp = (*projected_)(s);
  // Time and momenta (mass × velocity) in the output's units.
  state_row_[0] = s.t * sc_.units.out(Dimension::time);
  for (int i = 0; i < s.size(); ++i)
    for (int a = 0; a < 3; ++a) {
      state_row_[1 + 3 * i + a] = s.x(a, i);
      state_row_[1 + 3 * s.size() + 3 * i + a] = pp(a, i) * velocity_scale_;
    }
  state_->write(state_row_);
}

void RunOutputs::close() {
  xyz_.reset();
  thermo_.reset();
  state_.reset();
  if (h5md_) h5md_->close();  // collective for a shared file: every rank closes here
  h5md_.reset();
}

void RunOutputs::write_final(std::vector<std::string>& files) {
  if (dir_.empty()) return;
  const fs::path dir(dir_);
  if (!sc_.output.lammps_data.empty()) {
    write_scene_lammps_data(sc_, (dir / sc_.output.lammps_data).string(),
                            "stiffmd " STIFFMD_VERSION " final state of " + sc_.deck_path);
    files.push_back((dir / sc_.output.lammps_data).string());
  }
  if (sc_.observables.histograms && !sc_.topology.bonds.empty()) {
    write_histograms((dir / "histograms.csv").string(), sc_.state.x, sc_.forces->box(), sc_.topology);
    files.push_back((dir / "histograms.csv").string());
  }
}

}  // namespace stiffmd
