// The CHARMM bonded terms, each LAMMPS's style of the same name coefficient for coefficient
// (doc/src/angle_charmm.rst, dihedral_charmm.rst; checked against LAMMPS 29 Sep 2021 in
// tests/test_impropers.cpp, CharmmStyles.MatchLammps), on the loops written once:
//   CharmmAngle     E = K (θ − θ₀)² + K_UB (r₁₃ − r_UB)²      (angle_style charmm: LAMMPS's K, no ½;
//                   the bend on the angle loop, the Urey–Bradley 1-3 spring on the bond loop)
//   CharmmDihedral  E = K [1 + cos(nφ − d)]                  (dihedral_style charmm, on the dihedral loop)
//                     + w · (4ε₁₄[(σ₁₄/r)¹² − (σ₁₄/r)⁶] + qqrd2e q_i q_l / r)   between i and l,
//                   r = |x_i − x_l|, unshifted and uncut, for each dihedral with w > 0 (on the bond
//                   loop), ε₁₄ and σ₁₄ those of the particle types of i and l (a TypePairMatrix, mixed
//                   by the caller), as LAMMPS's dihedral charmm takes them from a lj/charmm pair style.
// LAMMPS tallies the 1-4 energy as pair energy (evdwl, ecoul) and its virial as the pair's; here
// both are this term's: energy() is torsion + 1-4, virial() is Σ r·f of the 1-4 pairs (the
// torsion's is zero to round-off), and energy_parts() gives the three apart. The molecular virial
// share (add_forces_and_virial_diagonal) is zero as for every bonded term: the 1-4 pair lies within
// a molecule.
#pragma once

#include <cmath>
#include <sstream>
#include <stdexcept>
#include <string>
#include <string_view>
#include <vector>

#include "core/format.hpp"
#include "core/topology.hpp"
#include "forcefields/angle_loop.hpp"
#include "forcefields/angle_terms.hpp"
#include "forcefields/bond_loop.hpp"
#include "forcefields/bond_term.hpp"
#include "forcefields/coefficients.hpp"
#include "forcefields/dihedral_terms.hpp"
#include "forcefields/force_term.hpp"
#include "forcefields/pair_loop.hpp"
#include "forcefields/type_claim.hpp"

namespace stiffmd {

namespace charmm_detail {
// The Urey–Bradley spring, E = K (r − r₀)² (LAMMPS's K), on the bond loop.
struct UreyBradley {
  struct Params {
    double K = 0.0, r0 = 0.0;
  };
  static void eval(double r, const Params& p, double& e, double& de_dr) {
    const double g = r - p.r0;
    e = p.K * g * g;
    de_dr = 2.0 * p.K * g;
  }
};
// The weighted 1-4 pair, E = A/r¹² − B/r⁶ + Q/r with the weight folded in (A = 4wεσ¹², B = 4wεσ⁶,
// Q = w qqrd2e q_i q_l), on the bond loop.
struct Pair14 {
  struct Params {
    double A = 0.0, B = 0.0, Q = 0.0;
  };
  static void eval(double r, const Params& p, double& e, double& de_dr) {
    const double r2inv = 1.0 / (r * r);
    const double r6inv = r2inv * r2inv * r2inv;
    const double coul = p.Q / r;
    e = r6inv * (p.A * r6inv - p.B) + coul;
    de_dr = -(r6inv * (12.0 * p.A * r6inv - 6.0 * p.B) + coul) / r;
  }
};
}  // namespace charmm_detail

struct CharmmAngleCoeffs {
  double K = 0.0;       // energy/rad² (LAMMPS's K: E = K (θ − θ₀)²)
  double theta0 = 0.0;  // radians, 0 .. π
  double K_ub = 0.0;    // energy/length² (LAMMPS's K_UB)
  double r_ub = 0.0;    // length ≥ 0
};

class CharmmAngle final : public ForceTerm, public TypeClaim {
 public:
  static constexpr std::string_view kStyle = "charmm-angle";
  using Coeffs = CharmmAngleCoeffs;

