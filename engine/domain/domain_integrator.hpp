// A run on several ranks that own whole molecules (docs/parallel.md), as one Integrator of the
// whole system: the Run drives it as it drives any method, and it steps this rank's part.
//
// The part is a Scene of its own particles (the integrator never sees a ghost) with the deck's
// force terms built on it and the deck's method on those: every per-molecule solve (SHAKE/RATTLE,
// the tridiagonal G M⁻¹ Gᵀ, Fixman's log-det, the effective dynamics' modes) is the one-process
// code on whole molecules. Its pair terms act on owned particles and ghosts (GhostedPairs). The
// only communication inside a step is the halo before a pair term is evaluated (once per macro
// step when pairs are slow); after each step one reduction of two numbers (the largest over beads
// of the displacement since the ghosts were selected plus 2 |v| h, the first non-finite particle).
// When a bead may have moved margin/2 by the end of the next step, the molecules are
// redistributed by their anchors and the ghosts selected again, before that step; a part whose
// molecules changed is built afresh and takes over what the old one carried for the particles
// (Integrator::carried_state: cached kick forces move with their particles) and the effective
// dynamics' actions (Integrator::invariants).
//
// Until the first step, and for what the Run asks about the whole system before it (prepare,
// the first sample), the whole-system integrator answers, the same on every rank.
#pragma once

#include <functional>
#include <memory>
#include <vector>

#include "core/communicator.hpp"
#include "engine/domain/decomposition.hpp"
#include "engine/domain/ghosted_pairs.hpp"
#include "engine/domain/part_molecules.hpp"
#include "engine/io/particle_blocks.hpp"
#include "engine/observe/observables.hpp"
#include "engine/scene/scene.hpp"
#include "integrators/integrator.hpp"
#include "integrators/minimize.hpp"
#include "integrators/prepare.hpp"

namespace stiffmd {

// Throws InputError, naming the key, when [parallel] grid has another number of domains than ranks.
void check_parallel_grid(const Scene& scene, int ranks);
// Throws InputError, naming the key, for an output that a run on several ranks does not write:
// the state CSV (output.state), whose rows hold every particle (docs/parallel.md, "Outputs").
void check_parallel_outputs(const Scene& scene, int ranks);

// What a checkpoint written by every rank takes of a rank (engine/run/checkpoint.hpp
// CheckpointBlock), without the state gathered anywhere and without a copy of it: its block of
// particles (engine/io/particle_blocks.hpp), and either the block's x, v, inverse masses (before
// the parts: the whole state's columns, `owned` null) or its own particles' (the part's state and
// the integrator's carried columns, in the order of the global indices `owned`, which the writer
// brings to the blocks), and the whole integrator's words as runs. x, v, inv_mass point into the
// state given to state_block or the part's, current until the next step.
struct StateBlock {
  ParticleBlock block;
  const double* x = nullptr;
  const double* v = nullptr;
  const double* inv_mass = nullptr;
  const std::vector<int>* owned = nullptr;
  std::vector<Eigen::Matrix3Xd> columns;  // CarriedState::columns, of the owned particles
  std::vector<WordRun> words;             // save_state() of the whole system, columns by index
};

class DomainIntegrator final : public Integrator {
 public:
  // `whole`: the integrator of the whole system (built on whole.forces), used until the first
  // step and for checkpoints; whole.forces, on a part's particles, its force terms
  // (ForceField::on_subset). Both must outlive this.
  DomainIntegrator(Scene& whole, const Communicator& comm, std::unique_ptr<Integrator> whole_method);
  ~DomainIntegrator() override;

  void prepare(State& s, std::ostream& log) override { whole_->prepare(s, log); }
  void step(State& s, double h) override;
  void reset() override;
  std::string_view method() const override { return whole_->method(); }
  double model_potential(const Eigen::Matrix3Xd& x) override;
  double constraint_virial(const State& s) override;
  double kinetic_energy_estimate(const State& s) const override;
  double thermostat_heat() const override;  // the ranks' heats added (collective)
  std::vector<double> invariants() const override { return whole_->invariants(); }
  void set_invariants(const std::vector<double>& w) override { whole_->set_invariants(w); }
  // The whole-system integrator's words (on rank 0; collective): a checkpoint that restarts on any
  // number of ranks, and on one as the same run.
  std::vector<double> save_state() const override;
  void load_state(const std::vector<double>& w) override { whole_->load_state(w); }
  // This rank's block of the state `whole` (current on every rank before the first step), or its
  // part's state and carried columns, and the words save_state() would give as runs (collective).
  StateBlock state_block(const State& whole) const;

