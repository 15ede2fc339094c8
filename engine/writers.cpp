#include "engine/writers.hpp"

#include <cerrno>
#include <cmath>
#include <cstring>
#include <sstream>

#include "engine/errors.hpp"

namespace stiffmd {
namespace {

std::FILE* open_for_writing(const std::string& path) {
  std::FILE* f = std::fopen(path.c_str(), "w");
  if (!f) throw InputError(path + ": cannot open output file for writing: " + std::strerror(errno));
  return f;
}

}  // namespace

XyzWriter::XyzWriter(const std::string& path, std::vector<std::string> species, const Box& box, bool velocities)
    : file_(open_for_writing(path)), path_(path), species_(std::move(species)), velocities_(velocities) {
  std::ostringstream h;
  h << "Properties=species:S:1:pos:R:3" << (velocities ? ":velo:R:3" : "");
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

XyzWriter::~XyzWriter() {
  if (file_) std::fclose(file_);
}

void XyzWriter::write(const State& s) {
  std::fprintf(file_, "%d\n%s time=%.12g step=%lld\n", s.size(), header_.c_str(), s.t,
               static_cast<long long>(s.step));
  for (int i = 0; i < s.size(); ++i) {
    std::fprintf(file_, "%s %.12g %.12g %.12g", species_[i].c_str(), s.x(0, i), s.x(1, i), s.x(2, i));
    if (velocities_) std::fprintf(file_, " %.12g %.12g %.12g", s.v(0, i), s.v(1, i), s.v(2, i));
    std::fputc('\n', file_);
  }
  if (std::fflush(file_) != 0) throw InputError(path_ + ": write failed: " + std::strerror(errno));
}

CsvWriter::CsvWriter(const std::string& path, const std::vector<std::string>& columns)
    : file_(open_for_writing(path)), path_(path) {
  for (size_t k = 0; k < columns.size(); ++k) std::fprintf(file_, "%s%s", k ? "," : "", columns[k].c_str());
  std::fputc('\n', file_);
  std::fflush(file_);
}

CsvWriter::~CsvWriter() {
  if (file_) std::fclose(file_);
}

void CsvWriter::write(const std::vector<double>& row) {
  for (size_t k = 0; k < row.size(); ++k) std::fprintf(file_, "%s%.12g", k ? "," : "", row[k]);
  std::fputc('\n', file_);
  if (std::fflush(file_) != 0) throw InputError(path_ + ": write failed: " + std::strerror(errno));
}

}  // namespace stiffmd
