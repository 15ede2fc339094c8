#!/usr/bin/python3
"""tools/analyze.py against known answers (run by ctest on Debian's python3):

    /usr/bin/python3 tests/test_analyze.py PATH/TO/stiffmd

Synthetic runs (a LAMMPS data file and an extended XYZ trajectory written here, in the formats
stiffmd writes) where exact answers need them: freely jointed chains (<R^2> = n b^2,
<Rg^2> = b^2 n (n + 2) / (6 (n + 1))), rotating and drifting rigid rods (Rg^2 = b^2 (N^2 - 1) / 12,
C(t) = cos(omega t), g3 = <V^2> t^2), regular-polygon rings (Rg = radius, diameter = 2 radius), a
helix and a planar zigzag (angle and torsion peaks), an ideal gas (g(r) = 1 within Poisson noise).
A real `stiffmd run` of free particles: g1 = <v^2> t^2, read from the XYZ and from the H5MD file.
"""
import csv
import io
import os
import subprocess
import sys
import tempfile
from contextlib import redirect_stdout

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
from checklist import finish, test  # noqa: E402  (tests/ is the script's directory)
sys.path.insert(0, os.path.join(ROOT, "tools"))
import analyze  # noqa: E402
from ase import Atoms  # noqa: E402
from ase.io import write as ase_write  # noqa: E402

EXE = sys.argv[1] if len(sys.argv) > 1 else None


# ---------------------------------------------------------------- synthetic runs

def write_run(d, x, times, molecules, bonds, masses=None, box=None):
    """x [F][N][3]; molecules: molecule id per atom; bonds: 0-based pairs; box: edge lengths or None
    (open). Writes d/final.data (atom_style bond, as stiffmd writes) and d/trajectory.xyz."""
    os.makedirs(d, exist_ok=True)
    f_, n, _ = x.shape
    masses = np.ones(n) if masses is None else masses
    types = {m: k + 1 for k, m in enumerate(sorted(set(masses)))}
    lo, hi = (np.zeros(3), np.asarray(box)) if box is not None else (x.min(axis=(0, 1)) - 1, x.max(axis=(0, 1)) + 1)
    with open(os.path.join(d, "final.data"), "w") as f:
        f.write(f"synthetic\n\n{n} atoms\n{len(bonds)} bonds\n{len(types)} atom types\n1 bond types\n\n")
        for k, a in enumerate("xyz"):
            f.write(f"{lo[k]:.10g} {hi[k]:.10g} {a}lo {a}hi\n")
        f.write("\nMasses\n\n" + "".join(f"{t} {m:.10g}\n" for m, t in types.items()))
        f.write("\nAtoms # bond\n\n")
        for i in range(n):
            f.write(f"{i + 1} {molecules[i]} {types[masses[i]]} {x[-1, i, 0]:.10g} {x[-1, i, 1]:.10g} {x[-1, i, 2]:.10g}\n")
        if bonds:
            f.write("\nBonds\n\n" + "".join(f"{k + 1} 1 {i + 1} {j + 1}\n" for k, (i, j) in enumerate(bonds)))
    frames = []
    for k in range(f_):
        a = Atoms("C" * n, positions=x[k], cell=np.diag(box) if box is not None else None, pbc=box is not None)
        a.info["time"] = float(times[k])
        frames.append(a)
    ase_write(os.path.join(d, "trajectory.xyz"), frames, format="extxyz")


def chains_topology(n_chains, beads, ring=False):
    molecules = np.repeat(np.arange(1, n_chains + 1), beads)
    bonds = []
    for c in range(n_chains):
        first = c * beads
        bonds += [(first + i, first + i + 1) for i in range(beads - 1)]
        if ring:
            bonds.append((first + beads - 1, first))
    return molecules, bonds


def run_tool(d, *args):
    """Runs the tool's main() on d; returns (exit code, stdout)."""
    out = io.StringIO()
    with redirect_stdout(out):
        code = analyze.main([d, *args])
    return code, out.getvalue()


def read_csv(path):
    with open(path) as f:
        rows = list(csv.DictReader(f))
    return {k: np.array([float(r[k]) if r[k] else np.nan for r in rows]) if k not in ("kind",) else [r[k] for r in rows]
            for k in rows[0]}


def random_unit_vectors(rng, shape):
    v = rng.normal(size=shape + (3,))
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


# ---------------------------------------------------------------- known answers

