#include "forcefields/external_terms.hpp"

#include <algorithm>
#include <cmath>
#include <sstream>
#include <stdexcept>

#include "core/errors.hpp"

namespace stiffmd {
namespace {

// A particle listed twice would feel the field twice: almost surely a deck mistake.
// An empty list is refused unless allowed: a particle subset (on_subset) may hold none of the
// particles a term selects.
void check_particle_list(const std::string& what, const std::vector<int>& particles, bool allow_empty) {
  if (particles.empty() && allow_empty) return;
  if (particles.empty()) throw std::invalid_argument(what + ": the particle list is empty");
  std::vector<int> sorted = particles;
  std::sort(sorted.begin(), sorted.end());
  if (sorted.front() < 0)
    throw std::invalid_argument(what + ": particle index " + std::to_string(sorted.front()) + " is negative");
  const auto dup = std::adjacent_find(sorted.begin(), sorted.end());
  if (dup != sorted.end())
    throw std::invalid_argument(what + ": particle " + std::to_string(*dup) + " is listed more than once");
}

char axis_name(int axis) {
  return "xyz"[axis];
}

// The unshifted 9-3 wall energy ε[(2/15)(σ/r)⁹ − (σ/r)³].
double lj93(double epsilon, double sigma, double r) {
  const double s3 = std::pow(sigma / r, 3);
  return epsilon * (2.0 / 15.0 * s3 * s3 * s3 - s3);
}

}  // namespace

HarmonicTether::HarmonicTether(std::string name, Level level, std::vector<int> particles, Eigen::Vector3d center,
                               double k, bool allow_empty)
    : ForceTerm(std::move(name), level), particles_(std::move(particles)), center_(center), k_(k) {
  const std::string what = "harmonic-tether '" + this->name() + "'";
  check_particle_list(what, particles_, allow_empty);
  if (!center_.allFinite()) throw std::invalid_argument(what + ": center must be finite");
  if (!(k_ >= 0.0) || !std::isfinite(k_)) {
    std::ostringstream m;
    m << what << ": k must be finite and >= 0, got " << k_;
    throw std::invalid_argument(m.str());
  }
}

double HarmonicTether::add_forces(const Eigen::Matrix3Xd& x, const Box& box, Eigen::Matrix3Xd& f) const {
  double energy = 0.0;
  const bool periodic = box.any_periodic();
  for (const int i : particles_) {
    Eigen::Vector3d d = x.col(i) - center_;
    if (periodic) d = box.min_image(d);  // the nearest image of c, so E is periodic like the box
    energy += 0.5 * k_ * d.squaredNorm();
    f.col(i) -= k_ * d;
  }
  return energy;
}

std::unique_ptr<ForceTerm> HarmonicTether::on_subset(const ParticleSubset& subset, const Box&) const {
  auto out = std::make_unique<HarmonicTether>(name(), level(), selected_on(subset, particles_), center_, k_, true);
  if (has_selection()) out->set_selection(selection());
  return out;
}

std::string HarmonicTether::describe() const {
  std::ostringstream s;
  s << particles_.size() << " particles tethered to (" << center_.x() << ", " << center_.y() << ", " << center_.z()
    << "), k = " << k_;
  return s.str();
}

void HarmonicTether::define(ParameterRecord& record) const {
  record.add("center", {center_.x(), center_.y(), center_.z()});
  record.add("k", k_);
  record.add("particles", std::span<const int>(particles_));
}

LJ93Wall::LJ93Wall(std::string name, Level level, LJ93WallParams params, std::vector<int> particles, bool allow_empty)
    : ForceTerm(std::move(name), level), p_(params), particles_(std::move(particles)), shift_(0.0) {
  const std::string what = "lj93-wall '" + this->name() + "'";
  std::ostringstream m;
  m << what << ": ";
  if (p_.axis < 0 || p_.axis > 2)
    m << "axis must be 0, 1 or 2 (x, y, z), got " << p_.axis;
  else if (p_.side != 1 && p_.side != -1)
    m << "side must be +1 or -1, got " << p_.side;
  else if (!std::isfinite(p_.position))
    m << "position must be finite, got " << p_.position;
  else if (!(p_.epsilon >= 0.0) || !std::isfinite(p_.epsilon))
    m << "epsilon must be finite and >= 0, got " << p_.epsilon;
  else if (!(p_.sigma > 0.0) || !std::isfinite(p_.sigma))
    m << "sigma must be finite and > 0, got " << p_.sigma;
  else if (!(p_.cutoff > 0.0) || !std::isfinite(p_.cutoff))
    m << "cutoff must be finite and > 0, got " << p_.cutoff;
  else {
    check_particle_list(what, particles_, allow_empty);
    shift_ = lj93(p_.epsilon, p_.sigma, p_.cutoff);
    return;
  }
  throw std::invalid_argument(m.str());
}

double LJ93Wall::add_forces(const Eigen::Matrix3Xd& x, const Box& box, Eigen::Matrix3Xd& f) const {
  if (box.periodic[p_.axis])
    throw std::invalid_argument("lj93-wall '" + name() + "': the box is periodic along the wall's axis " +
                                std::string(1, axis_name(p_.axis)));
  double energy = 0.0;
  for (const int i : particles_) {
    const double r = p_.side * (x(p_.axis, i) - p_.position);
    if (!(r > 0.0)) {
      std::ostringstream m;
      m.precision(10);
      m << "lj93-wall '" << name() << "': particle " << i << " is not on the wall's " << (p_.side > 0 ? "+" : "-")
        << " side (" << axis_name(p_.axis) << " = " << x(p_.axis, i) << ", wall at " << p_.position << ", distance "
        << r << ")";
      throw NumericalError(m.str());
    }
    if (r >= p_.cutoff) continue;
    const double s3 = std::pow(p_.sigma / r, 3), s9 = s3 * s3 * s3;
    energy += p_.epsilon * (2.0 / 15.0 * s9 - s3) - shift_;
    // dE/dr = ε[−(6/5)(σ/r)⁹ + 3(σ/r)³]/r; the force along the axis is −side·dE/dr.
    const double de_dr = p_.epsilon * (-1.2 * s9 + 3.0 * s3) / r;
    f(p_.axis, i) -= p_.side * de_dr;
  }
  return energy;
}

std::unique_ptr<ForceTerm> LJ93Wall::on_subset(const ParticleSubset& subset, const Box&) const {
  auto out = std::make_unique<LJ93Wall>(name(), level(), p_, selected_on(subset, particles_), true);
  if (has_selection()) out->set_selection(selection());
  return out;
}

std::string LJ93Wall::describe() const {
  std::ostringstream s;
  s << "9-3 wall at " << axis_name(p_.axis) << " = " << p_.position << " acting on " << particles_.size()
    << " particles on its " << (p_.side > 0 ? "+" : "-") << " side, epsilon = " << p_.epsilon
    << ", sigma = " << p_.sigma << ", cutoff = " << p_.cutoff;
  return s.str();
}

void LJ93Wall::define(ParameterRecord& record) const {
  record.add("axis", p_.axis);
  record.add("position", p_.position);
  record.add("side", p_.side);
  record.add("epsilon", p_.epsilon);
  record.add("sigma", p_.sigma);
  record.add("cutoff", p_.cutoff);
  record.add("particles", std::span<const int>(particles_));
}

}  // namespace stiffmd
