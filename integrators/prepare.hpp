// [prepare]: an initial state made ready for a stiff run — projected onto the constraint
// manifold, relaxed off a builder's overlaps with rigid bonds, given thermal bond vibrations —
// on one process or on a system held by parts (each rank its molecules). And the rigid methods'
// projection of their initial data (paper eq. ACIV), which RATTLE makes at a fresh start.
// The deck side (reading the table, errors at its file:line) is engine/scene/scene_sources.cpp.
#pragma once

#include <cstdint>
#include <ostream>
#include <span>
#include <string>
#include <vector>

#include "core/communicator.hpp"
#include "core/state.hpp"
#include "forcefields/force_field.hpp"
#include "forcefields/stiff_bond.hpp"
#include "integrators/constraints.hpp"

namespace stiffmd {

struct PrepareSettings {
  bool project = true;   // positions onto g = 0 (SHAKE), velocities onto the tangent space
  long relax_steps = 0;  // capped steepest descent on the non-stiff terms, rigid bonds
  double relax_max_displacement = 0.02;
  double vibrational_temperature = 0.0;  // thermal bond vibrations
  std::uint64_t seed = 1;
  // The vibrations' normals keyed by bond and by particle (global indices, counter-based: the
  // same on any number of ranks and for any partition), not one stream over the bonds and one
  // over the particles in order; what a preparation by parts needs.
  bool by_particle = false;
};

// The system a preparation acts on: the whole of it on one process, or this rank's part of it
// (whole molecules, so every stiff bond's two particles). Every call on parts is collective.
class PrepareParts {
 public:
  virtual ~PrepareParts() = default;
  virtual const Communicator* ranks() const = 0;  // null: one process
  virtual State& state() = 0;
  virtual const StiffBonds& stiff() = 0;
  // The global index of each of state()'s particles.
  virtual std::span<const int> global_ids() = 0;
  // f = the non-stiff terms' forces at state().x (3 × particles); returns their potential energy
  // (the whole system's, summed over the ranks) when `energy`, else NaN where it costs a pass.
  virtual double forces(Eigen::Matrix3Xd& f, bool energy) = 0;
  // After each relaxation move (collective): molecules may move to other ranks, taking their
  // columns of `carried` along. True when this rank's part is a new one.
  virtual bool redistribute(const std::vector<Eigen::Matrix3Xd*>& carried) = 0;
  // A message about this part in the whole system's numbers (its particles', as one process
  // names them).
  virtual std::string in_whole_numbers(const std::string& what) const { return what; }
};

// Applies the settings to `s` in the order project, relax, vibrate, and returns what it did as
// one line ("prepare: projected …; relaxed …; bond vibrations …"; empty if nothing was asked).
// `forces` gives the non-stiff terms for the relaxation (compute_unconstrained). Throws
// NumericalError when SHAKE does not converge, InputError for stiff bonds the toolbox refuses.
// `progress` (null: silent) gets a line as each stage starts and, while relaxing, the energy and
// the largest force about every tenth of the steps: a large system's preparation takes a while.
std::string prepare_state(ForceField& forces, const StiffBonds& stiff, State& s, const PrepareSettings& p,
                          std::ostream* progress = nullptr);

// The same on a system held by parts (collective; p.by_particle or nothing to vibrate when there
// is more than one rank). The positions and velocities are prepare_state's on one process bit for
// bit, on any number of ranks, when the part's forces are (a decomposed run's) — every step is per
// particle or per constraint cluster, and the relaxation's largest move is a max over the ranks;
// the note's energies are summed over the ranks (one process's to round-off). A SHAKE that fails
// on one rank throws AgreedInputError on every rank (NumericalError's message, its rank named).
std::string prepare_state(PrepareParts& parts, const PrepareSettings& p, std::ostream* progress = nullptr);

// The rigid methods' start (paper eq. ACIV): X0 = x0 + M⁻¹G(x0)ᵀλ with g(X0) = 0 (SHAKE), then
// Y0 = P(X0) y0. The largest |g| before and after and the largest coordinate changes of x and v:
// this part's, made the system's by one max over the ranks (max_over).
struct InitialProjection {
  double g_before = 0.0, g_after = 0.0, dx = 0.0, dv = 0.0;
  void max_over(const Communicator& ranks);
};
InitialProjection project_initial_data(ConstraintToolbox& toolbox, State& s);
// "METHOD: initial data projected onto the constraint manifold (paper eq. ACIV): max |g| … -> …,
// max |dx| = …, max |dv| = …"
std::string describe(const std::string& method, const InitialProjection& p);

}  // namespace stiffmd
