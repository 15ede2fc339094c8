#!/usr/bin/python3
"""A run on N ranks that fails on some of them ends, within seconds, with the failing rank's message
(run by ctest, label mpi; docs/parallel.md, "Errors"):

    test_mpi_failures.py STIFFMD MPIEXEC NUMPROC_FLAG CASE

CASE is one of
    rank_error     tests/decks/wall_crossing.toml on 2 ranks with H5MD on: a bead passes the 9-3
                   wall in rank 1's domain (a NumericalError on rank 1 alone, while rank 0 waits in
                   the halo): exit 3 naming rank 1, the wall and the bead by the serial run's
                   number; the H5MD file opens in h5py and its complete frames are the serial run's
    shake_error    tests/decks/shake_failure.toml on 2 ranks, H5MD on: SHAKE cannot hold rank 1's
                   dimer (one bead thrown 20 bond lengths in a step): exit 3 naming rank 1 and the
                   bond's particles by the serial run's numbers (the cluster and bond numbers are
                   rank 1's); the file's complete frames are the serial run's
    shake_error_pppm  the same with charges, coul/long and PPPM (the mesh summed over the ranks at
                   every force evaluation: rank 0 waits there): the same exit, message and frames
    actions        inputs/ring_solution.toml with [observables] actions (1 442 observables, each an
                   H5MD dataset) and H5MD on 2 ranks: it finishes, and the file's observables and
                   positions are the serial run's
    unwritable     the output directory read-only for rank 1 (a mount namespace): exit 2 naming
                   rank 1, before any rank opens the shared H5MD file
    unseen         the output directory not there for rank 1 (a tmpfs over its parent, as a
                   node-local path of rank 0's machine): exit 2 naming rank 1
    gzip_append    a compressed H5MD file (output.h5md_gzip) written by one process, continued on 2
                   ranks: parallel HDF5 cannot extend its chunks (allocated at their first write by
                   one process), so every rank refuses alike: exit 2, said once
    checkpoint     the output directory read-only for rank 1 and no H5MD file, so that the run
                   goes on until its checkpoint, which every rank writes its block of: exit 2 naming
                   rank 1 and the checkpoint, said once, and no checkpoint (nor its temporary file)
    setup          a restart whose checkpoint rank 1 cannot read (a tmpfs over the folder): rank 1
                   fails before the run's first collective call: exit 2 naming rank 1

Every launch has a time limit (LIMIT seconds): a job still running then has hung, and the test fails.
The mount namespaces need `unshare -m` (root, or user namespaces): without it those cases are skipped
(exit 77).
"""
import os
import shutil
import signal
import subprocess
import sys
import tempfile

import h5py
import numpy as np

ROOT = os.path.normpath(os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))
WALL = os.path.join(ROOT, "tests", "decks", "wall_crossing.toml")
RINGS = os.path.join(ROOT, "inputs", "ring_solution.toml")
FREE = os.path.join(ROOT, "tests", "decks", "periodic_free.toml")
SHAKE = os.path.join(ROOT, "tests", "decks", "shake_failure.toml")
LIMIT = 60  # seconds: every case ends in a few on 2 cores
SKIP = 77
P = "particles/all"


def environment():
    env = dict(os.environ, OMP_NUM_THREADS="1", OMPI_ALLOW_RUN_AS_ROOT="1", OMPI_ALLOW_RUN_AS_ROOT_CONFIRM="1",
               OMPI_MCA_rmaps_base_oversubscribe="1")
    env.pop("STIFFMD_SIGNAL_AT_STEP", None)
    return env


def run(cmd, expect):
    """Runs cmd within LIMIT seconds; its exit code must be `expect`."""
    print("$ " + " ".join(cmd), flush=True)
    # A session of its own, so that a hung job is ended whole: killing the launcher alone leaves
    # its ranks running (and holding the output pipes open).
    p = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=environment(),
                         start_new_session=True)
    try:
        out, err = p.communicate(timeout=LIMIT)
    except subprocess.TimeoutExpired:
        os.killpg(p.pid, signal.SIGKILL)
        p.communicate()
        raise SystemExit(f"FAIL: still running after {LIMIT} s (a hang): {' '.join(cmd)}")
    r = subprocess.CompletedProcess(cmd, p.returncode, out, err)
    if r.returncode != expect:
        sys.stderr.write(r.stdout[-3000:] + r.stderr[-3000:])
        raise SystemExit(f"FAIL: exit {r.returncode}, expected {expect}, from: {' '.join(cmd)}")
    return r


def on_rank_one(mpiexec, numproc_flag, stiffmd, args, rank_one_prefix):
    """2 ranks of `stiffmd args`; rank 1 runs inside `rank_one_prefix` (a shell command that ends
    by running what follows it, e.g. a mount namespace)."""
    quoted = " ".join("'" + a.replace("'", "'\\''") + "'" for a in [stiffmd] + args)
    script = ('r="${OMPI_COMM_WORLD_RANK:-${PMI_RANK:-0}}"; '
              f'if [ "$r" = 1 ]; then {rank_one_prefix} {quoted}; else exec {quoted}; fi')
    return [mpiexec, numproc_flag, "2", "sh", "-c", script]


