#include "engine/domain/decomposition.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <numeric>
#include <sstream>

#include <stdexcept>
#include "core/disjoint_sets.hpp"
#include "core/errors.hpp"
#include "core/timing.hpp"
#include "forcefields/neighbor_list.hpp"  // MinimumImage

namespace stiffmd {

namespace {

constexpr double kInf = std::numeric_limits<double>::infinity();

// p wrapped into [origin, origin + L) on a periodic axis.
double wrap(double p, double origin, double length, bool periodic) {
  return periodic ? p - length * std::floor((p - origin) / length) : p;
}

}  // namespace

bool DomainGrid::within(int domain, const Eigen::Vector3d& p, double slack) const {
  const int index[3] = {domain / (dims[1] * dims[2]), (domain / dims[2]) % dims[1], domain % dims[2]};
  for (int a = 0; a < 3; ++a) {
    const double width = length[a] / dims[a], lo = origin[a] + index[a] * width, hi = lo + width;
    double q = periodic[a] ? wrap(p[a], origin[a], length[a], true) : p[a];
    if (periodic[a] && q > hi + slack) q -= length[a];  // the image nearest the domain
    if (periodic[a] && q < lo - slack) q += length[a];
    if (q < lo - slack || q > hi + slack) return false;
  }
  return true;
}

int DomainGrid::domain_of(const Eigen::Vector3d& p) const {
  int index[3];
  for (int a = 0; a < 3; ++a) {
    const double q = wrap(p[a], origin[a], length[a], periodic[a] != 0);
    const int c = static_cast<int>(std::floor((q - origin[a]) / length[a] * dims[a]));
    index[a] = std::clamp(c, 0, dims[a] - 1);
  }
  return (index[0] * dims[1] + index[1]) * dims[2] + index[2];
}

DomainGrid make_domain_grid(const Box& box, int ranks, const Eigen::Vector3i* dims, const Eigen::Matrix3Xd& anchors) {
  DomainGrid g;
  g.periodic = box.periodic;
  for (int a = 0; a < 3; ++a) {
    if (box.periodic[a]) {
      g.origin[a] = box.origin[a], g.length[a] = box.lengths[a];
    } else {  // the anchors' extent at the start, a little wider so that the last one is inside
      const double lo = anchors.cols() ? anchors.row(a).minCoeff() : 0.0;
      const double hi = anchors.cols() ? anchors.row(a).maxCoeff() : 1.0;
      g.origin[a] = lo, g.length[a] = std::max(hi - lo, 1.0) * (1.0 + 1e-9);
    }
  }
  if (dims) {
    if (dims->prod() != ranks) throw std::invalid_argument("the domain grid does not have one domain per rank");
    g.dims = *dims;
    return g;
  }
  // The cut surface Σ_a (p_a − 1) A_a (A_a the box's section across axis a) is what the ghosts
  // grow with: the least of it over the factorisations, open axes cut only when no periodic one is.
  const bool any_periodic = box.periodic.any();
  double best = kInf;
  for (int px = 1; px <= ranks; ++px)
    for (int py = 1; px * py <= ranks; ++py) {
      if (ranks % (px * py) != 0) continue;
      const Eigen::Vector3i p(px, py, ranks / (px * py));
      double surface = 0.0;
      for (int a = 0; a < 3; ++a) {
        const double section = g.length[(a + 1) % 3] * g.length[(a + 2) % 3];
        const double penalty = (any_periodic && !box.periodic[a] && p[a] > 1) ? 1e6 : 1.0;
        surface += (p[a] - 1) * section * penalty;
      }
      if (surface < best) best = surface, g.dims = p;
    }
  return g;
}

Decomposition::Decomposition(const Topology& topology, const Eigen::VectorXd& inv_mass, const Box& box,
                             const Communicator& comm, double cutoff, double margin, const Eigen::Vector3i* dims)
    : comm_(comm), box_(box), mass_(inv_mass.size()), radius_(cutoff + margin), margin_(margin) {
  const int n = static_cast<int>(inv_mass.size());
  for (int i = 0; i < n; ++i) mass_[i] = inv_mass[i] > 0.0 ? 1.0 / inv_mass[i] : 1.0;
  // Molecules (bonded_molecules): pinned particles join too (a term acts on all its particles), so a
  // molecule may hold several constraint clusters (integrators/clusters.hpp).
  molecule_ = bonded_molecules(topology, n);
  int molecules = 0;
  for (int m : molecule_) molecules = std::max(molecules, m + 1);
  molecule_start_.assign(molecules + 1, 0);
  for (int i = 0; i < n; ++i) ++molecule_start_[molecule_[i] + 1];
  for (int m = 0; m < molecules; ++m) molecule_start_[m + 1] += molecule_start_[m];
  molecule_particles_.resize(n);
  std::vector<int> next(molecule_start_.begin(), molecule_start_.end() - 1);
  for (int i = 0; i < n; ++i) molecule_particles_[next[molecule_[i]]++] = i;  // increasing within each
  if (dims) grid_dims_ = *dims, have_dims_ = true;
  owned_of_.assign(n, -1);
  const int ranks = comm_.size();
  send_.resize(ranks);
  ghost_begin_.assign(ranks, 0);
  ghost_count_.assign(ranks, 0);
  send_buffer_.resize(ranks);
  recv_buffer_.resize(ranks);
}

namespace {

// Cells at least R wide over the box (periodic axes) or over the beads' extent (open axes): two
// beads closer than R sit in the same or adjacent cells (per axis, periodically on a periodic
// axis), so the beads within R of a set of beads lie in the cells adjacent to theirs.
struct HaloCells {
  int n[3] = {1, 1, 1};
  double lo[3] = {0, 0, 0}, width[3] = {1, 1, 1}, length[3] = {0, 0, 0};
  bool periodic[3] = {false, false, false};

