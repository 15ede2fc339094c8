// The exact mollified force of the constraint toolbox (integrators/constraints.hpp):
// F̄(x) = α′(x)ᵀ f(α(x)), α the M-orthogonal projection onto g = 0 (paper eq. (ProMol)).
#include "integrators/constraint_toolbox_impl.hpp"

#include "core/parallel.hpp"
#include "core/timing.hpp"

namespace stiffmd {
using namespace constraint_detail;  // the toolbox's private types (constraint_toolbox_impl.hpp)
namespace {

// SHAKE iterations allowed inside mollified_force, whose API has no max_iter.
constexpr int kMollifierMaxIter = 50;

}  // namespace

// Steps 2–4 of the mollified force (integrators/constraints.hpp), from
// α′(x) = (I − M⁻¹G(x)ᵀJ⁻¹G(X))(I + M⁻¹H_λ), which follows by differentiating
// X = x + M⁻¹G(x)ᵀλ(x), g(X) = 0. On entry f = f_slow(X) and data[c].lambda holds the multipliers
// of X = α(x).
void ConstraintToolbox::Impl::mollify_cluster(int c, Eigen::Matrix3Xd& f) {
  ClusterData& d = data[c];
  // G(x) and G(X) are in at_kept and at_cur: shake_cluster measured x as its reference and
  // X = α(x) in its last, converged iteration (mollified_force calls the two in turn, and
  // f_slow does not touch the toolbox).
  // Step 2: Jᵀμ = G(x) M⁻¹ f, Jᵀ = G(x) M⁻¹ G(X)ᵀ.
  factorize(c, at_kept, at_cur, false, "mollified force");
  ++d.factorizations;
  if (!d.spd) d.s_factored = false;  // Jᵀ took S's place in the solver
  for (int k = 0; k < d.rhs.size(); ++k) d.rhs[k] = at_kept.u.col(d.bonds[k]).dot(inv_mass_difference(d.bonds[k], f));
  d.solver->solve(d.rhs, d.sol);
  // Step 3: r = f − G(X)ᵀμ.
  add_constraint_force(c, at_cur, d.sol, -1.0, f);
  // Step 4: F̄ = r + H_λ M⁻¹ r. ∇²g_b acts on (x_i, x_j) as [[A, −A], [−A, A]],
  // A = (I − u uᵀ)/|x_i − x_j| at x (the derivative of u_b(x)). All of r is needed before
  // any of it is overwritten, hence the per-bond buffer.
  for (int k = 0; k < d.rhs.size(); ++k) {
    const int b = d.bonds[k];
    const Eigen::Vector3d w = inv_mass_difference(b, f);
    const Eigen::Vector3d u = at_kept.u.col(b);
    curvature.col(b) = d.lambda[k] * (w - u * u.dot(w)) / at_kept.length[b];
  }
  for (int b : d.bonds) {
    f.col(bonds[b].i) += curvature.col(b);
    f.col(bonds[b].j) -= curvature.col(b);
  }
}

void ConstraintToolbox::mollified_force(const Eigen::Matrix3Xd& x, const ForceFunction& f_slow, Eigen::Matrix3Xd& X,
                                        Eigen::Matrix3Xd& out, double tol) {
  const ScopedPhase phase(Phase::constraints);
  require_columns(x, impl_->num_particles(), "mollified_force");
  // Step 1: X = α(x), the M-orthogonal projection of x onto g = 0 (paper eq. (ProMol)).
  impl_->keep(x);
  X.resize(3, x.cols());  // no allocation once sized
  parallel_blocks(x.cols(), threads_for(x.cols()),
                  [&](std::int64_t b, std::int64_t e) { X.middleCols(b, e - b) = x.middleCols(b, e - b); });
  impl_->for_each_cluster([&](int c) { impl_->shake_cluster(c, X, tol, kMollifierMaxIter); });
  out.resize(3, x.cols());
  f_slow(X, out);
  require_columns(out, impl_->num_particles(), "mollified_force (f_slow output)");
  impl_->for_each_cluster([&](int c) { impl_->mollify_cluster(c, out); });
}

}  // namespace stiffmd
