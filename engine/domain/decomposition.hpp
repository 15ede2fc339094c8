// Domain decomposition with whole-molecule ownership (docs/parallel.md): which rank owns which
// molecule, which beads of other ranks it sees as ghosts, and the messages that move them.
//
// A grid of domains covers the box; a molecule (a lone bead is a molecule of one) belongs to the
// rank whose domain holds its anchor, the centre of mass wrapped into the box, and moves to another
// rank when its anchor has gone more than the halo's margin past its owner's domain. A rank's
// owned particles are its local arrays, in increasing global index. Its ghosts are every bead of
// another rank within R = r_c + margin of one of its own (through cells at least R wide); the
// owned particles and the ghosts together, in increasing global index, are the extended set the
// pair terms work on (GhostedPairs). Beads that were farther than R at the selection come within
// r_c of an owned bead only after some bead moved margin/2, so the ghosts are complete until then;
// they are selected again before that (DomainIntegrator). Ghosts carry their owners' coordinates,
// never a shifted image: every pair distance goes through the box's minimum image, as in one
// process.
#pragma once

#include <Eigen/Core>
#include <cstdint>
#include <span>
#include <vector>

#include "core/box.hpp"
#include "core/communicator.hpp"
#include "core/state.hpp"
#include "core/topology.hpp"

namespace stiffmd {

// The domains: dims[a] slabs per axis of equal width over the box (periodic axes) or over the
// anchors' extent at the start (open axes).
struct DomainGrid {
  Eigen::Vector3i dims = Eigen::Vector3i::Ones();
  Eigen::Vector3d origin = Eigen::Vector3d::Zero(), length = Eigen::Vector3d::Ones();
  Eigen::Vector3i periodic = Eigen::Vector3i::Zero();
  int size() const { return dims.prod(); }
  // The domain of a point (wrapped on periodic axes; clamped to the edge domains on open axes).
  int domain_of(const Eigen::Vector3d& p) const;
  // Whether p lies within `slack` of the domain (periodic axes: of its nearest image).
  bool within(int domain, const Eigen::Vector3d& p, double slack) const;
};

// The grid for `ranks` domains: `dims` when given (product = ranks), else the factorisation of
// ranks into three that makes the domains closest to cubes (least surface per volume), periodic
// axes cut first. `anchors`: the molecules' anchors, for the extent of open axes.
DomainGrid make_domain_grid(const Box& box, int ranks, const Eigen::Vector3i* dims, const Eigen::Matrix3Xd& anchors);

// What a decomposed run reports about itself (summary.json, docs/parallel.md).
struct DomainReport {
  int ranks = 1;
  Eigen::Vector3i grid = Eigen::Vector3i::Ones();
  double ghosts_per_owned = 0.0;        // mean over ranks, at the last selection
  double halo_bytes_per_step = 0.0;     // all ranks, one halo
  double halo_messages_per_step = 0.0;  // all ranks, one halo
  long redistributions = 0;             // the ghosts selected again (and molecules migrated) after the first
  long migrated_molecules = 0;          // all ranks
  long neighbor_rebuilds_min = 0;       // a rank's neighbour-list rebuilds: the fewest and the most
  long neighbor_rebuilds_max = 0;
};

class Decomposition {
 public:
  // The whole system's molecules (the connected components of its bonded terms) and masses.
  // `margin` > 0: the halo's margin beyond the pair cutoff `cutoff`.
  Decomposition(const Topology& topology, const Eigen::VectorXd& inv_mass, const Box& box, const Communicator& comm,
                double cutoff, double margin, const Eigen::Vector3i* dims);

  // From the whole state (the same on every rank, at the start): owners by anchor, and this
  // rank's owned x, v. Collective (through select_ghosts, which the caller runs next).
  void distribute(const State& whole, Eigen::Matrix3Xd& x, Eigen::Matrix3Xd& v);
  // Molecules whose anchor has gone more than the margin (at most a quarter of a domain's width)
  // past this rank's domain move whole to the
  // owner of their anchor's domain, with x, v and `carried` (per-particle columns that travel with
  // them); x, v, carried become the new owned arrays. Returns whether this rank's owned particles
  // changed. Collective.
  bool migrate(Eigen::Matrix3Xd& x, Eigen::Matrix3Xd& v, std::vector<Eigen::Matrix3Xd*> carried);
  // The ghosts of the owned positions x, and the extended set. Collective.
  void select_ghosts(const Eigen::Matrix3Xd& x);

  // The extended array of an owned one (x, or the mollified positions): the owned columns copied,
  // the ghost columns from their owners' arrays of the same kind. Collective; no allocation once
  // the buffers have their size. Stops the run (NumericalError) when a bead has moved margin/2
  // since the selection: pairs would be missed.
  // Every column is wrapped into the box (BoxWrap, forcefields/neighbor_list.hpp), as the pair
  // loop reads positions.
  void halo(const Eigen::Matrix3Xd& owned, Eigen::Matrix3Xd& extended) const;
  // Rank 0 gets every rank's owned columns of each array into a 3 × N array by global index (the
  // others get nothing). Collective.
  void gather_columns(const std::vector<Eigen::Matrix3Xd>& owned, std::vector<Eigen::Matrix3Xd>& whole,
                      int num_particles) const;

