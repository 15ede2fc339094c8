#!/usr/bin/env python3
# LAMMPS's energies per term on tests/data/butanes.data (three butane-like chains: bonds, angles,
# dihedrals, LJ; reduced units): the reference numbers of ImportedButanes.SameEnergiesAsLammps
# and ImportedButanes.MixingRulesAsLammps (tests/test_polymer_scenes.cpp), with pair_modify mix
# geometric and arithmetic. `--write` regenerates the data file (fixed seed). Needs `lmp`.
import math, os, random, subprocess, sys, tempfile

here = os.path.dirname(os.path.abspath(__file__))
data = os.path.join(here, '..', 'tests', 'data', 'butanes.data')

def write_data(path):
    rnd = random.Random(16)
    atoms, bonds, angles, dihedrals = [], [], [], []
    starts = [(1.0, 1.0, 1.0), (3.1, 1.4, 1.8), (1.6, 3.2, 0.4)]
    for m, s in enumerate(starts):
        x = [s]
        for k in range(3):
            while True:  # a step of length 0.95..1.1, bond angle 100..125 degrees from the last
                v = [rnd.uniform(-1, 1) for _ in range(3)]
                n = math.sqrt(sum(c * c for c in v))
                if n < 0.2: continue
                r = rnd.uniform(0.95, 1.1)
                p = tuple(x[-1][d] + r * v[d] / n for d in range(3))
                if k > 0:
                    a = [x[-2][d] - x[-1][d] for d in range(3)]; b = [p[d] - x[-1][d] for d in range(3)]
                    c = sum(a[d] * b[d] for d in range(3)) / math.sqrt(sum(t * t for t in a) * sum(t * t for t in b))
                    if not (math.cos(math.radians(125)) < c < math.cos(math.radians(100))): continue
                x.append(p); break
        base = 4 * m
        for k, p in enumerate(x): atoms.append((base + k + 1, m + 1, 1 if k in (0, 3) else 2, p))
        bonds += [(1 if k != 1 else 2, base + k + 1, base + k + 2) for k in range(3)]
        angles += [(1, base + 1, base + 2, base + 3), (1, base + 2, base + 3, base + 4)]
        dihedrals.append((1, base + 1, base + 2, base + 3, base + 4))
    with open(path, 'w') as f:
        f.write("three butane-like chains (tools/lammps_butane_reference.py --write)\n\n")
        f.write(f"{len(atoms)} atoms\n{len(bonds)} bonds\n{len(angles)} angles\n{len(dihedrals)} dihedrals\n"
                "2 atom types\n2 bond types\n1 angle types\n1 dihedral types\n\n"
                "-1 6 xlo xhi\n-1 6 ylo yhi\n-1 6 zlo zhi\n\nMasses\n\n1 15.0\n2 14.0\n\n"
                "Pair Coeffs # lj/cut\n\n1 1.2 1.05\n2 0.9 0.95\n\n"
                "Bond Coeffs # harmonic\n\n1 200 1.0\n2 150 1.05\n\n"
                "Angle Coeffs # harmonic\n\n1 30 114\n\n"
                "Dihedral Coeffs # opls\n\n1 1.41 -0.27 3.14 0.1\n\nAtoms # molecular\n\n")
        for i, m, t, p in atoms: f.write(f"{i} {m} {t} {p[0]:.6f} {p[1]:.6f} {p[2]:.6f}\n")
        for name, rows in (("Bonds", bonds), ("Angles", angles), ("Dihedrals", dihedrals)):
            f.write(f"\n{name}\n\n")
            for k, r in enumerate(rows): f.write(" ".join(str(v) for v in (k + 1,) + r) + "\n")

if '--write' in sys.argv: write_data(data)
for mix in ('geometric', 'arithmetic'):
  inp = f"""units lj
atom_style molecular
boundary p p p
bond_style harmonic
angle_style harmonic
dihedral_style opls
pair_style lj/cut 2.5
pair_modify mix {mix} shift yes
read_data {data}
special_bonds lj 0.0 0.0 1.0
thermo_style custom step ebond eangle edihed evdwl
thermo_modify norm no format float %.17g
run 0
"""
  d = tempfile.mkdtemp()
  open(os.path.join(d, 'in.butanes'), 'w').write(inp)
  out = subprocess.run(['lmp', '-in', os.path.join(d, 'in.butanes'), '-log', 'none', '-echo', 'none'],
                       capture_output=True, text=True).stdout.splitlines()
  k = next(i for i, l in enumerate(out) if l.split()[:1] == ['Step'])
  print(out[k]); print(out[k + 1]); print(inp)
