// Shared by the libFuzzer targets (and so by their replay driver): a per-process scratch file for
// the fuzzer's bytes, since the readers take paths, and the report of a finding.
#pragma once

#include <unistd.h>

#include <cstddef>
#include <cstdio>
#include <cstdlib>
#include <exception>
#include <filesystem>
#include <fstream>
#include <string>
#include <system_error>
#include <typeinfo>

namespace stiffmd::fuzz {

// A file in the temporary directory named by the process id, so that parallel fuzzing jobs
// (-jobs, -fork) do not share it; removed when the process exits.
struct ScratchFile {
  std::string path;
  explicit ScratchFile(const std::string& name)
      : path((std::filesystem::temp_directory_path() / ("stiffmd_fuzz_" + std::to_string(::getpid()) + "_" + name))
                 .string()) {}
  ~ScratchFile() {
    std::error_code ec;
    std::filesystem::remove(path, ec);
  }
  ScratchFile(const ScratchFile&) = delete;
  ScratchFile& operator=(const ScratchFile&) = delete;

  void write(const void* data, std::size_t size) const {
    std::ofstream out(path, std::ios::binary | std::ios::trunc);
    out.write(static_cast<const char*>(data), static_cast<std::streamsize>(size));
  }
};

// Anything but the expected InputError is a finding: say what it was, then abort, so that
// libFuzzer (or the replay driver under ctest) records the input as a crash.
[[noreturn]] inline void finding(const char* what, const std::exception* e = nullptr) {
  if (e)
    std::fprintf(stderr, "stiffmd fuzz finding: %s: %s: %s\n", what, typeid(*e).name(), e->what());
  else
    std::fprintf(stderr, "stiffmd fuzz finding: %s\n", what);
  std::fflush(stderr);
  std::abort();
}

}  // namespace stiffmd::fuzz
