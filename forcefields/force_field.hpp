// The set of force terms of a scene, grouped by level, with one entry point that
// evaluates a set of levels (style.md §2): forces(x, levels, out) -> energy.
#pragma once

#include <Eigen/Core>
#include <array>
#include <cstdint>
#include <initializer_list>
#include <memory>
#include <span>
#include <vector>

#include "engine/core/box.hpp"
#include "forcefields/force_term.hpp"

namespace stiffmd {

class ForceField {
 public:
  ForceField() = default;
  ForceField(Box box, int num_particles) : box_(box), num_particles_(num_particles) {}

  void add(std::unique_ptr<ForceTerm> term) { terms_.push_back(std::move(term)); }

  // out = Σ forces of the terms on the given levels (out is overwritten, not allocated when
  // already 3×N); returns their energy. Counts one evaluation per level.
  double compute(const Eigen::Matrix3Xd& x, std::span<const Level> levels, Eigen::Matrix3Xd& out);
  double compute(const Eigen::Matrix3Xd& x, std::initializer_list<Level> levels, Eigen::Matrix3Xd& out) {
    return compute(x, std::span<const Level>(levels.begin(), levels.size()), out);
  }

  // out = forces of every term that is not constraint-defining, on all levels: the force
  // of the constrained dynamics (RATTLE, effective), where the stiff bonds become g(x) = 0.
  // Counts as one slow evaluation.
  double compute_unconstrained(const Eigen::Matrix3Xd& x, Eigen::Matrix3Xd& out);

  // Total force of every term at x, for output (not counted as an evaluation).
  void total_force(const Eigen::Matrix3Xd& x, Eigen::Matrix3Xd& out) const {
    out.setZero(3, x.cols());
    for (const auto& term : terms_) term->add_forces(x, box_, out);
  }

  // Energy of one level at x (for observables; does not count as a force evaluation).
  double energy(const Eigen::Matrix3Xd& x, Level level) const;

  const std::vector<std::unique_ptr<ForceTerm>>& terms() const { return terms_; }
  bool has_level(Level l) const;
  // The constraint-defining bonds, if a term has them (at most one term may).
  const StiffBonds* stiff_bonds() const;

  std::int64_t evaluations(Level l) const { return evaluations_[static_cast<int>(l)]; }
  void reset_counters() { evaluations_.fill(0); }
  const Box& box() const { return box_; }
  int num_particles() const { return num_particles_; }

 private:
  std::vector<std::unique_ptr<ForceTerm>> terms_;
  Box box_;
  int num_particles_ = 0;
  std::array<std::int64_t, kNumLevels> evaluations_{};
  mutable Eigen::Matrix3Xd scratch_;
};

}  // namespace stiffmd
