#!/usr/bin/env python3
"""[ensemble] decks end to end: an ensemble member is the plain run.

    test_ensemble.py serial STIFFMD
        a 3-member ensemble (inputs/nvt_trimers.toml, seeds varied) run in one process: OUT/member_0..2,
        each member's files byte-identical to `stiffmd run` of the deck without [ensemble] and the
        member's --set (summary.json: every field but the wall times); one summary line per member;
        a member that fails numerically gives the job its exit code 3 while the others finish.
    test_ensemble.py mpi STIFFMD MPIEXEC NUMPROC_FLAG N
        the same ensemble under `MPIEXEC NUMPROC_FLAG N`: with N <= 3, the files of the serial ensemble
        byte for byte, and a [parallel] grid refused at its key (members are not divided); with N > 3,
        refused with exit 2, one error line, nothing written.

Open MPI as root and with more processes than cores wants permission: given by its environment
variables (which MPICH's launcher ignores, where it would reject --oversubscribe)."""
import json
import os
import shutil
import subprocess
import sys
import tempfile

ROOT = os.path.normpath(os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))
BASE = os.path.join(ROOT, "inputs", "nvt_trimers.toml")
SEEDS = [11, 12, 13]
SHORT = ["--set", "run.t_end=3"]
TIMES = ("wall_seconds", "cpu_seconds", "loop_seconds", "timing", "serial_share", "peak_rss_mib", "setup_seconds")


def ensemble_deck(tmp, vary):
    path = os.path.join(tmp, "ensemble.toml")
    with open(BASE) as f:
        base = f.read()
    with open(path, "w") as f:
        f.write("[ensemble]\nvary = { " + vary + " }\n\n" + base)
    return path


def run(cmd, env=None):
    return subprocess.run(cmd, capture_output=True, text=True, timeout=120, env=env)


def same_files(a, b):
    """The two run folders hold the same files, byte for byte (summary.json: but its times)."""
    names = sorted(os.listdir(a))
    assert names == sorted(os.listdir(b)), (a, names, b, sorted(os.listdir(b)))
    assert "thermo.csv" in names and "checkpoint.bin" in names, names
    for name in names:
        with open(os.path.join(a, name), "rb") as fa, open(os.path.join(b, name), "rb") as fb:
            da, db = fa.read(), fb.read()
        if name == "summary.json":
            da, db = ({k: v for k, v in json.loads(d).items() if k not in TIMES} for d in (da, db))
        assert da == db, f"{a}/{name} differs from {b}/{name}"


def serial(stiffmd):
    tmp = tempfile.mkdtemp(prefix="stiffmd_ensemble_")
    try:
        deck = ensemble_deck(tmp, '"thermostat.seed" = [%d, %d, %d]' % tuple(SEEDS))
        out = os.path.join(tmp, "out")
        r = run([stiffmd, "run", deck, "-o", out, "-q"] + SHORT)
        assert r.returncode == 0, r.stderr
        assert sorted(os.listdir(out)) == ["member_0", "member_1", "member_2"], os.listdir(out)
        summary = [l for l in r.stdout.splitlines() if l.startswith("member ") and "steps to t = 3" in l]
        assert len(summary) == 3, r.stdout
        for k, seed in enumerate(SEEDS):
            plain = os.path.join(tmp, f"plain_{k}")
            p = run([stiffmd, "run", BASE, "-o", plain, "-q"] + SHORT + ["--set", f"thermostat.seed={seed}"])
            assert p.returncode == 0, p.stderr
            same_files(os.path.join(out, f"member_{k}"), plain)
        # The members differ (the seed reaches the thermostat).
        with open(os.path.join(out, "member_0", "thermo.csv")) as a, open(os.path.join(out, "member_1", "thermo.csv")) as b:
            assert a.read() != b.read()
        # A member whose micro step is too long for its springs, stopped by the monitor: exit 3 for the job, named on stderr; the others still run.
        deck = ensemble_deck(tmp, '"integrator.micro_dt" = [0.005, 0.5, 0.005], "integrator.h" = [0.05, 0.5, 0.05], '
                             '"monitor.on_alert" = ["stop", "stop", "stop"]')
        failed = os.path.join(tmp, "failed")
        r = run([stiffmd, "run", deck, "-o", failed, "-q"] + SHORT)
        assert r.returncode == 3, (r.returncode, r.stderr)
        errors = [l for l in r.stderr.splitlines() if l.startswith("error: ")]
        assert len(errors) == 1 and "member 1 (integrator.h=0.5 integrator.micro_dt=0.5 monitor.on_alert='stop')" in errors[0], r.stderr
        assert "member 1 (integrator.h=0.5 integrator.micro_dt=0.5 monitor.on_alert='stop'): failed (exit 3)" in r.stdout, r.stdout
        for k in (0, 2):
            assert os.path.exists(os.path.join(failed, f"member_{k}", "summary.json")), k
        print("serial ensemble: 3 members, each the plain run byte for byte; a failing member exits 3")
    finally:
        shutil.rmtree(tmp)


