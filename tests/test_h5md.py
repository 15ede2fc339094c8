#!/usr/bin/python3
"""H5MD output (engine/h5md_writer.*) read back with h5py, MDAnalysis and ASE (run by ctest).

    /usr/bin/python3 tests/test_h5md.py PATH/TO/h5md_driver

Every H5MD file is checked against the plain-text record written beside it: an extended XYZ
trajectory of unwrapped positions (PREFIX.xyz) and a CSV of observables (PREFIX.csv). Files are
made in one place, `produce` (and `start_endless` for the kill tests): today they run
tests/h5md_driver.cpp; to test `stiffmd run` instead, make those two functions run a deck with
`[output] h5md`, `xyz` (same interval, velocities on) and `thermo`, and return the same paths.
"""
import csv
import os
import pwd
import random
import shlex
import signal
import subprocess
import sys
import tempfile
import time
import traceback
import warnings

import h5py
import numpy as np
from h5md_spec import h5md_problems

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
CONVERTER = os.path.join(ROOT, "tools", "h5md_to_xyz.py")
PY = "/usr/bin/python3"
EXE = None  # argv[1]
P = "particles/all"
TOL = dict(rtol=1e-10, atol=1e-10)  # the XYZ record may be printed with 12 significant digits
OBSERVABLES = ["kinetic", "potential_slow", "potential_stiff", "total", "max_violation", "action_1"]


# ---------------------------------------------------------------- making files

class Run:
    def __init__(self, prefix):
        self.h5, self.xyz, self.csv = prefix + ".h5", prefix + ".xyz", prefix + ".csv"


def produce(scene, workdir):
    """Writes scene `open`, `periodic`, `slab` or `append` into workdir; returns its Run."""
    prefix = os.path.join(workdir, scene)
    subprocess.run([EXE, scene, prefix], check=True)
    return Run(prefix)


def start_endless(workdir, name, sleep_ms, gzip=1):
    """Starts a writer that adds frames until killed; returns (process, Run)."""
    prefix = os.path.join(workdir, name)
    proc = subprocess.Popen([EXE, "forever", prefix, str(sleep_ms), str(gzip)], stdout=subprocess.DEVNULL)
    return proc, Run(prefix)


# ---------------------------------------------------------------- reading the record

def read_xyz(path):
    """Extended XYZ frames as dicts: info (comment keys), species, and one array per property.
    A trailing incomplete frame (a killed writer) is dropped."""
    with open(path) as f:
        lines = f.read().split("\n")
    frames, i = [], 0
    while i < len(lines) and lines[i].strip():
        n = int(lines[i])
        if i + 2 + n >= len(lines):  # the last line of a complete frame ends with a newline
            break
        info = dict(kv.split("=", 1) for kv in shlex.split(lines[i + 1]))
        rows = [ln.split() for ln in lines[i + 2:i + 2 + n]]
        if any(len(r) != len(rows[0]) for r in rows):
            break
        spec = info["Properties"].split(":")
        frame, col = {"info": info}, 0
        for name, kind, width in zip(spec[0::3], spec[1::3], spec[2::3]):
            width = int(width)
            block = [r[col:col + width] for r in rows]
            frame[name] = [b[0] for b in block] if kind == "S" else np.array(block, dtype=float)
            col += width
        frames.append(frame)
        i += 2 + n
    return frames


def read_csv(path):
    with open(path) as f:
        return [{k: float(v) for k, v in row.items()} for row in csv.DictReader(f)]


def lattice(frame):
    return np.array(frame["info"]["Lattice"].split(), dtype=float).reshape(3, 3)


def wrap(x, origin, lengths, periodic):
    """Reference wrapping into [origin, origin + L) on periodic axes."""
    x = x.copy()
    for k in range(3):
        if periodic[k]:
            x[:, k] = x[:, k] - lengths[k] * np.floor((x[:, k] - origin[k]) / lengths[k])
    return x


def string_list(values):
    return [v.decode() if isinstance(v, bytes) else str(v) for v in values]


def series_lengths(f):
    """Length of every time series (value/step/time) in the file, by path."""
    out = {}

    def visit(name, obj):
        if isinstance(obj, h5py.Dataset) and name.rsplit("/", 1)[-1] in ("value", "step", "time") \
                and obj.maxshape and obj.maxshape[0] is None:
            out[name] = obj.shape[0]
    f.visititems(visit)
    for g in [P + "/position", P + "/box/edges"]:  # hard links visititems reports only once
        for d in ("step", "time"):
            if g + "/" + d in f:
                out[g + "/" + d] = f[g + "/" + d].shape[0]
    return out


