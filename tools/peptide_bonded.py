#!/usr/bin/env python3
# The bonded part of LAMMPS's peptide example (examples/peptide/data.peptide: a solvated 5-mer,
# CHARMM: bond harmonic, angle charmm, dihedral charmm, improper harmonic) as inputs/peptide.data:
# the peptide's atoms (types 1-12, no water), every bond, angle, dihedral and improper among them,
# and every "… Coeffs" section as it is. Its charges are set to 0 (the bonded part alone: its
# LAMMPS reference has no Coulomb); the title line says so. The whole example: tools/peptide_deck.py.
#     /usr/bin/python3 tools/peptide_bonded.py [/usr/share/lammps/examples/peptide/data.peptide]
import os, sys

src = sys.argv[1] if len(sys.argv) > 1 else '/usr/share/lammps/examples/peptide/data.peptide'
out = os.path.join(os.path.dirname(os.path.abspath(__file__)), '..', 'inputs', 'peptide.data')
lines = open(src).read().splitlines()
sections, name, header = {}, None, []
KNOWN = ('Masses', 'Atoms', 'Velocities', 'Bonds', 'Angles', 'Dihedrals', 'Impropers')
for line in lines[1:]:
    head = line.split('#')[0].strip()
    if head in KNOWN or head.endswith('Coeffs'):
        name = head
        sections[name] = []
    elif name is None:
        header.append(line)
    elif line.strip():
        sections[name].append(line)
atoms = [l.split() for l in sections['Atoms'] if int(l.split()[2]) <= 12]
keep = {int(a[0]) for a in atoms}
counts = {'atoms': len(atoms)}
topology = {}
for kind in ('Bonds', 'Angles', 'Dihedrals', 'Impropers'):
    rows = [l.split() for l in sections[kind] if all(int(i) in keep for i in l.split()[2:])]
    topology[kind] = rows
    counts[kind.lower()] = len(rows)
with open(out, 'w') as f:
    f.write('LAMMPS peptide example (data.peptide), its bonded part: the peptide alone, charges set to 0 '
            '(tools/peptide_bonded.py)\n\n')
    for l in header[next(k for k, l in enumerate(header) if l.strip()):]:  # the header, its counts those kept
        words = l.split()
        if len(words) == 2 and words[1] in counts:
            l = f'{counts[words[1]]} {words[1]}'
        f.write(l.strip() + '\n')
    for sec in [s for s in sections if s.endswith('Coeffs') or s == 'Masses']:
        f.write(f'\n{sec}\n\n' + '\n'.join(l.strip() for l in sections[sec]) + '\n')
    f.write('\nAtoms # full\n\n')
    for a in atoms:
        a[3] = '0.0'
        f.write(' '.join(a) + '\n')
    f.write('\nVelocities\n\n')
    for l in sections['Velocities']:
        if int(l.split()[0]) in keep:
            f.write(' '.join(l.split()) + '\n')
    for kind, rows in topology.items():
        f.write(f'\n{kind}\n\n')
        for k, r in enumerate(rows, 1):
            f.write(' '.join([str(k)] + r[1:]) + '\n')
print(out, counts)
