// The deck's units (`units = "lj" | "real"`, README "Units"). The engine itself is unit-free: with
// real units its internal units are Å, kcal/mol, g/mol and the time unit they imply,
// τ = sqrt((g/mol) Å² / (kcal/mol)) = 48.88821291 fs, and it works with kT, never with T. The
// conversions happen once, at the boundaries: deck keys of time, temperature and velocity
// (engine/scene), imported velocities, and the columns and trajectories written
// (engine/run/outputs.cpp). Lengths, energies, masses, forces, stiffnesses and number densities
// need none: their internal unit is the deck's.
//
// Constants as LAMMPS's src/update.cpp (units real): boltz = 0.0019872067 kcal/(mol K),
// ftm2v = 1/48.88821291², nktv2p = 68568.415 atm per kcal/(mol Å³); LAMMPS's time unit is 1 fs
// and its velocities are Å/fs.
#pragma once

#include <optional>
#include <string>
#include <string_view>

namespace stiffmd {

// What a written number measures, for its conversion and its H5MD `unit` attribute.
enum class Dimension {
  none,
  length,
  time,
  velocity,
  force,
  energy,
  temperature,
  pressure,
  frequency,
  action,
  volume,
  density
};

struct Units {
  std::string name = "lj";
  double time = 1.0;       // one deck time unit in engine time units (real: 1 fs = 1/48.88821291 τ)
  double boltzmann = 1.0;  // k_B: engine energy per deck temperature unit (real: kcal/mol per K)
  double pressure = 1.0;   // one engine pressure unit (energy/length³) in the output's (real: atm)
  // Coulomb's constant qqrd2e: E = coulomb · q_i q_j / r with charges in e (real: kcal Å/(mol e²)).
  double coulomb = 1.0;

  static constexpr double kRealTimeFs = 48.88821291;      // τ in fs: 1/sqrt(ftm2v)
  static constexpr double kRealBoltzmann = 0.0019872067;  // kcal/(mol K)
  static constexpr double kRealPressure = 68568.415;      // nktv2p: atm per kcal/(mol Å³)
  static constexpr double kRealDensity = 1.66053906660;   // g/cm³ per (g/mol)/Å³: 10²⁴/N_A
  static constexpr double kRealCoulomb = 332.06371;       // qqr2e: kcal Å/(mol e²), as LAMMPS's units real

  // "lj" or "real"; nothing for any other name.
  static std::optional<Units> named(std::string_view n) {
    Units u;
    if (n == "lj") return u;
    if (n != "real") return std::nullopt;
    u.name = "real";
    u.time = 1.0 / kRealTimeFs;
    u.boltzmann = kRealBoltzmann;
    u.pressure = kRealPressure;
    u.coulomb = kRealCoulomb;
    return u;
  }
  bool reduced() const { return name == "lj"; }

  // Deck (or imported) values to the engine's units.
  double time_in(double t) const { return t * time; }
  double rate_in(double gamma) const { return gamma / time; }  // a friction, 1/time
  double velocity_in(double v) const { return v / time; }
  double kT(double temperature) const { return boltzmann * temperature; }

  // An engine value of the given dimension in the output's units (time in fs, T in K, p in atm, …).
  double out(Dimension d) const {
    switch (d) {
      case Dimension::time:
        return 1.0 / time;
      case Dimension::velocity:
        return time;
      case Dimension::temperature:
        return 1.0 / boltzmann;
      case Dimension::pressure:
        return pressure;
      case Dimension::frequency:
        return time;
      case Dimension::action:
        return 1.0 / time;
      case Dimension::density:  // real: g/mol per Å³ in g/cm³ (10²⁴ / N_A)
        return reduced() ? 1.0 : kRealDensity;
      default:
        return 1.0;
    }
  }

  // An engine value in the unit h5md_unit names: out(d), but velocities in Å/ps in real units.
  double h5md_scale(Dimension d) const { return d == Dimension::velocity && !reduced() ? 1000.0 * out(d) : out(d); }

  // The H5MD §Units string of a dimension; "" for none (reduced units carry no unit attribute).
  // The strings are those MDAnalysis 2.4.2's H5MD reader accepts. Velocities are written in Å/ps
  // (h5md_scale), not Å/fs: MDAnalysis up to 2.9 converts Å/fs the wrong way (a factor 10⁶ off,
  // MDAnalysis issue #5051), and Å/ps is its native unit, which it takes as is.
  std::string h5md_unit(Dimension d) const {
    if (reduced()) return "";
    switch (d) {
      case Dimension::length:
        return "Angstrom";
      case Dimension::time:
        return "fs";
      case Dimension::velocity:
        return "Angstrom ps-1";
      case Dimension::force:
        return "kcal mol-1 Angstrom-1";
      case Dimension::energy:
        return "kcal mol-1";
      case Dimension::temperature:
        return "K";
      case Dimension::pressure:
        return "atm";
      case Dimension::frequency:
        return "fs-1";
      case Dimension::action:
        return "kcal mol-1 fs";
      case Dimension::volume:
        return "Angstrom^3";
      case Dimension::density:
        return "g cm-3";
      default:
        return "";
    }
  }
};

}  // namespace stiffmd