  // One pass over the owned beads (this rank's): the largest |x − x at the selection| + t |v| of
  // those whose reach may be `floor` or more (the others count 0) — with t = 2h, a bound on each
  // bead's displacement by the end of the next step if none moves more than 2 |v| h in a step —
  // and the first owned bead whose x or v is not finite (−1: none; the pass stops there).
  struct Reach {
    double largest = 0.0;
    int first_bad = -1;
  };
  Reach reach(const Eigen::Matrix3Xd& x, const Eigen::Matrix3Xd& v, double t, double floor) const;

  const std::vector<int>& owned_ids() const { return ids_; }  // global index per owned particle
  int num_owned() const { return static_cast<int>(ids_.size()); }
  int owned_index(int global) const { return owned_of_[global]; }  // −1: not owned here
  // The extended set: global index per extended particle (increasing), the extended index of
  // owned particle k, and whether an extended particle is a ghost.
  const std::vector<int>& extended_ids() const { return extended_ids_; }
  int extended_slot(int owned) const { return owned_slot_[owned]; }
  const std::vector<char>& ghost_flags() const { return ghost_flag_; }
  const std::vector<int>& ghost_slots() const { return ghost_slot_; }  // the ghosts' extended indices
  bool owns_molecule(int m) const;
  const DomainGrid& grid() const { return grid_; }
  double margin() const { return margin_; }
  // A new margin for the next selection (> 0).
  void set_margin(double margin) { radius_ += margin - margin_, margin_ = margin; }
  const Communicator& comm() const { return comm_; }
  // Per halo: the doubles sent, the messages sent (this rank).
  std::int64_t halo_doubles() const { return halo_doubles_; }
  int halo_messages() const { return halo_messages_; }
  long selections() const { return selections_; }
  long migrated_molecules() const { return migrated_; }
  // The box after a barostat's cell move: the domains scale with it (periodic axes), and the next
  // ghost selection uses it.
  void set_box(const Box& box);
  const Box& box() const { return box_; }
  int molecule_of(int global) const { return molecule_[global]; }
  int num_molecules() const { return static_cast<int>(molecule_start_.size()) - 1; }
  // The global indices of molecule m, increasing.
  std::span<const int> molecule(int m) const {
    return {molecule_particles_.data() + molecule_start_[m],
            static_cast<size_t>(molecule_start_[m + 1] - molecule_start_[m])};
  }

 private:
  Eigen::Vector3d anchor(const Eigen::Matrix3Xd& x, std::span<const int> global, bool owned_columns) const;
  void own(std::vector<int> molecules);  // owned_ and ids_ from a list of molecules

  const Communicator& comm_;
  Box box_;
  Eigen::VectorXd mass_;  // per global particle (1 for fixed ones: they count in the anchor)
  std::vector<int> molecule_;
  std::vector<int> molecule_start_, molecule_particles_;
  DomainGrid grid_;
  Eigen::Vector3i grid_dims_ = Eigen::Vector3i::Ones();  // [parallel] grid, when given
  bool have_dims_ = false;
  double radius_, margin_;

  std::vector<int> owned_;     // molecules, increasing
  std::vector<int> ids_;       // owned particles: global index, increasing
  std::vector<int> owned_of_;  // global → owned index (−1: not owned here)
  Eigen::Matrix3Xd x_at_selection_;
  // The extended set and the halo's plan: to rank r the owned columns send_[r]; from rank r
  // ghost_count_[r] columns, into the extended slots ghost_slot_[ghost_begin_[r] + k].
  std::vector<int> extended_ids_, owned_slot_, ghost_slot_;
  std::vector<char> ghost_flag_;
  std::vector<std::vector<int>> send_;
  std::vector<int> ghost_begin_, ghost_count_;
  mutable std::vector<std::vector<double>> send_buffer_, recv_buffer_;
  std::int64_t halo_doubles_ = 0;
  int halo_messages_ = 0;
  long selections_ = 0, migrated_ = 0;
  // select_ghosts' scratch, kept from one selection to the next: per owned bead its cell and its
  // position wrapped into the cells' frame; the beads by cell (a counting sort) and their wrapped
  // positions in that order.
  struct SelectionScratch {
    std::vector<std::int64_t> cell_of, occupied;
    std::vector<int> cell_start, by_cell;
    std::vector<char> near;
    Eigen::Matrix3Xd wrapped, cell_x;
    std::vector<std::pair<int, int>> members;
  } scratch_;
};

}  // namespace stiffmd
