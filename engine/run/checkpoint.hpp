// Checkpoints: the complete dynamical state of a run, so that a restart continues it bit for bit
// — positions, velocities, step and time; the integrator's own state (cached kick forces, the
// constraint force, the effective dynamics' actions: Integrator::save_state); every force term's
// state (a pair term's neighbour list: ForceTerm::save_state); the observers' state (E(0), which
// warnings were given, the monitor's reference sample); and the run's statistics for the summary.
//
// Format (version 8), in the byte order and double format of the writing machine. Version 3:
// RATTLE-based methods under Langevin keep, in the constraint force's slot, the velocities their
// constraint force is formed from (integrators/rattle.cpp); a version-2 file would be read with
// the wrong meaning there, so it is refused. Version 4: the scene fingerprint is the exact
// parameter record of forcefields/parameter_record.hpp (every coefficient bit for bit, the
// dihedrals); a version-3 file of the same scene would be taken for another scene, so it is
// refused as of an older stiffmd. Version 5: the integrator's state holds the thermostat's heat
// (Integrator::thermostat_heat; the Langevin force's part of the kick force), the thermo's the
// conserved energy's reference, the run statistics its max error: a version-4 file lacks them.
// Version 6: the stage of a staged protocol that wrote it (engine/run/stages.hpp: number and name;
// 0 and "" for a run without stages) and the box as of the checkpoint (origin, lengths: a barostat
// moves it), after the run statistics; a version-5 file has neither and reads as a run without
// stages in the deck's box. Version 7: the scene fingerprint combines by blocks (scene_fingerprint:
// the same value from the whole scene and from any partition into parts); the layout is version
// 6's, and a version-5 or 6 file is checked against the sequential fingerprint of those versions
// (scene_fingerprint_sequential), so that it still restarts. Version 8: each force term enters the
// fingerprint by the definition of its description (the term made on no particle) and its rule
// (type claim, stiff-bond rule, selection, 1-4 table), not by its lists, which the particles and
// items already summed make by that rule: a decomposed run whose terms are descriptions alone
// (docs/parallel.md, "What is not distributed yet") gives the whole scene's value. The layout is
// version 7's, and a version-7 file is checked against the fingerprint of that version
// (scene_fingerprint_v7).
//   bytes  0–7   magic "STFMDCKP"
//          8–11  crc32 (zlib) of bytes 12 … end       — checked before anything else is read
//         12–15  format version (u32)
//         16–19  byte-order mark 0x01020304 (u32)
//         20–23  sizeof(double) = 8 (u32)
//         24–31  length of the file in bytes (u64)
//         32–39  scene fingerprint (u64: scene_fingerprint; scene_fingerprint_v7 in version 7,
//                scene_fingerprint_sequential before)
//         40–    particle count, step (i64), t, h (f64), method (u64 length + bytes), stage number
//                (i64) and name (u64 length + bytes; version 6), then blocks
//                of doubles (u64 count + values): x, v, inverse masses, integrator, thermo,
//                monitor, run statistics, box (6), then a u64 count of force terms and one block each.
// Written atomically — to a temporary file, fsync, rename — so a checkpoint on disk is whole.
// A decomposed run's processes write it together (docs/parallel.md, "Outputs"): each its block of
// particles (engine/io/particle_blocks.hpp) of every per-particle array at the array's offset,
// which N and the lengths of the method's and stage's names fix; rank 0 the rest; the crc32 is
// combined from the pieces' (zlib crc32_combine) in file order. The bytes are one process's.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include <Eigen/Core>

#include "core/box.hpp"
#include "core/communicator.hpp"
#include "core/state.hpp"
#include "engine/io/particle_blocks.hpp"
#include "integrators/integrator.hpp"

