// The real-space half of an Ewald sum, as a pair term of the coul/long family offers it
// (forcefields/coulomb_potentials.hpp: coul/long, lj/cut/coul/long, lj/charmm/coul/long) to the
// k-space term that completes it (forcefields/kspace/: EwaldSum, PPPM). The k-space term chooses
// the splitting parameter g from the term's Coulomb cutoff and its accuracy (choose_ewald,
// choose_pppm) and hands it over with set_ewald_splitting, after the pair term is read and before
// any evaluation; a term whose splitting was never set throws std::invalid_argument at its first
// evaluation (a deck without such a k-space term is refused at load: engine/scene/).
//
// The pair term's Coulomb energy of a pair at r < cutoff is then
//   qqrd2e q_i q_j [erfc(g r) − (1 − w_coul)] / r,
// w_coul its special_coul weight (1 for an ordinary pair, 0 for an excluded one): the pairs that
// special bonds exclude or scale are evaluated for the share of their full Coulomb energy the
// reciprocal sum counts and special bonds remove (LAMMPS pair_style coul/long).
#pragma once

namespace stiffmd {

class EwaldRealSpace {
 public:
  virtual ~EwaldRealSpace() = default;
  // The Coulomb cutoff r_c (length), one for every type pair.
  virtual double coulomb_cutoff() const = 0;
  // g (inverse length), finite and > 0; throws std::invalid_argument otherwise. Copies of the
  // term made afterwards (on_subset, on_particles: a decomposed run's parts) carry it.
  virtual void set_ewald_splitting(double g) = 0;
  // g as set; NaN until then.
  virtual double ewald_splitting() const = 0;

 protected:
  EwaldRealSpace() = default;
  EwaldRealSpace(const EwaldRealSpace&) = default;
  EwaldRealSpace& operator=(const EwaldRealSpace&) = default;
};

}  // namespace stiffmd