  // Validating constructor: K, K_UB ≥ 0, θ₀ in [0, π], r_UB ≥ 0; each angle's i, j, k ≥ 0 and
  // distinct, 0 ≤ type < types.size() (j the vertex). Throws std::invalid_argument naming the term.
  CharmmAngle(std::string name, Level level, std::vector<Angle> angles, std::vector<Coeffs> types)
      : ForceTerm(std::move(name), level), types_(std::move(types)), angles_(std::move(angles)) {
    // The bend is the harmonic angle ½k(θ − θ₀)² with k = 2K: the same bits as K(θ − θ₀)² (a
    // factor 2 and ½ are exact), validated and indexed by the angle terms' own checks.
    std::vector<AngleCoeffs> bend;
    for (size_t t = 0; t < types_.size(); ++t) {
      const Coeffs& c = types_[t];
      try {
        require(c.K_ub, kStiffness, "K_UB");
        if (!(std::isfinite(c.r_ub) && c.r_ub >= 0.0))
          throw std::invalid_argument("r_UB: expected a length >= 0, got " + format_number(c.r_ub));
      } catch (const std::invalid_argument& e) {
        throw std::invalid_argument(std::string(kStyle) + " '" + this->name() + "': angle type " + std::to_string(t) +
                                    ": " + e.what());
      }
      bend.push_back({2.0 * c.K, c.theta0});
    }
    bend_ = angle_detail::angle_instances(kStyle, this->name(), angles_, bend);
    for (const Angle& a : angles_)
      if (types_[a.type].K_ub != 0.0) ub_.push_back({a.i, a.k, {types_[a.type].K_ub, types_[a.type].r_ub}});
  }

  double add_forces(const Eigen::Matrix3Xd& x, const Box& box, Eigen::Matrix3Xd& f) const override {
    const double e = accumulate_angle_forces<HarmonicAngleKernel>(bend_, x, box, f, bend_partition_);
    return e + accumulate_bond_forces<charmm_detail::UreyBradley>(ub_, x, box, f, ub_partition_);
  }
  // The bend's share is zero to round-off (angle_loop.hpp); the Urey–Bradley springs' is Σ r·f.
  double virial(const Eigen::Matrix3Xd& x, const Box& box) const override {
    return accumulate_angle_virial<HarmonicAngleKernel>(bend_, x, box) +
           accumulate_bond_virial<charmm_detail::UreyBradley>(ub_, x, box);
  }
  std::unique_ptr<ForceTerm> on_subset(const ParticleSubset& subset, const Box&) const override {
    const std::string who = std::string(kStyle) + " '" + name() + "'";
    return keeping_claim(std::make_unique<CharmmAngle>(
        name(), level(), subset_items(angles_, subset, who, "angle", &Angle::i, &Angle::j, &Angle::k), types_));
  }
  std::string_view style() const override { return kStyle; }
  std::string describe() const override {
    std::ostringstream s;
    s << bend_.size() << " charmm angles (" << ub_.size() << " with a Urey-Bradley term)";
    for (size_t t = 0; t < types_.size(); ++t)
      s << "; type " << t << ": K = " << format_exact(types_[t].K)
        << ", theta0 = " << format_exact(types_[t].theta0 * 180.0 / M_PI)
        << " degrees, K_UB = " << format_exact(types_[t].K_ub) << ", r_UB = " << format_exact(types_[t].r_ub);
    return s.str();
  }
  void define(ParameterRecord& record) const override {
    record.add("angle types", types_.size());
    for (const Coeffs& c : types_) record.add("charmm", {c.K, c.theta0, c.K_ub, c.r_ub});
    record.add("angles", angles_.size());
    for (const Angle& a : angles_) record.add("angle", {a.i, a.j, a.k, a.type});
  }

 private:
  std::vector<Coeffs> types_;
  std::vector<Angle> angles_;
  std::vector<AngleInstance<AngleCoeffs>> bend_;
  std::vector<BondInstance<charmm_detail::UreyBradley::Params>> ub_;
  mutable TuplePartition<3> bend_partition_;
  mutable BondPartition ub_partition_;
};

// ε₁₄ and σ₁₄ of a type pair (the mixed values: CharmmDihedral takes them as given).
struct Lj14 {
  double epsilon = 0.0;  // energy ≥ 0
  double sigma = 0.0;    // length > 0
};

class CharmmDihedral final : public ForceTerm, public TypeClaim {
 public:
  static constexpr std::string_view kStyle = "charmm-dihedral";
  using Coeffs = CharmmDihedralKernel::Coeffs;

