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

// A stop every rank of a decomposed run takes at the same point (a non-finite state found by the
// step's reduction, rank 0's [monitor]): each exits with code 3, rank 0 alone saying why
// (printed_here: false on the ranks whose message is not to be printed).
class AgreedStop : public NumericalError {
 public:
  AgreedStop(const std::string& what, bool printed_here) : NumericalError(what), printed_here_(printed_here) {}
  bool printed_here() const { return printed_here_; }

 private:
  bool printed_here_;
};

// Bad input every rank of a decomposed run found, or learned of, at the same point (an agreement,
// engine/core/communicator.hpp `agree`): each exits with code 2, rank 0 alone saying why.
class AgreedInputError : public InputError {
 public:
  AgreedInputError(const std::string& what, bool printed_here) : InputError(what), printed_here_(printed_here) {}
  bool printed_here() const { return printed_here_; }

 private:
  bool printed_here_;
};

}  // namespace stiffmd
