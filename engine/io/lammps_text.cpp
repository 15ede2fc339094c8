// Text helpers of the data-file readers (lammps_data.cpp, xyz_bonds.cpp): reading a whole file,
// whole-token number parses, quoting for messages, splitting on whitespace.
#include <charconv>
#include <filesystem>
#include <fstream>
#include <sstream>

#include "core/errors.hpp"
#include "engine/io/lammps_data.hpp"

namespace stiffmd {

namespace detail {

std::string read_text_file(const std::string& path) {
  std::error_code ec;
  const auto status = std::filesystem::status(path, ec);
  if (std::filesystem::is_directory(status)) throw InputError(path + ": is a directory, expected a file");
  // A device or FIFO (/dev/zero, a pipe) could be read forever: only regular files are read.
  if (std::filesystem::exists(status) && !std::filesystem::is_regular_file(status))
    throw InputError(path + ": is not a regular file (a device or pipe?), expected a file");
#ifdef FUZZING_BUILD_MODE_UNSAFE_FOR_PRODUCTION
  // A fuzzing build reads small files only, so that a deck naming a big one stays fast.
  if (const auto size = std::filesystem::file_size(path, ec); !ec && size > (256u << 10))
    throw InputError(path + ": larger than a fuzzing build reads");
#endif
  std::ifstream in(path, std::ios::binary);
  if (!in) throw InputError(path + ": cannot open file (missing or unreadable)");
  std::ostringstream buf;
  buf << in.rdbuf();
  if (in.bad()) throw InputError(path + ": read error");
  std::string text = std::move(buf).str();
  // The trajectory writer produces .gz files; say so rather than report binary garbage on line 1.
  if (text.size() >= 2 && static_cast<unsigned char>(text[0]) == 0x1f && static_cast<unsigned char>(text[1]) == 0x8b)
    throw InputError(path + ": is gzip-compressed; decompress it first (gunzip)");
  return text;
}

void check_lammps_data_file(const std::string& path) {
  std::error_code ec;
  const auto status = std::filesystem::status(path, ec);
  if (std::filesystem::is_directory(status)) throw InputError(path + ": is a directory, expected a file");
  if (std::filesystem::exists(status) && !std::filesystem::is_regular_file(status))
    throw InputError(path + ": is not a regular file (a device or pipe?), expected a file");
  std::ifstream in(path, std::ios::binary);
  if (!in) throw InputError(path + ": cannot open file (missing or unreadable)");
  char magic[2] = {0, 0};
  in.read(magic, 2);
  if (in.gcount() == 2 && static_cast<unsigned char>(magic[0]) == 0x1f && static_cast<unsigned char>(magic[1]) == 0x8b)
    throw InputError(path + ": is gzip-compressed; decompress it first (gunzip)");
  if (in.gcount() == 0)
    throw InputError(path + ": file is empty; expected a LAMMPS data file (title line, header, sections)");
}

// from_chars rejects a leading '+', which Fortran- and printf("%+g")-style writers emit.
static std::string_view drop_plus(std::string_view s) {
  if (s.size() >= 2 && s[0] == '+' && s[1] != '-' && s[1] != '+') s.remove_prefix(1);
  return s;
}

bool parse_double(std::string_view s, double& out) {
  s = drop_plus(s);
  if (s.empty()) return false;
  const auto [p, ec] = std::from_chars(s.data(), s.data() + s.size(), out);
  return ec == std::errc() && p == s.data() + s.size() && std::isfinite(out);
}

bool parse_long(std::string_view s, long long& out) {
  s = drop_plus(s);
  if (s.empty()) return false;
  const auto [p, ec] = std::from_chars(s.data(), s.data() + s.size(), out);
  return ec == std::errc() && p == s.data() + s.size();
}

std::string quote(std::string_view s) {
  constexpr size_t kMax = 40;
  std::string q = "'";
  for (size_t k = 0; k < s.size() && k < kMax; ++k) {
    const auto c = static_cast<unsigned char>(s[k]);
    q += (c >= 0x20 && c < 0x7f) ? static_cast<char>(c) : '?';
  }
  if (s.size() > kMax) q += "...";
  return q + "'";
}

bool is_space(char c) {
  return c == ' ' || c == '\t' || c == '\r' || c == '\v' || c == '\f';
}

std::string_view trim(std::string_view s) {
  while (!s.empty() && is_space(s.front())) s.remove_prefix(1);
  while (!s.empty() && is_space(s.back())) s.remove_suffix(1);
  return s;
}

void split_ws_into(std::string_view s, std::vector<std::string_view>& out) {
  out.clear();
  size_t k = 0;
  while (k < s.size()) {
    while (k < s.size() && is_space(s[k])) ++k;
    const size_t b = k;
    while (k < s.size() && !is_space(s[k])) ++k;
    if (k > b) out.push_back(s.substr(b, k - b));
  }
}

std::vector<std::string_view> split_ws(std::string_view s) {
  std::vector<std::string_view> out;
  split_ws_into(s, out);
  return out;
}

}  // namespace detail

}  // namespace stiffmd
