// The kick forces of the impulse family's levels slower than the innermost (docs/design.md §3;
// Lubich & Weiss §2.2–2.3), one strategy per level (Stage::kick: the method's, or the level's own):
//   projected impulse:  K(x) = P(x) f(x)                       (the projected kick)
//   mollified impulse:  K(x) = α′(x)ᵀ f(α(x))                   (projection mollifier, eq. ProMol)
//   impulse:            K(x) = f(x)                            (PlainKick, multiple_time_stepping.hpp)
// P(x) removes the M-orthogonal (bond-normal) part of the slow force, which is what pumps
// energy into the bond vibrations and destroys the actions' adiabatic invariance under the
// plain impulse method when the level's step does not resolve the stiff period.
#pragma once

#include "core/parallel.hpp"
#include "integrators/constraints.hpp"
#include "integrators/multiple_time_stepping.hpp"

namespace stiffmd {

// to = from, in particle blocks on the threads (same size after the first call: no allocation in
// the step loop).
inline void copy_forces(const Eigen::Matrix3Xd& from, Eigen::Matrix3Xd& to) {
  to.resize(3, from.cols());
  parallel_blocks(from.cols(), threads_for(from.cols()),
                  [&](std::int64_t b, std::int64_t e) { to.middleCols(b, e - b) = from.middleCols(b, e - b); });
}

// Σ x · (f − k) over the particles: the virial of the part f − k of a force a kick leaves out, in
// particle blocks added in block order (parallel_sum).
inline double removed_virial_of(const Eigen::Matrix3Xd& x, const Eigen::Matrix3Xd& f, const Eigen::Matrix3Xd& k) {
  return parallel_sum(x.cols(), threads_for(x.cols()), [&](std::int64_t b, std::int64_t e) {
    return (x.middleCols(b, e - b).array() * (f.middleCols(b, e - b) - k.middleCols(b, e - b)).array()).sum();
  });
}

class ProjectedKick final : public KickForce {
 public:
  explicit ProjectedKick(ConstraintToolbox toolbox) : toolbox_(std::move(toolbox)) {}
  void evaluate(const Eigen::Matrix3Xd& x, ForceField& forces, const std::vector<Level>& levels,
                Eigen::Matrix3Xd& out) override {
    forces.compute_forces(x, levels, out);
    copy_forces(out, raw_);
    toolbox_.project_force(x, out);
    removed_virial_ = removed_virial_of(x, raw_, out);
  }
  double removed_virial() const override { return removed_virial_; }

 private:
  ConstraintToolbox toolbox_;
  Eigen::Matrix3Xd raw_;  // f(x) before the projection, scratch
  double removed_virial_ = 0.0;
};

class MollifiedKick final : public KickForce {
 public:
  MollifiedKick(ConstraintToolbox toolbox, int num_particles)
      : toolbox_(std::move(toolbox)), X_(3, num_particles), f_at_X_(3, num_particles) {}
  void evaluate(const Eigen::Matrix3Xd& x, ForceField& forces, const std::vector<Level>& levels,
                Eigen::Matrix3Xd& out) override {
    toolbox_.mollified_force(
        x,
        [&](const Eigen::Matrix3Xd& X, Eigen::Matrix3Xd& f) {
          forces.compute_forces(X, levels, f);
          copy_forces(f, f_at_X_);
        },
        X_, out);
    // The part of f(α(x)) the mollifier leaves out, f(α) − α′(x)ᵀf(α): the bond-normal part, as
    // the projected kick's f − P(x)f (α′(x) = P(x) on the manifold). It sums to zero over each
    // cluster (α commutes with translations), so its virial Σ x·(…) does not depend on which
    // periodic image a molecule is in. The stiff system's bonds carry it as tension: it belongs
    // in the pressure (MultipleTimeStepping::constraint_virial).
    removed_virial_ = removed_virial_of(x, f_at_X_, out);
  }
  double removed_virial() const override { return removed_virial_; }

 private:
  ConstraintToolbox toolbox_;
  Eigen::Matrix3Xd X_;       // α(x), scratch
  Eigen::Matrix3Xd f_at_X_;  // f(α(x)) before α′(x)ᵀ, scratch
  double removed_virial_ = 0.0;
};

}  // namespace stiffmd