# ---------------------------------------------------------------- shared checks

def check_metadata(f):
    """The whole layout against the specification (tests/h5md_spec.py), then our values."""
    problems = h5md_problems(f)
    assert not problems, "\n".join(problems)
    v = f["h5md"].attrs["version"]
    assert v.dtype == np.int32 and list(v) == [1, 1], v
    assert f["h5md/author"].attrs["name"], "empty author"
    assert string_list([f["h5md/creator"].attrs["name"]]) == ["stiffmd"]
    assert f["h5md/creator"].attrs["version"]


def check_time_series(f, run):
    """position/step, time and value against the XYZ record; every element on the same grid."""
    ref = read_xyz(run.xyz)
    pos = f[P + "/position"]
    n = len(ref)
    for name, dtype, item in [("step", np.int64, ()), ("time", np.float64, ()),
                              ("value", np.float64, (len(ref[0]["species"]), 3))]:
        d = pos[name]
        assert d.dtype == dtype, (name, d.dtype)
        assert d.shape == (n,) + item, (name, d.shape)
        assert d.maxshape == (None,) + item and d.chunks is not None, (name, d.maxshape, d.chunks)
    assert list(pos["step"][()]) == [int(fr["info"]["step"]) for fr in ref]
    assert np.allclose(pos["time"][()], [float(fr["info"]["time"]) for fr in ref], **TOL)
    # One time grid: every other element's step/time is a hard link to position's.
    for g in ["image", "velocity", "force", "box/edges"]:
        if P + "/" + g in f:
            for d in ("step", "time"):
                assert f[P + "/" + g + "/" + d].id == pos[d].id, (g, d)
    for name in f.get("observables", {}):
        assert f["observables/" + name + "/step"].id == pos["step"].id, name
    return ref


def check_observables(f, run):
    rows = read_csv(run.csv)
    assert sorted(f["observables"]) == sorted(OBSERVABLES), list(f["observables"])
    for name in OBSERVABLES:
        v = f["observables/" + name + "/value"]
        assert v.dtype == np.float64 and v.shape == (len(rows),), (name, v.shape)
        if name in rows[0]:
            assert np.allclose(v[()], [r[name] for r in rows], **TOL), name


def check_unwrapped(f, ref):
    """position (+ image·edges when periodic) equals the unwrapped record; velocities and forces too."""
    p = f[P]
    for k, fr in enumerate(ref):
        x = p["position/value"][k]
        if "image" in p:
            x = x + p["image/value"][k] @ p["box/edges/value"][k]
        assert np.allclose(x, fr["pos"], **TOL), (k, x - fr["pos"])
        for name, prop in (("velocity", "velo"), ("force", "forces")):
            assert (name in p) == (prop in fr), name
            if name in p:
                assert np.allclose(p[name + "/value"][k], fr[prop], **TOL), (name, k)


def open_universe(run):
    """How MDAnalysis 2.4.2 opens our files: a topology (here the XYZ record; any file with the
    atoms will do) plus format="H5MD" (".h5" is not recognised) and convert_units=False (no units
    are stored: stiffmd's units are reduced)."""
    import MDAnalysis as mda
    return mda.Universe(run.xyz, run.h5, format="H5MD", convert_units=False)


def check_mdanalysis(run, periodic_lengths=None, frames=None):
    """Every frame (all, or the first `frames` complete ones of a killed file): wrapped positions
    (float32), time, box dimensions and observables."""
    with h5py.File(run.h5, "r") as f:
        count = f[P + "/position/value"].shape[0]
        n = count if frames is None else frames
        stored = f[P + "/position/value"][:n]
        times = f[P + "/position/time"][:n]
        total = f["observables/total/value"][:n]
    u = open_universe(run)
    assert len(u.trajectory) == count, (len(u.trajectory), count)  # MDAnalysis counts position/value
    seen = 0
    for ts in u.trajectory:
        k = ts.frame
        scale = max(1.0, np.abs(stored[k]).max())
        assert np.allclose(ts.positions, stored[k], rtol=0, atol=1e-6 * scale), k
        assert abs(ts.time - times[k]) <= 1e-12 * max(1.0, abs(times[k])), (ts.time, times[k])
        assert np.isclose(ts.data["total"], total[k], rtol=1e-12)
        if periodic_lengths is None:
            assert ts.dimensions is None, ts.dimensions
        else:
            assert np.allclose(ts.dimensions, list(periodic_lengths) + [90, 90, 90], rtol=1e-6), ts.dimensions
        seen += 1
    assert seen == len(stored)
    u.trajectory.close()  # releases HDF5's file lock, so the file can be appended to


