// The force-term interface (docs/design.md §11.1–§11.3). A term knows its energy and forces and the
// level it is integrated on; it knows nothing about decks or integrators.
#pragma once

#include <Eigen/Core>
#include <cstdint>
#include <memory>
#include <span>
#include <stdexcept>
#include <string>
#include <string_view>
#include <vector>

#include "core/box.hpp"
#include "core/communicator.hpp"
#include "core/exact_sum.hpp"
#include "core/timing.hpp"
#include "core/topology.hpp"
#include "forcefields/parameter_record.hpp"
#include "forcefields/particle_subset.hpp"
#include "forcefields/stiff_bond.hpp"

namespace stiffmd {

// Time-scale levels of the splitting H = T + U + ε⁻²V (docs/design.md §1, §3): an index into the
// scene's levels, innermost (fastest) first, as LAMMPS numbers its r-RESPA levels. A scene
// without [[integrator.levels]] has two, "fast" (index 0, the micro steps) and "slow" (index 1,
// the macro-step kicks); Level::fast and Level::slow name those, and in the force-style
// registry they are a style's default role: the innermost level or the outermost one
// (engine/scene/scene.cpp resolves them for decks with named levels).
struct Level {
  int index = 0;
  static const Level fast;
  static const Level slow;
  friend constexpr bool operator==(Level, Level) = default;
};
inline constexpr Level Level::fast{0};
inline constexpr Level Level::slow{1};

// A capability of a fast term (docs/design.md §3): the innermost micro steps of multiple time
// stepping without a pass over the particles per operation. kick_drift_force does v += dt_kick M⁻¹f,
// x += dt v, and then replaces f by the term's force at the new x — the same bits as kick_drift,
// f = 0, add_forces (MultipleTimeStepping::run_innermost uses it when the term is first on the
// innermost level). kick_drift_forces does `steps` of them, the first kicking by first_kick, the
// others by dt_kick — the same bits as kick_drift_force `steps` times; the term may take them
// molecule by molecule (forcefields/bond_loop.hpp, MicroStepPlan), so only when it is alone on the
// innermost level.
class FusedMicroStep {
 public:
  void kick_drift_force(Eigen::Matrix3Xd& x, Eigen::Matrix3Xd& v, const Eigen::VectorXd& inv_mass, Eigen::Matrix3Xd& f,
                        double dt_kick, double dt) const {
    kick_drift_forces(x, v, inv_mass, f, dt_kick, dt_kick, dt, 1);
  }
  virtual void kick_drift_forces(Eigen::Matrix3Xd& x, Eigen::Matrix3Xd& v, const Eigen::VectorXd& inv_mass,
                                 Eigen::Matrix3Xd& f, double first_kick, double dt_kick, double dt,
                                 int steps) const = 0;

 protected:
  ~FusedMicroStep() = default;
};

class ForceTerm {
 public:
  ForceTerm(std::string name, Level level) : name_(std::move(name)), level_(level) {}
  virtual ~ForceTerm() = default;

  // Adds this term's force −∇E(x) into f (3×N) and returns its energy E(x).
  virtual double add_forces(const Eigen::Matrix3Xd& x, const Box& box, Eigen::Matrix3Xd& f) const = 0;

  // Adds the same force into f as add_forces, bit for bit, without the energy: what the
  // integrators' steps ask for (ForceField::compute_forces). A term whose energy costs extra work
  // per item (the pair terms: a sum per pair, every pair evaluated) overrides it; the default is
  // add_forces.
  virtual void add_forces_only(const Eigen::Matrix3Xd& x, const Box& box, Eigen::Matrix3Xd& f) const {
    add_forces(x, box, f);
  }

  // Σ over interacting pairs of r_ij · f_ij (the pair virial, for the pressure; design note:
  // computed only at output times, so it may repeat work add_forces does). Terms whose forces
  // are not pairwise (external fields) return 0.
  virtual double virial(const Eigen::Matrix3Xd& x, const Box& box) const {
    (void)x, (void)box;
    return 0.0;
  }

  // The energy and the virial as the thermo row wants them: this process's share of them in a
  // decomposed run (docs/parallel.md; a pair term counts a pair with a ghost half, so the
  // processes' shares add up to the whole system's), else the plain ones. `scratch` (3×N) takes
  // the forces add_forces computes on the way. Default: add_forces's energy and virial().
  struct Sums {
    double energy = 0.0, virial = 0.0;
    double coulomb = 0.0;  // the Coulomb part of energy (charged pair styles, 1-4 pairs: LAMMPS's ecoul)
    // The van der Waals part, LAMMPS's evdwl: a pair term's energy less its Coulomb part (its tail
    // correction included), the charmm dihedrals' 1-4 Lennard-Jones; 0 for the other terms.
    double vdwl = 0.0;
  };
  virtual Sums energy_and_virial(const Eigen::Matrix3Xd& x, const Box& box, Eigen::Matrix3Xd& scratch) const {
    const double energy = add_forces(x, box, scratch);
    return {energy, virial(x, box)};
  }

  // Adds this term's force into f, like add_forces, and its virial tensor's diagonal, Σ over
  // interacting pairs of (r_ij)_a (f_ij)_a, a = x, y, z, into w (exactly: ExactDiagonal), in the
  // same pass: the barostat's per-axis pressure (integrators/barostat.hpp). Pair terms give it; a
  // decomposed run's part its share (a pair with a ghost half). The default (bonded terms, whose
  // share of the molecular virial is zero, and external fields) adds the forces only.
  virtual void add_forces_and_virial_diagonal(const Eigen::Matrix3Xd& x, const Box& box, Eigen::Matrix3Xd& f,
                                              ExactDiagonal& w) const {
    (void)w;
    add_forces(x, box, f);
  }

