// Improper terms on quadruples (i, j, k, l) as LAMMPS lists them, i the central atom. Each is
// LAMMPS's improper style of the same name, coefficient for coefficient (LAMMPS
// doc/src/improper_harmonic.rst, improper_cvff.rst, improper_umbrella.rst; the formulas checked
// against LAMMPS 29 Sep 2021 in tests/test_impropers.cpp, ImproperStyles.MatchLammps):
//   harmonic-improper  E = K (χ − χ₀)²   χ = |φ| in [0, π], φ the dihedral angle of i, j, k, l
//                                        (the angle between the planes i, j, k and j, k, l; LAMMPS's
//                                        K includes the ½: no factor 2 anywhere)
//   cvff-improper      E = K [1 + d cos(nφ)]  φ the same dihedral angle (the harmonic dihedral's form)
//   umbrella-improper  E = ½ K (cos ω − cos ω₀)² / sin²ω₀   (ω₀ ≠ 0)
//                      E = K (1 − cos ω)                    (ω₀ = 0)
//                      ω the angle between the axis i–l and the plane i, j, k (DREIDING's inversion)
// harmonic and cvff run on the dihedral loop (dihedral_loop.hpp) as DihedralTerm<K, Improper>;
// umbrella has its own geometry (below) on the same owner-computes plan.
//
// Umbrella's ω as LAMMPS defines it: with h_j = x_j − x_i, h_k = x_k − x_i, h_l = x_l − x_i and the
// plane normal n = h_j × h_k, c = n̂·ĥ_l is sin of the elevation of i–l above the plane, and
//     cos ω = σ √(1 − c²),   σ = −1 when h_l·(ĥ_j + ĥ_k) > 0 (l leans towards j and k), else +1:
// ω = 0 is l in the plane on the side away from j and k. E is a function of c (and σ, piecewise
// constant); dE/dc = dE/dcos ω · (−c / cos ω), and
//     ∂c/∂x_l = (n̂ − c ĥ_l)/|h_l|,  ∂c/∂x_j = h_k × u,  ∂c/∂x_k = u × h_j,  u = (ĥ_l − c n̂)/|n|,
//     ∂c/∂x_i = −(the other three).
// Where cos ω = 0 (l along the normal) E has a cone (no gradient): the force is set to 0 there
// (LAMMPS clamps |cos ω| to 10⁻³ instead). Where j, i, k are collinear (n = 0) or l sits on i
// the plane or the axis is undefined: c = 0 and no force, as LAMMPS's clamps give.
#pragma once

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <algorithm>
#include <array>
#include <cmath>
#include <sstream>
#include <stdexcept>
#include <string>
#include <string_view>
#include <vector>

#include "core/format.hpp"
#include "core/parallel.hpp"
#include "core/state.hpp"
#include "core/topology.hpp"
#include "forcefields/coefficients.hpp"
#include "forcefields/dihedral_terms.hpp"
#include "forcefields/force_term.hpp"
#include "forcefields/parameter_record.hpp"
#include "forcefields/tuple_partition.hpp"
#include "forcefields/type_claim.hpp"