def convert(h5, out, *flags):
    subprocess.run([PY, CONVERTER, h5, out, *flags], check=True, stdout=subprocess.DEVNULL)
    return read_xyz(out)


# ---------------------------------------------------------------- tests

def test_open_box_layout(work):
    """(a) open box, 3 particles, 2 bonds, forces: groups, attributes, shapes, dtypes, links."""
    run = produce("open", work)
    with h5py.File(run.h5, "r") as f:
        check_metadata(f)
        assert string_list([f["h5md/author"].attrs["name"]])[0] == (os.environ.get("USER") or pwd.getpwuid(os.getuid()).pw_name)
        ref = check_time_series(f, run)
        check_observables(f, run)
        p = f[P]
        assert set(p) == {"position", "force", "species", "mass", "id", "box"}, set(p)
        box = p["box"]
        assert box.attrs["dimension"] == 3 and string_list(box.attrs["boundary"]) == ["none"] * 3
        assert "edges" not in box  # open box: H5MD allows omitting edges
        elements = string_list(p["species"].attrs["elements"])
        assert p["species"].dtype == np.int32
        assert [elements[s] for s in p["species"][()]] == ref[0]["species"] == ["C", "O", "C"]
        assert p["mass"].dtype == np.float64 and np.allclose(p["mass"][()], [1.0, 1.5, 2.0])
        assert p["id"].dtype == np.int64 and list(p["id"][()]) == [0, 1, 2]
        assert p["force/value"].shape == (len(ref), 3, 3)
        bonds = f["connectivity/bonds"]
        assert bonds.shape == (2, 2) and np.issubdtype(bonds.dtype, np.integer)
        assert bonds[()].tolist() == [[0, 1], [1, 2]]
        assert f[bonds.attrs["particles_group"]].name == "/" + P
        vmd = f["parameters/vmd_structure"]
        assert list(vmd["bond_from"][()]) == [1, 2] and list(vmd["bond_to"][()]) == [2, 3]
        assert [s.decode() for s in vmd["name"][()]] == elements and list(vmd["indexOfSpecies"][()]) == [0, 1]
        # No unit attributes anywhere (reduced units; see engine/io/h5md_writer.cpp).
        units = []
        f.visititems(lambda name, obj: units.append(name) if "unit" in obj.attrs else None)
        assert not units, units
        check_unwrapped(f, ref)


def test_periodic_layout_and_images(work):
    """(b) periodic, 20 particles crossing the faces, velocities, gzip: wrapping and images."""
    run = produce("periodic", work)
    with h5py.File(run.h5, "r") as f:
        check_metadata(f)
        ref = check_time_series(f, run)
        check_observables(f, run)
        p = f[P]
        n, N = len(ref), 20
        assert string_list(p["box"].attrs["boundary"]) == ["periodic"] * 3
        L = np.diag(lattice(ref[0]))
        origin = np.array(ref[0]["info"]["Origin"].split(), dtype=float)
        assert np.allclose(p["box/offset"][()], origin)
        edges = p["box/edges/value"]
        assert edges.shape == (n, 3, 3) and edges.dtype == np.float64 and edges.maxshape[0] is None
        assert np.allclose(edges[()], np.diag(L)[None, :, :])
        image = p["image/value"]
        assert image.dtype == np.int32 and image.shape == (n, N, 3)
        assert p["velocity/value"].shape == (n, N, 3)
        for name in ("position", "velocity", "image"):
            d = p[name + "/value"]
            assert d.compression == "gzip" and d.compression_opts == 4, (name, d.compression)
        x = p["position/value"][()]
        assert np.all(x >= origin - 1e-12) and np.all(x < origin + L), "positions not wrapped into the box"
        a = image[()]
        assert (a > 0).any() and (a < 0).any(), "the scene should cross faces both ways"
        for k, fr in enumerate(ref):
            assert np.allclose(x[k] + a[k] * L, fr["pos"], **TOL), k
            assert np.allclose(x[k], wrap(fr["pos"], origin, L, [1, 1, 1]), **TOL), k
        check_unwrapped(f, ref)


