// Domain decomposition with two ownerships (docs/parallel.md): which rank integrates which
// molecule, which rank computes which bead's pair forces, and the messages that move positions out
// and forces back.
//
// A grid of domains covers the box. A molecule (a lone bead is a molecule of one) is integrated by
// the rank whose domain holds its anchor, the centre of mass wrapped into the box (its owner); it
// moves to another rank when its anchor has gone more than the margin past its owner's domain. A
// rank's owned particles are its local arrays, in increasing global index. The pair forces are
// computed where the beads are: a bead's home is the rank whose domain held its position at the
// last selection of the pair sets; that rank's pair set is every bead within R = r_c + margin of
// its domain, in increasing global index (its home beads and a thin halo). A bead's partners
// within r_c lie in its home's pair set while no bead has moved margin/2 since the selection, and
// its partners within r_c + skin (a list build's) while none has moved (margin − skin)/2, so
// the pair sets are selected again before that (GhostedPairs, with displacement_since_selection
// at each list build and NeighborList::set_displacement_limit between builds). Per pair evaluation the owners send each
// bead's position to the ranks whose pair set holds it, and its force so far to its home (forward); the home ranks send
// the forces back (reverse). Positions are their owners' coordinates wrapped into the box, never a shifted image: every
// pair distance goes through the box's minimum image, as in one process.
#pragma once

#include <Eigen/Core>
#include <array>
#include <cstdint>
#include <span>
#include <utility>
#include <vector>

#include "core/box.hpp"
#include "core/communicator.hpp"
#include "core/state.hpp"
#include "core/topology.hpp"
#include "engine/domain/part_molecules.hpp"
#include "engine/scene/parallel_settings.hpp"  // BalanceSettings

