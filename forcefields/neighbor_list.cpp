#include "forcefields/neighbor_list.hpp"

#include <algorithm>
#include <compare>
#include <sstream>
#include <stdexcept>
#include <string>

namespace stiffmd {
namespace {

constexpr char kAxis[3] = {'x', 'y', 'z'};

bool same_box(const Box& a, const Box& b) {
  return a.periodic == b.periodic && a.lengths == b.lengths && a.origin == b.origin;
}

// Cell coordinate of a scaled coordinate s ∈ [0, n], clamped into 0 … n − 1. Written so that
// NaN (a blown-up configuration) lands in cell 0 instead of an out-of-range index: the engine
// reports non-finite states itself, the list must only not write out of bounds.
int cell_coordinate(double s, int n) {
  if (s >= 0.0 && s < n) return static_cast<int>(s);
  return s >= n ? n - 1 : 0;
}

}  // namespace

void check_box_for_cutoff(const Box& box, double cutoff, double skin) {
  const double need = 2.0 * (cutoff + skin);
  for (int a = 0; a < 3; ++a) {
    if (!box.periodic[a]) continue;
    const double len = box.lengths[a];
    if (!(len >= need) || !std::isfinite(len)) {
      std::ostringstream s;
      s << "periodic box length L = " << len << " on axis " << kAxis[a] << ": box length L < 2 × (cutoff + skin) = 2 × ("
        << cutoff << " + " << skin << ") = " << need
        << ", so the minimum image is ambiguous; enlarge the box or reduce the cutoff or skin";
      throw std::invalid_argument(s.str());
    }
  }
}

std::vector<SpecialPair> special_pairs(int num_particles, const std::vector<Bond>& bonds, SpecialWeights w) {
  if (num_particles < 0) throw std::invalid_argument("special_pairs: negative particle count");
  // Bonded partners per particle (CSR), to walk 1-2 and then 1-3 neighbours.
  std::vector<int> deg(static_cast<std::size_t>(num_particles) + 1, 0);
  for (const Bond& b : bonds) {
    if (b.i < 0 || b.i >= num_particles || b.j < 0 || b.j >= num_particles) {
      std::ostringstream s;
      s << "bond (" << b.i << ", " << b.j << ") refers to a particle outside 0 … " << num_particles - 1;
      throw std::invalid_argument(s.str());
    }
    if (b.i == b.j) throw std::invalid_argument("bond (" + std::to_string(b.i) + ", " + std::to_string(b.j) + ") joins a particle to itself");
    ++deg[b.i + 1];
    ++deg[b.j + 1];
  }
  for (int i = 0; i < num_particles; ++i) deg[i + 1] += deg[i];
  std::vector<int> partner(deg.back()), fill(deg.begin(), deg.end() - 1);
  for (const Bond& b : bonds) {
    partner[fill[b.i]++] = b.j;
    partner[fill[b.j]++] = b.i;
  }

  // Every 1-2 and 1-3 relation, tagged with its distance along the bonds; after sorting, the
  // first entry of a pair is its closest relation (1-2 before 1-3), whose weight it takes.
  struct Relation {
    int i, j, bonds_apart;
    auto operator<=>(const Relation&) const = default;
  };
  std::vector<Relation> rel;
  for (const Bond& b : bonds) rel.push_back({std::min(b.i, b.j), std::max(b.i, b.j), 1});
  for (int k = 0; k < num_particles; ++k)
    for (int p = deg[k]; p < deg[k + 1]; ++p)
      for (int q = p + 1; q < deg[k + 1]; ++q)  // both bonded to k: 1-3 through k
        if (partner[p] != partner[q])
          rel.push_back({std::min(partner[p], partner[q]), std::max(partner[p], partner[q]), 2});
  std::sort(rel.begin(), rel.end());

  std::vector<SpecialPair> out;
  for (std::size_t r = 0; r < rel.size(); ++r) {
    if (r > 0 && rel[r].i == rel[r - 1].i && rel[r].j == rel[r - 1].j) continue;
    const double weight = rel[r].bonds_apart == 1 ? w.w12 : w.w13;
    if (weight != 1.0) out.push_back({rel[r].i, rel[r].j, weight});  // weight 1: an ordinary pair
  }
  return out;
}

NeighborList::NeighborList(double cutoff, double skin) : cutoff_(cutoff), skin_(skin) {
  if (!(cutoff > 0.0) || !std::isfinite(cutoff)) throw std::invalid_argument("neighbour list: cutoff must be finite and > 0");
  if (!(skin >= 0.0) || !std::isfinite(skin)) throw std::invalid_argument("neighbour list: skin must be finite and >= 0");
}

void NeighborList::set_exclusions(int num_particles, std::span<const SpecialPair> pairs) {
  excl_particles_ = num_particles;
  excl_offsets_.assign(static_cast<std::size_t>(num_particles) + 1, 0);
  for (const SpecialPair& p : pairs) {
    if (p.i < 0 || p.j < 0 || p.i >= num_particles || p.j >= num_particles)
      throw std::invalid_argument("neighbour list: excluded pair refers to a particle out of range");
    ++excl_offsets_[p.i + 1];
    ++excl_offsets_[p.j + 1];
  }
  for (int i = 0; i < num_particles; ++i) excl_offsets_[i + 1] += excl_offsets_[i];
  excl_.assign(excl_offsets_.back(), 0);
  std::vector<int> fill(excl_offsets_.begin(), excl_offsets_.end() - 1);
  for (const SpecialPair& p : pairs) {
    excl_[fill[p.i]++] = p.j;
    excl_[fill[p.j]++] = p.i;
  }
  for (int i = 0; i < num_particles; ++i) std::sort(excl_.begin() + excl_offsets_[i], excl_.begin() + excl_offsets_[i + 1]);
  built_ = false;
}

bool NeighborList::excluded(int i, int j) const {
  // Rows hold a handful of bonded neighbours: a linear scan beats a search.
  for (int k = excl_offsets_[i]; k < excl_offsets_[i + 1]; ++k)
    if (excl_[k] == j) return true;
  return false;
}

bool NeighborList::needs_rebuild(const Eigen::Matrix3Xd& x, const Box& box) const {
  if (!built_ || x.cols() != x_at_build_.cols() || !same_box(box, box_at_build_)) return true;
  // Raw (unwrapped) displacements: the engine never wraps positions, and if something did, the
  // jump of a box length would only cause an early rebuild.
  const double limit2 = 0.25 * skin_ * skin_;
  const double* xp = x.data();
  const double* x0 = x_at_build_.data();
  const Eigen::Index n = x.cols();
  for (Eigen::Index i = 0; i < n; ++i) {
    const double dx = xp[3 * i] - x0[3 * i], dy = xp[3 * i + 1] - x0[3 * i + 1], dz = xp[3 * i + 2] - x0[3 * i + 2];
    if (dx * dx + dy * dy + dz * dz > limit2) return true;
  }
  return false;
}

bool NeighborList::update(const Eigen::Matrix3Xd& x, const Box& box) {
  if (!needs_rebuild(x, box)) return false;
  build(x, box);
  return true;
}

void NeighborList::bin(const Eigen::Matrix3Xd& x, const Box& box) {
  const int n = static_cast<int>(x.cols());
  const double width = cutoff_ + skin_;

  // Binned extent per axis: the box on periodic axes (coordinates wrapped into it), the
  // particles' bounding box on open ones.
  double lo[3], len[3];
  for (int a = 0; a < 3; ++a) {
    if (box.periodic[a]) {
      lo[a] = box.origin[a];
      len[a] = box.lengths[a];
    } else if (n == 0) {
      lo[a] = len[a] = 0.0;
    } else {
      const double mn = x.row(a).minCoeff(), mx = x.row(a).maxCoeff();
      lo[a] = mn;
      len[a] = mx - mn;
    }
  }

  // Cells at least `width` wide, so that every pair within the list radius lies in the same or
  // adjacent cells. Sparse or spread-out systems (open boxes, a few particles in a big box) get
  // wider cells: at most ~2 cells per particle, so memory and the stencil walk stay O(N).
  const double max_cells = std::max(27.0, 2.0 * n);
  double want[3];
  for (int a = 0; a < 3; ++a) want[a] = len[a] > width ? std::min(std::floor(len[a] / width), max_cells) : 1.0;
  while (want[0] * want[1] * want[2] > max_cells) {
    const int a = static_cast<int>(std::max_element(want, want + 3) - want);
    want[a] = std::max(1.0, std::floor(want[a] / 2.0));
  }
  for (int a = 0; a < 3; ++a) ncell_[a] = static_cast<int>(want[a]);
  const int ncells = ncell_[0] * ncell_[1] * ncell_[2];

  double inv_len[3];
  for (int a = 0; a < 3; ++a) inv_len[a] = len[a] > 0.0 ? 1.0 / len[a] : 0.0;
  cell_of_.resize(n);
  wrapped_x_.resize(3, n);
  cell_start_.assign(static_cast<std::size_t>(ncells) + 1, 0);
  for (int i = 0; i < n; ++i) {
    int c[3];
    for (int a = 0; a < 3; ++a) {
      double s = (x(a, i) - lo[a]) * inv_len[a];
      if (box.periodic[a]) {
        s -= std::floor(s);  // positions are unwrapped: bin the image inside the box
        wrapped_x_(a, i) = lo[a] + s * len[a];
      } else {
        wrapped_x_(a, i) = x(a, i);
      }
      c[a] = cell_coordinate(s * ncell_[a], ncell_[a]);
    }
    const int cell = (c[0] * ncell_[1] + c[1]) * ncell_[2] + c[2];
    cell_of_[i] = cell;
    ++cell_start_[cell + 1];
  }
  for (int c = 0; c < ncells; ++c) cell_start_[c + 1] += cell_start_[c];
  cell_particles_.resize(n);
  cell_x_.resize(3, n);
  // Counting sort in increasing i keeps each cell's particles in increasing index: fill
  // through a cursor held in cell_start_, then shift the starts back.
  for (int i = 0; i < n; ++i) {
    const int k = cell_start_[cell_of_[i]]++;
    cell_particles_[k] = i;
    cell_x_.col(k) = wrapped_x_.col(i);
  }
  for (int c = ncells; c > 0; --c) cell_start_[c] = cell_start_[c - 1];
  cell_start_[0] = 0;

  needs_rounding_ = false;
  for (int a = 0; a < 3; ++a) {
    const int m = ncell_[a];
    if (box.periodic[a] && m < 3) needs_rounding_ = true;
    stencil_[a].resize(3 * static_cast<std::size_t>(m));
    stencil_shift_[a].resize(3 * static_cast<std::size_t>(m));
    stencil_count_[a].resize(m);
    for (int c = 0; c < m; ++c) {
      int* slot = &stencil_[a][3 * c];
      double* shift = &stencil_shift_[a][3 * c];
      int k = 0;
      for (int o = -1; o <= 1; ++o) {
        int cc = c + o;
        double sh = 0.0;
        if (box.periodic[a]) {
          if (cc < 0) sh = -len[a];  // cell m − 1 seen from cell 0: its image below the box
          if (cc >= m) sh = len[a];
          cc = (cc + m) % m;
        } else if (cc < 0 || cc >= m) {
          continue;
        }
        // With fewer than 3 cells a periodic axis wraps onto itself: visit each cell once,
        // or pairs would be listed twice.
        if (std::find(slot, slot + k, cc) == slot + k) {
          slot[k] = cc;
          shift[k++] = sh;
        }
      }
      stencil_count_[a][c] = k;
    }
  }
}

template <bool kRound>
void NeighborList::search(int n, const MinimumImage& mi, bool have_exclusions) {
  const double rlist2 = (cutoff_ + skin_) * (cutoff_ + skin_);
  const double* xw = wrapped_x_.data();
  const double* xc = cell_x_.data();
  const int* cp = cell_particles_.data();
  const int* cs = cell_start_.data();
  const int ny = ncell_[1], nz = ncell_[2];
  offsets_.resize(static_cast<std::size_t>(n) + 1);
  offsets_[0] = 0;
  neighbors_.clear();  // keeps its capacity
  for (int i = 0; i < n; ++i) {
    const int cell = cell_of_[i];
    const int cx = cell / (ny * nz), cy = (cell / nz) % ny, cz = cell % nz;
    const bool may_exclude = have_exclusions && excl_offsets_[i + 1] > excl_offsets_[i];
    for (int sx = 0; sx < stencil_count_[0][cx]; ++sx) {
      const int gx = stencil_[0][3 * cx + sx];
      const double xi = xw[3 * i] - stencil_shift_[0][3 * cx + sx];  // d = x_i − (x_j + shift)
      for (int sy = 0; sy < stencil_count_[1][cy]; ++sy) {
        const int gy = stencil_[1][3 * cy + sy];
        const double yi = xw[3 * i + 1] - stencil_shift_[1][3 * cy + sy];
        for (int sz = 0; sz < stencil_count_[2][cz]; ++sz) {
          const int c = (gx * ny + gy) * nz + stencil_[2][3 * cz + sz];
          const double zi = xw[3 * i + 2] - stencil_shift_[2][3 * cz + sz];
          // Half list, j > i only (the pair is found again from j's side otherwise): a cell's
          // particles are in increasing index, so those are a suffix of its range.
          for (int k = cs[c + 1] - 1; k >= cs[c] && cp[k] > i; --k) {
            const int j = cp[k];
            double dx = xi - xc[3 * k], dy = yi - xc[3 * k + 1], dz = zi - xc[3 * k + 2];
            if constexpr (kRound) mi.apply(dx, dy, dz);
            if (dx * dx + dy * dy + dz * dz < rlist2 && !(may_exclude && excluded(i, j))) neighbors_.push_back(j);
          }
        }
      }
    }
    // Ascending j within a row: the force loop then walks x and f forward in memory.
    std::sort(neighbors_.begin() + offsets_[i], neighbors_.end());
    offsets_[i + 1] = static_cast<std::int64_t>(neighbors_.size());
  }
}

void NeighborList::build(const Eigen::Matrix3Xd& x, const Box& box) {
  check_box_for_cutoff(box, cutoff_, skin_);
  const int n = static_cast<int>(x.cols());
  const bool have_exclusions = !excl_.empty();
  if (have_exclusions && excl_particles_ != n) {
    std::ostringstream s;
    s << "neighbour list: exclusions were set for " << excl_particles_ << " particles, positions have " << n;
    throw std::invalid_argument(s.str());
  }
  bin(x, box);
  if (needs_rounding_)
    search<true>(n, MinimumImage(box), have_exclusions);
  else
    search<false>(n, MinimumImage(box), have_exclusions);

  x_at_build_ = x;  // same size after the first build: Eigen reuses the storage
  box_at_build_ = box;
  built_ = true;
  ++rebuilds_;
}

}  // namespace stiffmd