  // Validating constructor. `types`: per dihedral type K, n ≥ 0, d (integer degrees), w in [0, 1].
  // `particle_types`: per particle of the system, its index into `lj14` (ε₁₄, σ₁₄ per type pair,
  // mixed by the caller); `charges`: per particle (empty: no 1-4 Coulomb); `qqrd2e`: Coulomb's
  // constant in the units (Units::coulomb, core/units.hpp). The 1-4 pair of a dihedral with w > 0 needs its
  // two particles' types in range and their pair set in lj14 (a dihedral with w = 0 needs neither).
  // Throws std::invalid_argument naming the term.
  CharmmDihedral(std::string name, Level level, std::vector<Dihedral> dihedrals, std::vector<Coeffs> types,
                 std::vector<int> particle_types, TypePairMatrix<Lj14> lj14, std::vector<double> charges, double qqrd2e)
      : ForceTerm(std::move(name), level),
        torsion_(this->name(), level, dihedrals, types),
        dihedrals_(std::move(dihedrals)),
        types_(std::move(types)),
        particle_types_(std::move(particle_types)),
        lj14_(std::move(lj14)),
        charges_(std::move(charges)),
        charged_(!charges_.empty()),
        qqrd2e_(qqrd2e) {
    auto fail = [&](const std::string& what) {
      throw std::invalid_argument(std::string(kStyle) + " '" + this->name() + "': " + what);
    };
    if (!std::isfinite(qqrd2e_)) fail("qqrd2e: expected a finite number");
    for (int a = 0; a < lj14_.num_types(); ++a)
      for (int b = a; b < lj14_.num_types(); ++b)
        if (lj14_.is_set(a, b)) {
          const Lj14& c = lj14_(a, b);
          if (!kEnergy.admits(c.epsilon) || !kLength.admits(c.sigma))
            fail("lj14 of types " + std::to_string(a) + ", " + std::to_string(b) +
                 ": expected epsilon >= 0 and sigma > 0, got " + format_number(c.epsilon) + ", " +
                 format_number(c.sigma));
        }
    for (const double q : charges_)
      if (!std::isfinite(q)) fail("a charge is not finite");
    for (const Dihedral& d : dihedrals_) {
      const Coeffs& c = types_[static_cast<size_t>(d.type)];  // the torsion checked the type
      if (c.w == 0.0) continue;
      const std::string which = "the 1-4 pair of dihedral (" + std::to_string(d.i) + ", " + std::to_string(d.j) + ", " +
                                std::to_string(d.k) + ", " + std::to_string(d.l) + ")";
      const int n = static_cast<int>(particle_types_.size());
      if (d.i >= n || d.l >= n) fail(which + ": no particle type given for its particles");
      const int ti = particle_types_[d.i], tl = particle_types_[d.l];
      if (ti < 0 || tl < 0 || ti >= lj14_.num_types() || tl >= lj14_.num_types() || !lj14_.is_set(ti, tl))
        fail(which + ": no lj14 coefficients for particle types " + std::to_string(ti) + " and " + std::to_string(tl));
      if (!charges_.empty() && (d.i >= static_cast<int>(charges_.size()) || d.l >= static_cast<int>(charges_.size())))
        fail(which + ": no charge given for its particles");
      const Lj14& p = lj14_(ti, tl);
      const double s6 = std::pow(p.sigma, 6);
      const double q = charges_.empty() ? 0.0 : qqrd2e_ * charges_[d.i] * charges_[d.l];
      pairs_.push_back({d.i, d.l, {c.w * 4.0 * p.epsilon * s6 * s6, c.w * 4.0 * p.epsilon * s6, c.w * q}});
    }
  }

