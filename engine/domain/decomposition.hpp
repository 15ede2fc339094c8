// Domain decomposition with whole-molecule ownership (docs/parallel.md): which rank owns which
// molecule, which beads of other ranks it sees as ghosts, and the messages that move them.
//
// A grid of domains covers the box; a molecule (a lone bead is a molecule of one) belongs to the
// rank whose domain holds its anchor, the centre of mass wrapped into the box. The local arrays of
// a rank hold its owned particles and its ghosts in increasing global index: the ghosts are every bead
// of another rank within the halo radius R = r_c + margin of the region its owned beads occupy
// (their bounding box, each molecule taken at the image of its anchor). Beads that were farther
// than R at the selection come within r_c of an owned bead only after some bead moved more than
// margin/2, so the ghosts are complete until then; the decomposition is redone before that
// (DomainIntegrator). Ghosts carry their owners' coordinates, never a shifted image: every pair
// distance goes through the box's minimum image, as in one process.
#pragma once

#include <Eigen/Core>
#include <cstdint>
#include <span>
#include <vector>

#include "engine/core/box.hpp"
#include "engine/core/communicator.hpp"
#include "engine/core/state.hpp"
#include "engine/core/topology.hpp"

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
  long redistributions = 0;
  long migrated_molecules = 0;  // all ranks
};

class Decomposition {
 public:
  // The whole system's molecules (topology.molecule; a particle without one is a molecule of its
  // own) and masses. `margin` > 0: the halo's margin beyond the cutoff `cutoff`.
  Decomposition(const Topology& topology, const Eigen::VectorXd& inv_mass, const Box& box, const Communicator& comm,
                double cutoff, double margin, const Eigen::Vector3i* dims);

  // From the whole state (the same on every rank, at the start): owners by anchor, ghosts, and
  // this rank's local x, v (owned then ghosts). Collective.
  void distribute(const State& whole, Eigen::Matrix3Xd& x, Eigen::Matrix3Xd& v);
  // From the local arrays of the last distribution: molecules whose anchor left this rank's
  // domain move to their new owner with x, v and `carried` (per-particle columns that travel with
  // them); then new ghosts. x, v, carried are replaced by the new local arrays. Collective.
  void redistribute(Eigen::Matrix3Xd& x, Eigen::Matrix3Xd& v, std::vector<Eigen::Matrix3Xd*> carried = {});

  // Fills the ghost columns of a local array from the owners' columns of theirs (the same kind of
  // array on every rank). Collective; no allocation once the buffers have their size.
  void halo(Eigen::Matrix3Xd& a) const;
  // Rank 0 gets every rank's owned columns of x and v into whole.x, whole.v by global index.
  // Collective.
  void gather(const Eigen::Matrix3Xd& x, const Eigen::Matrix3Xd& v, State& whole) const;
  // Rank 0 gets every rank's owned columns of each array into a 3 × N array by global index (the
  // others get nothing). Collective.
  void gather_columns(const std::vector<Eigen::Matrix3Xd>& local, std::vector<Eigen::Matrix3Xd>& whole,
                      int num_particles) const;

  // The largest displacement of an owned bead since the ghosts were selected (this rank's).
  double max_displacement(const Eigen::Matrix3Xd& x) const;

  // The local particles, in increasing global index, owned ones and ghosts mixed.
  const std::vector<int>& local_ids() const { return ids_; }  // global index per local particle
  bool owned(int local) const { return owned_flag_[local] != 0; }
  const std::vector<int>& owned_particles() const { return owned_index_; }  // local indices, increasing
  int num_owned() const { return num_owned_; }
  int num_local() const { return static_cast<int>(ids_.size()); }
  const std::vector<int>& owned_molecules() const { return owned_; }
  bool owns_molecule(int m) const;
  const DomainGrid& grid() const { return grid_; }
  double halo_radius() const { return radius_; }
  double margin() const { return margin_; }
  const Communicator& comm() const { return comm_; }
  // Per halo: the doubles sent, the messages sent (this rank).
  std::int64_t halo_doubles() const { return halo_doubles_; }
  int halo_messages() const { return halo_messages_; }
  long redistributions() const { return redistributions_; }
  long migrated_molecules() const { return migrated_; }
  int molecule_of(int global) const { return molecule_[global]; }
  int local_index(int global) const { return local_of_[global]; }  // −1: neither owned nor a ghost
  int num_molecules() const { return static_cast<int>(molecule_start_.size()) - 1; }
  // The global indices of molecule m, increasing.
  std::span<const int> molecule(int m) const {
    return {molecule_particles_.data() + molecule_start_[m],
            static_cast<size_t>(molecule_start_[m + 1] - molecule_start_[m])};
  }

 private:
  Eigen::Vector3d anchor(const Eigen::Matrix3Xd& x, std::span<const int> local) const;
  void select_ghosts(Eigen::Matrix3Xd& x, Eigen::Matrix3Xd& v, std::vector<Eigen::Matrix3Xd*>& carried);

  const Communicator& comm_;
  Box box_;
  Eigen::VectorXd mass_;  // per global particle (1 for fixed ones: they count in the anchor)
  std::vector<int> molecule_;
  std::vector<int> molecule_start_, molecule_particles_;
  DomainGrid grid_;
  Eigen::Vector3i grid_dims_ = Eigen::Vector3i::Ones();  // [parallel] grid, when given
  bool have_dims_ = false;
  double radius_, margin_;
  std::vector<int> local_of_;  // global → local index (−1: not here)

  std::vector<int> owned_;  // molecules, increasing
  std::vector<int> ids_;    // local → global
  int num_owned_ = 0;
  std::vector<char> owned_flag_;     // per local particle
  std::vector<int> owned_index_;     // the owned ones' local indices
  Eigen::Matrix3Xd x_at_selection_;  // owned columns
  // Halo plan: to rank r the owned columns send_[r]; from rank r ghost_count_[r] columns, into
  // ghost_slot_[ghost_begin_[r] − num_owned_ + k] (ghost_begin_ counts from num_owned_).
  std::vector<std::vector<int>> send_;
  std::vector<int> ghost_begin_, ghost_count_, ghost_slot_;
  mutable std::vector<std::vector<double>> send_buffer_, recv_buffer_;
  std::int64_t halo_doubles_ = 0;
  int halo_messages_ = 0;
  long redistributions_ = 0, migrated_ = 0;
};

}  // namespace stiffmd
