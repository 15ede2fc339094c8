#include "integrators/prepare.hpp"

#include <cmath>
#include <limits>
#include <memory>
#include <numeric>
#include <sstream>
#include <vector>

#include "core/errors.hpp"
#include "core/portable_random.hpp"
#include "integrators/part_velocities.hpp"
#include "integrators/thermostat.hpp"

namespace stiffmd {

namespace {

// One process: the whole system.
class WholeSystem final : public PrepareParts {
 public:
  WholeSystem(ForceField& forces, const StiffBonds& stiff, State& s) : forces_(forces), stiff_(stiff), s_(s) {}
  const Communicator* ranks() const override { return nullptr; }
  State& state() override { return s_; }
  const StiffBonds& stiff() override { return stiff_; }
  std::span<const int> global_ids() override {
    if (ids_.size() != static_cast<size_t>(s_.size())) {
      ids_.resize(static_cast<size_t>(s_.size()));
      std::iota(ids_.begin(), ids_.end(), 0);
    }
    return ids_;
  }
  double forces(Eigen::Matrix3Xd& f, bool) override { return forces_.compute_unconstrained(s_.x, f); }
  bool redistribute(const std::vector<Eigen::Matrix3Xd*>&) override { return false; }

 private:
  ForceField& forces_;
  const StiffBonds& stiff_;
  State& s_;
  std::vector<int> ids_;
};

// max_i |a_i| over the columns (0 for none).
double largest_column(const Eigen::Matrix3Xd& a) { return a.cols() > 0 ? a.colwise().norm().maxCoeff() : 0.0; }

// The unit normal of stiff bond (i, j) (global indices) for its thermal length: counter-based,
// keyed by the seed and the bond's particles, so the same whichever rank holds the bond. The
// stream of step −2: none of the Langevin noise's (steps ≥ 0) nor the velocities' (step −1).
double bond_normal(std::uint64_t seed, std::int64_t i, std::int64_t j) {
  return particle_noise(noise_key(seed, -2, static_cast<std::uint64_t>(j)), i)[0];
}

}  // namespace

std::string prepare_state(ForceField& forces, const StiffBonds& stiff, State& s, const PrepareSettings& p,
                          std::ostream* progress) {
  WholeSystem whole(forces, stiff, s);
  return prepare_state(whole, p, progress);
}

// project = true: positions onto the constraint manifold g = 0 (SHAKE, M-orthogonal) and
// velocities onto its tangent space; vibrational_temperature = T: then give every stiff bond
// thermal vibrational energy — bond-length deviations g_b ~ N(0, T ε²/α_b²) (the stiff potential
// ½ε⁻²α_b² g_b² is diagonal in g) and normal velocities u − P u with u thermal at T (so that
// ġ = G u ~ N(0, T S): equipartition in the bonds' normal modes, linearised). Every step acts per
// particle or per constraint cluster (the toolbox's SHAKE and projections solve each cluster on
// its own), and the relaxation's one global number, its largest move, is a max: so a system held
// by parts, each rank its whole molecules, is prepared to one process's bits.
std::string prepare_state(PrepareParts& parts, const PrepareSettings& p, std::ostream* progress) {
  const Communicator* ranks = parts.ranks();
  const bool many = ranks && ranks->size() > 1;
  const double tv = p.vibrational_temperature;
  if (many && tv > 0 && !p.by_particle)
    throw std::logic_error("prepare_state on parts: the vibrations' draws are not by particle");
  auto max_over = [&](double v) { return many ? ranks->max(v) : v; };
  auto count_over = [&](std::int64_t n) {
    if (many) ranks->sum(&n, 1);
    return n;
  };
  // Work of this rank alone that may fail (a toolbox that refuses its bonds, a SHAKE that does not
  // converge): on parts every rank learns of it at the same point (agree, core/communicator.hpp).
  auto agreed = [&](auto&& local) {
    if (!many) return local();
    agree(ranks, [&] {
      try {
        local();
      } catch (const NumericalError& e) {
        throw InputError(parts.in_whole_numbers(std::string("could not project the initial state: ") + e.what()));
      } catch (const InputError& e) {
        throw InputError(parts.in_whole_numbers(e.what()));
      }
    });
  };
  std::ostringstream note;
  note.precision(4);
  auto say = [&](auto&&... what) {
    if (!progress) return;
    const auto old = progress->precision(4);
    ((*progress) << ... << what) << std::endl;  // flushed: it is progress
    progress->precision(old);
  };
  State* s = &parts.state();
  std::unique_ptr<ConstraintToolbox> toolbox;
  // This rank's part and its toolbox; again after a migration gave this rank a new part (on that
  // rank alone: no collective call here). A migrated molecule's bonds passed the first time.
  auto bind = [&] {
    s = &parts.state();
    toolbox = std::make_unique<ConstraintToolbox>(parts.stiff().bonds, s->inv_mass);
  };
  agreed(bind);
  const double g0 = max_over(toolbox->max_violation(s->x));
  const std::int64_t particles = count_over(s->size());
  const std::int64_t bonds = count_over(static_cast<std::int64_t>(parts.stiff().bonds.size()));
  if (p.project) {
    say("prepare: projecting ", particles, " particles onto ", bonds, " stiff bonds (max |g| = ", g0, ") ...");
    agreed([&] { toolbox->shake(s->x, s->x, nullptr, 1e-12, 200); });
    toolbox->project_velocity(s->x, s->v);
    note << "prepare: projected onto the constraint manifold (max |g| " << g0 << " -> "
         << max_over(toolbox->max_violation(s->x)) << ") and the velocities onto its tangent space";
  }
  if (p.relax_steps > 0) {
    // Overlaps left by a builder: steepest descent on every non-stiff term, each step moving
    // no particle more than max_move, then SHAKE back onto the bonds (g = 0).
    Eigen::Matrix3Xd f, x_old, step;
    const double e_before = parts.forces(f, true);
    double e = e_before;
    const long report_every = (p.relax_steps + 9) / 10;
    const double f_before = max_over(largest_column(f));
    say("prepare: relaxing ", p.relax_steps, " steps of at most ", p.relax_max_displacement,
        " (non-stiff potential energy ", e, ", max |F| ", f_before, ") ...");
    for (long k = 0; k < p.relax_steps; ++k) {
      step = f * s->inv_mass.asDiagonal();
      const double largest = max_over(largest_column(step));
      if (largest == 0.0) break;
      x_old = s->x;
      s->x += (p.relax_max_displacement / largest) * step;
      agreed([&] { toolbox->shake(x_old, s->x, nullptr, 1e-10, 200); });
      const bool report = (k + 1) % report_every == 0 || k + 1 == p.relax_steps;
      e = parts.forces(f, report);
      if (report) {
        const double f_max = max_over(largest_column(f));
        say("prepare: relax step ", k + 1, "/", p.relax_steps, ": non-stiff potential energy ", e, ", max |F| ", f_max);
      }
      // Molecules may move to other ranks with their forces at x (no evaluation repeated).
      if (parts.redistribute({&f})) bind();
    }
    if (std::isnan(e)) e = parts.forces(f, true);  // a stop before the last step on parts: the energy there
    toolbox->project_velocity(s->x, s->v);  // the velocities stay, tangent at the new positions
    note << (p.project ? "; " : "prepare: ") << "relaxed " << p.relax_steps << " steps: non-stiff potential energy "
         << e_before << " -> " << e;
  }
  if (tv > 0) {
    say("prepare: thermalising the vibrations of ", bonds, " stiff bonds at T = ", tv, " ...");
    // Target bond lengths ℓ_b + g_b, reached by SHAKE along M⁻¹Gᵀ with the shifted lengths.
    // by_particle: each bond's unit normal keyed by its particles, the velocities u by particle
    // (maxwell_boltzmann_by_particle). Else the normals are one component of a Maxwell–Boltzmann
    // draw at T = 1 for unit masses (the builders' portable generator), whose exact rescaling and
    // zero-mean correction are O(1/m) departures from independent N(0, 1), harmless for
    // thermalising many bonds.
    const StiffBonds& stiff = parts.stiff();
    std::vector<StiffBond> shifted = stiff.bonds;
    Eigen::Matrix3Xd u;
    if (p.by_particle) {
      const std::span<const int> global = parts.global_ids();
      for (StiffBond& b : shifted)
        b.length += std::sqrt(tv) * stiff.epsilon / b.alpha * bond_normal(p.seed + 1, global[b.i], global[b.j]);
      u = maxwell_boltzmann_by_particle(s->inv_mass, global, tv, p.seed, ranks);
    } else {
      const Eigen::Matrix3Xd normal =
          maxwell_boltzmann(Eigen::VectorXd::Ones(static_cast<Eigen::Index>(stiff.bonds.size())), 1.0, p.seed + 1);
      for (size_t b = 0; b < shifted.size(); ++b)
        shifted[b].length += std::sqrt(tv) * stiff.epsilon / shifted[b].alpha * normal(0, static_cast<Eigen::Index>(b));
    }
    agreed([&] { ConstraintToolbox(shifted, s->inv_mass).shake(s->x, s->x, nullptr, 1e-12, 200); });
    if (!p.by_particle) u = maxwell_boltzmann(s->inv_mass, tv, p.seed);
    Eigen::Matrix3Xd pu = u;
    toolbox->project_velocity(s->x, pu);
    s->v += u - pu;
    note << (p.project || p.relax_steps > 0 ? "; " : "prepare: ") << "bond vibrations thermalised at T = " << tv
         << " (max |g| = " << max_over(toolbox->max_violation(s->x)) << ")";
  }
  return note.str();
}

void InitialProjection::max_over(const Communicator& ranks) {
  double m[4] = {g_before, g_after, dx, dv};
  ranks.max(m, 4);
  g_before = m[0], g_after = m[1], dx = m[2], dv = m[3];
}

InitialProjection project_initial_data(ConstraintToolbox& toolbox, State& s) {
  const Eigen::Matrix3Xd x0 = s.x, v0 = s.v;
  InitialProjection r;
  r.g_before = toolbox.max_violation(s.x);
  toolbox.shake(s.x, s.x);             // X0 = x0 + M⁻¹G(x0)ᵀλ, g(X0) = 0
  toolbox.project_velocity(s.x, s.v);  // Y0 = P(X0) y0
  r.g_after = toolbox.max_violation(s.x);
  if (s.size() > 0) {
    r.dx = (s.x - x0).cwiseAbs().maxCoeff();
    r.dv = (s.v - v0).cwiseAbs().maxCoeff();
  }
  return r;
}

std::string describe(const std::string& method, const InitialProjection& p) {
  std::ostringstream m;
  m << method << ": initial data projected onto the constraint manifold (paper eq. ACIV): max |g| " << p.g_before
    << " -> " << p.g_after << ", max |dx| = " << p.dx << ", max |dv| = " << p.dv;
  return m.str();
}

}  // namespace stiffmd
