// [prepare] and the rigid methods' initial projection on a decomposed run's parts (docs/parallel.md,
// "The start from the source's parts"): each rank projects, relaxes and thermalises its own
// molecules (prepare_state on PrepareParts, integrators/prepare.hpp), the relaxation's forces those
// of the part — the pair terms on the pair sets with the halo, the bonded terms on the owned
// molecules — and its molecules migrating between moves as in a run's step. The positions and
// velocities are one process's bit for bit: every step acts per particle or per constraint
// cluster, which lies in one part.
#include <limits>
#include <stdexcept>

#include "core/errors.hpp"
#include "engine/domain/domain_integrator.hpp"
#include "integrators/methods.hpp"

namespace stiffmd {

std::string DomainIntegrator::prepare_parts(const PrepareSettings& p, std::ostream* progress) {
  if (!part_) throw std::logic_error("DomainIntegrator::prepare_parts: the parts are not distributed yet");
  class Parts final : public PrepareParts {
   public:
    explicit Parts(DomainIntegrator& d) : d_(d), selections_(d.domains_->selections()) {}
    const Communicator* ranks() const override { return &d_.comm_; }
    State& state() override { return d_.mutable_part_scene().state; }
    const StiffBonds& stiff() override {
      static const StiffBonds none;
      const StiffBonds* s = d_.mutable_part_scene().forces->stiff_bonds();
      return s ? *s : none;
    }
    std::span<const int> global_ids() override { return d_.domains_->owned_ids(); }
    double forces(Eigen::Matrix3Xd& f, bool energy) override {
      Scene& part = d_.mutable_part_scene();
      if (!energy) {
        part.forces->compute_forces_unconstrained(part.state.x, f);
        return std::numeric_limits<double>::quiet_NaN();
      }
      const double share = part_energy_share(*part.forces, part.state.x, f, scratch_, true);
      return d_.comm_.sum(share);
    }
    std::string in_whole_numbers(const std::string& what) const override { return d_.in_whole_numbers(what); }
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
    Eigen::Matrix3Xd scratch_;
  };
  Parts parts(*this);
  const std::string note = prepare_state(parts, p, comm_.root() ? progress : nullptr);
  // The positions changed other than by a step: the integrators forget their cached forces, and
  // the run's force evaluations count from its first step (as after minimize).
  reset();
  std::fill(evaluations_.begin(), evaluations_.end(), 0);
  mutable_part_scene().forces->reset_counters();
  return note;
}

std::string DomainIntegrator::project_parts() {
  if (!part_) throw std::logic_error("DomainIntegrator::project_parts: the parts are not distributed yet");
  const MethodInfo* m = find_method(whole_scene_.integrator.method);
  if (!m || !m->rigid_constraints || m->effective)
    throw std::logic_error("DomainIntegrator::project_parts: " + whole_scene_.integrator.method +
                           " is not a rigid method without actions");
  Scene& part = mutable_part_scene();
  InitialProjection projection;
  if (const StiffBonds* stiff = part.forces->stiff_bonds()) {
    ConstraintToolbox toolbox(stiff->bonds, part.state.inv_mass);
    projection = project_initial_data(toolbox, part.state);
  }
  projection.max_over(comm_);
  reset();
  return describe(whole_scene_.integrator.method, projection);
}

}  // namespace stiffmd
