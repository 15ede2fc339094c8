#include "engine/domain/decomposition.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <numeric>
#include <sstream>

#include <stdexcept>

#if defined(__x86_64__)
#include <immintrin.h>
#endif

#include "core/errors.hpp"
#include "core/finite.hpp"
#include "core/molecule_anchor.hpp"
#include "core/timing.hpp"
#include "forcefields/neighbor_list.hpp"  // MinimumImage

namespace stiffmd {

namespace {

constexpr double kInf = std::numeric_limits<double>::infinity();
// The load balance's histograms: bins per slab of the most cut axis (the cuts fall within a bin's
// width of the exact quantiles, linear inside the bin).
constexpr int kBinsPerSlab = 64;

// floor by truncation and a correction, as BoxWrap (forcefields/neighbor_list.hpp): no call (x86-64
// before SSE4.1 has no floor instruction; the selection of the pair sets places every owned bead);
// the same value as std::floor for |q| < 2⁶³.
double floor_of(double q) {
  const double t = static_cast<double>(static_cast<std::int64_t>(q));
  return t > q ? t - 1.0 : t;
}

// p wrapped into [origin, origin + L) on a periodic axis.
double wrap(double p, double origin, double length, bool periodic) {
  return periodic ? p - length * floor_of((p - origin) / length) : p;
}

// Slabs up to which the cut slab's lookup counts the faces below q (no branch per face) rather
// than bisecting them.
constexpr int kCountedSlabs = 32;

}  // namespace

int DomainGrid::cut_slab_of(int a, double q) const {
  const int n = dims[a];
  // The last face at or below q's fraction of the axis: the count of the inner faces at or below it.
  const double f = (q - origin[a]) / length[a];
  if (n <= kCountedSlabs) {
    int below = 0;
    for (int c = 1; c < n; ++c) below += cut[a][c] <= f;
    return below;
  }
  const auto above = std::upper_bound(cut[a].begin() + 1, cut[a].end() - 1, f);
  return static_cast<int>(above - cut[a].begin()) - 1;
}

bool DomainGrid::within(int domain, const Eigen::Vector3d& p, double slack) const {
  const int index[3] = {domain / (dims[1] * dims[2]), (domain / dims[2]) % dims[1], domain % dims[2]};
  for (int a = 0; a < 3; ++a) {
    const double lo = face(a, index[a]), hi = face(a, index[a] + 1);
    double q = periodic[a] ? wrap(p[a], origin[a], length[a], true) : p[a];
    if (periodic[a] && q > hi + slack) q -= length[a];  // the image nearest the domain
    if (periodic[a] && q < lo - slack) q += length[a];
    if (q < lo - slack || q > hi + slack) return false;
  }
  return true;
}

int DomainGrid::domain_of(const Eigen::Vector3d& p) const {
  int index[3];
  for (int a = 0; a < 3; ++a) index[a] = slab_of(a, wrap(p[a], origin[a], length[a], periodic[a] != 0));
  return (index[0] * dims[1] + index[1]) * dims[2] + index[2];
}

std::vector<double> domain_loads(const DomainGrid& g, const Eigen::Matrix3Xd& x) {
  std::vector<double> loads(g.size(), 0.0);
  for (Eigen::Index k = 0; k < x.cols(); ++k) loads[g.domain_of(x.col(k))] += 1.0;
  return loads;
}

double load_imbalance(const std::vector<double>& loads) {
  const double total = std::accumulate(loads.begin(), loads.end(), 0.0);
  if (loads.empty() || total <= 0.0) return 1.0;
  return *std::max_element(loads.begin(), loads.end()) / (total / static_cast<double>(loads.size()));
}

std::vector<double> axis_histograms(const DomainGrid& g, const Eigen::Matrix3Xd& x, int bins) {
  std::vector<double> h(3 * static_cast<size_t>(bins), 0.0);
  for (Eigen::Index k = 0; k < x.cols(); ++k)
    for (int a = 0; a < 3; ++a) {
      const double q = wrap(x(a, k), g.origin[a], g.length[a], g.periodic[a] != 0);
      const int b = std::clamp(static_cast<int>(std::floor((q - g.origin[a]) / g.length[a] * bins)), 0, bins - 1);
      h[static_cast<size_t>(a) * bins + b] += 1.0;
    }
  return h;
}

std::vector<double> quantile_cuts(std::span<const double> histogram, int slabs) {
  const int bins = static_cast<int>(histogram.size());
  const double total = std::accumulate(histogram.begin(), histogram.end(), 0.0);
  std::vector<double> cut(slabs + 1);
  for (int k = 0; k <= slabs; ++k) cut[k] = static_cast<double>(k) / slabs;
  if (total <= 0.0 || bins == 0) return cut;
  // Cut k where the cumulative work reaches k/slabs of the total, in the first bin that holds work
  // there (an empty stretch of the axis goes to the slab below).
  double below = 0.0;  // the work in the bins before b
  int b = 0;
  for (int k = 1; k < slabs; ++k) {
    const double target = total * k / slabs;
    while (b < bins && (below + histogram[b] < target || histogram[b] <= 0.0)) below += histogram[b++];
    if (b == bins) {
      cut[k] = 1.0;
      continue;
    }
    cut[k] = (b + std::clamp((target - below) / histogram[b], 0.0, 1.0)) / bins;
  }
  // Strictly increasing, every slab of some width: a slab with no bead is still a domain, and the
  // migration's slack is a quarter of a domain's width.
  const double least = 1e-3 / slabs;
  for (int k = 1; k < slabs; ++k) cut[k] = std::max(cut[k], cut[k - 1] + least);
  for (int k = slabs - 1; k >= 1; --k) cut[k] = std::min(cut[k], cut[k + 1] - least);
  return cut;
}

DomainGrid balanced_grid(const DomainGrid& g, const std::vector<double>& histograms, int bins) {
  DomainGrid out = g;
  for (int a = 0; a < 3; ++a) {
    out.cut[a].clear();
    if (g.dims[a] > 1)
      out.cut[a] =
          quantile_cuts(std::span<const double>(histograms).subspan(static_cast<size_t>(a) * bins, bins), g.dims[a]);
  }
  return out;
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

Decomposition::Decomposition(const Box& box, const Communicator& comm, double cutoff, double margin,
                             const Eigen::Vector3i* dims)
    : comm_(comm), box_(box), radius_(cutoff + margin), margin_(margin) {
  if (dims) grid_dims_ = *dims, have_dims_ = true;
  const int ranks = comm_.size();
  out_.resize(ranks);
  in_.resize(ranks);
  for (int kind = 0; kind < kMessages; ++kind) send_buffer_[kind].resize(ranks), recv_buffer_[kind].resize(ranks);
}

bool Decomposition::owns_molecule(int m) const {
  return std::binary_search(owned_.begin(), owned_.end(), m);
}

int Decomposition::owned_index(int global) const {
  const auto it = std::lower_bound(ids_.begin(), ids_.end(), global);
  return it != ids_.end() && *it == global ? static_cast<int>(it - ids_.begin()) : -1;
}

// The centre of mass of a whole molecule (unwrapped: its bonds are their own minimum images),
// summed over its particles by increasing global index.
Eigen::Vector3d Decomposition::owned_anchor(const Eigen::Matrix3Xd& x, int i) const {
  MoleculeAnchor anchor;
  for (int e = owned_start_[i]; e < owned_start_[i + 1]; ++e) {
    const int k = owned_columns_[e];
    anchor.add(owned_mass_[k], x.col(k));
  }
  return anchor.value();
}

void Decomposition::set_box(const Box& box) {
  box_ = box;
  for (int a = 0; a < 3; ++a)
    if (box.periodic[a]) grid_.origin[a] = box.origin[a], grid_.length[a] = box.lengths[a];
}

void Decomposition::own() {
  // The owned molecules, and each one's columns by a counting sort of the owned particles (their
  // columns increase within each molecule).
  owned_ = owned_molecule_;
  std::sort(owned_.begin(), owned_.end());
  owned_.erase(std::unique(owned_.begin(), owned_.end()), owned_.end());
  owned_start_.assign(owned_.size() + 1, 0);
  std::vector<int> slot(ids_.size());
  for (size_t k = 0; k < ids_.size(); ++k) {
    slot[k] = static_cast<int>(std::lower_bound(owned_.begin(), owned_.end(), owned_molecule_[k]) - owned_.begin());
    ++owned_start_[slot[k] + 1];
  }
  for (size_t i = 0; i < owned_.size(); ++i) owned_start_[i + 1] += owned_start_[i];
  owned_columns_.resize(ids_.size());
  std::vector<int> next(owned_start_.begin(), owned_start_.end() - 1);
  for (size_t k = 0; k < ids_.size(); ++k) owned_columns_[next[slot[k]]++] = static_cast<int>(k);
}

std::pair<DomainGrid, double> Decomposition::recut(const Eigen::Matrix3Xd& x) const {
  // The owned beads' histograms summed over the ranks, and the new cuts' loads likewise (counts:
  // exact in any order, so the cuts and their measure are the same on every rank).
  const int bins = kBinsPerSlab * grid_.dims.maxCoeff();
  std::vector<double> histograms = axis_histograms(grid_, x, bins);
  comm_.sum(histograms.data(), static_cast<int>(histograms.size()));
  DomainGrid cut = balanced_grid(grid_, histograms, bins);
  std::vector<double> loads = domain_loads(cut, x);
  comm_.sum(loads.data(), static_cast<int>(loads.size()));
  const double imbalance = load_imbalance(loads);
  return {std::move(cut), imbalance};
}

void Decomposition::start(PartMolecules& molecules, Eigen::Matrix3Xd& x, Eigen::Matrix3Xd& v) {
  const int n = molecules.size(), me = comm_.rank();
  if (x.cols() != n || v.cols() != n)
    throw std::logic_error("Decomposition::start: x, v are not the columns of the molecules' particles");
  // The molecules of the part: the components of its items (bonded_molecules, numbered by first
  // particle; the part's topology refuses an item with a particle elsewhere: a part holds whole
  // molecules), each named by its first global index, which no other rank's molecule has.
  const std::vector<int> component = bonded_molecules(molecules.topology(Topology{}), n);
  std::vector<int> name;
  ids_ = molecules.global;
  owned_molecule_.resize(n);
  owned_mass_.resize(n);
  for (int k = 0; k < n; ++k) {
    if (static_cast<size_t>(component[k]) == name.size()) name.push_back(ids_[k]);
    owned_molecule_[k] = name[component[k]];
    owned_mass_[k] = anchor_mass(molecules.inv_mass[k]);
  }
  own();
  // The anchors (each molecule's sum over its particles by increasing global index: the whole
  // system's at every rank count), and their extent over every rank for the open axes.
  const int owned = static_cast<int>(owned_.size());
  Eigen::Matrix3Xd anchors(3, owned);
  for (int i = 0; i < owned; ++i) anchors.col(i) = owned_anchor(x, i);
  std::int64_t count[2] = {n, owned};
  comm_.sum(count, 2);
  num_particles_ = static_cast<int>(count[0]);
  double extent[6];  // −low, high per axis (a max of each is the extent: exact)
  for (int a = 0; a < 3; ++a) {
    extent[a] = owned ? -anchors.row(a).minCoeff() : -kInf;
    extent[3 + a] = owned ? anchors.row(a).maxCoeff() : -kInf;
  }
  comm_.max(extent, 6);
  Eigen::Matrix3Xd span(3, count[1] > 0 ? 2 : 0);
  if (count[1] > 0)
    for (int a = 0; a < 3; ++a) span(a, 0) = -extent[a], span(a, 1) = extent[3 + a];
  grid_ = make_domain_grid(box_, comm_.size(), have_dims_ ? &grid_dims_ : nullptr, span);
  // The measure and the start's recut from the beads counted over the ranks (integer counts: the
  // same sums in any order, so every rank cuts alike).
  std::vector<double> loads = domain_loads(grid_, x);
  comm_.sum(loads.data(), static_cast<int>(loads.size()));
  imbalance_before_ = load_imbalance(loads);
  if (balance_.when != BalanceSettings::When::off && imbalance_before_ > balance_.threshold) {
    auto [cut, cut_imbalance] = recut(x);
    if (cut_imbalance < imbalance_before_) grid_ = std::move(cut), ++recuts_;
  }
  // Each molecule to the rank of its anchor's domain, by the migration's messages.
  std::vector<int> to(n, -1);
  bool leaving = false;
  for (int i = 0; i < owned; ++i) {
    const int dest = grid_.domain_of(anchors.col(i));
    if (dest == me) continue;
    leaving = true;
    for (int e = owned_start_[i]; e < owned_start_[i + 1]; ++e) to[owned_columns_[e]] = dest;
  }
  send_molecules(to, leaving, x, v, {}, &molecules);
}

void Decomposition::distribute(const Topology& topology, const State& whole, Eigen::Matrix3Xd& x, Eigen::Matrix3Xd& v) {
  const int n = whole.size();
  const std::vector<int> type(static_cast<size_t>(n), 0);
  const std::vector<double> charge(static_cast<size_t>(n), 0.0);
  const std::vector<int> mine = whole_block(topology, n, comm_.size(), comm_.rank());
  PartMolecules molecules = cut_part(
      {std::span<const double>(whole.inv_mass.data(), static_cast<size_t>(n)), type, charge, {}, {}, topology}, mine);
  x.resize(3, static_cast<Eigen::Index>(mine.size()));
  v.resize(3, static_cast<Eigen::Index>(mine.size()));
  for (size_t k = 0; k < mine.size(); ++k) x.col(k) = whole.x.col(mine[k]), v.col(k) = whole.v.col(mine[k]);
  start(molecules, x, v);
}

int Decomposition::find_leaving(const Eigen::Matrix3Xd& x) const {
  const int me = comm_.rank();
  // A molecule leaves when its anchor is past this rank's domain by more than a quarter of the
  // domain's narrowest width: an anchor near a face does not go back and forth (each move rebuilds
  // two ranks' parts). A molecule away from its domain costs only messages: its beads' pair forces
  // are computed at their homes whoever owns it.
  const int mine[3] = {me / (grid_.dims[1] * grid_.dims[2]), (me / grid_.dims[2]) % grid_.dims[1], me % grid_.dims[2]};
  double slack = std::numeric_limits<double>::infinity();
  for (int a = 0; a < 3; ++a) slack = std::min(slack, 0.25 * (grid_.face(a, mine[a] + 1) - grid_.face(a, mine[a])));
  leave_to_.assign(num_owned(), -1);
  int leaving = 0;
  for (int i = 0; i < static_cast<int>(owned_.size()); ++i) {
    const Eigen::Vector3d c = owned_anchor(x, i);
    const int dest = grid_.domain_of(c);
    if (dest == me || grid_.within(me, c, slack)) continue;
    ++leaving;
    for (int e = owned_start_[i]; e < owned_start_[i + 1]; ++e) leave_to_[owned_columns_[e]] = dest;
  }
  return leaving;
}

bool Decomposition::molecules_leave(const Eigen::Matrix3Xd& x) const {
  const ScopedPhase phase(Phase::domain);
  double leaving = find_leaving(x) > 0 ? 1.0 : 0.0;
  comm_.max(&leaving, 1);
  return leaving > 0.0;
}

bool Decomposition::migrate(Eigen::Matrix3Xd& x, Eigen::Matrix3Xd& v, std::vector<Eigen::Matrix3Xd*> carried,
                            PartMolecules* molecules) {
  const ScopedPhase phase(Phase::domain);
  if (molecules && molecules->global != ids_)
    throw std::logic_error("Decomposition::migrate: the part's molecules are not the owned particles");
  const int leaving = find_leaving(x);
  migrated_ += leaving;
  return send_molecules(leave_to_, leaving > 0, x, v, std::move(carried), molecules);
}

bool Decomposition::send_molecules(const std::vector<int>& to, bool leaving, Eigen::Matrix3Xd& x, Eigen::Matrix3Xd& v,
                                   std::vector<Eigen::Matrix3Xd*> carried, PartMolecules* molecules) {
  const int ranks = comm_.size(), owned = num_owned();
  // Per particle: its global index, its molecule, its mass in the anchor, x, v, the carried columns.
  const int words = 9 + 3 * static_cast<int>(carried.size());
  // A message: the particle count, each particle's words by increasing global index, then (with
  // molecules) their share of the part's molecules, in the same order.
  std::vector<std::vector<double>> out(ranks), in;
  for (int r = 0; r < ranks; ++r) out[r].push_back(0.0);
  for (int k = 0; k < owned; ++k) {
    if (to[k] < 0) continue;
    std::vector<double>& o = out[to[k]];
    o[0] += 1.0;
    o.push_back(ids_[k]);
    o.push_back(owned_molecule_[k]);
    o.push_back(owned_mass_[k]);
    for (int a = 0; a < 3; ++a) o.push_back(x(a, k));
    for (int a = 0; a < 3; ++a) o.push_back(v(a, k));
    for (const Eigen::Matrix3Xd* c : carried)
      for (int a = 0; a < 3; ++a) o.push_back((*c)(a, k));
  }
  std::vector<PartMolecules> pieces(molecules ? ranks : 0);
  PartMolecules kept_molecules;
  if (molecules && leaving) kept_molecules = split_part(*molecules, to, pieces);
  for (int r = 0; r < ranks; ++r) {
    if (out[r][0] == 0.0) {
      out[r].clear();
      continue;
    }
    if (molecules) pack_part(pieces[r], out[r]);
  }
  comm_.exchange(out, in);
  bool arrived = false;
  for (const auto& b : in) arrived |= !b.empty();
  if (!leaving && !arrived) return false;
  // The new owned particles in increasing global index: kept ones from the old columns, arrived
  // ones from the messages.
  std::vector<std::pair<int, const double*>> from_messages;  // global index, its words
  std::vector<PartMolecules> parts;
  if (molecules) parts.push_back(leaving ? std::move(kept_molecules) : std::move(*molecules));
  for (const auto& b : in) {
    if (b.empty()) continue;
    const auto count = static_cast<size_t>(b[0]);
    const double* w = b.data() + 1;
    for (size_t e = 0; e < count; ++e, w += words) from_messages.emplace_back(static_cast<int>(w[0]), w);
    if (molecules) {
      parts.emplace_back();
      unpack_part(w, parts.back());
    }
  }
  std::sort(from_messages.begin(), from_messages.end());
  std::vector<int> now;  // the new owned particles: kept ones (old column k ≥ 0) or arrived ones (−1 − e)
  now.reserve(owned + from_messages.size());
  {
    int k = 0;
    size_t e = 0;
    while (k < owned || e < from_messages.size()) {
      while (k < owned && to[k] >= 0) ++k;
      const bool old = k < owned && (e == from_messages.size() || ids_[k] < from_messages[e].first);
      if (old)
        now.push_back(k++);
      else if (e < from_messages.size())
        now.push_back(-1 - static_cast<int>(e++));
    }
  }
  const int n = static_cast<int>(now.size());
  std::vector<int> ids(n), molecule_of(n);
  std::vector<double> mass(n);
  Eigen::Matrix3Xd nx(3, n), nv(3, n);
  std::vector<Eigen::Matrix3Xd> nc(carried.size(), Eigen::Matrix3Xd(3, n));
  for (int k = 0; k < n; ++k) {
    if (const int o = now[k]; o >= 0) {
      ids[k] = ids_[o], molecule_of[k] = owned_molecule_[o], mass[k] = owned_mass_[o];
      nx.col(k) = x.col(o), nv.col(k) = v.col(o);
      for (size_t c = 0; c < carried.size(); ++c) nc[c].col(k) = carried[c]->col(o);
      continue;
    }
    const double* w = from_messages[static_cast<size_t>(-1 - now[k])].second;
    ids[k] = static_cast<int>(w[0]), molecule_of[k] = static_cast<int>(w[1]), mass[k] = w[2];
    nx.col(k) = Eigen::Vector3d(w[3], w[4], w[5]);
    nv.col(k) = Eigen::Vector3d(w[6], w[7], w[8]);
    for (size_t c = 0; c < carried.size(); ++c)
      nc[c].col(k) = Eigen::Vector3d(w[9 + 3 * c], w[10 + 3 * c], w[11 + 3 * c]);
  }
  ids_ = std::move(ids);
  owned_molecule_ = std::move(molecule_of);
  owned_mass_ = std::move(mass);
  own();
  x = std::move(nx);
  v = std::move(nv);
  for (size_t c = 0; c < carried.size(); ++c) *carried[c] = std::move(nc[c]);
  if (molecules) {
    *molecules = merge_parts(std::move(parts));
    if (molecules->global != ids_)
      throw std::logic_error("Decomposition::migrate: the molecules that arrived are not the particles that did");
  }
  return true;
}

namespace {

// Per axis, the domain coordinates whose slab comes within `reach` of the coordinate q (wrapped
// into the box on a periodic axis), each once with its gap (the distance from q to the slab, over
// the periodic images; the edge slabs of an open axis reach to infinity, as domain_of clamps);
// `home` (the coordinate domain_of gives) is among them, at gap 0.
void slabs_within(const DomainGrid& g, int a, double q, double reach, int home,
                  std::vector<std::pair<int, double>>& out) {
  const int n = g.dims[a];
  out.assign(1, {home, 0.0});
  const auto add = [&](int c, double gap) {
    for (auto& [coordinate, least] : out)
      if (coordinate == c) return void(least = std::min(least, gap));
    out.emplace_back(c, gap);
  };
  // The slabs c of the image shifted by `shift` whose faces come within reach of q (the low one
  // from slab_of(q − reach), the high one from slab_of(q + reach), both in that image's frame).
  const auto add_image = [&](double shift, int lo, int hi) {
    for (int c = lo; c <= hi; ++c) {
      double below = g.face(a, c) + shift, above = g.face(a, c + 1) + shift;
      if (!g.periodic[a] && c == 0) below = -std::numeric_limits<double>::infinity();
      if (!g.periodic[a] && c == n - 1) above = std::numeric_limits<double>::infinity();
      add(c, std::max({0.0, below - q, q - above}));
    }
  };
  if (!g.periodic[a]) return add_image(0.0, g.slab_of(a, q - reach), g.slab_of(a, q + reach));
  const double length = g.length[a];
  const int first = static_cast<int>(floor_of((q - reach - g.origin[a]) / length));
  const int last = static_cast<int>(floor_of((q + reach - g.origin[a]) / length));
  for (int j = first; j <= last; ++j) {
    const double shift = j * length;
    add_image(shift, j == first ? g.slab_of(a, q - reach - shift) : 0,
              j == last ? g.slab_of(a, q + reach - shift) : n - 1);
  }
}

// slabs_within where every slab of the axis is wider than `reach`, so that a point's slabs within
// it are its own (`home`) and those beside it (on a periodic axis of two slabs the other one, on
// either side: the nearer gap): the same slabs with the same gaps, the faces read from `faces`
// (DomainGrid::face of 0 … dims[a]), without the walk over the images. Into `out` (room for
// three); returns their count. Inlined into the selection's loop over the beads near a face.
[[gnu::always_inline]] inline int adjacent_slabs_within(const DomainGrid& g, int a, std::span<const double> faces,
                                                        double q, double reach, int home, std::pair<int, double>* out) {
  const int n = g.dims[a];
  out[0] = {home, 0.0};
  int count = 1;
  if (n == 1) return count;
  const bool periodic = g.periodic[a] != 0;
  const double length = g.length[a];
  constexpr double kInfinity = std::numeric_limits<double>::infinity();
  // The gap from q to slab c whose faces are shifted by `shift` (slabs_within's add_image).
  const auto gap = [&](int c, double shift) {
    double below = faces[c] + shift, above = faces[c + 1] + shift;
    if (!periodic && c == 0) below = -kInfinity;
    if (!periodic && c == n - 1) above = kInfinity;
    return std::max({0.0, below - q, q - above});
  };
  if (home > 0 || periodic) {
    const int c = home > 0 ? home - 1 : n - 1;
    if (const double d = gap(c, home > 0 ? 0.0 : -length); d <= reach) out[count++] = {c, d};
  }
  if (home < n - 1 || periodic) {
    const int c = home < n - 1 ? home + 1 : 0;
    if (const double d = gap(c, home < n - 1 ? 0.0 : length); d <= reach) {
      if (out[count - 1].first == c)  // two periodic slabs: the other one is on both sides
        out[count - 1].second = std::min(out[count - 1].second, d);
      else
        out[count++] = {c, d};
    }
  }
  return count;
}

// v sized n, with a quarter more room when it grows past its capacity: a pair set grows and
// shrinks a little from one selection to the next, and a vector that grows past its capacity
// copies what it holds into a new block, at each selection where the kept buffers are sized to
// the last one exactly.
template <class T>
void resize_with_room(std::vector<T>& v, std::size_t n) {
  if (n > v.capacity()) v.reserve(n + n / 4);
  v.resize(n);
}

// The runs of the pairs (from[m], to[m]) for every m (`all`) and for the m with home[m] (`homes`),
// in one pass: the longest stretches where both go up by one from one m to the next. An absent
// `from` or `to` stands for the position of m among all (for `all`) or among the home ones (for
// `homes`). With `halos` (the halo pairs once) also the runs of the m without home[m], an absent
// side their position among those. The runs being made are kept in registers and stored when the
// next one starts.
template <bool kFrom, bool kTo>
void make_all_and_home_runs_of(const int* from, const int* to, const char* home, std::size_t count,
                               std::vector<ColumnRun>& all, std::vector<ColumnRun>& homes,
                               std::vector<ColumnRun>* halos) {
  all.clear(), homes.clear();
  if (halos) halos->clear();
  ColumnRun a{0, 0, 0}, h{0, 0, 0}, g{0, 0, 0};
  int position = 0, halo_position = 0;
  const auto extend = [](ColumnRun& run, int f, int t, std::vector<ColumnRun>& runs) {
    if (run.count > 0 && run.from + run.count == f && run.to + run.count == t) return void(++run.count);
    if (run.count > 0) runs.push_back(run);
    run = {f, t, 1};
  };
  for (std::size_t m = 0; m < count; ++m) {
    const int f = kFrom ? from[m] : static_cast<int>(m), t = kTo ? to[m] : static_cast<int>(m);
    extend(a, f, t, all);
    if (home[m]) {
      extend(h, kFrom ? f : position, kTo ? t : position, homes);
      ++position;
    } else if (halos) {
      extend(g, kFrom ? f : halo_position, kTo ? t : halo_position, *halos);
      ++halo_position;
    }
  }
  if (a.count > 0) all.push_back(a);
  if (h.count > 0) homes.push_back(h);
  if (halos && g.count > 0) halos->push_back(g);
}

void make_all_and_home_runs(std::span<const int> from, std::span<const int> to, std::span<const char> home,
                            std::size_t count, std::vector<ColumnRun>& all, std::vector<ColumnRun>& homes,
                            std::vector<ColumnRun>* halos) {
  if (!from.empty() && !to.empty())
    return make_all_and_home_runs_of<true, true>(from.data(), to.data(), home.data(), count, all, homes, halos);
  if (!from.empty())
    return make_all_and_home_runs_of<true, false>(from.data(), nullptr, home.data(), count, all, homes, halos);
  make_all_and_home_runs_of<false, true>(nullptr, to.data(), home.data(), count, all, homes, halos);
}

// Columns run.to … of `source` added onto run.from … of `target` (reverse's direction), run by
// run in order: the halo pairs once's partial forces onto their owners' forces.
void add_runs_backwards(std::span<const ColumnRun> runs, const double* __restrict source, double* __restrict target) {
  for (const ColumnRun& run : runs) {
    const double* from = source + 3 * static_cast<std::ptrdiff_t>(run.to);
    double* to = target + 3 * static_cast<std::ptrdiff_t>(run.from);
    if (run.count == 1) {  // most halo runs: a lone halo bead between home beads
      to[0] += from[0], to[1] += from[1], to[2] += from[2];
      continue;
    }
    for (int q = 0; q < 3 * run.count; ++q) to[q] += from[q];
  }
}

// The copies by runs. A run of `count` columns is 3 × count consecutive doubles on both sides, so
// it is copied as one stretch of doubles, four at a time (AVX2, where the CPU has it: one load and
// one store per four doubles, the last four overlapping the ones before where the stretch is not a
// multiple of four) — a copy moves bits, so any order gives the same array. A call of memcpy
// costs tens of instructions on the few beads of most runs of a pair set with a halo (a halo bead
// ends a run of home beads), and glibc's memcpy moves a long stretch with `rep movsb`; a column
// loop moves three doubles in about eight instructions.
//
// `backwards`: each run read at run.to and written at run.from (reverse's direction).
void copy_runs_scalar(std::span<const ColumnRun> runs, const double* source, double* target, bool backwards) {
  for (const ColumnRun& run : runs) {
    const double* from = source + 3 * static_cast<std::ptrdiff_t>(backwards ? run.to : run.from);
    double* to = target + 3 * static_cast<std::ptrdiff_t>(backwards ? run.from : run.to);
    for (int q = 0; q < run.count; ++q, from += 3, to += 3) {
      const double x = from[0], y = from[1], z = from[2];
      to[0] = x, to[1] = y, to[2] = z;
    }
  }
}

// Zeros on each run's columns run.to … (from = to).
void clear_runs_scalar(std::span<const ColumnRun> runs, double* target) {
  for (const ColumnRun& run : runs) {
    double* to = target + 3 * static_cast<std::ptrdiff_t>(run.to);
    for (int q = 0; q < run.count; ++q, to += 3) to[0] = 0.0, to[1] = 0.0, to[2] = 0.0;
  }
}

#if defined(__x86_64__)
// Not turned into calls of memcpy and memset (GCC's loop distribution takes these loops for them):
// a call costs tens of instructions on a run of a few columns, and glibc moves a long one with
// `rep movsb`, which callgrind counts as an instruction per byte.
#define STIFFMD_NO_LIBC_CALLS gnu::target("avx2"), gnu::optimize("no-tree-loop-distribute-patterns")
[[STIFFMD_NO_LIBC_CALLS]] void copy_runs_avx2(std::span<const ColumnRun> runs, const double* __restrict source,
                                              double* __restrict target, bool backwards) {
  for (const ColumnRun& run : runs) {
    const double* from = source + 3 * static_cast<std::ptrdiff_t>(backwards ? run.to : run.from);
    double* to = target + 3 * static_cast<std::ptrdiff_t>(backwards ? run.from : run.to);
    const std::ptrdiff_t n = 3 * static_cast<std::ptrdiff_t>(run.count);
    if (n < 4) {  // one column
      const double x = from[0], y = from[1], z = from[2];
      to[0] = x, to[1] = y, to[2] = z;
      continue;
    }
    std::ptrdiff_t d = 0;
    for (; d + 4 <= n; d += 4) _mm256_storeu_pd(to + d, _mm256_loadu_pd(from + d));
    if (d < n) _mm256_storeu_pd(to + n - 4, _mm256_loadu_pd(from + n - 4));
  }
}

[[STIFFMD_NO_LIBC_CALLS]] void clear_runs_avx2(std::span<const ColumnRun> runs, double* __restrict target) {
  const __m256d zero = _mm256_setzero_pd();
  for (const ColumnRun& run : runs) {
    double* to = target + 3 * static_cast<std::ptrdiff_t>(run.to);
    const std::ptrdiff_t n = 3 * static_cast<std::ptrdiff_t>(run.count);
    if (n < 4) {
      to[0] = 0.0, to[1] = 0.0, to[2] = 0.0;
      continue;
    }
    std::ptrdiff_t d = 0;
    for (; d + 4 <= n; d += 4) _mm256_storeu_pd(to + d, zero);
    if (d < n) _mm256_storeu_pd(to + n - 4, zero);
  }
}

#undef STIFFMD_NO_LIBC_CALLS

// Before main: the CPU's features read first (__builtin_cpu_init), as GCC asks of a check made
// while constructors run.
const bool kHaveAvx2 = (__builtin_cpu_init(), __builtin_cpu_supports("avx2"));
#endif

// Columns run.from … of `source` onto run.to … of `target` (backwards: run.to … onto run.from …),
// for every run; source and target do not overlap.
void copy_runs(std::span<const ColumnRun> runs, const double* source, double* target, bool backwards = false) {
#if defined(__x86_64__)
  if (kHaveAvx2) return copy_runs_avx2(runs, source, target, backwards);
#endif
  copy_runs_scalar(runs, source, target, backwards);
}

void clear_runs(std::span<const ColumnRun> runs, double* target) {
#if defined(__x86_64__)
  if (kHaveAvx2) return clear_runs_avx2(runs, target);
#endif
  clear_runs_scalar(runs, target);
}

}  // namespace

void Decomposition::set_owned_pair_data(PairBeadData owned) {
  owned_data_ = std::move(owned);
  // The beads it is of (checked at the selection: the owned particles may change before it);
  // −1: a charge column not of the beads'.
  owned_data_beads_ = static_cast<long>(owned_data_.type.size());
  if (owned_data_.charged && owned_data_.charge.size() != owned_data_.type.size()) owned_data_beads_ = -1;
  carry_ = true;
  owned_packed_ = false;
}

int Decomposition::pair_slot(int global) const {
  const auto it = std::lower_bound(pair_ids_.begin(), pair_ids_.end(), global);
  return it != pair_ids_.end() && *it == global ? static_cast<int>(it - pair_ids_.begin()) : -1;
}

namespace {

// What owned column k carries to a pair set (Decomposition::set_owned_pair_data), written at w: its
// type, its charge (when charged), and per pair term its partner count and then each partner's
// global index and two weights. Every number is an integer below 2⁵³ or the double itself: exact.
// Returns the word past it.
double* pack_bead_data(const PairBeadData& d, int k, double* w) {
  *w++ = d.type[k];
  if (d.charged) *w++ = d.charge[k];
  for (const SpecialPartners& s : d.special) {
    const int first = s.start[k], last = s.start[k + 1];
    *w++ = last - first;
    for (int q = first; q < last; ++q) w[0] = s.partner[q], w[1] = s.weight[q], w[2] = s.weight_coul[q], w += 3;
  }
  return w;
}

}  // namespace

void Decomposition::pack_owned_words() {
  const int owned = num_owned();
  owned_word_at_.resize(owned + 1);
  std::size_t words = 0;
  for (int k = 0; k < owned; ++k) {
    owned_word_at_[k] = words;
    words += 1 + owned_data_.charged + owned_data_.special.size();
    for (const SpecialPartners& s : owned_data_.special)
      words += 3 * static_cast<std::size_t>(s.start[k + 1] - s.start[k]);
  }
  owned_word_at_[owned] = words;
  owned_words_.resize(words);
  for (int k = 0; k < owned; ++k) pack_bead_data(owned_data_, k, owned_words_.data() + owned_word_at_[k]);
  owned_packed_ = true;
  // The packed words are the beads' data from now on: the per-bead arrays go (a second copy of
  // them, docs/parallel.md "What a rank holds"). Each term's partner offsets stay: a message counts
  // its beads' partners from them.
  std::vector<int>().swap(owned_data_.type);
  std::vector<double>().swap(owned_data_.charge);
  for (SpecialPartners& sp : owned_data_.special) {
    std::vector<int>().swap(sp.partner);
    std::vector<double>().swap(sp.weight);
    std::vector<double>().swap(sp.weight_coul);
  }
}

void Decomposition::select_pair_set(const Eigen::Matrix3Xd& x) {
  const ScopedPhase phase(Phase::domain);
  if (carry_ && owned_data_beads_ != num_owned())
    throw std::logic_error("Decomposition::select_pair_set: the owned beads' pair data is not of the owned particles");
  ++selections_;
  at_selection_ = x;
  const int ranks = comm_.size(), me = comm_.rank(), owned = num_owned();
  // Each owned bead goes to every rank whose domain comes within R of its position wrapped into
  // the box (a hair more, so that rounding cannot drop a bead at R: the distance to the domain's
  // box, not per axis), as a home bead to the one whose domain holds it. A bead's partners within r_c of it while no
  // bead has moved margin/2 were within r_c + margin of it at the selection, hence within R of its home's domain.
  const double reach = radius_ * (1.0 + 1e-12) + 1e-12;
  const BoxWrap into_box(box_);
  for (Plan& p : out_) p.owned.clear(), p.home.clear(), p.homes = 0;
  local_.owned.clear(), local_.home.clear(), local_.homes = 0;
  std::vector<std::pair<int, double>> axis[3];
  std::pair<int, double> near[3][3];
  const Eigen::Vector3i& dims = grid_.dims;
  const double reach2 = reach * reach;
  // Per axis its faces, and whether a point's slabs within R are its own and those beside it
  // (adjacent_slabs_within): every slab wider than R (with room for rounding).
  std::vector<double> faces[3], inner_lo[3], inner_hi[3];
  bool adjacent[3];
  for (int a = 0; a < 3; ++a) {
    const int n = dims[a];
    faces[a].resize(n + 1);
    for (int c = 0; c <= n; ++c) faces[a][c] = grid_.face(a, c);
    double narrowest = std::numeric_limits<double>::infinity();
    for (int c = 0; c < n; ++c) narrowest = std::min(narrowest, faces[a][c + 1] - faces[a][c]);
    adjacent[a] = n == 1 || narrowest > reach * (1.0 + 1e-9);
    // A bead in slab c lies deeper than R inside it on axis a where q − inner_lo ≥ R and
    // inner_hi − q ≥ R: the slab's faces, an open axis's edge faces and an uncut axis's at
    // infinity (nothing lies beyond them), so that the test below takes no branch per axis.
    inner_lo[a].resize(n), inner_hi[a].resize(n);
    for (int c = 0; c < n; ++c) {
      const bool open = !grid_.periodic[a];
      inner_lo[a][c] = n == 1 || (c == 0 && open) ? -std::numeric_limits<double>::infinity() : faces[a][c];
      inner_hi[a][c] = n == 1 || (c == n - 1 && open) ? std::numeric_limits<double>::infinity() : faces[a][c + 1];
    }
  }
  for (int k = 0; k < owned; ++k) {
    Eigen::Vector3d q;
    for (int a = 0; a < 3; ++a) q[a] = into_box(x(a, k), a);
    // q is wrapped already: its slabs directly (domain_of would wrap it again).
    const int hc[3] = {grid_.slab_of(0, q[0]), grid_.slab_of(1, q[1]), grid_.slab_of(2, q[2])};
    const int home = (hc[0] * dims[1] + hc[1]) * dims[2] + hc[2];
    // Most beads lie deeper than R inside their domain on every cut axis: home alone.
    bool inside = true;
    for (int a = 0; a < 3; ++a) inside &= (q[a] - inner_lo[a][hc[a]] >= reach) & (inner_hi[a][hc[a]] - q[a] >= reach);
    if (inside) {
      Plan& p = home == me ? local_ : out_[home];
      p.owned.push_back(k);
      p.home.push_back(1);
      ++p.homes;
      continue;
    }
    // Per axis the slabs within R of q with their gaps: at most three where the slabs are wider
    // than R (near[a]), any number on narrower ones (axis[a]).
    const std::pair<int, double>* list[3];
    int length[3];
    for (int a = 0; a < 3; ++a) {
      if (adjacent[a]) {
        length[a] = adjacent_slabs_within(grid_, a, faces[a], q[a], reach, hc[a], near[a]);
        list[a] = near[a];
      } else {
        slabs_within(grid_, a, q[a], reach, hc[a], axis[a]);
        list[a] = axis[a].data(), length[a] = static_cast<int>(axis[a].size());
      }
    }
    // The domains within R of q: the per-axis gaps add in squares (a domain's corner is farther
    // than its faces).
    for (const auto& [cx, gx] : std::span(list[0], length[0]))
      for (const auto& [cy, gy] : std::span(list[1], length[1]))
        for (const auto& [cz, gz] : std::span(list[2], length[2])) {
          if (gx * gx + gy * gy + gz * gz > reach2) continue;
          const int d = (cx * dims[1] + cy) * dims[2] + cz;
          Plan& p = d == me ? local_ : out_[d];
          p.owned.push_back(k);
          p.home.push_back(d == home);
          p.homes += d == home;
        }
  }
  // The runs of owned columns each rank is sent (sender's side of the plan): the carried words
  // of consecutive owned beads are consecutive (owned_words_), so a message's data is copied by
  // these runs.
  for (Plan& p : out_) make_all_and_home_runs(p.owned, {}, p.home, p.owned.size(), p.all, p.home_runs, halo_runs_of(p));
  // The receivers learn which beads come, which are home, and what they carry. A message is
  // [n][per pair term, its partners' count over the n beads][n words: a global index g as g
  // (home) or −1 − g (halo)][the n beads' carried words (pack_bead_data), in the same order].
  const std::size_t terms = carry_ ? owned_data_.special.size() : 0;
  if (carry_ && !owned_packed_) pack_owned_words();
  std::vector<std::vector<double>>&out = selection_out_, &in = selection_in_;
  out.resize(ranks);
  for (int r = 0; r < ranks; ++r) {
    const Plan& p = out_[r];
    const std::size_t beads = p.owned.size();
    std::size_t words = 0;
    if (carry_)
      for (const Run& run : p.all) words += owned_word_at_[run.from + run.count] - owned_word_at_[run.from];
    std::vector<double>& b = out[r];
    resize_with_room(b, beads == 0 ? 0 : 1 + terms + beads + words);  // no message without beads
    if (beads == 0) continue;
    double* w = b.data();
    *w++ = static_cast<double>(beads);
    for (std::size_t t = 0; t < terms; ++t) {
      const std::vector<int>& start = owned_data_.special[t].start;
      std::size_t partners = 0;
      for (const Run& run : p.all) partners += start[run.from + run.count] - start[run.from];
      *w++ = static_cast<double>(partners);
    }
    for (std::size_t m = 0; m < beads; ++m) {
      const int g = ids_[p.owned[m]];
      *w++ = p.home[m] ? g : -1 - g;
    }
    if (carry_)
      for (const Run& run : p.all)
        w = std::copy(owned_words_.begin() + owned_word_at_[run.from],
                      owned_words_.begin() + owned_word_at_[run.from + run.count], w);
  }
  comm_.exchange(out, in);
  // The pair set: every bead received or kept, in increasing global index (so a home bead's pairs
  // are summed in the one-process order: forcefields/neighbor_list.hpp). Each member is a key
  // g · 2³² + source · 2 + home, so that merging the keys orders the members by global index and
  // says where each came from; the sources' own orders are increasing (the local beads in the
  // owned order, each rank's in its owned order).
  std::vector<std::uint64_t>& keys = merge_keys_;
  std::vector<std::size_t>& bounds = merge_bounds_;  // the runs' ends, the local one first
  std::size_t arriving = 0;
  for (int r = 0; r < ranks; ++r) arriving += in[r].empty() ? 0 : static_cast<std::size_t>(in[r][0]);
  const std::size_t local_count = local_.owned.size(), total = local_count + arriving;
  resize_with_room(keys, total);
  bounds.assign(1, local_count);
  const auto key = [](int g, int source, bool home) {
    return static_cast<std::uint64_t>(g) << 32 | static_cast<std::uint64_t>(source) << 1 | (home ? 1u : 0u);
  };
  for (std::size_t m = 0; m < local_count; ++m) keys[m] = key(ids_[local_.owned[m]], me, local_.home[m] != 0);
  std::size_t filled = local_count;
  std::vector<std::size_t>& partners_total = partners_total_;
  partners_total.assign(terms, 0);
  for (int r = 0; r < ranks; ++r) {
    Plan& p = in_[r];
    const std::size_t count = in[r].empty() ? 0 : static_cast<std::size_t>(in[r][0]);
    resize_with_room(p.slot, count), resize_with_room(p.home, count), p.homes = 0;  // every entry written below
    if (count == 0) continue;
    for (std::size_t t = 0; t < terms; ++t) partners_total[t] += static_cast<std::size_t>(in[r][1 + t]);
    const double* w = in[r].data() + 1 + terms;
    for (std::size_t m = 0; m < count; ++m) {
      const bool home = w[m] >= 0.0;
      keys[filled + m] = key(home ? static_cast<int>(w[m]) : static_cast<int>(-1.0 - w[m]), r, home);
      p.home[m] = home, p.homes += home;
    }
    filled += count;
    bounds.push_back(filled);
  }
  // Merged, not sorted: the arrivals' runs pairwise, level by level, then with the local beads
  // (most of the set: merged once, where merging each rank's run into the growing set moved them
  // once per rank).
  {
    std::vector<std::uint64_t>& other = merge_other_;
    resize_with_room(other, total);
    std::vector<std::size_t>& merged = merge_next_bounds_;
    const auto at = [](std::vector<std::uint64_t>& v, std::size_t e) {
      return v.begin() + static_cast<std::ptrdiff_t>(e);
    };
    // Level by level: the arrivals' runs (after bounds[0]) two by two into one, from keys into
    // other and back; the local run stays where it is in both.
    if (bounds.size() > 2) std::copy(at(keys, 0), at(keys, bounds[0]), at(other, 0));
    while (bounds.size() > 2) {
      merged.assign(1, bounds[0]);
      std::size_t q = 1;
      for (; q + 1 < bounds.size(); q += 2) {
        std::merge(at(keys, bounds[q - 1]), at(keys, bounds[q]), at(keys, bounds[q]), at(keys, bounds[q + 1]),
                   at(other, bounds[q - 1]));
        merged.push_back(bounds[q + 1]);
      }
      if (q < bounds.size()) {  // an odd run out: carried over
        std::copy(at(keys, bounds[q - 1]), at(keys, bounds[q]), at(other, bounds[q - 1]));
        merged.push_back(bounds[q]);
      }
      keys.swap(other);
      bounds.swap(merged);
    }
    if (bounds.size() == 2) {
      std::merge(at(keys, 0), at(keys, bounds[0]), at(keys, bounds[0]), at(keys, bounds[1]), at(other, 0));
      keys.swap(other);
    }
  }
  const int n = static_cast<int>(total);
  resize_with_room(pair_ids_, n);
  resize_with_room(halo_flag_, n);
  resize_with_room(local_.slot, local_count);
  num_home_ = 0;
  // Per source, the slots of its beads in its order (each source's beads come in that order), and
  // where its next bead's carried words start (an arrival's follow one another in its message; a
  // local bead's are its owned words).
  std::vector<int*>& slot_of = source_slots_;
  std::vector<int>& next = source_next_;
  std::vector<const double*>& words = source_words_;
  slot_of.resize(ranks), next.assign(ranks, 0), words.resize(ranks);
  for (int r = 0; r < ranks; ++r) {
    slot_of[r] = (r == me ? local_.slot : in_[r].slot).data();
    words[r] = in[r].empty() ? nullptr : in[r].data() + 1 + terms + static_cast<std::size_t>(in[r][0]);
  }
  // The pair set's carried data, sized for the pass below.
  PairBeadData& d = pair_data_;
  std::vector<int>& fill = partners_filled_;
  fill.assign(terms, 0);
  if (carry_) {
    d.charged = owned_data_.charged;
    resize_with_room(d.type, n);
    resize_with_room(d.charge, d.charged ? n : 0);
    d.special.resize(terms);
    for (std::size_t t = 0; t < terms; ++t) {
      // Room for the partners of every owned bead and every arrival (the local beads are most of
      // the owned ones); cut to those written after the pass below.
      const std::size_t room = partners_total[t] + static_cast<std::size_t>(owned_data_.special[t].start.back());
      SpecialPartners& s = d.special[t];
      resize_with_room(s.start, n + 1), s.start[0] = 0;
      resize_with_room(s.partner, room), resize_with_room(s.weight, room), resize_with_room(s.weight_coul, room);
    }
  }
  // The slots: each member's global index and flag, its source's next slot, and the halo's runs
  // of slots (from = to).
  halo_runs_.clear();
  {
    int* const pair_ids = pair_ids_.data();
    char* const halo = halo_flag_.data();
    int homes = 0;
    ColumnRun run{0, 0, 0};
    for (int e = 0; e < n; ++e) {
      const std::uint64_t k = keys[e];
      const int source = static_cast<int>(static_cast<std::uint32_t>(k) >> 1);
      const bool home = (k & 1u) != 0;
      pair_ids[e] = static_cast<int>(k >> 32);
      halo[e] = !home;
      homes += home;
      slot_of[source][next[source]++] = e;
      if (home) continue;
      if (run.count > 0 && run.to + run.count == e) {
        ++run.count;
        continue;
      }
      if (run.count > 0) halo_runs_.push_back(run);
      run = {e, e, 1};
    }
    if (run.count > 0) halo_runs_.push_back(run);
    num_home_ = homes;
  }
  // What the beads carried, per slot: each slot's words read in turn from its source (an
  // arrival's follow one another in its message; a local bead's are its owned words).
  if (carry_) {
    std::vector<SpecialRow>& rows = special_rows_;
    rows.resize(terms);
    for (std::size_t t = 0; t < terms; ++t) {
      SpecialPartners& s = d.special[t];
      rows[t] = {s.start.data(), s.partner.data(), s.weight.data(), s.weight_coul.data()};
    }
    int* const type = d.type.data();
    double* const charge = d.charge.data();
    const bool charged = d.charged;
    const int* const local_owned = local_.owned.data();
    int local_next = 0;
    for (int e = 0; e < n; ++e) {
      const int source = static_cast<int>(static_cast<std::uint32_t>(keys[e]) >> 1);
      const double* w = source == me ? owned_words_.data() + owned_word_at_[local_owned[local_next++]] : words[source];
      type[e] = static_cast<int>(*w++);
      if (charged) charge[e] = *w++;
      for (std::size_t t = 0; t < terms; ++t) {
        SpecialRow& row = rows[t];
        const int count = static_cast<int>(*w++);
        for (int q = fill[t], end = fill[t] + count; q < end; ++q, w += 3)
          row.partner[q] = static_cast<int>(w[0]), row.weight[q] = w[1], row.weight_coul[q] = w[2];
        fill[t] += count;
        row.start[e + 1] = fill[t];
      }
      if (source != me) words[source] = w;
    }
    for (std::size_t t = 0; t < terms; ++t) {
      SpecialPartners& s = d.special[t];
      s.partner.resize(fill[t]), s.weight.resize(fill[t]), s.weight_coul.resize(fill[t]);
    }
  }
  // The copies' runs.
  make_all_and_home_runs(local_.owned, local_.slot, local_.home, local_.owned.size(), local_.all, local_.home_runs,
                         halo_runs_of(local_));
  for (Plan& p : in_) make_all_and_home_runs({}, p.slot, p.home, p.slot.size(), p.all, p.home_runs, halo_runs_of(p));
  // What one evaluation with forces sends: positions out (and the forces so far of the home
  // beads), the home beads' forces back (with the halo pairs once, every bead's).
  halo_doubles_ = 0;
  halo_messages_ = 0;
  for (int r = 0; r < ranks; ++r) {
    const std::int64_t out = 3 * static_cast<std::int64_t>(out_[r].owned.size() + out_[r].homes);
    const std::int64_t back = 3 * static_cast<std::int64_t>(halo_pairs_once_ ? in_[r].slot.size() : in_[r].homes);
    halo_doubles_ += out + back;
    halo_messages_ += (out > 0) + (back > 0);
  }
}

double Decomposition::displacement_since_selection(const Eigen::Matrix3Xd& x) const {
  const ScopedPhase phase(Phase::domain);
  double worst = 0.0;
  if (x.cols() != at_selection_.cols()) {
    worst = std::numeric_limits<double>::infinity();
  } else {
    const double* p = x.data();
    const double* p0 = at_selection_.data();
    for (Eigen::Index k = 0; k < 3 * x.cols(); k += 3) {
      const double dx = p[k] - p0[k], dy = p[k + 1] - p0[k + 1], dz = p[k + 2] - p0[k + 2];
      const double d2 = dx * dx + dy * dy + dz * dz;
      // A value that is not finite makes it infinite (and stays so: nothing exceeds it).
      if (!(d2 <= worst)) worst = d2 == d2 ? d2 : std::numeric_limits<double>::infinity();
    }
  }
  comm_.max(&worst, 1);
  return std::sqrt(worst);
}

double Decomposition::imbalance(const Eigen::Matrix3Xd& x) const {
  std::vector<double> loads = domain_loads(grid_, x);
  comm_.sum(loads.data(), static_cast<int>(loads.size()));
  return load_imbalance(loads);
}

bool Decomposition::rebalance(const Eigen::Matrix3Xd& x) {
  if (balance_.when != BalanceSettings::When::dynamic) return false;
  const ScopedPhase phase(Phase::domain);
  // Every bead is home on one rank: the mean is N / ranks, and one max of the home beads (counted
  // at the selection) tells every rank alike whether to recut.
  const double mean = static_cast<double>(num_particles_) / comm_.size();
  const double most = comm_.max(static_cast<double>(num_home_));
  const double before = mean > 0.0 ? most / mean : 1.0;
  if (before <= balance_.threshold) return false;
  auto [cut, after] = recut(x);
  // A recut costs a selection of the pair sets (every rank's lists built again) and the parts of
  // the ranks whose molecules move: kept when it halves the excess over 1 at least, so that a small
  // system's fluctuations about the threshold are not chased at every selection.
  if (after - 1.0 > 0.5 * (before - 1.0)) return false;
  grid_ = std::move(cut);
  ++recuts_;
  return true;
}

void Decomposition::forward(const Eigen::Matrix3Xd& a, Eigen::Matrix3Xd& pair, const Eigen::Matrix3Xd* owned_f,
                            Eigen::Matrix3Xd* pair_f) const {
  const ScopedPhase phase(Phase::domain);
  const int ranks = comm_.size();
  const bool forces = owned_f && pair_f;
  const Eigen::Index n = static_cast<Eigen::Index>(pair_ids_.size());
  pair.resize(3, n);  // no allocation once sized
  // The owned columns go as they are; the pair set's array is wrapped into the box in place once
  // they have landed, as one stretch (BoxWrap::wrap_particles: four beads at a time). The wrap is
  // a function of the position alone, so each bead's wrapped position is the bits its owner (or
  // one process) would make, and no wrapped copy of the owned array is kept.
  if (forces) {
    pair_f->resize(3, n);
    clear_runs(halo_runs_, pair_f->data());
  }
  copy_runs(local_.all, a.data(), pair.data());
  if (forces) copy_runs(local_.home_runs, owned_f->data(), pair_f->data());
  std::vector<std::vector<double>>& send = send_buffer_[forces ? kPositionsAndForces : kPositions];
  std::vector<std::vector<double>>& recv = recv_buffer_[forces ? kPositionsAndForces : kPositions];
  for (int r = 0; r < ranks; ++r) {
    const Plan& p = out_[r];
    std::vector<double>& b = send[r];
    const std::size_t positions = 3 * p.owned.size();
    resize_with_room(b, positions + (forces ? 3 * p.homes : 0));
    copy_runs(p.all, a.data(), b.data());
    if (forces) copy_runs(p.home_runs, owned_f->data(), b.data() + positions);
    resize_with_room(recv[r], 3 * in_[r].slot.size() + (forces ? 3 * in_[r].homes : 0));
  }
  comm_.exchange_known(send, recv);
  for (int r = 0; r < ranks; ++r) {
    const Plan& p = in_[r];
    const double* w = recv[r].data();
    copy_runs(p.all, w, pair.data());
    if (forces) copy_runs(p.home_runs, w + 3 * p.slot.size(), pair_f->data());
  }
  BoxWrap(box_).wrap_particles(pair.data(), pair.data(), 0, n);
}

void Decomposition::reverse(const Eigen::Matrix3Xd& pair_f, Eigen::Matrix3Xd& owned_f) const {
  const ScopedPhase phase(Phase::domain);
  const int ranks = comm_.size();
  // The home runs read backwards: slot → owned column (locally), slot → message position.
  copy_runs(local_.home_runs, pair_f.data(), owned_f.data(), true);
  std::vector<std::vector<double>>& send = send_buffer_[kForces];
  std::vector<std::vector<double>>& recv = recv_buffer_[kForces];
  // A message: the home beads' forces, then (halo pairs once) the halo beads' pair forces.
  for (int r = 0; r < ranks; ++r) {
    const Plan& p = in_[r];
    std::vector<double>& b = send[r];
    const std::size_t homes = 3 * static_cast<std::size_t>(p.homes);
    resize_with_room(b, halo_pairs_once_ ? 3 * p.slot.size() : homes);
    copy_runs(p.home_runs, pair_f.data(), b.data(), true);
    if (halo_pairs_once_) copy_runs(p.halo_runs, pair_f.data(), b.data() + homes, true);
    resize_with_room(recv[r], 3 * (halo_pairs_once_ ? out_[r].owned.size() : static_cast<size_t>(out_[r].homes)));
  }
  comm_.exchange_known(send, recv);
  for (int r = 0; r < ranks; ++r) copy_runs(out_[r].home_runs, recv[r].data(), owned_f.data(), true);
  if (!halo_pairs_once_) return;
  // Each bead's force is now its home's; its pair forces as a halo bead added in a fixed order:
  // this rank's pair set's, then rank by rank.
  add_runs_backwards(local_.halo_runs, pair_f.data(), owned_f.data());
  for (int r = 0; r < ranks; ++r)
    add_runs_backwards(out_[r].halo_runs, recv[r].data() + 3 * static_cast<size_t>(out_[r].homes), owned_f.data());
}

void Decomposition::gather_columns(const std::vector<const Eigen::Matrix3Xd*>& local,
                                   const std::vector<Eigen::Matrix3Xd*>& whole, int num_particles, int block) const {
  const size_t arrays = local.size(), words = 1 + 3 * arrays;
  if (comm_.root())
    for (Eigen::Matrix3Xd* w : whole)
      if (w->cols() != num_particles) w->resize(3, num_particles);
  std::vector<double> mine;
  std::vector<std::vector<double>> all;
  int k = 0;  // the owned columns increase in global index: one pass over them
  for (int first = 0; first < num_particles; first += block) {
    const int end = std::min(num_particles, first + block);
    mine.clear();
    for (; k < num_owned() && ids_[k] < end; ++k) {
      mine.push_back(ids_[k]);
      for (const Eigen::Matrix3Xd* a : local)
        for (int c = 0; c < 3; ++c) mine.push_back((*a)(c, k));
    }
    comm_.gather(mine, all);
    for (const std::vector<double>& b : all)
      for (size_t at = 0; at + words <= b.size(); at += words) {
        const int g = static_cast<int>(b[at]);
        for (size_t a = 0; a < arrays; ++a)
          whole[a]->col(g) = Eigen::Vector3d(b[at + 1 + 3 * a], b[at + 2 + 3 * a], b[at + 3 + 3 * a]);
      }
  }
}

void Decomposition::gather_columns(const std::vector<Eigen::Matrix3Xd>& local, std::vector<Eigen::Matrix3Xd>& whole,
                                   int num_particles, int block) const {
  whole.assign(local.size(), Eigen::Matrix3Xd(3, 0));
  std::vector<const Eigen::Matrix3Xd*> in;
  std::vector<Eigen::Matrix3Xd*> out;
  for (size_t a = 0; a < local.size(); ++a) in.push_back(&local[a]), out.push_back(&whole[a]);
  gather_columns(in, out, num_particles, block);
}

int Decomposition::first_non_finite(const Eigen::Matrix3Xd& x, const Eigen::Matrix3Xd& v) const {
  if (all_finite(x.data(), x.size()) && all_finite(v.data(), v.size())) return -1;
  for (int k = 0; k < num_owned(); ++k)
    if (!x.col(k).allFinite() || !v.col(k).allFinite()) return k;
  return -1;
}

}  // namespace stiffmd
