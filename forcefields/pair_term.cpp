#include "forcefields/pair_term.hpp"

#include <sstream>
#include <stdexcept>

namespace stiffmd::pair_detail {

void fail(const std::string& name, std::string_view style, const std::string& what) {
  throw std::invalid_argument("pair term '" + name + "' (" + std::string(style) + "): " + what);
}

void check_types(const std::string& name, std::string_view style, std::span<const int> types, int ntypes) {
  for (std::size_t i = 0; i < types.size(); ++i)
    if (types[i] < 0 || types[i] >= ntypes) {
      std::ostringstream s;
      s << "particle " << i << " has type " << types[i] << ", outside 0 … " << ntypes - 1
        << " (the types given pair coefficients)";
      fail(name, style, s.str());
    }
}

void check_pair_inputs(const std::string& name, std::string_view style, const std::vector<int>& types, int ntypes,
                       SpecialWeights weights, const Box& box, double rc, double skin) {
  check_types(name, style, types, ntypes);
  for (const auto& [what, w] :
       {std::pair{"w12", weights.w12}, std::pair{"w13", weights.w13}, std::pair{"w14", weights.w14}})
    if (!(w >= 0.0 && w <= 1.0)) {
      std::ostringstream s;
      s << "special-bond weight " << what << " must be in [0, 1] (got " << w << ")";
      fail(name, style, s.str());
    }
  if (!(skin >= 0.0) || !std::isfinite(skin)) {
    std::ostringstream s;
    s << "neighbour skin must be finite and >= 0 (got " << skin << ")";
    fail(name, style, s.str());
  }
  try {
    check_box_for_cutoff(box, rc, skin);
  } catch (const std::invalid_argument& e) {
    fail(name, style, e.what());
  }
}

std::vector<SpecialPair> special_pairs_of(const std::string& name, std::string_view style, int n,
                                          const std::vector<Bond>& bonds, SpecialWeights weights, SpecialWeights coul) {
  try {
    return special_pairs(n, bonds, weights, coul);
  } catch (const std::invalid_argument& e) {
    fail(name, style, e.what());
  }
}

std::string number_text(double v) {
  std::ostringstream s;
  s.precision(17);
  s << v;
  double back = 0.0;
  for (int digits = 1; digits <= 17; ++digits) {  // the shortest that reads back
    std::ostringstream t;
    t.precision(digits);
    t << v;
    std::istringstream(t.str()) >> back;
    if (back == v) return t.str();
  }
  return s.str();
}

void check_electrostatics(const std::string& name, std::string_view style, const Electrostatics& e,
                          std::size_t particles) {
  for (const auto& [what, w] :
       {std::pair{"coul w12", e.coul.w12}, std::pair{"coul w13", e.coul.w13}, std::pair{"coul w14", e.coul.w14}})
    if (!(w >= 0.0 && w <= 1.0)) {
      std::ostringstream s;
      s << "special-bond weight " << what << " must be in [0, 1] (got " << w << ")";
      fail(name, style, s.str());
    }
  if (!(e.qqrd2e > 0.0) || !std::isfinite(e.qqrd2e)) fail(name, style, "the Coulomb constant qqrd2e must be > 0");
  if (e.charges.size() != particles)
    fail(name, style,
         std::to_string(e.charges.size()) + " charges for " + std::to_string(particles) +
             " particles: a charged style needs one per particle");
  for (std::size_t i = 0; i < particles; ++i)
    if (!std::isfinite(e.charges[i])) fail(name, style, "particle " + std::to_string(i) + " has a non-finite charge");
}

void check_sizes(const std::string& name, std::string_view style, const Eigen::Matrix3Xd& x, const Eigen::Matrix3Xd* f,
                 std::size_t num_types) {
  if (x.cols() != static_cast<Eigen::Index>(num_types) || (f && f->cols() != x.cols())) {
    std::ostringstream s;
    s << "positions of " << x.cols() << " particles" << (f ? ", forces of " + std::to_string(f->cols()) : "")
      << ", but types were given for " << num_types;
    fail(name, style, s.str());
  }
}

std::string describe_pairs(std::string_view style, int num_types, double cutoff, const NeighborList& list,
                           SpecialWeights weights, std::size_t excluded, std::size_t scaled) {
  std::ostringstream s;
  s << style << " pairs, " << num_types << " particle type(s), cutoff " << cutoff << ", skin " << list.skin()
    << ", special bonds w12 = " << weights.w12 << ", w13 = " << weights.w13;
  if (weights.w14 != 1.0) s << ", w14 = " << weights.w14;
  s << " (" << excluded << " pairs excluded, " << scaled << " scaled)";
  return s.str();
}

void define_pair_settings(ParameterRecord& record, const std::vector<int>& types, double cutoff, double skin,
                          SpecialWeights weights, std::size_t excluded, std::span<const SpecialPair> scaled) {
  record.add("types", std::span<const int>(types));
  record.add("cutoff", cutoff);
  record.add("skin", skin);
  record.add("w12", weights.w12);
  record.add("w13", weights.w13);
  record.add("w14", weights.w14);
  record.add("excluded pairs", excluded);
  record.add("scaled pairs", scaled.size());
  for (const SpecialPair& p : scaled) {
    record.add("i", p.i);
    record.add("j", p.j);
    record.add("weight", p.weight);
  }
}

// Words: rebuilds, periodic x y z (0/1), origin (3), lengths (3), then x_at_build column-major.
std::vector<double> save_list_state(const NeighborList& list) {
  if (!list.built()) return {};
  const Box& b = list.box_at_build();
  const Eigen::Matrix3Xd& x = list.positions_at_build();
  std::vector<double> w = {static_cast<double>(list.rebuilds())};
  for (int a = 0; a < 3; ++a) w.push_back(b.periodic[a] ? 1.0 : 0.0);
  for (int a = 0; a < 3; ++a) w.push_back(b.origin[a]);
  for (int a = 0; a < 3; ++a) w.push_back(b.lengths[a]);
  w.insert(w.end(), x.data(), x.data() + x.size());
  return w;
}

void load_list_state(const std::string& name, std::string_view style, NeighborList& list, std::span<const double> w,
                     std::size_t n) {
  if (w.empty()) return;  // saved before the first build: the next evaluation builds
  // A term that holds no particle — a decomposed run's description, whose parts list their own
  // pairs — restarting from a checkpoint of the whole system's list (one process's) keeps its
  // rebuilds and box; the positions are of particles it does not hold.
  if (n == 0 && w.size() >= 10 && (w.size() - 10) % 3 == 0) w = w.first(10);
  if (w.size() != 10 + 3 * n)
    fail(name, style,
         "neighbour-list state of " + std::to_string(w.size()) + " words, expected " + std::to_string(10 + 3 * n));
  Box b;
  for (int a = 0; a < 3; ++a) {
    b.periodic[a] = w[1 + a] != 0.0;
    b.origin[a] = w[4 + a];
    b.lengths[a] = w[7 + a];
  }
  const Eigen::Map<const Eigen::Matrix3Xd> x(w.data() + 10, 3, static_cast<Eigen::Index>(n));
  list.restore(x, b, static_cast<long>(w[0]));
}

}  // namespace stiffmd::pair_detail
