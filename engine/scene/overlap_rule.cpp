#include "engine/scene/overlap_rule.hpp"

#include "core/format.hpp"

namespace stiffmd {

std::string overlap_message(const OverlapRule& rule, const std::string& first, const std::string& second, double r,
                            int a, int b, long overlapping) {
  return first + " and " + second + " are " + format_number(r) + " apart at the start, closer than " + rule.why(a, b) +
         "; " +
         (overlapping > 1 ? std::to_string(overlapping) + " pairs overlap, this is the closest"
                          : "the only such pair") +
         ": place the sources apart (a [[build]]'s density or box, [[particles]] positions, the [import]'s file) or "
         "relax them first ([minimize] with max_force)";
}

}  // namespace stiffmd
