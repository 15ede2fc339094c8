// H5MD 1.1 writer on the HDF5 C API; the layout is drawn in h5md_writer.hpp. Section names in
// comments ("§Time-dependent data", "§Simulation box", ...) are those of the H5MD specification,
// https://nongnu.org/h5md/h5md.html.
//
// Units. In reduced units (`units = "lj"`) no dataset carries a `unit` attribute (§Units module:
// the attribute is optional). This is also what MDAnalysis 2.4.2 needs: its H5MD reader raises a
// RuntimeError for any unit string it does not know (e.g. "reduced"), even with
// convert_units=False, and a known one such as "nm" would make it rescale our reduced lengths by
// default. Without units it reads the file when opened with convert_units=False (with the default
// convert_units=True it raises ValueError: "H5MD file must have readable units").
// In real units (`units = "real"`, core/units.hpp) position/value, position/time (shared by
// every element through hard links), velocity/value, force/value, box/edges/value and the
// observables carry `unit` (Angstrom, fs, "Angstrom ps-1", "kcal mol-1 Angstrom-1", …), strings
// MDAnalysis 2.4.2 knows; as variable-length strings, because h5py hands fixed-length ones to it
// as bytes, which its unit table does not match.
//
// Crash safety (a SIGKILL at any moment leaves a file h5py and MDAnalysis read up to a complete
// frame; tests/test_h5md.py kills writers mid-frame to check it). Three choices make it so:
//  - write_frame ends with H5Fflush, which hands the frame to the operating system (there is no
//    fsync: a power cut may still lose recent frames);
//  - position/value and then position/step are extended last, each after a flush (write_frame);
//  - compressed series have one frame per chunk, so no chunk is ever moved (see chunk_shape).
// The file uses the HDF5 1.8 format (superblock v2): the 1.10 format (superblock v3) marks a file
// open for writing, and HDF5 then refuses to open a killed file until `h5clear` is run on it.
// What remains (seen in about 1 of 200 kills of a writer that does nothing but flush, so far
// rarer in a run): a kill inside H5Fflush after metadata naming newly allocated space is written
// but before the superblock, which records the end of the allocated space and is written last.
// HDF5 then refuses reads of that space ("addr overflow"), which can include older frames when a
// chunk index node was just split. Reopening for appending extends the recorded end to the file's
// size (see append), as `h5clear --increment=0 FILE` would; that repaired every such file seen in
// testing (HDF5 writes the new space before the superblock), though HDF5 does not promise it.
#include "engine/io/h5md_writer.hpp"

#include <hdf5.h>
#include <pwd.h>
#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <limits>
#include <stdexcept>

#include "core/communicator.hpp"
#include "core/errors.hpp"
#include "engine/io/particle_blocks.hpp"

namespace stiffmd {
namespace {

// A failed HDF5 call or a file that does not fit the setup; the public entry points turn it into
// one InputError line that starts with the path.
struct Failure : std::runtime_error {
  using std::runtime_error::runtime_error;
  // Found by every process of a shared file at the same point (a check of the file's content, or
  // an outcome broadcast), rather than by this one alone.
  bool agreed = false;
};

Failure agreed_failure(const std::string& what) {
  Failure f(what);
  f.agreed = true;
  return f;
}

// Why the last HDF5 call failed, from the innermost entry of its error stack: the system's message
// where there is one ("Permission denied", "No space left on device"), else HDF5's own.
std::string hdf5_reason() {
  std::string innermost;
  H5Ewalk2(
      H5E_DEFAULT, H5E_WALK_UPWARD,
      [](unsigned, const H5E_error2_t* e, void* data) -> herr_t {
        auto* s = static_cast<std::string*>(data);
        if (s->empty() && e->desc) *s = e->desc;
        return 0;
      },
      &innermost);
  if (innermost.find("unable to lock file") != std::string::npos)
    return "the file is locked: another program has it open";
  const std::string key = "error message = '";
  if (const auto p = innermost.find(key); p != std::string::npos)
    return innermost.substr(p + key.size(), innermost.find('\'', p + key.size()) - p - key.size());
  return innermost;
}

[[noreturn]] void fail(const std::string& what) {
  const std::string reason = hdf5_reason();
  throw Failure(reason.empty() ? what : what + ": " + reason);
}

void ok(herr_t status, const std::string& what) {
  if (status < 0) fail(what);
}

// Owns one HDF5 identifier and closes it with the matching H5?close function.
class Handle {
 public:
  using Closer = herr_t (*)(hid_t);
  Handle() = default;
  Handle(hid_t id, Closer close, const std::string& what) : id_(id), close_(close) {
    if (id_ < 0) fail(what);
  }
  Handle(Handle&& o) noexcept : id_(std::exchange(o.id_, H5I_INVALID_HID)), close_(o.close_) {}
  Handle& operator=(Handle&& o) noexcept {
    if (this != &o) {
      reset();
      id_ = std::exchange(o.id_, H5I_INVALID_HID);
      close_ = o.close_;
    }
    return *this;
  }
  ~Handle() { reset(); }
  void reset() {
    if (id_ >= 0 && close_) close_(id_);
    id_ = H5I_INVALID_HID;
  }
  // Forgets the identifier without closing it (a shared file's rank that is about to end the job:
  // see H5mdWriter::Impl::~Impl).
  void release() { id_ = H5I_INVALID_HID; }
  operator hid_t() const { return id_; }  // NOLINT: passes straight into the C API