def namespace(setup):
    """A prefix that runs the rest in a private mount namespace after the shell commands `setup`."""
    return f"exec unshare -m --propagation private sh -c '{setup} && exec \"$0\" \"$@\"'"


def can_unshare():
    try:
        return subprocess.run(["unshare", "-m", "--propagation", "private", "true"],
                              capture_output=True, timeout=20).returncode == 0
    except (OSError, subprocess.TimeoutExpired):
        return False


def expect_message(r, *parts):
    for p in parts:
        if p not in r.stderr:
            raise SystemExit(f"FAIL: stderr does not say {p!r}:\n{r.stderr}")


def rank_error(stiffmd, mpiexec, numproc_flag, tmp, deck, sets, said, both=()):
    """`both`: --set arguments of the serial and the 2-rank run alike; `sets`: the 2-rank run's."""
    serial, ranks = os.path.join(tmp, "serial"), os.path.join(tmp, "ranks")
    base = ["run", deck, "-q", "--no-progress"] + list(both)
    run([stiffmd] + base + ["-o", serial], 3)
    r = run([mpiexec, numproc_flag, "2", stiffmd] + base + ["-o", ranks, "--set", "parallel.grid=[2,1,1]"] + sets, 3)
    expect_message(r, "error (rank 1)", said, "step 1")
    with h5py.File(os.path.join(serial, "trajectory.h5md"), "r") as f:
        want = f[P + "/position/value"][:len(f[P + "/position/step"])]
    with h5py.File(os.path.join(ranks, "trajectory.h5md"), "r") as f:
        steps = f[P + "/position/step"][()]
        got = f[P + "/position/value"][:len(steps)]
    if len(steps) == 0 or not np.array_equal(got, want[:len(steps)]):
        raise SystemExit(f"FAIL: the 2-rank file's complete frames ({len(steps)}) are not the serial run's")
    print(f"rank 1's failure ended the job (exit 3); the file's {len(steps)} complete frame(s) read as the serial run's")


def actions(stiffmd, mpiexec, numproc_flag, tmp):
    sets = ["--set", "run.t_end=0.1", "--set", "observables.actions=true", "--set", 'output.h5md="t.h5md"',
            "--set", 'output.xyz=""']
    serial, ranks = os.path.join(tmp, "serial"), os.path.join(tmp, "ranks")
    run([stiffmd, "run", RINGS, "-q", "--no-progress", "-o", serial] + sets, 0)
    run([mpiexec, numproc_flag, "2", stiffmd, "run", RINGS, "-q", "--no-progress", "-o", ranks] + sets, 0)
    with h5py.File(os.path.join(serial, "t.h5md"), "r") as a, h5py.File(os.path.join(ranks, "t.h5md"), "r") as b:
        names = sorted(a["observables"])
        if names != sorted(b["observables"]) or len(names) < 1000:
            raise SystemExit(f"FAIL: observables differ or too few ({len(names)})")
        for name in names:
            x, y = a["observables/" + name + "/value"][()], b["observables/" + name + "/value"][()]
            scale = max(1.0, float(np.max(np.abs(x))))
            if x.shape != y.shape or np.max(np.abs(x - y)) > 1e-10 * scale:
                raise SystemExit(f"FAIL: observable {name} differs: {x} vs {y}")
        if not np.array_equal(a[P + "/position/value"][()], b[P + "/position/value"][()]):
            raise SystemExit("FAIL: positions differ from the serial run's")
        frames = len(b[P + "/position/step"])
    print(f"2 ranks wrote {len(names)} observables over {frames} frames, the serial run's")


def unwritable(stiffmd, mpiexec, numproc_flag, tmp, hidden):
    out = os.path.join(tmp, "out")
    os.makedirs(out)
    if hidden:  # rank 1 sees an empty file system where the folder holding `out` is
        setup = f"mount -t tmpfs none {tmp}"
    else:
        setup = f"mount --bind {out} {out} && mount -o remount,bind,ro {out}"
    args = ["run", FREE, "-q", "--no-progress", "-o", out, "--set", 'output.h5md="t.h5md"']
    r = run(on_rank_one(mpiexec, numproc_flag, stiffmd, args, namespace(setup)), 2)
    expect_message(r, "rank 1", "not there for rank 1" if hidden else "not writable by rank 1")
    if r.stderr.count("error") != 1:
        raise SystemExit(f"FAIL: the agreed error is to be said once:\n{r.stderr}")
    print("rank 1's output directory refused on every rank (exit 2) before the shared H5MD file")


