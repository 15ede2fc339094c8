// The constraint toolbox's molecule blocks (integrators/constraints.hpp, blocks_available): the
// plan of blocks of whole clusters over ranges of particles, the kept configuration block by
// block, and the blocks on the threads. The block operations themselves sit beside their
// whole-system versions (shake.cpp, constraint_projections.cpp).
#include <algorithm>
#include <cstring>
#include <limits>
#include <numeric>

#include "core/molecule_blocks.hpp"
#include "integrators/constraint_toolbox_impl.hpp"

namespace stiffmd {
using namespace constraint_detail;  // the toolbox's private types (constraint_toolbox_impl.hpp)

// Blocks as the micro steps' (core/molecule_blocks.hpp): a cluster covers the range of particle
// indices from its lowest to its highest particle, overlapping ranges join, and a block closes at
// the first end of such a union past min_block_particles particles. The
// clusters (ordered by their first bond: integrators/clusters.hpp) must then run through the
// blocks in order, else everything is one block.
void ConstraintToolbox::Impl::plan_blocks() {
  blocks.clear();
  blocks_split_parts = 0;
  blocks_ok = !clusters_share_particles;
  if (!blocks_ok) return;
  const std::int64_t n = num_particles();
  const int nc = static_cast<int>(clusters.size());
  std::vector<std::int64_t> reach(n);
  std::iota(reach.begin(), reach.end(), std::int64_t{0});
  for (const ConstraintCluster& c : clusters)
    reach[c.particles.front()] = std::max<std::int64_t>(reach[c.particles.front()], c.particles.back());
  const std::vector<std::int64_t> block_of =
      molecule_blocks(reach, min_block_particles, [&](std::int64_t first, std::int64_t last) {
        blocks.push_back({first, last, 0, 0});
      });
  int c = 0;
  for (int k = 0; k < static_cast<int>(blocks.size()); ++k) {
    blocks[k].cluster_begin = c;
    while (c < nc && block_of[clusters[c].particles.front()] == k) ++c;
    blocks[k].cluster_end = c;
  }
  if (c != nc) blocks.assign(1, {0, n, 0, nc});  // clusters not in particle order
}

void ConstraintToolbox::Impl::keep_block(const Block& b, const Eigen::Matrix3Xd& x) {
  const std::size_t bytes = sizeof(double) * 3 * static_cast<std::size_t>(b.last - b.first);
  double* kept_block = kept_x.data() + 3 * b.first;
  const double* x_block = x.data() + 3 * b.first;
  if (bytes == 0 || std::memcmp(kept_block, x_block, bytes) == 0) return;
  std::memcpy(kept_block, x_block, bytes);
  for (int c = b.cluster_begin; c < b.cluster_end; ++c) data[c].frame_kept = data[c].s_factored = false;
}

bool ConstraintToolbox::blocks_available() const {
  return impl_->blocks_ok;
}
std::int64_t ConstraintToolbox::block_particles() const {
  return impl_->min_block_particles;
}
void ConstraintToolbox::set_block_particles(std::int64_t n) {
  impl_->min_block_particles = std::max<std::int64_t>(n, 1);
  impl_->plan_blocks();
}
int ConstraintToolbox::num_blocks() const {
  return static_cast<int>(impl_->blocks.size());
}
std::int64_t ConstraintToolbox::block_first(int b) const {
  return impl_->blocks.at(static_cast<std::size_t>(b)).first;
}
std::int64_t ConstraintToolbox::block_last(int b) const {
  return impl_->blocks.at(static_cast<std::size_t>(b)).last;
}

void ConstraintToolbox::begin_blocks() {
  Impl& d = *impl_;
  const Eigen::Index n = d.num_particles();
  if (d.kept && d.kept_x.cols() == n) return;
  // Nothing kept: a configuration no block equals (NaN's bits are none of a finite x's), so each
  // block's first operation copies its particles.
  d.kept_x.setConstant(3, n, std::numeric_limits<double>::quiet_NaN());
  for (ClusterData& c : d.data) c.frame_kept = c.s_factored = false;
  d.kept = true;
}

void ConstraintToolbox::for_each_block(int parts, const std::function<void(int)>& f) {
  Impl& d = *impl_;
  const int nb = static_cast<int>(d.blocks.size());
  parts = std::min(parts, nb);
  if (parts <= 1) {
    run_as_one_part(d.num_particles(), [&] {
      for (int b = 0; b < nb; ++b) f(b);
    });
    return;
  }
  if (parts != d.blocks_split_parts) {  // about the same number of particles per part
    d.blocks_split_parts = parts;
    d.owned_blocks.assign(parts + 1, nb);
    d.owned_blocks[0] = 0;
    const std::int64_t n = d.num_particles();
    int b = 0;
    for (int u = 1; u < parts; ++u) {
      const std::int64_t target = n * u / parts;
      while (b < nb && d.blocks[b].last <= target) ++b;
      d.owned_blocks[u] = b;
    }
  }
  run_parts(parts, [&](int u) {
    for (int b = d.owned_blocks[u]; b < d.owned_blocks[u + 1]; ++b) f(b);
  });
}

int ConstraintToolbox::block_cluster_begin(int b) const {
  return impl_->blocks.at(static_cast<std::size_t>(b)).cluster_begin;
}
int ConstraintToolbox::block_cluster_end(int b) const {
  return impl_->blocks.at(static_cast<std::size_t>(b)).cluster_end;
}

void ConstraintToolbox::inverse_bands_block(int b, const Eigen::Matrix3Xd& x) {
  Impl& d = *impl_;
  const Impl::Block& k = d.blocks[b];
  d.keep_block(k, x);
  d.run_groups(k.cluster_begin, k.cluster_end, [&](int c, int count) {
    if (d.data[c].spd) d.chain_inverse_band_group(c, count);
  });
}

double ConstraintToolbox::normal_energy_sum() const {
  double sum = 0.0;  // in cluster order, as normal_kinetic_energy
  for (const ClusterData& d : impl_->data) sum += d.normal_energy;
  return sum;
}

}  // namespace stiffmd
