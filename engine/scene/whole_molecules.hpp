// Whole molecules from wrapped positions (the guarantee stated in core/state.hpp): each connected
// component of the bond graph is traversed breadth first from its lowest-index particle, which
// stays where it is; each particle reached over a bond is moved by whole box lengths so that the
// bond's raw difference is its minimum image. Open axes are left alone.
#pragma once

#include <Eigen/Core>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "core/box.hpp"

namespace stiffmd {

// What cannot be made whole: `bond` indexes the bond list, `what` says why (without naming the
// bond's particles: the caller names them in its own terms, indices or file ids).
struct WholeMoleculesProblem {
  int bond = -1;
  std::string what;
};

// keep_images = false: shift particles as described above (positions may be wrapped).
// keep_images = true: the positions are already unwrapped (a LAMMPS data file with image flags):
// nothing moves, and a bond whose raw difference is not its own minimum image is a bond longer
// than half the box length, which is refused.
// Refused either way: a bond that spans exactly half a box length on a periodic axis (its image
// is ambiguous), a bond that closes a ring only across a box length, and a bond of zero length
// once whole (two particles one box length apart). x is modified only by
// whole multiples of the box lengths, and left as it was when a problem is returned.
std::optional<WholeMoleculesProblem> make_molecules_whole(Eigen::Matrix3Xd& x,
                                                          const std::vector<std::pair<int, int>>& bonds, const Box& box,
                                                          bool keep_images = false);

}  // namespace stiffmd
