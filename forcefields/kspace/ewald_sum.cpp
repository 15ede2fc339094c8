#include "forcefields/kspace/ewald_sum.hpp"

#include <cmath>
#include <numbers>
#include <sstream>
#include <stdexcept>

#include "core/format.hpp"
#include "forcefields/kspace/subset_charges.hpp"

namespace stiffmd {

namespace {

constexpr double kPi = std::numbers::pi;

}  // namespace

EwaldSum::EwaldSum(std::string name, Level level, std::vector<double> charges, const EwaldParameters& parameters,
                   double qqrd2e, const Box& box, const Communicator* comm)
    : ForceTerm(std::move(name), level),
      charges_(std::move(charges)),
      parameters_(parameters),
      qqrd2e_(qqrd2e),
      comm_(comm) {
  const std::string who = "force term '" + this->name() + "' (ewald)";
  require_kspace_box(box, who);
  if (!(parameters_.g_ewald > 0.0 && std::isfinite(parameters_.g_ewald)))
    throw std::invalid_argument(who + ": g_ewald " + format_number(parameters_.g_ewald) + " is not > 0");
  for (int a = 0; a < 3; ++a)
    if (parameters_.kmax[a] < 1 || parameters_.kmax[a] > 1000)
      throw std::invalid_argument(who + ": kmax " + std::to_string(parameters_.kmax[a]) + " on axis " +
                                  std::string(1, "xyz"[a]) + " is not in 1 … 1000");
  if (!(qqrd2e_ > 0.0 && std::isfinite(qqrd2e_)))
    throw std::invalid_argument(who + ": qqrd2e " + format_number(qqrd2e_) + " is not > 0");
  for (std::size_t i = 0; i < charges_.size(); ++i)
    if (!std::isfinite(charges_[i]))
      throw std::invalid_argument(who + ": the charge of particle " + std::to_string(i) + " is not finite");

  // The k-vectors: |n_a| ≤ kmax[a] inside the sphere of the largest per-axis |k| (LAMMPS's gsqmx,
  // widened by 1e-5 relative against round-off), one of each ±n pair: n_x > 0, or n_x = 0 and
  // n_y > 0, or n_x = n_y = 0 and n_z > 0. Fixed here, at the construction box.
  double kmax2 = 0.0;
  for (int a = 0; a < 3; ++a) kmax2 = std::max(kmax2, std::pow(2.0 * kPi * parameters_.kmax[a] / box.lengths[a], 2));
  kmax2 *= 1.00001;
  const int* km = parameters_.kmax;
  for (int nx = 0; nx <= km[0]; ++nx)
    for (int ny = -km[1]; ny <= km[1]; ++ny)
      for (int nz = -km[2]; nz <= km[2]; ++nz) {
        if (nx == 0 && (ny < 0 || (ny == 0 && nz <= 0))) continue;
        const Eigen::Vector3d k(2.0 * kPi * nx / box.lengths[0], 2.0 * kPi * ny / box.lengths[1],
                                2.0 * kPi * nz / box.lengths[2]);
        if (k.squaredNorm() <= kmax2) index_.emplace_back(nx, ny, nz);
      }
  const std::size_t n = charges_.size();
  for (int a = 0; a < 3; ++a) phase_[a].resize(n * static_cast<std::size_t>(km[a] + 1));
  s_.resize(2 * index_.size() + 1);
  p_.resize(index_.size());
  coef_.resize(4 * index_.size());
}

EwaldSum::Result EwaldSum::evaluate(const Eigen::Matrix3Xd& x, const Box& box, Eigen::Matrix3Xd* f) const {
  // (Messages built only on failure: an evaluation allocates nothing.)
  if (!is_kspace_box(box)) require_kspace_box(box, "force term '" + name() + "' (ewald)");
  const int n = static_cast<int>(charges_.size());
  if (x.cols() != n)
    throw std::invalid_argument("force term '" + name() + "' (ewald): " + std::to_string(x.cols()) +
                                " particles, but " + std::to_string(n) + " charges");
  const double g = parameters_.g_ewald;
  const double volume = box.lengths.prod();
  const Eigen::Vector3d unit = 2.0 * kPi * box.lengths.cwiseInverse();
  const int* km = parameters_.kmax;
  const std::size_t nk = index_.size();

  // Phases e^{i 2π m s_a} of the folded fractional coordinate s_a ∈ [0, 1), m = 0 … kmax[a].
  for (int i = 0; i < n; ++i)
    for (int a = 0; a < 3; ++a) {
      double s = (x(a, i) - box.origin[a]) / box.lengths[a];
      s -= std::floor(s);
      std::complex<double>* row = &phase_[a][static_cast<std::size_t>(i) * (km[a] + 1)];
      for (int m = 0; m <= km[a]; ++m) row[m] = std::polar(1.0, 2.0 * kPi * m * s);
    }
  auto phase = [&](int i, int a, int m) {
    const std::complex<double> e = phase_[a][static_cast<std::size_t>(i) * (km[a] + 1) + std::abs(m)];
    return m < 0 ? std::conj(e) : e;
  };
  auto eikr = [&](int i, const Eigen::Vector3i& m) {
    return phase(i, 0, m[0]) * phase(i, 1, m[1]) * phase(i, 2, m[2]);
  };

  // Per k-vector: k and A(k) = (4π/k²) e^{−k²/4g²}.
  for (std::size_t k = 0; k < nk; ++k) {
    const Eigen::Vector3d kv = index_[k].cast<double>().cwiseProduct(unit);
    const double k2 = kv.squaredNorm();
    coef_[4 * k] = kv[0], coef_[4 * k + 1] = kv[1], coef_[4 * k + 2] = kv[2];
    coef_[4 * k + 3] = 4.0 * kPi / k2 * std::exp(-k2 / (4.0 * g * g));
  }

  // This process's structure factors and charge, then the whole system's.
  std::fill(s_.begin(), s_.end(), 0.0);
  double own_charge = 0.0, own_q2 = 0.0;
  for (int i = 0; i < n; ++i) {
    const double q = charges_[i];
    own_charge += q;
    own_q2 += q * q;
    if (q == 0.0) continue;
    for (std::size_t k = 0; k < nk; ++k) {
      const std::complex<double> e = eikr(i, index_[k]);
      s_[2 * k] += q * e.real();
      s_[2 * k + 1] += q * e.imag();
    }
  }
  s_[2 * nk] = own_charge;
  if (comm_ && comm_->size() > 1) comm_->sum(s_.data(), static_cast<int>(s_.size()));
  const double total_charge = s_[2 * nk];

  // Per k, Σ over this process's particles of q_i Re[S* e^{ik·r_i}] (|S|² on one process), and
  // the forces: 2 (C/V) q_i A(k) k Im[S* e^{ik·r_i}] over the half of the k-vectors.
  std::fill(p_.begin(), p_.end(), 0.0);
  const double c = qqrd2e_ / volume;
  for (int i = 0; i < n; ++i) {
    const double q = charges_[i];
    if (q == 0.0) continue;
    Eigen::Vector3d fi = Eigen::Vector3d::Zero();
    for (std::size_t k = 0; k < nk; ++k) {
      const std::complex<double> e = eikr(i, index_[k]);
      const double sr = s_[2 * k], si = s_[2 * k + 1];
      // S* e = (sr − i si)(er + i ei)
      const double re = sr * e.real() + si * e.imag();
      p_[k] += q * re;
      if (f) {
        const double t = coef_[4 * k + 3] * (sr * e.imag() - si * e.real());
        fi[0] += t * coef_[4 * k], fi[1] += t * coef_[4 * k + 1], fi[2] += t * coef_[4 * k + 2];
      }
    }
    if (f) f->col(i) += (2.0 * c * q) * fi;
  }

  Result r;
  for (std::size_t k = 0; k < nk; ++k) {
    const Eigen::Vector3d kv(coef_[4 * k], coef_[4 * k + 1], coef_[4 * k + 2]);
    // Both of ±k: 2 · (C/2V) A(k) p_k.
    const double ek = c * coef_[4 * k + 3] * p_[k];
    r.energy += ek;
    const double b = 2.0 * (1.0 / kv.squaredNorm() + 1.0 / (4.0 * g * g));
    for (int a = 0; a < 3; ++a) r.w[a] += ek * (1.0 - b * kv[a] * kv[a]);
  }
  const double self = -qqrd2e_ * g / std::sqrt(kPi) * own_q2;
  const double background = -qqrd2e_ * kPi * total_charge * own_charge / (2.0 * volume * g * g);
  r.energy += self + background;
  for (double& w : r.w) w += background;  // E_background ∝ 1/V: −L_a ∂E/∂L_a = E_background
  return r;
}

double EwaldSum::add_forces(const Eigen::Matrix3Xd& x, const Box& box, Eigen::Matrix3Xd& f) const {
  return evaluate(x, box, &f).energy;
}

double EwaldSum::virial(const Eigen::Matrix3Xd& x, const Box& box) const {
  const Result r = evaluate(x, box, nullptr);
  return r.w[0] + r.w[1] + r.w[2];
}

ForceTerm::Sums EwaldSum::energy_and_virial(const Eigen::Matrix3Xd& x, const Box& box,
                                            Eigen::Matrix3Xd& scratch) const {
  const Result r = evaluate(x, box, &scratch);
  return {r.energy, r.w[0] + r.w[1] + r.w[2]};
}

void EwaldSum::add_forces_and_virial_diagonal(const Eigen::Matrix3Xd& x, const Box& box, Eigen::Matrix3Xd& f,
                                              ExactDiagonal& w) const {
  const Result r = evaluate(x, box, &f);
  for (int a = 0; a < 3; ++a) w.axis[a].add(r.w[a]);
}

std::unique_ptr<ForceTerm> EwaldSum::on_subset(const ParticleSubset& subset, const Box& box) const {
  std::vector<double> q = subset_charges(subset, charges_, "force term '" + name() + "' (ewald)");
  return std::make_unique<EwaldSum>(name(), level(), std::move(q), parameters_, qqrd2e_, box, comm_);
}

std::string EwaldSum::describe() const {
  std::ostringstream s;
  s << "Ewald reciprocal sum, g_ewald = " << format_number(parameters_.g_ewald) << ", kmax = " << parameters_.kmax[0]
    << " " << parameters_.kmax[1] << " " << parameters_.kmax[2] << " (" << index_.size() << " k-vector pairs), "
    << charges_.size() << " charges, qqrd2e = " << format_number(qqrd2e_);
  if (parameters_.accuracy_absolute > 0.0)
    s << ", RMS force accuracy " << format_number(parameters_.accuracy_absolute, 3) << " requested, "
      << format_number(parameters_.estimated_error, 3) << " estimated";
  return s.str();
}

void EwaldSum::define(ParameterRecord& record) const {
  record.add("g_ewald", parameters_.g_ewald);
  record.add("kmax", {parameters_.kmax[0], parameters_.kmax[1], parameters_.kmax[2]});
  record.add("qqrd2e", qqrd2e_);
  record.add("accuracy_absolute", parameters_.accuracy_absolute);
  record.add("estimated_error", parameters_.estimated_error);
  record.add("charges", std::span<const double>(charges_));
}

}  // namespace stiffmd
