#include "forcefields/kspace/pppm.hpp"

#include <fftw3.h>

#include <cmath>
#include <mutex>
#include <numbers>
#include <sstream>
#include <stdexcept>

#include "core/format.hpp"

namespace stiffmd {

namespace {

constexpr double kPi = std::numbers::pi;

// FFTW's planner (and plan destruction) is not thread-safe; fftw_execute is.
std::mutex& planner_mutex() {
  static std::mutex m;
  return m;
}

// The index of mesh point m (any integer) folded into 0 … n − 1.
inline int fold(int m, int n) {
  const int r = m % n;
  return r < 0 ? r + n : r;
}

// The coefficients b_l (l < P) of Σ_m U²(k + 2πm/h) = Σ_l b_l sin^{2l}(kh/2) for one axis, U the
// order-P assignment function's transform (Hockney & Eastwood; the recurrence LAMMPS's
// compute_gf_denom uses, normalised by (2P − 1)!).
std::vector<double> aliasing_coefficients(int order) {
  std::vector<double> b(static_cast<std::size_t>(order), 0.0);
  b[0] = 1.0;
  for (int m = 1; m < order; ++m) {
    for (int l = m; l > 0; --l) b[l] = 4.0 * (b[l] * (l - m) * (l - m - 0.5) - b[l - 1] * (l - m - 1) * (l - m - 1));
    b[0] = 4.0 * (b[0] * (-m) * (-m - 0.5));
  }
  double factorial = 1.0;
  for (int k = 1; k < 2 * order; ++k) factorial *= k;
  for (double& v : b) v /= factorial;
  return b;
}

// (sin x / x)^p, 1 at x = 0.
inline double sinc_power(double x, int p) {
  return x == 0.0 ? 1.0 : std::pow(std::sin(x) / x, p);
}

}  // namespace

int assignment_weights(double s, int order, double* w) {
  // The P mesh points nearest s: for odd P centred on the nearest point, for even P on the cell
  // holding s. With t = s + shift, w_frac = t − ⌊t⌋ ∈ [0, 1) and M_P the cardinal B-spline on
  // [0, P], w[j] = M_P(w_frac + P − 1 − j) by the recurrence M_n(x) = (x M_{n−1}(x) + (n − x)
  // M_{n−1}(x − 1)) / (n − 1) (Schoenberg; as in smooth PME, Essmann et al. 1995).
  const double t = s + (order % 2 ? 0.5 : 0.0);
  const double base = std::floor(t);
  const double u = t - base;
  w[0] = 1.0;
  for (int n = 2; n <= order; ++n) {
    // From v_{n−1}[j] = M_{n−1}(u + n − 2 − j) to v_n[j] = M_n(u + n − 1 − j), j = n − 1 … 0.
    const double inv = 1.0 / (n - 1);
    w[n - 1] = inv * u * w[n - 2];
    for (int j = n - 2; j > 0; --j) w[j] = inv * ((u + n - 1 - j) * w[j - 1] + (1.0 - u + j) * w[j]);
    w[0] = inv * (1.0 - u) * w[0];
  }
  return static_cast<int>(base) - (order - 1) / 2;
}

struct ParticleParticleParticleMesh::Fftw {
  int n[3];                                        // mesh points per axis (x fastest in memory)
  std::size_t real = 0, modes = 0;                 // nz·ny·nx, nz·ny·(nx/2 + 1)
  double* density = nullptr;                       // the mesh's charges, then one slot for Σq and one for Σq²
  fftw_complex* spectrum = nullptr;                // ρ̂
  fftw_complex* work = nullptr;                    // the input of each inverse transform (destroyed by it)
  double* field[3] = {nullptr, nullptr, nullptr};  // E_x, E_y, E_z on the mesh
  fftw_plan forward = nullptr, backward = nullptr;

