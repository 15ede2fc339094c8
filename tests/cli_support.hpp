// Running the stiffmd binary from tests: exit code, stdout, stderr.
#pragma once

#include <sys/wait.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>

namespace stiffmd::test {

struct CliResult {
  int code;
  std::string out, err;
};

inline std::string slurp(const std::filesystem::path& p) {
  std::ifstream in(p, std::ios::binary);
  std::stringstream s;
  s << in.rdbuf();
  return s.str();
}

inline std::filesystem::path scratch_dir(const std::string& name) {
  const auto d = std::filesystem::temp_directory_path() / ("stiffmd_test_" + name + "_" + std::to_string(::getpid()));
  std::filesystem::remove_all(d);
  std::filesystem::create_directories(d);
  return d;
}

// Runs `stiffmd ARGS` through the shell (so ARGS may hold redirections or a `timeout` prefix
// is not needed); returns the exit code (128 + signal if killed).
inline CliResult cli(const std::string& args, const std::string& prefix = "") {
  static int counter = 0;
  const auto d = scratch_dir("cli_capture_" + std::to_string(counter++));
  const std::string cmd =
      prefix + std::string(STIFFMD_EXE) + " " + args + " >" + (d / "out").string() + " 2>" + (d / "err").string();
  const int status = std::system(cmd.c_str());
  CliResult r{WIFEXITED(status) ? WEXITSTATUS(status) : 128 + WTERMSIG(status), slurp(d / "out"), slurp(d / "err")};
  std::filesystem::remove_all(d);
  return r;
}

}  // namespace stiffmd::test