def test_slab_box(work):
    """Periodic in x and y only: z is stored as is with image 0 (a placeholder)."""
    run = produce("slab", work)
    with h5py.File(run.h5, "r") as f:
        check_metadata(f)
        ref = check_time_series(f, run)
        p = f[P]
        assert string_list(p["box"].attrs["boundary"]) == ["periodic", "periodic", "none"]
        assert (p["image/value"][:, :, 2] == 0).all()
        assert (p["image/value"][:, :, :2] != 0).any()
        assert np.allclose(p["position/value"][:, :, 2], [fr["pos"][:, 2] for fr in ref], **TOL)
        check_unwrapped(f, ref)


def test_mdanalysis_reads_every_frame(work):
    """MDAnalysis: every frame, wrapped positions, times, box dimensions, observables; and the
    unit decision: without convert_units=False it refuses a file without units."""
    import MDAnalysis as mda
    for scene, lengths in (("open", None), ("periodic", (3.0, 4.0, 5.0)), ("append", (3.0, 4.0, 5.0))):
        run = produce(scene, work)
        check_mdanalysis(run, lengths)
    u = mda.Universe.empty(20, trajectory=False)  # topology-free alternative
    u.load_new(run.h5, format="H5MD", convert_units=False)
    assert len(u.trajectory) == 8
    try:
        mda.Universe(run.xyz, run.h5, format="H5MD")
    except ValueError as e:
        assert "units" in str(e)
    else:
        raise AssertionError("MDAnalysis converted units that the file does not have")


def test_append_drops_frames_from_first_step(work):
    """(c) 5 frames (steps 0..40), reopened with first_step 30: steps 30, 40 replaced by the
    continuation (shifted by 100), which goes on to step 70."""
    run = produce("append", work)
    with h5py.File(run.h5, "r") as f:
        check_metadata(f)
        ref = check_time_series(f, run)
        assert list(f[P + "/position/step"][()]) == [0, 10, 20, 30, 40, 50, 60, 70]
        assert len(set(series_lengths(f).values())) == 1, series_lengths(f)
        check_observables(f, run)
        check_unwrapped(f, ref)  # the record's frames from step 30 on are the continuation's


def test_spec_checker_catches_departures(work):
    """tests/h5md_spec.py is not a rubber stamp: each departure from H5MD 1.1 made to a good file
    (variable-length strings, a wrong boundary, missing edges, an unlinked time grid, a bad
    connectivity reference, mismatched lengths) is reported."""
    import shutil
    good = produce("periodic", work).h5
    with h5py.File(good, "r") as f:
        assert h5md_problems(f) == []

    def vl_author(f):
        f["h5md/author"].attrs["name"] = "Someone"  # h5py writes a Python str as variable-length

    def vl_boundary(f):
        f[P + "/box"].attrs["boundary"] = ["periodic"] * 3

    def wrong_boundary(f):
        f[P + "/box"].attrs["boundary"] = np.array([b"periodic", b"closed", b"none"], dtype="S9")

    def no_edges(f):
        del f[P + "/box/edges"]

    def unlinked_edges_time(f):
        t = f[P + "/box/edges/time"][()]
        del f[P + "/box/edges/time"]
        f[P + "/box/edges"].create_dataset("time", data=t)

    def bond_reference_to_root(f):
        f["connectivity/bonds"].attrs["particles_group"] = f["/"].ref

    def short_step(f):
        step = f[P + "/velocity/step"][()]
        del f[P + "/velocity/step"]
        f[P + "/velocity"].create_dataset("step", data=step[:-1])

    def float_species(f):
        del f[P + "/species"]
        f[P].create_dataset("species", data=np.zeros(20))

    for damage, expected in ((vl_author, "variable-length"), (vl_boundary, "variable-length"),
                             (wrong_boundary, "periodic or none"), (no_edges, "edges may be omitted"),
                             (unlinked_edges_time, "hard link"), (bond_reference_to_root, "/particles"),
                             (short_step, "value's first dimension"), (float_species, "Enumeration or Integer")):
        bad = os.path.join(work, damage.__name__ + ".h5")
        shutil.copy(good, bad)
        with h5py.File(bad, "r+") as f:
            damage(f)
        with h5py.File(bad, "r") as f:
            problems = h5md_problems(f)
        assert any(expected in p for p in problems), (damage.__name__, problems)


