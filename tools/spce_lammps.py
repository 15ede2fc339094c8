"""The SPC/E water model of inputs/spce_water.toml as LAMMPS commands, for the tools that run the same
box in LAMMPS (tools/spce_compare.py, tools/water_constraints.py): STYLES before `read_data` (LAMMPS
reads a data file's Coeffs sections only for styles already defined), COEFFS and the neighbour list
and 2 fs step after it."""

STYLES = """units real
atom_style full
pair_style lj/cut/coul/long 10.0
pair_modify table 0
bond_style harmonic
angle_style harmonic
kspace_style pppm 1e-5
special_bonds lj/coul 0.0 0.0 0.0
"""

COEFFS = """pair_coeff 1 1 0.1553 3.166
pair_coeff * 2 0.0 1.0
bond_coeff 1 1000.0 1.0
angle_coeff 1 100.0 109.47
neighbor 2.0 bin
neigh_modify every 1 delay 0 check yes
timestep 2.0
"""
