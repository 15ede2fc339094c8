// The set of force terms of a scene, grouped by level, with one entry point that
// evaluates a set of levels (docs/design.md §11.2): forces(x, levels, out) -> energy.
#pragma once

#include <Eigen/Core>
#include <algorithm>
#include <cstdint>
#include <initializer_list>
#include <memory>
#include <optional>
#include <span>
#include <string>
#include <string_view>
#include <vector>

#include "core/box.hpp"
#include "forcefields/force_term.hpp"

namespace stiffmd {

class ForceField {
 public:
  ForceField() : ForceField(Box{}, 0) {}
  // The levels, innermost first (force_term.hpp): by default "fast" and "slow".
  ForceField(Box box, int num_particles, std::vector<std::string> level_names = {"fast", "slow"})
      : box_(box),
        num_particles_(num_particles),
        level_names_(std::move(level_names)),
        evaluations_(level_names_.size(), 0) {}

  void add(std::unique_ptr<ForceTerm> term);

  // ghost[i] = 1: particle i is a ghost, for every term (ForceTerm::set_ghosts).
  void set_ghosts(const std::vector<char>& ghost) {
    for (const auto& term : terms_) term->set_ghosts(ghost);
  }

  // out = Σ forces of the terms on the given levels (out is overwritten, not allocated when
  // already 3×N); returns their energy. Counts one evaluation per level.
  double compute(const Eigen::Matrix3Xd& x, std::span<const Level> levels, Eigen::Matrix3Xd& out);
  double compute(const Eigen::Matrix3Xd& x, std::initializer_list<Level> levels, Eigen::Matrix3Xd& out) {
    return compute(x, std::span<const Level>(levels.begin(), levels.size()), out);
  }

  // out = forces of every term that is not constraint-defining, on all levels: the force
  // of the constrained dynamics (RATTLE, effective), where the stiff bonds become g(x) = 0.
  // Counts as one evaluation of the outermost level.
  double compute_unconstrained(const Eigen::Matrix3Xd& x, Eigen::Matrix3Xd& out);

  // compute and compute_unconstrained without the energy (ForceTerm::add_forces_only): the same
  // out, bit for bit, counted the same. The integrators' steps use these; the energy is for the
  // minimiser and the thermo (energies_and_virial).
  void compute_forces(const Eigen::Matrix3Xd& x, std::span<const Level> levels, Eigen::Matrix3Xd& out);
  void compute_forces(const Eigen::Matrix3Xd& x, std::initializer_list<Level> levels, Eigen::Matrix3Xd& out) {
    compute_forces(x, std::span<const Level>(levels.begin(), levels.size()), out);
  }
  void compute_forces_unconstrained(const Eigen::Matrix3Xd& x, Eigen::Matrix3Xd& out);

  // Total force of every term at x, for output (not counted as an evaluation).
  void total_force(const Eigen::Matrix3Xd& x, Eigen::Matrix3Xd& out) const {
    out.setZero(3, x.cols());
    for (const ForceTerm* term : order_) term->add_forces(x, box_, out);
  }

  // Energy of one level at x (for observables; does not count as a force evaluation).
  double energy(const Eigen::Matrix3Xd& x, Level level) const;
  // The energy of every level (energy(x, level) for each, innermost first) and the virial Σ r·f
  // of every term, in one evaluation of each term (ForceTerm::energy_and_virial: a decomposed
  // run's part gives its share of both). For observables: not a force evaluation.
  void energies_and_virial(const Eigen::Matrix3Xd& x, std::vector<double>& level_energy, double& virial) const;
  // Of the last energies_and_virial (this process's shares): the Coulomb energy of the charged
  // terms (LAMMPS's ecoul: real-space pairs and 1-4 pairs, ForceTerm::Sums::coulomb), the van der
  // Waals energy (LAMMPS's evdwl: the pair terms' rest with their tail corrections, the 1-4
  // Lennard-Jones, Sums::vdwl) and the k-space terms' energy (elong).
  double last_coulomb_energy() const;
  double last_vdwl_energy() const;
  double last_kspace_energy() const;
  // Whether a term reads charges (the thermo's ecoul column) and whether one is a k-space term (elong).
  bool has_charges() const;
  bool has_kspace() const;

  const std::vector<std::unique_ptr<ForceTerm>>& terms() const { return terms_; }
  // The terms in the order their forces are summed (compute and the others below): those that
  // offer a fused step (the stiff harmonic bonds) first, then the others, each in the order added.
  // A fused step (FusedMicroStep: kick, drift and the bond forces in one pass, starting from
  // f = 0) followed by the other terms in this order then sums what compute sums, in the same
  // order: the same bits (MultipleTimeStepping).
  // Not by level: a deck's forces are the same bits whatever levels its terms are put on.
  // terms() keeps the order added (the deck's), which names columns and checkpoint sections.
  const std::vector<const ForceTerm*>& evaluation_order() const { return order_; }
  bool has_level(Level l) const;
  // The constraint-defining bonds, if a term has them (at most one term may).
  const StiffBonds* stiff_bonds() const;

  int num_levels() const { return static_cast<int>(level_names_.size()); }
  Level innermost() const { return Level{0}; }
  Level outermost() const { return Level{num_levels() - 1}; }
  const std::string& level_name(Level l) const { return level_names_[l.index]; }
  std::optional<Level> find_level(std::string_view name) const;
  // Every level, innermost first (for evaluating all of them through compute()).
  std::vector<Level> all_levels() const;

  std::int64_t evaluations(Level l) const { return evaluations_[l.index]; }
  // Counts one evaluation of each level done outside compute (the fused micro step).
  void count_evaluations(std::span<const Level> levels) {
    for (Level l : levels) ++evaluations_[l.index];
  }
  void reset_counters() { std::fill(evaluations_.begin(), evaluations_.end(), 0); }
  const Box& box() const { return box_; }
  // The box every later evaluation uses: a barostat's cell move (integrators/barostat.hpp). The
  // neighbour lists follow it without a rebuild while the move keeps them complete
  // (NeighborList::needs_rebuild).
  void set_box(const Box& box) { box_ = box; }
  int num_particles() const { return num_particles_; }

  // The same terms acting on a subset of the particles alone (ForceTerm::on_subset), in the same
  // order (terms() and evaluation_order()), on the same levels, in the box now; no evaluations
  // counted yet. A decomposed run's part is built so from the whole system's force field
  // (docs/parallel.md). Throws std::invalid_argument, naming the term, when a term cannot be.
  std::unique_ptr<ForceField> on_subset(const ParticleSubset& subset) const;

  // Term k replaced by `term` (same level, neither fused), in term k's place in the evaluation
  // order; returns the old one. A decomposed run's part wraps its pair terms so (docs/parallel.md).
  std::unique_ptr<ForceTerm> replace(size_t k, std::unique_ptr<ForceTerm> term);

 private:
  std::vector<std::unique_ptr<ForceTerm>> terms_;
  std::vector<const ForceTerm*> order_;  // evaluation_order()
  Box box_;
  int num_particles_ = 0;
  std::vector<std::string> level_names_;
  std::vector<std::int64_t> evaluations_;
  mutable Eigen::Matrix3Xd scratch_;
  mutable std::vector<ForceTerm::Sums> term_sums_;  // energies_and_virial
};

}  // namespace stiffmd
