#include "integrators/prepare.hpp"

#include <cmath>
#include <sstream>
#include <vector>

#include "core/portable_random.hpp"
#include "integrators/constraints.hpp"

namespace stiffmd {

// project = true: positions onto the constraint manifold g = 0 (SHAKE, M-orthogonal) and
// velocities onto its tangent space; vibrational_temperature = T: then give every stiff bond
// thermal vibrational energy — bond-length deviations g_b ~ N(0, T ε²/α_b²) (the stiff potential
// ½ε⁻²α_b² g_b² is diagonal in g) and normal velocities u − P u with u thermal at T (so that
// ġ = G u ~ N(0, T S): equipartition in the bonds' normal modes, linearised).
std::string prepare_state(ForceField& forces, const StiffBonds& stiff, State& s, const PrepareSettings& p,
                          std::ostream* progress) {
  std::ostringstream note;
  note.precision(4);
  auto say = [&](auto&&... what) {
    if (!progress) return;
    const auto old = progress->precision(4);
    ((*progress) << ... << what) << std::endl;  // flushed: it is progress
    progress->precision(old);
  };
  ConstraintToolbox toolbox(stiff.bonds, s.inv_mass);
  const double g0 = toolbox.max_violation(s.x);
  if (p.project) {
    say("prepare: projecting ", s.size(), " particles onto ", stiff.bonds.size(), " stiff bonds (max |g| = ", g0,
        ") ...");
    toolbox.shake(s.x, s.x, nullptr, 1e-12, 200);
    toolbox.project_velocity(s.x, s.v);
    note << "prepare: projected onto the constraint manifold (max |g| " << g0 << " -> " << toolbox.max_violation(s.x)
         << ") and the velocities onto its tangent space";
  }
  if (p.relax_steps > 0) {
    // Overlaps left by a builder: steepest descent on every non-stiff term, each step moving
    // no particle more than max_move, then SHAKE back onto the bonds (g = 0).
    Eigen::Matrix3Xd f, x_old;
    const double e_before = forces.compute_unconstrained(s.x, f);
    double e = e_before;
    const long report_every = (p.relax_steps + 9) / 10;
    say("prepare: relaxing ", p.relax_steps, " steps of at most ", p.relax_max_displacement,
        " (non-stiff potential energy ", e, ", max |F| ", f.colwise().norm().maxCoeff(), ") ...");
    for (long k = 0; k < p.relax_steps; ++k) {
      Eigen::Matrix3Xd step = f * s.inv_mass.asDiagonal();
      const double largest = step.colwise().norm().maxCoeff();
      if (largest == 0.0) break;
      x_old = s.x;
      s.x += (p.relax_max_displacement / largest) * step;
      toolbox.shake(x_old, s.x, nullptr, 1e-10, 200);
      e = forces.compute_unconstrained(s.x, f);
      if ((k + 1) % report_every == 0 || k + 1 == p.relax_steps)
        say("prepare: relax step ", k + 1, "/", p.relax_steps, ": non-stiff potential energy ", e, ", max |F| ",
            f.colwise().norm().maxCoeff());
    }
    toolbox.project_velocity(s.x, s.v);  // the velocities stay, tangent at the new positions
    note << (p.project ? "; " : "prepare: ") << "relaxed " << p.relax_steps << " steps: non-stiff potential energy "
         << e_before << " -> " << e;
  }
  const double tv = p.vibrational_temperature;
  if (tv > 0) {
    say("prepare: thermalising the vibrations of ", stiff.bonds.size(), " stiff bonds at T = ", tv, " ...");
    // Target bond lengths ℓ_b + g_b, reached by SHAKE along M⁻¹Gᵀ with the shifted lengths.
    // The unit normals are one component of a Maxwell–Boltzmann draw at T = 1 for unit masses
    // (the builders' portable generator); its exact rescaling and zero-mean correction are
    // O(1/m) departures from independent N(0, 1), harmless for thermalising many bonds.
    const Eigen::Matrix3Xd normal =
        maxwell_boltzmann(Eigen::VectorXd::Ones(static_cast<Eigen::Index>(stiff.bonds.size())), 1.0, p.seed + 1);
    std::vector<StiffBond> shifted = stiff.bonds;
    for (size_t b = 0; b < shifted.size(); ++b)
      shifted[b].length += std::sqrt(tv) * stiff.epsilon / shifted[b].alpha * normal(0, static_cast<Eigen::Index>(b));
    ConstraintToolbox(shifted, s.inv_mass).shake(s.x, s.x, nullptr, 1e-12, 200);
    Eigen::Matrix3Xd u = maxwell_boltzmann(s.inv_mass, tv, p.seed), pu = u;
    toolbox.project_velocity(s.x, pu);
    s.v += u - pu;
    note << (p.project || p.relax_steps > 0 ? "; " : "prepare: ") << "bond vibrations thermalised at T = " << tv
         << " (max |g| = " << toolbox.max_violation(s.x) << ")";
  }
  return note.str();
}

}  // namespace stiffmd
