#include "forcefields/pair_term.hpp"

#include <algorithm>
#include <sstream>
#include <stdexcept>

namespace stiffmd {
namespace {

[[noreturn]] void fail(const std::string& name, std::string_view style, const std::string& what) {
  throw std::invalid_argument("pair term '" + name + "' (" + std::string(style) + "): " + what);
}

// Checks every input of the constructor; returns the largest cutoff over type pairs, which
// sets the list radius.
template <class Kernel>
double validated_cutoff(const std::string& name, const std::vector<int>& types,
                        const TypePairMatrix<typename Kernel::Coeffs>& coeffs, SpecialWeights weights, const Box& box,
                        double skin) {
  const int ntypes = coeffs.num_types();
  if (ntypes < 1) fail(name, Kernel::kStyle, "no particle types given pair coefficients");
  double rc = 0.0;
  for (int a = 0; a < ntypes; ++a)
    for (int b = a; b < ntypes; ++b) {
      std::ostringstream where;
      where << "types (" << a << ", " << b << "): ";
      if (!coeffs.is_set(a, b)) fail(name, Kernel::kStyle, where.str() + "pair coefficients not given");
      try {
        Kernel::validate(coeffs(a, b));
      } catch (const std::invalid_argument& e) {
        fail(name, Kernel::kStyle, where.str() + e.what());
      }
      rc = std::max(rc, Kernel::cutoff(coeffs(a, b)));
    }
  for (std::size_t i = 0; i < types.size(); ++i)
    if (types[i] < 0 || types[i] >= ntypes) {
      std::ostringstream s;
      s << "particle " << i << " has type " << types[i] << ", outside 0 … " << ntypes - 1
        << " (the types given pair coefficients)";
      fail(name, Kernel::kStyle, s.str());
    }
  for (const auto& [what, w] : {std::pair{"w12", weights.w12}, std::pair{"w13", weights.w13}})
    if (!(w >= 0.0 && w <= 1.0)) {
      std::ostringstream s;
      s << "special-bond weight " << what << " must be in [0, 1] (got " << w << ")";
      fail(name, Kernel::kStyle, s.str());
    }
  if (!(skin >= 0.0) || !std::isfinite(skin)) {
    std::ostringstream s;
    s << "neighbour skin must be finite and >= 0 (got " << skin << ")";
    fail(name, Kernel::kStyle, s.str());
  }
  try {
    check_box_for_cutoff(box, rc, skin);
  } catch (const std::invalid_argument& e) {
    fail(name, Kernel::kStyle, e.what());
  }
  return rc;
}

}  // namespace

template <class Kernel>
PairTerm<Kernel>::PairTerm(std::string name, Level level, std::vector<int> types, TypePairMatrix<Coeffs> coeffs,
                           const std::vector<Bond>& bonds, SpecialWeights weights, const Box& box, double skin)
    : ForceTerm(std::move(name), level),
      types_(std::move(types)),
      coeffs_(std::move(coeffs)),
      cutoff_(validated_cutoff<Kernel>(this->name(), types_, coeffs_, weights, box, skin)),
      params_(coeffs_.transform([](const Coeffs& c) { return Kernel::params(c); })),
      weights_(weights),
      list_(cutoff_, skin) {
  const int n = static_cast<int>(types_.size());
  std::vector<SpecialPair> special;
  try {
    special = special_pairs(n, bonds, weights);
  } catch (const std::invalid_argument& e) {
    fail(this->name(), Kernel::kStyle, e.what());
  }
  for (const SpecialPair& sp : special) {
    if (sp.weight > 0.0)
      scaled_.push_back(sp);
    else
      ++excluded_;
  }
  list_.set_exclusions(n, special);  // every pair with w ≠ 1; the scaled ones go through scaled_
}

template <class Kernel>
void PairTerm<Kernel>::check_positions(const Eigen::Matrix3Xd& x, const Eigen::Matrix3Xd* f) const {
  if (x.cols() != static_cast<Eigen::Index>(types_.size()) || (f && f->cols() != x.cols())) {
    std::ostringstream s;
    s << "positions of " << x.cols() << " particles" << (f ? ", forces of " + std::to_string(f->cols()) : "")
      << ", but types were given for " << types_.size();
    fail(name(), Kernel::kStyle, s.str());
  }
}

template <class Kernel>
double PairTerm<Kernel>::add_forces(const Eigen::Matrix3Xd& x, const Box& box, Eigen::Matrix3Xd& f) const {
  check_positions(x, &f);
  list_.update(x, box);
  return accumulate_pairs<Kernel, true, false>(list_, scaled_, params_, types_.data(), x, box, f.data(), scratch_)
      .energy;
}

template <class Kernel>
double PairTerm<Kernel>::virial(const Eigen::Matrix3Xd& x, const Box& box) const {
  check_positions(x, nullptr);
  list_.update(x, box);
  return accumulate_pairs<Kernel, false, true>(list_, scaled_, params_, types_.data(), x, box, nullptr, scratch_)
      .virial;
}

template <class Kernel>
std::string PairTerm<Kernel>::definition() const {
  std::ostringstream s;
  s << Kernel::kStyle << " pairs, " << coeffs_.num_types() << " particle type(s), cutoff " << cutoff_ << ", skin "
    << list_.skin() << ", special bonds w12 = " << weights_.w12 << ", w13 = " << weights_.w13 << " (" << excluded_
    << " pairs excluded, " << scaled_.size() << " scaled)";
  return s.str();
}

template <class Kernel>
std::string PairTerm<Kernel>::describe() const {
  return definition() + ", " + std::to_string(list_.rebuilds()) + " neighbour-list rebuilds so far";
}

// Words: rebuilds, periodic x y z (0/1), origin (3), lengths (3), then x_at_build column-major.
template <class Kernel>
std::vector<double> PairTerm<Kernel>::save_state() const {
  if (!list_.built()) return {};
  const Box& b = list_.box_at_build();
  const Eigen::Matrix3Xd& x = list_.positions_at_build();
  std::vector<double> w = {static_cast<double>(list_.rebuilds())};
  for (int a = 0; a < 3; ++a) w.push_back(b.periodic[a] ? 1.0 : 0.0);
  for (int a = 0; a < 3; ++a) w.push_back(b.origin[a]);
  for (int a = 0; a < 3; ++a) w.push_back(b.lengths[a]);
  w.insert(w.end(), x.data(), x.data() + x.size());
  return w;
}

template <class Kernel>
void PairTerm<Kernel>::load_state(std::span<const double> w) {
  if (w.empty()) return;  // saved before the first build: the next evaluation builds
  const std::size_t n = types_.size();
  if (w.size() != 10 + 3 * n)
    fail(name(), Kernel::kStyle,
         "neighbour-list state of " + std::to_string(w.size()) + " words, expected " + std::to_string(10 + 3 * n));
  Box b;
  for (int a = 0; a < 3; ++a) {
    b.periodic[a] = w[1 + a] != 0.0;
    b.origin[a] = w[4 + a];
    b.lengths[a] = w[7 + a];
  }
  const Eigen::Map<const Eigen::Matrix3Xd> x(w.data() + 10, 3, static_cast<Eigen::Index>(n));
  list_.restore(x, b, static_cast<long>(w[0]));
}

template class PairTerm<LennardJones>;
template class PairTerm<WeeksChandlerAndersen>;
template class PairTerm<SoftCosine>;

}  // namespace stiffmd
