// A LAMMPS data file's text piece by piece: the header (counts, box, Masses, Coeffs sections),
// then one line per atom, velocity or bonded item. write_lammps_data (lammps_data.hpp) writes a
// whole system with them; a decomposed run's rank 0 writes the trajectories' topology.data block
// by block with the same pieces (engine/run/topology_parts.hpp), so the two files are the same
// bytes.
#pragma once

#include <Eigen/Core>
#include <initializer_list>
#include <map>
#include <string>
#include <vector>

#include "engine/io/lammps_data.hpp"
#include "engine/io/lammps_data_format.hpp"

namespace stiffmd::lammps_rows {

struct Header {
  std::string title;
  const lammps_format::Style* style = nullptr;
  long long atoms = 0, bonds = 0, angles = 0, dihedrals = 0, impropers = 0;
  // The numbers of types declared (the largest used, or more).
  int atom_types = 0, bond_types = 0, angle_types = 0, dihedral_types = 0, improper_types = 0;
  Eigen::Vector3d lo = Eigen::Vector3d::Zero(), hi = Eigen::Vector3d::Zero();
  const std::map<int, double>* type_mass = nullptr;
  const std::vector<ImportedSystem::CoeffSection>* coeffs = nullptr;
};

// The title line, the counts, the box, Masses and the Coeffs sections.
void append_header(std::string& out, const Header& h);
// The blank line, the section's name and the blank line before its rows: "Atoms # <style>",
// "Velocities", "Bonds", "Angles", "Dihedrals", "Impropers".
void append_section(std::string& out, const std::string& name);
// One Atoms line: id, molecule (styles with one), type, charge (styles with one), the position
// wrapped into [lo, hi) with the image flags that reproduce it bit for bit
// (lammps_data.hpp, "Exactness").
void append_atom(std::string& out, const lammps_format::Style& style, long long id, long long molecule, int type,
                 double charge, const double* x, const Eigen::Vector3d& lo, const Eigen::Vector3d& hi);
void append_velocity(std::string& out, long long id, const double* v);
// One Bonds/Angles/Dihedrals/Impropers line: its number k (from 1), type and atom ids.
void append_item(std::string& out, long long k, int type, std::initializer_list<long long> ids);

}  // namespace stiffmd::lammps_rows
