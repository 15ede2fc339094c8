// Dihedral (torsion) terms on quadruples (i, j, k, l) about the bond j–k, through the shared
// loop in dihedral_loop.hpp. φ in radians, φ = ±π trans (IUPAC/polymer convention, LAMMPS's);
// every kernel below but charmm's (d not 0 or 180) is even in φ; its sign is LAMMPS's too. Coefficients per dihedral
// type. Each kernel is LAMMPS's dihedral style of the same name, coefficient for coefficient
// (LAMMPS doc/src/dihedral_harmonic.rst, dihedral_multi_harmonic.rst, dihedral_opls.rst):
//   HarmonicDihedral       E = K [1 + d cos(nφ)],                 d = ±1, n ≥ 0 an integer
//   MultiHarmonicDihedral  E = Σ_{n=1..5} A_n cos^{n−1}(φ)
//   OplsDihedral           E = ½K₁(1 + cos φ) + ½K₂(1 − cos 2φ) + ½K₃(1 + cos 3φ) + ½K₄(1 − cos 4φ)
//   CharmmDihedralKernel   E = K [1 + cos(nφ − d)]        (with its 1-4 pair: charmm_terms.hpp)
// A kernel: Coeffs, kStyle, validate(c) (throws std::invalid_argument naming the coefficient),
// eval(φ, c, E, dE/dφ), describe(os, c) and define(record, c) (every coefficient, exactly, for the
// scene fingerprint of checkpoints: parameter_record.hpp).
#pragma once

#include <array>
#include <cmath>
#include <sstream>
#include <stdexcept>
#include <string>
#include <string_view>
#include <vector>

#include "core/format.hpp"
#include "core/topology.hpp"
#include "forcefields/coefficients.hpp"
#include "forcefields/dihedral_loop.hpp"
#include "forcefields/force_term.hpp"
#include "forcefields/parameter_record.hpp"
#include "forcefields/type_claim.hpp"

