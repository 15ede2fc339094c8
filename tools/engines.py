"""Running the two engines, stiffmd and LAMMPS, and reading what a stiffmd run leaves behind.

The benchmark and study tools in tools/ all start runs the same way: one thread unless told
otherwise, the outputs in a run directory, a failure reported with the command and the tail of its
output. Their own measurements (drifts, observables, timings) stay in each tool; what is common is
here, imported as `import engines` (tools/ is the script's directory, and tests put it on sys.path).
"""
import csv
import json
import math
import os
import shlex
import subprocess
import time
from collections import namedtuple

import numpy as np

TIMEOUT = "timeout"  # the exit code of a run stopped by its time limit

Run = namedtuple("Run", "code stdout stderr seconds cmd")
Run.__doc__ = """A finished run: exit code (or TIMEOUT), its stdout and stderr text, wall seconds, the command."""


class RunFailed(Exception):
    """A run failed for a reason other than a numerical blow-up (bad input, missing binary...)."""


def whole_steps_t_end(t_end, h):
    """t_end as a whole number of macro steps h (stiffmd refuses any other): the run's own ceil, as text
    for --set. The 1e-9 keeps a t_end that is already a multiple of h from being rounded up by an ulp."""
    return repr(math.ceil(float(t_end) / float(h) - 1e-9) * float(h))


def engine_env(threads=1):
    """The environment of an engine run. threads: OMP_NUM_THREADS for the run (int or text), or None to
    leave the caller's setting (or the engine's default, every core) alone. Idle OpenMP threads wait
    passively unless the caller says otherwise, so that runs side by side do not steal each other's cores."""
    env = dict(os.environ)
    if threads is not None:
        env["OMP_NUM_THREADS"] = str(threads)
    env.setdefault("OMP_WAIT_POLICY", "passive")
    return env


def stiffmd_command(exe, deck, out_dir, sets=()):
    """The command line of `stiffmd run DECK -o OUT_DIR --no-progress`, one --set per override in sets."""
    cmd = [exe, "run", deck, "-o", out_dir, "--no-progress"]
    for s in sets:
        cmd += ["--set", s]
    return cmd


def lammps_command(lmp, lammps_input, log, echo=False):
    """The command line of a LAMMPS run of lammps_input, logging to log, nothing on the screen.
    echo: keep LAMMPS's default echo of the input commands into the log (off: the log holds output only)."""
    cmd = [lmp, "-in", lammps_input, "-log", log, "-screen", "none"]
    if not echo:
        cmd += ["-echo", "none"]
    return cmd + ["-nocite"]


def run_engine(cmd, threads=1, timeout=None, cwd=None):
    """Runs cmd to the end, output captured; returns a Run. threads: see engine_env. With a timeout
    (seconds) a run that takes longer is stopped and comes back with code TIMEOUT and no output."""
    start = time.monotonic()
    try:
        p = subprocess.run(cmd, capture_output=True, text=True, env=engine_env(threads), timeout=timeout, cwd=cwd)
        code, out, err = p.returncode, p.stdout, p.stderr
    except subprocess.TimeoutExpired:
        code, out, err = TIMEOUT, "", ""
    return Run(code, out, err, time.monotonic() - start, cmd)


def failure(run, what="stiffmd", chars=2000):
    """One message for a failed run: what failed, its exit code, the command, the end of its stderr."""
    return f"{what} failed (exit {run.code}): {shlex.join(map(str, run.cmd))}\n{run.stderr[-chars:]}"


def run_stiffmd(exe, deck, out_dir, sets=(), threads=1, timeout=None, accept=(0,), fail=None):
    """One `stiffmd run` (see stiffmd_command and run_engine); returns the Run. An exit code outside accept
    (e.g. (0, 3) where a numerical blow-up is a result, not an error; TIMEOUT where a timeout is) is a
    failure: fail(message) is called (sys.exit for a tool that stops there), or RunFailed raised."""
    run = run_engine(stiffmd_command(exe, deck, out_dir, sets), threads=threads, timeout=timeout)
    if run.code not in accept:
        message = failure(run)
        if fail is None:
            raise RunFailed(message)
        fail(message)
    return run


def run_lammps(lmp, lammps_input, log, cwd=None, threads=1, timeout=None, echo=False):
    """One LAMMPS run (see lammps_command and run_engine); returns the Run. Its exit code is the caller's
    to judge: a LAMMPS run that stops on lost atoms is a result for some tools and an error for others."""
    return run_engine(lammps_command(lmp, lammps_input, log, echo), threads=threads, timeout=timeout, cwd=cwd)