namespace stiffmd {

// The domains: a tensor-product grid of dims[a] slabs per axis over the box (periodic axes) or over
// the anchors' extent at the start (open axes). The slabs are equal unless the load balance cut
// them (docs/parallel.md, "Load balance"): cut[a] holds the faces of axis a as fractions of its
// length, 0 = cut[a][0] < … < cut[a][dims[a]] = 1 (empty: equal slabs), so that the slabs scale
// with the box under a barostat.
struct DomainGrid {
  Eigen::Vector3i dims = Eigen::Vector3i::Ones();
  Eigen::Vector3d origin = Eigen::Vector3d::Zero(), length = Eigen::Vector3d::Ones();
  Eigen::Vector3i periodic = Eigen::Vector3i::Zero();
  std::array<std::vector<double>, 3> cut;
  int size() const { return dims.prod(); }
  // The low face of slab c of axis a (c = dims[a]: the high face of the last slab).
  double face(int a, int c) const {
    return cut[a].empty() ? origin[a] + c * (length[a] / dims[a]) : origin[a] + length[a] * cut[a][c];
  }
  // The slab of axis a that holds the coordinate q (not wrapped; clamped to the edge slabs). Equal
  // slabs: floor((q − origin)/L × n) clamped into 0 … n − 1 (a NaN to 0), inline (the selection of
  // the pair sets places every owned bead on every axis); cut slabs: cut_slab_of.
  int slab_of(int a, double q) const {
    const int n = dims[a];
    if (!cut[a].empty()) return cut_slab_of(a, q);
    const double s = (q - origin[a]) / length[a] * n;
    return s >= 0.0 && s < n ? static_cast<int>(s) : (s >= n ? n - 1 : 0);
  }
  // The slab of cut slabs whose low face is the last at or below q.
  int cut_slab_of(int a, double q) const;
  // The domain of a point (wrapped on periodic axes; clamped to the edge domains on open axes).
  int domain_of(const Eigen::Vector3d& p) const;
  // Whether p lies within `slack` of the domain (periodic axes: of its nearest image).
  bool within(int domain, const Eigen::Vector3d& p, double slack) const;
};

// The grid for `ranks` domains: `dims` when given (product = ranks), else the factorisation of
// ranks into three that makes the domains closest to cubes (least surface per volume), periodic
// axes cut first. `anchors`: the molecules' anchors, for the extent of open axes.
DomainGrid make_domain_grid(const Box& box, int ranks, const Eigen::Vector3i* dims, const Eigen::Matrix3Xd& anchors);

// The measure per domain of grid g: the beads of x (columns) counted in the domain that holds them.
std::vector<double> domain_loads(const DomainGrid& g, const Eigen::Matrix3Xd& x);
// max/mean of the loads (1 when there is no load).
double load_imbalance(const std::vector<double>& loads);
// Per axis, the beads of x counted in `bins` equal bins over the grid's extent (wrapped on periodic
// axes, clamped on open ones): 3 × bins counts, axis-major.
std::vector<double> axis_histograms(const DomainGrid& g, const Eigen::Matrix3Xd& x, int bins);
// The faces (fractions of the axis, 0 … 1) of `slabs` slabs that hold equal shares of a histogram's
// total (its cumulative sum cut at k/slabs of the total, linear within a bin): the shift method's
// cuts (LAMMPS `balance shift`) reached exactly, since the whole histogram is known.
std::vector<double> quantile_cuts(std::span<const double> histogram, int slabs);
// The grid g cut at the quantiles of the summed histograms (axis_histograms with `bins`) on
// every axis with more than one slab.
DomainGrid balanced_grid(const DomainGrid& g, const std::vector<double>& histograms, int bins);

// What a decomposed run reports about itself (summary.json, docs/parallel.md).
struct DomainReport {
  int ranks = 1;
  Eigen::Vector3i grid = Eigen::Vector3i::Ones();
  bool halo_pairs_once = false;         // [parallel] halo_pairs = "once"
  double ghosts_per_owned = 0.0;        // halo beads per home bead (all ranks), at the last selection
  std::int64_t neighbor_pairs = 0;      // the pairs in the ranks' lists as last built, summed
  double halo_bytes_per_step = 0.0;     // all ranks, one halo
  double halo_messages_per_step = 0.0;  // all ranks, one halo
  long redistributions = 0;             // the ghosts selected again (and molecules migrated) after the first
  long migrated_molecules = 0;          // all ranks
  long neighbor_rebuilds_min = 0;       // a rank's neighbour-list rebuilds: the fewest and the most
  long neighbor_rebuilds_max = 0;
  // What a rank's pair forces hold (docs/parallel.md, "What a rank holds"): the particles of the
  // whole system, the largest pair set (home beads and halo) at the last selection, and the most
  // pairs a rank's whole-system force terms list at the end (0: no rank holds a neighbour list of
  // the whole system; rank 0 makes one for a thermo row of the gathered state, the actions).
  int particles = 0;
  long pair_set_max = 0;
  std::int64_t whole_list_pairs_max = 0;
  // The load balance: the measure's max/mean on equal slabs in the initial state, and on the final
  // cuts in the final state; the recuts (the start's among them) and the final cuts per axis.
  double imbalance_before = 1.0, imbalance_after = 1.0;
  long recuts = 0;
  std::array<std::vector<double>, 3> cuts;
};

// A pair term's special partners by bead: the partners of bead k are partner[start[k] … start[k + 1])
// by global index, increasing, with their weights (SpecialPair::weight, weight_coul,
// forcefields/neighbor_list.hpp): the bonded neighbours within its molecule whose special weight is
// not 1 (1-2, 1-3 and, with a 1-4 weight, 1-4).
struct SpecialPartners {
  std::vector<int> start{0}, partner;
  std::vector<double> weight, weight_coul;
  int size() const { return static_cast<int>(start.size()) - 1; }
  void clear() {
    start.assign(1, 0);
    partner.clear(), weight.clear(), weight_coul.clear();
  }
};

// What the pair terms read of a bead besides its position (docs/parallel.md, "The design"): its
// type, its charge (`charged`: some pair term reads charges) and, per pair term, its special
// partners. The owner knows them from its part (its molecules carry the types and charges, and
// the part's terms make the special pairs of its molecules' bonds); each bead carries them to
// the pair sets that hold it at the selection (Decomposition::select_pair_set), so a pair set
// holds them per slot and no rank reads them from arrays of the whole system.
struct PairBeadData {
  bool charged = false;
  std::vector<int> type;
  std::vector<double> charge;            // empty unless charged
  std::vector<SpecialPartners> special;  // per pair term of the part, in the force field's order
};

// Columns from … from + count − 1 of one 3 × m array and to … to + count − 1 of another: the
// unit of Decomposition's copies.
struct ColumnRun {
  int from, to, count;
};

class Decomposition {
 public:
  // No table of the whole system: the start brings each rank's molecules. `margin` > 0: the halo's
  // margin beyond the pair cutoff `cutoff`.
  Decomposition(const Box& box, const Communicator& comm, double cutoff, double margin, const Eigen::Vector3i* dims);

