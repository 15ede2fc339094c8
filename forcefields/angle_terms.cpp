#include "forcefields/angle_terms.hpp"

#include <cmath>
#include <numbers>
#include <sstream>
#include <stdexcept>

namespace stiffmd::angle_detail {

std::vector<AngleInstance<AngleCoeffs>> angle_instances(std::string_view style, const std::string& name,
                                                        const std::vector<Angle>& angles,
                                                        const std::vector<AngleCoeffs>& types) {
  auto fail = [&](const std::string& what) {
    throw std::invalid_argument(std::string(style) + " '" + name + "': " + what);
  };
  for (size_t t = 0; t < types.size(); ++t) {
    const AngleCoeffs& c = types[t];
    std::ostringstream m;
    m << "angle type " << t << ": ";
    if (!kStiffness.admits(c.k))
      m << "k: expected " << kStiffness.expected(c.k);
    else if (!(c.theta0 >= 0.0 && c.theta0 <= std::numbers::pi))
      m << "theta0 must be in [0, pi] radians, got " << c.theta0;
    else
      continue;
    fail(m.str());
  }
  std::vector<AngleInstance<AngleCoeffs>> out;
  out.reserve(angles.size());
  for (const Angle& a : angles) {
    const std::string which =
        "angle (" + std::to_string(a.i) + ", " + std::to_string(a.j) + ", " + std::to_string(a.k) + ")";
    if (a.i < 0 || a.j < 0 || a.k < 0) fail(which + ": particle indices must be >= 0");
    if (a.i == a.j || a.j == a.k || a.i == a.k) fail(which + ": the three particles must be distinct");
    if (a.type < 0 || static_cast<size_t>(a.type) >= types.size())
      fail(which + ": angle type " + std::to_string(a.type) + " is not defined (" + std::to_string(types.size()) +
           " types)");
    out.push_back({a.i, a.j, a.k, types[a.type]});
  }
  return out;
}

std::string describe_angles(std::string_view style, size_t n, const std::vector<AngleCoeffs>& types) {
  std::ostringstream s;
  s << n << " " << style.substr(0, style.find('-')) << " angles";
  for (size_t t = 0; t < types.size(); ++t)
    s << (t == 0 ? "; " : ", ") << "type " << t << ": k = " << types[t].k << ", theta0 = " << types[t].theta0;
  return s.str();
}

void define_angles(ParameterRecord& record, const std::vector<AngleCoeffs>& types, const std::vector<Angle>& angles) {
  record.add("angle types", types.size());
  for (const AngleCoeffs& c : types) {
    record.add("k", c.k);
    record.add("theta0", c.theta0);
  }
  record.add("angles", angles.size());
  for (const Angle& a : angles) record.add("angle", {a.i, a.j, a.k, a.type});
}

}  // namespace stiffmd::angle_detail
