#!/usr/bin/env python3
# SPC/E water (inputs/spce_water.data, 512 rigid molecules) in stiffmd and in LAMMPS from the same
# state: LAMMPS equilibrates it (Langevin, 300 K, fix rattle b 1 a 1, pppm 1e-5, 2 fs, --equil ps)
# and writes it out; then both run NVE for --nve ps from that state at 2 fs with the same styles
# (lj/cut/coul/long 10 Å, pppm 1e-5, rigid water; LAMMPS's fix rattle after the integrators, as
# it requires) and the tool reports each engine's energy drift
# (the slope of a line fitted to E_total(t), per atom and per ns) and the O–O radial distribution of
# the NVE trajectories (frames every 0.2 ps), with its statistical error from 5 blocks.
#     /usr/bin/python3 tools/spce_compare.py [--equil 10] [--nve 10] [--stiffmd build/stiffmd]
# Needs `lmp` (tools/setup.sh --bench). docs/electrostatics.md, "SPC/E water", has the numbers.
import argparse, os, subprocess, tempfile, time
import numpy as np

from spce_lammps import COEFFS, STYLES  # tools/ is the script's directory

here = os.path.dirname(os.path.abspath(__file__))
root = os.path.normpath(os.path.join(here, '..'))
ap = argparse.ArgumentParser()
ap.add_argument('--equil', type=float, default=10.0)
ap.add_argument('--nve', type=float, default=10.0)
ap.add_argument('--stiffmd', default=os.path.join(root, 'build', 'stiffmd'))
ap.add_argument('--keep', default=None, help='a directory to keep the runs in')
a = ap.parse_args()
dt = 2.0
n_equil, n_nve = int(a.equil * 1000 / dt), int(a.nve * 1000 / dt)
every = 100  # steps between frames and energy samples (0.2 ps)
work = a.keep or tempfile.mkdtemp(prefix='spce_')
os.makedirs(work, exist_ok=True)
env = dict(os.environ, OMP_NUM_THREADS='1')

equil = STYLES + f"read_data {os.path.join(root, 'inputs', 'spce_water.data')}\n" + COEFFS + f"""velocity all create 300.0 4928459 mom yes rot yes dist gaussian
fix i all nve
fix t all langevin 300.0 300.0 100.0 91
fix r all rattle 1e-10 200 0 b 1 a 1
run {n_equil}
write_data equilibrated.data nocoeff
"""
nve = STYLES + "read_data equilibrated.data\n" + COEFFS + f"""fix i all nve
fix r all rattle 1e-10 200 0 b 1 a 1
thermo_style custom step etotal pe ke temp
thermo_modify format float %.12g
thermo {every}
dump d all custom {every} lammps.dump id type xu yu zu
dump_modify d sort id
run {n_nve}
"""
def lmp(text, name):
    open(os.path.join(work, name), 'w').write(text)
    t = time.time()
    out = subprocess.run(['lmp', '-in', name, '-log', name + '.log'], cwd=work, capture_output=True, text=True,
                         env=env)
    if out.returncode: raise SystemExit(out.stdout[-2000:] + out.stderr[-2000:])
    return out.stdout, time.time() - t

print(f"working in {work}")
lmp(equil, 'in.equil')
log, t_lmp = lmp(nve, 'in.nve')
rows = [l.split() for l in log.splitlines() if l.split() and l.split()[0].isdigit() and len(l.split()) == 5]
lmp_t = np.array([float(r[0]) * dt for r in rows]); lmp_e = np.array([float(r[1]) for r in rows])

deck = open(os.path.join(root, 'inputs', 'spce_water.toml')).read()
deck = deck.split('[thermostat]')[0] + '[integrator]' + deck.split('[integrator]')[1]  # NVE: no [thermostat]
deck = deck.replace('lammps_data = "spce_water.data"', 'lammps_data = "equilibrated.data"')
deck = deck.replace('t_end = 2000.0', f't_end = {n_nve * dt}').replace('thermo_interval = 100.0', f'thermo_interval = {every * dt}\nxyz_interval = {every * dt}')
open(os.path.join(work, 'nve.toml'), 'w').write(deck)
t = time.time()
subprocess.run([a.stiffmd, 'run', 'nve.toml', '-o', 'stiffmd', '-q', '--no-progress'], cwd=work, check=True, env=env)
t_st = time.time() - t
thermo = np.genfromtxt(os.path.join(work, 'stiffmd', 'thermo.csv'), delimiter=',', names=True)
st_t, st_e = thermo['time'], thermo['total']  # kcal/mol, the whole system's
n = 1536