 private:
  hid_t id_ = H5I_INVALID_HID;
  Closer close_ = nullptr;
};

Handle create_group(hid_t parent, const std::string& name) {
  return {H5Gcreate2(parent, name.c_str(), H5P_DEFAULT, H5P_DEFAULT, H5P_DEFAULT), H5Gclose,
          "cannot create group " + name};
}

Handle open_group(hid_t parent, const std::string& name) {
  return {H5Gopen2(parent, name.c_str(), H5P_DEFAULT), H5Gclose, "missing group " + name};
}

Handle simple_space(const std::vector<hsize_t>& dims, const std::vector<hsize_t>* maxdims = nullptr) {
  return {H5Screate_simple(static_cast<int>(dims.size()), dims.data(), maxdims ? maxdims->data() : nullptr), H5Sclose,
          "cannot create a dataspace"};
}

// ---- attributes (§H5MD metadata, §Simulation box: strings are fixed-length, scalar or rank 1) ----

// A string type: variable-length (what reading an older file's attribute needs) or `fixed_size`
// bytes, null-terminated.
Handle string_type(bool variable_length, std::size_t fixed_size = 0) {
  Handle t(H5Tcopy(H5T_C_S1), H5Tclose, "cannot create a string type");
  ok(H5Tset_size(t, variable_length ? H5T_VARIABLE : fixed_size), "cannot size a string type");
  ok(H5Tset_cset(t, H5T_CSET_UTF8), "cannot set a string character set");
  return t;
}

void write_attribute(hid_t object, const std::string& name, hid_t type, hid_t space, const void* data) {
  Handle a(H5Acreate2(object, name.c_str(), type, space, H5P_DEFAULT, H5P_DEFAULT), H5Aclose,
           "cannot create attribute " + name);
  ok(H5Awrite(a, type, data), "cannot write attribute " + name);
}

// §H5MD metadata and §Simulation box ask for fixed-length strings (author, creator, boundary; we
// keep to it for our own `elements` too): one type of the longest value's length plus its
// terminating zero (as C and h5dump expect), shorter values zero-padded; ASCII unless a value
// needs UTF-8 (an author's name may). `scalar`: one value in a scalar dataspace, else rank 1.
void write_fixed_strings_attribute(hid_t object, const std::string& name, const std::vector<std::string>& values,
                                   bool scalar) {
  std::size_t size = 1;
  bool ascii = true;
  for (const auto& v : values) {
    size = std::max(size, v.size() + 1);
    for (unsigned char c : v) ascii = ascii && c < 0x80;
  }
  std::vector<char> packed(size * values.size(), '\0');
  for (std::size_t k = 0; k < values.size(); ++k) std::memcpy(&packed[k * size], values[k].data(), values[k].size());
  Handle type = string_type(false, size);
  ok(H5Tset_strpad(type, H5T_STR_NULLTERM), "cannot set a string padding");
  if (ascii) ok(H5Tset_cset(type, H5T_CSET_ASCII), "cannot set a string character set");
  Handle space = scalar ? Handle(H5Screate(H5S_SCALAR), H5Sclose, "dataspace") : simple_space({values.size()});
  write_attribute(object, name, type, space, packed.data());
}

void write_string_attribute(hid_t object, const std::string& name, const std::string& value) {
  write_fixed_strings_attribute(object, name, {value}, true);
}

void write_strings_attribute(hid_t object, const std::string& name, const std::vector<std::string>& values) {
  write_fixed_strings_attribute(object, name, values, false);
}

// §Units: a `unit` attribute, variable-length (see the top of this file); nothing for "".
void write_unit(hid_t object, const std::string& unit) {
  if (unit.empty()) return;
  const char* value = unit.c_str();
  Handle type = string_type(true);
  ok(H5Tset_cset(type, H5T_CSET_ASCII), "cannot set a string character set");
  write_attribute(object, "unit", type, Handle(H5Screate(H5S_SCALAR), H5Sclose, "dataspace"), &value);
}

void write_int_attribute(hid_t object, const std::string& name, const std::vector<int>& values, bool scalar) {
  Handle space = scalar ? Handle(H5Screate(H5S_SCALAR), H5Sclose, "dataspace") : simple_space({values.size()});
  Handle a(H5Acreate2(object, name.c_str(), H5T_STD_I32LE, space, H5P_DEFAULT, H5P_DEFAULT), H5Aclose,
           "cannot create attribute " + name);
  ok(H5Awrite(a, H5T_NATIVE_INT, values.data()), "cannot write attribute " + name);
}

// A scalar string attribute, fixed-length or variable-length (earlier stiffmd builds wrote the
// latter, and a restart may append to such a file); empty when absent or not a string.
std::string read_string_attribute(hid_t object, const std::string& name) {
  if (H5Aexists(object, name.c_str()) <= 0) return {};
  Handle a(H5Aopen(object, name.c_str(), H5P_DEFAULT), H5Aclose, "cannot open attribute " + name);
  Handle type(H5Aget_type(a), H5Tclose, "cannot read the type of attribute " + name);
  if (H5Tget_class(type) != H5T_STRING) return {};
  if (H5Tis_variable_str(type) > 0) {
    char* s = nullptr;
    if (H5Aread(a, string_type(true), &s) < 0 || !s) return {};
    std::string value(s);
    H5free_memory(s);
    return value;
  }
  std::vector<char> buffer(H5Tget_size(type) + 1, '\0');  // + 1: a zero even when the file has none
  if (H5Aread(a, type, buffer.data()) < 0) return {};
  return buffer.data();
}

// ---- time-independent datasets (§Time-independent data) ----

// `writes`: false on the processes of a shared file but rank 0 (the dataset is created by all of
// them, its data written by one, independently).
Handle create_dataset(hid_t parent, const std::string& name, hid_t file_type, const std::vector<hsize_t>& dims) {
  return {H5Dcreate2(parent, name.c_str(), file_type, simple_space(dims), H5P_DEFAULT, H5P_DEFAULT, H5P_DEFAULT),
          H5Dclose, "cannot create dataset " + name};
}

void write_dataset(hid_t parent, const std::string& name, hid_t file_type, hid_t memory_type,
                   const std::vector<hsize_t>& dims, const void* data, bool writes) {
  Handle d = create_dataset(parent, name, file_type, dims);
  bool empty = false;
  for (hsize_t n : dims) empty = empty || n == 0;
  if (!empty && writes)
    ok(H5Dwrite(d, memory_type, H5S_ALL, H5S_ALL, H5P_DEFAULT, data), "cannot write dataset " + name);
}

// Rows [first, first + count) of a time-independent dataset of `width` values a row (1: [n], 2:
// [n][2]), written by this process alone (independently, in a shared file too).
void write_rows(hid_t dataset, hid_t memory_type, std::int64_t first, std::int64_t count, hsize_t width,
                const void* data, const std::string& name) {
  if (count <= 0) return;
  Handle file_space(H5Dget_space(dataset), H5Sclose, "cannot select in " + name);
  const int rank = H5Sget_simple_extent_ndims(file_space);
  const hsize_t start[2] = {static_cast<hsize_t>(first), 0}, rows[2] = {static_cast<hsize_t>(count), width};
  ok(H5Sselect_hyperslab(file_space, H5S_SELECT_SET, start, nullptr, rows, nullptr), "cannot select in " + name);
  Handle memory = simple_space(std::vector<hsize_t>(rows, rows + rank));
  ok(H5Dwrite(dataset, memory_type, memory, file_space, H5P_DEFAULT, data), "cannot write dataset " + name);
}

// ---- time-dependent series (§Time-dependent data) ----

// What of a frame this process writes: all of it, nothing (a process of a shared file whose rank
// 0 writes this series), or along the particle axis its block of particles [first, first + count).
struct FramePart {
  enum What { all, none, block } what = all;
  hsize_t first = 0, count = 0;  // block
};

// The `value` (or `step`/`time`) dataset of a time-dependent element: [frames][item...], with an
// unlimited frame axis so frames can be appended.
struct Series {
  Handle dataset;
  hid_t memory_type = H5I_INVALID_HID;  // a predefined native type, owned by the library
  std::vector<hsize_t> item;            // shape of one frame: {} scalar, {3}, {N, 3}
  std::string name;
  hid_t transfer = H5P_DEFAULT;  // a shared file's: collective (owned by the writer)

  hsize_t length() const {
    Handle space(H5Dget_space(dataset), H5Sclose, "cannot read the extent of " + name);
    std::vector<hsize_t> dims(item.size() + 1);
    ok(H5Sget_simple_extent_dims(space, dims.data(), nullptr), "cannot read the extent of " + name);
    return dims[0];
  }

  void resize(hsize_t frames) const {
    std::vector<hsize_t> dims{frames};
    dims.insert(dims.end(), item.begin(), item.end());
    ok(H5Dset_extent(dataset, dims.data()), "cannot resize " + name);
  }

