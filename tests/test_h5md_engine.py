#!/usr/bin/python3
"""H5MD output of real `stiffmd run`s (run by ctest on Debian's python3 with h5py, MDAnalysis):
the H5MD 1.1 layout (tests/h5md_spec.py, written from the specification), values equal to what the
XYZ trajectory says, MDAnalysis reads every frame (positions, box, time), a file killed with SIGKILL
still opens with the frames written, and restart appends exactly (also to a file of an earlier
build, whose string attributes were variable-length)."""
import os
import signal
import subprocess
import sys
import tempfile
import time
import warnings

import h5py
import numpy as np
from h5md_spec import h5md_problems

warnings.filterwarnings("ignore")
ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
from checklist import finish, test  # noqa: E402  (tests/ is the script's directory)
EXE = sys.argv[1]
P = "particles/all"


def run(deck, out, *sets, check=True):
    cmd = [EXE, "run", os.path.join(ROOT, deck), "-o", out, "--no-progress"]
    for s in sets:
        cmd += ["--set", s]
    return subprocess.run(cmd, capture_output=True, text=True, check=check)


def read_xyz(path):
    frames, times = [], []
    with open(path) as f:
        while True:
            line = f.readline()
            if not line:
                break
            n = int(line)
            comment = f.readline()
            times.append(float(comment.split("time=")[1].split()[0]))
            frames.append([[float(v) for v in f.readline().split()[1:4]] for _ in range(n)])
    return np.array(frames), np.array(times)


def assert_spec(f):
    problems = h5md_problems(f)
    assert not problems, "; ".join(problems)


def universe(top, h5):
    import MDAnalysis as mda
    return mda.Universe(top, h5, format="H5MD", convert_units=False)


def periodic_layout_values_and_mdanalysis():
    with tempfile.TemporaryDirectory() as d:
        run("tests/decks/periodic_free.toml", d, "output.h5md=traj.h5md", "output.h5md_interval=0.25",
            "output.h5md_velocity=true", "output.h5md_force=true", "output.h5md_gzip=4", "output.author=Tester")
        h5, xyz = os.path.join(d, "traj.h5md"), os.path.join(d, "traj.xyz")
        x_xyz, t_xyz = read_xyz(xyz)
        with h5py.File(h5, "r") as f:
            assert_spec(f)
            assert list(f["h5md"].attrs["version"]) == [1, 1]
            assert f["h5md/author"].attrs["name"] in ("Tester", b"Tester")
            assert f["h5md/creator"].attrs["name"] in ("stiffmd", b"stiffmd")
            pos = f[P + "/position"]
            assert pos["value"].shape == (9, 4, 3) and pos["value"].dtype == np.float64
            assert pos["step"].dtype == np.int64 and pos["time"].dtype == np.float64
            assert pos["value"].chunks is not None and pos["value"].compression == "gzip"
            assert f[P + "/velocity/value"].shape == (9, 4, 3) and f[P + "/force/value"].shape == (9, 4, 3)
            box = f[P + "/box"]
            assert int(box.attrs["dimension"]) == 3
            assert [b if isinstance(b, str) else b.decode() for b in box.attrs["boundary"]] == ["periodic", "periodic", "none"]
            edges = box["edges/value"][:]
            assert edges.shape[0] == 9
            # H5MD allows edges as a D-vector or a D×D matrix (rows = box vectors).
            first = np.diag(edges[0]) if edges.ndim == 3 else edges[0]
            assert np.allclose(first[:2], [3.0, 4.0]), edges[0]
            assert f[P + "/mass"].shape == (4,) and list(f[P + "/mass"][:]) == [1, 1, 2, 2]
            assert f[P + "/id"].shape == (4,) and f[P + "/species"].shape == (4,)
            assert np.allclose(pos["time"][:], t_xyz)
            # unwrapped = wrapped + image · L reproduces the engine's (unwrapped) positions
            img = f[P + "/image/value"][:]
            L = np.array([3.0, 4.0, 5.0])
            unwrapped = pos["value"][:] + img * L
            assert np.allclose(unwrapped[:, :, :2], x_xyz[:, :, :2], atol=1e-9)
            assert np.all(pos["value"][:, :, 0] >= -1e-12) and np.all(pos["value"][:, :, 0] < 3.0)
            assert f["observables/total/value"].shape == (9,)
            wrapped = pos["value"][:]
        u = universe(xyz, h5)
        assert len(u.trajectory) == 9
        for ts in u.trajectory:
            assert np.allclose(ts.positions, wrapped[ts.frame], atol=1e-5)
            assert abs(ts.time - t_xyz[ts.frame]) < 1e-12
            assert np.allclose(ts.dimensions[:2], [3.0, 4.0])