  // Capabilities (docs/design.md §11.1: facts on the term, not lists of style names elsewhere).
  // Whether the term finds its pairs through a neighbour list (pair styles).
  virtual bool uses_neighbor_list() const { return false; }
  // Whether its forces sum to zero (internal forces: bonds, angles, pairs). External fields
  // (gravity, tethers, walls) do not conserve total momentum, so the thermo's degrees of
  // freedom keep the centre-of-mass motion.
  virtual bool conserves_momentum() const { return true; }
  // The phase of the step loop's timing its evaluation counts to (core/timing.hpp): pair terms
  // the pair phase, the reciprocal sums their own, the rest bonded.
  virtual Phase phase() const { return uses_neighbor_list() ? Phase::pair : Phase::bonded; }
  // Whether it reads the particles' charges (the Coulomb styles): a scene with charges and no
  // such term is refused, since its charges would act on nothing.
  virtual bool uses_charges() const { return false; }
  // Whether it defines the constraint manifold g(x) = 0 (stiff bonds: see stiff_bonds()).
  bool is_constraint_defining() const { return stiff_bonds() != nullptr; }

  // The same term acting on other particles: `types` per particle, the scene's `bonds` among them
  // (special pairs), the box (neighbour-list terms: a decomposed run's part, docs/parallel.md,
  // re-targets them on its owned particles and ghosts); null for terms that cannot.
  virtual std::unique_ptr<ForceTerm> on_particles(std::vector<int> types, const std::vector<Bond>& bonds,
                                                  const Box& box) const {
    (void)types, (void)bonds, (void)box;
    return nullptr;
  }
  // The same term on a subset of the system's particles alone, in the subset's numbering
  // (particle_subset.hpp), evaluated in `box`, with this term's parameters: a bonded term its
  // bonds (angles, dihedrals) among them, in its order; a pair term the pairs among them; an
  // external field or tether those of its particles in the subset (possibly none). On whole
  // molecules it gives each of their particles, bit for bit, what this term gives it from within
  // its molecule and from outside fields: a decomposed run's part is built so (docs/parallel.md).
  // Throws std::invalid_argument for a term that cannot (the default: a term must say how) or for
  // an item the subset holds only in part.
  virtual std::unique_ptr<ForceTerm> on_subset(const ParticleSubset& subset, const Box& box) const {
    (void)subset, (void)box;
    throw std::invalid_argument("force term '" + name_ + "' (" + std::string(style()) +
                                ") cannot be built on a subset of the particles");
  }
  // The largest pair distance it acts over and its list's skin (pair terms; 0 for the others):
  // what a decomposed run's pair sets must cover (engine/domain/decomposition.hpp).
  virtual double pair_cutoff() const { return 0.0; }
  virtual double pair_skin() const { return 0.0; }
  // Neighbour-list rebuilds so far (pair terms; 0 for the others).
  virtual long neighbor_list_rebuilds() const { return 0; }
  // The pairs in its neighbour list as last built (pair terms; 0 for the others): what an
  // evaluation goes through.
  virtual std::int64_t listed_pairs() const { return 0; }

  // ghost[i] = 1: particle i is a ghost, a copy of another domain's particle whose force the
  // caller ignores, while the forces on the others must stay complete. A term may then skip what
  // acts on ghosts alone (a pair term: the pairs of two ghosts, NeighborList::set_ghosts). Empty:
  // no ghosts. Default: nothing to skip.
  virtual void set_ghosts(const std::vector<char>& ghost) { (void)ghost; }

  // The deck's style name and a one-line description of the instance (for `stiffmd check`).
  virtual std::string_view style() const = 0;
  virtual std::string describe() const = 0;

  // What defines the term, for the scene fingerprint of checkpoints (engine/run/checkpoint.hpp):
  // every parameter and every list its forces depend on — each coefficient of each type or type
  // pair as used (after mixing), cutoffs, weights, the bonds, angles, dihedrals or particles it
  // acts on — written exactly into `record`; no run-time counters. A checkpoint is refused by a
  // scene whose terms differ in any of it.
  virtual void define(ParameterRecord& record) const = 0;

  // State the term carries from one evaluation to the next that its forces depend on (a pair
  // term's neighbour list: which pairs, in which order, with which periodic images), for
  // checkpoints: after load_state(save_state()) on a term of the same scene, every later
  // evaluation is bit-identical to the saved term's. Default: none. load_state throws
  // std::invalid_argument for words it cannot take.
  virtual std::vector<double> save_state() const { return {}; }
  virtual void load_state(std::span<const double> words) {
    if (!words.empty())
      throw std::invalid_argument("force term '" + name_ + "' carries no state, the checkpoint has some");
  }

  // A term whose evaluation sums over every particle of the system (the Ewald and PPPM reciprocal
  // sums, forcefields/kspace/) is told the processes of a decomposed run: its part on a rank then
  // sums over the ranks, so every rank evaluates it at the same points (a collective). Null: one
  // process. Default: a term that needs only its own particles, which ignores them.
  virtual void set_processes(const Communicator* processes) { (void)processes; }
  // Drops buffers the term makes again at its next evaluation, with the same results (PPPM's whole
  // mesh: a decomposed run's whole-system terms once the parts have taken over). Default: none.
  virtual void release_buffers() const {}

  // Constraint-defining terms (stiff bonds) expose their bonds to the constraint toolbox.
  virtual const StiffBonds* stiff_bonds() const { return nullptr; }
  // The fused micro step, for terms that offer it (stiff harmonic bonds); null: the plain path.
  virtual const FusedMicroStep* fused_micro_step() const { return nullptr; }

  const std::string& name() const { return name_; }
  Level level() const { return level_; }

 private:
  std::string name_;
  Level level_;
};

}  // namespace stiffmd