namespace stiffmd {

struct HarmonicImproperKernel {
  static constexpr std::string_view kStyle = "harmonic-improper";
  struct Coeffs {
    double K = 0.0;     // energy/rad² (LAMMPS's K: E = K (χ − χ₀)²)
    double chi0 = 0.0;  // radians, 0 .. π
  };
  static void validate(const Coeffs& c) {
    require(c.K, kStiffness, "K");
    if (!(c.chi0 >= 0.0 && c.chi0 <= M_PI))
      throw std::invalid_argument("chi0: expected an angle 0 .. 180 degrees, got " +
                                  format_number(c.chi0 * 180.0 / M_PI) + " degrees");
  }
  // χ = |φ|: dE/dφ = 2K (χ − χ₀) sign φ. At φ = 0 with χ₀ > 0 (and φ = π with χ₀ < π) E has a
  // kink; there sign φ = 0 gives no force, the symmetric choice (what a central difference gives).
  static void eval(double phi, const Coeffs& c, double& e, double& de_dphi) {
    const double g = std::abs(phi) - c.chi0;
    e = c.K * g * g;
    const double sign = phi > 0.0 ? 1.0 : phi < 0.0 ? -1.0 : 0.0;
    de_dphi = (std::abs(phi) == M_PI ? 0.0 : 2.0 * c.K * g * sign);
  }
  static void describe(std::ostream& s, const Coeffs& c) {
    s << "K = " << format_exact(c.K) << ", chi0 = " << format_exact(c.chi0 * 180.0 / M_PI) << " degrees";
  }
  static void define(ParameterRecord& r, const Coeffs& c) {
    r.add("K", c.K);
    r.add("chi0", c.chi0);
  }
};

// LAMMPS improper_style cvff: the harmonic dihedral's K [1 + d cos(nφ)] on the improper's φ.
struct CvffImproperKernel : HarmonicDihedralKernel {
  static constexpr std::string_view kStyle = "cvff-improper";
};

using HarmonicImproper = DihedralTerm<HarmonicImproperKernel, Improper>;
using CvffImproper = DihedralTerm<CvffImproperKernel, Improper>;

struct UmbrellaCoeffs {
  double K = 0.0;       // energy (LAMMPS's K)
  double omega0 = 0.0;  // radians, 0 .. π/2 (LAMMPS takes any; beyond 90° the two minima repeat)
};

namespace umbrella_detail {

struct Params {
  bool planar = true;  // ω₀ = 0: E = K (1 − cos ω)
  double K = 0.0;
  double C = 0.0;  // K / sin²ω₀ (ω₀ ≠ 0)
  double cos0 = 1.0;
};

inline Params params(const UmbrellaCoeffs& c) {
  Params p;
  p.K = c.K;
  p.planar = c.omega0 == 0.0;
  if (!p.planar) {
    const double s = std::sin(c.omega0);
    p.C = c.K / (s * s);
    p.cos0 = std::cos(c.omega0);
  }
  return p;
}

struct Instance {
  int i, j, k, l;
  Params params;
};

struct Geometry {
  Eigen::Vector3d h_j, h_k, h_l;
  double cos_omega = 1.0;
  double c = 0.0;
  Eigen::Vector3d dc_dj, dc_dk, dc_dl;  // ∂c/∂x_j, ∂c/∂x_k, ∂c/∂x_l; ∂c/∂x_i is minus their sum
};

inline Geometry geometry(int i, int j, int k, int l, const Eigen::Matrix3Xd& x) {
  Geometry g;
  g.h_j = bond_vector(x, j, i);  // raw differences: molecules are whole (ARCHITECTURE.md)
  g.h_k = bond_vector(x, k, i);
  g.h_l = bond_vector(x, l, i);
  const Eigen::Vector3d n = g.h_j.cross(g.h_k);
  const double n_len = n.norm(), h_len = g.h_l.norm();
  g.dc_dj.setZero();
  g.dc_dk.setZero();
  g.dc_dl.setZero();
  const double jj = g.h_j.norm(), kk = g.h_k.norm();
  const double lean = (jj > 0.0 ? g.h_l.dot(g.h_j) / jj : 0.0) + (kk > 0.0 ? g.h_l.dot(g.h_k) / kk : 0.0);
  const double sigma = lean > 0.0 ? -1.0 : 1.0;
  if (!(n_len > 0.0) || !(h_len > 0.0)) {  // no plane or no axis: see the header comment
    g.c = 0.0;
    g.cos_omega = sigma;
    return g;
  }
  const Eigen::Vector3d n_hat = n / n_len, h_hat = g.h_l / h_len;
  g.c = std::clamp(n_hat.dot(h_hat), -1.0, 1.0);
  g.cos_omega = sigma * std::sqrt(1.0 - g.c * g.c);
  g.dc_dl = (n_hat - g.c * h_hat) / h_len;
  const Eigen::Vector3d u = (h_hat - g.c * n_hat) / n_len;
  g.dc_dj = g.h_k.cross(u);
  g.dc_dk = u.cross(g.h_j);
  return g;
}

// E and dE/dc at the geometry g.
inline void eval(const Geometry& g, const Params& p, double& e, double& de_dc) {
  double de_dcos = 0.0;
  if (p.planar) {
    e = p.K * (1.0 - g.cos_omega);
    de_dcos = -p.K;
  } else {
    const double d = g.cos_omega - p.cos0;
    e = 0.5 * p.C * d * d;
    de_dcos = p.C * d;
  }
  de_dc = g.cos_omega != 0.0 ? -de_dcos * g.c / g.cos_omega : 0.0;  // the cone at cos ω = 0: no force
}

}  // namespace umbrella_detail

// The umbrella improper (LAMMPS improper_style umbrella, DREIDING's inversion).
class UmbrellaImproper final : public ForceTerm, public TypeClaim {
 public:
  static constexpr std::string_view kStyle = "umbrella-improper";
  using Coeffs = UmbrellaCoeffs;

  // Validating constructor: K ≥ 0, ω₀ in [0, π/2]; i, j, k, l ≥ 0 and distinct, 0 ≤ type <
  // types.size(); throws std::invalid_argument naming the term.
  UmbrellaImproper(std::string name, Level level, std::vector<Improper> impropers, std::vector<Coeffs> types)
      : ForceTerm(std::move(name), level), types_(std::move(types)), impropers_(std::move(impropers)) {
    auto fail = [&](const std::string& what) {
      throw std::invalid_argument(std::string(kStyle) + " '" + this->name() + "': " + what);
    };
    for (size_t t = 0; t < types_.size(); ++t) {
      const Coeffs& c = types_[t];
      try {
        require(c.K, kStiffness, "K");
      } catch (const std::invalid_argument& e) {
        fail("improper type " + std::to_string(t) + ": " + e.what());
      }
      if (!(c.omega0 >= 0.0 && c.omega0 <= 0.5 * M_PI))
        fail("improper type " + std::to_string(t) + ": omega0: expected an angle 0 .. 90 degrees, got " +
             format_number(c.omega0 * 180.0 / M_PI));
    }
    for (const Improper& d : impropers_) {
      const std::string which = "improper (" + std::to_string(d.i) + ", " + std::to_string(d.j) + ", " +
                                std::to_string(d.k) + ", " + std::to_string(d.l) + ")";
      if (d.i < 0 || d.j < 0 || d.k < 0 || d.l < 0) fail(which + ": particle indices must be >= 0");
      if (d.i == d.j || d.i == d.k || d.i == d.l || d.j == d.k || d.j == d.l || d.k == d.l)
        fail(which + ": the four particles must be distinct");
      if (d.type < 0 || static_cast<size_t>(d.type) >= types_.size())
        fail(which + ": improper type " + std::to_string(d.type) + " is not defined (" + std::to_string(types_.size()) +
             " types)");
      instances_.push_back({d.i, d.j, d.k, d.l, umbrella_detail::params(types_[d.type])});
    }
  }