def test_error_messages(work):
    """Unusable paths and mismatched files: one line that starts with the path; nothing from HDF5."""
    d = os.path.join(work, "errors")
    os.mkdir(d)
    r = subprocess.run([EXE, "errors", d], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    assert r.stderr == "", "HDF5 printed its error stack: " + r.stderr[:500]
    cases = dict(line.split("\t", 1) for line in r.stdout.splitlines())
    expect = {
        "missing_directory": ("/no/such/dir/traj.h5", "does not exist"),
        "path_is_directory": ("", "is a directory"),
        "append_missing_file": ("/absent.h5", "does not exist"),
        "append_not_hdf5": ("/text.h5", "not an HDF5 file"),
        "append_not_stiffmd": ("/plain.h5", "not an H5MD file written by stiffmd"),
        "append_particle_count": ("/good.h5", "particle count mismatch"),
        "append_velocity_mismatch": ("/good.h5", "velocity"),
        "append_observables_mismatch": ("/good.h5", "observables"),
    }
    if os.geteuid() != 0:
        expect["unwritable_directory"] = ("/readonly/traj.h5", "Permission denied")
    for case, (path, phrase) in expect.items():
        msg = cases.get(case)
        assert msg is not None, f"{case}: not run"
        assert msg.startswith(d + path + ": "), f"{case}: {msg}"
        assert phrase in msg, f"{case}: {msg}"
    # Appending to a file another program holds open (HDF5 locks files): said in one line.
    run = produce("periodic", work)
    with h5py.File(run.h5, "r"):
        r = subprocess.run([EXE, "resume", run.h5[:-3], "0"], capture_output=True, text=True)
    assert r.returncode != 0 and r.stderr.startswith(run.h5 + ": ") and "locked" in r.stderr, r.stderr
    assert r.stderr.count("\n") == 1, r.stderr


def wait_for_frames(run, proc, n, timeout=30):
    t0 = time.time()
    while time.time() - t0 < timeout:
        if os.path.exists(run.xyz) and len(read_xyz(run.xyz)) >= n:
            return
        assert proc.poll() is None, "the writer exited"
        time.sleep(0.01)
    raise AssertionError(f"fewer than {n} frames after {timeout} s")


def check_killed_file(run):
    """A killed file: position/step is no longer than position/value and that no longer than any
    other series (what MDAnalysis needs to iterate without error); h5py reads every series up to
    the length of position/step (a kill inside a flush may leave the frame after that unreadable);
    the frames also in the XYZ record match it; MDAnalysis reads every complete frame. Returns the
    number of complete frames."""
    ref = read_xyz(run.xyz)
    with h5py.File(run.h5, "r") as f:
        lengths = series_lengths(f)
        n = lengths[P + "/position/step"]
        others = [v for k, v in lengths.items() if not k.endswith("/step") and k != P + "/position/value"]
        assert n <= lengths[P + "/position/value"] <= min(others), lengths
        assert n >= len(ref), (n, len(ref))
        for name in lengths:
            f[name][:n]
        steps = f[P + "/position/step"][:n]
        assert list(steps) == [5 * k for k in range(n)], steps
        check_unwrapped(f, ref)
    check_mdanalysis(run, (3.0, 4.0, 5.0), frames=n)
    return n


def test_kill_between_frames(work):
    """SIGKILL while the writer waits between frames; then the file is read and continued."""
    proc, run = start_endless(work, "killed", sleep_ms=200)  # the kill lands between frames
    try:
        wait_for_frames(run, proc, 3)
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait()
    n = check_killed_file(run)
    assert n >= 3
    with h5py.File(run.h5, "r") as f:
        assert len(set(series_lengths(f).values())) == 1, series_lengths(f)
    frames = convert(run.h5, os.path.join(work, "killed_converted.xyz"))
    assert len(frames) == n
    # Continue it as a restart from the last frame's step would (replaces that frame, adds one).
    r = subprocess.run([EXE, "resume", run.h5[:-3], str(5 * (n - 1))], capture_output=True, text=True, check=True)
    assert r.stdout.split() == ["kept", str(n - 1), "frames", str(n + 1)], r.stdout
    with h5py.File(run.h5, "r") as f:
        assert list(f[P + "/position/step"][()]) == [5 * k for k in range(n + 1)]
        assert len(set(series_lengths(f).values())) == 1


def test_kill_mid_frame(work):
    """SIGKILL at random moments of a writer that never pauses (so mostly inside write_frame and
    its flushes), gzip on and off: the file reads up to its last complete frame. One case HDF5
    cannot prevent is allowed: a kill inside a flush after metadata naming newly allocated space
    was written but before the superblock recording the file's new end (HDF5 writes it last);
    HDF5 then refuses those addresses ("addr overflow") until the recorded end is extended, which
    reopening the file for appending (a restart) does. Every file is then continued by a restart
    and must read in full."""
    rng = random.Random(7)
    repaired = 0
    for trial in range(6):
        proc, run = start_endless(work, f"storm{trial}", sleep_ms=0, gzip=trial % 2)
        try:
            wait_for_frames(run, proc, 2)
            time.sleep(rng.uniform(0.0, 0.2))
        finally:
            proc.send_signal(signal.SIGKILL)
            proc.wait()
        try:
            check_killed_file(run)
            intact = True
        except (OSError, RuntimeError) as e:
            assert "addr overflow" in str(e), repr(e)
            intact = False
            repaired += 1
        with h5py.File(run.h5, "r") as f:
            n = f[P + "/position/step"].shape[0]
        # A restart from the last complete frame's step: the file is whole again.
        r = subprocess.run([EXE, "resume", run.h5[:-3], str(5 * (n - 1))], capture_output=True, text=True)
        assert r.returncode == 0, r.stderr
        with h5py.File(run.h5, "r") as f:
            lengths = series_lengths(f)
            assert set(lengths.values()) == {n + 1}, lengths
            for name in lengths:
                f[name][()]
        if not intact:
            check_killed_file(run)
    if repaired:
        print(f"note: {repaired} of 6 killed files needed the restart's repair (kill inside an HDF5 flush)")


def test_h5md_to_xyz(work):
    """tools/h5md_to_xyz.py: frame count, unwrapped and wrapped positions, and ASE reads it."""
    import ase.io
    for scene in ("periodic", "open", "slab"):
        run = produce(scene, work)
        ref = read_xyz(run.xyz)
        with h5py.File(run.h5, "r") as f:
            stored = f[P + "/position/value"][()]
            pbc = [b == "periodic" for b in string_list(f[P + "/box"].attrs["boundary"])]
        out = os.path.join(work, scene + "_converted.xyz")
        frames = convert(run.h5, out)
        assert len(frames) == len(ref), scene
        for got, want in zip(frames, ref):
            assert got["species"] == want["species"]
            assert np.allclose(got["pos"], want["pos"], **TOL), scene
            assert np.isclose(float(got["info"]["time"]), float(want["info"]["time"]), **TOL)
            assert got["info"]["step"] == want["info"]["step"]
            assert got["info"]["pbc"] == want["info"]["pbc"]
            assert ("Lattice" in got["info"]) == any(pbc)
            if "velo" in want:
                assert np.allclose(got["velo"], want["velo"], **TOL)
        wrapped = convert(run.h5, out + ".wrapped.xyz", "--wrapped")
        assert all(np.array_equal(w["pos"], s) for w, s in zip(wrapped, stored)), scene
        atoms = ase.io.read(out, index=":")
        assert len(atoms) == len(ref), scene
        for a, want in zip(atoms, ref):
            assert a.get_chemical_symbols() == want["species"]
            assert np.allclose(a.positions, want["pos"], **TOL)
            assert list(a.pbc) == pbc
            assert np.isclose(a.info["time"], float(want["info"]["time"]))
            if any(pbc):
                assert np.allclose(a.cell[:], lattice(want))


TESTS = [test_open_box_layout, test_periodic_layout_and_images, test_slab_box, test_mdanalysis_reads_every_frame,
         test_append_drops_frames_from_first_step, test_spec_checker_catches_departures, test_error_messages, test_kill_between_frames,
         test_kill_mid_frame, test_h5md_to_xyz]


def main():
    global EXE
    if len(sys.argv) != 2:
        sys.exit("usage: test_h5md.py PATH/TO/h5md_driver")
    EXE = os.path.abspath(sys.argv[1])
    warnings.simplefilter("ignore")  # MDAnalysis deprecation chatter
    passed = failed = 0
    for test in TESTS:
        with tempfile.TemporaryDirectory() as work:
            try:
                test(work)
                passed += 1
                print(f"ok   {test.__name__}")
            except Exception:
                failed += 1
                print(f"FAIL {test.__name__}")
                traceback.print_exc()
    print(f"{passed} passed, {failed} failed")
    sys.exit(1 if failed else 0)


if __name__ == "__main__":
    main()
