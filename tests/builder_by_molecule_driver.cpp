// Time, peak resident set and overlaps of the builders on a melt (docs/parallel.md, "The set-up by
// parts"): the builder by molecules for the whole system or one rank's share, the anchors pass,
// and the builder that grows every molecule together.
//   builder_by_molecule_driver whole|together|anchors [CHAINS BEADS]
//   builder_by_molecule_driver part R P [CHAINS BEADS]      molecules [R·M/P, (R+1)·M/P)
//   builder_by_molecule_driver overlaps by-molecule|together [CHAINS BEADS]
// Melt: density 0.85, bond_length 0.97, min_distance 0.8, seed 11 (tests/decks/melt_million.toml's
// builder; CHAINS BEADS default 10 000 × 100). "overlaps" prints the distribution of each bead's
// closest non-bonded distance (minimum image) and the pairs closer than σ/2 and min_distance.
#include <sys/resource.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <string>
#include <vector>

#include "engine/scene/chains_by_molecule.hpp"

namespace {

using namespace stiffmd;

double peak_rss_mib() {
  rusage u{};
  getrusage(RUSAGE_SELF, &u);
  return u.ru_maxrss / 1024.0;  // kilobytes on Linux
}

// Each bead's closest non-bonded bead (another molecule, or its own at least two bonds away)
// within `reach`, by cells at least `reach` wide in the periodic box; `reach` where none is.
std::vector<double> closest_nonbonded(const Polymer& p, const Box& box, double reach) {
  const int n = static_cast<int>(p.x.cols());
  int cells[3];
  for (int a = 0; a < 3; ++a) cells[a] = std::max(1, static_cast<int>(box.lengths[a] / reach));
  auto cell_of = [&](int i) {
    int c[3];
    for (int a = 0; a < 3; ++a) {
      double w = p.x(a, i) - box.origin[a];
      w -= box.lengths[a] * std::floor(w / box.lengths[a]);
      c[a] = std::min(cells[a] - 1, static_cast<int>(w / box.lengths[a] * cells[a]));
    }
    return (c[0] * cells[1] + c[1]) * cells[2] + c[2];
  };
  std::vector<int> head(static_cast<size_t>(cells[0]) * cells[1] * cells[2], -1), next(static_cast<size_t>(n), -1);
  std::vector<int> cell(static_cast<size_t>(n));
  for (int i = 0; i < n; ++i) {
    cell[i] = cell_of(i);
    next[i] = head[cell[i]];
    head[cell[i]] = i;
  }
  std::vector<double> best(static_cast<size_t>(n), reach);
  for (int i = 0; i < n; ++i) {
    const int c = cell[i];
    const int ci[3] = {c / (cells[1] * cells[2]), (c / cells[2]) % cells[1], c % cells[2]};
    for (int dx = -1; dx <= 1; ++dx)
      for (int dy = -1; dy <= 1; ++dy)
        for (int dz = -1; dz <= 1; ++dz) {
          const int o[3] = {(ci[0] + dx + cells[0]) % cells[0], (ci[1] + dy + cells[1]) % cells[1],
                            (ci[2] + dz + cells[2]) % cells[2]};
          for (int j = head[(o[0] * cells[1] + o[1]) * cells[2] + o[2]]; j >= 0; j = next[j]) {
            if (j == i || (p.molecule[i] == p.molecule[j] && std::abs(i - j) < 2)) continue;
            const double r = box.min_image(p.x.col(i) - p.x.col(j)).norm();
            best[i] = std::min(best[i], r);
          }
        }
  }
  return best;
}

}  // namespace

int main(int argc, char** argv) {
  if (argc < 2) {
    std::fprintf(stderr, "usage: %s whole|together|anchors|part R P|overlaps STYLE [CHAINS BEADS]\n", argv[0]);
    return 2;
  }
  const std::string mode = argv[1];
  int arg = 2;
  int rank = 0, ranks = 1;
  std::string style;
  if (mode == "part") rank = std::atoi(argv[arg++]), ranks = std::atoi(argv[arg++]);
  if (mode == "overlaps") style = argv[arg++];
  ChainSpec spec;
  spec.chains = arg < argc ? std::atoi(argv[arg++]) : 10000;
  spec.beads = arg < argc ? std::atoi(argv[arg++]) : 100;
  spec.bond_length = 0.97;
  spec.min_distance = 0.8;
  spec.seed = 11;
  const Box box = box_for_density(spec.chains * spec.beads, 0.85);
  const auto t0 = std::chrono::steady_clock::now();
  long long beads = 0;
  double check = 0.0;
  if (mode == "whole" || mode == "part") {
    const int first = static_cast<int>(static_cast<long long>(rank) * spec.chains / ranks);
    const int end = static_cast<int>(static_cast<long long>(rank + 1) * spec.chains / ranks);
    const BuiltMolecules b = build_linear_chains_by_molecule(spec, box, first, end);
    beads = b.x.cols();
    check = b.x.sum() + b.anchors.sum();
  } else if (mode == "together") {
    const Polymer p = build_linear_chains(spec, box);
    beads = p.x.cols();
    check = p.x.sum();
  } else if (mode == "anchors") {
    const Eigen::Matrix3Xd a = chain_anchors_by_molecule(spec, box);
    beads = static_cast<long long>(spec.chains) * spec.beads;
    check = a.sum();
  } else if (mode == "overlaps") {
    const Polymer p = style == "together" ? build_linear_chains(spec, box) : build_linear_chains_by_molecule(spec, box);
    std::vector<double> d = closest_nonbonded(p, box, 1.2);
    const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    long below_half = 0, below_min = 0;
    for (double r : d) below_half += r < 0.5, below_min += r < spec.min_distance;
    std::sort(d.begin(), d.end());
    std::printf("%s: %lld beads; closest non-bonded distance per bead: min %.4f", style.c_str(),
                static_cast<long long>(d.size()), d.front());
    for (double q : {0.001, 0.01, 0.05, 0.1, 0.25, 0.5})
      std::printf(", %g-quantile %.3f", q, d[static_cast<size_t>(q * (d.size() - 1))]);
    std::printf(
        "\n  beads with one closer than sigma/2 = 0.5: %ld (%.2f%%); closer than min_distance 0.8: %ld (%.2f%%)"
        " [%.2f s with the analysis]\n",
        below_half, 100.0 * below_half / d.size(), below_min, 100.0 * below_min / d.size(), seconds);
    return 0;
  } else {
    std::fprintf(stderr, "unknown mode %s\n", mode.c_str());
    return 2;
  }
  const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  std::printf("%s %d/%d: %lld beads in %.3f s, peak resident set %.1f MiB (checksum %.17g)\n", mode.c_str(), rank,
              ranks, beads, seconds, peak_rss_mib(), check);
  return 0;
}
