#!/usr/bin/env python3
# SPC/E water (Berendsen, Grigera & Straatsma 1987) as a LAMMPS data file (atom_style full): N
# waters on a simple cubic lattice, each rigidly rotated at random (fixed seed), at 0.997 g/cm³.
# O–H 1.0 Å, H–O–H 109.47°, q_O = −0.8476 e, q_H = +0.4238 e; one bond type (O–H), one angle type.
#     /usr/bin/python3 tools/spce_water.py [--waters 512] [--out inputs/spce_water.data]
# The deck inputs/spce_water.toml runs it (rigid, RATTLE, PPPM); the same file runs in LAMMPS with
# `fix rattle 1e-6 100 0 b 1 a 1` (docs/electrostatics.md, "SPC/E water").
import argparse, math, os, random

here = os.path.dirname(os.path.abspath(__file__))
ap = argparse.ArgumentParser()
ap.add_argument('--waters', type=int, default=512)
ap.add_argument('--seed', type=int, default=7)
ap.add_argument('--out', default=os.path.join(here, '..', 'inputs', 'spce_water.data'))
a = ap.parse_args()

m_o, m_h = 15.9994, 1.008
density = 0.997  # g/cm³
volume = a.waters * (m_o + 2 * m_h) / 0.602214076 / density  # Å³
L = volume ** (1 / 3)
n = math.ceil(a.waters ** (1 / 3))
spacing = L / n
half = math.radians(109.47) / 2
body = [(0.0, 0.0, 0.0), (math.sin(half), math.cos(half), 0.0), (-math.sin(half), math.cos(half), 0.0)]
rnd = random.Random(a.seed)

def rotation():  # a uniformly random rotation matrix from a unit quaternion
    q = [rnd.gauss(0, 1) for _ in range(4)]
    s = math.sqrt(sum(c * c for c in q))
    w, x, y, z = (c / s for c in q)
    return [[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]]

sites = [(i, j, k) for i in range(n) for j in range(n) for k in range(n)][:a.waters]
atoms, bonds, angles = [], [], []
for mol, (i, j, k) in enumerate(sites, start=1):
    R = rotation()
    c = [(i + 0.5) * spacing, (j + 0.5) * spacing, (k + 0.5) * spacing]
    first = len(atoms) + 1
    for s, (t, q) in enumerate([(1, -0.8476), (2, 0.4238), (2, 0.4238)]):
        p = [c[r] + sum(R[r][m] * body[s][m] for m in range(3)) for r in range(3)]
        atoms.append((len(atoms) + 1, mol, t, q, p))
    bonds += [(1, first, first + 1), (1, first, first + 2)]
    angles.append((1, first + 1, first, first + 2))

with open(a.out, 'w') as f:
    f.write(f"SPC/E water, {a.waters} molecules at {density} g/cm3 (tools/spce_water.py --waters {a.waters} "
            f"--seed {a.seed})\n\n")
    f.write(f"{len(atoms)} atoms\n{len(bonds)} bonds\n{len(angles)} angles\n"
            "2 atom types\n1 bond types\n1 angle types\n\n")
    for ax in 'xyz':
        f.write(f"0.0 {L:.10f} {ax}lo {ax}hi\n")
    f.write(f"\nMasses\n\n1 {m_o}\n2 {m_h}\n\nAtoms # full\n\n")
    for i, mol, t, q, p in atoms:
        f.write(f"{i} {mol} {t} {q} {p[0]:.10f} {p[1]:.10f} {p[2]:.10f}\n")
    f.write("\nBonds\n\n" + "".join(f"{k + 1} {t} {i} {j}\n" for k, (t, i, j) in enumerate(bonds)))
    f.write("\nAngles\n\n" + "".join(f"{k + 1} {t} {i} {j} {l}\n" for k, (t, i, j, l) in enumerate(angles)))
print(f"wrote {a.out}: {a.waters} waters, box {L:.4f} Å")
