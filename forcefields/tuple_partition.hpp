// Owner computes for the terms of several particles (angles: 3, dihedrals: 4), as the bond loop's
// BondPartition for two (bond_loop.hpp): the particles are split into `parts` contiguous ranges of
// about equal numbers of tuple ends; part u evaluates, in list order, every tuple with a particle
// in its range and adds the forces on those particles only (a tuple across ranges is evaluated by
// each of its parts). Each particle then receives its forces from the tuples in list order whatever
// the number of parts — the serial loop's sums, bit for bit — and no two threads write one
// particle. A tuple's energy is counted by the part owning its first particle; the parts' energies
// are added in part order.
#pragma once

#include <algorithm>
#include <array>
#include <cstdint>
#include <vector>

namespace stiffmd {

// Owner computes' particle ranges: `ends[p + 1]` counts the bond or tuple ends at particle p (as
// built by the caller); the counts are summed in place and the particles split into `parts`
// contiguous ranges of about equal ends. Returns first[0 … parts], part u owning particles
// first[u] … first[u + 1] − 1 (first[parts] = the particle count).
inline std::vector<int> owner_ranges(std::vector<std::int64_t>& ends, int parts) {
  const int n = static_cast<int>(ends.size()) - 1;
  for (int p = 0; p < n; ++p) ends[p + 1] += ends[p];
  std::vector<int> first(parts + 1, n);
  for (int u = 1; u < parts; ++u)
    first[u] = static_cast<int>(std::lower_bound(ends.begin(), ends.end(), ends[n] * u / parts) - ends.begin());
  first[0] = 0;
  return first;
}

template <int K>
class TuplePartition {
 public:
  struct Work {
    int tuple;
    std::uint8_t owned;  // bit a: this part owns the tuple's particle a (adds its force)
  };

  // Rebuilds for `parts` owners if the part count or the tuples changed; particles(t) returns the
  // K particle indices of tuple t. Allocates only then (not in the step loop).
  template <class Particles>
  void prepare(std::size_t tuples, int parts, Particles&& particles) {
    if (parts == parts_ && tuples == tuples_) return;
    parts_ = parts;
    tuples_ = tuples;
    start_.assign(parts + 1, 0);
    work_.clear();
    if (parts == 1) {  // every tuple, every particle, in order
      for (std::size_t t = 0; t < tuples; ++t) work_.push_back({static_cast<int>(t), (1u << K) - 1});
      start_[1] = static_cast<std::int64_t>(work_.size());
      return;
    }
    int n = 0;
    for (std::size_t t = 0; t < tuples; ++t)
      for (int p : particles(t)) n = std::max(n, p + 1);
    std::vector<std::int64_t> ends(n + 1, 0);  // ends[p + 1]: tuple ends at particles ≤ p
    for (std::size_t t = 0; t < tuples; ++t)
      for (int p : particles(t)) ++ends[p + 1];
    const std::vector<int> first = owner_ranges(ends, parts);  // part u: particles first[u] … first[u + 1] − 1
    auto owner = [&](int p) {
      return static_cast<int>(std::upper_bound(first.begin(), first.end() - 1, p) - first.begin()) - 1;
    };
    std::vector<std::vector<Work>> per(parts);
    for (std::size_t t = 0; t < tuples; ++t) {
      const std::array<int, K> q = particles(t);
      std::array<std::uint8_t, kMaxOwners> mask{};  // per part, the particles it owns
      std::array<int, K> who{};
      for (int a = 0; a < K; ++a) {
        who[a] = owner(q[a]);
        for (int b = 0; b <= a; ++b)
          if (who[b] == who[a]) {
            mask[b] |= static_cast<std::uint8_t>(1u << a);
            break;
          }
      }
      for (int a = 0; a < K; ++a)
        if (mask[a] != 0) per[who[a]].push_back({static_cast<int>(t), mask[a]});
    }
    for (int u = 0; u < parts; ++u) {
      start_[u + 1] = start_[u] + static_cast<std::int64_t>(per[u].size());
      work_.insert(work_.end(), per[u].begin(), per[u].end());
    }
  }

  const Work* begin(int u) const { return work_.data() + start_[u]; }
  const Work* end(int u) const { return work_.data() + start_[u + 1]; }

 private:
  static constexpr int kMaxOwners = K;  // a tuple's particles have at most K owners
  int parts_ = 0;
  std::size_t tuples_ = 0;
  std::vector<std::int64_t> start_;
  std::vector<Work> work_;
};

}  // namespace stiffmd
