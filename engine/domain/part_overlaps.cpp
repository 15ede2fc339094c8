#include "engine/domain/part_overlaps.hpp"

#include <algorithm>
#include <cstdint>
#include <limits>
#include <stdexcept>

namespace stiffmd {

std::string part_overlaps(const std::vector<OverlapRule>& rules, const std::vector<std::string>& pair_terms,
                          const Decomposition& domains, const Eigen::Matrix3Xd& owned_x, const Box& box,
                          const Scene& description, const Communicator& comm) {
  if (rules.empty()) return "";
  Eigen::Matrix3Xd x;
  domains.forward(owned_x, x);
  const std::vector<int>& ids = domains.pair_ids();
  const std::vector<char>& halo = domains.halo_flags();
  const PairBeadData& data = domains.pair_data();
  const std::int64_t n = description.whole_particles();
  constexpr std::int64_t kNone = std::numeric_limits<std::int64_t>::max();
  for (const OverlapRule& rule : rules) {
    const auto term = std::find(pair_terms.begin(), pair_terms.end(), rule.term);
    if (term == pair_terms.end() || static_cast<size_t>(term - pair_terms.begin()) >= data.special.size())
      throw std::logic_error("part_overlaps: the part has no pair term '" + rule.term + "'");
    const SpecialPartners& special = data.special[static_cast<size_t>(term - pair_terms.begin())];
    std::int64_t overlapping = 0;
    int ci = -1, cj = -1;  // slots; their global indices increase with them
    double closest = 0.0;
    close_pairs(x, box, rule.range(), [&](int i, int j, double r) {
      if (halo[static_cast<size_t>(i)] && halo[static_cast<size_t>(j)]) return;
      if (!(r < rule.distance(data.type[static_cast<size_t>(i)], data.type[static_cast<size_t>(j)]))) return;
      const auto first = special.partner.begin() + special.start[static_cast<size_t>(i)];
      const auto last = special.partner.begin() + special.start[static_cast<size_t>(i) + 1];
      const auto at = std::lower_bound(first, last, ids[static_cast<size_t>(j)]);
      if (at != last && *at == ids[static_cast<size_t>(j)] &&
          special.weight[static_cast<size_t>(at - special.partner.begin())] == 0.0)
        return;
      if (!halo[static_cast<size_t>(i)]) ++overlapping;  // i, the lower index, is home here
      if (ci < 0 || r < closest || (r == closest && std::pair{i, j} < std::pair{ci, cj})) ci = i, cj = j, closest = r;
    });
    comm.sum(&overlapping, 1);
    if (overlapping == 0) continue;
    // The least (r, i, j) over the ranks, and the lowest rank that has it names it.
    double least = ci < 0 ? -std::numeric_limits<double>::infinity() : -closest;
    comm.max(&least, 1);
    const bool closest_here = ci >= 0 && -closest == least;
    const std::int64_t pair = closest_here ? ids[static_cast<size_t>(ci)] * n + ids[static_cast<size_t>(cj)] : kNone;
    std::int64_t agreed = pair;
    comm.min(&agreed, 1);
    std::int64_t speaker = closest_here && pair == agreed ? comm.rank() : kNone;
    comm.min(&speaker, 1);
    std::string found;
    if (comm.rank() == speaker)
      found = rule.where + ": " +
              overlap_message(rule, particle_and_source(description, ids[static_cast<size_t>(ci)]),
                              particle_and_source(description, ids[static_cast<size_t>(cj)]), closest,
                              data.type[static_cast<size_t>(ci)], data.type[static_cast<size_t>(cj)],
                              static_cast<long>(overlapping));
    comm.broadcast(found, static_cast<int>(speaker));
    return found;
  }
  return "";
}

}  // namespace stiffmd