def ideal_chain_statistics():
    """Freely jointed chains, every frame an independent sample: <R^2> = n b^2 and
    <Rg^2> = b^2 n (n + 2) / (6 (n + 1)) within 4 standard errors."""
    rng = np.random.default_rng(1)
    chains, n, b, frames = 300, 10, 1.3, 10
    steps = b * random_unit_vectors(rng, (frames, chains, n))
    x = np.concatenate([np.zeros((frames, chains, 1, 3)), np.cumsum(steps, axis=2)], axis=2)
    x += rng.uniform(0, 50, size=(frames, chains, 1, 3))  # chains anywhere
    x = x.reshape(frames, chains * (n + 1), 3)
    with tempfile.TemporaryDirectory() as d:
        write_run(d, x, np.arange(frames) * 0.5, *chains_topology(chains, n + 1))
        code, out = run_tool(d)
        assert code == 0, out
        per_chain = read_csv(os.path.join(d, "analysis", "chains.csv"))
        assert per_chain["kind"] == ["linear"] * chains
        # Every (frame, chain) is an independent sample: recompute them to get the standard error.
        r2 = np.sum((x.reshape(frames, chains, n + 1, 3)[:, :, -1] - x.reshape(frames, chains, n + 1, 3)[:, :, 0]) ** 2,
                    axis=-1)
        se_r2 = r2.std(ddof=1) / np.sqrt(r2.size)
        r2_tool = per_chain["r2_mean"].mean()
        assert abs(r2_tool - r2.mean()) < 1e-6 * r2.mean(), (r2_tool, r2.mean())  # the tool's own sum
        assert abs(r2_tool - n * b * b) < 4 * se_r2, (r2_tool, n * b * b, se_r2)
        rg2_exact = b * b * n * (n + 2) / (6 * (n + 1))
        rg2_tool = per_chain["rg2_mean"].mean()
        assert abs(rg2_tool - rg2_exact) < 4 * se_r2 / 6, (rg2_tool, rg2_exact)
        assert "linear chains: 300 of 11 beads" in out, out


def rotating_rods():
    """Straight rods of N beads (spacing b) spinning at omega about their centre while drifting at
    V_k: Rg^2 = b^2 (N^2 - 1) / 12, R^2 = ((N - 1) b)^2 in every frame, C(t) = cos(omega t),
    g3(t) = <V^2> t^2. A last frame off the time grid is left out of the time correlations."""
    rng = np.random.default_rng(2)
    rods, beads, b, omega, dt, frames = 6, 8, 0.7, 0.3, 0.5, 16
    times = np.append(np.arange(frames) * dt, frames * dt - 0.2)  # + an off-grid final frame
    velocity = rng.normal(size=(rods, 3))
    centre0 = rng.uniform(0, 30, size=(rods, 3))
    s = (np.arange(beads) - (beads - 1) / 2) * b
    x = np.empty((len(times), rods * beads, 3))
    for k, t in enumerate(times):
        for r in range(rods):
            direction = np.array([np.cos(omega * t), np.sin(omega * t), 0.0])
            x[k, r * beads:(r + 1) * beads] = centre0[r] + velocity[r] * t + s[:, None] * direction
    with tempfile.TemporaryDirectory() as d:
        write_run(d, x, times, *chains_topology(rods, beads), masses=np.full(rods * beads, 2.0))
        code, out = run_tool(d)
        assert code == 0, out
        size = read_csv(os.path.join(d, "analysis", "size_vs_time.csv"))
        assert len(size["time"]) == frames + 1
        assert np.allclose(size["rg2_mean"], b * b * (beads ** 2 - 1) / 12, rtol=1e-6), size["rg2_mean"]
        assert np.allclose(size["r2_mean"], ((beads - 1) * b) ** 2, rtol=1e-6)
        msd = read_csv(os.path.join(d, "analysis", "msd.csv"))
        assert np.allclose(msd["time"], np.arange(frames) * dt), msd["time"]  # the off-grid frame left out
        v2 = np.mean(np.sum(velocity ** 2, axis=1))
        assert np.allclose(msd["g3"], v2 * msd["time"] ** 2, rtol=1e-6, atol=1e-9), (msd["g3"], v2 * msd["time"] ** 2)
        acf = read_csv(os.path.join(d, "analysis", "ree_autocorrelation.csv"))
        assert np.allclose(acf["c"], np.cos(omega * acf["time"]), atol=1e-6), acf["c"]
        angles = read_csv(os.path.join(d, "analysis", "angles.csv"))
        assert angles["degrees"][np.argmax(angles["p"])] > 179, "straight rods: bond angles 180"