  Fftw(const int mesh[3]) {
    for (int a = 0; a < 3; ++a) n[a] = mesh[a];
    real = static_cast<std::size_t>(n[0]) * n[1] * n[2];
    modes = static_cast<std::size_t>(n[0] / 2 + 1) * n[1] * n[2];
    std::lock_guard lock(planner_mutex());
    density = fftw_alloc_real(real + 2);
    spectrum = fftw_alloc_complex(modes);
    work = fftw_alloc_complex(modes);
    for (double*& m : field) m = fftw_alloc_real(real);
    if (!density || !spectrum || !work || !field[0] || !field[1] || !field[2]) {
      release();
      throw std::bad_alloc();
    }
    forward = fftw_plan_dft_r2c_3d(n[2], n[1], n[0], density, spectrum, FFTW_ESTIMATE);
    backward = fftw_plan_dft_c2r_3d(n[2], n[1], n[0], work, field[0], FFTW_ESTIMATE);
    if (!forward || !backward) {
      release();
      throw std::runtime_error("FFTW could not plan a " + std::to_string(n[0]) + "×" + std::to_string(n[1]) + "×" +
                               std::to_string(n[2]) + " transform");
    }
  }
  ~Fftw() {
    std::lock_guard lock(planner_mutex());
    release();
  }
  Fftw(const Fftw&) = delete;
  Fftw& operator=(const Fftw&) = delete;