  // When the domains are recut (off unless set; before the start).
  void set_balance(const BalanceSettings& b) { balance_ = b; }
  // Halo pairs once ([parallel] halo_pairs = "once"; before the first selection): a pair of a home
  // bead and a halo bead is computed on one of the two homes (NeighborList::set_ghost_pairs_once),
  // and reverse sends the halo beads' pair forces back too, each added onto its owner's force after
  // the home's, in a fixed order (the local pair set's, then rank by rank). Off: each home computes
  // its beads' pairs whole, one process's sums (the default).
  void set_halo_pairs_once(bool once) { halo_pairs_once_ = once; }
  bool halo_pairs_once() const { return halo_pairs_once_; }
  // The start, from any partition of whole molecules: this rank's `molecules` (particles by
  // increasing global index, with their inverse masses and bonded items) at x, v. Each owned
  // molecule (a component of its items, named by its first global index) is anchored at its
  // centre of mass; the grid's open axes span the anchors' extent (a max-reduction), the load
  // balance recuts from bead counts summed over the ranks (exact: the same cuts on every rank),
  // and every molecule goes, as a migration moves it, to the rank of its anchor's domain.
  // molecules, x, v become the owned ones: for any partition what the whole system's molecules
  // cut by anchor give, bit for bit. Collective; the caller selects the pair sets next.
  void start(PartMolecules& molecules, Eigen::Matrix3Xd& x, Eigen::Matrix3Xd& v);
  // The start from the whole state (the same on every rank) and its topology: each rank gives
  // the molecules of its block (whole_block), with their inverse masses (types, charges 0).
  void distribute(const Topology& topology, const State& whole, Eigen::Matrix3Xd& x, Eigen::Matrix3Xd& v);
  // Molecules whose anchor has gone more than a quarter of this rank's domain's narrowest width
  // past it move whole to the owner of their anchor's domain, with x, v and `carried` (per-particle columns that travel
  // with them), their global indices and masses (the receiver's anchors), and with `molecules`,
  // their share of it (what the part is built from: PartMolecules); x, v, carried and molecules
  // become the new owned ones. Returns whether this rank's owned particles changed. Collective.
  bool migrate(Eigen::Matrix3Xd& x, Eigen::Matrix3Xd& v, std::vector<Eigen::Matrix3Xd*> carried,
               PartMolecules* molecules = nullptr);
  // Whether migrate(x, ...) would move a molecule on any rank (its test alone, one
  // max-reduction): where it would not, a caller need not gather what travels with the
  // molecules, nor call migrate. Collective.
  bool molecules_leave(const Eigen::Matrix3Xd& x) const;
  // What each owned bead carries to the pair sets at the selections from now on (per owned
  // column, in the owned order; the same `charged` and number of pair terms on every rank): set
  // whenever the owned particles change (a part built). Not set: the beads carry their global
  // indices alone, and pair_data() stays empty.
  void set_owned_pair_data(PairBeadData owned);
  // The pair sets of the owned positions x (every rank's home beads and halo), each bead with
  // what it carries (set_owned_pair_data). Collective.
  void select_pair_set(const Eigen::Matrix3Xd& x);
  // The largest displacement of a bead from its position at the last selection, over every rank:
  // x is the owned array of the selection (the positions, or the mollified positions) at a later
  // time; each bead is owned by one rank, so the owned beads alone give the whole system's
  // largest. Infinite when x has another column count or a value that is not finite. Collective.
  double displacement_since_selection(const Eigen::Matrix3Xd& x) const;
  // After a selection of the pair sets, with the dynamic balance: when the home beads' max/mean
  // exceeds the threshold, the grid is recut to the owned positions x if that halves its excess
  // over 1 at least (the same on every rank). Returns whether it was recut: then the molecules migrate and the pair
  // sets are selected again. Collective.
  bool rebalance(const Eigen::Matrix3Xd& x);
  // The measure's max/mean on the current grid for the owned positions x. Collective.
  double imbalance(const Eigen::Matrix3Xd& x) const;
  double imbalance_before() const { return imbalance_before_; }
  long recuts() const { return recuts_; }

