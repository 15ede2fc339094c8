#include "forcefields/kspace/ewald_parameters.hpp"

#include <algorithm>
#include <cmath>
#include <numbers>
#include <stdexcept>
#include <string>

#include "core/format.hpp"

namespace stiffmd {

namespace {

constexpr double kPi = std::numbers::pi;

// Deserno & Holm (1998), eq. (38)'s coefficients a_P,m of the ik-differentiated P3M error, as
// tabulated in LAMMPS's PPPM (kAikCoefficients[P][m], P = 1 … 7, m < P).
constexpr double kAikCoefficients[8][7] = {
    {},
    {2.0 / 3.0},
    {1.0 / 50.0, 5.0 / 294.0},
    {1.0 / 588.0, 7.0 / 1440.0, 21.0 / 3872.0},
    {1.0 / 4320.0, 3.0 / 1936.0, 7601.0 / 2271360.0, 143.0 / 28800.0},
    {1.0 / 23232.0, 7601.0 / 13628160.0, 143.0 / 69120.0, 517231.0 / 106536960.0, 106640677.0 / 11737571328.0},
    {691.0 / 68140800.0, 13.0 / 57600.0, 47021.0 / 35512320.0, 9694607.0 / 2095994880.0, 733191589.0 / 59609088000.0,
     326190917.0 / 11700633600.0},
    {1.0 / 345600.0, 3617.0 / 35512320.0, 745739.0 / 838397952.0, 56399353.0 / 12773376000.0, 25091609.0 / 1560084480.0,
     1755948832039.0 / 36229939200000.0, 4887769399.0 / 37838389248.0},
};

struct Charges {
  double n = 0.0;   // the number of charges
  double q2 = 0.0;  // qqrd2e Σ q²
};

Charges check_inputs(std::string_view who, double accuracy_relative, double real_cutoff, const ChargeSums& charges,
                     const Box& box, double qqrd2e) {
  const std::string w(who);
  if (!(accuracy_relative > 0.0 && accuracy_relative < 1.0))
    throw std::invalid_argument(w + ": the relative accuracy " + format_number(accuracy_relative) +
                                " is not inside (0, 1)");
  if (!(real_cutoff > 0.0 && std::isfinite(real_cutoff)))
    throw std::invalid_argument(w + ": the real-space cutoff " + format_number(real_cutoff) + " is not > 0");
  if (!(qqrd2e > 0.0 && std::isfinite(qqrd2e)))
    throw std::invalid_argument(w + ": qqrd2e " + format_number(qqrd2e) + " is not > 0");
  require_kspace_box(box, who);
  if (!charges.finite) throw std::invalid_argument(w + ": a charge is not finite");
  if (charges.particles == 0 || charges.sum_q2 == 0.0)
    throw std::invalid_argument(w + ": no charges (" + std::to_string(charges.particles) +
                                " particles, Σq² = 0): the splitting cannot be chosen by an accuracy");
  return {static_cast<double>(charges.particles), qqrd2e * charges.sum_q2};
}

double volume_of(const Box& box) {
  return box.lengths.prod();
}

// LAMMPS's first g, from the real-space estimate alone: ΔF_real(g) = accuracy.
double initial_g(double accuracy, double real_cutoff, const Charges& c, double volume) {
  const double e = accuracy * std::sqrt(c.n * real_cutoff * volume) / (2.0 * c.q2);
  return e >= 1.0 ? (1.35 - 0.15 * std::log(accuracy)) / real_cutoff : std::sqrt(-std::log(e)) / real_cutoff;
}

bool factorable_235(int n) {
  for (const int f : {2, 3, 5})
    while (n > 1 && n % f == 0) n /= f;
  return n == 1;
}

}  // namespace

bool is_kspace_box(const Box& box) {
  for (int a = 0; a < 3; ++a)
    if (!box.periodic[a] || !(box.lengths[a] > 0.0 && std::isfinite(box.lengths[a]))) return false;
  return true;
}

void require_kspace_box(const Box& box, std::string_view who) {
  for (int a = 0; a < 3; ++a)
    if (!box.periodic[a] || !(box.lengths[a] > 0.0 && std::isfinite(box.lengths[a])))
      throw std::invalid_argument(std::string(who) + ": needs a box periodic on every axis (axis " +
                                  std::string(1, "xyz"[a]) + ": " + (box.periodic[a] ? "periodic" : "open") +
                                  ", length " + format_number(box.lengths[a]) + ")");
}

double real_space_error(double g_ewald, double real_cutoff, double n, double q2, double volume) {
  return 2.0 * q2 * std::exp(-g_ewald * g_ewald * real_cutoff * real_cutoff) / std::sqrt(n * real_cutoff * volume);
}

double ewald_axis_error(int kmax, double length, double g_ewald, double n, double q2) {
  return 2.0 * q2 * g_ewald / length * std::sqrt(1.0 / (kPi * kmax * n)) *
         std::exp(-kPi * kPi * kmax * kmax / (g_ewald * g_ewald * length * length));
}

double ewald_kspace_error(const EwaldParameters& p, const Box& box, double n, double q2) {
  double s = 0.0;
  for (int a = 0; a < 3; ++a) s += std::pow(ewald_axis_error(p.kmax[a], box.lengths[a], p.g_ewald, n, q2), 2);
  return std::sqrt(s / 3.0);
}

double pppm_axis_error(double spacing, double length, double g_ewald, int order, double n, double q2) {
  const double hg = spacing * g_ewald;
  double sum = 0.0;
  for (int m = 0; m < order; ++m) sum += kAikCoefficients[order][m] * std::pow(hg, 2.0 * m);
  return q2 * std::pow(hg, order) * std::sqrt(g_ewald * length * std::sqrt(2.0 * kPi) * sum / n) / (length * length);
}

double pppm_kspace_error(const MeshParameters& p, const Box& box, double n, double q2) {
  double s = 0.0;
  for (int a = 0; a < 3; ++a) {
    const double e = pppm_axis_error(box.lengths[a] / p.mesh[a], box.lengths[a], p.g_ewald, p.order, n, q2);
    s += e * e;
  }
  return std::sqrt(s / 3.0);
}

EwaldParameters choose_ewald(double accuracy_relative, double real_cutoff, std::span<const double> charges,
                             const Box& box, double qqrd2e) {
  return choose_ewald(accuracy_relative, real_cutoff, charge_sums_of(charges), box, qqrd2e);
}

EwaldParameters choose_ewald(double accuracy_relative, double real_cutoff, const ChargeSums& charges, const Box& box,
                             double qqrd2e) {
  const Charges c = check_inputs("choose_ewald", accuracy_relative, real_cutoff, charges, box, qqrd2e);
  EwaldParameters p;
  p.accuracy_absolute = accuracy_relative * qqrd2e;  // × two_charge_force / qqrd2e = 1
  const double volume = volume_of(box);
  p.g_ewald = initial_g(p.accuracy_absolute, real_cutoff, c, volume);
  for (int a = 0; a < 3; ++a) {
    int k = 1;
    while (ewald_axis_error(k, box.lengths[a], p.g_ewald, c.n, c.q2) > p.accuracy_absolute) {
      if (++k > 100000) throw std::invalid_argument("choose_ewald: no kmax below 100000 reaches the accuracy");
    }
    p.kmax[a] = k;
  }
  const double real = real_space_error(p.g_ewald, real_cutoff, c.n, c.q2, volume);
  const double kspace = ewald_kspace_error(p, box, c.n, c.q2);
  p.estimated_error = std::sqrt(real * real + kspace * kspace);
  return p;
}

MeshParameters choose_pppm(double accuracy_relative, double real_cutoff, std::span<const double> charges,
                           const Box& box, double qqrd2e, int order) {
  return choose_pppm(accuracy_relative, real_cutoff, charge_sums_of(charges), box, qqrd2e, order);
}

MeshParameters choose_pppm(double accuracy_relative, double real_cutoff, const ChargeSums& charges, const Box& box,
                           double qqrd2e, int order) {
  if (order < 1 || order > 7)
    throw std::invalid_argument("choose_pppm: the charge-assignment order " + std::to_string(order) +
                                " is not in 1 … 7");
  const Charges c = check_inputs("choose_pppm", accuracy_relative, real_cutoff, charges, box, qqrd2e);
  MeshParameters p;
  p.order = order;
  p.accuracy_absolute = accuracy_relative * qqrd2e;
  const double volume = volume_of(box);
  p.g_ewald = initial_g(p.accuracy_absolute, real_cutoff, c, volume);

  // The mesh per axis (LAMMPS's set_grid_global for ik differentiation, its loop as it is: the
  // error is of the spacing before each increment, so the mesh ends one point past the first
  // spacing that meets the accuracy; the first spacing, 1/g, is not the first mesh's).
  for (int a = 0; a < 3; ++a) {
    const double length = box.lengths[a];
    int n = static_cast<int>(length * p.g_ewald) + 1;
    double h = 1.0 / p.g_ewald;
    double err = pppm_axis_error(h, length, p.g_ewald, order, c.n, c.q2);
    while (err > p.accuracy_absolute) {
      err = pppm_axis_error(h, length, p.g_ewald, order, c.n, c.q2);
      if (++n > 16384)
        throw std::invalid_argument("choose_pppm: no mesh below 16384 points per axis reaches the accuracy");
      h = length / n;
    }
    while (!factorable_235(n)) ++n;
    p.mesh[a] = n;
  }

  // g balancing the two errors on this mesh (LAMMPS's adjust_gewald: Newton's method with a
  // forward-difference derivative of step 1e-6, until |f| < 1e-5 in force units).
  auto f = [&](double g) {
    MeshParameters q = p;
    q.g_ewald = g;
    return real_space_error(g, real_cutoff, c.n, c.q2, volume) - pppm_kspace_error(q, box, c.n, c.q2);
  };
  bool converged = false;
  for (int i = 0; i < 10000 && !converged; ++i) {
    const double fg = f(p.g_ewald);
    const double derivative = (f(p.g_ewald + 1e-6) - fg) / 1e-6;
    p.g_ewald -= fg / derivative;
    if (!(p.g_ewald > 0.0 && std::isfinite(p.g_ewald))) break;
    converged = std::abs(f(p.g_ewald)) < 1e-5;
  }
  if (!converged)
    throw std::invalid_argument(
        "choose_pppm: Newton's method found no g_ewald balancing the real-space and mesh errors");

  const double real = real_space_error(p.g_ewald, real_cutoff, c.n, c.q2, volume);
  const double kspace = pppm_kspace_error(p, box, c.n, c.q2);
  p.estimated_error = std::sqrt(real * real + kspace * kspace);
  return p;
}

}  // namespace stiffmd
