#!/usr/bin/env python3
# LAMMPS's peptide example (examples/peptide: a CHARMM22 5-mer in 669 TIP3P-like waters, 2004 atoms,
# atom_style full, lj/charmm/coul/long 8 10, pppm 1e-4, SHAKE on the bonds to hydrogen and the
# water angle) as stiffmd decks on the same data file:
#   inputs/peptide_solvated.data   the example's data.peptide, unchanged
#   inputs/peptide.toml            the example's run: rigid X–H bonds and water (RATTLE, LAMMPS's
#                                  fix shake b 4 6 8 10 12 14 18 a 31), 2 fs, 275 K, pppm 1e-4
#   tests/decks/peptide_run0.toml  every bond flexible, ewald 1e-8: LAMMPS's `run 0` of the same
#                                  styles (PeptideLammps.*, tests/test_peptide.cpp)
# Bonded coefficients come from the data file (coefficients = "data"); the pair coefficients and
# the charmm dihedrals' 1-4 coefficients are the file's Pair Coeffs columns (ε σ ε14 σ14), written
# into the decks here. `--reference` also runs LAMMPS (`lmp`) on the run-0 input and writes its
# energies, pressure and forces to tests/data/peptide_lammps/.
#     /usr/bin/python3 tools/peptide_deck.py [--reference] [DATA]
import math, os, shutil, sys

import engines

here = os.path.dirname(os.path.abspath(__file__))
root = os.path.join(here, '..')
args = [a for a in sys.argv[1:] if not a.startswith('--')]
src = args[0] if args else '/usr/share/lammps/examples/peptide/data.peptide'
data_name = 'peptide_solvated.data'
shutil.copyfile(src, os.path.join(root, 'inputs', data_name))

sections, name = {}, None
for line in open(src).read().splitlines()[1:]:
    head = line.split('#')[0].strip()
    if head and not head[0].isdigit() and not head[0] == '-' and len(head.split()) <= 3 and head[0].isupper():
        name = head
        sections[name] = []
    elif name and line.strip():
        sections[name].append(line.split())
masses = {int(r[0]): float(r[1]) for r in sections['Masses']}
pair = {int(r[0]): [float(v) for v in r[1:5]] for r in sections['Pair Coeffs']}
bond = {int(r[0]): (float(r[1]), float(r[2])) for r in sections['Bond Coeffs']}
angle = {int(r[0]): float(r[2]) for r in sections['Angle Coeffs']}
element = lambda m: 'H' if m < 2 else 'C' if m < 13 else 'N' if m < 15 else 'O' if m < 17 else 'S'
tname = {t: f"{element(m).lower()}{t}" for t, m in masses.items()}

rigid_bonds, rigid_angles = [4, 6, 8, 10, 12, 14, 18], [31]  # in.peptide's fix shake
shake_tolerance = 1e-4  # in.peptide's fix shake 0.0001 10 100
eps = 0.05  # the stiff bonds' ε: under RATTLE only their rest lengths matter