  std::int64_t size() const { return static_cast<std::int64_t>(n[0]) * n[1] * n[2]; }
  // q: a coordinate wrapped into the box on a periodic axis (BoxWrap).
  int coordinate(double q, int a) const {
    return std::clamp(static_cast<int>(std::floor((q - lo[a]) / width[a])), 0, n[a] - 1);
  }
  std::int64_t index(const double* q) const {
    return (static_cast<std::int64_t>(coordinate(q[0], 0)) * n[1] + coordinate(q[1], 1)) * n[2] + coordinate(q[2], 2);
  }
  // Per axis and cell coordinate, the distinct coordinates within one cell of it (periodically on
  // a periodic axis): around[a][4 c] is their count, the next three the coordinates.
  std::vector<int> around[3];
  void tabulate() {
    for (int a = 0; a < 3; ++a) {
      around[a].assign(4 * static_cast<size_t>(n[a]), 0);
      for (int c = 0; c < n[a]; ++c) {
        int* out = around[a].data() + 4 * c;
        for (int d = -1; d <= 1; ++d) {
          int q = c + d;
          if (periodic[a])
            q = (q + n[a]) % n[a];
          else if (q < 0 || q >= n[a])
            continue;
          if (std::find(out + 1, out + 1 + out[0], q) == out + 1 + out[0]) out[1 + out[0]++] = q;
        }
      }
    }
  }
  // The cells adjacent to cell c (itself included), each once (after tabulate).
  template <class F>
  void for_each_adjacent(std::int64_t c, F f) const {
    const int c2 = static_cast<int>(c % n[2]), c1 = static_cast<int>((c / n[2]) % n[1]),
              c0 = static_cast<int>(c / (static_cast<std::int64_t>(n[2]) * n[1]));
    const int *a0 = around[0].data() + 4 * c0, *a1 = around[1].data() + 4 * c1, *a2 = around[2].data() + 4 * c2;
    for (int i = 1; i <= a0[0]; ++i)
      for (int j = 1; j <= a1[0]; ++j) {
        const std::int64_t row = (static_cast<std::int64_t>(a0[i]) * n[1] + a1[j]) * n[2];
        for (int l = 1; l <= a2[0]; ++l) f(row + a2[l]);
      }
  }
};

// Whether two intervals (each within a box length of the box on a periodic axis) come closer
// than r, over the periodic images of the second.
bool intervals_within(double lo1, double hi1, double lo2, double hi2, double r, double length, bool periodic) {
  if (lo1 > hi1 || lo2 > hi2) return false;
  const auto gap = [&](double shift) { return std::max({0.0, lo2 + shift - hi1, lo1 - hi2 - shift}); };
  if (!periodic) return gap(0.0) < r;
  return std::min({gap(-length), gap(0.0), gap(length)}) < r;
}

}  // namespace

bool Decomposition::owns_molecule(int m) const {
  return std::binary_search(owned_.begin(), owned_.end(), m);
}

Eigen::Vector3d Decomposition::anchor(const Eigen::Matrix3Xd& x, std::span<const int> global,
                                      bool owned_columns) const {
  // The centre of mass of a whole molecule (unwrapped: its bonds are their own minimum images).
  Eigen::Vector3d c = Eigen::Vector3d::Zero();
  double total = 0.0;
  for (int g : global) {
    c += mass_[g] * x.col(owned_columns ? owned_of_[g] : g);
    total += mass_[g];
  }
  return c / total;
}

void Decomposition::set_box(const Box& box) {
  box_ = box;
  for (int a = 0; a < 3; ++a)
    if (box.periodic[a]) grid_.origin[a] = box.origin[a], grid_.length[a] = box.lengths[a];
}

void Decomposition::own(std::vector<int> molecules) {
  for (int g : ids_) owned_of_[g] = -1;
  owned_ = std::move(molecules);
  std::sort(owned_.begin(), owned_.end());
  ids_.clear();
  for (int m : owned_)
    for (int g : molecule(m)) ids_.push_back(g);
  std::sort(ids_.begin(), ids_.end());
  for (int k = 0; k < static_cast<int>(ids_.size()); ++k) owned_of_[ids_[k]] = k;
}

void Decomposition::distribute(const State& whole, Eigen::Matrix3Xd& x, Eigen::Matrix3Xd& v) {
  const int molecules = num_molecules();
  Eigen::Matrix3Xd anchors(3, molecules);
  for (int m = 0; m < molecules; ++m) anchors.col(m) = anchor(whole.x, molecule(m), false);
  grid_ = make_domain_grid(box_, comm_.size(), have_dims_ ? &grid_dims_ : nullptr, anchors);
  std::vector<int> mine;
  for (int m = 0; m < molecules; ++m)
    if (grid_.domain_of(anchors.col(m)) == comm_.rank()) mine.push_back(m);
  own(std::move(mine));
  x.resize(3, num_owned());
  v.resize(3, num_owned());
  for (int k = 0; k < num_owned(); ++k) x.col(k) = whole.x.col(ids_[k]), v.col(k) = whole.v.col(ids_[k]);
}

bool Decomposition::migrate(Eigen::Matrix3Xd& x, Eigen::Matrix3Xd& v, std::vector<Eigen::Matrix3Xd*> carried) {
  const ScopedPhase phase(Phase::domain);
  const int ranks = comm_.size(), me = comm_.rank();
  const int words = 6 + 3 * static_cast<int>(carried.size());  // per particle: x, v, the carried columns
  // A molecule leaves when its anchor is past this rank's domain by more than the margin (at most a
  // quarter of the domain's narrowest width): an anchor near a face does not go back and forth
  // (each move rebuilds two ranks' parts), nor does a wide margin keep molecules far from home.
  double slack = margin_;
  for (int a = 0; a < 3; ++a) slack = std::min(slack, 0.25 * grid_.length[a] / grid_.dims[a]);
  std::vector<std::vector<double>> out(ranks), in;
  std::vector<int> kept;
  for (int m : owned_) {
    const Eigen::Vector3d c = anchor(x, molecule(m), true);
    const int to = grid_.domain_of(c);
    if (to == me || grid_.within(me, c, slack)) {
      kept.push_back(m);
      continue;
    }
    ++migrated_;
    std::vector<double>& o = out[to];
    o.push_back(m);
    for (int g : molecule(m)) {
      const int k = owned_of_[g];
      for (int a = 0; a < 3; ++a) o.push_back(x(a, k));
      for (int a = 0; a < 3; ++a) o.push_back(v(a, k));
      for (const Eigen::Matrix3Xd* c : carried)
        for (int a = 0; a < 3; ++a) o.push_back((*c)(a, k));
    }
  }
  comm_.exchange(out, in);
  bool arrived = false;
  for (const auto& b : in) arrived |= !b.empty();
  if (kept.size() == owned_.size() && !arrived) return false;
  // The new owned particles in increasing global index: kept ones from the old columns, arrived
  // ones from the messages.
  std::vector<std::pair<int, const double*>> from_messages;  // global index, its words
  std::vector<int> molecules = kept;
  for (const auto& b : in)
    for (size_t k = 0; k < b.size();) {
      const int m = static_cast<int>(b[k++]);
      molecules.push_back(m);
      for (int g : molecule(m)) {
        from_messages.emplace_back(g, b.data() + k);
        k += words;
      }
    }
  std::sort(from_messages.begin(), from_messages.end());
  const std::vector<int> was = ids_;  // the old owned particles, increasing
  own(std::move(molecules));
  std::vector<int> old_index(ids_.size(), -1);  // per new owned particle: its old index, −1 if it arrived
  for (size_t k = 0, j = 0; k < ids_.size(); ++k) {
    while (j < was.size() && was[j] < ids_[k]) ++j;
    if (j < was.size() && was[j] == ids_[k]) old_index[k] = static_cast<int>(j);
  }
  const int n = num_owned();
  Eigen::Matrix3Xd nx(3, n), nv(3, n);
  std::vector<Eigen::Matrix3Xd> nc(carried.size(), Eigen::Matrix3Xd(3, n));
  for (int k = 0; k < n; ++k) {
    if (const int o = old_index[k]; o >= 0) {
      nx.col(k) = x.col(o), nv.col(k) = v.col(o);
      for (size_t c = 0; c < carried.size(); ++c) nc[c].col(k) = carried[c]->col(o);
      continue;
    }
    const auto it = std::lower_bound(from_messages.begin(), from_messages.end(),
                                     std::make_pair(ids_[k], static_cast<const double*>(nullptr)));
    const double* w = it->second;
    nx.col(k) = Eigen::Vector3d(w[0], w[1], w[2]);
    nv.col(k) = Eigen::Vector3d(w[3], w[4], w[5]);
    for (size_t c = 0; c < carried.size(); ++c)
      nc[c].col(k) = Eigen::Vector3d(w[6 + 3 * c], w[7 + 3 * c], w[8 + 3 * c]);
  }
  x = std::move(nx);
  v = std::move(nv);
  for (size_t c = 0; c < carried.size(); ++c) *carried[c] = std::move(nc[c]);
  return true;
}

void Decomposition::select_ghosts(const Eigen::Matrix3Xd& x) {
  const ScopedPhase phase(Phase::domain);
  ++selections_;
  const int ranks = comm_.size(), me = comm_.rank(), owned = num_owned();
  // Each rank's region: the bounding box of its owned beads, each molecule at its anchor's image,
  // and (open axes) the extent of every owned bead.
  std::vector<double> regions(6 * static_cast<size_t>(ranks) + 6, 0.0);
  double* mine = regions.data() + 6 * me;
  double* extent = regions.data() + 6 * ranks;  // −min, max per axis over all ranks (max-reduced)
  for (int a = 0; a < 3; ++a) mine[a] = kInf, mine[3 + a] = -kInf, extent[a] = extent[3 + a] = -kInf;
  for (int m : owned_) {
    const Eigen::Vector3d c = anchor(x, molecule(m), true);
    Eigen::Vector3d shift = Eigen::Vector3d::Zero();
    for (int a = 0; a < 3; ++a)
      if (box_.periodic[a]) shift[a] = c[a] - wrap(c[a], box_.origin[a], box_.lengths[a], true);
    for (int g : molecule(m)) {
      const Eigen::Vector3d p = x.col(owned_of_[g]) - shift;
      for (int a = 0; a < 3; ++a) mine[a] = std::min(mine[a], p[a]), mine[3 + a] = std::max(mine[3 + a], p[a]);
    }
  }
  for (int k = 0; k < owned; ++k)
    for (int a = 0; a < 3; ++a)
      extent[a] = std::max(extent[a], -x(a, k)), extent[3 + a] = std::max(extent[3 + a], x(a, k));
  // One max-reduction: the other ranks' slots are −∞ here (so a rank's slot is its own), the
  // extent is the largest over ranks.
  for (int r = 0; r < ranks; ++r)
    if (r != me)
      for (int k = 0; k < 6; ++k) regions[6 * r + k] = -kInf;
  for (int a = 0; a < 3; ++a) mine[a] = -mine[a];  // lows as −low, so that max reduces them too
  comm_.max(regions.data(), static_cast<int>(regions.size()));
  for (int r = 0; r < ranks; ++r)
    for (int a = 0; a < 3; ++a) regions[6 * r + a] = -regions[6 * r + a];
  HaloCells cells;
  for (int a = 0; a < 3; ++a) {
    cells.periodic[a] = box_.periodic[a] != 0;
    const double lo = cells.periodic[a] ? box_.origin[a] : -extent[a];
    const double len = cells.periodic[a] ? box_.lengths[a] : std::max(extent[3 + a] + extent[a], 0.0) + radius_;
    cells.lo[a] = lo, cells.length[a] = len;
    cells.n[a] =
        std::clamp(static_cast<int>(std::floor(len / radius_)), 1, 256);  // wider cells: more ghosts, still every one
    cells.width[a] = len / cells.n[a];
  }
  cells.tabulate();
  // The neighbour ranks: those whose region comes within R of this one's (the relation is
  // symmetric, so both sides agree on it). They exchange the cells their owned beads occupy.
  std::vector<char> neighbour(ranks, 0);
  for (int r = 0; r < ranks; ++r) {
    if (r == me) continue;
    bool near = true;
    for (int a = 0; a < 3 && near; ++a)
      near = intervals_within(mine[a], mine[3 + a], regions[6 * r + a], regions[6 * r + 3 + a], radius_,
                              box_.lengths[a], cells.periodic[a]);
    neighbour[r] = near;
  }
  // The owned beads by cell (a counting sort, increasing owned index within a cell): those of
  // cell c are by_cell[cell_start[c] … cell_start[c + 1]), their wrapped positions cell_x in the
  // same order; `occupied` the cells that hold one.
  SelectionScratch& sc = scratch_;
  std::vector<std::int64_t>& cell_of = sc.cell_of;
  std::vector<int>&cell_start = sc.cell_start, &by_cell = sc.by_cell;
  std::vector<std::int64_t>& occupied = sc.occupied;
  const BoxWrap into_box(box_);  // the cells' frame on periodic axes is the box
  const auto wrapped = [&](const double* p, double* q) {
    for (int a = 0; a < 3; ++a) q[a] = into_box(p[a], a);
  };
  sc.wrapped.resize(3, owned);
  cell_of.resize(static_cast<size_t>(owned));
  for (int k = 0; k < owned; ++k) {
    double* q = sc.wrapped.col(k).data();
    wrapped(x.col(k).data(), q);
    cell_of[k] = cells.index(q);
  }
  cell_start.assign(static_cast<size_t>(cells.size()) + 1, 0);
  by_cell.resize(static_cast<size_t>(owned));
  for (int k = 0; k < owned; ++k) ++cell_start[cell_of[k] + 1];
  occupied.clear();
  for (std::int64_t c = 0; c < cells.size(); ++c) {
    if (cell_start[c + 1] > 0) occupied.push_back(c);
    cell_start[c + 1] += cell_start[c];
  }
  for (int k = 0; k < owned; ++k) by_cell[cell_start[cell_of[k]]++] = k;
  for (std::int64_t c = cells.size(); c > 0; --c) cell_start[c] = cell_start[c - 1];
  cell_start[0] = 0;
  sc.cell_x.resize(3, owned);
  for (int i = 0; i < owned; ++i) sc.cell_x.col(i) = sc.wrapped.col(by_cell[i]);
  std::vector<std::vector<double>> out(ranks), in;
  for (int r = 0; r < ranks; ++r)
    if (neighbour[r]) out[r].assign(occupied.begin(), occupied.end());
  comm_.exchange(out, in);
  // The candidates for neighbour r: the owned beads in a cell adjacent to one r's beads occupy
  // (every bead within R of one of r's, and more: up to two cells away).
  for (auto& list : send_) list.clear();
  std::vector<char>& near_r = sc.near;
  near_r.resize(static_cast<size_t>(cells.size()));
  for (int r = 0; r < ranks; ++r) {
    if (!neighbour[r] || in[r].empty()) continue;
    std::fill(near_r.begin(), near_r.end(), 0);
    for (double c : in[r])
      cells.for_each_adjacent(static_cast<std::int64_t>(c), [&](std::int64_t q) { near_r[q] = 1; });
    for (int k = 0; k < owned; ++k)
      if (near_r[cell_of[k]]) send_[r].push_back(k);
  }
  // Each candidate's global index and position to r, which keeps those within R of one of its
  // beads (minimum image) and answers which: the ghosts are exactly the beads within R of the
  // selection's positions, 40 % fewer than the cells' candidates on a melt of chains.
  for (int r = 0; r < ranks; ++r) {
    out[r].clear();
    out[r].resize(4 * send_[r].size());
    double* w = out[r].data();
    for (int k : send_[r]) w[0] = ids_[k], w[1] = x(0, k), w[2] = x(1, k), w[3] = x(2, k), w += 4;
  }
  comm_.exchange(out, in);
  // Both positions wrapped into the frame: a separation is within a box length on a periodic
  // axis, and one fold (NearestImage) makes it the minimum image.
  const double radius2 = radius_ * radius_;
  const NearestImage image(box_);
  const double* cx = sc.cell_x.data();
  const auto near_an_owned_bead = [&](const Eigen::Vector3d& raw) {
    double p[3];
    wrapped(raw.data(), p);
    bool near = false;
    const auto scan = [&](std::int64_t q) {
      for (int i = cell_start[q]; i < cell_start[q + 1] && !near; ++i) {
        double dx = p[0] - cx[3 * i], dy = p[1] - cx[3 * i + 1], dz = p[2] - cx[3 * i + 2];
        image.apply(dx, dy, dz);
        near = dx * dx + dy * dy + dz * dz <= radius2;
      }
    };
    const std::int64_t own = cells.index(p);
    scan(own);  // most candidates that are ghosts have a bead in their own cell
    cells.for_each_adjacent(own, [&](std::int64_t q) {
      if (!near && q != own) scan(q);
    });
    return near;
  };
  std::vector<std::vector<int>> ghost_ids(ranks);
  for (int r = 0; r < ranks; ++r) {
    out[r].clear();
    for (size_t m = 0; m + 4 <= in[r].size(); m += 4) {
      const bool near = near_an_owned_bead(Eigen::Vector3d(in[r][m + 1], in[r][m + 2], in[r][m + 3]));
      out[r].push_back(near ? 1.0 : 0.0);
      if (near) ghost_ids[r].push_back(static_cast<int>(in[r][m]));
    }
  }
  comm_.exchange(out, in);
  for (int r = 0; r < ranks; ++r) {
    size_t kept = 0;
    for (size_t m = 0; m < send_[r].size(); ++m)
      if (in[r][m] != 0.0) send_[r][kept++] = send_[r][m];
    send_[r].resize(kept);
  }
  // The extended set: owned and ghosts in increasing global index (so a particle's pairs are
  // summed in the one-process order: forcefields/neighbor_list.hpp).
  std::vector<std::pair<int, int>>& members = sc.members;  // global index, owned index (≥ 0) or −1 − ghost number
  members.clear();
  for (int k = 0; k < owned; ++k) members.emplace_back(ids_[k], k);
  int ghosts = 0;
  for (int r = 0; r < ranks; ++r) {
    ghost_begin_[r] = ghosts;
    ghost_count_[r] = static_cast<int>(ghost_ids[r].size());
    for (int g : ghost_ids[r]) members.emplace_back(g, -1 - ghosts++);
  }
  // Runs in increasing global index (the owned particles, then each rank's ghosts, which it sends
  // in its owned order): merged, not sorted.
  for (int r = 0, end = owned; r < ranks; ++r) {
    const auto middle = members.begin() + end;
    end += ghost_count_[r];
    if (ghost_count_[r] > 0) std::inplace_merge(members.begin(), middle, members.begin() + end);
  }
  const int n = static_cast<int>(members.size());
  extended_ids_.resize(n);
  ghost_flag_.assign(n, 0);
  owned_slot_.resize(owned);
  ghost_slot_.resize(ghosts);
  for (int e = 0; e < n; ++e) {
    extended_ids_[e] = members[e].first;
    if (members[e].second >= 0)
      owned_slot_[members[e].second] = e;
    else
      ghost_slot_[-1 - members[e].second] = e, ghost_flag_[e] = 1;
  }
  x_at_selection_ = x;
  halo_doubles_ = 0;
  halo_messages_ = 0;
  for (int r = 0; r < ranks; ++r) {
    send_buffer_[r].resize(3 * send_[r].size());
    recv_buffer_[r].resize(3 * static_cast<size_t>(ghost_count_[r]));
    halo_doubles_ += static_cast<std::int64_t>(send_buffer_[r].size());
    halo_messages_ += !send_[r].empty();
  }
}

void Decomposition::halo(const Eigen::Matrix3Xd& a, Eigen::Matrix3Xd& extended) const {
  const ScopedPhase phase(Phase::domain);
  // The ghosts cover every bead within r_c of ours while no bead moved margin/2 since their
  // selection (DomainIntegrator selects them again before a step that may): a step that moved one
  // farther would miss pairs, so it stops here (on this rank: the others wait in the halo, so the
  // job ends).
  // (Checked in the pass that copies the owned columns, before anything is sent.)
  extended.resize(3, static_cast<Eigen::Index>(extended_ids_.size()));  // no allocation once sized
  double d2 = 0.0;
  const BoxWrap into_box(box_);
  for (int k = 0; k < num_owned(); ++k) {
    const int e = owned_slot_[k];
    for (int c = 0; c < 3; ++c) extended(c, e) = into_box(a(c, k), c);
    d2 = std::max(d2, (a.col(k) - x_at_selection_.col(k)).squaredNorm());
  }
  if (const double d = std::sqrt(d2); d >= 0.5 * margin_) {
    std::ostringstream m;
    m << "a bead moved " << d << " since the ghosts were selected, more than half the halo margin " << margin_
      << " ([parallel] halo_margin) in less than a step: pairs would be missed; a larger halo_margin or a smaller step";
    throw NumericalError(m.str());
  }
  const int ranks = comm_.size();
  for (int r = 0; r < ranks; ++r) {
    double* b = send_buffer_[r].data();
    for (int k : send_[r]) b[0] = a(0, k), b[1] = a(1, k), b[2] = a(2, k), b += 3;
  }
  comm_.exchange_known(send_buffer_, recv_buffer_);
  for (int r = 0; r < ranks; ++r) {
    const double* b = recv_buffer_[r].data();
    const int* slot = ghost_slot_.data() + ghost_begin_[r];
    for (int k = 0; k < ghost_count_[r]; ++k, b += 3)
      for (int c = 0; c < 3; ++c) extended(c, slot[k]) = into_box(b[c], c);
  }
}

void Decomposition::gather_columns(const std::vector<Eigen::Matrix3Xd>& local, std::vector<Eigen::Matrix3Xd>& whole,
                                   int num_particles) const {
  const size_t arrays = local.size(), words = 1 + 3 * arrays;
  std::vector<double> mine;
  mine.reserve(words * static_cast<size_t>(num_owned()));
  for (int k = 0; k < num_owned(); ++k) {
    mine.push_back(ids_[k]);
    for (const Eigen::Matrix3Xd& a : local)
      for (int c = 0; c < 3; ++c) mine.push_back(a(c, k));
  }
  std::vector<std::vector<double>> all;
  comm_.gather(mine, all);
  whole.assign(arrays, Eigen::Matrix3Xd::Zero(3, comm_.root() ? num_particles : 0));
  for (const std::vector<double>& b : all)
    for (size_t k = 0; k + words <= b.size(); k += words) {
      const int g = static_cast<int>(b[k]);
      for (size_t a = 0; a < arrays; ++a)
        whole[a].col(g) = Eigen::Vector3d(b[k + 1 + 3 * a], b[k + 2 + 3 * a], b[k + 3 + 3 * a]);
    }
}

Decomposition::Reach Decomposition::reach(const Eigen::Matrix3Xd& x, const Eigen::Matrix3Xd& v, double t,
                                          double floor) const {
  // d + t|v| < floor whenever 2 (d² + t²|v|²) < floor², as (a + b)² ≤ 2 (a² + b²): most beads pass
  // that test, without a square root. A non-finite x or v fails it (NaN compares false).
  Reach r;
  const double floor2 = floor * floor, t2 = t * t;
  for (int k = 0; k < num_owned(); ++k) {
    const double d2 = (x.col(k) - x_at_selection_.col(k)).squaredNorm(), s2 = t2 * v.col(k).squaredNorm();
    if (2.0 * (d2 + s2) < floor2) continue;
    if (!x.col(k).allFinite() || !v.col(k).allFinite()) {
      r.first_bad = k;
      return r;
    }
    r.largest = std::max(r.largest, std::sqrt(d2) + std::sqrt(s2));
  }
  return r;
}

}  // namespace stiffmd
