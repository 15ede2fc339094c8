#include "engine/run/h5md_static_parts.hpp"

#include <algorithm>
#include <limits>
#include <stdexcept>

#include "core/errors.hpp"
#include "engine/io/rows_to_root.hpp"

namespace stiffmd {

void describe_h5md_static(const Scene& sc, const PartMolecules& mine, const Communicator& ranks, H5mdSetup& setup) {
  // Per type, the first global index that holds it (none: the largest int64), then the rank's
  // bonds and whether it holds a charge: one reduction of each kind.
  const std::size_t types = sc.types.size();
  constexpr std::int64_t kNone = std::numeric_limits<std::int64_t>::max();
  std::vector<std::int64_t> first(types, kNone);
  for (std::size_t k = 0; k < mine.global.size(); ++k) {
    std::int64_t& f = first[static_cast<std::size_t>(mine.type[k])];
    f = std::min<std::int64_t>(f, mine.global[k]);
  }
  if (types > 0) ranks.min(first.data(), static_cast<int>(types));
  std::int64_t counts[2] = {static_cast<std::int64_t>(mine.bonds.size()),
                            std::any_of(mine.charge.begin(), mine.charge.end(), [](double q) { return q != 0.0; })};
  ranks.sum(counts, 2);
  // Each symbol appears first where the first of its types does.
  std::vector<std::pair<std::int64_t, std::string>> appearing;
  for (std::size_t t = 0; t < types; ++t) {
    if (first[t] == kNone) continue;
    const std::string& symbol = sc.types[t].element;
    auto it = std::find_if(appearing.begin(), appearing.end(), [&](const auto& a) { return a.second == symbol; });
    if (it == appearing.end())
      appearing.emplace_back(first[t], symbol);
    else
      it->first = std::min(it->first, first[t]);
  }
  std::sort(appearing.begin(), appearing.end());
  setup.by_rows = true;
  setup.elements.clear();
  for (const auto& a : appearing) setup.elements.push_back(a.second);
  setup.num_bonds = counts[0];
  setup.charged = counts[1] > 0;
}

void write_h5md_static_parts(H5mdWriter* writer, const H5mdSetup& setup, const Scene& sc, const PartMolecules& mine,
                             const Communicator& ranks) {
  if (ranks.root() != (writer != nullptr))
    throw std::invalid_argument("write_h5md_static_parts: rank 0, and it alone, passes the writer");
  // Each type's index into the element table.
  std::vector<int> species(sc.types.size(), -1);
  for (std::size_t t = 0; t < sc.types.size(); ++t) {
    const auto it = std::find(setup.elements.begin(), setup.elements.end(), sc.types[t].element);
    if (it != setup.elements.end()) species[t] = static_cast<int>(it - setup.elements.begin());
  }
  // A failure of the writer (rank 0's) stops its writing, not the stream: the ranks then agree.
  std::string problem;
  std::vector<int> index, pairs;
  std::vector<double> mass, charge;
  const auto here = static_cast<std::size_t>(mine.size());
  stream_rows_to_root(
      ranks, {setup.num_particles, 3}, here, [&](std::size_t k) { return static_cast<std::int64_t>(mine.global[k]); },
      [&](std::size_t k, double* row) {
        const auto t = static_cast<std::size_t>(mine.type[k]);
        row[0] = species[t];
        row[1] = sc.types[t].mass;
        row[2] = mine.charge[k];
      },
      [&](std::int64_t first, std::int64_t count, const double* rows) {
        if (!problem.empty()) return;
        const auto n = static_cast<std::size_t>(count);
        index.resize(n), mass.resize(n), charge.resize(n);
        for (std::size_t r = 0; r < n; ++r)
          index[r] = static_cast<int>(rows[3 * r]), mass[r] = rows[3 * r + 1], charge[r] = rows[3 * r + 2];
        try {
          writer->write_particle_rows(first, count, index.data(), mass.data(), charge.data());
        } catch (const InputError& e) {
          problem = e.what();
        }
      });
  stream_rows_to_root(
      ranks, {setup.num_bonds, 2}, mine.bonds.size(), [&](std::size_t k) { return mine.bonds[k].place; },
      [&](std::size_t k, double* row) { row[0] = mine.bonds[k].item.i, row[1] = mine.bonds[k].item.j; },
      [&](std::int64_t first, std::int64_t count, const double* rows) {
        if (!problem.empty()) return;
        pairs.resize(2 * static_cast<std::size_t>(count));
        for (std::size_t r = 0; r < pairs.size(); ++r) pairs[r] = static_cast<int>(rows[r]);
        try {
          writer->write_bond_rows(first, count, pairs.data());
        } catch (const InputError& e) {
          problem = e.what();
        }
      });
  if (const Communicator::Problem failed = ranks.first_problem(problem); failed.rank >= 0) {
    if (ranks.size() > 1) throw AgreedInputError(failed.said(), ranks.root());
    throw InputError(failed.said());
  }
}

}  // namespace stiffmd
