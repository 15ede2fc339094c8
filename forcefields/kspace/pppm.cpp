#include "forcefields/kspace/pppm.hpp"

#include <fftw3.h>

#include <cmath>
#include <mutex>
#include <numbers>
#include <sstream>
#include <stdexcept>

#include "core/format.hpp"
#include "forcefields/kspace/subset_charges.hpp"

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

// Particle i's P mesh points per axis a, as offsets (the point folded into the mesh, times
// stride[a]) into offset[a P + j], and their assignment weights into w[a P + j].
void particle_stencil(const Eigen::Matrix3Xd& x, int i, const Box& box, const int* n, int order,
                      const std::size_t* stride, std::size_t* offset, double* w) {
  for (int a = 0; a < 3; ++a) {
    double s = (x(a, i) - box.origin[a]) / box.lengths[a];
    s -= std::floor(s);
    const int first = assignment_weights(s * n[a], order, w + a * order);
    for (int j = 0; j < order; ++j) offset[a * order + j] = static_cast<std::size_t>(fold(first + j, n[a])) * stride[a];
  }
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
  double* density = nullptr;                       // the mesh's charges
  fftw_complex* spectrum = nullptr;                // ρ̂
  fftw_complex* work = nullptr;                    // the input of each inverse transform (destroyed by it)
  double* field[3] = {nullptr, nullptr, nullptr};  // E_x, E_y, E_z on the mesh
  fftw_plan forward = nullptr, backward = nullptr;

  Fftw(const int mesh[3]) {
    for (int a = 0; a < 3; ++a) n[a] = mesh[a];
    real = static_cast<std::size_t>(n[0]) * n[1] * n[2];
    modes = static_cast<std::size_t>(n[0] / 2 + 1) * n[1] * n[2];
    std::lock_guard lock(planner_mutex());
    density = fftw_alloc_real(real);
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

// One rank's part of the distributed mesh (pppm.hpp): its planes and columns, their FFTW buffers
// and plans, the transposes' fixed buffers and the window's, which grow.
struct ParticleParticleParticleMesh::Slabs {
  using Buffers = std::vector<std::vector<double>>;
  int n[3];                        // mesh points per axis
  int nxh;                         // n_x/2 + 1
  std::size_t plane = 0, row = 0;  // reals per plane (n_x n_y), columns per plane (n_y nxh)
  int ranks = 1, rank = 0;
  std::vector<int> z_first, c_first;   // rank r's planes [z_first[r], z_first[r + 1]), columns likewise
  std::vector<int> owner;              // per plane, the rank that owns it
  int z0 = 0, pz = 0, c0 = 0, pc = 0;  // this rank's first plane and count, first column and count
  double* real = nullptr;              // 3 pz planes: the owned charges (the first pz), then E_x, E_y, E_z
  fftw_complex* spectra = nullptr;     // 3 pz planes' 2D spectra (row each)
  fftw_complex* rho = nullptr;         // pc columns of n_z: ρ̂ (column c_local at c_local n_z)
  fftw_complex* field = nullptr;       // 3 pc columns: (−i k_a) G ρ̂, then along z transformed back
  fftw_plan forward_planes = nullptr, forward_columns = nullptr, backward_columns = nullptr, backward_planes = nullptr;
  // The transposes (fixed: planes × columns of each pair of ranks; none to itself).
  Buffers forward_send, forward_recv, backward_send, backward_recv;
  // The window: per rank its first plane and width (this evaluation's, from one sum); this
  // rank's planes touched; per window plane its owner, its index among the planes sent to that
  // owner, and where its charges and its field's three components are; the charges to each other
  // owner and the field back (a plane this rank owns: its charges in own_charges, its field read
  // where the inverse FFT left it, none of it through the exchanges).
  std::vector<std::int64_t> windows;
  std::vector<unsigned char> touched;
  std::vector<int> window_owner, window_index, per_owner;
  std::vector<double*> charge_plane;
  std::vector<const double*> field_plane;  // 3 per window plane
  std::vector<double> own_charges;
  Buffers spread_send, spread_recv, field_send, field_recv;

  Slabs(const int mesh[3], int ranks_, int rank_) : ranks(ranks_), rank(rank_) {
    for (int a = 0; a < 3; ++a) n[a] = mesh[a];
    nxh = n[0] / 2 + 1;
    plane = static_cast<std::size_t>(n[0]) * n[1];
    row = static_cast<std::size_t>(n[1]) * nxh;
    const auto split = [&](std::int64_t total, std::vector<int>& first) {
      first.resize(static_cast<std::size_t>(ranks) + 1);
      for (int r = 0; r <= ranks; ++r) first[r] = static_cast<int>(total * r / ranks);
    };
    split(n[2], z_first);
    split(static_cast<std::int64_t>(row), c_first);
    owner.resize(static_cast<std::size_t>(n[2]));
    for (int r = 0; r < ranks; ++r)
      for (int z = z_first[r]; z < z_first[r + 1]; ++z) owner[z] = r;
    z0 = z_first[rank], pz = z_first[rank + 1] - z0;
    c0 = c_first[rank], pc = c_first[rank + 1] - c0;
    forward_send.resize(ranks), forward_recv.resize(ranks), backward_send.resize(ranks), backward_recv.resize(ranks);
    for (int t = 0; t < ranks; ++t) {  // this rank's own block is copied, not exchanged
      const std::size_t pz_t = t == rank ? 0 : z_first[t + 1] - z_first[t];
      const std::size_t pc_t = t == rank ? 0 : c_first[t + 1] - c_first[t];
      forward_send[t].resize(2 * pz * pc_t);
      forward_recv[t].resize(2 * pz_t * pc);
      backward_send[t].resize(6 * pc * pz_t);
      backward_recv[t].resize(6 * pz * pc_t);
    }
    windows.resize(2 * static_cast<std::size_t>(ranks));
    touched.resize(static_cast<std::size_t>(n[2]));
    window_owner.resize(static_cast<std::size_t>(n[2]));
    window_index.resize(static_cast<std::size_t>(n[2]));
    per_owner.resize(static_cast<std::size_t>(ranks));
    charge_plane.reserve(static_cast<std::size_t>(n[2]));
    field_plane.reserve(3 * static_cast<std::size_t>(n[2]));
    spread_send.resize(ranks), spread_recv.resize(ranks), field_send.resize(ranks), field_recv.resize(ranks);

    std::lock_guard lock(planner_mutex());
    // At least one element each: a rank without planes or columns still has valid pointers.
    real = fftw_alloc_real(std::max<std::size_t>(3 * pz * plane, 1));
    spectra = fftw_alloc_complex(std::max<std::size_t>(3 * pz * row, 1));
    rho = fftw_alloc_complex(std::max<std::size_t>(static_cast<std::size_t>(pc) * n[2], 1));
    field = fftw_alloc_complex(std::max<std::size_t>(3 * static_cast<std::size_t>(pc) * n[2], 1));
    if (!real || !spectra || !rho || !field) {
      release();
      throw std::bad_alloc();
    }
    const int planes_shape[2] = {n[1], n[0]};
    const int column_shape[1] = {n[2]};
    const int plane_reals = static_cast<int>(plane), plane_modes = static_cast<int>(row);
    bool failed = false;
    if (pz > 0) {
      forward_planes = fftw_plan_many_dft_r2c(2, planes_shape, pz, real, nullptr, 1, plane_reals, spectra, nullptr, 1,
                                              plane_modes, FFTW_ESTIMATE);
      backward_planes = fftw_plan_many_dft_c2r(2, planes_shape, 3 * pz, spectra, nullptr, 1, plane_modes, real, nullptr,
                                               1, plane_reals, FFTW_ESTIMATE);
      failed = !forward_planes || !backward_planes;
    }
    if (pc > 0) {
      forward_columns = fftw_plan_many_dft(1, column_shape, pc, rho, nullptr, 1, n[2], rho, nullptr, 1, n[2],
                                           FFTW_FORWARD, FFTW_ESTIMATE);
      backward_columns = fftw_plan_many_dft(1, column_shape, 3 * pc, field, nullptr, 1, n[2], field, nullptr, 1, n[2],
                                            FFTW_BACKWARD, FFTW_ESTIMATE);
      failed = failed || !forward_columns || !backward_columns;
    }
    if (failed) {
      release();
      throw std::runtime_error("FFTW could not plan the slabs of a " + std::to_string(n[0]) + "×" +
                               std::to_string(n[1]) + "×" + std::to_string(n[2]) + " transform on rank " +
                               std::to_string(rank) + " of " + std::to_string(ranks));
    }
  }
  ~Slabs() {
    std::lock_guard lock(planner_mutex());
    release();
  }
  Slabs(const Slabs&) = delete;
  Slabs& operator=(const Slabs&) = delete;

  std::size_t own_modes() const { return static_cast<std::size_t>(pc) * n[2]; }

 private:
  void release() {
    for (fftw_plan p : {forward_planes, forward_columns, backward_columns, backward_planes})
      if (p) fftw_destroy_plan(p);
    forward_planes = forward_columns = backward_columns = backward_planes = nullptr;
    fftw_free(real);
    fftw_free(spectra);
    fftw_free(rho);
    fftw_free(field);
    real = nullptr, spectra = rho = field = nullptr;
  }
};

namespace {

// The smallest circular range of planes [lo, lo + width) (mod n) holding every touched plane: the
// complement of the longest run of untouched ones (the first such run from the lowest touched plane
// on, at a tie). Width 0 when none is touched.
void circular_window(const std::vector<unsigned char>& touched, int& lo, int& width) {
  const int n = static_cast<int>(touched.size());
  int first = 0;
  while (first < n && !touched[first]) ++first;
  if (first == n) {
    lo = 0, width = 0;
    return;
  }
  int best_gap = 0, best_end = first, gap = 0;
  for (int k = 1; k <= n; ++k) {
    const int z = (first + k) % n;
    if (!touched[z]) {
      ++gap;
      continue;
    }
    if (gap > best_gap) best_gap = gap, best_end = z;
    gap = 0;
  }
  lo = best_gap > 0 ? best_end : 0;
  width = n - best_gap;
}

}  // namespace

ParticleParticleParticleMesh::ParticleParticleParticleMesh(std::string name, Level level, std::vector<double> charges,
                                                           const MeshParameters& parameters, double qqrd2e,
                                                           const Box& box, const Communicator* comm)
    : ParticleParticleParticleMesh(Deferred{}, std::move(name), level, std::move(charges), parameters, qqrd2e, box,
                                   comm) {
  build_mesh();
  influence_function(box);
}

ParticleParticleParticleMesh::ParticleParticleParticleMesh(Deferred, std::string name, Level level,
                                                           std::vector<double> charges,
                                                           const MeshParameters& parameters, double qqrd2e,
                                                           const Box& box, const Communicator* comm)
    : ForceTerm(std::move(name), level),
      charges_(std::move(charges)),
      parameters_(parameters),
      qqrd2e_(qqrd2e),
      comm_(comm),
      box_(box) {
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
  for (int a = 0; a < 3; ++a) wavenumber_[a].resize(static_cast<std::size_t>(parameters_.mesh[a]));
  offset_.resize(3 * charges_.size() * static_cast<std::size_t>(parameters_.order));
  weight_.resize(3 * charges_.size() * static_cast<std::size_t>(parameters_.order));
}

ParticleParticleParticleMesh::~ParticleParticleParticleMesh() = default;

void ParticleParticleParticleMesh::build_mesh() const {
  if (comm_ && comm_->size() > 1) {
    fft_.reset();
    slabs_.reset();  // first: never two ranks' worth at once
    slabs_ = std::make_unique<Slabs>(parameters_.mesh, comm_->size(), comm_->rank());
    green_.assign(slabs_->own_modes(), 0.0);
  } else {
    slabs_.reset();
    if (!fft_) fft_ = std::make_unique<Fftw>(parameters_.mesh);
    green_.assign(fft_->modes, 0.0);
  }
  virial_factor_.assign(3 * green_.size(), 0.0);
  green_lengths_.setZero();
}

void ParticleParticleParticleMesh::release_buffers() const {
  fft_.reset();
  slabs_.reset();
  green_ = {};
  virial_factor_ = {};
  green_lengths_.setZero();
}

void ParticleParticleParticleMesh::set_processes(const Communicator* comm) {
  comm_ = comm;
  build_mesh();
  influence_function(box_);
}

void ParticleParticleParticleMesh::influence_function(const Box& box) const {
  const int* n = parameters_.mesh;
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
  // G and the virial factors of mode (ix, iy, iz), stored at `mode`.
  auto factors = [&](int ix, int iy, int iz, std::size_t mode) {
    const int pz = signed_index(iz, n[2]);
    const int py = signed_index(iy, n[1]);
    const int px = signed_index(ix, n[0]);
    const int p[3] = {px, py, pz};
    const Eigen::Vector3d k(unit[0] * px, unit[1] * py, unit[2] * pz);
    const double k2 = k.squaredNorm();
    const double bv = 2.0 * (k2 > 0.0 ? 1.0 / k2 : 0.0) + 2.0 / (4.0 * g * g);
    for (int a = 0; a < 3; ++a) virial_factor_[3 * mode + a] = 1.0 - bv * k[a] * k[a];
    if (k2 == 0.0) {
      green_[mode] = 0.0;
      return;
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
  };
  const int nxh = n[0] / 2 + 1;
  if (slabs_) {  // this rank's columns, each along z
    const Slabs& s = *slabs_;
    for (int cl = 0; cl < s.pc; ++cl) {
      const int c = s.c0 + cl;
      for (int iz = 0; iz < n[2]; ++iz) factors(c % nxh, c / nxh, iz, static_cast<std::size_t>(cl) * n[2] + iz);
    }
  } else {
    std::size_t mode = 0;
    for (int iz = 0; iz < n[2]; ++iz)
      for (int iy = 0; iy < n[1]; ++iy)
        for (int ix = 0; ix < nxh; ++ix) factors(ix, iy, iz, mode++);
  }
  green_lengths_ = box.lengths;
  box_ = box;
}

ParticleParticleParticleMesh::Result ParticleParticleParticleMesh::evaluate(const Eigen::Matrix3Xd& x, const Box& box,
                                                                            Eigen::Matrix3Xd* f) const {
  // (Messages built only on failure: an evaluation allocates nothing.)
  if (!is_kspace_box(box)) require_kspace_box(box, "force term '" + name() + "' (pppm)");
  const int count = static_cast<int>(charges_.size());
  if (x.cols() != count)
    throw std::invalid_argument("force term '" + name() + "' (pppm): " + std::to_string(x.cols()) + " particles, but " +
                                std::to_string(count) + " charges");
  if (!fft_ && !slabs_) build_mesh();  // from on_subset and never given processes, or released
  if (box.lengths != green_lengths_) influence_function(box);
  if (slabs_) return evaluate_slabs(x, box, f);
  Fftw& t = *fft_;
  const int* n = t.n;
  const int order = parameters_.order;
  const double g = parameters_.g_ewald;
  const double volume = box.lengths.prod();

  // 1. Charge assignment.
  const std::size_t stride[3] = {1, static_cast<std::size_t>(n[0]), static_cast<std::size_t>(n[0]) * n[1]};
  std::fill(t.density, t.density + t.real, 0.0);
  double own_charge = 0.0, own_q2 = 0.0;
  for (int i = 0; i < count; ++i) {
    const double q = charges_[i];
    own_charge += q;
    own_q2 += q * q;
    // The mesh points' offsets (folded, times the axis's stride) and weights per axis.
    std::size_t* offset = &offset_[3 * static_cast<std::size_t>(i) * order];
    double* w = &weight_[3 * static_cast<std::size_t>(i) * order];
    particle_stencil(x, i, box, n, order, stride, offset, w);
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
  const double total_charge = own_charge;
  const double total_q2 = own_q2;

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

  Result r;
  const double self = -qqrd2e_ * g / std::sqrt(kPi);
  const double background = -qqrd2e_ * kPi * total_charge / (2.0 * volume * g * g);
  r.energy = kspace + self * total_q2 + background * total_charge;
  for (int a = 0; a < 3; ++a) r.w[a] = w[a];
  return r;
}

ParticleParticleParticleMesh::Result ParticleParticleParticleMesh::evaluate_slabs(const Eigen::Matrix3Xd& x,
                                                                                  const Box& box,
                                                                                  Eigen::Matrix3Xd* f) const {
  Slabs& s = *slabs_;
  const Communicator& comm = *comm_;
  const int count = static_cast<int>(charges_.size());
  const int* n = s.n;
  const int nz = n[2], nxh = s.nxh, ranks = s.ranks, me = s.rank;
  const std::size_t plane = s.plane, row = s.row;
  const int order = parameters_.order;
  const double g = parameters_.g_ewald;
  const double volume = box.lengths.prod();
  traffic_ = Traffic{};
  auto grow = [&](std::vector<double>& v, std::size_t size) {
    if (size > v.capacity()) {
      ++traffic_.growths;
      v.reserve(size + size / 4);
    }
    v.resize(size);
  };
  auto exchange = [&](const Slabs::Buffers& send, Slabs::Buffers& recv) {
    for (int r = 0; r < ranks; ++r)
      if (r != me && !send[r].empty())
        ++traffic_.messages, traffic_.bytes += static_cast<long>(send[r].size() * sizeof(double));
    comm.exchange_known(send, recv);
  };

  // 1. Each particle's mesh points and weights (z: the plane, folded), the planes touched.
  const std::size_t stride[3] = {1, static_cast<std::size_t>(n[0]), 1};  // z: the plane's index
  std::fill(s.touched.begin(), s.touched.end(), 0);
  double own_charge = 0.0, own_q2 = 0.0;
  for (int i = 0; i < count; ++i) {
    const double q = charges_[i];
    own_charge += q;
    own_q2 += q * q;
    std::size_t* offset = &offset_[3 * static_cast<std::size_t>(i) * order];
    double* w = &weight_[3 * static_cast<std::size_t>(i) * order];
    particle_stencil(x, i, box, n, order, stride, offset, w);
    if (q != 0.0)
      for (int j = 0; j < order; ++j) s.touched[offset[2 * order + j]] = 1;
  }

  // 2. The windows: every rank's, by one sum; where each of this rank's window planes goes, and
  // what this rank receives from each.
  int lo = 0, width = 0;
  circular_window(s.touched, lo, width);
  traffic_.window_planes = width;
  std::fill(s.windows.begin(), s.windows.end(), 0);
  s.windows[2 * me] = lo, s.windows[2 * me + 1] = width;
  comm.sum(s.windows.data(), 2 * ranks);
  ++traffic_.reductions;
  std::fill(s.per_owner.begin(), s.per_owner.end(), 0);
  for (int j = 0; j < width; ++j) {
    const int o = s.owner[(lo + j) % nz];
    s.window_owner[j] = o;
    s.window_index[j] = s.per_owner[o]++;
  }
  for (int o = 0; o < ranks; ++o) {
    const std::size_t planes = o == me ? 0 : s.per_owner[o];
    grow(s.spread_send[o], planes * plane);
    grow(s.field_recv[o], 3 * planes * plane);
  }
  grow(s.own_charges, s.per_owner[me] * plane);
  s.charge_plane.resize(width);
  s.field_plane.resize(3 * static_cast<std::size_t>(width));
  for (int j = 0; j < width; ++j) {
    const int o = s.window_owner[j];
    const std::size_t k = s.window_index[j];
    s.charge_plane[j] = (o == me ? s.own_charges.data() : s.spread_send[o].data()) + k * plane;
    for (int a = 0; a < 3; ++a)
      s.field_plane[3 * j + a] =
          o == me ? s.real + (a * s.pz + ((lo + j) % nz - s.z0)) * plane : s.field_recv[o].data() + (3 * k + a) * plane;
  }
  for (int r = 0; r < ranks; ++r) {
    const int lo_r = static_cast<int>(s.windows[2 * r]), width_r = static_cast<int>(s.windows[2 * r + 1]);
    std::size_t mine = 0;
    for (int j = 0; j < width_r && r != me; ++j) mine += s.owner[(lo_r + j) % nz] == me;
    grow(s.spread_recv[r], mine * plane);
    grow(s.field_send[r], 3 * mine * plane);
  }

  // 3. Charge assignment into the window (z now the window's plane), sent to the planes' owners,
  // who add the ranks' charges in rank order.
  for (std::vector<double>& b : s.spread_send) std::fill(b.begin(), b.end(), 0.0);
  std::fill(s.own_charges.begin(), s.own_charges.end(), 0.0);
  for (int i = 0; i < count; ++i) {
    const double q = charges_[i];
    if (q == 0.0) continue;
    std::size_t* offset = &offset_[3 * static_cast<std::size_t>(i) * order];
    const double* w = &weight_[3 * static_cast<std::size_t>(i) * order];
    for (int j = 0; j < order; ++j) offset[2 * order + j] = (offset[2 * order + j] + nz - lo) % nz;
    for (int jz = 0; jz < order; ++jz) {
      const double wz = q * w[2 * order + jz];
      for (int jy = 0; jy < order; ++jy) {
        const double wyz = wz * w[order + jy];
        double* line = s.charge_plane[offset[2 * order + jz]] + offset[order + jy];
        for (int jx = 0; jx < order; ++jx) line[offset[jx]] += wyz * w[jx];
      }
    }
  }
  exchange(s.spread_send, s.spread_recv);
  std::fill(s.real, s.real + s.pz * plane, 0.0);
  for (int r = 0; r < ranks; ++r) {
    const int lo_r = static_cast<int>(s.windows[2 * r]), width_r = static_cast<int>(s.windows[2 * r + 1]);
    const double* in = r == me ? s.own_charges.data() : s.spread_recv[r].data();
    for (int j = 0; j < width_r; ++j) {
      const int z = (lo_r + j) % nz;
      if (s.owner[z] != me) continue;
      double* out = s.real + (z - s.z0) * plane;
      for (std::size_t m = 0; m < plane; ++m) out[m] += in[m];
      in += plane;
    }
  }

  // 4. ρ̂: the owned planes' 2D transforms, the transpose (each rank its columns, whole along z),
  // the columns' transforms.
  if (s.forward_planes) fftw_execute(s.forward_planes);
  for (int t = 0; t < ranks; ++t) {
    if (t == me) continue;
    double* out = s.forward_send[t].data();
    const int c_t = s.c_first[t], pc_t = s.c_first[t + 1] - c_t;
    for (int lz = 0; lz < s.pz; ++lz) {
      const fftw_complex* in = s.spectra + lz * row + c_t;
      for (int c = 0; c < pc_t; ++c) *out++ = in[c][0], *out++ = in[c][1];
    }
  }
  exchange(s.forward_send, s.forward_recv);
  for (int lz = 0; lz < s.pz; ++lz)  // this rank's planes of its own columns
    for (int cl = 0; cl < s.pc; ++cl) {
      const fftw_complex& in = s.spectra[lz * row + s.c0 + cl];
      fftw_complex& v = s.rho[static_cast<std::size_t>(cl) * nz + s.z0 + lz];
      v[0] = in[0], v[1] = in[1];
    }
  for (int t = 0; t < ranks; ++t) {
    if (t == me) continue;
    const double* in = s.forward_recv[t].data();
    for (int z = s.z_first[t]; z < s.z_first[t + 1]; ++z)
      for (int cl = 0; cl < s.pc; ++cl, in += 2) {
        fftw_complex& v = s.rho[static_cast<std::size_t>(cl) * nz + z];
        v[0] = in[0], v[1] = in[1];
      }
  }
  if (s.forward_columns) fftw_execute(s.forward_columns);

  // 5. The energy and virial over this rank's modes, each with ix ∉ {0, n_x/2} standing for itself
  // and its mirror image; then over the ranks, with the charges' sums.
  double sums[6] = {0.0, 0.0, 0.0, 0.0, own_charge, own_q2};
  for (int cl = 0; cl < s.pc; ++cl) {
    const int ix = (s.c0 + cl) % nxh;
    const double times = (ix == 0 || 2 * ix == n[0]) ? 1.0 : 2.0;
    for (int iz = 0; iz < nz; ++iz) {
      const std::size_t mode = static_cast<std::size_t>(cl) * nz + iz;
      const double e = times * green_[mode] * (s.rho[mode][0] * s.rho[mode][0] + s.rho[mode][1] * s.rho[mode][1]);
      sums[0] += e;
      for (int a = 0; a < 3; ++a) sums[1 + a] += e * virial_factor_[3 * mode + a];
    }
  }
  comm.sum(sums, 6);
  ++traffic_.reductions;
  const double c = qqrd2e_ / volume;
  const double kspace = 0.5 * c * sums[0];
  const double total_charge = sums[4], total_q2 = sums[5];
  const double background_total = -qqrd2e_ * kPi * total_charge * total_charge / (2.0 * volume * g * g);
  double w[3];
  for (int a = 0; a < 3; ++a) w[a] = 0.5 * c * sums[1 + a] + background_total;

  // 6. The field (C/V) (−i k_a) G ρ̂ on this rank's columns, transformed back along z, the transpose
  // back, the owned planes' inverse 2D transforms; each window plane's field to the ranks whose
  // windows hold it, and the forces on this rank's particles from its window.
  if (f) {
    for (int a = 0; a < 3; ++a)
      for (int cl = 0; cl < s.pc; ++cl) {
        const int col = s.c0 + cl, ix = col % nxh, iy = col / nxh;
        for (int iz = 0; iz < nz; ++iz) {
          const std::size_t mode = static_cast<std::size_t>(cl) * nz + iz;
          const double scale = c * green_[mode];
          const int j = a == 0 ? ix : a == 1 ? iy : iz;
          const double k = 2 * j == n[a] ? 0.0 : wavenumber_[a][static_cast<std::size_t>(j)];
          fftw_complex& out = s.field[static_cast<std::size_t>(a) * s.pc * nz + mode];
          out[0] = scale * k * s.rho[mode][1];
          out[1] = -scale * k * s.rho[mode][0];
        }
      }
    if (s.backward_columns) fftw_execute(s.backward_columns);
    for (int t = 0; t < ranks; ++t) {
      if (t == me) continue;
      double* out = s.backward_send[t].data();
      for (int a = 0; a < 3; ++a)
        for (int z = s.z_first[t]; z < s.z_first[t + 1]; ++z)
          for (int cl = 0; cl < s.pc; ++cl) {
            const fftw_complex& v = s.field[(static_cast<std::size_t>(a) * s.pc + cl) * nz + z];
            *out++ = v[0], *out++ = v[1];
          }
    }
    exchange(s.backward_send, s.backward_recv);
    for (int a = 0; a < 3; ++a)
      for (int lz = 0; lz < s.pz; ++lz)
        for (int cl = 0; cl < s.pc; ++cl) {
          const fftw_complex& in = s.field[(static_cast<std::size_t>(a) * s.pc + cl) * nz + s.z0 + lz];
          fftw_complex& out = s.spectra[(static_cast<std::size_t>(a) * s.pz + lz) * row + s.c0 + cl];
          out[0] = in[0], out[1] = in[1];
        }
    for (int t = 0; t < ranks; ++t) {
      if (t == me) continue;
      const double* in = s.backward_recv[t].data();
      const int c_t = s.c_first[t], pc_t = s.c_first[t + 1] - c_t;
      for (int a = 0; a < 3; ++a)
        for (int lz = 0; lz < s.pz; ++lz) {
          fftw_complex* out = s.spectra + (static_cast<std::size_t>(a) * s.pz + lz) * row + c_t;
          for (int cc = 0; cc < pc_t; ++cc, in += 2) out[cc][0] = in[0], out[cc][1] = in[1];
        }
    }
    if (s.backward_planes) fftw_execute(s.backward_planes);
    for (int r = 0; r < ranks; ++r) {
      const int lo_r = static_cast<int>(s.windows[2 * r]), width_r = static_cast<int>(s.windows[2 * r + 1]);
      if (r == me) continue;  // read in place
      double* out = s.field_send[r].data();
      for (int j = 0; j < width_r; ++j) {
        const int z = (lo_r + j) % nz;
        if (s.owner[z] != me) continue;
        for (int a = 0; a < 3; ++a, out += plane) {
          const double* in = s.real + (static_cast<std::size_t>(a) * s.pz + (z - s.z0)) * plane;
          std::copy(in, in + plane, out);
        }
      }
    }
    exchange(s.field_send, s.field_recv);
    for (int i = 0; i < count; ++i) {
      const double q = charges_[i];
      if (q == 0.0) continue;
      const std::size_t* offset = &offset_[3 * static_cast<std::size_t>(i) * order];
      const double* wt = &weight_[3 * static_cast<std::size_t>(i) * order];
      double ex = 0.0, ey = 0.0, ez = 0.0;
      for (int jz = 0; jz < order; ++jz) {
        const double* const* field = &s.field_plane[3 * offset[2 * order + jz]];
        const double *fx = field[0], *fy = field[1], *fz = field[2];
        for (int jy = 0; jy < order; ++jy) {
          const double wyz = wt[2 * order + jz] * wt[order + jy];
          const std::size_t line = offset[order + jy];
          for (int jx = 0; jx < order; ++jx) {
            const std::size_t m = line + offset[jx];
            const double wm = wyz * wt[jx];
            ex += wm * fx[m];
            ey += wm * fy[m];
            ez += wm * fz[m];
          }
        }
      }
      (*f)(0, i) += q * ex;
      (*f)(1, i) += q * ey;
      (*f)(2, i) += q * ez;
    }
  }

  // Every rank has the whole energy and virial: each returns 1/size of them, so that the shares
  // add up to the whole system's.
  Result r;
  const double self = -qqrd2e_ * g / std::sqrt(kPi);
  const double background = -qqrd2e_ * kPi * total_charge / (2.0 * volume * g * g);
  const double share = 1.0 / ranks;
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
  std::vector<double> q = subset_charges(subset, charges_, "force term '" + name() + "' (pppm)");
  // No mesh yet: the part is given its processes next (set_processes), which builds its share.
  return std::unique_ptr<ParticleParticleParticleMesh>(
      new ParticleParticleParticleMesh(Deferred{}, name(), level(), std::move(q), parameters_, qqrd2e_, box, comm_));
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