  // Writes frame `index` (this process's `part` of it), setting the extent to index + 1 (so a
  // frame interrupted by an error is overwritten by the next call rather than left as a gap). In
  // a shared file every process calls it (collective), each with its part.
  void write(hsize_t index, const void* data, const FramePart& part = {}) const {
    resize(index + 1);
    std::vector<hsize_t> start(item.size() + 1, 0), count{1};
    start[0] = index;
    count.insert(count.end(), item.begin(), item.end());
    Handle file_space(H5Dget_space(dataset), H5Sclose, "cannot select in " + name);
    Handle memory = simple_space(count);
    const std::string what = "cannot select in " + name;
    if (part.what == FramePart::all) {
      ok(H5Sselect_hyperslab(file_space, H5S_SELECT_SET, start.data(), nullptr, count.data(), nullptr), what);
    } else if (part.what == FramePart::none) {
      ok(H5Sselect_none(file_space), what);
      ok(H5Sselect_none(memory), what);
    } else {  // the block of particles
      start[1] = part.first, count[1] = part.count;
      ok(H5Sselect_hyperslab(file_space, H5S_SELECT_SET, start.data(), nullptr, count.data(), nullptr), what);
      memory = simple_space(count);
    }
    static const double nothing = 0.0;  // HDF5 wants a buffer even for an empty selection
    ok(H5Dwrite(dataset, memory_type, memory, file_space, transfer, data ? data : &nothing), "cannot write " + name);
  }
};

// Chunks along the frame axis (unlimited, so frames can be appended).
//
// Uncompressed: about 64 KiB, at least one frame and at most 1024 (each flush rewrites the partly
// filled last chunk in place, so scalar series keep small chunks; a chunk's space is allocated
// whole, so a short run's file holds up to 64 KiB per element). Frames of more than 2^20
// particles are split along the particle axis to keep a chunk below 24 MiB.
//
// Compressed: one frame per chunk. A compressed chunk that is rewritten with more frames grows and
// is moved; HDF5 frees the old place and may reuse it before the next flush records the move, so a
// kill in between leaves an index pointing at overwritten bytes ("inflate() failed" on reading,
// seen in testing). A chunk written once is never moved. Only the per-particle elements are
// compressed (callers pass gzip = 0 for step, time, edges and observables): one-frame chunks of a
// scalar would cost more than they save.
std::vector<hsize_t> chunk_shape(const std::vector<hsize_t>& item, std::size_t type_size, bool compressed) {
  std::vector<hsize_t> chunk{1};
  chunk.insert(chunk.end(), item.begin(), item.end());
  if (item.size() == 2) chunk[1] = std::min<hsize_t>(item[0], hsize_t{1} << 20);
  hsize_t frame_bytes = type_size;
  for (std::size_t k = 1; k < chunk.size(); ++k) frame_bytes *= chunk[k];
  chunk[0] = compressed ? 1 : std::clamp<hsize_t>(65536 / frame_bytes, 1, 1024);
  return chunk;
}

Series create_series(hid_t group, const std::string& name, hid_t file_type, hid_t memory_type,
                     const std::vector<hsize_t>& item, int gzip) {
  std::vector<hsize_t> dims{0}, maxdims{H5S_UNLIMITED};
  dims.insert(dims.end(), item.begin(), item.end());
  maxdims.insert(maxdims.end(), item.begin(), item.end());
  const std::vector<hsize_t> chunk = chunk_shape(item, H5Tget_size(file_type), gzip > 0);
  Handle dcpl(H5Pcreate(H5P_DATASET_CREATE), H5Pclose, "cannot create dataset properties");
  ok(H5Pset_chunk(dcpl, static_cast<int>(chunk.size()), chunk.data()), "cannot chunk " + name);
  if (gzip > 0) {
    ok(H5Pset_shuffle(dcpl), "cannot set the shuffle filter on " + name);  // byte shuffle: doubles compress better
    ok(H5Pset_deflate(dcpl, static_cast<unsigned>(gzip)), "cannot set gzip on " + name);
  } else {
    // Chunks allocated when the frame axis grows, as parallel HDF5 allocates them in a shared
    // file: it writes an unfiltered series only into allocated chunks, so a file that one process
    // wrote with HDF5's serial default (a chunk allocated at its first write) could not be
    // appended to by several (a restart onto more ranks). No fill value is written: every frame
    // is written whole.
    ok(H5Pset_alloc_time(dcpl, H5D_ALLOC_TIME_EARLY), "cannot set the allocation time of " + name);
    ok(H5Pset_fill_time(dcpl, H5D_FILL_TIME_NEVER), "cannot set the fill time of " + name);
  }
  Series s;
  s.dataset =
      Handle(H5Dcreate2(group, name.c_str(), file_type, simple_space(dims, &maxdims), H5P_DEFAULT, dcpl, H5P_DEFAULT),
             H5Dclose, "cannot create dataset " + name);
  s.memory_type = memory_type;
  s.item = item;
  s.name = name;
  return s;
}

// Opens an existing series and checks that one frame has the expected shape.
Series open_series(hid_t group, const std::string& name, hid_t memory_type, const std::vector<hsize_t>& item) {
  Series s;
  s.dataset = Handle(H5Dopen2(group, name.c_str(), H5P_DEFAULT), H5Dclose, "missing dataset " + name);
  s.memory_type = memory_type;
  s.item = item;
  s.name = name;
  Handle space(H5Dget_space(s.dataset), H5Sclose, "cannot read the extent of " + name);
  std::vector<hsize_t> dims(item.size() + 1);
  if (H5Sget_simple_extent_ndims(space) != static_cast<int>(dims.size()) ||
      H5Sget_simple_extent_dims(space, dims.data(), nullptr) < 0 ||
      !std::equal(item.begin(), item.end(), dims.begin() + 1))
    throw Failure(name + " does not have the shape this run writes");
  return s;
}

// Each element's step and time are hard links to position's (§Time-dependent data allows it for
// equal sampling; §Particles group and §Simulation box require it for image and box/edges).
void link_time_grid(hid_t position_group, hid_t element_group) {
  for (const char* name : {"step", "time"})
    ok(H5Lcreate_hard(position_group, name, element_group, name, H5P_DEFAULT, H5P_DEFAULT),
       std::string("cannot link ") + name);
}

// ---- scene data ----

std::string default_author() {
  if (const char* user = std::getenv("USER"); user && *user) return user;
  if (const passwd* pw = getpwuid(getuid()); pw && pw->pw_name) return pw->pw_name;
  return "unknown";
}

// Distinct symbols in order of first appearance, and each particle's index into them.
std::pair<std::vector<std::string>, std::vector<int>> element_table(const std::vector<std::string>& species) {
  std::vector<std::string> table;
  std::vector<int> index;
  for (const auto& s : species) {
    auto it = std::find(table.begin(), table.end(), s);
    index.push_back(static_cast<int>(it - table.begin()));
    if (it == table.end()) table.push_back(s);
  }
  return {table, index};
}

// Periodic axes wrapped into [origin, origin + L) with the integer image, so that
// x = r + a L (§Particles group, `image`); open axes are copied with image 0 (a placeholder).
void wrap_into_box(const Box& box, const Eigen::Matrix3Xd& x, Eigen::Matrix3Xd& r,
                   Eigen::Matrix<std::int32_t, 3, Eigen::Dynamic>& a) {
  r = x;
  a.setZero(3, x.cols());
  for (Eigen::Index i = 0; i < x.cols(); ++i)
    for (int k = 0; k < 3; ++k) {
      if (!box.periodic[k]) continue;
      const double o = box.origin[k], L = box.lengths[k];
      double n = std::floor((x(k, i) - o) / L);
      if (!std::isfinite(n) || std::abs(n) > std::numeric_limits<std::int32_t>::max() - 1) continue;  // as is
      double w = x(k, i) - n * L;
      if (w >= o + L) w = x(k, i) - (++n) * L;  // rounding put it on the upper face
      if (w < o) w = x(k, i) - (--n) * L;
      r(k, i) = w;
      a(k, i) = static_cast<std::int32_t>(n);
    }
}

void check_setup(const H5mdSetup& s) {
  const auto n = static_cast<std::size_t>(std::max(s.num_particles, 0));
  if (s.num_particles < 1) throw Failure("no particles to write");
  if (s.by_rows && (!s.species.empty() || s.mass.size() != 0 || !s.charge.empty() || !s.bonds.empty() ||
                    s.elements.empty() || s.num_bonds < 0))
    throw std::invalid_argument("H5mdSetup: by rows, the element table and no per-particle data");
  if (!s.by_rows && (s.species.size() != n || static_cast<std::size_t>(s.mass.size()) != n))
    throw std::invalid_argument("H5mdSetup: species and mass need one entry per particle");
  if (!s.charge.empty() && s.charge.size() != n)
    throw std::invalid_argument("H5mdSetup: charge needs one entry per particle (or none)");
  for (const auto& [i, j] : s.bonds)
    if (i < 0 || j < 0 || i >= s.num_particles || j >= s.num_particles)
      throw std::invalid_argument("H5mdSetup: bond index out of range");
  for (const auto& name : s.observables)
    if (name.empty() || name.find('/') != std::string::npos || name == "." || name == "..")
      throw std::invalid_argument("H5mdSetup: observable name '" + name + "' is not a valid HDF5 name");
  for (int k = 0; k < 3; ++k)
    if (s.box.periodic[k] && !(s.box.lengths[k] > 0)) throw Failure("periodic box axis with length <= 0");
  if (s.gzip < 0 || s.gzip > 9) throw Failure("gzip level must be 0..9");
}

}  // namespace

struct H5mdWriter::Impl {
  std::string path;
  H5mdSetup setup;
  // A file shared by the processes (H5mdSetup::processes, parallel HDF5): every metadata call is
  // made by all of them alike; rank 0 alone writes the time-independent datasets and the scalar
  // series, each process its own particles' rows through a collective transfer.
  bool shared = false;
  bool writes_whole = true;  // one process, or rank 0 of a shared file
  Handle transfer;           // shared: the collective transfer properties
  Handle file;               // declared after transfer: closed first
  Series step, time, position, image, velocity, force, edges;
  std::vector<Series> observables;
  std::int64_t frames = 0;
  Eigen::Matrix3Xd wrapped;  // scratch for write_frame
  // A shared file: this process's block of particles (block_rows), its x, v, f, and the exchange
  // that brings them there (to_block).
  Eigen::Matrix3Xd block_x, block_v, block_f;
  BlockExchange exchange;                          // to_block's buffers
  std::vector<double> shared_scalars, shared_obs;  // rank 0's time and observables, broadcast
  Eigen::Matrix<std::int32_t, 3, Eigen::Dynamic> images;
  Eigen::Matrix3d edge_vectors = Eigen::Matrix3d::Zero();  // diag(L): rows are the edge vectors
  // By rows (H5mdSetup::by_rows): the time-independent datasets, open until they are written.
  Handle species, mass, charge, id, bonds, bond_from, bond_to;
  std::vector<std::int64_t> id_rows;
  std::vector<int> from_rows, to_rows;