  // Rank 0's whole.x, whole.v become the system's current state (collective; nothing before the
  // first step: the whole state is then current on every rank).
  void gather(State& whole) const;
  // The parts built from the whole state s (the same on every rank) now, rather than at the first
  // step (collective; nothing once built): the Run does it before its step loop, which then times
  // steps only.
  void distribute(const State& s) {
    if (!part_) start(s);
  }
  // The same from this rank's `molecules` (any partition of whole molecules, each rank its own,
  // with their x, v) rather than from the whole state (s: its step and time; what the whole
  // integrator carries, by global index). Collective; nothing once built.
  void distribute(PartMolecules molecules, Eigen::Matrix3Xd x, Eigen::Matrix3Xd v, const State& s) {
    if (!part_) start_parts(std::move(molecules), std::move(x), std::move(v), s);
  }
  // The rows of the integrator's carried columns (CarriedState::columns, each 3 × ids.size()) of
  // the particles `ids` (global indices): a restart by parts reads them from its checkpoint
  // (CheckpointParts::columns). Collective: called on every rank at the same point.
  using CarriedRows = std::function<std::vector<Eigen::Matrix3Xd>(const std::vector<int>& ids)>;
  // The same for a restart of a scene of descriptions (no particle) by parts: the whole-system
  // integrator has loaded the checkpoint's words but its columns (it holds no particle), and each
  // part takes its owned particles' rows of the columns from `carried`, once the molecules are at
  // their owners — what the whole path's start hands each part from the whole columns.
  void distribute(PartMolecules molecules, Eigen::Matrix3Xd x, Eigen::Matrix3Xd v, const State& s,
                  const CarriedRows& carried) {
    if (!part_) start_parts(std::move(molecules), std::move(x), std::move(v), s, true, &carried);
  }
  // The whole-system integrator's words as runs (save_state: word runs, and each carried column by
  // index), as a checkpoint lays them out: what a reader by parts needs to find the columns
  // (CheckpointParts). The words of the runs are the integrator's now. Before the start.
  std::vector<WordRun> word_layout() const;
  bool distributed() const { return part_ != nullptr; }
  // [minimize] on the parts, once distributed (engine/domain/part_minimize.cpp; collective, every
  // rank with the same p): FIRE, CG or SD moves each rank's particles with its part's forces, its
  // sums added exactly over the ranks, molecules migrating as in a run. The positions are those
  // minimize gives on one process for the same state, bit for bit, on any number of ranks
  // (integrators/minimize.hpp); the report is the same on every rank. `progress`: rank 0's
  // stream (null elsewhere).
  MinimizeReport minimize(const MinimizeSettings& p, std::ostream* progress = nullptr,
                          const MinimizeObserver& after_move = {}, SumRule rule = SumRule::exact);
  // [prepare] on the parts, once distributed (engine/domain/part_prepare.cpp; collective, every
  // rank with the same p, p.by_particle when it thermalises the bonds): prepare_state on each
  // rank's molecules, one process's positions and velocities bit for bit on any number of ranks;
  // the note (its energies summed over the ranks) is the same on every rank. `progress`: rank 0's
  // stream (null elsewhere). Then, as after minimize, nothing is carried and start_again follows.
  std::string prepare_parts(const PrepareSettings& p, std::ostream* progress = nullptr);
  // A rigid method's initial projection (paper eq. ACIV, project_initial_data) on the parts, once
  // distributed (collective): what the whole-system integrator's prepare does to the whole state,
  // with its log line, the maxima taken over the ranks. Not for the effective dynamics, whose
  // actions are the whole system's.
  std::string project_parts();
  // The description's overlap rules (Scene::overlap_rules) applied to the parts, once distributed
  // (engine/domain/part_overlaps.hpp; collective): the first term's finding, "file:line:
  // forces.NAME: …" as the whole load says it, or "" when no two particles overlap.
  std::string overlaps(const Scene& description) const;
  // The parts started afresh from the molecules they hold now (collective, once distributed): a
  // new decomposition — its grid from their anchors, each molecule sent to its anchor's domain,
  // the pair sets selected and listed, the counters at zero — and new parts' integrators, with
  // nothing carried (as after reset()). After minimize, the run then goes on from the state a
  // start from the minimised system gives: the whole path's, whose [minimize] came before its start.
  void start_again();
  // Force evaluations per level and neighbour-list rebuilds of this rank's parts so far.
  std::vector<std::int64_t> evaluations() const;
  long neighbor_rebuilds() const;
  DomainReport report() const;  // collective