  // The pair set's array of an owned one (the positions, or the mollified positions), wrapped into
  // the box (BoxWrap, forcefields/neighbor_list.hpp) as the pair loop reads positions; with
  // `owned_f`, also `pair_f`: each home bead's force as its owner has it so far (so that the pair
  // forces add onto it in the one-process order), 0 on the halo. Collective; no allocation once
  // the buffers have their size.
  void forward(const Eigen::Matrix3Xd& owned, Eigen::Matrix3Xd& pair, const Eigen::Matrix3Xd* owned_f = nullptr,
               Eigen::Matrix3Xd* pair_f = nullptr) const;
  // Each owned bead's force from its home's pair-set array `pair_f` into owned_f (replacing it:
  // the home added the pair forces onto the owner's); with the halo pairs once, then each pair
  // set's force on it as a halo bead added. Collective.
  void reverse(const Eigen::Matrix3Xd& pair_f, Eigen::Matrix3Xd& owned_f) const;
  // Rank 0 gets every rank's owned columns of each array into a 3 × N array by global index (the
  // others get nothing). Collective: one gather per `block` consecutive global indices, so that
  // rank 0 holds one block's messages beside the arrays it fills (whole[a], resized to 3 × N
  // where it is not: the whole state's x and v are written in place).
  static constexpr int kGatherBlock = 1 << 16;
  void gather_columns(const std::vector<const Eigen::Matrix3Xd*>& owned, const std::vector<Eigen::Matrix3Xd*>& whole,
                      int num_particles, int block = kGatherBlock) const;
  void gather_columns(const std::vector<Eigen::Matrix3Xd>& owned, std::vector<Eigen::Matrix3Xd>& whole,
                      int num_particles, int block = kGatherBlock) const;

  // The first owned bead whose x or v is not finite (−1: none).
  int first_non_finite(const Eigen::Matrix3Xd& x, const Eigen::Matrix3Xd& v) const;