  Impl(std::string p, const H5mdSetup& s) : path(std::move(p)), setup(s) {
    edge_vectors.diagonal() = s.box.lengths;
    shared = s.processes && s.processes->size() > 1;
    writes_whole = !shared || s.processes->root();
    shared_obs.resize(s.observables.size());
  }
  // Closing a shared file is collective (H5Fclose, and H5Dclose where metadata is flushed): it is
  // done by close(), which every process calls at the same point. A shared file destroyed without
  // it belongs to a process that is leaving alone (an error on this rank: the job is ended by
  // MPI_Abort, engine/main.cpp), and a collective call there would wait for ranks that never come:
  // its identifiers are dropped unclosed. Every frame was flushed when written, so the file reads
  // as a killed writer's (see the top of this file).
  ~Impl() {
    if (!shared) return;
    for (Series* s : all_series()) s->dataset.release();
    for (Handle* h : static_datasets()) h->release();
    file.release();
  }
  Impl(const Impl&) = delete;
  Impl& operator=(const Impl&) = delete;
  void close() {
    for (Series* s : all_series()) s->dataset.reset();
    for (Handle* h : static_datasets()) h->reset();
    const herr_t status = file >= 0 ? H5Fclose(file) : 0;
    file.release();
    ok(status, "cannot close the file");
  }

  void create();
  void append(std::int64_t first_step);
  void open_for_append(std::int64_t first_step, hid_t access);
  void write_frame(std::int64_t step, double t, const Eigen::Matrix3Xd& x, const Eigen::Matrix3Xd* v,
                   const Eigen::Matrix3Xd* f, const std::vector<double>& obs, const std::vector<int>* ids);

