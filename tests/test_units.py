"""units = "lj" and units = "real" (README "Units", core/units.hpp).

1. The same physical system — bead-spring chains with stiff bonds, LJ, Langevin at T — once in
   reduced units (σ = ε = m = 1) and once in real units with σ = 3.4 Å, ε = 0.2381 kcal/mol,
   m = 39.948 g/mol gives the same trajectory after conversion: thermo columns (time in fs,
   energies in kcal/mol, temperature in K = kT/k_B, pressure in atm), XYZ positions and velocities
   (Å/fs), to round-off.
2. The real run's H5MD file carries `unit` attributes that MDAnalysis 2.4.2 reads and converts
   (time fs -> ps; velocities are written in Å/ps) to the same numbers.
3. Against LAMMPS (when `lmp` is installed): an argon gas in `units real` with velocities in the
   data file (Å/fs), NVE velocity Verlet, 2 fs steps: the positions, velocities, temperature (K)
   and pressure (atm) after 50 steps equal LAMMPS's.
4. A bad units value exits 2 naming the key.

usage: test_units.py STIFFMD_BINARY
"""
import csv
import math
import os
import shutil
import subprocess
import sys
import tempfile
import warnings

import numpy as np

sys.path.insert(0, os.path.dirname(__file__))
from checklist import finish, test  # noqa: E402

BIN = os.path.abspath(sys.argv[1])
TMP = tempfile.mkdtemp(prefix="stiffmd_units_")

SIGMA, EPS, MASS = 3.4, 0.2381, 39.948  # Å, kcal/mol, g/mol
KB = 0.0019872067  # kcal/(mol K), LAMMPS real
TAU_FS = 48.88821291  # fs per sqrt(g/mol Å² / (kcal/mol))
NKTV2P = 68568.415  # atm per kcal/(mol Å³)
TAU_LJ = SIGMA * math.sqrt(MASS / EPS) * TAU_FS  # the reduced time unit in fs

DECK = """
units = "{units}"
[types.bead]
mass = {m}
[[build]]
style = "linear-chains"
type = "bead"
chains = 12
beads = 6
bond_length = {l}
bond_type = "b"
density = {rho}
min_distance = {dmin}
seed = 5
[velocities]
temperature = {T}
seed = 6
[forces.bonds]
style = "stiff-harmonic"
epsilon = 0.1
bond_types.b = {{ length = {l}, alpha = {alpha} }}
[forces.lj]
style = "lj"
epsilon = {e}
sigma = {s}
cutoff = {rc}
skin = {skin}
[thermostat]
style = "langevin"
temperature = {T}
damp = {damp}
seed = 9
[integrator]
method = "impulse"
h = {h}
micro_steps = 5
[run]
t_end = {t_end}
[output]
xyz_interval = {dt_out}
xyz_velocities = true
thermo_interval = {dt_out}
h5md = "traj.h5"
h5md_interval = {dt_out}
h5md_velocity = true
"""


def deck(units, s, e, m, t):
    """The deck with lengths in s, energies in e, masses in m, times in t, temperatures in e/k_B."""
    kb = 1.0 if units == "lj" else KB
    return DECK.format(units=units, m=m, l=0.97 * s, rho=0.3 / s**3, dmin=0.8 * s, T=1.2 * e / kb,
                       alpha=1.0 * math.sqrt(e) / s, e=e, s=s, rc=2.5 * s, skin=0.3 * s, damp=1.0 * t,
                       h=0.005 * t, t_end=0.5 * t, dt_out=0.1 * t)