  double add_forces(const Eigen::Matrix3Xd& x, const Box& box, Eigen::Matrix3Xd& f) const override {
    const double e = torsion_.add_forces(x, box, f);
    return e + accumulate_bond_forces<charmm_detail::Pair14>(pairs_, x, box, f, pair_partition_);
  }
  // Σ r·f of the 1-4 pairs (and the torsion's, zero to round-off).
  double virial(const Eigen::Matrix3Xd& x, const Box& box) const override {
    return torsion_.virial(x, box) + accumulate_bond_virial<charmm_detail::Pair14>(pairs_, x, box);
  }
  // The thermo's sums, with the 1-4 pairs' Coulomb and Lennard-Jones energies apart (Sums::coulomb
  // and Sums::vdwl: LAMMPS counts them in ecoul and evdwl).
  Sums energy_and_virial(const Eigen::Matrix3Xd& x, const Box& box, Eigen::Matrix3Xd& scratch) const override {
    Sums s = ForceTerm::energy_and_virial(x, box, scratch);
    for (const auto& b : pairs_) {
      const double r = bond_vector(x, b.i, b.j).norm();
      const double r2inv = 1.0 / (r * r), r6inv = r2inv * r2inv * r2inv;
      s.coulomb += b.params.Q / r;
      s.vdwl += r6inv * (b.params.A * r6inv - b.params.B);
    }
    return s;
  }
  // The energy in LAMMPS's three parts: the torsion (edihed), the 1-4 Lennard-Jones (its share of
  // evdwl) and the 1-4 Coulomb (of ecoul).
  struct Parts {
    double torsion = 0.0, lj14 = 0.0, coul14 = 0.0;
  };
  Parts energy_parts(const Eigen::Matrix3Xd& x, const Box& box) const {
    Parts p;
    Eigen::Matrix3Xd scratch = Eigen::Matrix3Xd::Zero(3, x.cols());
    p.torsion = torsion_.add_forces(x, box, scratch);
    for (const auto& b : pairs_) {
      const double r = bond_vector(x, b.i, b.j).norm();
      const double r2inv = 1.0 / (r * r), r6inv = r2inv * r2inv * r2inv;
      p.lj14 += r6inv * (b.params.A * r6inv - b.params.B);
      p.coul14 += b.params.Q / r;
    }
    return p;
  }
  bool uses_charges() const override { return charged_; }
  // The subset's dihedrals (TypeClaim), with the particle types and charges the subset carries
  // (ParticleSubset::types, ::charges: a decomposed run's part has them from its molecules), so
  // that this term's arrays of the whole system are never read: the subset's types index lj14 as
  // this term's particle_types do (the deck reader gives it the scene's types). A charged term on
  // a subset that carries no charges (one made of indices alone) takes this term's by index.
  std::unique_ptr<ForceTerm> on_subset(const ParticleSubset& subset, const Box&) const override {
    const std::string who = std::string(kStyle) + " '" + name() + "'";
    std::vector<int> types(subset.types.begin(), subset.types.end());
    std::vector<double> charges;
    if (charged_ && subset.charges.size() == subset.global.size())
      charges.assign(subset.charges.begin(), subset.charges.end());
    else if (charged_)
      for (const int g : subset.global) charges.push_back(g < static_cast<int>(charges_.size()) ? charges_[g] : 0.0);
    auto out = std::make_unique<CharmmDihedral>(
        name(), level(),
        subset_items(dihedrals_, subset, who, "dihedral", &Dihedral::i, &Dihedral::j, &Dihedral::k, &Dihedral::l),
        types_, std::move(types), lj14_, std::move(charges), qqrd2e_);
    out->charged_ = charged_;  // also on a subset that holds no particle
    return keeping_claim(std::move(out));
  }
  std::string_view style() const override { return kStyle; }
  std::string describe() const override {
    std::ostringstream s;
    s << torsion_.describe() << "; " << pairs_.size() << " weighted 1-4 pairs"
      << (charged_ ? " (Lennard-Jones and Coulomb)" : " (Lennard-Jones only)");
    return s.str();
  }
  void define(ParameterRecord& record) const override {
    torsion_.define(record);
    record.add("1-4 pairs", pairs_.size());
    for (const auto& b : pairs_) {
      record.add("pair", {b.i, b.j});
      record.add("A B Q", {b.params.A, b.params.B, b.params.Q});
    }
  }

 private:
  CharmmTorsion torsion_;
  std::vector<Dihedral> dihedrals_;
  std::vector<Coeffs> types_;
  std::vector<int> particle_types_;
  TypePairMatrix<Lj14> lj14_;
  std::vector<double> charges_;
  bool charged_;  // charges given (the 1-4 Coulomb part), even on a subset of no particle
  double qqrd2e_;
  std::vector<BondInstance<charmm_detail::Pair14::Params>> pairs_;  // the 1-4 pairs of the dihedrals with w > 0
  mutable BondPartition pair_partition_;
};

}  // namespace stiffmd
