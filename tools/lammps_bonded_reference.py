#!/usr/bin/env python3
# LAMMPS's energies and forces on the small molecules of tests/data/lammps_bonded/ (one data file
# per case): the reference numbers of tests/test_impropers.cpp (LammpsReference.*), written next to
# each data file as CASE.ref. Needs `lmp` on PATH; the tests do not (the .ref files are committed).
# Each .ref names the command and repeats the LAMMPS input it came from.
#     /usr/bin/python3 tools/lammps_bonded_reference.py
import os, re, subprocess, sys, tempfile

HERE = os.path.join(os.path.dirname(os.path.abspath(__file__)), '..', 'tests', 'data', 'lammps_bonded')
ZERO_PAIR = ('pair_style zero 5.0\n', 'pair_coeff * *\n')
# lj/charmm/coul/charmm for its 1-4 coefficients (eps sigma eps14 sigma14 per type, mixed
# arithmetically); its cutoff 1.1 Å is below every distance, so only the dihedrals' 1-4 pairs count.
CHARMM_PAIR = ('pair_style lj/charmm/coul/charmm 1.0 1.1\n',
               'pair_coeff 1 1 0.11 3.5636 0.01 3.3854\n'
               'pair_coeff 2 2 0.08 3.67 0.055 3.2\n'
               'pair_coeff 3 3 0.1521 3.1506 0.12 3.0\n'
               'pair_coeff 4 4 0.2 3.296 0.2 3.296\n')
# Per case: the pair style and the bonded styles (before read_data, so that its Coeffs sections are
# read as theirs), and the pair coefficients (after it).
CASES = {
    'improper_harmonic': (ZERO_PAIR[0] + 'improper_style harmonic\n', ZERO_PAIR[1]),
    'improper_cvff': (ZERO_PAIR[0] + 'improper_style cvff\n', ZERO_PAIR[1]),
    'improper_umbrella': (ZERO_PAIR[0] + 'improper_style umbrella\n', ZERO_PAIR[1]),
    'angle_charmm': (ZERO_PAIR[0] + 'bond_style harmonic\nangle_style charmm\n', ZERO_PAIR[1]),
    'angle_harmonic': (ZERO_PAIR[0] + 'bond_style harmonic\nangle_style harmonic\n', ZERO_PAIR[1]),
    'dihedral_charmm': (CHARMM_PAIR[0] + 'dihedral_style charmm\n', CHARMM_PAIR[1]),
    'dihedral_charmm_q': (CHARMM_PAIR[0] + 'dihedral_style charmm\n', CHARMM_PAIR[1]),
    # The bonded part of the peptide example (inputs/peptide.data, its Pair Coeffs' 1-4 columns).
    'peptide': ('pair_style lj/charmm/coul/charmm 1.0 1.1\nbond_style harmonic\nangle_style charmm\n'
                'dihedral_style charmm\nimproper_style harmonic\n', ''),
}
# Where a case's data file is, when not tests/data/lammps_bonded/CASE.data.
DATA = {'peptide': os.path.join(HERE, '..', '..', '..', 'inputs', 'peptide.data')}
COLUMNS = ['pe', 'ebond', 'eangle', 'edihed', 'eimp', 'evdwl', 'ecoul']


def main():
    version = subprocess.run(['lmp', '-h'], capture_output=True, text=True).stdout.splitlines()
    version = next((l.strip() for l in version if 'Large-scale' in l), 'LAMMPS')
    tmp = tempfile.mkdtemp()
    for case, (styles, pair_coeffs) in CASES.items():
        data = os.path.normpath(DATA.get(case, os.path.join(HERE, case + '.data')))
        forces = os.path.join(tmp, case + '.forces')
        inp = ('units real\natom_style full\nboundary f f f\n' + styles + f'read_data {data}\n' + pair_coeffs +
               'special_bonds lj/coul 0.0 0.0 0.0\n'
               'thermo_style custom step ' + ' '.join(COLUMNS) + '\n'
               'thermo_modify norm no format float %.17g\nrun 0\n'
               f'write_dump all custom {forces} id fx fy fz modify format float %.17g sort id\n')
        out = subprocess.run(['lmp', '-log', 'none', '-echo', 'none', '-nocite'], input=inp, capture_output=True,
                             text=True).stdout
        lines = out.splitlines()
        k = next((i for i, l in enumerate(lines) if l.split()[:1] == ['Step']), None)
        if k is None:
            sys.exit(f'{case}: no thermo output\n' + out[-2000:])
        energies = lines[k + 1].split()[1:]
        rows = [l.split() for l in open(forces).read().splitlines()[9:]]
        with open(os.path.join(HERE, case + '.ref'), 'w') as f:
            f.write(f'# LAMMPS ({version}) on {os.path.basename(data)}: made by /usr/bin/python3 tools/lammps_bonded_reference.py\n')
            f.write('# with the input (data file path shortened):\n')
            for l in inp.replace(data, os.path.basename(data)).replace(forces, case + '.forces').splitlines():
                f.write('#   ' + l + '\n')
            f.write('# energies (kcal/mol): ' + ' '.join(COLUMNS) + '\n')
            f.write(' '.join(energies) + '\n')
            f.write('# forces (kcal/mol/A): id fx fy fz\n')
            for r in rows:
                f.write(' '.join(r) + '\n')
        print(case, ' '.join(energies))


if __name__ == '__main__':
    main()
