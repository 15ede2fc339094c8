#!/usr/bin/env python3
# LAMMPS's dihedral energies on fixed 4-atom geometries: the reference numbers of
# DihedralStyles.MatchLammpsEnergies (tests/test_bonded_kernels.cpp), which builds the same
# quadruples (bonds 1.0, 1.1, 0.9; angles 110° and 100°; torsion phi). Needs `lmp` on PATH.
# Prints one row per style: its dihedral_coeff and E(phi) for each phi, as `run 0` reports it.
import math, subprocess, sys, tempfile
d = tempfile.mkdtemp()
t1, t2 = math.radians(110), math.radians(100)
def quad(phi):
    return [(math.cos(t1), math.sin(t1), 0.0), (0.0, 0.0, 0.0), (1.1, 0.0, 0.0),
            (1.1 - 0.9 * math.cos(t2), 0.9 * math.sin(t2) * math.cos(phi), 0.9 * math.sin(t2) * math.sin(phi))]
phis = [0.3, 1.2, 2.0, math.pi - 0.05, -2.6]
styles = [('harmonic', '1.5 1 3'), ('harmonic', '-0.8 -1 2'), ('multi/harmonic', '1.0 -0.5 0.8 1.2 -0.3'),
          ('opls', '1.4 -0.3 0.9 0.2')]
for st, co in styles:
    row = []
    for phi in phis:
        with open(f'{d}/q.data', 'w') as f:
            f.write("q\n\n4 atoms\n1 dihedrals\n1 atom types\n1 dihedral types\n-5 5 xlo xhi\n-5 5 ylo yhi\n-5 5 zlo zhi\n\n"
                    "Masses\n\n1 1.0\n\nAtoms # molecular\n\n")
            for k, p in enumerate(quad(phi)): f.write(f"{k+1} 1 1 {p[0]!r} {p[1]!r} {p[2]!r}\n")
            f.write("\nDihedrals\n\n1 1 1 2 3 4\n")
        inp = (f"units lj\natom_style molecular\nboundary f f f\nread_data {d}/q.data\ndihedral_style {st}\n"
               f"dihedral_coeff 1 {co}\npair_style zero 1.0\npair_coeff * *\n"
               "thermo_style custom step edihed\nthermo_modify norm no format float %.17g\nrun 0\n")
        open(f'{d}/in.q', 'w').write(inp)
        out = subprocess.run(['lmp', '-in', f'{d}/in.q', '-log', 'none', '-echo', 'none'], capture_output=True, text=True).stdout
        lines = out.splitlines()
        if not any(l.split()[:2] == ['Step', 'E_dihed'] for l in lines): print(out[-1500:]); sys.exit(1)
        k = next(i for i, l in enumerate(lines) if l.split()[:2] == ['Step', 'E_dihed'])
        row.append(lines[k + 1].split()[1])
    print(st, co, ', '.join(row))
