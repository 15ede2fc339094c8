// The bond-length and bond-angle histograms a run writes at its end (histograms.csv), from the
// whole state or from a decomposed run's parts (the same bytes).
#pragma once

#include <Eigen/Core>
#include <string>

#include "core/box.hpp"
#include "core/communicator.hpp"
#include "core/topology.hpp"

namespace stiffmd {

// Writes DIR/histograms.csv: quantity,bin_low,bin_high,count for bond lengths (every bond) and
// bond angles in degrees (the topology's angles, or every pair of bonds sharing a particle).
void write_histograms(const std::string& path, const Eigen::Matrix3Xd& x, const Box& box, const Topology& topology,
                      int bins = 100);

// The same file from a decomposed run's parts (collective; rank 0 writes `path`): each rank's
// `x` and `topology` are its whole molecules' (its part's numbering). The bins span the values'
// min and max over the ranks and the counts are summed over them, exact in any order, so the file
// is the whole system's to the byte; the angles are the topology's wherever some rank has one
// (else every pair of bonds sharing a particle, as above). No file when no rank has a bond:
// false (on every rank).
bool write_histograms_parts(const std::string& path, const Eigen::Matrix3Xd& x, const Topology& topology,
                            const Communicator& ranks, int bins = 100);

}  // namespace stiffmd
