#include "engine/io/rows_to_root.hpp"

#include <algorithm>
#include <stdexcept>
#include <string>
#include <vector>

namespace stiffmd {

void stream_rows_to_root(const Communicator& ranks, const RowStream& stream, std::size_t mine,
                         const std::function<std::int64_t(std::size_t)>& key,
                         const std::function<void(std::size_t, double*)>& fill,
                         const std::function<void(std::int64_t, std::int64_t, const double*)>& take) {
  const auto width = static_cast<std::size_t>(stream.width);
  const std::int64_t block = std::max<std::int64_t>(stream.block, 1);
  std::vector<double> sent, rows;
  std::vector<std::vector<double>> all;
  std::vector<char> filled;
  std::size_t k = 0;
  std::int64_t last = -1;
  for (std::int64_t first = 0; first < stream.rows; first += block) {
    const std::int64_t end = std::min(stream.rows, first + block);
    // This rank's rows in [first, end), each as its number then its values.
    sent.clear();
    for (; k < mine && key(k) < end; ++k) {
      const std::int64_t g = key(k);
      if (g <= last || g < first) throw std::logic_error("stream_rows_to_root: row numbers that do not increase");
      last = g;
      sent.push_back(static_cast<double>(g));
      sent.resize(sent.size() + width);
      fill(k, sent.data() + sent.size() - width);
    }
    ranks.gather(sent, all);
    if (!ranks.root()) continue;
    const auto count = static_cast<std::size_t>(end - first);
    rows.resize(count * width);
    filled.assign(count, 0);
    for (const std::vector<double>& piece : all)
      for (std::size_t at = 0; at < piece.size(); at += width + 1) {
        const auto row = static_cast<std::size_t>(static_cast<std::int64_t>(piece[at]) - first);
        if (row >= count || filled[row]++) throw std::logic_error("stream_rows_to_root: a row on two ranks");
        std::copy_n(piece.begin() + static_cast<std::ptrdiff_t>(at + 1), width,
                    rows.begin() + static_cast<std::ptrdiff_t>(row * width));
      }
    if (std::find(filled.begin(), filled.end(), 0) != filled.end())
      throw std::logic_error("stream_rows_to_root: row " +
                             std::to_string(first + (std::find(filled.begin(), filled.end(), 0) - filled.begin())) +
                             " on no rank");
    take(first, end - first, rows.data());
  }
  if (k < mine) throw std::logic_error("stream_rows_to_root: a row number out of range");
}

}  // namespace stiffmd