namespace stiffmd {

struct Scene;
struct PartMolecules;

inline constexpr std::uint32_t kCheckpointVersion = 8;
// The first version whose fingerprint combines by blocks (scene_fingerprint_v7); an older file's is
// scene_fingerprint_sequential's.
inline constexpr std::uint32_t kFirstFingerprintByBlocks = 7;
// The first version whose fingerprint records the terms by their descriptions (scene_fingerprint).
inline constexpr std::uint32_t kFirstFingerprintByDescriptions = 8;
// The oldest version read (as a run without stages, in the deck's box).
inline constexpr std::uint32_t kOldestCheckpointVersion = 5;

struct Checkpoint {
  State state;         // x, v, inverse masses, t, step
  std::string method;  // integrator that wrote it
  double h = 0.0;
  // The stage of a staged protocol it was written in (StageIdentity: number 1.., name); 0 and ""
  // for a run without stages.
  int stage = 0;
  std::string stage_name;
  std::uint32_t version = kCheckpointVersion;  // the format version it was read as (read_checkpoint)
  std::uint64_t scene_fingerprint = 0;
  std::vector<double> integrator_state;                // Integrator::save_state()
  std::vector<std::vector<double>> force_term_states;  // ForceTerm::save_state(), in the field's order
  std::vector<double> thermo_state;                    // Thermo::save_state(): E(0), warnings given
  std::vector<double> monitor_state;                   // Monitor::save_state()
  std::vector<double>
      run_state;         // for the summary: max |E − E(0)|, slow and fast evaluations, rebuilds, initial actions
  Box box;               // the box at the checkpoint (origin and lengths; ForceField::box)
  bool has_box = false;  // version 6 on: a version-5 file leaves the deck's box
};

// What defines the scene, exactly (a ParameterRecord, forcefields/parameter_record.hpp): particle
// count, inverse masses, particle types, topology (bonds, angles, dihedrals, molecules), box,
// levels, units, and every force term's name, style, level and what defines it (each of its
// coefficients bit for bit, and the rule that makes its lists) — but not the integrator, run or
// output settings, which a restart may change with --set, nor run-time counters such as
// neighbour-list rebuilds.
//
// Version 7 on, the fingerprint combines by blocks: the description (types, box, levels, units,
// particle and item counts, every term's record) hashed in sequence, and per particle (its
// global index, inverse mass, type, charge, molecule id) and per topology item (its kind, place in
// the whole list, particles and type) a 64-bit hash, summed mod 2⁶⁴ — so that the value is the
// same from the whole scene and from any partition of it into parts (scene_fingerprint_parts).
// Version 8 on, a term's record is the ForceTerm::define of its description (ForceTerm::on_subset
// on a subset of no particle: its coefficients, no list) and its rule (a bonded term's claim on
// the topology's types, the stiff bonds' rule, an external term's selection, a charmm-dihedral's
// 1-4 table); its lists are functions of that rule and of the particles and items the sums hold.
// So the value is the same from a scene whose terms are descriptions alone. A term that has no
// rule (made from its lists alone) or cannot be made on a subset is recorded by its own
// ForceTerm::define, lists and all.
std::uint64_t scene_fingerprint(const Scene& scene);

// The same value as scene_fingerprint of the whole scene, from this rank's `part` of its particles
// and items (any partition of the whole scene's molecules into the ranks' parts) and the scene's
// description (`description`: its types, box, levels, units and force terms, whole or their
// descriptions alone; none of its per-particle arrays or topology items are read). Collective
// over `ranks`.
std::uint64_t scene_fingerprint_parts(const Scene& description, const PartMolecules& part, const Communicator& ranks);

// The fingerprint of format version 7: by blocks, each term by its own ForceTerm::define, lists
// and all. What a version-7 checkpoint holds, checked so when it is read.
std::uint64_t scene_fingerprint_v7(const Scene& scene);

// The fingerprint of format versions 5 and 6 (FNV-1a of the whole scene in sequence, ParameterRecord):
// what a checkpoint written before version 7 holds, checked so when it is read.
std::uint64_t scene_fingerprint_sequential(const Scene& scene);

// Writes `state` and everything of `rest` but rest.state. Throws InputError naming the path on
// any I/O failure.
void write_checkpoint(const std::string& path, const State& state, const Checkpoint& rest);
inline void write_checkpoint(const std::string& path, const Checkpoint& c) {
  write_checkpoint(path, c.state, c);
}

// A process's part of a checkpoint of a decomposed run: its block of the num_particles particles,
// their x, v (3 × count each, column-major), inverse masses (count) and the integrator's carried
// columns (3 × count each, CarriedState::columns' order), and the whole integrator's words as
// runs (Integrator::save_state: the same on every process). With `owned`, x, v, inv_mass and the
// columns are instead this process's own particles (any set, each on exactly one process), in the
// order of their global indices `owned`: the writer brings them to the blocks itself, by rounds of
// `round` rows of every block (BlockExchange; the same on every process), and writes each round's
// rows as they arrive, so that a process holds one round's rows of its block and their messages,
// not the block. The file's bytes are the same whatever the round.
inline constexpr std::int64_t kCheckpointRound = 1 << 12;
struct CheckpointBlock {
  std::int64_t num_particles = 0;
  ParticleBlock block;
  const double* x = nullptr;
  const double* v = nullptr;
  const double* inv_mass = nullptr;
  std::vector<const double*> columns;
  const std::vector<WordRun>* integrator = nullptr;
  const std::vector<int>* owned = nullptr;
  std::int64_t round = kCheckpointRound;
};

// The same file written by every process, each its block: `rest`'s step, time, method, h and
// stage on every process, the rest (integrator_state and rest.state's arrays aside: `mine` has
// them) on rank 0. Collective: an I/O failure on any process throws AgreedInputError (naming the
// path) on every process, or InputError with one process.
void write_checkpoint(const std::string& path, const Communicator& processes, const CheckpointBlock& mine,
                      const Checkpoint& rest);

// Throws InputError with one line naming the path and what is wrong: missing, not a checkpoint,
// damaged (checksum), truncated, of another byte order, or of another format version.
Checkpoint read_checkpoint(const std::string& path);

// read_checkpoint, then checked to be of this scene: of its stage (a staged protocol's stage
// number and name, or none: check_checkpoint_stage), particle count, masses, fingerprint, one
// state per force term. Nothing of the scene changes. Throws InputError naming the path.
Checkpoint read_checkpoint_of(const Scene& scene, const std::string& path);
// InputError with one line when the checkpoint is of a staged protocol's stage and the scene of
// none, of none and the scene a stage's, or of another stage (number or name).
void check_checkpoint_stage(const Scene& scene, const Checkpoint& c, const std::string& path);

// Whether the checkpoint's step is the scene's run.steps, or its time run.t_end or later: its run
// is complete (a staged protocol continues with the next stage from it).
bool checkpoint_at_end(const Scene& scene, const Checkpoint& c);

// read_checkpoint_of, then checked to be before the scene's end (run.steps, run.t_end) and
// loaded: the force terms' states into the scene (nothing else of the scene changes). Throws
// InputError naming the path.
Checkpoint read_checkpoint_for(Scene& scene, const std::string& path);

// The format version of the checkpoint at `path` (bytes 12–15 after a stiffmd magic), 0 when it
// cannot be read or is not a checkpoint: whether a restart can read it by parts (format 8 on:
// the fingerprint by descriptions, which scene_fingerprint_parts gives). Reads 16 bytes.
std::uint32_t checkpoint_format_version(const std::string& path);

// read_checkpoint_for's checks and loads of what is not the state, for a checkpoint `c` already
// read (whole or by parts): its stage, one state per force term, before the scene's end
// (run.steps, run.t_end); then the box and the force terms' states into the scene. Throws
// InputError naming the path.
void load_checkpoint_rest(Scene& scene, const Checkpoint& c, const std::string& path);

// A checkpoint read by parts (docs/parallel.md, "A restart by parts"): every rank reads the
// header, the prefix (particle count, step, t, h, method, stage) and every block that is not per
// particle — the integrator's words but its carried columns, the thermo, monitor and run
// statistics, the box, the force terms' states — and, on demand, the rows of the particles it is
// given of x, v, the inverse masses and the integrator's carried columns, each contiguous run of
// global indices by one pread: never the whole file. The crc32 of bytes 12 … end is computed by
// blocks, each rank its byte range (block_of), and combined on rank 0 (zlib crc32_combine).
//
// `layout`: the integrator's words as runs (DomainIntegrator::word_layout: word runs by their
// length, carried columns by index), as the integrator of the scene lays them out; the file's
// integrator block must be those words with each column 3 N words long. The words but the columns
// become rest().integrator_state, what an integrator of no particle loads (Integrator::load_state).
// `method`: the deck's; a checkpoint of another method has its words skipped (rest().integrator_state
// and columns() empty: the restart starts that method afresh, as the whole path does).
//
// Collective: every failure — missing, not a checkpoint, of format before 8, truncated, damaged
// (crc32), malformed, a layout that does not fit — throws AgreedInputError on every rank with one
// line naming the path (read_checkpoint's wording).
class CheckpointParts {
 public:
  CheckpointParts(const std::string& path, const Communicator& ranks, const std::vector<WordRun>& layout,
                  const std::string& method);
  ~CheckpointParts();
  CheckpointParts(const CheckpointParts&) = delete;
  CheckpointParts& operator=(const CheckpointParts&) = delete;

