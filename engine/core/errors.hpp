// Error types that map onto the CLI's exit codes (docs/design.md §8):
//   InputError     -> exit 2: one line naming the file, line, key and what was expected;
//   NumericalError -> exit 3: where (step, time, particle/cluster/bond) and what went wrong.
#pragma once

#include <stdexcept>
#include <string>

namespace stiffmd {

class InputError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

class NumericalError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

}  // namespace stiffmd