  // This rank's particles, once distributed: their global indices (increasing), their state, and
  // their total forces at the current positions (collective: the pair terms' halo).
  const std::vector<int>& owned_ids() const { return domains_->owned_ids(); }
  const State& owned_state() const;
  // This rank's part (its particles, their types and charges, its topology and force terms), once
  // distributed.
  const Scene& part_scene() const;
  // The molecules this rank owns, with what they carry (the part is built from them), once
  // distributed: in the order of owned_ids().
  const PartMolecules& owned_molecules() const { return molecules_; }
  void owned_forces(Eigen::Matrix3Xd& f) const;
  // Whether the thermo row can be summed by parts (sample_sums): once distributed, when every
  // molecule of the topology (its molecule ids: Rg, end-to-end) lies within one bonded molecule,
  // which a rank owns whole.
  bool samples_by_parts() const { return part_ && molecules_whole_; }
  // The thermo row's sums of the whole system: each rank's part's (its share of the pair terms),
  // added up over the ranks. Collective; the same on every rank.
  ThermoSums sample_sums() const;

  // The whole system's numbers, summed from the parts at the start: csvr's degrees of freedom,
  // whether every topology molecule (its molecule id) lies within one bonded molecule, and the
  // effective dynamics' modes per constraint cluster of the whole system (find_clusters,
  // integrators/clusters.hpp, in the order the modes take): its molecule (named by its first
  // global index: Decomposition::owned_molecule), first mode and mode count.
  struct Cluster {
    int molecule, first, modes;
  };
  int whole_degrees_of_freedom() const { return whole_dof_; }
  // The whole system's particle count, summed from the parts at the start (before it: the whole
  // scene's): what the Run, its outputs and the checkpoint count once the whole scene need not
  // hold the particles.
  int whole_particles() const { return part_ ? whole_n_ : whole_scene_.state.size(); }
  bool molecules_whole() const { return molecules_whole_; }
  // The thermo row's numbers of the whole system (Thermo's columns), summed from the parts at the
  // start: the temperature's degrees of freedom (those above) and whether some topology molecule has
  // an rg, some an end-to-end size (each part's Thermo counts its own molecules: the whole system's
  // when every molecule lies within one bonded molecule, molecules_whole).
  const ThermoNumbers& thermo_numbers() const { return thermo_numbers_; }
  const std::vector<Cluster>& clusters() const { return clusters_; }

 private:
  struct Part;
  void start(const State& s);
  // carry: the parts take over what the whole-system integrator carries (a first start).
  // carried: the rows of the columns read for the owned particles (a restart by parts).
  void start_parts(PartMolecules molecules, Eigen::Matrix3Xd x, Eigen::Matrix3Xd v, const State& s, bool carry = true,
                   const CarriedRows* carried = nullptr);
  std::unique_ptr<Decomposition> make_domains() const;
  // `extra`: per-particle columns that move with the molecules besides the integrator's.
  void reselect(bool box_moved, const std::vector<Eigen::Matrix3Xd*>& extra = {});
  Scene& mutable_part_scene();  // the part's scene (minimize moves its particles)
  // A message of this rank's part named in the whole system's numbers: its particles' (as one
  // process names them), its stiff bonds' none (a part numbers its bonds in its own order).
  std::string in_whole_numbers(const std::string& what) const;
  // at_start: the first part, built by every rank (the whole system's numbers summed then).
  void build_part(Eigen::Matrix3Xd x, Eigen::Matrix3Xd v, const State& s, bool at_start);
  void whole_numbers(const Scene& part);
  std::vector<double> part_invariants() const;

  Scene& whole_scene_;
  const Communicator& comm_;
  std::unique_ptr<Integrator> whole_;
  std::unique_ptr<Decomposition> domains_;
  std::unique_ptr<Part> part_;
  PartMolecules molecules_;             // what the part is built from: its molecules' particles and items
  IntegratorSettings settings_;         // the whole system's, less its per-particle arrays
  bool per_particle_friction_ = false;  // the thermostat has a friction per particle
  bool reselect_ = false;               // the pair sets were selected again: molecules may migrate before the next step
  bool box_moved_ = false;              // a barostat moved the cell: the pair sets follow before the next step
  int whole_dof_ = 0;                   // csvr: the whole system's degrees of freedom
  int whole_n_ = 0;                     // the whole system's particles, summed from the parts
  bool molecules_whole_ = true;         // every topology molecule within one bonded molecule
  bool charged_ = false;                // some particle of the whole system has a charge (at the start)
  bool rigid_method_ = false;           // the method holds the stiff bonds rigid
  bool effective_modes_ = false;        // the effective dynamics, with stiff bonds: clusters_
  bool terms_conserve_momentum_ = true;  // every force term of the deck does
  std::vector<Cluster> clusters_;
  ThermoNumbers thermo_numbers_;
  std::vector<std::int64_t> evaluations_;  // of the parts before the current one
  long rebuilds_ = 0;
};

}  // namespace stiffmd
