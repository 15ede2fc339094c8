#include "engine/domain/decomposition.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <numeric>
#include <sstream>

#include "engine/core/errors.hpp"
#include "engine/core/timing.hpp"
#include <stdexcept>

namespace stiffmd {

namespace {

constexpr double kInf = std::numeric_limits<double>::infinity();

// p wrapped into [origin, origin + L) on a periodic axis.
double wrap(double p, double origin, double length, bool periodic) {
  return periodic ? p - length * std::floor((p - origin) / length) : p;
}

}  // namespace

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
  // Molecules: the connected components of the bonded terms (bonds, angles, dihedrals), numbered
  // by their first particle; a lone particle is its own. Not the deck's or the data file's
  // molecule ids: a term must never join two molecules, whatever a file calls them.
  std::vector<int> parent(n);
  for (int i = 0; i < n; ++i) parent[i] = i;
  const auto find = [&](int i) {
    while (parent[i] != i) i = parent[i] = parent[parent[i]];
    return i;
  };
  const auto join = [&](int i, int j) {
    i = find(i), j = find(j);
    if (i != j) parent[std::max(i, j)] = std::min(i, j);
  };
  for (const Bond& b : topology.bonds) join(b.i, b.j);
  for (const Angle& a : topology.angles) join(a.i, a.j), join(a.j, a.k);
  for (const Dihedral& d : topology.dihedrals) join(d.i, d.j), join(d.j, d.k), join(d.k, d.l);
  molecule_.assign(n, -1);
  int molecules = 0;
  for (int i = 0; i < n; ++i) {
    const int root = find(i);
    molecule_[i] = root == i ? molecules++ : molecule_[root];  // a root is its component's first particle
  }
  molecule_start_.assign(molecules + 1, 0);
  for (int i = 0; i < n; ++i) ++molecule_start_[molecule_[i] + 1];
  for (int m = 0; m < molecules; ++m) molecule_start_[m + 1] += molecule_start_[m];
  molecule_particles_.resize(n);
  std::vector<int> next(molecule_start_.begin(), molecule_start_.end() - 1);
  for (int i = 0; i < n; ++i) molecule_particles_[next[molecule_[i]]++] = i;  // increasing within each
  if (dims) grid_dims_ = *dims, have_dims_ = true;
  local_of_.assign(n, -1);
  const int ranks = comm_.size();
  send_.resize(ranks);
  ghost_begin_.assign(ranks, 0);
  ghost_count_.assign(ranks, 0);
  send_buffer_.resize(ranks);
  recv_buffer_.resize(ranks);
}

bool Decomposition::owns_molecule(int m) const {
  return std::binary_search(owned_.begin(), owned_.end(), m);
}

Eigen::Vector3d Decomposition::anchor(const Eigen::Matrix3Xd& x, std::span<const int> global) const {
  // The centre of mass of a whole molecule (unwrapped: its bonds are their own minimum images).
  Eigen::Vector3d c = Eigen::Vector3d::Zero();
  double total = 0.0;
  for (int g : global) {
    const int i = local_of_[g] >= 0 ? local_of_[g] : g;  // local columns, or the whole state's
    c += mass_[g] * x.col(i);
    total += mass_[g];
  }
  return c / total;
}

void Decomposition::distribute(const State& whole, Eigen::Matrix3Xd& x, Eigen::Matrix3Xd& v) {
  const int molecules = num_molecules();
  Eigen::Matrix3Xd anchors(3, molecules);
  std::fill(local_of_.begin(), local_of_.end(), -1);
  for (int m = 0; m < molecules; ++m) anchors.col(m) = anchor(whole.x, molecule(m));
  grid_ = make_domain_grid(box_, comm_.size(), have_dims_ ? &grid_dims_ : nullptr, anchors);
  owned_.clear();
  for (int m = 0; m < molecules; ++m)
    if (grid_.domain_of(anchors.col(m)) == comm_.rank()) owned_.push_back(m);
  ids_.clear();
  for (int m : owned_)
    for (int g : molecule(m)) ids_.push_back(g);
  std::sort(ids_.begin(), ids_.end());
  num_owned_ = static_cast<int>(ids_.size());
  x.resize(3, num_owned_);
  v.resize(3, num_owned_);
  for (int i = 0; i < num_owned_; ++i) x.col(i) = whole.x.col(ids_[i]), v.col(i) = whole.v.col(ids_[i]);
  owned_flag_.assign(num_owned_, 1);
  std::vector<Eigen::Matrix3Xd*> none;
  select_ghosts(x, v, none);
}