def ring_polygons():
    """Rings of N beads on circles of radius rho: Rg = rho, diameter = 2 rho."""
    rng = np.random.default_rng(3)
    rings, beads, rho = 5, 12, 2.0
    phase = 2 * np.pi * np.arange(beads) / beads
    x = []
    for r in range(rings):
        q, _ = np.linalg.qr(rng.normal(size=(3, 3)))  # a random orientation
        circle = rho * np.column_stack([np.cos(phase), np.sin(phase), np.zeros(beads)])
        x.append(circle @ q.T + rng.uniform(0, 20, size=3))
    x = np.array([np.concatenate(x)] * 3)
    with tempfile.TemporaryDirectory() as d:
        write_run(d, x, [0, 1, 2], *chains_topology(rings, beads, ring=True))
        code, out = run_tool(d)
        assert code == 0, out
        per_chain = read_csv(os.path.join(d, "analysis", "chains.csv"))
        assert per_chain["kind"] == ["ring"] * rings
        assert np.allclose(per_chain["rg2_mean"], rho ** 2, rtol=1e-6)
        assert np.allclose(per_chain["r2_mean"], (2 * rho) ** 2, rtol=1e-6)
        angles = read_csv(os.path.join(d, "analysis", "angles.csv"))
        interior = 180 - 360 / beads
        assert abs(angles["degrees"][np.argmax(angles["p"])] - interior) <= 0.5, interior


def chain_with_known_angles(theta, phi, beads, b=1.0):
    """Positions of a chain with every bond angle theta and every torsion phi (degrees; NeRF)."""
    th, ph = np.radians(theta), np.radians(phi)
    x = [np.zeros(3), np.array([b, 0, 0]), np.array([b - b * np.cos(th), b * np.sin(th), 0])]
    while len(x) < beads:
        a, bb, c = x[-3], x[-2], x[-1]
        bc = (c - bb) / np.linalg.norm(c - bb)
        n = np.cross(bb - a, bc)
        n /= np.linalg.norm(n)
        m = np.cross(n, bc)
        d = np.array([-b * np.cos(th), b * np.sin(th) * np.cos(ph), b * np.sin(th) * np.sin(ph)])
        x.append(c + d[0] * bc + d[1] * m + d[2] * n)
    return np.array(x)


def torsion(a, b, c, d):
    """IUPAC torsion angle (degrees, 180 = trans), written out independently of the tool."""
    b0, b1, b2 = a - b, c - b, d - c
    b1 /= np.linalg.norm(b1)
    v, w = b0 - np.dot(b0, b1) * b1, b2 - np.dot(b2, b1) * b1
    return np.degrees(np.arctan2(np.dot(np.cross(b1, v), w), np.dot(v, w)))


def angle_and_torsion_peaks():
    """A helix (theta = 112, phi = 65) and a planar zigzag (theta = 120, phi = 180): the angle and
    torsion histograms peak in the bins holding those values."""
    for theta, phi in ((112.0, 65.0), (120.0, 180.0)):
        x = chain_with_known_angles(theta, phi, 20)
        assert abs(abs(torsion(*x[:4])) - phi) < 1e-9 and abs(torsion(*x[:4]) - torsion(*x[5:9])) < 1e-9
        expected_phi = torsion(*x[:4])
        with tempfile.TemporaryDirectory() as d:
            write_run(d, np.array([x, x]), [0, 1], *chains_topology(1, 20))
            code, out = run_tool(d)
            assert code == 0, out
            a = read_csv(os.path.join(d, "analysis", "angles.csv"))
            t = read_csv(os.path.join(d, "analysis", "dihedrals.csv"))
            peak_a, peak_t = a["degrees"][np.argmax(a["p"])], t["degrees"][np.argmax(t["p"])]
            assert abs(peak_a - theta) <= 0.5, (peak_a, theta)
            if abs(expected_phi) > 179.5:
                assert abs(abs(peak_t) - 180) <= 1.0, (peak_t, expected_phi)
            else:
                assert abs(peak_t - expected_phi) <= 0.5, (peak_t, expected_phi)
            assert np.isclose(np.sum(a["p"]) * 1.0, 1.0) and np.isclose(np.sum(t["p"]) * 2.0, 1.0)