  const std::vector<int>& owned_ids() const { return ids_; }  // global index per owned particle
  int num_owned() const { return static_cast<int>(ids_.size()); }
  int owned_index(int global) const;  // −1: not owned here (a search of the owned indices)
  // The pair set: global index per slot (increasing), whether a slot is a halo bead (not home
  // here: NeighborList::set_ghosts), the home beads' count, what its beads carried (per slot:
  // set_owned_pair_data), and the slot of a global index (−1: not in this rank's pair set; a
  // search of the pair set's indices, none of the whole system's size).
  const std::vector<int>& pair_ids() const { return pair_ids_; }
  const std::vector<char>& halo_flags() const { return halo_flag_; }
  int num_home() const { return num_home_; }
  const PairBeadData& pair_data() const { return pair_data_; }
  int pair_slot(int global) const;
  // The same, looked for first in the two slots after `near` (a bonded neighbour's slot: the
  // global indices of a molecule's beads are near one another), then searched.
  int pair_slot_near(int global, int near) const {
    const int n = static_cast<int>(pair_ids_.size());
    if (near + 1 < n && near >= 0 && pair_ids_[near + 1] == global) return near + 1;
    if (near + 2 < n && near >= 0 && pair_ids_[near + 2] == global) return near + 2;
    return pair_slot(global);
  }
  bool owns_molecule(int m) const;  // m: a molecule's name (owned_molecule)
  const DomainGrid& grid() const { return grid_; }
  double margin() const { return margin_; }
  double radius() const { return radius_; }  // R = r_c + margin: the pair sets' reach
  const Communicator& comm() const { return comm_; }
  // Per pair evaluation with forces (forward and reverse): the doubles and messages this rank sends.
  std::int64_t halo_doubles() const { return halo_doubles_; }
  int halo_messages() const { return halo_messages_; }
  long selections() const { return selections_; }
  long migrated_molecules() const { return migrated_; }
  // The box after a barostat's cell move: the domains scale with it (periodic axes), and the next
  // selection of the pair sets uses it.
  void set_box(const Box& box);
  const Box& box() const { return box_; }
  // The owned molecule of owned column k: its name, the first global index of its particles.
  int owned_molecule(int k) const { return owned_molecule_[k]; }
  int num_particles() const { return num_particles_; }  // the whole system's, summed at the start

 private:
  // The centre of mass of the owned molecule at owned_[i] (its columns of x, the owned masses).
  Eigen::Vector3d owned_anchor(const Eigen::Matrix3Xd& x, int i) const;
  // owned_ and each owned molecule's columns from ids_ and owned_molecule_.
  void own();
  // The grid recut to the owned beads x of every rank, and the measure (home beads max/mean) on
  // it. Collective.
  std::pair<DomainGrid, double> recut(const Eigen::Matrix3Xd& x) const;
  // The owned columns k with to[k] ≥ 0 move to rank to[k] (whole molecules) with x, v, carried
  // and their share of `molecules`; what arrives is merged in by global index. Returns whether
  // the owned particles changed. Collective.
  bool send_molecules(const std::vector<int>& to, bool leaving, Eigen::Matrix3Xd& x, Eigen::Matrix3Xd& v,
                      std::vector<Eigen::Matrix3Xd*> carried, PartMolecules* molecules);

  const Communicator& comm_;
  Box box_;
  int num_particles_ = 0;  // the whole system's
  DomainGrid grid_;
  Eigen::Vector3i grid_dims_ = Eigen::Vector3i::Ones();  // [parallel] grid, when given
  bool have_dims_ = false;
  double radius_, margin_;
  BalanceSettings balance_;
  bool halo_pairs_once_ = false;
  double imbalance_before_ = 1.0;
  long recuts_ = 0;

  // What this rank owns, all of the part's size: its molecules (increasing) and each one's owned
  // columns (owned_start_, owned_columns_: increasing); per owned particle its global index
  // (increasing), its molecule (named by its first global index) and its mass in the anchor (1
  // for a fixed one: it counts there).
  std::vector<int> owned_;
  std::vector<int> owned_start_, owned_columns_;
  std::vector<int> ids_;
  std::vector<int> owned_molecule_;
  std::vector<double> owned_mass_;