void Decomposition::redistribute(Eigen::Matrix3Xd& x, Eigen::Matrix3Xd& v, std::vector<Eigen::Matrix3Xd*> carried) {
  const ScopedPhase phase(Phase::domain);
  ++redistributions_;
  const int ranks = comm_.size(), me = comm_.rank();
  const int words = 6 + 3 * static_cast<int>(carried.size());  // per particle: x, v, the carried columns
  // Molecules whose anchor left the domain, whole, to their new owner: [m, columns of its particles].
  std::vector<std::vector<double>> out(ranks), in;
  std::vector<int> kept;
  for (int m : owned_) {
    const int to = grid_.domain_of(anchor(x, molecule(m)));
    if (to == me) {
      kept.push_back(m);
      continue;
    }
    ++migrated_;
    std::vector<double>& o = out[to];
    o.push_back(m);
    for (int g : molecule(m)) {
      const int i = local_of_[g];
      for (int a = 0; a < 3; ++a) o.push_back(x(a, i));
      for (int a = 0; a < 3; ++a) o.push_back(v(a, i));
      for (const Eigen::Matrix3Xd* c : carried)
        for (int a = 0; a < 3; ++a) o.push_back((*c)(a, i));
    }
  }
  comm_.exchange(out, in);
  // The new owned particles in increasing global index: kept ones from the local columns,
  // received ones from the messages.
  std::vector<int> received_slot(0);
  std::vector<std::pair<int, const double*>> arrived;  // global index, its words
  std::vector<int> owned = kept;
  for (int r = 0; r < ranks; ++r) {
    const std::vector<double>& b = in[r];
    for (size_t k = 0; k < b.size();) {
      const int m = static_cast<int>(b[k++]);
      owned.push_back(m);
      for (int g : molecule(m)) {
        arrived.emplace_back(g, b.data() + k);
        k += words;
      }
    }
  }
  std::sort(owned.begin(), owned.end());
  std::sort(arrived.begin(), arrived.end());
  std::vector<int> ids;
  for (int m : owned)
    for (int g : molecule(m)) ids.push_back(g);
  std::sort(ids.begin(), ids.end());
  const int n = static_cast<int>(ids.size());
  Eigen::Matrix3Xd nx(3, n), nv(3, n);
  std::vector<Eigen::Matrix3Xd> nc(carried.size(), Eigen::Matrix3Xd(3, n));
  for (int i = 0; i < n; ++i) {
    const int g = ids[i];
    const int old = local_of_[g];
    if (old >= 0 && owned_flag_[old]) {
      nx.col(i) = x.col(old), nv.col(i) = v.col(old);
      for (size_t c = 0; c < carried.size(); ++c) nc[c].col(i) = carried[c]->col(old);
      continue;
    }
    const auto it =
        std::lower_bound(arrived.begin(), arrived.end(), std::make_pair(g, static_cast<const double*>(nullptr)));
    const double* w = it->second;
    nx.col(i) = Eigen::Vector3d(w[0], w[1], w[2]);
    nv.col(i) = Eigen::Vector3d(w[3], w[4], w[5]);
    for (size_t c = 0; c < carried.size(); ++c)
      nc[c].col(i) = Eigen::Vector3d(w[6 + 3 * c], w[7 + 3 * c], w[8 + 3 * c]);
  }
  for (int g : ids_) local_of_[g] = -1;
  owned_ = std::move(owned);
  ids_ = std::move(ids);
  num_owned_ = n;
  x = std::move(nx);
  v = std::move(nv);
  for (size_t c = 0; c < carried.size(); ++c) *carried[c] = std::move(nc[c]);
  select_ghosts(x, v, carried);
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
  int coordinate(double p, int a) const {
    const double q = periodic[a] ? wrap(p, lo[a], length[a], true) : p;
    return std::clamp(static_cast<int>(std::floor((q - lo[a]) / width[a])), 0, n[a] - 1);
  }
  std::int64_t index(const double* p) const {
    return (static_cast<std::int64_t>(coordinate(p[0], 0)) * n[1] + coordinate(p[1], 1)) * n[2] + coordinate(p[2], 2);
  }
  // The cells adjacent to cell c (itself included), each once.
  template <class F>
  void for_each_adjacent(std::int64_t c, F f) const {
    const int c2 = static_cast<int>(c % n[2]), c1 = static_cast<int>((c / n[2]) % n[1]),
              c0 = static_cast<int>(c / (static_cast<std::int64_t>(n[2]) * n[1]));
    int a0[3], a1[3], a2[3], k0 = 0, k1 = 0, k2 = 0;
    const auto around = [&](int cc, int a, int* out, int& k) {
      for (int d = -1; d <= 1; ++d) {
        int q = cc + d;
        if (periodic[a])
          q = (q + n[a]) % n[a];
        else if (q < 0 || q >= n[a])
          continue;
        if (std::find(out, out + k, q) == out + k) out[k++] = q;
      }
    };
    around(c0, 0, a0, k0), around(c1, 1, a1, k1), around(c2, 2, a2, k2);
    for (int i = 0; i < k0; ++i)
      for (int j = 0; j < k1; ++j)
        for (int l = 0; l < k2; ++l) f((static_cast<std::int64_t>(a0[i]) * n[1] + a1[j]) * n[2] + a2[l]);
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

void Decomposition::select_ghosts(Eigen::Matrix3Xd& x, Eigen::Matrix3Xd& v, std::vector<Eigen::Matrix3Xd*>& carried) {
  const int ranks = comm_.size(), me = comm_.rank();
  for (int g : ids_) local_of_[g] = -1;
  ids_.resize(num_owned_);
  for (int i = 0; i < num_owned_; ++i) local_of_[ids_[i]] = i;
  // Each rank's region: the bounding box of its owned beads, each molecule at its anchor's image,
  // and (open axes) the extent of every owned bead.
  std::vector<double> regions(6 * static_cast<size_t>(ranks) + 6, 0.0);
  double* mine = regions.data() + 6 * me;
  double* extent = regions.data() + 6 * ranks;  // −min, max per axis over all ranks (max-reduced)
  for (int a = 0; a < 3; ++a) mine[a] = kInf, mine[3 + a] = -kInf, extent[a] = extent[3 + a] = -kInf;
  for (int m : owned_) {
    const Eigen::Vector3d c = anchor(x, molecule(m));
    Eigen::Vector3d shift = Eigen::Vector3d::Zero();
    for (int a = 0; a < 3; ++a)
      if (box_.periodic[a]) shift[a] = c[a] - wrap(c[a], box_.origin[a], box_.lengths[a], true);
    for (int g : molecule(m)) {
      const Eigen::Vector3d p = x.col(local_of_[g]) - shift;
      for (int a = 0; a < 3; ++a) mine[a] = std::min(mine[a], p[a]), mine[3 + a] = std::max(mine[3 + a], p[a]);
    }
  }
  for (int i = 0; i < num_owned_; ++i)
    for (int a = 0; a < 3; ++a)
      extent[a] = std::max(extent[a], -x(a, i)), extent[3 + a] = std::max(extent[3 + a], x(a, i));
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
  std::vector<std::int64_t> occupied(static_cast<size_t>(num_owned_));
  for (int i = 0; i < num_owned_; ++i) occupied[i] = cells.index(x.col(i).data());
  std::sort(occupied.begin(), occupied.end());
  occupied.erase(std::unique(occupied.begin(), occupied.end()), occupied.end());
  std::vector<std::vector<double>> out(ranks), in;
  for (int r = 0; r < ranks; ++r)
    if (neighbour[r]) out[r].assign(occupied.begin(), occupied.end());
  comm_.exchange(out, in);
  // An owned bead is a ghost of neighbour r when its cell is adjacent to one r's beads occupy.
  for (auto& s : send_) s.clear();
  std::vector<char> near_r(static_cast<size_t>(cells.size()));
  for (int r = 0; r < ranks; ++r) {
    if (!neighbour[r] || in[r].empty()) continue;
    std::fill(near_r.begin(), near_r.end(), 0);
    for (double c : in[r])
      cells.for_each_adjacent(static_cast<std::int64_t>(c), [&](std::int64_t q) { near_r[q] = 1; });
    for (int i = 0; i < num_owned_; ++i)
      if (near_r[cells.index(x.col(i).data())]) send_[r].push_back(i);
  }
  for (int r = 0; r < ranks; ++r) {
    out[r].clear();
    for (int i : send_[r]) {
      out[r].push_back(ids_[i]);
      for (int a = 0; a < 3; ++a) out[r].push_back(x(a, i));
    }
  }
  comm_.exchange(out, in);
  int ghosts = 0;
  for (int r = 0; r < ranks; ++r)
    ghost_begin_[r] = num_owned_ + ghosts, ghosts += ghost_count_[r] = static_cast<int>(in[r].size() / 4);
  const int n = num_owned_ + ghosts;
  x.conservativeResize(3, n);
  v.conservativeResize(3, n);
  v.rightCols(ghosts).setZero();
  for (Eigen::Matrix3Xd* c : carried) {
    c->conservativeResize(3, n);
    c->rightCols(ghosts).setZero();
  }
  for (int r = 0; r < ranks; ++r)
    for (int k = 0; k < ghost_count_[r]; ++k) {
      const double* w = in[r].data() + 4 * k;
      const int i = ghost_begin_[r] + k;
      ids_.push_back(static_cast<int>(w[0]));
      x.col(i) = Eigen::Vector3d(w[1], w[2], w[3]);
    }
  // The local arrays in increasing global index, ghosts among the owned particles: every
  // particle's pair partners then come in the order they come in one process (the lists' rows
  // are sorted, NeighborList), so its forces are the same sums, bit for bit, at one thread.
  std::vector<int> order(n);
  std::iota(order.begin(), order.end(), 0);
  std::sort(order.begin(), order.end(), [&](int a, int b) { return ids_[a] < ids_[b]; });
  std::vector<int> new_index(n);
  for (int k = 0; k < n; ++k) new_index[order[k]] = k;
  const auto permute = [&](Eigen::Matrix3Xd& a) {
    Eigen::Matrix3Xd b(3, n);
    for (int k = 0; k < n; ++k) b.col(k) = a.col(order[k]);
    a = std::move(b);
  };
  permute(x), permute(v);
  for (Eigen::Matrix3Xd* c : carried) permute(*c);
  std::vector<int> ids(n);
  for (int k = 0; k < n; ++k) ids[k] = ids_[order[k]];
  ids_ = std::move(ids);
  owned_flag_.assign(n, 0);
  owned_index_.clear();
  for (int k = 0; k < n; ++k) {
    local_of_[ids_[k]] = k;
    if (order[k] < num_owned_) owned_flag_[k] = 1, owned_index_.push_back(k);
  }
  for (auto& list : send_)
    for (int& i : list) i = new_index[i];
  ghost_slot_.resize(ghosts);
  for (int g = 0; g < ghosts; ++g) ghost_slot_[g] = new_index[num_owned_ + g];
  x_at_selection_.resize(3, num_owned_);
  for (int k = 0; k < num_owned_; ++k) x_at_selection_.col(k) = x.col(owned_index_[k]);
  halo_doubles_ = 0;
  halo_messages_ = 0;
  for (int r = 0; r < ranks; ++r) {
    send_buffer_[r].resize(3 * send_[r].size());
    recv_buffer_[r].resize(3 * static_cast<size_t>(ghost_count_[r]));
    halo_doubles_ += static_cast<std::int64_t>(send_buffer_[r].size());
    halo_messages_ += !send_[r].empty();
  }
}

void Decomposition::halo(Eigen::Matrix3Xd& a) const {
  const ScopedPhase phase(Phase::domain);
  // The ghosts cover every bead within r_c of ours while no bead moved margin/2 since their
  // selection (the redistribution before each step sees to that, from the last step's growth): a
  // step that moved one farther would miss pairs, so it stops here (on this rank: the others wait
  // in the halo, so the job ends).
  if (const double d = max_displacement(a); d >= 0.5 * margin_) {
    std::ostringstream m;
    m << "a bead moved " << d << " within one step, more than half the halo margin " << margin_
      << " ([parallel] halo_margin): pairs would be missed; a larger halo_margin or a smaller step";
    throw NumericalError(m.str());
  }
  const int ranks = comm_.size();
  for (int r = 0; r < ranks; ++r) {
    double* b = send_buffer_[r].data();
    for (int i : send_[r]) b[0] = a(0, i), b[1] = a(1, i), b[2] = a(2, i), b += 3;
  }
  comm_.exchange_known(send_buffer_, recv_buffer_);
  for (int r = 0; r < ranks; ++r) {
    const double* b = recv_buffer_[r].data();
    const int* slot = ghost_slot_.data() + (ghost_begin_[r] - num_owned_);
    for (int k = 0; k < ghost_count_[r]; ++k, b += 3) a.col(slot[k]) = Eigen::Vector3d(b[0], b[1], b[2]);
  }
}

void Decomposition::gather(const Eigen::Matrix3Xd& x, const Eigen::Matrix3Xd& v, State& whole) const {
  std::vector<double> mine;
  mine.reserve(7 * static_cast<size_t>(num_owned_));
  for (int i : owned_index_) {
    mine.push_back(ids_[i]);
    for (int a = 0; a < 3; ++a) mine.push_back(x(a, i));
    for (int a = 0; a < 3; ++a) mine.push_back(v(a, i));
  }
  std::vector<std::vector<double>> all;
  comm_.gather(mine, all);
  for (const std::vector<double>& b : all)
    for (size_t k = 0; k + 7 <= b.size(); k += 7) {
      const int g = static_cast<int>(b[k]);
      whole.x.col(g) = Eigen::Vector3d(b[k + 1], b[k + 2], b[k + 3]);
      whole.v.col(g) = Eigen::Vector3d(b[k + 4], b[k + 5], b[k + 6]);
    }
}

void Decomposition::gather_columns(const std::vector<Eigen::Matrix3Xd>& local, std::vector<Eigen::Matrix3Xd>& whole,
                                   int num_particles) const {
  const size_t arrays = local.size(), words = 1 + 3 * arrays;
  std::vector<double> mine;
  mine.reserve(words * static_cast<size_t>(num_owned_));
  for (int i : owned_index_) {
    mine.push_back(ids_[i]);
    for (const Eigen::Matrix3Xd& a : local)
      for (int k = 0; k < 3; ++k) mine.push_back(a(k, i));
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

double Decomposition::max_displacement(const Eigen::Matrix3Xd& x) const {
  double d2 = 0.0;
  for (int k = 0; k < num_owned_; ++k)
    d2 = std::max(d2, (x.col(owned_index_[k]) - x_at_selection_.col(k)).squaredNorm());
  return std::sqrt(d2);
}

}  // namespace stiffmd
