// Energy minimisation by FIRE 2.0 (Guénolé et al., Comput. Mater. Sci. 175, 109584 (2020),
// Algorithm 2; the variant and defaults of LAMMPS's `min_style fire`) or by a line-search method,
// Polak–Ribière conjugate gradient or steepest descent with LAMMPS's quadratic line search
// (`min_style cg` / `sd`, `min_modify line quadratic`), all with LAMMPS's stopping rules `minimize
// etol ftol maxiter maxeval`. Rigid bonds stay exact: the force is projected onto the tangent
// space of the constraint manifold and the positions are SHAKEn after every move, as GROMACS does
// (docs/design.md §12). The deck side ([minimize], errors at its file:line) is
// engine/scene/scene_sources.cpp.
#pragma once

#include <functional>
#include <ostream>
#include <string>
#include <vector>

#include "core/communicator.hpp"
#include "core/state.hpp"
#include "forcefields/force_field.hpp"
#include "forcefields/stiff_bond.hpp"

namespace stiffmd {

enum class MinimizeStyle { fire, cg, sd };
const char* style_name(MinimizeStyle style);  // "fire", "cg", "sd": the deck's words

struct MinimizeSettings {
  MinimizeStyle style = MinimizeStyle::fire;
  // Stopping rules, as LAMMPS's `minimize etol ftol maxiter maxeval` (0 switches etol or ftol off):
  //   etol: |E_k − E_{k−1}| < etol · ½ (|E_k| + |E_{k−1}| + 1e-8)  (LAMMPS's relative change, EPS_ENERGY = 1e-8)
  //   ftol: ‖F‖₂ = (Σ_i |F_i|²)^{1/2} < ftol over the whole system's force vector (LAMMPS's default
  //         min_modify norm two), F the true force (not the soft start's cap): projected under
  //         rigid bonds, and zero at fixed particles
  double etol = 0.0;
  double ftol = 1e-6;  // a force
  long maxiter = 10000;
  long maxeval = 100000;
  // FIRE 2.0 (LAMMPS min_style fire defaults, its names): the initial step dt, the bounds
  // tmax·dt and tmin·dt on the adapted step, the steps after an uphill move before dt may grow,
  // the growth and shrink factors, the mixing α and its decay, and the half step back on an
  // uphill move (the "inertia correction"); the scheme is semi-implicit Euler.
  double dt = 0.0;  // engine time units; must be > 0
  // No coordinate of any particle moves further in one step (LAMMPS min_modify dmax; for cg and
  // sd the largest step the line search tries, capped at α = 1 as LAMMPS's ALPHA_MAX).
  double dmax = 0.1;
  double tmax = 10.0, tmin = 0.02;
  long delaystep = 20;
  double dtgrow = 1.1, dtshrink = 0.5, alpha0 = 0.25, alphashrink = 0.99;
  bool halfstepback = true;
  // Soft start: each particle's force magnitude capped at this during the moves (0: no cap), so
  // that overlapping beads move apart by dmax per step instead of by what r⁻¹³ asks. The
  // stopping rules read the true force. For cg and sd the capped force is the search direction
  // (steepest descent while any particle's force exceeds the cap), and the line search measures
  // the true energy and slope along it.
  double max_force = 0.0;
  // Hold the constraint-defining stiff bonds rigid (a method with rigid_constraints): minimise
  // the other terms on g(x) = 0. Otherwise every term, the stiff springs included, is minimised.
  bool rigid = false;
  double shake_tolerance = 1e-10;  // max |g| after each move
};

struct MinimizeReport {
  MinimizeStyle style = MinimizeStyle::fire;
  // "etol", "ftol", "maxiter", "maxeval"; FIRE's "vdfmax" (over 2000 steps with F·v ≤ 0, as
  // LAMMPS); a line search's failure, as LAMMPS's stop strings: "zero-alpha" (backtracked until the
  // expected decrease is below round-off, 1e-8, without enough decrease: "linesearch alpha is
  // zero"), "zero-quadratic" (the slope along the direction or its change below 1e-28: "quadratic
  // factors are zero"), "zero-force" (the search direction is zero: "forces are zero").
  std::string stopped_by;
  long iterations = 0;
  long evaluations = 0;  // force evaluations, the first one included
  double initial_energy = 0.0, energy = 0.0;
  double fmax = 0.0;           // the largest |F_i| at the end
  double fnorm = 0.0;          // ‖F‖₂ at the end
  bool rigid = false;          // minimised on g = 0
  double max_violation = 0.0;  // max |g| at the end (rigid bonds; 0 otherwise)
};

// Called after every move with the new positions and their energy (for tests and progress): every
// FIRE step, every accepted line search (the trial points of a line search are not reported; each is
// SHAKEn to the same tolerance, or NumericalError is thrown).
using MinimizeObserver = std::function<void(const Eigen::Matrix3Xd& x, double energy)>;

// How FIRE adds its sums over the particles (P = F·v, |F|², |v|², ‖f‖₂², the energy): `exact`,
// each sum's terms scaled by one power of two fixed by the whole system's largest components and
// added as integers (as SignedExactSum, core/exact_sum.hpp), the same bits for any order of the
// terms and any partition of the particles over ranks (docs/design.md §12); `plain`, each rank's
// floating-point sum added over the ranks: not the same bits on another number of ranks — for
// tests that show the exact sums are needed, never a run's.
enum class SumRule { exact, plain };

// A system held by parts on several ranks, as FIRE sees it (a decomposed run's parts:
// DomainIntegrator::minimize, engine/domain/part_minimize.cpp). Each rank moves its own
// particles with the forces of its part, and the global numbers (the sums and maxima over the
// particles, the energy from each rank's share) are added over the ranks.
class MinimizeParts {
 public:
  virtual ~MinimizeParts() = default;
  virtual const Communicator& ranks() const = 0;
  // This rank's part: its force field (whose pair terms give this rank's share of the energy,
  // ForceTerm::energy_and_virial), its stiff bonds (null: none) and its particles' state (x, v,
  // inv_mass). Valid until redistribute returns true.
  virtual ForceField& forces() = 0;
  virtual const StiffBonds* stiff() = 0;
  virtual State& state() = 0;
  // After each move, on every rank (collective): particles may move to other ranks, taking their
  // columns of `carried` (3 × owned particles, in the owned order) with them. True when this
  // rank's part is a new one (forces(), stiff(), state() and the columns then its new part's).
  virtual bool redistribute(const std::vector<Eigen::Matrix3Xd*>& carried) = 0;
};

// The forces of every term at x into f (3 × particles; without the constraint-defining stiff bonds
// when `unconstrained`: compute_unconstrained's terms), each term's forces the bits of
// ForceField::compute's, and this part's share of the potential energy: the pair terms' by
// ForceTerm::energy_and_virial (a part's share, so that the parts' shares add up to the whole
// system's energy), the others' as they add their forces. On one process the whole energy, to
// round-off. No evaluation is counted. `scratch`: 3 × particles, overwritten.
double part_energy_share(ForceField& forces, const Eigen::Matrix3Xd& x, Eigen::Matrix3Xd& f, Eigen::Matrix3Xd& scratch,
                         bool unconstrained);

// p.style's method: minimize_fire or minimize_linesearch.
MinimizeReport minimize(ForceField& forces, const StiffBonds* stiff, State& s, const MinimizeSettings& p,
                        std::ostream* progress = nullptr, const MinimizeObserver& after_move = {});

// Minimises the potential energy of `s` in place. The velocities s.v are not FIRE's: they are
// kept (projected onto the tangent space at the minimum under rigid bonds), as a LAMMPS
// `minimize` leaves a run's velocities to the deck. `stiff` may be null when !p.rigid.
// Throws NumericalError when SHAKE does not converge or the energy is not finite.
// Its global sums are exact (SumRule::exact): the same bits as FIRE on the parts below.
MinimizeReport minimize_fire(ForceField& forces, const StiffBonds* stiff, State& s, const MinimizeSettings& p,
                             std::ostream* progress = nullptr, const MinimizeObserver& after_move = {});

// The same FIRE on a system held by parts (collective: every rank calls it with the same p). For
// the same system, each particle's position at every move, the iterations, the force
// evaluations, the stop and the forces' norms are the bits of minimize_fire on one process, on
// any number of ranks and for any partition (with SumRule::exact): each particle's force is the
// same bits when the part's forces are (a decomposed run's: docs/parallel.md), and every sum
// FIRE takes over the particles is exact. The energy is each rank's share (in floating point, the
// part's terms in their order) added exactly over the ranks: one process's energy to round-off,
// and its bits on one rank; so is a stop by etol, which compares two energies. `after_move` sees
// this rank's positions (state().x) and the system's energy; `progress` should be given on one
// rank. Under p.rigid every move is projected and SHAKEn per constraint cluster, which lies in
// one part. The returned report is the same on every rank.
MinimizeReport minimize_fire(MinimizeParts& parts, const MinimizeSettings& p, std::ostream* progress = nullptr,
                             const MinimizeObserver& after_move = {}, SumRule rule = SumRule::exact);

// Conjugate gradient (p.style cg: Polak–Ribière with β = max(0, ·), restarted every 3N − m
// iterations and whenever the direction is not downhill) or steepest descent (sd), each iteration
// one quadratic line search from x along h as LAMMPS's MinLineSearch::linemin_quadratic. Positions
// move as x + αh, not by the masses: under rigid bonds the projection and SHAKE use the unit
// metric (fixed particles still 0), and h is re-projected onto the tangent space at each new x
// (docs/design.md §12). Velocities and errors as minimize_fire. Every sum over the system (the
// slopes f·h, F·F, F·g, g·g, ‖f‖²) is exact (SumRule::exact), so that the same line searches on
// parts below give these bits.
MinimizeReport minimize_linesearch(ForceField& forces, const StiffBonds* stiff, State& s, const MinimizeSettings& p,
                                   std::ostream* progress = nullptr, const MinimizeObserver& after_move = {});

// The same CG or SD on a system held by parts (collective), as minimize_fire on parts: the
// positions at every trial point, the iterations, evaluations, stop and force norms are the bits
// of minimize_linesearch on one process, on any number of ranks and for any partition; the
// energies the ranks' shares added exactly (one process's to round-off). Between iterations the
// molecules migrate with g, h and the forces.
MinimizeReport minimize_linesearch(MinimizeParts& parts, const MinimizeSettings& p, std::ostream* progress = nullptr,
                                   const MinimizeObserver& after_move = {}, SumRule rule = SumRule::exact);

// p.style's method on parts: minimize_fire or minimize_linesearch.
MinimizeReport minimize(MinimizeParts& parts, const MinimizeSettings& p, std::ostream* progress = nullptr,
                        const MinimizeObserver& after_move = {}, SumRule rule = SumRule::exact);

// "minimize: FIRE stopped by ftol after N iterations (M force evaluations): E0 -> E, largest
// force |f|max = …, force 2-norm …[, max |g| = …]" (CG or SD for the line-search styles; max |g|
// under rigid bonds).
std::string describe(const MinimizeReport& r);

}  // namespace stiffmd