  // The pair set and the plan of forward and reverse. From this rank to rank r (≠ this one):
  // the owned columns out_[r].owned, each a home bead there or not (out_[r].home); back from r
  // the forces of the home ones, in the same order. From rank r: its columns into the slots
  // in_[r].slot, home here or not. The beads this rank sends itself: `local_`.
  //
  // The copies go by runs of consecutive columns (most beads' home is their owner, and a rank's
  // beads that go to one other rank are stretches of chains): columns from … from + count − 1 of
  // one array to columns to … to + count − 1 of the other, made at the selection. A message is the
  // positions (wrapped) of out_[r].owned in order, then (with forces) the forces of its home ones.
  using Run = ColumnRun;
  struct Plan {
    std::vector<int> owned, slot;  // sender: owned index; receiver: pair slot
    std::vector<char> home;
    int homes = 0;
    // Sender: owned column → message position (all; the home ones among the home ones; the halo
    // ones among the halo ones, made with the halo pairs once). Receiver: message position → slot.
    // local_: owned column → slot.
    std::vector<Run> all, home_runs, halo_runs;
  };
  std::vector<Plan> out_, in_;
  Plan local_;  // owned index and slot together
  // A plan's halo runs where they are used (the halo pairs once), else null: none made.
  std::vector<Run>* halo_runs_of(Plan& p) const { return halo_pairs_once_ ? &p.halo_runs : nullptr; }
  std::vector<int> pair_ids_;
  PairBeadData owned_data_, pair_data_;  // per owned column; per pair-set slot
  // The selection's messages (per rank: sent, received), kept from one selection to the next (a
  // resize fills only what grew).
  std::vector<std::vector<double>> selection_out_, selection_in_;
  bool carry_ = false;         // set_owned_pair_data was called
  long owned_data_beads_ = 0;  // the beads set_owned_pair_data's data is of
  // What each owned bead carries, packed once per set_owned_pair_data (pack_owned_words): bead k's
  // words (the selection's message format) are owned_words_[owned_word_at_[k] … owned_word_at_[k + 1]),
  // so consecutive owned beads' words are one stretch, copied into a message by the plan's runs.
  // Once packed, owned_data_ keeps its partner offsets (SpecialPartners::start) and `charged`
  // alone: the words hold the rest.
  bool owned_packed_ = false;
  std::vector<double> owned_words_;
  std::vector<std::size_t> owned_word_at_;
  void pack_owned_words();
  // The selection's working buffers, kept from one selection to the next: the members' keys and
  // the merge's second buffer and run bounds; per source rank its slots, its next bead and where
  // its next bead's words are; per pair term the partners counted and written.
  std::vector<std::uint64_t> merge_keys_, merge_other_;
  std::vector<std::size_t> merge_bounds_, merge_next_bounds_;
  std::vector<int*> source_slots_;
  std::vector<int> source_next_;
  std::vector<const double*> source_words_;
  std::vector<std::size_t> partners_total_;
  std::vector<int> partners_filled_;
  struct SpecialRow {  // a pair term's SpecialPartners of the pair set, as the selection writes them
    int *start, *partner;
    double *weight, *weight_coul;
  };
  std::vector<SpecialRow> special_rows_;
  Eigen::Matrix3Xd at_selection_;  // the owned array given to the last selection
  std::vector<char> halo_flag_;
  std::vector<Run> halo_runs_;  // the halo's slots (from = to)
  int num_home_ = 0;
  // Per message kind (Message), per rank: a buffer per kind keeps its size from one evaluation
  // to the next (one shared by all would grow and shrink, and std::vector zero-fills each growth).
  enum Message { kPositions, kPositionsAndForces, kForces, kMessages };
  mutable std::vector<std::vector<double>> send_buffer_[kMessages], recv_buffer_[kMessages];
  std::int64_t halo_doubles_ = 0;
  int halo_messages_ = 0;
  long selections_ = 0, migrated_ = 0;
  // Per owned column, the rank its molecule leaves for (−1: it stays): migrate's test, kept
  // between calls so that it allocates nothing once sized.
  mutable std::vector<int> leave_to_;
  // Fills leave_to_ for the owned positions x; returns the number of molecules that leave.
  int find_leaving(const Eigen::Matrix3Xd& x) const;
};

}  // namespace stiffmd
