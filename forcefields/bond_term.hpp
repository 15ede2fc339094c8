// A bond style as a force term: BondTerm<Kernel> over a kernel of bond_potentials.hpp, as
// PairTerm is over a pair kernel and AngleTerm over an angle kernel. Energy E = Σ_b E_t(b)(r_b),
// r_b = |x_i − x_j| by minimum image on periodic axes, through the shared loop in bond_loop.hpp.
// Header-only, so a new kernel needs no explicit instantiation anywhere.
//
// The constraint-defining stiff bond is not one of these: it also hands its bonds to the
// constraint toolbox (stiff_harmonic_bond.hpp).
#pragma once

#include <sstream>
#include <stdexcept>
#include <string>
#include <string_view>
#include <vector>

#include "core/errors.hpp"
#include "core/topology.hpp"
#include "forcefields/bond_loop.hpp"
#include "forcefields/bond_potentials.hpp"
#include "forcefields/force_term.hpp"
#include "forcefields/type_claim.hpp"

namespace stiffmd {

namespace bond_detail {
// Checks each bond's particles and type (i, j ≥ 0, i ≠ j, 0 ≤ type < num_types); throws
// std::invalid_argument prefixed with `who`.
inline void check_bonds(const std::string& who, const std::vector<Bond>& bonds, std::size_t num_types) {
  for (const Bond& b : bonds) {
    const std::string which = who + ": bond (" + std::to_string(b.i) + ", " + std::to_string(b.j) + ")";
    if (b.i < 0 || b.j < 0) throw std::invalid_argument(which + ": particle indices must be >= 0");
    if (b.i == b.j) throw std::invalid_argument(which + ": a bond joins a particle to itself");
    if (b.type < 0 || static_cast<std::size_t>(b.type) >= num_types)
      throw std::invalid_argument(which + ": bond type " + std::to_string(b.type) + " is not defined (" +
                                  std::to_string(num_types) + " types)");
  }
}
}  // namespace bond_detail

template <class K>
class BondTerm final : public ForceTerm, public TypeClaim {
 public:
  using Kernel = K;
  using Coeffs = typename K::Coeffs;
  using Params = typename K::Params;

  // Validating constructor: every type's coefficients by Kernel::validate; per bond i, j ≥ 0,
  // i ≠ j, 0 ≤ type < types.size(). Bond::type indexes `types` (the reader maps the deck's bond
  // types onto this list). Throws std::invalid_argument naming the term.
  BondTerm(std::string name, Level level, std::vector<Bond> bonds, std::vector<Coeffs> types)
      : ForceTerm(std::move(name), level), types_(std::move(types)) {
    const std::string who = std::string(K::kStyle) + " '" + this->name() + "'";
    std::vector<Params> params;
    for (std::size_t t = 0; t < types_.size(); ++t) {
      try {
        K::validate(types_[t]);
      } catch (const std::invalid_argument& e) {
        throw std::invalid_argument(who + ": bond type " + std::to_string(t) + ": " + e.what());
      }
      params.push_back(K::params(types_[t]));
    }
    bond_detail::check_bonds(who, bonds, types_.size());
    instances_.reserve(bonds.size());
    for (const Bond& b : bonds) instances_.push_back({b.i, b.j, params[b.type]});
    bonds_ = std::move(bonds);
  }

  double add_forces(const Eigen::Matrix3Xd& x, const Box& box, Eigen::Matrix3Xd& f) const override {
    try {
      return accumulate_bond_forces<K>(instances_, x, box, f, partition_);
    } catch (const NumericalError&) {
      throw_outside_domain(x, box);  // f holds part of the bonds: the run is over anyway
    }
  }
  double virial(const Eigen::Matrix3Xd& x, const Box& box) const override {
    try {
      return accumulate_bond_virial<K>(instances_, x, box);
    } catch (const NumericalError&) {
      throw_outside_domain(x, box);
    }
  }
  // The bonds of the subset, in this term's order, with its coefficients.
  std::unique_ptr<ForceTerm> on_subset(const ParticleSubset& subset, const Box&) const override {
    const std::string who = std::string(K::kStyle) + " '" + name() + "'";
    return keeping_claim(std::make_unique<BondTerm>(
        name(), level(), subset_items(bonds_, subset, who, "bond", &Bond::i, &Bond::j), types_));
  }
  std::string_view style() const override { return K::kStyle; }
  std::string describe() const override {
    std::ostringstream s;
    s << instances_.size() << " " << K::kStyle << " bonds";
    for (std::size_t t = 0; t < types_.size(); ++t) {
      s << (t == 0 ? "; " : ", ") << "type " << t << ": ";
      K::describe(s, types_[t]);
    }
    return s.str();
  }
  // Every type's coefficients, then every bond: its particles and its type.
  void define(ParameterRecord& record) const override {
    record.add("bond types", types_.size());
    for (const Coeffs& c : types_) K::define(record, c);
    record.add("bonds", bonds_.size());
    for (const Bond& b : bonds_) record.add("bond", {b.i, b.j, b.type});
  }
  const std::vector<Coeffs>& types() const { return types_; }

 private:
  // The kernel threw for some bond but does not know which: find the first it refuses (the same
  // test, bond by bond; only reached on failure) and throw NumericalError naming it.
  [[noreturn]] void throw_outside_domain(const Eigen::Matrix3Xd& x, const Box& box) const {
    for (const auto& b : instances_) {
      (void)box;  // the bond vector needs no box: molecules are whole (core/state.hpp)
      const double r = bond_vector(x, b.i, b.j).norm();
      double e = 0.0, de_dr = 0.0;
      try {
        K::eval(r, b.params, e, de_dr);
      } catch (const NumericalError& why) {
        throw NumericalError(std::string(K::kStyle) + " '" + name() + "': bond between particles " +
                             std::to_string(b.i) + " and " + std::to_string(b.j) + ": " + why.what());
      }
    }
    throw NumericalError(std::string(K::kStyle) + " '" + name() + "': a bond left the kernel's domain");
  }

  std::vector<Coeffs> types_;
  std::vector<Bond> bonds_;  // as given, type indexing types_: for define()
  std::vector<BondInstance<Params>> instances_;
  mutable BondPartition partition_;  // thread plan of the bond loop
};

using FeneCoeffs = Fene::Coeffs;
using FeneBond = BondTerm<Fene>;

}  // namespace stiffmd