def ideal_gas_rdf():
    """Uniform random particles in a periodic cube: g(r) = 1 in every bin within Poisson noise
    (chi^2 per bin ~ 1), total and intermolecular alike (every particle its own molecule)."""
    rng = np.random.default_rng(4)
    n, L, frames, bins = 500, 10.0, 8, 50
    x = rng.uniform(0, L, size=(frames, n, 3))
    with tempfile.TemporaryDirectory() as d:
        write_run(d, x, np.arange(frames), np.arange(1, n + 1), [], box=[L, L, L])
        code, out = run_tool(d, "--rdf-bins", str(bins))
        assert code == 0, out
        g = read_csv(os.path.join(d, "analysis", "rdf.csv"))
        rmax = L / 2
        assert abs(g["r"][-1] - rmax * (1 - 0.5 / bins)) < 1e-3 * rmax, g["r"][-1]
        edges = np.linspace(0, rmax, bins + 1)
        shell = 4 / 3 * np.pi * (edges[1:] ** 3 - edges[:-1] ** 3)
        expected_pairs = frames * n * (n - 1) / 2 * shell / L ** 3  # unordered pairs per bin
        z = (g["g_total"] - 1) * np.sqrt(expected_pairs)
        assert np.mean(z ** 2) < 1.6 and np.max(np.abs(z)) < 4.5, (np.mean(z ** 2), np.max(np.abs(z)))
        assert np.allclose(g["g_inter"], g["g_total"]), "single particles: intermolecular = total"


def ballistic_stiffmd_run():
    """Free particles in a periodic box run by stiffmd (velocity Verlet is exact for them):
    g1(t) = <|v|^2> t^2, from the run's own files found by default (final.data, trajectory.xyz),
    and the same from the H5MD file (wrapped positions unwrapped with its image element)."""
    rng = np.random.default_rng(5)
    n, L = 24, 4.0
    v = rng.normal(size=(n, 3))
    v -= v.mean(axis=0)
    deck = ["[box]", "periodic = true", f"lengths = [{L}, {L}, {L}]", "", "[types.A]", "mass = 1.0", ""]
    for i in range(n):
        p = rng.uniform(0, L, 3)
        deck += ["[[particles]]", 'type = "A"', f"position = [{p[0]!r}, {p[1]!r}, {p[2]!r}]",
                 f"velocity = [{v[i, 0]!r}, {v[i, 1]!r}, {v[i, 2]!r}]", ""]
    deck += ["[integrator]", 'method = "velocity-verlet"', "h = 0.01", "", "[run]", "t_end = 3.03", "",
             "[output]", 'xyz = "trajectory.xyz"', "xyz_interval = 0.25", 'lammps_data = "final.data"',
             'h5md = "traj.h5md"', "h5md_interval = 0.25", "thermo_interval = 0.25"]
    with tempfile.TemporaryDirectory() as d:
        with open(os.path.join(d, "free.toml"), "w") as f:
            f.write("\n".join(deck) + "\n")
        subprocess.run([EXE, "run", os.path.join(d, "free.toml"), "-o", os.path.join(d, "run"), "--no-progress"],
                       check=True, capture_output=True)
        v2 = np.mean(np.sum(v ** 2, axis=1))
        for args in ([], ["--trajectory", os.path.join(d, "run", "traj.h5md"), "-o", os.path.join(d, "h5")]):
            code, out = run_tool(os.path.join(d, "run"), *args)
            assert code == 0, out
            msd = read_csv(os.path.join(args[-1] if args else os.path.join(d, "run", "analysis"), "msd.csv"))
            assert len(msd["time"]) == 13 and abs(msd["time"][-1] - 3.0) < 1e-9, msd["time"]
            assert np.allclose(msd["g1"], v2 * msd["time"] ** 2, rtol=1e-6, atol=1e-9), (args, msd["g1"] / (v2 * msd["time"] ** 2))
            assert "g3" not in msd  # no chains
            g = read_csv(os.path.join(args[-1] if args else os.path.join(d, "run", "analysis"), "rdf.csv"))
            assert len(g["r"]) == 100 and g["r"][-1] < L / 2


def bad_inputs_exit_2():
    with tempfile.TemporaryDirectory() as d:
        proc = subprocess.run(["/usr/bin/python3", os.path.join(ROOT, "tools", "analyze.py"), d],
                              capture_output=True, text=True)
        assert proc.returncode == 2, proc
        assert proc.stderr.strip().count("\n") == 0 and "no topology" in proc.stderr, proc.stderr


for t in (ideal_chain_statistics, rotating_rods, ring_polygons, angle_and_torsion_peaks, ideal_gas_rdf,
          ballistic_stiffmd_run, bad_inputs_exit_2):
    test(t)
finish()