def run(name, text):
    d = os.path.join(TMP, name)
    os.makedirs(d, exist_ok=True)
    path = os.path.join(d, "deck.toml")
    with open(path, "w") as f:
        f.write(text)
    r = subprocess.run([BIN, "run", path, "-o", d], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    return d


def read_thermo(d):
    with open(os.path.join(d, "thermo.csv")) as f:
        rows = list(csv.DictReader(f))
    return {k: np.array([float(r[k]) for r in rows]) for k in rows[0]}


def read_xyz(path):
    """Frames of (time, positions, velocities) from an extended XYZ with velocities."""
    frames = []
    with open(path) as f:
        lines = f.read().splitlines()
    k = 0
    while k < len(lines):
        n = int(lines[k])
        comment = lines[k + 1]
        t = float(comment.split(" time=")[1].split()[0])
        data = np.array([[float(x) for x in line.split()[1:]] for line in lines[k + 2:k + 2 + n]])
        frames.append((t, data[:, 0:3], data[:, 4:7]))  # species, pos(3), masses, velo(3)
        k += 2 + n
    return frames


def close(a, b, scale, rtol=1e-8, what=""):
    a, b = np.asarray(a, float), np.asarray(b, float)
    err = np.max(np.abs(a - b)) / max(np.max(np.abs(b)), 1e-300) if b.size else 0.0
    assert err < rtol, f"{what}: max relative difference {err:.3g} (scale {scale})"


RUNS = {}


@test
def same_trajectory_in_lj_and_real_units():
    lj = run("lj", deck("lj", 1.0, 1.0, 1.0, 1.0))
    real = run("real", deck("real", SIGMA, EPS, MASS, TAU_LJ))
    RUNS["lj"], RUNS["real"] = lj, real
    a, b = read_thermo(lj), read_thermo(real)
    assert list(a) == list(b) and len(a["time"]) == 6, (list(a), len(a["time"]))
    assert np.array_equal(a["step"], b["step"])
    close(a["time"] * TAU_LJ, b["time"], "fs", 1e-12, "time (fs)")
    for col in ("kinetic", "potential_slow", "potential_stiff", "total"):
        close(a[col] * EPS, b[col], "kcal/mol", 1e-8, col)
    close(a["temperature"] * EPS / KB, b["temperature"], "K", 1e-8, "temperature (K)")
    close(a["pressure"] * EPS / SIGMA**3 * NKTV2P, b["pressure"], "atm", 1e-8, "pressure (atm)")
    for col in ("rg", "end_to_end", "max_violation"):
        close(a[col] * SIGMA, b[col], "A", 1e-7 if col == "max_violation" else 1e-9, col)
    fa, fb = read_xyz(os.path.join(lj, "trajectory.xyz")), read_xyz(os.path.join(real, "trajectory.xyz"))
    assert len(fa) == len(fb) == 6
    for (ta, xa, va), (tb, xb, vb) in zip(fa, fb):
        close(ta * TAU_LJ, tb, "fs", 1e-12, "XYZ time")
        close(xa * SIGMA, xb, "A", 1e-10, "XYZ positions")
        close(va * SIGMA / TAU_LJ, vb, "A/fs", 1e-8, "XYZ velocities (A/fs)")
    # The temperature in K is kT/k_B of the same state: a real, not a reduced, number.
    assert 100 < b["temperature"][0] < 300, b["temperature"][0]


@test
def h5md_units_read_by_mdanalysis():
    import h5py
    real, lj = RUNS["real"], RUNS["lj"]
    with h5py.File(os.path.join(real, "traj.h5"), "r") as f:
        p = f["particles/all"]
        assert p["position/value"].attrs["unit"] == "Angstrom"
        assert p["position/time"].attrs["unit"] == "fs"
        assert p["velocity/time"].attrs["unit"] == "fs"  # a hard link to position/time
        # Å/ps, MDAnalysis's own unit: its Å/fs conversion is inverted (MDAnalysis issue #5051).
        assert p["velocity/value"].attrs["unit"] == "Angstrom ps-1"
        close(p["velocity/value"][-1], read_xyz(os.path.join(real, "trajectory.xyz"))[-1][2] * 1000.0, "A/ps",
              1e-10, "H5MD velocities (A/ps)")
        assert p["box/edges/value"].attrs["unit"] == "Angstrom"
        assert f["observables/temperature/value"].attrs["unit"] == "K"
        assert f["observables/pressure/value"].attrs["unit"] == "atm"
        assert f["observables/total/value"].attrs["unit"] == "kcal mol-1"
        assert "unit" not in f["observables/alerts/value"].attrs
        t_obs = f["observables/temperature/value"][:]
    with h5py.File(os.path.join(lj, "traj.h5"), "r") as f:
        units = []
        f.visititems(lambda name, obj: units.append(name) if "unit" in obj.attrs else None)
        assert not units, units  # reduced units carry none
    close(t_obs, read_thermo(real)["temperature"], "K", 1e-10, "H5MD temperature")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        import MDAnalysis as mda
        u = mda.Universe(os.path.join(real, "trajectory.xyz"), os.path.join(real, "traj.h5"), format="H5MD")
    frames = read_xyz(os.path.join(real, "trajectory.xyz"))
    assert len(u.trajectory) == len(frames)
    for ts, (t, x, v) in zip(u.trajectory, frames):
        close(ts.time, t / 1000.0, "ps", 1e-12, "MDAnalysis time (ps)")
        close(ts.velocities, v * 1000.0, "A/ps", 1e-6, "MDAnalysis velocities (A/ps), float32")
        # Positions are wrapped into the box in H5MD, unwrapped in the XYZ.
        L = ts.dimensions[:3]
        d = ts.positions - x
        err = np.max(np.abs(d - L * np.round(d / L)))
        assert err < 1e-4 * L[0], f"MDAnalysis positions (A, float32): {err}"


ARGON = """LAMMPS data file: argon in real units
8 atoms
1 atom types
0 20 xlo xhi
0 20 ylo yhi
0 20 zlo zhi

Masses

1 39.948

Atoms # atomic

{atoms}
Velocities

{velocities}
"""


@test
def argon_in_real_units_against_lammps():
    lmp = shutil.which("lmp")
    if not lmp:
        print("  (lmp not installed: skipped)")
        return
    rng = np.random.default_rng(3)
    x = np.array([[i, j, k] for i in (0, 1) for j in (0, 1) for k in (0, 1)], float) * 10.0 + 5.0
    x += rng.uniform(-1.0, 1.0, x.shape)
    v = rng.normal(0.0, 0.005, x.shape)  # Å/fs: about 300 K for argon
    d = os.path.join(TMP, "argon")
    os.makedirs(d, exist_ok=True)
    atoms = "".join(f"{i + 1} 1 {a:.10f} {b:.10f} {c:.10f}\n" for i, (a, b, c) in enumerate(x))
    vels = "".join(f"{i + 1} {a:.10f} {b:.10f} {c:.10f}\n" for i, (a, b, c) in enumerate(v))
    with open(os.path.join(d, "argon.data"), "w") as f:
        f.write(ARGON.format(atoms=atoms, velocities=vels))
    with open(os.path.join(d, "in.argon"), "w") as f:
        f.write("units real\natom_style atomic\nread_data argon.data\n"
                "pair_style lj/cut 8.5\npair_coeff 1 1 0.2381 3.4\npair_modify shift yes\n"
                "neighbor 1.0 bin\ntimestep 2.0\nfix 1 all nve\n"
                "thermo_style custom step temp press pe ke\nthermo_modify format float %.12g\n"
                "run 50\nwrite_dump all custom final.dump id x y z vx vy vz modify format float %.12g sort id\n")
    r = subprocess.run([lmp, "-in", "in.argon", "-log", "log.lammps", "-screen", "none"], cwd=d,
                       capture_output=True, text=True)
    assert r.returncode == 0, r.stdout + r.stderr
    log = open(os.path.join(d, "log.lammps")).read().splitlines()
    k = next(i for i, line in enumerate(log) if line.split()[:2] == ["Step", "Temp"])
    lammps_last = [float(w) for w in log[k + 2].split()]  # step 50: step temp press pe ke
    dump = np.loadtxt(os.path.join(d, "final.dump"), skiprows=9)
    with open(os.path.join(d, "deck.toml"), "w") as f:
        f.write('units = "real"\n[types.Ar]\nmass = 39.948\n'
                '[import]\nlammps_data = "argon.data"\natom_types = { "1" = "Ar" }\n'
                '[forces.lj]\nstyle = "lj"\nepsilon = 0.2381\nsigma = 3.4\ncutoff = 8.5\nskin = 1.0\n'
                '[integrator]\nmethod = "velocity-verlet"\nh = 2.0\n[run]\nt_end = 100.0\n'
                '[output]\nxyz_interval = 100.0\nxyz_velocities = true\nthermo_interval = 100.0\n')
    r = subprocess.run([BIN, "run", "deck.toml", "-o", "out"], cwd=d, capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    t, xs, vs = read_xyz(os.path.join(d, "out", "trajectory.xyz"))[-1]
    assert t == 100.0, t
    L = 20.0
    dx = xs - dump[:, 1:4]
    err = np.max(np.abs(dx - L * np.round(dx / L)))
    assert err < 1e-8 * L, f"positions vs LAMMPS: max difference {err} A"
    close(vs, dump[:, 4:7], "A/fs", 1e-7, "velocities vs LAMMPS (A/fs)")
    th = read_thermo(os.path.join(d, "out"))
    # LAMMPS's temperature counts 3N − 3 degrees of freedom, as stiffmd's without external forces.
    close(th["temperature"][-1], lammps_last[1], "K", 1e-7, "temperature vs LAMMPS (K)")
    close(th["pressure"][-1], lammps_last[2], "atm", 1e-6, "pressure vs LAMMPS (atm)")
    close(th["potential_slow"][-1], lammps_last[3], "kcal/mol", 1e-7, "potential vs LAMMPS")
    close(th["kinetic"][-1], lammps_last[4], "kcal/mol", 1e-7, "kinetic vs LAMMPS")
    # The final state written as a LAMMPS data file keeps LAMMPS's velocity unit (Å/fs).
    r = subprocess.run([BIN, "run", "deck.toml", "-o", "out2", "--set", 'output.lammps_data="final.data"',
                        "--set", "run.t_end=2.0"], cwd=d, capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    lines = open(os.path.join(d, "out2", "final.data")).read().splitlines()
    k = lines.index("Velocities")
    written = np.array([[float(w) for w in line.split()[1:4]] for line in lines[k + 2:k + 2 + len(x)]])
    _, _, v1 = read_xyz(os.path.join(d, "out2", "trajectory.xyz"))[-1]
    close(written, v1, "A/fs", 1e-10, "data file velocities (A/fs)")


@test
def bad_units_value_exits_2_at_the_key():
    d = os.path.join(TMP, "bad")
    os.makedirs(d, exist_ok=True)
    path = os.path.join(d, "deck.toml")
    with open(path, "w") as f:
        f.write('units = "metal"\n' + deck("lj", 1, 1, 1, 1).split("\n", 2)[2])
    r = subprocess.run([BIN, "check", path], capture_output=True, text=True)
    assert r.returncode == 2, (r.returncode, r.stderr)
    assert f"{path}:1" in r.stderr and "units" in r.stderr and "real" in r.stderr, r.stderr
    assert len(r.stderr.strip().splitlines()) == 1, r.stderr


try:
    finish()
finally:
    if not os.environ.get("KEEP"): shutil.rmtree(TMP, ignore_errors=True)