  // Adds −∇E into f and returns Σ E, by owner computes as the dihedral loop (the serial loop's
  // bits for any thread count).
  double add_forces(const Eigen::Matrix3Xd& x, const Box& box, Eigen::Matrix3Xd& f) const override {
    (void)box;  // raw differences of whole molecules
    const int parts = threads_for(static_cast<std::int64_t>(instances_.size()));
    partition_.prepare(instances_.size(), parts, [&](std::size_t t) {
      return std::array<int, 4>{instances_[t].i, instances_[t].j, instances_[t].k, instances_[t].l};
    });
    std::array<double, kMaxParts> energy{};
    run_parts(parts, [&](int u) {
      double e_u = 0.0;
      for (const auto* w = partition_.begin(u); w < partition_.end(u); ++w) {
        const auto& t = instances_[w->tuple];
        const umbrella_detail::Geometry g = umbrella_detail::geometry(t.i, t.j, t.k, t.l, x);
        double e = 0.0, de_dc = 0.0;
        umbrella_detail::eval(g, t.params, e, de_dc);
        if (w->owned & 1u) e_u += e;
        if (w->owned & 1u) f.col(t.i) += de_dc * (g.dc_dj + g.dc_dk + g.dc_dl);
        if (w->owned & 2u) f.col(t.j) -= de_dc * g.dc_dj;
        if (w->owned & 4u) f.col(t.k) -= de_dc * g.dc_dk;
        if (w->owned & 8u) f.col(t.l) -= de_dc * g.dc_dl;
      }
      energy[u] = e_u;
    });
    double sum = energy[0];
    for (int u = 1; u < parts; ++u) sum += energy[u];
    return sum;
  }
  // Σ r_a · F_a with positions relative to x_i: c is invariant under x → λx, so this vanishes
  // analytically; what is returned is the sum as computed, zero to round-off.
  double virial(const Eigen::Matrix3Xd& x, const Box& box) const override {
    (void)box;
    const std::int64_t n = static_cast<std::int64_t>(instances_.size());
    return parallel_sum(n, threads_for(n), [&](std::int64_t first, std::int64_t last) {
      double w = 0.0;
      for (std::int64_t q = first; q < last; ++q) {
        const auto& t = instances_[q];
        const umbrella_detail::Geometry g = umbrella_detail::geometry(t.i, t.j, t.k, t.l, x);
        double e = 0.0, de_dc = 0.0;
        umbrella_detail::eval(g, t.params, e, de_dc);
        w -= de_dc * (g.h_j.dot(g.dc_dj) + g.h_k.dot(g.dc_dk) + g.h_l.dot(g.dc_dl));
      }
      return w;
    });
  }
  std::unique_ptr<ForceTerm> on_subset(const ParticleSubset& subset, const Box&) const override {
    const std::string who = std::string(kStyle) + " '" + name() + "'";
    return keeping_claim(std::make_unique<UmbrellaImproper>(
        name(), level(),
        subset_items(impropers_, subset, who, "improper", &Improper::i, &Improper::j, &Improper::k, &Improper::l),
        types_));
  }
  std::string_view style() const override { return kStyle; }
  std::string describe() const override {
    std::ostringstream s;
    s << instances_.size() << " umbrella impropers";
    for (size_t t = 0; t < types_.size(); ++t)
      s << "; type " << t << ": K = " << format_exact(types_[t].K)
        << ", omega0 = " << format_exact(types_[t].omega0 * 180.0 / M_PI) << " degrees";
    return s.str();
  }
  void define(ParameterRecord& record) const override {
    record.add("improper types", types_.size());
    for (const Coeffs& c : types_) {
      record.add("K", c.K);
      record.add("omega0", c.omega0);
    }
    record.add("impropers", impropers_.size());
    for (const Improper& d : impropers_) record.add("improper", {d.i, d.j, d.k, d.l, d.type});
  }

 private:
  std::vector<Coeffs> types_;
  std::vector<Improper> impropers_;  // as given: for define() and on_subset
  std::vector<umbrella_detail::Instance> instances_;
  mutable TuplePartition<4> partition_;
};

}  // namespace stiffmd