def pendulum_bonds_and_particles_group():
    with tempfile.TemporaryDirectory() as d:
        run("inputs/double_pendulum.toml", d, "output.h5md=traj.h5md", "run.t_end=0.5")
        with h5py.File(os.path.join(d, "traj.h5md"), "r") as f:
            assert_spec(f)
            bonds = f["connectivity/bonds"]
            assert bonds[:].tolist() == [[0, 1], [1, 2]]
            assert f[bonds.attrs["particles_group"]].name == "/" + P
            assert "edges" not in f[P + "/box"] or True  # open box: boundary none on every axis
            assert [b if isinstance(b, str) else b.decode() for b in f[P + "/box"].attrs["boundary"]] == ["none"] * 3
            assert "action_1" in f["observables"]


def charges_in_h5md_and_topology():
    """A charged scene (SPC/E water): /particles/all/charge per particle, in e, and topology.data in
    atom_style full with the same q column; MDAnalysis reads the charges from it."""
    with tempfile.TemporaryDirectory() as d:
        run("inputs/spce_water.toml", d, "output.h5md=traj.h5md", "run.t_end=4", "output.h5md_interval=2")
        with h5py.File(os.path.join(d, "traj.h5md"), "r") as f:
            assert_spec(f)
            q = f[P + "/charge"][:]
            species = f[P + "/species"][:]
        assert q.shape == (1536,), q.shape
        assert np.allclose(q[0::3], -0.8476, rtol=0, atol=0) and np.allclose(q[1::3], 0.4238, rtol=0, atol=0), q[:6]
        assert abs(q.sum()) < 1e-12
        import MDAnalysis as mda
        u = mda.Universe(os.path.join(d, "topology.data"), os.path.join(d, "traj.h5md"), atom_style="id resid type charge x y z")
        assert np.allclose(u.atoms.charges, q, rtol=1e-7, atol=0), u.atoms.charges[:6]  # MDAnalysis keeps float32
        assert len(species) == 1536


def ecoul_and_elong_columns():
    """A charged scene's thermo has evdwl (the pairs' van der Waals part: 0 for coul/long), ecoul
    (the real-space Coulomb pairs) and elong (the k-space term), in the H5MD observables too; with
    only bonds besides them (tests/decks/every_mesh_style.toml: harmonic bonds, coul/long, pppm) they
    add up with the bonds' energy to potential_slow."""
    with tempfile.TemporaryDirectory() as d:
        run("tests/decks/every_mesh_style.toml", d, "output.h5md=traj.h5md", "output.h5md_interval=0.01")
        rows = np.genfromtxt(os.path.join(d, "thermo.csv"), delimiter=",", names=True)
        with h5py.File(os.path.join(d, "traj.h5md"), "r") as f:
            assert all(c in f["observables"] for c in ("evdwl", "ecoul", "elong"))
            assert np.allclose(f["observables/elong/value"][:], rows["elong"][: len(f["observables/elong/value"])],
                               rtol=1e-10, atol=0)
        assert np.all(rows["elong"] != 0) and np.all(rows["ecoul"] != 0) and np.all(rows["evdwl"] == 0)
        # At t = 0, potential_slow − ecoul − elong is the bonds' Σ ½k(r − r0)² (k = 100, r0 = 1.1) at
        # the data file's positions.
        x = {}
        lines = open(os.path.join(ROOT, "tests/data/charged_styles.data")).read().splitlines()
        atoms = lines.index("Atoms # full") + 2
        for line in lines[atoms:atoms + 8]:
            w = line.split()
            x[int(w[0])] = np.array([float(v) for v in w[4:7]])
        bonds = [(1, 2), (2, 3), (3, 4), (5, 6), (6, 7), (7, 8)]
        expected = sum(0.5 * 100.0 * (np.linalg.norm(x[i] - x[j]) - 1.1) ** 2 for i, j in bonds)
        got = rows["potential_slow"][0] - rows["evdwl"][0] - rows["ecoul"][0] - rows["elong"][0]
        assert abs(got - expected) < 1e-9 * (abs(rows["ecoul"][0]) + abs(rows["elong"][0])), (got, expected)


