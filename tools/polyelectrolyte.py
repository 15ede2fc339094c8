#!/usr/bin/env python3
# A salt-free polyelectrolyte solution in reduced (LJ) units: 8 chains of 32 beads, every second bead
# carrying charge −1, and 128 monovalent counterions (+1), so the box is neutral. Bead density 0.02,
# Bjerrum length 1 (q = ±1, kT = 1, qqrd2e = 1: LAMMPS's lj units without a dielectric). Excluded
# volume WCA between every pair except bonded neighbours; the Coulomb interaction between every
# pair, bonded neighbours included (special_bonds lj 0 1 1 coul 1 1 1), split by Ewald.
#   inputs/polyelectrolyte.data          the chains (self-avoiding random walks, bond lengths 0.94–1.00)
#                                        and the counterions, placed at random (fixed seed), atom_style full
#   inputs/polyelectrolyte.toml          the production deck: stiff bonds (ε = 0.01) integrated by the
#                                        projected impulse with the PPPM mesh on the macro step, 1e-4
#   tests/decks/polyelectrolyte_run0.toml  every bond a harmonic spring ½k(r − r0)², ewald 1e-8: LAMMPS's
#                                        `run 0` of the same styles (PolyelectrolyteLammps.*, tests/test_peptide.cpp)
# `--reference` also runs LAMMPS (`lmp`) on the run-0 input and writes its energies, pressure and
# forces to tests/data/polyelectrolyte_lammps/.
#     /usr/bin/python3 tools/polyelectrolyte.py [--reference]
import math, os, random, sys

import engines

here = os.path.dirname(os.path.abspath(__file__))
root = os.path.join(here, '..')
chains, beads, counterions = 8, 32, 128
density, bond_length = 0.02, 0.97
eps, alpha = 0.01, 1.0  # stiff bonds ½(α/ε)²(r − r0)²: the run-0 deck's harmonic k = (α/ε)²
wca = 2 ** (1 / 6)
coulomb_cutoff = 3.0
L = ((chains * beads + counterions) / density) ** (1 / 3)
rnd = random.Random(31)


def image(d):
    return d - L * round(d / L)


def too_close(p, placed, skip=None):
    for k, q in enumerate(placed):
        if k != skip and sum(image(p[a] - q[a]) ** 2 for a in range(3)) < 0.9 ** 2:
            return True
    return False


def unit():
    while True:
        v = [rnd.gauss(0, 1) for _ in range(3)]
        n = math.sqrt(sum(c * c for c in v))
        if n > 1e-6:
            return [c / n for c in v]


atoms, bonds = [], []  # atoms: (mol, type, q, position unwrapped)
placed = []
for c in range(chains):
    while True:  # a self-avoiding walk, restarted where it cannot grow
        walk = [[rnd.uniform(0, L) for _ in range(3)]]
        if too_close(walk[0], placed):
            continue
        for _ in range(beads - 1):
            for _ in range(200):
                step = rnd.uniform(0.94, 1.00)
                p = [walk[-1][a] + step * u for a, u in enumerate(unit())]
                if not too_close(p, placed + walk, skip=len(placed) + len(walk) - 1):
                    walk.append(p)
                    break
            else:
                break
        if len(walk) == beads:
            break
    for b, p in enumerate(walk):
        charged = b % 2 == 1
        atoms.append((c + 1, 2 if charged else 1, -1.0 if charged else 0.0, p))
        if b:
            bonds.append((len(atoms) - 1, len(atoms)))
    placed += walk
for k in range(counterions):
    while True:
        p = [rnd.uniform(0, L) for _ in range(3)]
        if not too_close(p, placed):
            break
    placed.append(p)
    atoms.append((chains + k + 1, 3, 1.0, p))

data = os.path.join(root, 'inputs', 'polyelectrolyte.data')
with open(data, 'w') as f:
    f.write(f"Salt-free polyelectrolyte: {chains} chains x {beads} beads, every second bead q = -1, "
            f"{counterions} counterions (tools/polyelectrolyte.py)\n\n")
    f.write(f"{len(atoms)} atoms\n{len(bonds)} bonds\n\n3 atom types\n1 bond types\n\n")
    f.write(f"0 {L:.12f} xlo xhi\n0 {L:.12f} ylo yhi\n0 {L:.12f} zlo zhi\n\n")
    f.write("Masses\n\n1 1.0\n2 1.0\n3 1.0\n\nAtoms # full\n\n")
    for i, (mol, t, q, p) in enumerate(atoms, start=1):
        w = [x % L for x in p]
        img = [math.floor(x / L) for x in p]
        f.write(f"{i} {mol} {t} {q:g} {w[0]:.12f} {w[1]:.12f} {w[2]:.12f} {img[0]} {img[1]} {img[2]}\n")
    v = [[rnd.gauss(0, 1) for _ in range(3)] for _ in atoms]  # T = 1, unit masses, no net momentum
    mean = [sum(r[a] for r in v) / len(v) for a in range(3)]
    f.write("\nVelocities\n\n")
    for i, r in enumerate(v, start=1):
        f.write(f"{i} {r[0] - mean[0]:.12f} {r[1] - mean[1]:.12f} {r[2] - mean[2]:.12f}\n")
    f.write("\nBonds\n\n")
    for k, (i, j) in enumerate(bonds, start=1):
        f.write(f"{k} 1 {i} {j}\n")