 private:
  Handle file_access(bool shared_access) const;
  void write_metadata();
  void create_particles();
  void create_box(hid_t particles, hid_t position_group);
  void create_connectivity();
  void create_vmd_structure();
  void create_observables(hid_t position_group);
  void open_elements();
  void check_allocation();
  void check_particle_count(hid_t position_group) const;
  void check_optional_element(hid_t particles, const char* name, bool wanted) const;
  void check_observables() const;
  std::vector<Series*> all_series();
  std::vector<Handle*> static_datasets() { return {&species, &mass, &charge, &id, &bonds, &bond_from, &bond_to}; }
  void share_series();
  std::pair<hsize_t, hsize_t> block_rows(int rank) const;
  void to_block(const std::vector<int>& ids, const Eigen::Matrix3Xd& x, const Eigen::Matrix3Xd* v,
                const Eigen::Matrix3Xd* f);
  void flush() const { ok(H5Fflush(file, H5F_SCOPE_LOCAL), "cannot write the file"); }
};

// §File format recommends the HDF5 format version 2 (library 1.8); it also keeps a killed file
// readable (see the top of this file). File locks where the file system has them, none elsewhere.
// A shared file goes through MPI-IO, its metadata written collectively.
Handle H5mdWriter::Impl::file_access(bool shared_access) const {
  Handle fapl(H5Pcreate(H5P_FILE_ACCESS), H5Pclose, "cannot create file properties");
  ok(H5Pset_libver_bounds(fapl, H5F_LIBVER_V18, H5F_LIBVER_V18), "cannot set the file format version");
  ok(H5Pset_file_locking(fapl, true, true), "cannot set file locking");
#ifdef H5_HAVE_PARALLEL
  if (shared_access) {
    const MPI_Comm comm = *static_cast<const MPI_Comm*>(setup.processes->native());
    ok(H5Pset_fapl_mpio(fapl, comm, MPI_INFO_NULL), "cannot open the file on every process (MPI-IO)");
    ok(H5Pset_all_coll_metadata_ops(fapl, true), "cannot set collective metadata reads");
    ok(H5Pset_coll_metadata_write(fapl, true), "cannot set collective metadata writes");
  }
#endif
  return fapl;
}

// Every series of a shared file is written through the collective transfer.
void H5mdWriter::Impl::share_series() {
  if (!shared) return;
#ifdef H5_HAVE_PARALLEL
  transfer = Handle(H5Pcreate(H5P_DATASET_XFER), H5Pclose, "cannot create transfer properties");
  ok(H5Pset_dxpl_mpio(transfer, H5FD_MPIO_COLLECTIVE), "cannot set collective transfers");
  for (Series* s : all_series()) s->transfer = transfer;
#endif
}

void H5mdWriter::Impl::create() {
  namespace fs = std::filesystem;
  std::error_code ec;
  if (fs::is_directory(path, ec)) throw Failure("is a directory, not an output file");
  const fs::path parent = fs::path(path).parent_path();
  if (!parent.empty() && !fs::is_directory(parent, ec))
    throw Failure("directory " + parent.string() + " does not exist");
  file = Handle(H5Fcreate(path.c_str(), H5F_ACC_TRUNC, H5P_DEFAULT, file_access(shared)), H5Fclose,
                "cannot create the HDF5 file");
  write_metadata();
  create_particles();
  create_connectivity();
  create_vmd_structure();
  share_series();
  flush();
}

// §H5MD metadata: /h5md with version {1, 1}, author/name and creator/{name, version}.
void H5mdWriter::Impl::write_metadata() {
  Handle h5md = create_group(file, "h5md");
  write_int_attribute(h5md, "version", {1, 1}, false);
  write_string_attribute(create_group(h5md, "author"), "name", setup.author.empty() ? default_author() : setup.author);
  Handle creator = create_group(h5md, "creator");
  write_string_attribute(creator, "name", "stiffmd");
  write_string_attribute(creator, "version", setup.creator_version);
}

// §Particles group: the time-dependent position (and image, velocity, force) elements, sharing one
// time grid, and the time-independent species, mass and id.
void H5mdWriter::Impl::create_particles() {
  const auto n = static_cast<hsize_t>(setup.num_particles);
  const std::vector<hsize_t> vectors{n, 3};
  Handle particles = create_group(create_group(file, "particles"), kParticleGroup);

  Handle pos = create_group(particles, "position");
  step = create_series(pos, "step", H5T_STD_I64LE, H5T_NATIVE_INT64, {}, 0);
  time = create_series(pos, "time", H5T_IEEE_F64LE, H5T_NATIVE_DOUBLE, {}, 0);
  position = create_series(pos, "value", H5T_IEEE_F64LE, H5T_NATIVE_DOUBLE, vectors, setup.gzip);
  write_unit(time.dataset, setup.time_unit);
  write_unit(position.dataset, setup.length_unit);

  auto element = [&](const char* name, hid_t file_type, hid_t memory_type) {
    Handle g = create_group(particles, name);
    link_time_grid(pos, g);
    return create_series(g, "value", file_type, memory_type, vectors, setup.gzip);
  };
  if (setup.box.any_periodic()) image = element("image", H5T_STD_I32LE, H5T_NATIVE_INT32);
  if (setup.velocity) velocity = element("velocity", H5T_IEEE_F64LE, H5T_NATIVE_DOUBLE);
  if (setup.force) force = element("force", H5T_IEEE_F64LE, H5T_NATIVE_DOUBLE);
  if (setup.velocity) write_unit(velocity.dataset, setup.velocity_unit);
  if (setup.force) write_unit(force.dataset, setup.force_unit);

  // species: an index into the element table stored as the `elements` attribute (H5MD leaves the
  // meaning of species values to the application; symbols are what trajectory viewers need).
  if (setup.by_rows) {  // written by rows after creation (write_particle_rows)
    species = create_dataset(particles, "species", H5T_STD_I32LE, {n});
    write_strings_attribute(species, "elements", setup.elements);
    mass = create_dataset(particles, "mass", H5T_IEEE_F64LE, {n});
    if (setup.charged) charge = create_dataset(particles, "charge", H5T_IEEE_F64LE, {n});
    id = create_dataset(particles, "id", H5T_STD_I64LE, {n});
  } else {
    const auto [table, index] = element_table(setup.species);
    write_dataset(particles, "species", H5T_STD_I32LE, H5T_NATIVE_INT, {n}, index.data(), writes_whole);
    write_strings_attribute(Handle(H5Dopen2(particles, "species", H5P_DEFAULT), H5Dclose, "species"), "elements",
                            table);
    write_dataset(particles, "mass", H5T_IEEE_F64LE, H5T_NATIVE_DOUBLE, {n}, setup.mass.data(), writes_whole);
    if (!setup.charge.empty())
      write_dataset(particles, "charge", H5T_IEEE_F64LE, H5T_NATIVE_DOUBLE, {n}, setup.charge.data(), writes_whole);
    std::vector<std::int64_t> ids(n);
    for (hsize_t i = 0; i < n; ++i) ids[i] = static_cast<std::int64_t>(i);
    write_dataset(particles, "id", H5T_STD_I64LE, H5T_NATIVE_INT64, {n}, ids.data(), writes_whole);
  }

  create_box(particles, pos);
  create_observables(pos);
}

// §Simulation box: dimension and boundary always; when an axis is periodic, the edges as a
// time-dependent element on the position grid and the origin as `offset` (an stiffmd addition:
// the low corner of the cell the positions are wrapped into). Edges are written as the 3 x 3
// matrix diag(L) (rows = edge vectors), which §Simulation box allows for any box: MDAnalysis 2.4.2
// reads box/edges/value[frame] as three edge vectors only (a [frames][3] vector of lengths gives
// it an invalid box, dimensions None), and only from a time-dependent element. For an open box
// edges is omitted, as §Simulation box allows; MDAnalysis then reports dimensions None. On the open
// axes of a partly periodic box the edge values are placeholders: the box's own lengths (0 when
// the deck gives none, which MDAnalysis reads as "no box" rather than as a false periodic axis).
void H5mdWriter::Impl::create_box(hid_t particles, hid_t position_group) {
  Handle box = create_group(particles, "box");
  write_int_attribute(box, "dimension", {3}, true);
  std::vector<std::string> boundary;
  for (int k = 0; k < 3; ++k) boundary.push_back(setup.box.periodic[k] ? "periodic" : "none");
  write_strings_attribute(box, "boundary", boundary);
  if (!setup.box.any_periodic()) return;
  Handle g = create_group(box, "edges");
  link_time_grid(position_group, g);
  edges = create_series(g, "value", H5T_IEEE_F64LE, H5T_NATIVE_DOUBLE, {3, 3}, 0);
  write_unit(edges.dataset, setup.length_unit);
  write_dataset(box, "offset", H5T_IEEE_F64LE, H5T_NATIVE_DOUBLE, {3}, setup.box.origin.data(), writes_whole);
}

// §Observables group: one time-dependent scalar element per name, on the position grid.
void H5mdWriter::Impl::create_observables(hid_t position_group) {
  if (setup.observables.empty()) return;
  Handle group = create_group(file, "observables");
  for (std::size_t k = 0; k < setup.observables.size(); ++k) {
    Handle g = create_group(group, setup.observables[k]);
    link_time_grid(position_group, g);
    observables.push_back(create_series(g, "value", H5T_IEEE_F64LE, H5T_NATIVE_DOUBLE, {}, 0));
    if (k < setup.observable_units.size()) write_unit(observables.back().dataset, setup.observable_units[k]);
  }
}

// H5MD 1.1 connectivity (proposal 103 / 101): /connectivity/bonds [m][2] of particle indices
// into the group named by `particles_group`, an object reference to /particles/all.
void H5mdWriter::Impl::create_connectivity() {
  Handle group = create_group(file, "connectivity");
  if (setup.by_rows) {
    bonds = create_dataset(group, "bonds", H5T_STD_I32LE, {static_cast<hsize_t>(setup.num_bonds), 2});
  } else {
    std::vector<std::int32_t> pairs;
    for (const auto& [i, j] : setup.bonds) pairs.insert(pairs.end(), {i, j});
    write_dataset(group, "bonds", H5T_STD_I32LE, H5T_NATIVE_INT32, {setup.bonds.size(), 2}, pairs.data(), writes_whole);
  }
  hobj_ref_t ref{};
  ok(H5Rcreate(&ref, file, (std::string("/particles/") + kParticleGroup).c_str(), H5R_OBJECT, -1),
     "cannot reference the particle group");
  Handle opened(H5Dopen2(group, "bonds", H5P_DEFAULT), H5Dclose, "cannot open connectivity/bonds");
  write_attribute(opened, "particles_group", H5T_STD_REF_OBJ, Handle(H5Screate(H5S_SCALAR), H5Sclose, "dataspace"),
                  &ref);
}

// What VMD's H5MD plugin reads for names and bonds (§Parameters group is application-specific):
// indexOfSpecies and per-species name/type as fixed-length strings (the plugin reads char[16]),
// and 1-based bond_from/bond_to.
void H5mdWriter::Impl::create_vmd_structure() {
  const auto table = setup.by_rows ? setup.elements : element_table(setup.species).first;
  std::vector<int> index(table.size());
  std::vector<char> names(table.size() * 16, '\0');
  for (std::size_t s = 0; s < table.size(); ++s) {
    index[s] = static_cast<int>(s);
    std::strncpy(&names[16 * s], table[s].c_str(), 15);
  }
  std::vector<int> from, to;
  for (const auto& [i, j] : setup.bonds) {
    from.push_back(i + 1);
    to.push_back(j + 1);
  }
  Handle vmd = create_group(create_group(file, "parameters"), "vmd_structure");
  const hsize_t s = table.size(), m = setup.by_rows ? static_cast<hsize_t>(setup.num_bonds) : setup.bonds.size();
  write_dataset(vmd, "indexOfSpecies", H5T_STD_I32LE, H5T_NATIVE_INT, {s}, index.data(), writes_whole);
  Handle fixed = string_type(false, 16);
  write_dataset(vmd, "name", fixed, fixed, {s}, names.data(), writes_whole);
  write_dataset(vmd, "type", fixed, fixed, {s}, names.data(), writes_whole);
  if (setup.by_rows) {  // written by rows after creation (write_bond_rows)
    bond_from = create_dataset(vmd, "bond_from", H5T_STD_I32LE, {m});
    bond_to = create_dataset(vmd, "bond_to", H5T_STD_I32LE, {m});
    return;
  }
  write_dataset(vmd, "bond_from", H5T_STD_I32LE, H5T_NATIVE_INT, {m}, from.data(), writes_whole);
  write_dataset(vmd, "bond_to", H5T_STD_I32LE, H5T_NATIVE_INT, {m}, to.data(), writes_whole);
}

// ---- append ----

void H5mdWriter::Impl::append(std::int64_t first_step) {
  if (!shared) {
    open_for_append(first_step, file_access(false));
    return;
  }
  // A shared file: rank 0 alone readies it (the checks, the frames dropped) through one process's
  // driver and closes it; then every process opens it and only writes frames. So the processes
  // start from the same state, an empty metadata cache each: in one test of 4 processes appending
  // to a 2-process file, dropping the frames together left one process's cache without an object
  // header the others had, and it waited alone in a collective read (HDF5 1.10).
  std::string problem;
  std::int64_t kept = 0;
  if (writes_whole) try {
      open_for_append(first_step, file_access(false));
      kept = frames;
      close();
    } catch (const Failure& e) {
      problem = e.what();
      for (Series* s : all_series()) s->dataset.reset();
      file.reset();
    }
  setup.processes->broadcast(problem, 0);
  setup.processes->broadcast(&kept, 1);
  if (!problem.empty()) throw agreed_failure(problem);
  observables.clear();
  file = Handle(H5Fopen(path.c_str(), H5F_ACC_RDWR, file_access(true)), H5Fclose,
                "cannot open the HDF5 file for appending");
  open_elements();
  share_series();
  frames = kept;
}

// Opens the file for appending through `access` (one process's) and drops the frames at or after
// first_step, and any frame a kill left half written.
void H5mdWriter::Impl::open_for_append(std::int64_t first_step, hid_t access) {
  namespace fs = std::filesystem;
  std::error_code ec;
  if (fs::is_directory(path, ec)) throw Failure("is a directory, not an H5MD file");
  if (!fs::exists(path, ec)) throw Failure("cannot append: the file does not exist");
  if (H5Fis_hdf5(path.c_str()) <= 0) throw Failure("cannot append: not an HDF5 file");
  file = Handle(H5Fopen(path.c_str(), H5F_ACC_RDWR, access), H5Fclose, "cannot open the HDF5 file for appending");
  // A kill inside a flush can leave the newest chunk of the frame being written beyond the end of
  // allocation recorded in the superblock (written last in a flush); HDF5 then fails when that
  // frame is dropped below. Extending the recorded end to the file's size (`h5clear --increment`)
  // makes such a chunk ordinary space. Frames before the last step are never affected. (HDF5 does
  // it through one process's driver only.)
  ok(H5Fincrement_filesize(file, 0), "cannot open the HDF5 file for appending");
  if (H5Lexists(file, "h5md", H5P_DEFAULT) <= 0 || H5Lexists(file, "h5md/creator", H5P_DEFAULT) <= 0 ||
      read_string_attribute(open_group(file, "h5md/creator"), "name") != "stiffmd")
    throw Failure("cannot append: not an H5MD file written by stiffmd");
  open_elements();
  if (shared) check_allocation();  // before anything is changed

  std::vector<Series*> series = all_series();
  hsize_t keep = std::numeric_limits<hsize_t>::max();
  for (const Series* s : series) keep = std::min(keep, s->length());
  std::vector<std::int64_t> steps(step.length());
  if (!steps.empty())
    ok(H5Dread(step.dataset, H5T_NATIVE_INT64, H5S_ALL, H5S_ALL, H5P_DEFAULT, steps.data()), "cannot read steps");
  const auto later = std::find_if(steps.begin(), steps.end(), [&](std::int64_t s) { return s >= first_step; });
  keep = std::min<hsize_t>(keep, static_cast<hsize_t>(later - steps.begin()));
  for (const Series* s : series) s->resize(keep);
  frames = static_cast<std::int64_t>(keep);
  flush();
}

// Parallel HDF5 writes a series only into chunks allocated when it grows (H5D_ALLOC_TIME_EARLY,
// its own choice in a shared file); one process allocates a compressed series' chunk at its
// first write (so that a chunk is written once and never moved, the crash safety at the top of
// this file), as an earlier stiffmd did every series'. Rank 0 checks it while it readies the file
// alone (append); every process refuses.
void H5mdWriter::Impl::check_allocation() {
  for (Series* s : all_series()) {
    Handle dcpl(H5Dget_create_plist(s->dataset), H5Pclose, "cannot read the properties of " + s->name);
    H5D_alloc_time_t when = H5D_ALLOC_TIME_DEFAULT;
    ok(H5Pget_alloc_time(dcpl, &when), "cannot read the allocation time of " + s->name);
    if (when == H5D_ALLOC_TIME_EARLY) continue;
    const std::string why = H5Pget_nfilters(dcpl) > 0
                                ? "its compressed series (output.h5md_gzip) were written by one process"
                                : "it was written by one process of an earlier stiffmd";
    throw agreed_failure("cannot append on " + std::to_string(setup.processes->size()) + " processes: " + why +
                         ", whose chunks parallel HDF5 cannot extend; continue this run on one process, or write a "
                         "new H5MD file (another output.h5md)");
  }
}

// Opens every series this setup writes and checks that the file holds exactly those.
void H5mdWriter::Impl::open_elements() {
  const std::string group_path = std::string("particles/") + kParticleGroup;
  if (H5Lexists(file, "particles", H5P_DEFAULT) <= 0 || H5Lexists(file, group_path.c_str(), H5P_DEFAULT) <= 0 ||
      H5Lexists(file, (group_path + "/position").c_str(), H5P_DEFAULT) <= 0)
    throw Failure("cannot append: no /" + group_path + "/position in the file");
  Handle particles = open_group(file, group_path);
  Handle pos = open_group(particles, "position");
  check_particle_count(pos);
  const std::vector<hsize_t> vectors{static_cast<hsize_t>(setup.num_particles), 3};
  position = open_series(pos, "value", H5T_NATIVE_DOUBLE, vectors);
  step = open_series(pos, "step", H5T_NATIVE_INT64, {});
  time = open_series(pos, "time", H5T_NATIVE_DOUBLE, {});

  check_optional_element(particles, "image", setup.box.any_periodic());
  check_optional_element(particles, "velocity", setup.velocity);
  check_optional_element(particles, "force", setup.force);
  check_optional_element(particles, "box/edges", setup.box.any_periodic());
  if (setup.box.any_periodic()) {
    image = open_series(open_group(particles, "image"), "value", H5T_NATIVE_INT32, vectors);
    edges = open_series(open_group(particles, "box/edges"), "value", H5T_NATIVE_DOUBLE, {3, 3});
  }
  if (setup.velocity) velocity = open_series(open_group(particles, "velocity"), "value", H5T_NATIVE_DOUBLE, vectors);
  if (setup.force) force = open_series(open_group(particles, "force"), "value", H5T_NATIVE_DOUBLE, vectors);

  check_observables();
  for (const auto& name : setup.observables)
    observables.push_back(open_series(open_group(file, "observables/" + name), "value", H5T_NATIVE_DOUBLE, {}));
}

void H5mdWriter::Impl::check_particle_count(hid_t position_group) const {
  Handle value(H5Dopen2(position_group, "value", H5P_DEFAULT), H5Dclose, "cannot append: no position/value");
  Handle space(H5Dget_space(value), H5Sclose, "cannot append: cannot read position/value");
  hsize_t dims[3] = {0, 0, 0};
  if (H5Sget_simple_extent_ndims(space) != 3 || H5Sget_simple_extent_dims(space, dims, nullptr) < 0 || dims[2] != 3)
    throw Failure("cannot append: position/value is not [frames][N][3]");
  if (dims[1] != static_cast<hsize_t>(setup.num_particles))
    throw Failure("cannot append: particle count mismatch (the file has " + std::to_string(dims[1]) +
                  " particles, this run has " + std::to_string(setup.num_particles) + ")");
}

void H5mdWriter::Impl::check_optional_element(hid_t particles, const char* name, bool wanted) const {
  const bool present = H5Lexists(particles, name, H5P_DEFAULT) > 0;
  if (present != wanted)
    throw Failure(std::string("cannot append: the file ") + (present ? "has" : "has no") + " particles/" +
                  kParticleGroup + "/" + name + " but this run writes " + (wanted ? "it" : "none"));
}

// The observables in the file must be those of this run (in any order).
void H5mdWriter::Impl::check_observables() const {
  std::vector<std::string> in_file;
  if (H5Lexists(file, "observables", H5P_DEFAULT) > 0) {
    Handle group = open_group(file, "observables");
    H5G_info_t info{};
    ok(H5Gget_info(group, &info), "cannot list /observables");
    for (hsize_t k = 0; k < info.nlinks; ++k) {
      char name[1024] = {};
      ok(static_cast<herr_t>(
             H5Lget_name_by_idx(group, ".", H5_INDEX_NAME, H5_ITER_INC, k, name, sizeof name, H5P_DEFAULT)),
         "cannot list /observables");
      in_file.emplace_back(name);
    }
  }
  std::vector<std::string> wanted = setup.observables;
  std::sort(in_file.begin(), in_file.end());
  std::sort(wanted.begin(), wanted.end());
  if (in_file != wanted) throw Failure("cannot append: the file's /observables differ from this run's");
}

std::vector<Series*> H5mdWriter::Impl::all_series() {
  std::vector<Series*> all{&step, &time, &position};
  for (Series* s : {&image, &velocity, &force, &edges})
    if (s->dataset >= 0) all.push_back(s);
  for (Series& s : observables) all.push_back(&s);
  return all;
}

// ---- one frame ----

// The particles process `rank` of a shared file writes: its block (engine/io/particle_blocks.hpp).
std::pair<hsize_t, hsize_t> H5mdWriter::Impl::block_rows(int rank) const {
  const ParticleBlock b = block_of(setup.num_particles, setup.processes->size(), rank);
  return {static_cast<hsize_t>(b.first), static_cast<hsize_t>(b.count)};
}

// Each process's rows go to the process whose block holds them, in one exchange, so that every
// process writes one contiguous block: a single hyperslab, which HDF5 maps onto the chunks at
// once, where a union of runs (a rank's molecules) it maps element by element — measured 25×
// slower (docs/parallel.md).
void H5mdWriter::Impl::to_block(const std::vector<int>& ids, const Eigen::Matrix3Xd& x, const Eigen::Matrix3Xd* v,
                                const Eigen::Matrix3Xd* f) {
  const auto count = static_cast<Eigen::Index>(block_rows(setup.processes->rank()).second);
  block_x.resize(3, count);
  std::vector<BlockArray> arrays = {{x.data(), block_x.data(), 3}};
  if (setup.velocity) {
    block_v.resize(3, count);
    arrays.push_back({v->data(), block_v.data(), 3});
  }
  if (setup.force) {
    block_f.resize(3, count);
    arrays.push_back({f->data(), block_f.data(), 3});
  }
  try {
    exchange.run(*setup.processes, setup.num_particles, ids, arrays);
  } catch (const std::invalid_argument& e) {
    throw std::invalid_argument(std::string("H5mdWriter::write_frame: ") + e.what());
  }
}

void H5mdWriter::Impl::write_frame(std::int64_t step_number, double t, const Eigen::Matrix3Xd& x,
                                   const Eigen::Matrix3Xd* v, const Eigen::Matrix3Xd* f, const std::vector<double>& obs,
                                   const std::vector<int>* ids) {
  const Eigen::Index n = ids ? static_cast<Eigen::Index>(ids->size()) : setup.num_particles;
  if (x.cols() != n || (setup.velocity && (!v || v->cols() != n)) || (setup.force && (!f || f->cols() != n)) ||
      obs.size() != setup.observables.size() || (ids != nullptr) != shared)
    throw std::invalid_argument("H5mdWriter::write_frame: arrays do not match the setup");
  // This process's part of the per-particle series (with ids, its block). The scalar series (step,
  // time, edges, observables) every process of a shared file writes alike, rank 0's values: HDF5
  // keeps one metadata cache per process, and a collective write that selects elements on one
  // process and none on the others reads the chunk index on the one alone, so the caches part
  // and a later collective call finds the processes at different points (a hang). The same
  // bytes from every process to the same place leave the file as one writer's.
  FramePart rows;
  if (!writes_whole) rows.what = FramePart::none;
  const Eigen::Matrix3Xd *xs = &x, *vs = v, *fs = f;
  const std::vector<double>* scalar_values = &obs;
  if (shared) {
    setup.processes->broadcast(&step_number, 1);
    shared_scalars.assign(1, t);
    shared_scalars.insert(shared_scalars.end(), obs.begin(), obs.end());
    setup.processes->broadcast(shared_scalars.data(), static_cast<int>(shared_scalars.size()));
    t = shared_scalars[0];
    std::copy(shared_scalars.begin() + 1, shared_scalars.end(), shared_obs.begin());
    scalar_values = &shared_obs;
  }
  if (ids) {
    to_block(*ids, x, v, f);
    const auto [first, count] = block_rows(setup.processes->rank());
    rows = {count > 0 ? FramePart::block : FramePart::none, first, count};
    xs = &block_x, vs = &block_v, fs = &block_f;
  }
  const auto index = static_cast<hsize_t>(frames);
  const Eigen::Matrix3Xd* positioned = xs;
  if (setup.box.any_periodic()) {
    wrap_into_box(setup.box, *xs, wrapped, images);
    positioned = &wrapped;
    image.write(index, images.data(), rows);
    edges.write(index, edge_vectors.data());
  }
  if (setup.velocity) velocity.write(index, vs->data(), rows);
  if (setup.force) force.write(index, fs->data(), rows);
  for (std::size_t k = 0; k < obs.size(); ++k) observables[k].write(index, &(*scalar_values)[k]);
  time.write(index, &t);
  flush();
  // The frame's other series and time first, then position/value and then step, each after a
  // flush of what came before (the crash-safety order at the top of this file). HDF5 writes metadata
  // (such as a dataset's extent) in no fixed order within a flush, and MDAnalysis counts frames by
  // position/value, stops iterating at the end of position/step, and reads every other series at
  // those indices. So a kill at any moment leaves step no longer than position/value, and that no
  // longer than any other series (tests/test_h5md.py kills writers mid-frame to check it).
  position.write(index, positioned->data(), rows);
  flush();
  step.write(index, &step_number);
  flush();
  ++frames;
}

// ---- public interface ----

H5mdWriter::H5mdWriter(const std::string& path, const H5mdSetup& setup, bool append, std::int64_t first_step) {
  // No atexit hook: after a failed H5Fclose (disk full) HDF5 1.10 leaves the file id dangling and
  // its exit-time cleanup then crashes; every frame is flushed anyway, so the hook has nothing to
  // do. (Effective only before the library's first use, which this is in stiffmd.)
  static const bool no_atexit = (H5dont_atexit(), true);
  (void)no_atexit;
  H5Eset_auto2(H5E_DEFAULT, nullptr, nullptr);  // our one-line errors only, no HDF5 error stack on stderr
  try {
    check_setup(setup);
    impl_ = std::make_unique<Impl>(path, setup);
    if (append)
      impl_->append(first_step);
    else
      impl_->create();
  } catch (const Failure& e) {
    const std::string what = path + ": H5MD output: " + e.what();
    const bool agreed = e.agreed || !impl_ || !impl_->shared;
    // Every process of a shared file failed here alike: they close it together (collective);
    // a failure of this process alone leaves it to the job's end (~Impl).
    if (impl_ && impl_->shared && e.agreed) try {
        impl_->close();
      } catch (const Failure&) {
      }
    impl_.reset();
    if (setup.processes && setup.processes->size() > 1 && agreed) throw AgreedInputError(what, setup.processes->root());
    throw InputError(what);
  }
}

H5mdWriter::~H5mdWriter() = default;

void H5mdWriter::close() {
  try {
    impl_->close();
  } catch (const Failure& e) {
    throw InputError(impl_->path + ": H5MD output: " + e.what());
  }
}

void H5mdWriter::write_frame(std::int64_t step, double time, const Eigen::Matrix3Xd& x, const Eigen::Matrix3Xd* v,
                             const Eigen::Matrix3Xd* f, const std::vector<double>& observables,
                             const std::vector<int>* ids) {
  try {
    impl_->write_frame(step, time, x, v, f, observables, ids);
  } catch (const Failure& e) {
    throw InputError(impl_->path + ": H5MD output: " + e.what());
  }
}

void H5mdWriter::set_box_lengths(const Eigen::Vector3d& lengths) {
  if (!impl_) return;
  impl_->setup.box.lengths = lengths;
  impl_->edge_vectors.diagonal() = lengths;
}

std::int64_t H5mdWriter::frames() const {
  return impl_->frames;
}

void H5mdWriter::write_particle_rows(std::int64_t first, std::int64_t count, const int* species, const double* mass,
                                     const double* charge) {
  Impl& w = *impl_;
  if (!w.setup.by_rows || w.species < 0 || first < 0 || count < 0 || first + count > w.setup.num_particles ||
      (w.setup.charged && !charge))
    throw std::invalid_argument("H5mdWriter::write_particle_rows: not a file created by rows, or rows out of range");
  try {
    w.id_rows.resize(static_cast<std::size_t>(count));
    for (std::int64_t k = 0; k < count; ++k) w.id_rows[static_cast<std::size_t>(k)] = first + k;
    write_rows(w.species, H5T_NATIVE_INT, first, count, 1, species, "species");
    write_rows(w.mass, H5T_NATIVE_DOUBLE, first, count, 1, mass, "mass");
    if (w.setup.charged) write_rows(w.charge, H5T_NATIVE_DOUBLE, first, count, 1, charge, "charge");
    write_rows(w.id, H5T_NATIVE_INT64, first, count, 1, w.id_rows.data(), "id");
  } catch (const Failure& e) {
    throw InputError(w.path + ": H5MD output: " + e.what());
  }
}

void H5mdWriter::write_bond_rows(std::int64_t first, std::int64_t count, const int* pairs) {
  Impl& w = *impl_;
  if (!w.setup.by_rows || w.bonds < 0 || first < 0 || count < 0 || first + count > w.setup.num_bonds)
    throw std::invalid_argument("H5mdWriter::write_bond_rows: not a file created by rows, or rows out of range");
  try {
    // VMD's bond_from/bond_to: 1-based.
    w.from_rows.resize(static_cast<std::size_t>(count));
    w.to_rows.resize(static_cast<std::size_t>(count));
    for (std::size_t k = 0; k < w.from_rows.size(); ++k)
      w.from_rows[k] = pairs[2 * k] + 1, w.to_rows[k] = pairs[2 * k + 1] + 1;
    write_rows(w.bonds, H5T_NATIVE_INT32, first, count, 2, pairs, "connectivity/bonds");
    write_rows(w.bond_from, H5T_NATIVE_INT, first, count, 1, w.from_rows.data(), "bond_from");
    write_rows(w.bond_to, H5T_NATIVE_INT, first, count, 1, w.to_rows.data(), "bond_to");
  } catch (const Failure& e) {
    throw InputError(w.path + ": H5MD output: " + e.what());
  }
}

bool H5mdWriter::shared_files() {
#ifdef H5_HAVE_PARALLEL
  return true;
#else
  return false;
#endif
}

}  // namespace stiffmd