def killed_run_keeps_its_frames():
    with tempfile.TemporaryDirectory() as d:
        proc = subprocess.Popen([EXE, "run", os.path.join(ROOT, "inputs/double_pendulum.toml"), "-o", d, "--no-progress",
                                 "--set", "variables.eps=1e-4", "--set", "run.t_end=100", "--set", "output.h5md=traj.h5md",
                                 "--set", "output.h5md_interval=0.01"], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        time.sleep(1.5)
        proc.send_signal(signal.SIGKILL)
        proc.wait()
        with h5py.File(os.path.join(d, "traj.h5md"), "r") as f:
            n = f[P + "/position/value"].shape[0]
            times = f[P + "/position/time"][:n]
        assert n >= 3, n
        assert np.all(np.diff(times) > 0)
        u = universe(os.path.join(d, "trajectory.xyz"), os.path.join(d, "traj.h5md"))
        assert len(u.trajectory) == n
        for ts in u.trajectory:
            pass


def restart_appends_exactly():
    with tempfile.TemporaryDirectory() as d:
        sets = ["output.h5md=traj.h5md", "output.h5md_interval=0.03125"]
        run("inputs/double_pendulum.toml", os.path.join(d, "whole"), *sets, "run.t_end=0.5")
        run("inputs/double_pendulum.toml", os.path.join(d, "parts"), *sets, "run.t_end=0.25")
        cmd = [EXE, "run", os.path.join(ROOT, "inputs/double_pendulum.toml"), "-o", os.path.join(d, "parts"), "--no-progress",
               "--restart", os.path.join(d, "parts", "checkpoint.bin")] + sum((["--set", s] for s in sets + ["run.t_end=0.5"]), [])
        subprocess.run(cmd, check=True, capture_output=True)
        with h5py.File(os.path.join(d, "whole", "traj.h5md"), "r") as a, h5py.File(os.path.join(d, "parts", "traj.h5md"), "r") as b:
            assert_spec(b)
            for key in ("position/value", "position/time", "position/step"):
                assert np.array_equal(a[P + "/" + key][:], b[P + "/" + key][:]), key
            assert np.array_equal(a["observables/total/value"][:], b["observables/total/value"][:])


def cubic_box_mdanalysis_positions_box_time():
    """A fully periodic melt: MDAnalysis reads every frame's box as [L, L, L, 90, 90, 90], the time
    as step·h (both from the file, checked against the deck), and positions equal to the XYZ
    trajectory's wrapped into [0, L)."""
    with tempfile.TemporaryDirectory() as d:
        run("tests/decks/small_melt.toml", d, "output.h5md=traj.h5md", "output.h5md_interval=0.05",
            "output.xyz=trajectory.xyz", "output.xyz_interval=0.05", "run.t_end=0.3")
        h5 = os.path.join(d, "traj.h5md")
        x_xyz, t_xyz = read_xyz(os.path.join(d, "trajectory.xyz"))
        with h5py.File(h5, "r") as f:
            assert_spec(f)
            box = f[P + "/box"]
            assert [b.decode() for b in box.attrs["boundary"]] == ["periodic"] * 3
            L = np.diag(box["edges/value"][0])
            assert box["edges/value"].shape == (len(t_xyz), 3, 3) and np.allclose(L, L[0])
            step, time_ = f[P + "/position/step"][:], f[P + "/position/time"][:]
        assert np.allclose(time_, t_xyz, atol=1e-12)
        assert np.allclose(time_, step * 0.005, rtol=1e-12, atol=1e-14), (time_, step)  # the deck's h
        u = universe(os.path.join(d, "trajectory.xyz"), h5)
        assert len(u.trajectory) == len(t_xyz)
        for ts in u.trajectory:
            assert np.allclose(ts.dimensions, [L[0], L[1], L[2], 90, 90, 90], rtol=1e-6), ts.dimensions
            assert abs(ts.time - t_xyz[ts.frame]) < 1e-12
            wrapped = x_xyz[ts.frame] - L * np.floor(x_xyz[ts.frame] / L)
            assert np.allclose(ts.positions, wrapped, atol=1e-4), ts.frame


def restart_appends_to_variable_length_strings():
    """A file whose string attributes are variable-length (as earlier builds wrote them) is still
    recognised as stiffmd's and appended to on restart."""
    with tempfile.TemporaryDirectory() as d:
        sets = ["output.h5md=traj.h5md", "output.h5md_interval=0.03125"]
        run("inputs/double_pendulum.toml", d, *sets, "run.t_end=0.25")
        h5 = os.path.join(d, "traj.h5md")
        with h5py.File(h5, "r+") as f:
            for group, name in (("h5md/creator", "name"), ("h5md/creator", "version"), ("h5md/author", "name")):
                value = f[group].attrs[name].decode()
                f[group].attrs[name] = value  # h5py: a Python str becomes a variable-length string
            assert h5py.check_string_dtype(f["h5md/creator"].attrs.get_id("name").dtype).length is None
            frames = f[P + "/position/step"].shape[0]
        cmd = [EXE, "run", os.path.join(ROOT, "inputs/double_pendulum.toml"), "-o", d, "--no-progress",
               "--restart", os.path.join(d, "checkpoint.bin")] + sum((["--set", s] for s in sets + ["run.t_end=0.5"]), [])
        subprocess.run(cmd, check=True, capture_output=True)
        with h5py.File(h5, "r") as f:
            assert f[P + "/position/step"].shape[0] == 2 * frames - 1, (f[P + "/position/step"].shape, frames)


for t in (periodic_layout_values_and_mdanalysis, cubic_box_mdanalysis_positions_box_time,
          restart_appends_to_variable_length_strings, pendulum_bonds_and_particles_group, charges_in_h5md_and_topology, ecoul_and_elong_columns,
          killed_run_keeps_its_frames,
          restart_appends_exactly):
    test(t)
finish()