def tail(path, lines=15):
    """The last lines of a text file, or '' when it cannot be read."""
    try:
        with open(path, errors="replace") as f:
            return "".join(f.readlines()[-lines:])
    except OSError:
        return ""


def run_measured(cmd, run_dir, threads):
    """Runs cmd in run_dir (stdout/stderr to files there) with OMP_NUM_THREADS = threads.

    Returns (exit code, seconds, max RSS of that process in MiB). os.wait4 gives the rusage of
    exactly this child (and of children it waited for, none here)."""
    env = dict(os.environ, OMP_NUM_THREADS=str(threads))
    with open(os.path.join(run_dir, "stdout.txt"), "w") as out, open(os.path.join(run_dir, "stderr.txt"), "w") as err:
        start = time.monotonic()
        proc = subprocess.Popen(cmd, cwd=run_dir, stdout=out, stderr=err, env=env)
        _, status, usage = os.wait4(proc.pid, 0)
        seconds = time.monotonic() - start
    proc.returncode = os.waitstatus_to_exitcode(status)  # reaped here: tell Popen
    return proc.returncode, seconds, usage.ru_maxrss / 1024.0


def check_exit(code, cmd, run_dir, log="stdout.txt"):
    """A failed run_measured run: one line naming it, then the tail of its stderr (or of its log when
    stderr is empty)."""
    if code != 0:
        text = tail(os.path.join(run_dir, "stderr.txt")) or tail(os.path.join(run_dir, log))
        raise RunFailed(f"run failed (exit {code}): {shlex.join(cmd)}\n--- tail of its output ({run_dir}) ---\n{text}")


def read_summary(run_dir):
    """The summary.json a finished stiffmd run writes into its run directory, as a dict."""
    with open(os.path.join(run_dir, "summary.json")) as f:
        return json.load(f)


def read_thermo(path, missing_ok=False):
    """A stiffmd thermo.csv as {column: float array}, the columns in the header's order and named as there.

    A run stopped from outside (a timeout) may leave its last row cut short: reading stops at the first
    row with too few fields or a field that is not a number, so the arrays hold the rows written whole. A missing file raises
    FileNotFoundError, or with missing_ok gives {} (a run that stopped before its first row)."""
    try:
        f = open(path, newline="")
    except FileNotFoundError:
        if missing_ok:
            return {}
        raise
    with f:
        reader = csv.reader(f)
        header = next(reader, [])
        rows = []
        for row in reader:
            if not row:
                continue
            try:
                values = [float(v) for v in row]
            except ValueError:
                break
            if len(values) != len(header):
                break
            rows.append(values)
    data = np.array(rows, dtype=float).reshape(len(rows), len(header))
    return {name: data[:, k] for k, name in enumerate(header)}


def lammps_run_zero(input_text, out_dir, about, force_unit, lmp="lmp"):
    """LAMMPS's `run 0` of input_text, a reference for a test: the input must print one thermo row
    whose header starts `Step E_bond` and dump `forces.dump` (id fx fy fz, sorted by id). Writes
    out_dir/energies.txt (a `NAME value` line per thermo column, under a header naming LAMMPS's
    version and `about`: what was run and the command that reruns it) and out_dir/forces.txt."""
    import tempfile
    os.makedirs(out_dir, exist_ok=True)
    with tempfile.TemporaryDirectory() as d:
        with open(os.path.join(d, "in.run0"), "w") as f:
            f.write(input_text)
        log = subprocess.run([lmp, "-in", "in.run0", "-log", "none"], cwd=d, capture_output=True, text=True,
                             check=True).stdout.splitlines()
        head = next(k for k, line in enumerate(log) if line.split()[:2] == ["Step", "E_bond"])
        names, values = log[head].split()[1:], log[head + 1].split()[1:]
        version = subprocess.run([lmp, "-h"], capture_output=True, text=True).stdout.splitlines()[1].strip()
        with open(os.path.join(out_dir, "energies.txt"), "w") as f:
            f.write(f"# LAMMPS ({version}) {about}\n")
            for n, v in zip(names, values):
                f.write(f"{n} {v}\n")
        rows = open(os.path.join(d, "forces.dump")).read().splitlines()
        start = rows.index("ITEM: ATOMS id fx fy fz") + 1
        with open(os.path.join(out_dir, "forces.txt"), "w") as f:
            f.write(f"# id fx fy fz ({force_unit}), LAMMPS run 0 as energies.txt\n")
            for r in rows[start:]:
                i, *fx = r.split()
                f.write(i + " " + " ".join(f"{float(v):.12g}" for v in fx) + "\n")