def mpi(stiffmd, mpiexec, numproc_flag, n):
    env = dict(os.environ, OMPI_ALLOW_RUN_AS_ROOT="1", OMPI_ALLOW_RUN_AS_ROOT_CONFIRM="1",
               OMPI_MCA_rmaps_base_oversubscribe="1", OMP_NUM_THREADS="1")
    tmp = tempfile.mkdtemp(prefix="stiffmd_ensemble_mpi_")
    try:
        deck = ensemble_deck(tmp, '"thermostat.seed" = [%d, %d, %d]' % tuple(SEEDS))
        out = os.path.join(tmp, "mpi")
        r = run([mpiexec, numproc_flag, str(n), stiffmd, "run", deck, "-o", out] + SHORT, env)
        if n > len(SEEDS):
            assert r.returncode == 2, (r.returncode, r.stderr)
            errors = [l for l in r.stderr.splitlines() if l.startswith("error: ")]
            assert len(errors) == 1, r.stderr
            assert f"{n} processes for 3 members" in errors[0] and "use at most 3" in errors[0], errors
            assert not os.path.exists(out)
            print(f"{n} processes for 3 members: refused")
            return
        assert r.returncode == 0, r.stderr
        assert f"3 members on {n} processes" in r.stdout, r.stdout
        # [parallel] divides one run among processes, and the members run whole: a grid is refused
        # at its key (the deck's line, or the --set), before anything is written.
        with open(deck) as f:
            text = f.read()
        gridded = os.path.join(tmp, "gridded.toml")
        with open(gridded, "w") as f:
            f.write(text + f"\n[parallel]\ngrid = [{n}, 1, 1]\n")
        line = text.count("\n") + 3
        for cmd, where in (([gridded], f"{gridded}:{line}: parallel.grid"),
                           ([deck, "--set", f"parallel.grid=[{n}, 1, 1]"], "--set parallel.grid: parallel.grid")):
            refused = os.path.join(tmp, "refused")
            g = run([mpiexec, numproc_flag, str(n), stiffmd, "run"] + cmd + ["-o", refused] + SHORT, env)
            errors = [l for l in g.stderr.splitlines() if l.startswith("error: ")]
            assert g.returncode == 2 and len(errors) == 1, (g.returncode, g.stderr)
            assert errors[0].startswith(f"error: {where}: {n} domains ({n} x 1 x 1) divide one run among ranks, and "
                                        f"an [ensemble] runs each member whole on one process (3 members on {n} "
                                        "processes): expected no grid"), errors
            assert not os.path.exists(refused)
        print(f"{n} processes: a [parallel] grid is refused at its key")
        summary = [l for l in r.stdout.splitlines() if l.startswith("member ")]
        assert [l.split(" ")[1] for l in summary] == ["0", "1", "2"], r.stdout  # once each, in order
        serial_out = os.path.join(tmp, "serial")
        s = run([stiffmd, "run", deck, "-o", serial_out, "-q"] + SHORT, dict(os.environ, OMP_NUM_THREADS="1"))
        assert s.returncode == 0, s.stderr
        for k in range(3):
            same_files(os.path.join(out, f"member_{k}"), os.path.join(serial_out, f"member_{k}"))
        print(f"{n} processes: every member's files equal the serial ensemble's")
    finally:
        shutil.rmtree(tmp)


if __name__ == "__main__":
    if sys.argv[1] == "serial":
        serial(sys.argv[2])
    else:
        mpi(sys.argv[2], sys.argv[3], sys.argv[4], int(sys.argv[5]))
