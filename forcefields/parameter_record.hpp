// What defines a scene, written exactly: the one writer through which every force term
// (ForceTerm::define) and the scene itself (scene_fingerprint, engine/run/checkpoint.hpp) put
// every parameter and list their dynamics depend on. Numbers enter as their bytes, never printed
// and so never rounded: a coefficient changed in its last bit changes the record. Each value
// follows its key, and each list and text its length, so that different records do not run
// together. The record is a 64-bit FNV-1a hash of those bytes, in the host's byte order (as the
// checkpoints are): a fingerprint that tells scenes apart, not a defence against forgery.
#pragma once

#include <concepts>
#include <cstddef>
#include <cstdint>
#include <initializer_list>
#include <span>
#include <string_view>

namespace stiffmd {

class ParameterRecord {
 public:
  void add(std::string_view key, double v) {
    text(key);
    bytes(&v, sizeof v);
  }
  template <std::integral T>  // counts, flags, small integer coefficients
  void add(std::string_view key, T v) {
    text(key);
    integer(static_cast<std::int64_t>(v));
  }
  void add(std::string_view key, std::string_view v) {
    text(key);
    text(v);
  }
  // A string literal is text, not the bool its pointer converts to.
  void add(std::string_view key, const char* v) { add(key, std::string_view(v)); }
  void add(std::string_view key, std::span<const double> v) {
    text(key);
    integer(static_cast<std::int64_t>(v.size()));
    bytes(v.data(), v.size_bytes());
  }
  void add(std::string_view key, std::span<const int> v) {  // particle indices, types
    text(key);
    integer(static_cast<std::int64_t>(v.size()));
    bytes(v.data(), v.size_bytes());
  }
  void add(std::string_view key, std::initializer_list<double> v) {
    add(key, std::span<const double>(v.begin(), v.size()));
  }
  void add(std::string_view key, std::initializer_list<int> v) { add(key, std::span<const int>(v.begin(), v.size())); }

  std::uint64_t value() const { return h_; }

 private:
  void text(std::string_view s) {
    integer(static_cast<std::int64_t>(s.size()));
    bytes(s.data(), s.size());
  }
  void integer(std::int64_t n) { bytes(&n, sizeof n); }
  void bytes(const void* p, std::size_t n) {
    const auto* c = static_cast<const unsigned char*>(p);
    for (std::size_t k = 0; k < n; ++k) h_ = (h_ ^ c[k]) * 0x100000001b3ull;  // the FNV prime
  }

  std::uint64_t h_ = 0xcbf29ce484222325ull;  // the FNV-1a 64-bit offset basis
};

}  // namespace stiffmd
