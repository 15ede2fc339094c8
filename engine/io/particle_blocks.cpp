#include "engine/io/particle_blocks.hpp"

#include <algorithm>
#include <stdexcept>

namespace stiffmd {

ParticleBlock block_of(std::int64_t n, int ranks, int rank) {
  const std::int64_t first = n * rank / ranks, end = n * (rank + 1) / ranks;
  return {first, end - first};
}

int block_owner(std::int64_t g, std::int64_t n, int ranks) {
  return static_cast<int>(((g + 1) * ranks - 1) / n);
}

void BlockExchange::run(const Communicator& comm, std::int64_t n, const std::vector<int>& ids,
                        const std::vector<BlockArray>& arrays) {
  run(comm, n, ids, arrays, 0, (n + comm.size() - 1) / comm.size());  // ⌈n / P⌉: every block's rows
}

void BlockExchange::run(const Communicator& comm, std::int64_t n, const std::vector<int>& ids,
                        const std::vector<BlockArray>& arrays, std::int64_t from, std::int64_t to) {
  const int p = comm.size();
  std::size_t record = 1;  // the global index, then each array's rows
  for (const BlockArray& a : arrays) record += static_cast<std::size_t>(a.rows);
  // The block row of global index g, and whether it is in this exchange's rows.
  auto row_of = [&](int g, int owner) { return g - n * owner / p; };
  // Each message sized once (its rows counted first), so that a kept buffer grows only when a
  // larger exchange needs it, and never by doubling past what it holds.
  sending_.assign(static_cast<std::size_t>(p), 0);
  for (const int g : ids) {
    if (g < 0 || g >= n) throw std::invalid_argument("BlockExchange: a particle index out of range");
    const int owner = block_owner(g, n, p);
    if (const std::int64_t row = row_of(g, owner); row >= from && row < to) ++sending_[static_cast<std::size_t>(owner)];
  }
  send_.resize(static_cast<std::size_t>(p));
  for (int r = 0; r < p; ++r) {
    send_[static_cast<std::size_t>(r)].resize(record * sending_[static_cast<std::size_t>(r)]);
    sending_[static_cast<std::size_t>(r)] = 0;  // now: the next word to write
  }
  for (std::size_t k = 0; k < ids.size(); ++k) {
    const int owner = block_owner(ids[k], n, p);
    if (const std::int64_t row = row_of(ids[k], owner); row < from || row >= to) continue;
    std::vector<double>& b = send_[static_cast<std::size_t>(owner)];
    double* at = b.data() + sending_[static_cast<std::size_t>(owner)];
    *at++ = static_cast<double>(ids[k]);
    for (const BlockArray& a : arrays) {
      const std::size_t rows = static_cast<std::size_t>(a.rows);
      at = std::copy(a.owned + rows * k, a.owned + rows * (k + 1), at);
    }
    sending_[static_cast<std::size_t>(owner)] += record;
  }
  comm.exchange(send_, received_);
  const ParticleBlock mine = block_of(n, p, comm.rank());
  const std::int64_t first = std::min(from, mine.count), count = std::min(to, mine.count) - first;
  filled_.assign(static_cast<std::size_t>(count), 0);
  for (const std::vector<double>& b : received_)
    for (std::size_t at = 0; at < b.size(); at += record) {
      const auto row = static_cast<std::int64_t>(b[at]) - mine.first - first;
      if (filled_[static_cast<std::size_t>(row)]++)
        throw std::invalid_argument("BlockExchange: a particle on two processes");
      std::size_t next = at + 1;
      for (const BlockArray& a : arrays) {
        std::copy(b.begin() + static_cast<std::ptrdiff_t>(next), b.begin() + static_cast<std::ptrdiff_t>(next + a.rows),
                  a.block + a.rows * row);
        next += static_cast<std::size_t>(a.rows);
      }
    }
  if (std::find(filled_.begin(), filled_.end(), 0) != filled_.end())
    throw std::invalid_argument("BlockExchange: a particle on no process");
}

}  // namespace stiffmd
