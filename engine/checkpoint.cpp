#include "engine/checkpoint.hpp"

#include <fcntl.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <system_error>

#include "engine/errors.hpp"

namespace stiffmd {
namespace {

constexpr char kMagic[8] = {'S', 'T', 'F', 'M', 'D', 'C', 'K', '1'};

// A little-endian-as-host binary image; checkpoints are for restarting on the same kind of
// machine, not for archiving (the trajectory formats are for that).
class Writer {
 public:
  // Writes through a 64 KiB buffer to fd (the whole image is never held in memory: a checkpoint
  // of a large system would otherwise double the run's peak memory at its end).
  Writer(int fd, std::string path) : fd_(fd), path_(std::move(path)) { buf_.reserve(kBuffer); }
  template <class T>
  void put(const T& v) {
    append(reinterpret_cast<const char*>(&v), sizeof(T));
  }
  void put(const std::string& s) {
    put<std::uint64_t>(s.size());
    append(s.data(), s.size());
  }
  void put(const double* d, size_t n) {
    put<std::uint64_t>(n);
    append(reinterpret_cast<const char*>(d), n * sizeof(double));
  }
  std::uint64_t written() const { return total_; }  // bytes put so far
  void flush() {
    size_t done = 0;
    while (done < buf_.size()) {
      const ssize_t k = ::write(fd_, buf_.data() + done, buf_.size() - done);
      if (k < 0) {
        if (errno == EINTR) continue;
        throw std::system_error(errno, std::generic_category(), "write");
      }
      done += static_cast<size_t>(k);
    }
    buf_.clear();
  }

 private:
  static constexpr size_t kBuffer = 1 << 16;
  void append(const char* p, size_t n) {
    total_ += n;
    while (n > 0) {
      const size_t k = std::min(n, kBuffer - buf_.size());
      buf_.insert(buf_.end(), p, p + k);
      p += k;
      n -= k;
      if (buf_.size() == kBuffer) flush();
    }
  }
  int fd_;
  std::string path_;
  std::vector<char> buf_;
  std::uint64_t total_ = 0;
};

class Reader {
 public:
  Reader(std::vector<char> b, std::string path) : buf_(std::move(b)), path_(std::move(path)) {}
  template <class T>
  T get() {
    need(sizeof(T));
    T v;
    std::memcpy(&v, buf_.data() + pos_, sizeof(T));
    pos_ += sizeof(T);
    return v;
  }
  std::string string() {
    const auto n = get<std::uint64_t>();
    need(n);
    std::string s(buf_.data() + pos_, n);
    pos_ += n;
    return s;
  }
  std::vector<double> doubles() {
    const auto n = get<std::uint64_t>();
    if (n > buf_.size()) bad();
    need(n * sizeof(double));
    std::vector<double> v(n);
    if (n > 0) std::memcpy(v.data(), buf_.data() + pos_, n * sizeof(double));  // no null pointer to memcpy
    pos_ += n * sizeof(double);
    return v;
  }
  bool at_end() const { return pos_ == buf_.size(); }
  size_t size() const { return buf_.size(); }
  [[noreturn]] void bad() const { throw InputError(path_ + ": not a stiffmd checkpoint, or truncated"); }

 private:
  void need(size_t n) const {
    if (n > buf_.size() - pos_) bad();  // pos_ <= size; pos_ + n could wrap for a corrupt length
  }
  std::vector<char> buf_;
  std::string path_;
  size_t pos_ = 0;
};

void fail_io(const std::string& path, const char* what) {
  throw InputError(path + ": cannot " + what + " checkpoint: " + std::strerror(errno));
}

}  // namespace

void write_checkpoint(const std::string& path, const Checkpoint& c) {
  write_checkpoint(path, c.state, c.method, c.h, c.integrator_state, c.initial_energy);
}

void write_checkpoint(const std::string& path, const State& state, const std::string& method, double h,
                      const std::vector<double>& integrator_state, double initial_energy) {
  // Temporary file in the same directory, fsync, rename over the old one, fsync the directory.
  const std::string tmp = path + ".tmp";
  const int fd = ::open(tmp.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
  if (fd < 0) fail_io(path, "create");
  try {
    Writer w(fd, path);
    for (char ch : kMagic) w.put(ch);
    w.put<std::int64_t>(state.size());
    w.put<std::int64_t>(state.step);
    w.put<double>(state.t);
    w.put(method);
    w.put<double>(h);
    w.put<double>(initial_energy);
    w.put(state.x.data(), static_cast<size_t>(state.x.size()));
    w.put(state.v.data(), static_cast<size_t>(state.v.size()));
    w.put(state.inv_mass.data(), static_cast<size_t>(state.inv_mass.size()));
    w.put(integrator_state.data(), integrator_state.size());
    w.put<std::uint64_t>(w.written() + sizeof(std::uint64_t));  // length trailer: detects truncation
    w.flush();
  } catch (const std::system_error& e) {
    ::close(fd);
    ::unlink(tmp.c_str());
    errno = e.code().value();
    fail_io(path, "write");
  }
  if (::fsync(fd) != 0 || ::close(fd) != 0) {
    ::unlink(tmp.c_str());
    fail_io(path, "sync");
  }
  if (std::rename(tmp.c_str(), path.c_str()) != 0) fail_io(path, "rename");
  const std::string dir = std::filesystem::path(path).parent_path().string();
  const int dfd = ::open(dir.empty() ? "." : dir.c_str(), O_RDONLY | O_DIRECTORY);
  if (dfd >= 0) {
    ::fsync(dfd);
    ::close(dfd);
  }
}

Checkpoint read_checkpoint(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw InputError(path + ": cannot open checkpoint");
  std::vector<char> bytes((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  Reader r(std::move(bytes), path);
  for (char ch : kMagic)
    if (r.get<char>() != ch) r.bad();
  Checkpoint c;
  const auto n = r.get<std::int64_t>();
  c.state.step = r.get<std::int64_t>();
  c.state.t = r.get<double>();
  c.method = r.string();
  c.h = r.get<double>();
  c.initial_energy = r.get<double>();
  const auto x = r.doubles(), v = r.doubles(), im = r.doubles();
  c.integrator_state = r.doubles();
  const auto length = r.get<std::uint64_t>();
  if (n < 0 || x.size() != 3 * static_cast<size_t>(n) || v.size() != x.size() || im.size() != static_cast<size_t>(n) ||
      !r.at_end() || length != r.size())
    r.bad();
  c.state.x = Eigen::Map<const Eigen::Matrix3Xd>(x.data(), 3, n);
  c.state.v = Eigen::Map<const Eigen::Matrix3Xd>(v.data(), 3, n);
  c.state.inv_mass = Eigen::Map<const Eigen::VectorXd>(im.data(), n);
  return c;
}

}  // namespace stiffmd