def checkpoint(stiffmd, mpiexec, numproc_flag, tmp):
    out = os.path.join(tmp, "out")
    os.makedirs(out)
    setup = f"mount --bind {out} {out} && mount -o remount,bind,ro {out}"
    args = ["run", FREE, "-q", "--no-progress", "-o", out, "--set", 'output.h5md=""', "--set", 'output.xyz=""']
    r = run(on_rank_one(mpiexec, numproc_flag, stiffmd, args, namespace(setup)), 2)
    expect_message(r, "rank 1: ", "checkpoint.bin: cannot open checkpoint")
    if r.stderr.count("error") != 1:
        raise SystemExit(f"FAIL: the agreed error is to be said once:\n{r.stderr}")
    left = [name for name in os.listdir(out) if name.startswith("checkpoint")]
    if left:
        raise SystemExit(f"FAIL: a failed checkpoint left {left}")
    print("a checkpoint rank 1 cannot write its block of ended every rank (exit 2), no file left")


def setup(stiffmd, mpiexec, numproc_flag, tmp):
    out = os.path.join(tmp, "out")
    run([stiffmd, "run", FREE, "-q", "--no-progress", "-o", out, "--set", "run.t_end=1"], 0)
    args = ["run", FREE, "-q", "--no-progress", "-o", out, "--restart", os.path.join(out, "checkpoint.bin")]
    r = run(on_rank_one(mpiexec, numproc_flag, stiffmd, args, namespace(f"mount -t tmpfs none {out}")), 2)
    expect_message(r, "rank 1: ", "checkpoint.bin")
    print("a checkpoint rank 1 cannot read ended every rank (exit 2) before the run")


def gzip_append(stiffmd, mpiexec, numproc_flag, tmp):
    out = os.path.join(tmp, "out")
    sets = ["--set", 'output.h5md="t.h5md"', "--set", "output.h5md_gzip=4"]
    run([stiffmd, "run", FREE, "-q", "--no-progress", "-o", out, "--set", "run.t_end=1"] + sets, 0)
    with h5py.File(os.path.join(out, "t.h5md"), "r") as f:
        steps = f[P + "/position/step"][()]
    r = run([mpiexec, numproc_flag, "2", stiffmd, "run", FREE, "-q", "--no-progress", "-o", out, "--restart",
             os.path.join(out, "checkpoint.bin")] + sets, 2)
    expect_message(r, "cannot append on 2 processes: its compressed series (output.h5md_gzip) were written by one")
    if r.stderr.count("error") != 1:
        raise SystemExit(f"FAIL: the agreed error is to be said once:\n{r.stderr}")
    with h5py.File(os.path.join(out, "t.h5md"), "r") as f:  # untouched: the one-process run's frames
        if not np.array_equal(f[P + "/position/step"][()], steps):
            raise SystemExit(f"FAIL: the refused append changed the file's frames {steps}")
    print("a compressed one-process file refused on 2 ranks (exit 2), the file as it was")


def main(argv):
    if len(argv) != 5:
        raise SystemExit(__doc__)
    stiffmd, mpiexec, numproc_flag, case = argv[1:]
    if case in ("unwritable", "unseen", "setup", "checkpoint") and not can_unshare():
        print(f"SKIP: {case}: no mount namespaces here (unshare -m)")
        return SKIP
    tmp = tempfile.mkdtemp(prefix="stiffmd_mpi_failures_")
    try:
        if case == "rank_error":
            # The serial run's numbers: the bead is particle 3 of the system (rank 1 holds it as its 1).
            rank_error(stiffmd, mpiexec, numproc_flag, tmp, WALL, ["--set", "parallel.halo_margin=5"],
                       "lj93-wall 'wall': particle 3 is not on the wall")
        elif case == "shake_error":
            rank_error(stiffmd, mpiexec, numproc_flag, tmp, SHAKE, [],
                       "SHAKE did not converge in cluster 0 after 50 iterations: worst bond 0 (particles 2–3)")
        elif case == "shake_error_pppm":
            # The same with charges, coul/long and PPPM: rank 0 waits in the mesh's sum over the ranks.
            rank_error(stiffmd, mpiexec, numproc_flag, tmp, SHAKE, [],
                       "SHAKE did not converge in cluster 0 after 50 iterations: worst bond 0 (particles 2–3)",
                       ["--set", "types.A.charge=0.3", "--set",
                        'forces.coul={ style = "coul/long", coulomb_cutoff = 2.5, skin = 0.3 }',
                        "--set", 'forces.mesh={ style = "pppm", accuracy = 1e-4 }'])
        elif case == "actions":
            actions(stiffmd, mpiexec, numproc_flag, tmp)
        elif case in ("unwritable", "unseen"):
            unwritable(stiffmd, mpiexec, numproc_flag, tmp, case == "unseen")
        elif case == "gzip_append":
            gzip_append(stiffmd, mpiexec, numproc_flag, tmp)
        elif case == "setup":
            setup(stiffmd, mpiexec, numproc_flag, tmp)
        elif case == "checkpoint":
            checkpoint(stiffmd, mpiexec, numproc_flag, tmp)
        else:
            raise SystemExit(f"unknown case {case}")
    except BaseException:
        print(f"(outputs kept in {tmp})")
        raise
    shutil.rmtree(tmp)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