def drift(t, e):  # kcal/mol per atom per ns
    return np.polyfit(t, e, 1)[0] / n * 1e6

def frames_lammps(path):
    lines = open(path).read().splitlines()
    out, k = [], 0
    while k < len(lines):
        if lines[k].startswith('ITEM: NUMBER OF ATOMS'):
            m = int(lines[k + 1]); k += 2
        elif lines[k].startswith('ITEM: BOX BOUNDS'):
            box = [float(lines[k + 1 + d].split()[1]) - float(lines[k + 1 + d].split()[0]) for d in range(3)]; k += 4
        elif lines[k].startswith('ITEM: ATOMS'):
            rows = np.array([l.split() for l in lines[k + 1:k + 1 + m]], dtype=float); k += 1 + m
            out.append((rows[rows[:, 1] == 1][:, 2:5], np.array(box)))
        else:
            k += 1
    return out

def frames_xyz(path, box):
    lines = open(path).read().splitlines()
    out, k = [], 0
    while k < len(lines):
        m = int(lines[k]); atoms = lines[k + 2:k + 2 + m]; k += 2 + m
        xyz = np.array([l.split()[1:4] for l in atoms if l.split()[0] == 'O'], dtype=float)
        out.append((xyz, box))
    return out

def rdf(frames, rmax=8.0, bins=80):
    edges = np.linspace(0, rmax, bins + 1)
    blocks = np.array_split(np.arange(len(frames)), 5)
    g = []
    for b in blocks:
        h = np.zeros(bins)
        for f in b:
            x, L = frames[f]
            d = x[:, None, :] - x[None, :, :]
            d -= L * np.round(d / L)
            r = np.sqrt((d ** 2).sum(-1))[np.triu_indices(len(x), 1)]
            h += np.histogram(r, edges)[0]
        rho = len(frames[0][0]) / np.prod(frames[0][1])
        shell = 4 / 3 * np.pi * (edges[1:] ** 3 - edges[:-1] ** 3)
        g.append(2 * h / (len(b) * len(frames[0][0]) * rho * shell))
    g = np.array(g)
    return 0.5 * (edges[1:] + edges[:-1]), g.mean(0), g.std(0, ddof=1) / np.sqrt(len(g))

L = np.array([float(l.split()[1]) - float(l.split()[0]) for l in open(os.path.join(work, 'equilibrated.data')) if l.strip().endswith(('xhi', 'yhi', 'zhi'))])
r, g_l, s_l = rdf(frames_lammps(os.path.join(work, 'lammps.dump'))[1:])
_, g_s, s_s = rdf(frames_xyz(os.path.join(work, 'stiffmd', 'trajectory.xyz'), L)[1:])
z = np.abs(g_s - g_l) / np.sqrt(s_l ** 2 + s_s ** 2 + 1e-30)
peak = np.argmax(g_l)
print(f"NVE {a.nve} ps at 2 fs after {a.equil} ps of Langevin (LAMMPS), 1536 atoms, pppm 1e-5, rigid (RATTLE):")
print(f"  energy drift   stiffmd {drift(st_t, st_e):+.4g}   LAMMPS {drift(lmp_t, lmp_e):+.4g}   kcal/mol per atom per ns")
print(f"  NVE wall       stiffmd {t_st:.1f} s   LAMMPS {t_lmp:.1f} s  (one core each; LAMMPS with pair_modify table 0)")
print(f"  g_OO peak      stiffmd {g_s[peak]:.3f} ± {s_s[peak]:.3f}   LAMMPS {g_l[peak]:.3f} ± {s_l[peak]:.3f}  at r = {r[peak]:.2f} Å")
print(f"  g_OO |Δ|/σ     max {z[r > 2.4].max():.2f}, mean {z[r > 2.4].mean():.2f} over r in 2.4 .. 8 Å ({(z[r > 2.4] > 3).sum()} bins over 3σ)")
