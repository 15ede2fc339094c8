#include "engine/io/writers.hpp"

#include <zlib.h>

#include <cerrno>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <sstream>

#include "core/errors.hpp"

namespace stiffmd {
namespace {

bool is_gzip_name(const std::string& path) {
  return path.size() > 3 && path.compare(path.size() - 3, 3, ".gz") == 0;
}

// The whole (decompressed) text of a plain or gzip file.
std::string read_all(const std::string& path) {
  std::string text;
  gzFile g = gzopen(path.c_str(), "rb");  // reads plain files transparently too
  if (!g) throw InputError(path + ": cannot read output file to continue it: " + std::strerror(errno));
  char buf[1 << 16];
  int n;
  while ((n = gzread(g, buf, sizeof buf)) > 0) text.append(buf, static_cast<size_t>(n));
  gzclose(g);
  return text;
}

// Rewrites the file to hold only its first `keep` bytes of text (cheap truncate for plain
// files; a re-compression for gzip files).
void keep_prefix(const std::string& path, const std::string& text, size_t keep) {
  if (keep == text.size()) return;
  if (!is_gzip_name(path)) {
    std::filesystem::resize_file(path, keep);
    return;
  }
  const std::string tmp = path + ".tmp";
  gzFile g = gzopen(tmp.c_str(), "wb");
  const bool ok = g && gzwrite(g, text.data(), static_cast<unsigned>(keep)) == static_cast<int>(keep);
  if (!g || gzclose(g) != Z_OK || !ok) throw InputError(path + ": cannot rewrite output file to continue it");
  std::filesystem::rename(tmp, path);
}

}  // namespace

struct TextFile::Impl {
  std::string path;
  std::FILE* plain = nullptr;
  gzFile gz = nullptr;
};

TextFile::TextFile(const std::string& path, const char* mode) : impl_(std::make_unique<Impl>()) {
  impl_->path = path;
  const bool append = mode[0] == 'a';
  if (is_gzip_name(path))
    impl_->gz = gzopen(path.c_str(), append ? "ab" : "wb");  // appending adds a gzip member: still one valid stream
  else
    impl_->plain = std::fopen(path.c_str(), append ? "a" : "w");
  if (!impl_->gz && !impl_->plain)
    throw InputError(path + ": cannot open output file for writing: " + std::strerror(errno));
}

TextFile::~TextFile() {
  if (impl_->plain) std::fclose(impl_->plain);
  if (impl_->gz) gzclose(impl_->gz);
}

void TextFile::write(const std::string& text) {
  bool ok;
  if (impl_->plain) {
    ok = std::fwrite(text.data(), 1, text.size(), impl_->plain) == text.size() && std::fflush(impl_->plain) == 0;
  } else {
    // Z_SYNC_FLUSH: everything so far is decodable if the run dies now.
    ok = gzwrite(impl_->gz, text.data(), static_cast<unsigned>(text.size())) == static_cast<int>(text.size()) &&
         gzflush(impl_->gz, Z_SYNC_FLUSH) == Z_OK;
  }
  if (!ok) throw InputError(impl_->path + ": write failed: " + std::strerror(errno ? errno : EIO));
}

bool truncate_xyz_after(const std::string& path, double t, double tolerance) {
  if (!std::filesystem::exists(path)) return false;
  const std::string text = read_all(path);
  size_t pos = 0, keep = 0;
  while (pos < text.size()) {
    // Frame: count line, comment line with time=, count particle lines.
    const size_t count_end = text.find('\n', pos);
    if (count_end == std::string::npos) break;
    const long n = std::strtol(text.c_str() + pos, nullptr, 10);
    const size_t comment_end = text.find('\n', count_end + 1);
    if (comment_end == std::string::npos || n <= 0) break;
    const std::string comment = text.substr(count_end + 1, comment_end - count_end - 1);
    const size_t tp = comment.find(" time=");
    if (tp == std::string::npos) break;
    const double ft = std::strtod(comment.c_str() + tp + 6, nullptr);
    size_t end = comment_end;
    for (long i = 0; i < n && end != std::string::npos; ++i) end = text.find('\n', end + 1);
    if (end == std::string::npos || ft > t + tolerance) break;  // incomplete, or after the checkpoint
    pos = keep = end + 1;
  }
  keep_prefix(path, text, keep);
  return true;
}

bool truncate_csv_after(const std::string& path, double t, double tolerance, const std::vector<std::string>& columns) {
  if (!std::filesystem::exists(path)) return false;
  const std::string text = read_all(path);
  std::string header;
  for (size_t k = 0; k < columns.size(); ++k) header += (k ? "," : "") + columns[k];
  if (text.compare(0, header.size() + 1, header + "\n") != 0)
    throw InputError(path + ": cannot continue this file on restart: its columns differ from this run's");
  size_t pos = header.size() + 1, keep = pos;
  while (pos < text.size()) {
    const size_t end = text.find('\n', pos);
    if (end == std::string::npos || std::strtod(text.c_str() + pos, nullptr) > t + tolerance) break;
    pos = keep = end + 1;
  }
  keep_prefix(path, text, keep);
  return true;
}

XyzWriter::XyzWriter(const std::string& path, std::vector<std::string> species, const Box& box, bool velocities,
                     bool append, std::vector<double> masses)
    : file_(path, append ? "a" : "w"),
      species_(std::move(species)),
      masses_(std::move(masses)),
      velocities_(velocities) {
  set_box(box);
}

void XyzWriter::set_box(const Box& box) {
  std::ostringstream h;
  h << "Properties=species:S:1:pos:R:3" << (masses_.empty() ? "" : ":masses:R:1") << (velocities_ ? ":velo:R:3" : "");
  h << " pbc=\"" << (box.periodic[0] ? 'T' : 'F') << ' ' << (box.periodic[1] ? 'T' : 'F') << ' '
    << (box.periodic[2] ? 'T' : 'F') << '"';
  if (box.any_periodic()) {
    // Lattice rows are the cell vectors (ASE/OVITO convention); Origin is OVITO's cell origin.
    h.precision(12);
    h << " Lattice=\"" << box.lengths[0] << " 0 0 0 " << box.lengths[1] << " 0 0 0 " << box.lengths[2] << "\"";
    h << " Origin=\"" << box.origin[0] << ' ' << box.origin[1] << ' ' << box.origin[2] << "\"";
  }
  header_ = h.str();
}

void XyzWriter::write(const State& s, const int* type) {
  begin_frame(s.size(), s.t, s.step);
  write_rows(s.size(), s.x.data(), s.v.data(), type);
}

void XyzWriter::begin_frame(int n, double t, std::int64_t step) {
  char line[256];
  buffer_.clear();
  std::snprintf(line, sizeof line, "%d\n", n);
  buffer_ += line;
  buffer_ += header_;
  std::snprintf(line, sizeof line, " time=%.12g step=%lld\n", t * time_scale_, static_cast<long long>(step));
  buffer_ += line;
}

void XyzWriter::write_rows(int count, const double* x, const double* v, const int* type) {
  char line[256];
  for (int k = 0; k < count; ++k) {
    const auto t = static_cast<std::size_t>(type[k]);
    const double* xk = x + 3 * k;
    int c = std::snprintf(line, sizeof line, "%s %.12g %.12g %.12g", species_[t].c_str(), xk[0], xk[1], xk[2]);
    if (!masses_.empty()) c += std::snprintf(line + c, sizeof line - c, " %.12g", masses_[t]);
    if (velocities_) {
      const double* vk = v + 3 * k;
      c += std::snprintf(line + c, sizeof line - c, " %.12g %.12g %.12g", vk[0] * velocity_scale_,
                         vk[1] * velocity_scale_, vk[2] * velocity_scale_);
    }
    buffer_.append(line, static_cast<size_t>(c));
    buffer_ += '\n';
  }
  file_.write(buffer_);
  buffer_.clear();
}

CsvWriter::CsvWriter(const std::string& path, const std::vector<std::string>& columns, bool append)
    : file_(path, append ? "a" : "w") {
  if (append) return;
  std::string header;
  for (size_t k = 0; k < columns.size(); ++k) header += (k ? "," : "") + columns[k];
  file_.write(header + "\n");
}

void CsvWriter::write(const std::vector<double>& row) {
  char cell[32];
  buffer_.clear();
  for (size_t k = 0; k < row.size(); ++k) {
    const int n = std::snprintf(cell, sizeof cell, "%s%.12g", k ? "," : "", row[k]);
    buffer_.append(cell, static_cast<size_t>(n));
  }
  buffer_ += '\n';
  file_.write(buffer_);
}

}  // namespace stiffmd