  // Everything but the per-particle arrays: state.step and state.t (state's arrays empty), the
  // method, h, the stage, the fingerprint, the integrator's words without its columns, the other
  // blocks.
  const Checkpoint& rest() const { return rest_; }
  std::int64_t num_particles() const { return n_; }
  // The rows of the particles `ids` (global indices, any order) of x, v and the inverse masses.
  // Collective (a failed read is agreed).
  void particles(const std::vector<int>& ids, Eigen::Matrix3Xd& x, Eigen::Matrix3Xd& v,
                 Eigen::VectorXd& inv_mass) const;
  // The rows of `ids` of each carried column (the layout's column indices), 3 × ids.size() each.
  // Collective.
  std::vector<Eigen::Matrix3Xd> columns(const std::vector<int>& ids) const;
  // The bytes this rank has read of the file so far: its rows and the blocks but the checksum's
  // (crc_bytes_read), a measure of what a rank holds.
  std::uint64_t bytes_read() const { return bytes_read_; }
  // The bytes this rank read to compute its share of the crc32: its byte range of the file.
  std::uint64_t crc_bytes_read() const { return crc_bytes_read_; }

 private:
  void rows(std::uint64_t first_word, int per_particle, const std::vector<int>& ids, double* out) const;
  std::string path_;
  const Communicator& ranks_;
  int fd_ = -1;
  std::int64_t n_ = 0;
  Checkpoint rest_;
  std::uint64_t x_ = 0, v_ = 0, inv_mass_ = 0;  // offsets of the first value of each block
  std::vector<std::uint64_t> column_;           // offset of each carried column's first value
  mutable std::uint64_t bytes_read_ = 0;
  std::uint64_t crc_bytes_read_ = 0;
};

}  // namespace stiffmd
