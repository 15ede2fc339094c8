#!/usr/bin/env python3
# LAMMPS's real-space Coulomb pair styles on one fixed charged system: the reference numbers of
# CoulombLammps.* (tests/test_coulomb.cpp). Needs `lmp` on PATH (29 Sep 2021 was used).
#
#     tools/lammps_coulomb_reference.py [--write-data tests/data/coulomb_chains.data]
#
# The system (written to the data file with --write-data; the test reads the committed file): 8
# chains of 5 atoms in a periodic 18 Å box, real units, all-trans zigzags (bonds ~1.5 Å, angles
# ~110°, each atom moved by up to 0.1 Å: 1-2, 1-3, 1-4 and 1-5 pairs near 1.5, 2.5, 3.7 and 4.9 Å), two atom types, charges ±0.25…0.5 e
# (net 0), special_bonds lj 0 0.5 0.7 coul 0 0.3 0.8333333. Each case is one `run 0` with
# bond_style zero (pair forces only); it prints evdwl, ecoul and the pair virial W (from compute
# pressure NULL pair, W = 3 V P / nktv2p) in %.17g, and for the styles without k-space the pair
# forces on atoms 1, 7 and 23. The coul/long styles run with kspace_style ewald, kspace_modify
# gewald 0.28 and pair_modify table 0: LAMMPS reports their real-space sum as ecoul, apart from
# elong.
import math, random, subprocess, sys, tempfile

L = 18.0
d = tempfile.mkdtemp()


def system():
    rng = random.Random(39)
    atoms, bonds = [], []
    for c in range(8):
        base = ((c % 2) * 9.0 + 2.0, ((c // 2) % 2) * 9.0 + 2.0, (c // 4) * 9.0 + 2.0)
        for k in range(5):  # an all-trans zigzag (bonds 1.5, angles 109.5°), each atom moved ≤ 0.1
            p = [base[0] + 1.2247 * k, base[1] + 0.866 * (k % 2), base[2]]
            p = [a + rng.uniform(-0.1, 0.1) for a in p]
            if k > 0:
                bonds.append((len(atoms) - 1, len(atoms)))
            q = [0.5, -0.25, -0.5, 0.25, 0.0][k] * (1 if c % 2 == 0 else -1)
            atoms.append((c + 1, 1 + (k % 2), q, [a % L for a in p]))
    return atoms, bonds


def write_data(path, atoms, bonds):
    with open(path, 'w') as f:
        f.write("charged chains for tests/test_coulomb.cpp (tools/lammps_coulomb_reference.py)\n\n")
        f.write(f"{len(atoms)} atoms\n{len(bonds)} bonds\n2 atom types\n1 bond types\n")
        f.write(f"0 {L!r} xlo xhi\n0 {L!r} ylo yhi\n0 {L!r} zlo zhi\n\nMasses\n\n1 12.011\n2 15.999\n\n")
        f.write("Atoms # full\n\n")
        for k, (mol, t, q, p) in enumerate(atoms):
            f.write(f"{k + 1} {mol} {t} {q!r} {p[0]!r} {p[1]!r} {p[2]!r} 0 0 0\n")
        f.write("\nBonds\n\n")
        for k, (i, j) in enumerate(bonds):
            f.write(f"{k + 1} 1 {i + 1} {j + 1}\n")


CASES = [
    ("coul/cut", "coul/cut 8.0", ["* *"], ""),
    ("coul/debye", "coul/debye 0.2 8.0", ["* *"], ""),
    ("lj/cut/coul/cut", "lj/cut/coul/cut 7.0 8.0", ["1 1 0.1 3.0", "2 2 0.2 3.4"], ""),
    ("lj/cut/coul/cut tail", "lj/cut/coul/cut 7.0 8.0", ["1 1 0.1 3.0", "2 2 0.2 3.4"], "pair_modify tail yes\n"),
    ("lj/cut/coul/debye shift", "lj/cut/coul/debye 0.2 7.0 8.0", ["1 1 0.1 3.0", "2 2 0.2 3.4"],
     "pair_modify shift yes\n"),
    ("coul/long", "coul/long 8.0", ["* *"], "long"),
    ("lj/cut/coul/long", "lj/cut/coul/long 7.0 8.0", ["1 1 0.1 3.0", "2 2 0.2 3.4"], "long"),
    ("lj/charmm/coul/long", "lj/charmm/coul/long 6.0 7.0 8.0", ["1 1 0.1 3.0 0.05 2.8", "2 2 0.2 3.4 0.1 3.2"],
     "long"),
]


def run(case, data):
    name, style, coeffs, extra = case
    long = extra == "long"
    inp = (f"units real\natom_style full\nboundary p p p\nread_data {data}\n"
           "special_bonds lj 0.0 0.5 0.7 coul 0.0 0.3 0.8333333\n"
           f"pair_style {style}\n" + "".join(f"pair_coeff {c}\n" for c in coeffs) +
           ("pair_modify table 0\nkspace_style ewald 1.0e-6\nkspace_modify gewald 0.28\n" if long else extra) +
           "bond_style zero\nbond_coeff *\nneighbor 0.3 bin\ncompute pp all pressure NULL pair\n"
           "thermo_style custom step evdwl ecoul elong c_pp vol\nthermo_modify norm no format float %.17g\n"
           f"dump d all custom 1 {d}/f.dump id fx fy fz\ndump_modify d format float %.17g sort id\nrun 0\n")
    open(f'{d}/in.c', 'w').write(inp)
    out = subprocess.run(['lmp', '-in', f'{d}/in.c', '-log', 'none', '-echo', 'none'], capture_output=True,
                         text=True).stdout
    lines = out.splitlines()
    k = next((i for i, l in enumerate(lines) if l.split()[:3] == ['Step', 'E_vdwl', 'E_coul']), None)
    if k is None:
        print(out[-2000:])
        sys.exit(1)
    _, evdwl, ecoul, elong, press, vol = lines[k + 1].split()
    nktv2p = 68568.415
    w = 3.0 * float(vol) * float(press) / nktv2p
    forces = {}
    dump = open(f'{d}/f.dump').read().splitlines()
    start = dump.index(next(l for l in dump if l.startswith('ITEM: ATOMS'))) + 1
    for l in dump[start:]:
        i, fx, fy, fz = l.split()
        forces[int(i)] = (fx, fy, fz)
    return evdwl, ecoul, repr(w), forces


if __name__ == '__main__':
    atoms, bonds = system()
    data = f'{d}/c.data'
    write_data(data, atoms, bonds)
    if len(sys.argv) == 3 and sys.argv[1] == '--write-data':
        write_data(sys.argv[2], atoms, bonds)
    for case in CASES:
        evdwl, ecoul, w, forces = run(case, data)
        row = f'{{"{case[0]}", {evdwl}, {ecoul}, {w}'
        if case[3] != "long":
            row += ', {' + ', '.join('{' + ', '.join(forces[i]) + '}' for i in (1, 7, 23)) + '}'
        print(row + '},')
