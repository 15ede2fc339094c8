// The parameters of Ewald summation chosen from a requested accuracy, as LAMMPS chooses them
// (`kspace_style ewald ACC`, `kspace_style pppm ACC` with ik differentiation): the splitting
// parameter g (the real-space pairs are erfc(g r)/r, the reciprocal sum has e^{−k²/4g²}) and the
// reciprocal resolution — the largest k-vector index per axis for the exact sum (ewald_sum.hpp),
// the mesh and the charge-assignment order for PPPM (pppm.hpp).
//
// The accuracy is LAMMPS's relative RMS force accuracy: accuracy_absolute = accuracy_relative ×
// two_charge_force, the force between two unit charges 1 length unit apart, qqrd2e · 1 e² / (1 Å)²
// in real units (qqrd2e = 332.06371 kcal·Å/(mol·e²), so 332.06371) and 1 in LJ units: so
// accuracy_absolute = accuracy_relative · qqrd2e (a dielectric constant other than 1 would divide
// qqrd2e but not the reference force; none is supported here). The error estimates are of the RMS
// over particles of |ΔF_i| for random, uncorrelated charges (q2 = qqrd2e Σ q_i², N charges,
// volume V, real-space cutoff r_c):
//   real space   (Kolafa & Perram 1992)   ΔF_real = 2 q2 e^{−g² r_c²} / √(N r_c V);
//   exact sum    (LAMMPS's Ewald `rms`)   ΔF_a(k_max) = 2 q2 g / L_a · √(1/(π k_max N))
//                                                       · e^{−π² k_max² / (g² L_a²)}  per axis,
//                                          ΔF_k = √(Σ_a ΔF_a²/3);
//   PPPM, ik     (Deserno & Holm 1998, LAMMPS's `estimate_ik_error`) per axis with spacing h_a
//                                          ΔF_a = q2 (h_a g)^P √(g L_a √(2π) Σ_m a_P,m (h_a g)^{2m} / N) / L_a²,
//                                          ΔF_k = √(Σ_a ΔF_a²/3);
// and the estimated total error is √(ΔF_real² + ΔF_k²) (LAMMPS's `final_accuracy`, without
// tabulation errors: the real-space styles here do not tabulate).
#pragma once

#include <span>
#include <string_view>

#include "core/box.hpp"
#include "forcefields/kspace/charge_sums.hpp"

namespace stiffmd {

// The exact reciprocal sum's parameters: k = 2π (n_x/L_x, n_y/L_y, n_z/L_z) with |n_a| ≤ kmax[a]
// and |k| ≤ max_a 2π kmax[a]/L_a (the sphere LAMMPS's Ewald sums over, at the box it was
// chosen in).
struct EwaldParameters {
  double g_ewald = 0.0;            // the splitting parameter g (1/length)
  int kmax[3] = {0, 0, 0};         // the largest index per axis
  double accuracy_absolute = 0.0;  // the requested RMS force error (force units); 0: not chosen by an accuracy
  double estimated_error = 0.0;    // the estimated total RMS force error at these parameters (force units)
};

// PPPM's parameters: a mesh of mesh[0] × mesh[1] × mesh[2] points over the box, charges assigned
// with the order-`order` Hockney–Eastwood weights (1 … 7).
struct MeshParameters {
  double g_ewald = 0.0;
  int mesh[3] = {0, 0, 0};
  int order = 5;
  double accuracy_absolute = 0.0;
  double estimated_error = 0.0;
};

// The charges enter as their sums (charge_sums.hpp): N = charges.particles (every particle, as
// LAMMPS's atom->natoms) and q2 = qqrd2e · charges.sum_q2; a span of per-particle charges is
// summed in its order first. A scene's description gives the sums of the particles it counts
// (engine/scene/kspace_deck.hpp, charge_sums), so the parameters are the whole scene's bit for bit.
//
// LAMMPS `kspace_style ewald accuracy_relative` with a real-space cutoff `real_cutoff`: g from the
// real-space estimate alone (g = √(−ln ε)/r_c with ε = accuracy · √(N r_c V)/(2 q2), or
// (1.35 − 0.15 ln accuracy)/r_c when ε ≥ 1), then each kmax[a] the smallest with ΔF_a ≤ accuracy.
// Throws std::invalid_argument for an accuracy outside (0, 1), a cutoff ≤ 0, qqrd2e ≤ 0, no
// charges or all zero, or a box that is not periodic on every axis.
EwaldParameters choose_ewald(double accuracy_relative, double real_cutoff, const ChargeSums& charges, const Box& box,
                             double qqrd2e);
EwaldParameters choose_ewald(double accuracy_relative, double real_cutoff, std::span<const double> charges,
                             const Box& box, double qqrd2e);

// LAMMPS `kspace_style pppm accuracy_relative` (ik differentiation, kspace_modify order `order`):
// g as for Ewald; per axis the mesh grows from ⌊L_a g⌋ + 1 until ΔF_a ≤ accuracy (LAMMPS's loop,
// which tests the spacing before each increment and so stops one point later), then to the next
// size factorable by 2, 3 and 5; last g is solved by Newton's method (numerical derivative) for
// ΔF_real(g) = ΔF_k(g) on that mesh. Throws as choose_ewald, and for an order outside 1 … 7.
MeshParameters choose_pppm(double accuracy_relative, double real_cutoff, const ChargeSums& charges, const Box& box,
                           double qqrd2e, int order = 5);
MeshParameters choose_pppm(double accuracy_relative, double real_cutoff, std::span<const double> charges,
                           const Box& box, double qqrd2e, int order = 5);

// The estimates above, in force units (q2 = qqrd2e Σ q², n the number of charges).
double real_space_error(double g_ewald, double real_cutoff, double n, double q2, double volume);
double ewald_axis_error(int kmax, double length, double g_ewald, double n, double q2);
double ewald_kspace_error(const EwaldParameters& p, const Box& box, double n, double q2);
double pppm_axis_error(double spacing, double length, double g_ewald, int order, double n, double q2);
double pppm_kspace_error(const MeshParameters& p, const Box& box, double n, double q2);

// Whether the box is periodic on every axis with positive finite edges.
bool is_kspace_box(const Box& box);
// Throws std::invalid_argument, naming `who`, unless the box is periodic on every axis with
// positive finite edges (the k-space terms are for fully periodic orthorhombic boxes only).
void require_kspace_box(const Box& box, std::string_view who);

}  // namespace stiffmd
