// [minimize] on a decomposed run's parts (docs/parallel.md, "The set-up by parts"): the soft start
// that a system built by parts needs (its molecules overlap, engine/scene/chains_by_molecule.hpp)
// without the whole system on any rank. FIRE, CG or SD (integrators/minimize.hpp, minimize on
// MinimizeParts) moves each rank's owned particles with its part's forces — the pair terms on
// the pair sets with the halo, the bonded terms on the owned molecules — and adds its global
// numbers over the ranks exactly, so that the positions are one process's bit for bit. Between
// moves the molecules migrate as in a run's step (DomainIntegrator::reselect), the method's
// per-particle columns (FIRE's velocities and last move, CG's g and h, the forces) travelling
// with them.
#include <algorithm>
#include <memory>
#include <stdexcept>

#include "core/errors.hpp"
#include "engine/domain/domain_integrator.hpp"

namespace stiffmd {

MinimizeReport DomainIntegrator::minimize(const MinimizeSettings& p, std::ostream* progress,
                                          const MinimizeObserver& after_move, SumRule rule) {
  if (!part_) throw std::logic_error("DomainIntegrator::minimize: the parts are not distributed yet");
  // The part as the minimiser sees it: the current part (a migration builds a new one), and after
  // each move the migration a step would make once the pair sets were selected again.
  class Parts final : public MinimizeParts {
   public:
    explicit Parts(DomainIntegrator& d) : d_(d), selections_(d.domains_->selections()) {}
    const Communicator& ranks() const override { return d_.comm_; }
    ForceField& forces() override { return *d_.mutable_part_scene().forces; }
    const StiffBonds* stiff() override { return d_.mutable_part_scene().forces->stiff_bonds(); }
    State& state() override { return d_.mutable_part_scene().state; }
    bool redistribute(const std::vector<Eigen::Matrix3Xd*>& carried) override {
      // Every rank selects the pair sets at the same evaluation, so every rank comes here alike.
      if (d_.domains_->selections() == selections_) return false;
      const Scene* before = &d_.mutable_part_scene();
      d_.reselect(false, carried);
      selections_ = d_.domains_->selections();
      return &d_.mutable_part_scene() != before;
    }

   private:
    DomainIntegrator& d_;
    long selections_;
  };
  Parts parts(*this);
  const MinimizeReport r = stiffmd::minimize(parts, p, comm_.root() ? progress : nullptr, after_move, rule);
  // The positions changed other than by a step: the integrators forget their cached forces
  // (Integrator::reset). The run's force evaluations count from its first step, as one process's
  // Run counts them after [minimize] (engine/run/run.cpp resets the counters).
  reset();
  std::fill(evaluations_.begin(), evaluations_.end(), 0);
  mutable_part_scene().forces->reset_counters();
  return r;
}

}  // namespace stiffmd
