// Shared fixtures of the decomposition's unit tests (tests/test_decomposition.cpp), run on fake
// ranks (tests/fake_processes.hpp): a small periodic melt whose molecules straddle the domain
// faces and the periodic faces, and the geometry of a domain grid computed here, independently of
// DomainGrid's own functions.
#pragma once

#include <Eigen/Core>
#include <cmath>
#include <numeric>
#include <vector>

#include "core/box.hpp"
#include "core/state.hpp"
#include "core/topology.hpp"
#include "engine/domain/decomposition.hpp"
#include "engine/scene/builders.hpp"

namespace stiffmd::fake {

// A periodic melt with its molecules as built: `label` per particle (the decomposition numbers its
// molecules itself). Positions unwrapped, molecules whole.
struct Melt {
  State state;
  Topology topology;
  Box box;
  std::vector<int> label;
  int molecules = 0;
  int size() const { return state.size(); }
  std::vector<int> members(int m) const {
    std::vector<int> out;
    for (int i = 0; i < size(); ++i)
      if (label[i] == m) out.push_back(i);
    return out;
  }
};

// Chains of the builder (random walks that start anywhere in the box, some across its faces),
// straight chains along the box's diagonal through its corner (across every periodic face) and
// through the points at 1/4, 1/3, 1/2, 2/3 and 3/4 of the diagonal (across the faces of any grid
// of up to 4 slabs per axis), one molecule of two bonded pieces joined by an angle alone (a
// molecule is a component of every bonded term), and lone beads, two of them outside the box.
// Every fifth bead is ten times as heavy (the anchor is the centre of mass, not the centroid). The
// particle indices are permuted (p → 7p mod n), so no molecule is a run of consecutive indices.
inline Melt straddling_melt() {
  Box box;
  box.origin = Eigen::Vector3d(-3.0, 1.0, 0.5);
  box.lengths = Eigen::Vector3d(12.0, 10.0, 9.0);
  box.periodic = Eigen::Vector3i::Ones();
  ChainSpec spec;
  spec.chains = 12, spec.beads = 8, spec.min_distance = 0.0, spec.seed = 7;
  const Polymer built = build_linear_chains(spec, box);

  std::vector<Eigen::Vector3d> x;
  std::vector<int> label;
  std::vector<std::pair<int, int>> bonds;
  std::vector<std::array<int, 3>> angles;
  for (int i = 0; i < built.x.cols(); ++i) x.push_back(built.x.col(i)), label.push_back(built.molecule[i]);
  for (const auto& b : built.bonds) bonds.push_back(b);
  int molecules = spec.chains;
  const Eigen::Vector3d diagonal = box.lengths / box.lengths.norm();
  auto straight_chain = [&](const Eigen::Vector3d& centre, int beads) {
    const int first = static_cast<int>(x.size());
    for (int k = 0; k < beads; ++k) {
      x.push_back(centre + 0.97 * (k - 0.5 * (beads - 1)) * diagonal);
      label.push_back(molecules);
      if (k > 0) bonds.emplace_back(first + k - 1, first + k);
    }
    return first + beads - 1;
  };
  const Eigen::Vector3d offset(0.13, 0.07, 0.03);  // no anchor exactly on a face
  for (double f : {0.0, 0.25, 1.0 / 3.0, 0.5, 2.0 / 3.0, 0.75}) {
    straight_chain(box.origin + f * box.lengths + offset, 9);
    ++molecules;
  }
  // Two pieces of 3 beads, joined by the angle (last of the first, first of the second, its next).
  const int end_of_first = straight_chain(box.origin + 0.4 * box.lengths + offset, 3);
  straight_chain(box.origin + 0.4 * box.lengths + offset + Eigen::Vector3d(0.0, 0.9, 0.0), 3);
  angles.push_back({end_of_first, end_of_first + 1, end_of_first + 2});
  ++molecules;
  for (const Eigen::Vector3d& p :
       {Eigen::Vector3d(box.origin - Eigen::Vector3d(0.4, 0.2, 0.1)),
        Eigen::Vector3d(box.origin + box.lengths + Eigen::Vector3d(0.3, 1.1, 0.2)),
        Eigen::Vector3d(box.origin + 0.6 * box.lengths), Eigen::Vector3d(box.origin + 0.1 * box.lengths)}) {
    x.push_back(p);
    label.push_back(molecules++);
  }

  const int n = static_cast<int>(x.size());
  int step = 7;
  while (std::gcd(step, n) != 1) ++step;
  auto slot = [&](int p) { return static_cast<int>((static_cast<long>(step) * p) % n); };
  Melt melt;
  melt.box = box;
  melt.molecules = molecules;
  melt.label.assign(n, -1);
  melt.state.x.resize(3, n);
  melt.state.v.resize(3, n);
  melt.state.inv_mass.resize(n);
  for (int p = 0; p < n; ++p) {
    const int i = slot(p);
    melt.state.x.col(i) = x[p];
    melt.label[i] = label[p];
    for (int a = 0; a < 3; ++a) melt.state.v(a, i) = std::sin(1.0 + 3 * i + a);
    melt.state.inv_mass[i] = i % 5 == 0 ? 0.1 : 1.0;
  }
  melt.topology.bond_types = {"bond"};
  melt.topology.angle_types = {"angle"};
  for (const auto& [i, j] : bonds) melt.topology.bonds.push_back({slot(i), slot(j), 0});
  for (const auto& [i, j, k] : angles) melt.topology.angles.push_back({slot(i), slot(j), slot(k), 0});
  return melt;
}

// The centre of mass of the particles `ids` (columns of x by global index).
inline Eigen::Vector3d centre_of_mass(const Melt& melt, const Eigen::Matrix3Xd& x, const std::vector<int>& ids) {
  Eigen::Vector3d c = Eigen::Vector3d::Zero();
  double total = 0.0;
  for (int i : ids) {
    const double m = 1.0 / melt.state.inv_mass[i];
    c += m * x.col(i);
    total += m;
  }
  return c / total;
}

// The faces of axis a's slabs, c = 0 … dims[a]: equal slabs, or the load balance's cuts (fractions
// of the axis).
inline std::vector<double> slab_faces(const DomainGrid& g, int a) {
  std::vector<double> faces(g.dims[a] + 1);
  for (int c = 0; c <= g.dims[a]; ++c)
    faces[c] = g.origin[a] + g.length[a] * (g.cut[a].empty() ? static_cast<double>(c) / g.dims[a] : g.cut[a][c]);
  return faces;
}

// The domain holding p (wrapped into the grid's periodic frame), ranks numbered x-major: rank =
// (i_x d_y + i_y) d_z + i_z.
inline int rank_of_point(const DomainGrid& g, const Eigen::Vector3d& p) {
  int index[3];
  for (int a = 0; a < 3; ++a) {
    double q = p[a];
    if (g.periodic[a]) q -= g.length[a] * std::floor((q - g.origin[a]) / g.length[a]);
    const std::vector<double> faces = slab_faces(g, a);
    index[a] = 0;  // the last slab whose low face is at or below q (the edge slabs clamp)
    for (int c = 1; c < g.dims[a]; ++c)
      if (q >= faces[c]) index[a] = c;
  }
  return (index[0] * g.dims[1] + index[1]) * g.dims[2] + index[2];
}

// The lowest and highest corner and the centre of rank r's domain.
inline Eigen::Vector3d domain_corner(const DomainGrid& g, int r, int side = 0) {
  const int index[3] = {r / (g.dims[1] * g.dims[2]), (r / g.dims[2]) % g.dims[1], r % g.dims[2]};
  Eigen::Vector3d corner;
  for (int a = 0; a < 3; ++a) corner[a] = slab_faces(g, a)[index[a] + side];
  return corner;
}
inline Eigen::Vector3d domain_upper_corner(const DomainGrid& g, int r) {
  return domain_corner(g, r, 1);
}
inline Eigen::Vector3d domain_centre(const DomainGrid& g, int r) {
  return 0.5 * (domain_corner(g, r) + domain_upper_corner(g, r));
}

}  // namespace stiffmd::fake