def deck(run0):
    o = []
    w = o.append
    w("# Written by tools/polyelectrolyte.py: do not edit by hand.")
    if run0:
        w("# LAMMPS's run 0 of the polyelectrolyte's styles (harmonic bonds, lj/cut/coul/long with WCA,")
        w("# ewald 1e-8): the energies, pressure and forces PolyelectrolyteLammps.* compares with")
        w("# tests/data/polyelectrolyte_lammps/.")
    else:
        w(f"# A salt-free polyelectrolyte solution (reduced units): {chains} chains of {beads} beads, every")
        w(f"# second bead q = -1, {counterions} counterions q = +1, bead density {density}, Bjerrum length 1.")
        w("# Stiff bonds (ε = 0.01, rest length 0.97) under the projected impulse: the macro step kicks with")
        w("# P(x)(−∇U) the WCA + real-space Coulomb pair and the PPPM mesh (1e-4); the bonds get micro steps.")
        w("# Langevin at T = 1. The data file's bonds are 0.94–1.00 long: [prepare] projects them onto the")
        w("# constraint manifold and gives the bond vibrations their thermal energy.")
        w("#   stiffmd run inputs/polyelectrolyte.toml")
        w("#   stiffmd run inputs/polyelectrolyte.toml --set integrator.method='\"impulse\"'   # plain kicks")
    w('units = "lj"\n')
    for name in ("neutral", "charged", "counterion"):
        w(f"[types.{name}]\nmass = 1.0\n")
    w("[import]")
    w(f'lammps_data = "{("../../inputs/" if run0 else "")}polyelectrolyte.data"')
    w('atom_types = { "1" = "neutral", "2" = "charged", "3" = "counterion" }')
    w('bond_types = { "1" = "backbone" }\n')
    if run0:
        w(f"[forces.bonds]\nstyle = \"harmonic-bond\"\nbond_types.backbone = {{ k = {(alpha / eps) ** 2:g}, "
          f"r0 = {bond_length} }}\n")
    else:
        w(f"[variables]\neps = {eps}\n")
        w(f"[forces.bonds]\nstyle = \"stiff-harmonic\"\nepsilon = \"eps\"\nbond_types.backbone = "
          f"{{ length = {bond_length}, alpha = {alpha} }}\n")
    w("[forces.pair]                  # pair_style lj/cut/coul/long 2^(1/6) 3.0, pair_modify shift yes")
    w("style = \"lj/cut/coul/long\"")
    w(f"cutoff = {wca:.15g}\ncoulomb_cutoff = {coulomb_cutoff}\nshift = true")
    w("special_lj = [0.0, 1.0, 1.0]\nspecial_coul = [1.0, 1.0, 1.0]")
    for name in ("neutral", "charged", "counterion"):
        w(f"types.{name} = {{ epsilon = 1.0, sigma = 1.0 }}")
    w("")
    if run0:
        w("[forces.long]\nstyle = \"ewald\"\naccuracy = 1e-8\n")
        w("[integrator]\nmethod = \"velocity-verlet\"\nh = 0.001\n\n[run]\nsteps = 1\n")
    else:
        w("[forces.mesh]                  # kspace_style pppm 1e-4, on the macro step")
        w("style = \"pppm\"\naccuracy = 1e-4\n")
        w("[prepare]\nproject = true\nvibrational_temperature = 1.0\nseed = 33\n")
        w("[thermostat]\nstyle = \"langevin\"\ntemperature = 1.0\ndamp = 1.0\nseed = 34\n")
        w("[integrator]\nmethod = \"projected-impulse\"\nh = 0.01\nmicro_steps = 10\n")
        w("[run]\nt_end = 20.0\n\n[output]\nxyz = \"\"\nthermo_interval = 1.0\n")
    return "\n".join(o)


open(os.path.join(root, 'inputs', 'polyelectrolyte.toml'), 'w').write(deck(False))
open(os.path.join(root, 'tests', 'decks', 'polyelectrolyte_run0.toml'), 'w').write(deck(True))
print("wrote inputs/polyelectrolyte.toml, inputs/polyelectrolyte.data, tests/decks/polyelectrolyte_run0.toml")

if '--reference' in sys.argv:
    out = os.path.join(root, 'tests', 'data', 'polyelectrolyte_lammps')
    os.makedirs(out, exist_ok=True)
    inp = f"""units lj
atom_style full
pair_style lj/cut/coul/long {wca:.15g} {coulomb_cutoff}
pair_modify shift yes table 0
bond_style harmonic
kspace_style ewald 1e-8
special_bonds lj 0 1 1 coul 1 1 1
read_data {os.path.abspath(data)}
pair_coeff * * 1.0 1.0
bond_coeff 1 {0.5 * (alpha / eps) ** 2:g} {bond_length}
thermo_style custom step ebond evdwl ecoul elong press ke
thermo_modify format float %.15g norm no
dump f all custom 1 forces.dump id fx fy fz
dump_modify f format float %.15g sort id
run 0
"""
    engines.lammps_run_zero(inp, out, "run 0 of tools/polyelectrolyte.py's input, ewald 1e-8, pair_modify table 0:\n"
                            "# /usr/bin/python3 tools/polyelectrolyte.py --reference  (lj units)", 'ε/σ')
    print("wrote tests/data/polyelectrolyte_lammps/energies.txt, forces.txt")