namespace stiffmd {

struct HarmonicDihedralKernel {
  static constexpr std::string_view kStyle = "harmonic-dihedral";
  struct Coeffs {
    double K = 0.0;  // energy, any sign (LAMMPS allows it)
    int d = 1;       // +1 or −1
    int n = 1;       // multiplicity ≥ 0
  };
  static void validate(const Coeffs& c) {
    require(c.K, kTorsionEnergy, "K");
    if (c.d != 1 && c.d != -1) throw std::invalid_argument("d: expected +1 or -1, got " + std::to_string(c.d));
    if (c.n < 0) throw std::invalid_argument("n: expected an integer >= 0, got " + std::to_string(c.n));
  }
  static void eval(double phi, const Coeffs& c, double& e, double& de_dphi) {
    e = c.K * (1.0 + c.d * std::cos(c.n * phi));
    de_dphi = -c.K * c.d * c.n * std::sin(c.n * phi);
  }
  static void describe(std::ostream& s, const Coeffs& c) {
    s << "K = " << format_exact(c.K) << ", d = " << c.d << ", n = " << c.n;
  }
  static void define(ParameterRecord& r, const Coeffs& c) {
    r.add("K", c.K);
    r.add("d", c.d);
    r.add("n", c.n);
  }
};

struct MultiHarmonicDihedralKernel {
  static constexpr std::string_view kStyle = "multi-harmonic-dihedral";
  struct Coeffs {
    std::array<double, 5> A{};  // A_1 … A_5, energies of any sign
  };
  static void validate(const Coeffs& c) {
    for (int n = 0; n < 5; ++n)
      require(c.A[n], kTorsionEnergy, std::array<const char*, 5>{"A1", "A2", "A3", "A4", "A5"}[n]);
  }
  static void eval(double phi, const Coeffs& c, double& e, double& de_dphi) {
    // Horner in c = cos φ: E = A1 + c(A2 + c(A3 + c(A4 + c A5))), dE/dc likewise; dE/dφ = −sin φ dE/dc.
    const double x = std::cos(phi);
    e = c.A[0] + x * (c.A[1] + x * (c.A[2] + x * (c.A[3] + x * c.A[4])));
    const double de_dc = c.A[1] + x * (2.0 * c.A[2] + x * (3.0 * c.A[3] + x * 4.0 * c.A[4]));
    de_dphi = -std::sin(phi) * de_dc;
  }
  static void describe(std::ostream& s, const Coeffs& c) {
    for (int n = 0; n < 5; ++n) s << (n ? ", " : "") << "A" << n + 1 << " = " << format_exact(c.A[n]);
  }
  static void define(ParameterRecord& r, const Coeffs& c) { r.add("A", std::span<const double>(c.A)); }
};

struct OplsDihedralKernel {
  static constexpr std::string_view kStyle = "opls-dihedral";
  struct Coeffs {
    std::array<double, 4> K{};  // K_1 … K_4, energies of any sign
  };
  static void validate(const Coeffs& c) {
    for (int n = 0; n < 4; ++n) require(c.K[n], kTorsionEnergy, std::array<const char*, 4>{"K1", "K2", "K3", "K4"}[n]);
  }
  static void eval(double phi, const Coeffs& c, double& e, double& de_dphi) {
    e = 0.5 * (c.K[0] * (1.0 + std::cos(phi)) + c.K[1] * (1.0 - std::cos(2.0 * phi)) +
               c.K[2] * (1.0 + std::cos(3.0 * phi)) + c.K[3] * (1.0 - std::cos(4.0 * phi)));
    de_dphi = 0.5 * (-c.K[0] * std::sin(phi) + 2.0 * c.K[1] * std::sin(2.0 * phi) - 3.0 * c.K[2] * std::sin(3.0 * phi) +
                     4.0 * c.K[3] * std::sin(4.0 * phi));
  }
  static void describe(std::ostream& s, const Coeffs& c) {
    for (int n = 0; n < 4; ++n) s << (n ? ", " : "") << "K" << n + 1 << " = " << format_exact(c.K[n]);
  }
  static void define(ParameterRecord& r, const Coeffs& c) { r.add("K", std::span<const double>(c.K)); }
};

// The torsion of LAMMPS's dihedral_style charmm, E = K [1 + cos(nφ − d)], d an integer number of
// degrees (as LAMMPS requires); w weights the 1-4 pair that CharmmDihedral (charmm_terms.hpp)
// adds, the kernel ignores it. LAMMPS evaluates cos(nφ − d) as cos nφ cos d + sin nφ sin d (the
// same to rounding); n = 0 gives K (1 + cos d).
struct CharmmDihedralKernel {
  static constexpr std::string_view kStyle = "charmm-dihedral";
  struct Coeffs {
    double K = 0.0;  // energy, any sign
    int n = 1;       // multiplicity >= 0
    int d = 0;       // phase, integer degrees
    double w = 0.0;  // weight of the 1-4 pair, 0 .. 1
  };
  static void validate(const Coeffs& c) {
    require(c.K, kTorsionEnergy, "K");
    if (c.n < 0) throw std::invalid_argument("n: expected an integer >= 0, got " + std::to_string(c.n));
    if (!(c.w >= 0.0 && c.w <= 1.0))
      throw std::invalid_argument("w: expected a weight 0 .. 1, got " + format_number(c.w));
  }
  static void eval(double phi, const Coeffs& c, double& e, double& de_dphi) {
    const double shift = c.d * (M_PI / 180.0);
    const double a = c.n * phi - shift;
    e = c.K * (1.0 + std::cos(a));
    de_dphi = -c.K * c.n * std::sin(a);
  }
  static void describe(std::ostream& s, const Coeffs& c) {
    s << "K = " << format_exact(c.K) << ", n = " << c.n << ", d = " << c.d << ", w = " << format_exact(c.w);
  }
  static void define(ParameterRecord& r, const Coeffs& c) {
    r.add("K", c.K);
    r.add("n", c.n);
    r.add("d", c.d);
    r.add("w", c.w);
  }
};

namespace dihedral_detail {
// The word for a term's items in its messages and its fingerprint: DihedralTerm serves the
// impropers too (improper_terms.hpp), on the same loop.
template <class Item>
constexpr const char* item_word();
template <>
constexpr const char* item_word<Dihedral>() {
  return "dihedral";
}
template <>
constexpr const char* item_word<Improper>() {
  return "improper";
}
}  // namespace dihedral_detail

// A dihedral term over a kernel (as AngleTerm is over an angle kernel). `Item` is Dihedral, or
// Improper for the improper styles whose angle is the dihedral angle of i, j, k, l (harmonic,
// cvff: improper_terms.hpp).
template <class K, class Item = Dihedral>
class DihedralTerm final : public ForceTerm, public TypeClaim {
 public:
  using Kernel = K;
  using Coeffs = typename K::Coeffs;
  static constexpr const char* kItem = dihedral_detail::item_word<Item>();

