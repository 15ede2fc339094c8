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

// An error every rank of a decomposed run finds, or learns of, at the same point, so that each
// rank ends alike without ending the others: exit 3 for a stop (a non-finite state found by the
// step's reduction, rank 0's [monitor]), exit 2 for bad input (an agreement, `agree` in
// core/communicator.hpp); rank 0 alone says why (printed_here: false on the ranks whose
// message is not to be printed).
template <class Error>
class Agreed : public Error {
 public:
  Agreed(const std::string& what, bool printed_here) : Error(what), printed_here_(printed_here) {}
  bool printed_here() const { return printed_here_; }

 private:
  bool printed_here_;
};
using AgreedStop = Agreed<NumericalError>;
using AgreedInputError = Agreed<InputError>;

}  // namespace stiffmd
