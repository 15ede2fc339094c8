#include "engine/checkpoint.hpp"

#include <fcntl.h>
#include <unistd.h>

#include <cerrno>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>

#include "engine/errors.hpp"

namespace stiffmd {
namespace {

constexpr char kMagic[8] = {'S', 'T', 'F', 'M', 'D', 'C', 'K', '1'};

// A little-endian-as-host binary image; checkpoints are for restarting on the same kind of
// machine, not for archiving (the trajectory formats are for that).
class Writer {
 public:
  template <class T>
  void put(const T& v) {
    const char* p = reinterpret_cast<const char*>(&v);
    buf_.insert(buf_.end(), p, p + sizeof(T));
  }
  void put(const std::string& s) {
    put<std::uint64_t>(s.size());
    buf_.insert(buf_.end(), s.begin(), s.end());
  }
  void put(const double* d, size_t n) {
    put<std::uint64_t>(n);
    const char* p = reinterpret_cast<const char*>(d);
    buf_.insert(buf_.end(), p, p + n * sizeof(double));
  }
  const std::vector<char>& bytes() const { return buf_; }

 private:
  std::vector<char> buf_;
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
    std::memcpy(v.data(), buf_.data() + pos_, n * sizeof(double));
    pos_ += n * sizeof(double);
    return v;
  }
  bool at_end() const { return pos_ == buf_.size(); }
  size_t size() const { return buf_.size(); }
  [[noreturn]] void bad() const { throw InputError(path_ + ": not a stiffmd checkpoint, or truncated"); }

 private:
  void need(size_t n) const {
    if (pos_ + n > buf_.size()) bad();
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
  Writer w;
  for (char ch : kMagic) w.put(ch);
  w.put<std::int64_t>(c.state.size());
  w.put<std::int64_t>(c.state.step);
  w.put<double>(c.state.t);
  w.put(c.method);
  w.put<double>(c.h);
  w.put<double>(c.initial_energy);
  w.put(c.state.x.data(), static_cast<size_t>(c.state.x.size()));
  w.put(c.state.v.data(), static_cast<size_t>(c.state.v.size()));
  w.put(c.state.inv_mass.data(), static_cast<size_t>(c.state.inv_mass.size()));
  w.put(c.integrator_state.data(), c.integrator_state.size());
  w.put<std::uint64_t>(w.bytes().size() + sizeof(std::uint64_t));  // length trailer: detects truncation

  // Temporary file in the same directory, fsync, rename over the old one, fsync the directory.
  const std::string tmp = path + ".tmp";
  const int fd = ::open(tmp.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
  if (fd < 0) fail_io(path, "create");
  const auto& bytes = w.bytes();
  size_t done = 0;
  while (done < bytes.size()) {
    const ssize_t k = ::write(fd, bytes.data() + done, bytes.size() - done);
    if (k < 0) {
      if (errno == EINTR) continue;
      const int e = errno;
      ::close(fd);
      ::unlink(tmp.c_str());
      errno = e;
      fail_io(path, "write");
    }
    done += static_cast<size_t>(k);
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