  // Validating constructor: every type's coefficients (Kernel::validate), i, j, k, l ≥ 0 and
  // distinct, 0 ≤ type < types.size(); throws std::invalid_argument naming the term.
  DihedralTerm(std::string name, Level level, const std::vector<Item>& dihedrals, std::vector<Coeffs> types)
      : ForceTerm(std::move(name), level), types_(std::move(types)) {
    auto fail = [&](const std::string& what) {
      throw std::invalid_argument(std::string(K::kStyle) + " '" + this->name() + "': " + what);
    };
    for (size_t t = 0; t < types_.size(); ++t) try {
        K::validate(types_[t]);
      } catch (const std::invalid_argument& e) {
        fail(std::string(kItem) + " type " + std::to_string(t) + ": " + e.what());
      }
    instances_.reserve(dihedrals.size());
    for (const Item& d : dihedrals) {
      const std::string which = std::string(kItem) + " (" + std::to_string(d.i) + ", " + std::to_string(d.j) + ", " +
                                std::to_string(d.k) + ", " + std::to_string(d.l) + ")";
      if (d.i < 0 || d.j < 0 || d.k < 0 || d.l < 0) fail(which + ": particle indices must be >= 0");
      if (d.i == d.j || d.i == d.k || d.i == d.l || d.j == d.k || d.j == d.l || d.k == d.l)
        fail(which + ": the four particles must be distinct");
      if (d.type < 0 || static_cast<size_t>(d.type) >= types_.size())
        fail(which + ": " + kItem + " type " + std::to_string(d.type) + " is not defined (" +
             std::to_string(types_.size()) + " types)");
      instances_.push_back({d.i, d.j, d.k, d.l, types_[d.type]});
    }
    dihedrals_ = dihedrals;
  }

  double add_forces(const Eigen::Matrix3Xd& x, const Box& box, Eigen::Matrix3Xd& f) const override {
    return accumulate_dihedral_forces<Kernel>(instances_, x, box, f, partition_);
  }
  double virial(const Eigen::Matrix3Xd& x, const Box& box) const override {
    return accumulate_dihedral_virial<Kernel>(instances_, x, box);
  }
  // The dihedrals of the subset, in this term's order, with its coefficients.
  std::unique_ptr<ForceTerm> on_subset(const ParticleSubset& subset, const Box&) const override {
    const std::string who = std::string(K::kStyle) + " '" + name() + "'";
    return keeping_claim(std::make_unique<DihedralTerm>(
        name(), level(), subset_items(dihedrals_, subset, who, kItem, &Item::i, &Item::j, &Item::k, &Item::l), types_));
  }
  std::string_view style() const override { return Kernel::kStyle; }
  std::string describe() const override {
    std::ostringstream s;
    s << instances_.size() << " " << K::kStyle.substr(0, K::kStyle.rfind('-')) << " " << kItem << "s";
    for (size_t t = 0; t < types_.size(); ++t) {
      s << "; type " << t << ": ";
      K::describe(s, types_[t]);
    }
    return s.str();
  }
  // Every type's coefficients, then every dihedral: its particles and its type.
  void define(ParameterRecord& record) const override {
    record.add(std::string(kItem) + " types", types_.size());
    for (const Coeffs& c : types_) K::define(record, c);
    record.add(std::string(kItem) + "s", dihedrals_.size());
    for (const Item& d : dihedrals_) record.add(kItem, {d.i, d.j, d.k, d.l, d.type});
  }
  const std::vector<Item>& items() const { return dihedrals_; }
  const std::vector<Coeffs>& types() const { return types_; }

 private:
  std::vector<Coeffs> types_;
  std::vector<Item> dihedrals_;  // as given, type indexing types_: for define()
  std::vector<DihedralInstance<Coeffs>> instances_;
  mutable TuplePartition<4> partition_;  // thread plan of the dihedral loop
};

using HarmonicDihedral = DihedralTerm<HarmonicDihedralKernel>;
using MultiHarmonicDihedral = DihedralTerm<MultiHarmonicDihedralKernel>;
using OplsDihedral = DihedralTerm<OplsDihedralKernel>;
using CharmmTorsion = DihedralTerm<CharmmDihedralKernel>;  // the torsion alone; CharmmDihedral adds the 1-4 pairs

}  // namespace stiffmd
