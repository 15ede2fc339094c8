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
  const int p = comm.size();
  std::size_t record = 1;  // the global index, then each array's rows
  for (const BlockArray& a : arrays) record += static_cast<std::size_t>(a.rows);
  send_.resize(static_cast<std::size_t>(p));
  for (auto& buffer : send_) buffer.clear();
  for (std::size_t k = 0; k < ids.size(); ++k) {
    if (ids[k] < 0 || ids[k] >= n) throw std::invalid_argument("BlockExchange: a particle index out of range");
    std::vector<double>& b = send_[static_cast<std::size_t>(block_owner(ids[k], n, p))];
    b.push_back(static_cast<double>(ids[k]));
    for (const BlockArray& a : arrays) {
      const std::size_t rows = static_cast<std::size_t>(a.rows);
      b.insert(b.end(), a.owned + rows * k, a.owned + rows * (k + 1));
    }
  }
  comm.exchange(send_, received_);
  const ParticleBlock mine = block_of(n, p, comm.rank());
  filled_.assign(static_cast<std::size_t>(mine.count), 0);
  for (const std::vector<double>& b : received_)
    for (std::size_t at = 0; at < b.size(); at += record) {
      const auto row = static_cast<std::int64_t>(b[at]) - mine.first;
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