def deck(run0):
    o = []
    w = o.append
    w("# Written by tools/peptide_deck.py from LAMMPS's examples/peptide/data.peptide: do not edit by hand.")
    if run0:
        w("# LAMMPS's run 0 of the example's styles, every bond flexible (no SHAKE), ewald 1e-8: the")
        w("# energies, pressure and forces PeptideLammps.* compares with tests/data/peptide_lammps/.")
    else:
        w("# The example's run (in.peptide): a solvated CHARMM22 5-mer, bonds to hydrogen and the water")
        w("# angle rigid (RATTLE, as LAMMPS's fix shake b 4 6 8 10 12 14 18 a 31), PPPM 1e-4, 2 fs, 275 K")
        w("# (Langevin here; LAMMPS's example uses Nose-Hoover). docs/electrostatics.md compares it with LAMMPS.")
        w("#   stiffmd run inputs/peptide.toml")
    w('units = "real"\n')
    for t in sorted(masses):
        w(f"[types.{tname[t]}]\nmass = {masses[t]}\nelement = \"{element(masses[t])}\"\n")
    w("[import]")
    w(f'lammps_data = "{("../../inputs/" if run0 else "") + data_name}"')
    w("atom_types = { " + ", ".join(f'"{t}" = "{tname[t]}"' for t in sorted(masses)) + " }\n")
    if not run0:
        w("[forces.rigid]                 # LAMMPS fix shake b 4 6 8 10 12 14 18 a 31; ε, α set the stiff")
        w("style = \"stiff-harmonic\"       # potential ½(α/ε)²(r − r0)² = K(r − r0)² the impulse methods integrate")
        w(f"epsilon = {eps}")
        for b in rigid_bonds:
            K, r0 = bond[b]
            w(f'bond_types."{b}" = {{ length = {r0}, alpha = {eps * math.sqrt(2 * K):.12g} }}')
        for a in rigid_angles:
            w(f'angle_types."{a}" = {{ theta0 = {angle[a]}, alpha = {eps * math.sqrt(2 * 450.0):.12g} }}')
        w(f"shake_tolerance = {shake_tolerance:g}        # fix shake's tolerance: SHAKE stops as LAMMPS's (docs/decks.md)")
        w("")
    w("[forces.bonds]\nstyle = \"harmonic-bond\"\ncoefficients = \"data\"\n")
    w("[forces.angles]\nstyle = \"charmm-angle\"\ncoefficients = \"data\"\n")
    w("[forces.dihedrals]\nstyle = \"charmm-dihedral\"\ncoefficients = \"data\"")
    for t in sorted(masses):
        w(f"lj14.{tname[t]} = {{ epsilon = {pair[t][2]}, sigma = {pair[t][3]} }}")
    w("\n[forces.impropers]\nstyle = \"harmonic-improper\"\ncoefficients = \"data\"\n")
    w("[forces.pair]                  # pair_style lj/charmm/coul/long 8.0 10.0 10.0")
    w("style = \"lj/charmm/coul/long\"\nlevel = \"slow\"\nskin = 2.0\nspecial_bonds = \"charmm\"")
    for t in sorted(masses):
        e, s, e14, s14 = pair[t]
        w(f"types.{tname[t]} = {{ epsilon = {e}, sigma = {s}, epsilon14 = {e14}, sigma14 = {s14}, "
          "inner = 8.0, cutoff = 10.0 }")
    w("")
    if run0:
        w("[forces.long]\nstyle = \"ewald\"\naccuracy = 1e-8\n")
        w("[integrator]\nmethod = \"velocity-verlet\"\nh = 1.0\n\n[run]\nsteps = 1\n")
    else:
        w("[forces.long]                  # kspace_style pppm 0.0001")
        w("style = \"pppm\"\naccuracy = 1e-4\n")
        w("[thermostat]\nstyle = \"langevin\"\ntemperature = 275.0\ndamp = 100.0\nseed = 3\n")
        w("[integrator]\nmethod = \"rattle\"\nh = 2.0                        # fs\n")
        w("[run]\nsteps = 300\n\n[output]\nthermo_interval = 100.0")
        w("xyz = \"\"                       # no trajectory, as the example (its dumps are commented out);")
        w("                               # --set output.h5md='\"traj.h5md\"' writes one\n")
    return "\n".join(o)

open(os.path.join(root, 'inputs', 'peptide.toml'), 'w').write(deck(False))
open(os.path.join(root, 'tests', 'decks', 'peptide_run0.toml'), 'w').write(deck(True))
print("wrote inputs/peptide.toml, inputs/peptide_solvated.data, tests/decks/peptide_run0.toml")

if '--reference' in sys.argv:
    out = os.path.join(root, 'tests', 'data', 'peptide_lammps')
    os.makedirs(out, exist_ok=True)
    inp = f"""units real
atom_style full
pair_style lj/charmm/coul/long 8.0 10.0 10.0
pair_modify table 0
bond_style harmonic
angle_style charmm
dihedral_style charmm
improper_style harmonic
kspace_style ewald 1e-8
read_data {os.path.abspath(src)}
thermo_style custom step ebond eangle edihed eimp evdwl ecoul elong press ke
thermo_modify format float %.15g
dump f all custom 1 forces.dump id fx fy fz
dump_modify f format float %.15g sort id
run 0
"""
    engines.lammps_run_zero(inp, out, "run 0 of examples/peptide with ewald 1e-8, pair_modify table 0, no SHAKE:\n"
                            "# /usr/bin/python3 tools/peptide_deck.py --reference  (real units: kcal/mol, atm)", 'kcal/mol/Å')
    print("wrote tests/data/peptide_lammps/energies.txt, forces.txt")
