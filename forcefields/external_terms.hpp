// External (one-body) potentials: the particle feels a fixed object, not another particle, so the
// energy is not translation invariant, Σ f ≠ 0, and the pair virial of force_term.hpp does not
// apply: virial() returns 0 (the ForceTerm default), as for Gravity.
//
//   HarmonicTether: E = Σ_{i ∈ particles} ½ k |x_i − c|²  (x_i − c by minimum image on periodic
//                   axes). LAMMPS's fix spring/self has the same ½ K per atom, each atom tied to its
//                   own initial position rather than to a common point c.
//   LJ93Wall:       a flat wall at x_axis = position acting on particles on its `side`
//                   (+1: x_axis > position, −1: x_axis < position), at distance
//                   r = side·(x_axis − position):
//                     E(r) = ε [ (2/15)(σ/r)⁹ − (σ/r)³ ] − E_LJ93(r_c)   for r < r_c, 0 beyond,
//                   as LAMMPS's fix wall/lj93 (same ε, σ, cutoff; shifted so E(r_c) = 0). The
//                   potential is the 12-6 LJ integrated over a half space of wall atoms; its
//                   minimum is at r = (2/5)^{1/6} σ ≈ 0.858 σ, so r_c = (2/5)^{1/6} σ gives a purely
//                   repulsive wall. A particle on the wrong side or on the wall (r ≤ 0) has no
//                   finite energy: NumericalError naming it.
#pragma once

#include <Eigen/Core>
#include <string>
#include <vector>

#include "forcefields/force_term.hpp"
#include "forcefields/particle_selection.hpp"

namespace stiffmd {

class HarmonicTether final : public ForceTerm, public SelectionRule {
 public:
  bool conserves_momentum() const override { return false; }  // an external field
  // Validating constructor: particles non-empty, each index ≥ 0 and listed once; center finite;
  // k finite and ≥ 0 (energy/length²).
  // allow_empty: a term on a particle subset (on_subset), which may hold none of the particles.
  HarmonicTether(std::string name, Level level, std::vector<int> particles, Eigen::Vector3d center, double k,
                 bool allow_empty = false);

  double add_forces(const Eigen::Matrix3Xd& x, const Box& box, Eigen::Matrix3Xd& f) const override;
  // On the subset's particles among this term's (possibly none): with a selection
  // (SelectionRule), those it selects among the subset's, never this term's list; without, this
  // term's list cut to the subset.
  std::unique_ptr<ForceTerm> on_subset(const ParticleSubset& subset, const Box& box) const override;
  std::string_view style() const override { return "harmonic-tether"; }
  std::string describe() const override;
  void define(ParameterRecord& record) const override;  // every parameter and particle

 private:
  std::vector<int> particles_;
  Eigen::Vector3d center_;
  double k_;
};

struct LJ93WallParams {
  int axis = 2;           // 0, 1, 2 for x, y, z; must not be periodic in the box
  double position = 0.0;  // wall coordinate along axis (length)
  int side = +1;          // +1: acts on particles above the wall, −1: below
  double epsilon = 1.0;   // ≥ 0 (energy)
  double sigma = 1.0;     // > 0 (length)
  double cutoff = 2.5;    // r_c > 0 (length)
};

class LJ93Wall final : public ForceTerm, public SelectionRule {
 public:
  bool conserves_momentum() const override { return false; }  // an external field
  // Validating constructor: axis in {0, 1, 2}, side ±1, position finite, epsilon finite and ≥ 0,
  // sigma and cutoff finite and > 0; particles non-empty, each index ≥ 0 and listed once.
  LJ93Wall(std::string name, Level level, LJ93WallParams params, std::vector<int> particles, bool allow_empty = false);

  // Throws std::invalid_argument if the box is periodic along the wall's axis (a wall there has no
  // meaning), NumericalError if a particle is not strictly on the wall's side.
  double add_forces(const Eigen::Matrix3Xd& x, const Box& box, Eigen::Matrix3Xd& f) const override;
  // On the subset's particles among this term's (possibly none): with a selection
  // (SelectionRule), those it selects among the subset's, never this term's list; without, this
  // term's list cut to the subset.
  std::unique_ptr<ForceTerm> on_subset(const ParticleSubset& subset, const Box& box) const override;
  std::string_view style() const override { return "lj93-wall"; }
  std::string describe() const override;
  void define(ParameterRecord& record) const override;  // every parameter and particle

 private:
  LJ93WallParams p_;
  std::vector<int> particles_;
  double shift_;  // E_LJ93(r_c), subtracted so that E(r_c) = 0
};

}  // namespace stiffmd