 private:
  void release() {
    if (forward) fftw_destroy_plan(forward);
    if (backward) fftw_destroy_plan(backward);
    fftw_free(density);
    fftw_free(spectrum);
    fftw_free(work);
    for (double* m : field) fftw_free(m);
    forward = backward = nullptr;
  }
};

ParticleParticleParticleMesh::ParticleParticleParticleMesh(std::string name, Level level, std::vector<double> charges,
                                                           const MeshParameters& parameters, double qqrd2e,
                                                           const Box& box, const Communicator* comm)
    : ForceTerm(std::move(name), level),
      charges_(std::move(charges)),
      parameters_(parameters),
      qqrd2e_(qqrd2e),
      comm_(comm) {
  const std::string who = "force term '" + this->name() + "' (pppm)";
  require_kspace_box(box, who);
  if (!(parameters_.g_ewald > 0.0 && std::isfinite(parameters_.g_ewald)))
    throw std::invalid_argument(who + ": g_ewald " + format_number(parameters_.g_ewald) + " is not > 0");
  if (parameters_.order < 1 || parameters_.order > 7)
    throw std::invalid_argument(who + ": the charge-assignment order " + std::to_string(parameters_.order) +
                                " is not in 1 … 7");
  for (int a = 0; a < 3; ++a)
    if (parameters_.mesh[a] < 1 || parameters_.mesh[a] > 4096)
      throw std::invalid_argument(who + ": the mesh size " + std::to_string(parameters_.mesh[a]) + " on axis " +
                                  std::string(1, "xyz"[a]) + " is not in 1 … 4096");
  if (!(qqrd2e_ > 0.0 && std::isfinite(qqrd2e_)))
    throw std::invalid_argument(who + ": qqrd2e " + format_number(qqrd2e_) + " is not > 0");
  for (std::size_t i = 0; i < charges_.size(); ++i)
    if (!std::isfinite(charges_[i]))
      throw std::invalid_argument(who + ": the charge of particle " + std::to_string(i) + " is not finite");

  aliasing_ = aliasing_coefficients(parameters_.order);
  fft_ = std::make_unique<Fftw>(parameters_.mesh);
  green_.resize(fft_->modes);
  virial_factor_.resize(3 * fft_->modes);
  for (int a = 0; a < 3; ++a) wavenumber_[a].resize(static_cast<std::size_t>(parameters_.mesh[a]));
  offset_.resize(3 * charges_.size() * static_cast<std::size_t>(parameters_.order));
  weight_.resize(3 * charges_.size() * static_cast<std::size_t>(parameters_.order));
  influence_function(box);
}

ParticleParticleParticleMesh::~ParticleParticleParticleMesh() = default;

void ParticleParticleParticleMesh::influence_function(const Box& box) const {
  const int* n = fft_->n;
  const int order = parameters_.order;
  const double g = parameters_.g_ewald;
  const Eigen::Vector3d unit = 2.0 * kPi * box.lengths.cwiseInverse();
  // The signed index p of each mesh index j (p = j below n/2, j − n from n/2 on: the Nyquist
  // index of an even n is −n/2, as LAMMPS numbers it).
  auto signed_index = [](int j, int nn) { return 2 * j < nn ? j : j - nn; };
  for (int a = 0; a < 3; ++a)
    for (int j = 0; j < n[a]; ++j) wavenumber_[a][static_cast<std::size_t>(j)] = unit[a] * signed_index(j, n[a]);
  const std::vector<double>& b = aliasing_;
  auto alias_sum = [&](double sin2) {  // Σ_l b_l sin^{2l}, by Horner
    double s = 0.0;
    for (int l = order - 1; l >= 0; --l) s = b[l] + s * sin2;
    return s;
  };
  int aliases[3];
  for (int a = 0; a < 3; ++a)
    aliases[a] = static_cast<int>(g * box.lengths[a] / (kPi * n[a]) * std::pow(-std::log(1e-7), 0.25));
  const int nxh = n[0] / 2 + 1;
  std::size_t mode = 0;
  for (int iz = 0; iz < n[2]; ++iz) {
    const int pz = signed_index(iz, n[2]);
    for (int iy = 0; iy < n[1]; ++iy) {
      const int py = signed_index(iy, n[1]);
      for (int ix = 0; ix < nxh; ++ix, ++mode) {
        const int px = signed_index(ix, n[0]);
        const int p[3] = {px, py, pz};
        const Eigen::Vector3d k(unit[0] * px, unit[1] * py, unit[2] * pz);
        const double k2 = k.squaredNorm();
        const double bv = 2.0 * (k2 > 0.0 ? 1.0 / k2 : 0.0) + 2.0 / (4.0 * g * g);
        for (int a = 0; a < 3; ++a) virial_factor_[3 * mode + a] = 1.0 - bv * k[a] * k[a];
        if (k2 == 0.0) {
          green_[mode] = 0.0;
          continue;
        }
        double denominator = 1.0;
        for (int a = 0; a < 3; ++a) denominator *= alias_sum(std::pow(std::sin(kPi * p[a] / n[a]), 2));
        denominator *= denominator;
        double numerator = 0.0;
        for (int mx = -aliases[0]; mx <= aliases[0]; ++mx) {
          const double qx = unit[0] * (px + n[0] * mx);
          const double sx = std::exp(-0.25 * qx * qx / (g * g));
          const double wx = sinc_power(0.5 * qx * box.lengths[0] / n[0], 2 * order);
          for (int my = -aliases[1]; my <= aliases[1]; ++my) {
            const double qy = unit[1] * (py + n[1] * my);
            const double sy = std::exp(-0.25 * qy * qy / (g * g));
            const double wy = sinc_power(0.5 * qy * box.lengths[1] / n[1], 2 * order);
            for (int mz = -aliases[2]; mz <= aliases[2]; ++mz) {
              const double qz = unit[2] * (pz + n[2] * mz);
              const double sz = std::exp(-0.25 * qz * qz / (g * g));
              const double wz = sinc_power(0.5 * qz * box.lengths[2] / n[2], 2 * order);
              const double dot = k[0] * qx + k[1] * qy + k[2] * qz;
              const double q2 = qx * qx + qy * qy + qz * qz;
              numerator += dot / q2 * sx * sy * sz * wx * wy * wz;
            }
          }
        }
        green_[mode] = 4.0 * kPi / k2 * numerator / denominator;
      }
    }
  }
  green_lengths_ = box.lengths;
}

ParticleParticleParticleMesh::Result ParticleParticleParticleMesh::evaluate(const Eigen::Matrix3Xd& x, const Box& box,
                                                                            Eigen::Matrix3Xd* f) const {
  // (Messages built only on failure: an evaluation allocates nothing.)
  if (!is_kspace_box(box)) require_kspace_box(box, "force term '" + name() + "' (pppm)");
  const int count = static_cast<int>(charges_.size());
  if (x.cols() != count)
    throw std::invalid_argument("force term '" + name() + "' (pppm): " + std::to_string(x.cols()) + " particles, but " +
                                std::to_string(count) + " charges");
  if (box.lengths != green_lengths_) influence_function(box);
  Fftw& t = *fft_;
  const int* n = t.n;
  const int order = parameters_.order;
  const double g = parameters_.g_ewald;
  const double volume = box.lengths.prod();
  const bool shared = comm_ && comm_->size() > 1;

  // 1. Charge assignment (this process's charges), then the whole system's mesh.
  const std::size_t stride[3] = {1, static_cast<std::size_t>(n[0]), static_cast<std::size_t>(n[0]) * n[1]};
  std::fill(t.density, t.density + t.real + 2, 0.0);
  double own_charge = 0.0, own_q2 = 0.0;
  for (int i = 0; i < count; ++i) {
    const double q = charges_[i];
    own_charge += q;
    own_q2 += q * q;
    // The mesh points' offsets (folded, times the axis's stride) and weights per axis.
    std::size_t* offset = &offset_[3 * static_cast<std::size_t>(i) * order];
    double* w = &weight_[3 * static_cast<std::size_t>(i) * order];
    for (int a = 0; a < 3; ++a) {
      double s = (x(a, i) - box.origin[a]) / box.lengths[a];
      s -= std::floor(s);
      const int first = assignment_weights(s * n[a], order, w + a * order);
      for (int j = 0; j < order; ++j)
        offset[a * order + j] = static_cast<std::size_t>(fold(first + j, n[a])) * stride[a];
    }
    if (q == 0.0) continue;
    for (int jz = 0; jz < order; ++jz) {
      const double wz = q * w[2 * order + jz];
      for (int jy = 0; jy < order; ++jy) {
        const double wyz = wz * w[order + jy];
        double* row = t.density + offset[2 * order + jz] + offset[order + jy];
        for (int jx = 0; jx < order; ++jx) row[offset[jx]] += wyz * w[jx];
      }
    }
  }
  t.density[t.real] = own_charge;
  t.density[t.real + 1] = own_q2;
  if (shared) comm_->sum(t.density, static_cast<int>(t.real + 2));
  const double total_charge = t.density[t.real];
  const double total_q2 = t.density[t.real + 1];

  // 2.–4. ρ̂; the energy and virial from the half spectrum, each mode with ix ∉ {0, n_x/2}
  // standing for itself and its mirror image.
  fftw_execute_dft_r2c(t.forward, t.density, t.spectrum);
  const int nxh = n[0] / 2 + 1;
  const double c = qqrd2e_ / volume;
  double kspace = 0.0, w[3] = {0.0, 0.0, 0.0};
  for (std::size_t mode = 0; mode < t.modes; ++mode) {
    const int ix = static_cast<int>(mode % nxh);
    const double times = (ix == 0 || 2 * ix == n[0]) ? 1.0 : 2.0;
    const double e =
        times * green_[mode] * (t.spectrum[mode][0] * t.spectrum[mode][0] + t.spectrum[mode][1] * t.spectrum[mode][1]);
    kspace += e;
    for (int a = 0; a < 3; ++a) w[a] += e * virial_factor_[3 * mode + a];
  }
  kspace *= 0.5 * c;
  for (double& v : w) v *= 0.5 * c;
  const double background_total = -qqrd2e_ * kPi * total_charge * total_charge / (2.0 * volume * g * g);
  for (double& v : w) v += background_total;

  // 5. The field on the mesh: (C/V) (−i k_a) G ρ̂.
  for (int a = 0; f && a < 3; ++a) {
    std::size_t mode = 0;
    for (int iz = 0; iz < n[2]; ++iz)
      for (int iy = 0; iy < n[1]; ++iy)
        for (int ix = 0; ix < nxh; ++ix, ++mode) {
          const double scale = c * green_[mode];
          const int j = a == 0 ? ix : a == 1 ? iy : iz;
          const double k = 2 * j == n[a] ? 0.0 : wavenumber_[a][static_cast<std::size_t>(j)];
          // (−i k)(re + i im) = k im − i k re
          t.work[mode][0] = scale * k * t.spectrum[mode][1];
          t.work[mode][1] = -scale * k * t.spectrum[mode][0];
        }
    fftw_execute_dft_c2r(t.backward, t.work, t.field[a]);
  }

  // Interpolation back to this process's particles.
  for (int i = 0; f && i < count; ++i) {
    const double q = charges_[i];
    if (q == 0.0) continue;
    const std::size_t* offset = &offset_[3 * static_cast<std::size_t>(i) * order];
    const double* wt = &weight_[3 * static_cast<std::size_t>(i) * order];
    double ex = 0.0, ey = 0.0, ez = 0.0;
    for (int jz = 0; jz < order; ++jz)
      for (int jy = 0; jy < order; ++jy) {
        const double wyz = wt[2 * order + jz] * wt[order + jy];
        const std::size_t row = offset[2 * order + jz] + offset[order + jy];
        for (int jx = 0; jx < order; ++jx) {
          const std::size_t m = row + offset[jx];
          const double wm = wyz * wt[jx];
          ex += wm * t.field[0][m];
          ey += wm * t.field[1][m];
          ez += wm * t.field[2][m];
        }
      }
    (*f)(0, i) += q * ex;
    (*f)(1, i) += q * ey;
    (*f)(2, i) += q * ez;
  }

  // Every process has the whole mesh, so the whole energy and virial: each returns 1/size of them,
  // so that the shares add up to the whole system's.
  Result r;
  const double self = -qqrd2e_ * g / std::sqrt(kPi);
  const double background = -qqrd2e_ * kPi * total_charge / (2.0 * volume * g * g);
  const double share = shared ? 1.0 / comm_->size() : 1.0;
  r.energy = share * (kspace + self * total_q2 + background * total_charge);
  for (int a = 0; a < 3; ++a) r.w[a] = share * w[a];
  return r;
}

double ParticleParticleParticleMesh::add_forces(const Eigen::Matrix3Xd& x, const Box& box, Eigen::Matrix3Xd& f) const {
  return evaluate(x, box, &f).energy;
}

double ParticleParticleParticleMesh::virial(const Eigen::Matrix3Xd& x, const Box& box) const {
  const Result r = evaluate(x, box, nullptr);
  return r.w[0] + r.w[1] + r.w[2];
}

ForceTerm::Sums ParticleParticleParticleMesh::energy_and_virial(const Eigen::Matrix3Xd& x, const Box& box,
                                                                Eigen::Matrix3Xd& scratch) const {
  const Result r = evaluate(x, box, &scratch);
  return {r.energy, r.w[0] + r.w[1] + r.w[2]};
}

void ParticleParticleParticleMesh::add_forces_and_virial_diagonal(const Eigen::Matrix3Xd& x, const Box& box,
                                                                  Eigen::Matrix3Xd& f, ExactDiagonal& w) const {
  const Result r = evaluate(x, box, &f);
  for (int a = 0; a < 3; ++a) w.axis[a].add(r.w[a]);
}

std::unique_ptr<ForceTerm> ParticleParticleParticleMesh::on_subset(const ParticleSubset& subset, const Box& box) const {
  std::vector<double> q;
  q.reserve(subset.global.size());
  for (const int g : subset.global) {
    if (g < 0 || g >= static_cast<int>(charges_.size()))
      throw std::invalid_argument("force term '" + name() + "' (pppm): the subset's particle " + std::to_string(g) +
                                  " is not among its " + std::to_string(charges_.size()) + " charges");
    q.push_back(charges_[static_cast<std::size_t>(g)]);
  }
  return std::make_unique<ParticleParticleParticleMesh>(name(), level(), std::move(q), parameters_, qqrd2e_, box,
                                                        comm_);
}

std::string ParticleParticleParticleMesh::describe() const {
  std::ostringstream s;
  s << "PPPM (ik differentiation), g_ewald = " << format_number(parameters_.g_ewald) << ", mesh " << parameters_.mesh[0]
    << "×" << parameters_.mesh[1] << "×" << parameters_.mesh[2] << ", order " << parameters_.order << ", "
    << charges_.size() << " charges, qqrd2e = " << format_number(qqrd2e_);
  if (parameters_.accuracy_absolute > 0.0)
    s << ", RMS force accuracy " << format_number(parameters_.accuracy_absolute, 3) << " requested, "
      << format_number(parameters_.estimated_error, 3) << " estimated";
  return s.str();
}

void ParticleParticleParticleMesh::define(ParameterRecord& record) const {
  record.add("g_ewald", parameters_.g_ewald);
  record.add("mesh", {parameters_.mesh[0], parameters_.mesh[1], parameters_.mesh[2]});
  record.add("order", parameters_.order);
  record.add("qqrd2e", qqrd2e_);
  record.add("accuracy_absolute", parameters_.accuracy_absolute);
  record.add("estimated_error", parameters_.estimated_error);
  record.add("charges", std::span<const double>(charges_));
}

}  // namespace stiffmd
