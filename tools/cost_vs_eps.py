#!/usr/bin/python3
"""Cost against ε on the stiff melt in NVT (docs/design.md §6): every method at its
largest step that keeps the equilibrium observables of the stiff springs.

    /usr/bin/python3 tools/cost_vs_eps.py                  # the README figure (≈ 30 min CPU, ≈ 20 wall, 2 jobs)
    /usr/bin/python3 tools/cost_vs_eps.py --eps 1e-2,1e-3  # a subset of ε
    /usr/bin/python3 tools/cost_vs_eps.py --quick --out /tmp/c --figure /tmp/c/c.png   # CI size, ≈ 5 s
    /usr/bin/python3 tools/cost_vs_eps.py --plot-only      # figure and tables from OUT/ladder.csv, cost.csv

Methods: velocity-verlet (BAOAB), impulse, projected-impulse, mollified-impulse (micro step δ = ε/10:
n = ceil(h/δ) micro steps per macro step h), rattle, fixman (RATTLE on U + Fixman's U_F, the thermal
stiff limit of docs/design.md §5; all these with the default splitting, BAOAB), rattle-obabo and
fixman-obabo (the same methods with `thermostat.splitting = "obabo"`: one SHAKE per step instead of
two; the run's command is kept in its directory, command.txt), and LAMMPS `run_style respa 2 n bond
1 pair 2` with `fix langevin` (same δ). Langevin kT = 1, damp = 1 everywhere; stiff harmonic bonds ℓ = 0.97, α = 1, WCA.

Two systems, because the statistics and the cost need different sizes (computational budget):

1. The largest step, on a small melt of the same density (0.85) and chains (100 beads, ℓ = 0.97):
   --chains (30) chains built by the engine (inputs/polymer_melt.toml's builder and relaxation), then
   equilibrated by fixman under Langevin for --t-equil; at every ε that state is prepared (projected,
   T = 1 velocities, thermal bond vibrations) and every run starts from it.

   Settings and seeds. A setting is a method at a step; the reference is velocity Verlet at h =
   --ref-h × ε (0.2: h ω_max = 0.4). Every setting runs --seeds (4) independent Langevin seeds from
   that one prepared state, the reference --ref-seeds (8), every run (the reference's too) for the
   same --t-run (2) time units. Seed k of a setting is crc32("TAG/seedk") mod 9e8 + 1, TAG naming ε,
   method and step (and "_ref"): deterministic, distinct, within LAMMPS's limit of 9e8; lammps-respa
   rows are seeded the same way. A run's value of an observable is its time average after --discard
   (0.5): ⟨cos θ⟩ and ⟨cos²θ⟩ of the bond angles (the first two moments of their law; frames every
   --frame-every), the radius of gyration averaged over the chains (from the same frames, the
   thermo's definition) and the pressure (thermo rows every --thermo-every).

   The criterion (tools/seed_statistics.py, as tools/trappe_pe.py's). A setting's value is the mean
   over its K seeds; per observable z = (mean − reference mean) / (s_p √(1/K + 1/K_ref)), s_p² =
   ((K−1) s² + (K_ref−1) s_ref²) / (K + K_ref − 2) the pooled seed-to-seed variance. Why seeds: the
   common start is equilibrated only --t-equil and the chains (Rouse time ~10⁴) barely move in a run,
   so the observables drift over a run. A run's average over the fixed window (--discard, --t-run]
   from that start is one draw of a random variable whose law any correct sampler of the same
   dynamics reproduces (up to its discretisation error), and its spread over independent seeds is the
   honest error of that draw; block errors within one run understate the spread of a drifting series,
   and windows of different lengths (the former 6-unit reference against 4-unit runs) compare
   different quantities — velocity Verlet failed against itself. What is compared is thus the law of
   --t-run windows from this start, not equilibrium values. Rg is tested like the others: each seed's
   chain-averaged Rg is one such draw. The former paired test (per-chain Rg differences, their mean
   against std/√chains) is dropped: it took the 30 chains of one run as independent samples, which
   the chains sharing one box and one start are not exactly, whereas seeds are independent by
   construction, and one rule for all four observables gives the false-alarm rate stated below.
   The limit: z is Student's t with K + K_ref − 2 degrees of freedom (10 by default), heavier-tailed
   than the normal, so a setting PASSES when every seed finished (an exit 3, a LAMMPS error or a
   non-finite average fails it; the seeds after a failing one are not run) and every |z| ≤ the t
   quantile at the two-sided tail probability of a --sigma normal test, erfc(σ/√2) = 0.0027 at 3σ
   (seed_statistics.sigma_threshold: 3.96 with 4 + 8 seeds, 6.62 with --quick's 3 + 3). A correct
   method (one whose discretisation error is below resolution) then fails an observable by chance
   with probability 0.27 %, a step (4 observables) with at most 1.1 %, and a whole ladder with at
   most 4.3 % (4 steps) or 8.6 % (8 steps): union bounds, valid whatever the correlations — ⟨cos θ⟩
   and ⟨cos²θ⟩ are strongly correlated and every step shares the reference's seeds, so the true
   rates are lower. (The former criterion: ≈ 5–10 % per step.) This assumes the per-seed averages
   normal (averages over 3 000 beads and 1.5 time units) with one variance for the method and the
   reference: with K < K_ref the pooled test raises more false alarms than stated for a method whose
   seed spread is larger than the reference's, fewer for a smaller one.

   Ladders. Each method climbs its ladder of steps (--vv-ladder × ε for velocity Verlet, --ladder for
   the others, --micro-ladder for the micro-step methods) from the smallest and stops at the first
   failing step; its largest step is the last passing one (velocity Verlet's first step is the
   reference itself, passing by definition). A method whose first step fails is marked FAILS and its
   cost is shown at that first step. Every seed's run is cached (work/runs/TAG/seedK/row.json, keyed
   by its settings): a rerun after an interruption reuses the finished seeds.

   CPU of the ladders with the defaults, estimated from the step-loop seconds of the ladders measured
   on the project's 2-core VM (docs/figures/cost_vs_eps_ladder.csv: 145 s for the 6-unit references, 485 s for
   the 4-unit ladder runs, 630 s in all, ≈ 12 min with the start-up and analysis of every run): a
   run's cost is proportional to its length, so the references now cost 8 × 2/6 × 145 ≈ 390 s, and
   the ladder steps 4 × 2/4 × 485 ≈ 970 s if the ladders stop where they did (1 360 s in all,
   23 min, 2.2×) or at most ≈ 1 340 s if every ladder climbed to its top (cost per unit time a + b/h
   fitted per method; fewer chance failures of correct methods let some ladders climb further:
   1 730 s in all, 29 min, 2.7×); plus ≈ 0.07 s of start-up and analysis per run (≈ 480–760 runs,
   < 1 min; measured at ε = 1e-2). The timed runs of 2 (≈ 4 min) are unchanged.
   Velocity Verlet at the smallest ε dominates (steps of 0.2–0.8 ε): at ε = 1e-4 its reference is
   8 × 2 × 16 s ≈ 260 s and its ladder ≤ 4 × 2 × 30 s ≈ 240 s.
2. The cost, on LAMMPS's data.chain (32 000 beads; inputs/lammps_chain.toml prepared at each ε) at
   the step found in 1: short timed runs (--timed-steps = 150 steps; micro-step methods max(10,
   --timed-micro / n) macro steps, --timed-micro = 1500), one thread, --repeats interleaved repeats, median. CPU seconds of
   the step loop (stiffmd summary.json; LAMMPS Loop time × CPU %) per unit of simulated time, and
   wall seconds the same way. Before a method without micro steps (velocity Verlet, rattle, fixman)
   is timed at a step, a stability run on the timing system must finish: --stable-time = 20 time
   units (640 000 bead-time units, 27× a ladder step's 4 × 2 × 3 000), at most --stable-steps = 2000
   steps; the 150-step timed runs alone (4 units at h = 0.028) let fixman through at h = 0.028 by
   chance on one noise and stopped it on another (a close WCA encounter every few hundred steps
   there). The micro-step methods are not checked so (20 units at ε = 1e-4 would be 400 000 micro
   steps per method and step); their largest steps are 0.02 or less.

Outputs in --out (default sweeps/cost_vs_eps): ladder.csv (a row per setting of 1: the number of
seeds, status, pass, the limit on |z|; per observable the mean over seeds, the pooled standard error
(on the reference's row its own s/√K_ref), z (0 on the reference's row) and the per-seed values
joined by ';' (q_seeds, enough to recompute the criterion); the thermostat seeds, frames per run and
the CPU seconds summed over the seeds), cost.csv (every timed run), cost_vs_eps.md (the table),
work/ (states, decks, runs).
Figure: --figure (default docs/figures/cost_vs_eps.png).
"""
import argparse
import concurrent.futures
import csv
import json
import math
import os
import shlex
import shutil
import statistics
import subprocess
import sys
import threading
import zlib

import numpy as np

from bench_lammps import parse_lammps_log  # tools/ is the script's directory
from chain_melt import (engine_method, fmt, prepare_state, read_bonds, write_deck, write_lammps_input,
                        xyz_frames)
from engines import RunFailed, read_summary, run_measured
import seed_statistics

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
METHODS = ["velocity-verlet", "impulse", "projected-impulse", "mollified-impulse", "rattle", "fixman", "rattle-obabo",
           "fixman-obabo", "lammps-respa"]
MICRO = {"impulse", "projected-impulse", "mollified-impulse", "lammps-respa"}


def with_splitting(cmd, method, run_dir):
    """cmd with the row's splitting overrides; the command is kept in run_dir/command.txt."""
    for o in engine_method(method)[1]:
        cmd = cmd + ["--set", o]
    with open(os.path.join(run_dir, "command.txt"), "w") as f:
        f.write(shlex.join(cmd) + "\n")
    return cmd
OBSERVABLES = ["cos", "cos2", "rg", "pressure"]
WRITER = "tools/cost_vs_eps.py"
KT, DAMP = 1.0, 1.0
LADDER_FIELDS = ["eps", "method", "h", "n", "t_end", "seeds", "status", "passed", "limit"] + \
    [f"{q}{s}" for q in OBSERVABLES for s in ("", "_err", "_z", "_seeds")] + ["thermostat_seeds", "frames",
                                                                             "cpu_seconds"]
COST_FIELDS = ["eps", "method", "h", "n", "steps", "repeat", "natoms", "status", "cpu_per_time", "wall_per_time"]


def split_floats(text):
    return [float(v) for v in text.replace(",", " ").split()]


# ------------------------------------------------------------------------- the small melt's state

def equilibrated_melt(args, work):
    """Builds --chains chains of --beads with inputs/polymer_melt.toml's builder, equilibrates them by
    fixman under Langevin for --t-equil and writes the final state; returns its data file."""
    data = os.path.join(work, "equilibrated.data")
    if os.path.exists(data):
        return data
    with open(os.path.join(ROOT, "inputs", "polymer_melt.toml")) as f:
        deck = f.read().replace("chains = 100", f"chains = {args.chains}").replace("beads = 100",
                                                                                   f"beads = {args.beads}")
    build = os.path.join(work, "build.toml")
    with open(build, "w") as f:
        f.write(f"# Written by {WRITER}: inputs/polymer_melt.toml with {args.chains} chains of {args.beads}.\n" + deck)
    run_dir = os.path.join(work, "equilibrate")
    cmd = [args.stiffmd, "run", build, "--no-progress", "-o", run_dir, "--set", 'integrator.method="fixman"',
           "--set", "integrator.h=0.005", "--set", f"run.t_end={fmt(args.t_equil)}",
           "--set", 'thermostat.style="langevin"', "--set", f"thermostat.temperature={fmt(KT)}",
           "--set", f"thermostat.damp={fmt(DAMP)}", "--set", "thermostat.seed=5", "--set", 'output.xyz=""',
           "--set", 'output.h5md=""', "--set", "output.checkpoint_interval=0",
           "--set", f"output.thermo_interval={fmt(args.t_equil)}", "--set", 'output.lammps_data="final.data"']
    p = subprocess.run(cmd, capture_output=True, text=True, env=dict(os.environ, OMP_NUM_THREADS="1"))
    if p.returncode != 0:
        raise RunFailed(f"equilibration failed (exit {p.returncode}): {shlex.join(cmd)}\n{p.stderr[-2000:]}")
    os.replace(os.path.join(run_dir, "final.data"), data)
    return data


def source_deck(path, data):
    """A deck that prepares `data` at ε = variables.eps (as inputs/lammps_chain.toml prepares data.chain)."""
    with open(os.path.join(ROOT, "inputs", "lammps_chain.toml")) as f:
        text = f.read()
    start = text.index("[variables]")
    text = text[start:].replace("/usr/share/lammps/examples/COUPLE/multiple/data.chain", data)
    with open(path, "w") as f:
        f.write(f"# Written by {WRITER}: inputs/lammps_chain.toml on the equilibrated small melt.\n" + text)
    return path


# ------------------------------------------------------------------------------- one run of ladder

class Chains:
    """The chains of a state (consecutive atoms bonded i–i+1), its bond-angle triples and its box."""

    def __init__(self, data):
        bonds = read_bonds(data)
        with open(data) as f:
            lines = f.read().split("\n")
        self.box = float(next(line for line in lines if line.endswith("xlo xhi")).split()[1])
        self.natoms = next(int(line.split()[0]) for line in lines if line.strip().endswith(" atoms"))
        bonded = np.zeros(self.natoms - 1, dtype=bool)
        for i, j in bonds:
            i, j = min(i, j), max(i, j)
            if j != i + 1:
                raise RunFailed(f"{data}: bond {i + 1}-{j + 1} does not join consecutive atoms")
            bonded[i] = True
        self.bonded = bonded
        self.starts = np.concatenate(([0], np.nonzero(~bonded)[0] + 1))
        middle = np.nonzero(bonded[:-1] & bonded[1:])[0] + 1  # atoms with a bond on both sides
        self.triples = np.stack((middle - 1, middle, middle + 1), axis=1)

    def measure(self, x):
        """(<cos θ>, <cos²θ>, Rg of every chain) of one frame; θ: the angle i-j-k, 180° = straight."""
        d = x[1:] - x[:-1]
        wrapped = d - self.box * np.round(d / self.box)
        d = np.where(self.bonded[:, None], wrapped, d)  # raw across chain ends: each chain restarts at its atom
        u = np.vstack((x[:1], x[:1] + np.cumsum(d, axis=0)))
        a = -wrapped[self.triples[:, 0]]  # x_i - x_j
        b = wrapped[self.triples[:, 1]]  # x_k - x_j
        c = np.einsum("ij,ij->i", a, b) / np.linalg.norm(a, axis=1) / np.linalg.norm(b, axis=1)
        counts = np.diff(np.append(self.starts, self.natoms))
        mean = np.add.reduceat(u, self.starts, axis=0) / counts[:, None]
        sq = np.add.reduceat((u * u).sum(axis=1), self.starts) / counts
        rg = np.sqrt(np.maximum(sq - (mean * mean).sum(axis=1), 0.0))
        return c.mean(), (c * c).mean(), rg


def lammps_frames(path):
    """(step, positions sorted by id) of every frame of a LAMMPS `dump custom id mol xu yu zu`."""
    with open(path) as f:
        while True:
            line = f.readline()
            if not line:
                return
            step = int(f.readline())
            f.readline()
            n = int(f.readline())
            for _ in range(5):  # ITEM: BOX BOUNDS, its 3 lines, ITEM: ATOMS
                f.readline()
            yield step, np.loadtxt([f.readline() for _ in range(n)], usecols=(2, 3, 4), ndmin=2)


def lammps_pressure(log):
    """(step, pressure) rows of the thermo of a LAMMPS log."""
    rows, columns = [], None
    with open(log, errors="replace") as f:
        for line in f:
            words = line.split()
            if words[:1] == ["Step"]:
                columns = words
            elif line.startswith("Loop time"):
                columns = None
            elif columns and len(words) == len(columns):
                try:
                    rows.append((int(words[0]), float(words[columns.index("Press")])))
                except ValueError:
                    columns = None
    return rows


def micro_steps(args, eps, h, method):
    return math.ceil(h / (eps / args.micro_per_eps) * (1 - 1e-9)) if method in MICRO else 1


def run_tag(eps, method, h, reference=False):
    """The name of a setting (its runs are in work/runs/TAG/seedK)."""
    return f"eps{eps:g}_{method}_h{h:.6g}" + ("_ref" if reference else "")


def thermostat_seed(tag, k):
    """Seed k of a setting: from the tag and k (crc32), in 1 … 9e8 (LAMMPS's Marsaglia generator takes
    at most 9e8; stiffmd takes the same): every run its own noise, the same at a rerun."""
    return zlib.crc32(f"{tag}/seed{k}".encode()) % 900000000 + 1


def run_one(args, eps, method, h, state, chains, work, k, reference=False):
    """Seed k of a setting (the reference when `reference`) at about the step h (rounded to divide
    --t-run); returns its time averages after --discard. Its row is kept in the run's directory
    (row.json) and reused by a rerun with the same settings, as are the outputs of a finished run that
    was not analysed: an interrupted ladder resumes at its first unfinished seed."""
    tag = run_tag(eps, method, h, reference)
    t_end = args.t_run
    steps = round(t_end / h)
    h = t_end / steps  # a whole number of steps
    n = micro_steps(args, eps, h, method)
    run_dir = os.path.join(work, "runs", tag, f"seed{k}")
    os.makedirs(run_dir, exist_ok=True)
    seed = thermostat_seed(tag, k)
    row = {"eps": eps, "method": method, "h": h, "n": n, "t_end": t_end, "seed": seed, "status": "ok"}
    key = {"eps": eps, "method": method, "h": h, "n": n, "t_end": t_end, "seed": seed, "discard": args.discard,
           "frame_every": args.frame_every, "thermo_every": args.thermo_every, "state": os.path.abspath(state)}
    cached = os.path.join(run_dir, "row.json")
    if os.path.exists(cached):
        with open(cached) as f:
            kept = json.load(f)
        if kept["key"] == key:
            return kept["row"]
    row = measure_run(args, eps, method, h, n, t_end, steps, seed, state, chains, run_dir, row)
    with open(cached, "w") as f:
        json.dump({"key": key, "row": row}, f)
    return row


def finished_earlier(run_dir, h, steps):
    """A stiffmd run in run_dir that finished with this h and these steps and was not analysed."""
    try:
        s = read_summary(run_dir)
    except (OSError, ValueError):
        return False
    return s["steps"] == steps and math.isclose(s["h"], h, rel_tol=1e-12) and \
        os.path.exists(os.path.join(run_dir, "frames.xyz"))


def measure_run(args, eps, method, h, n, t_end, steps, seed, state, chains, run_dir, row):
    if method == "lammps-respa":
        lmp_in = os.path.join(run_dir, "in.run")
        every = max(1, round(args.frame_every / h))
        write_lammps_input(lmp_in, state, eps, h, n, steps, max(1, round(args.thermo_every / h)), WRITER,
                           langevin=(KT, DAMP, seed), dump=(every, "frames.dump"))
        cmd = [args.lmp, "-in", lmp_in, "-log", "log.lammps", "-screen", "none", "-echo", "none", "-nocite"]
        code, _, _ = run_measured(cmd, run_dir, 1)
        log = os.path.join(run_dir, "log.lammps")
        try:
            loop, done, cpu_percent, _, _, _ = parse_lammps_log(log)
        except (RunFailed, OSError):
            loop, done, cpu_percent = None, 0, float("nan")
        if code != 0 or done != steps:
            row["status"] = f"failed (exit {code})"
            return row
        row["cpu_seconds"] = loop * cpu_percent / 100.0
        frames = [(s * h, x) for s, x in lammps_frames(os.path.join(run_dir, "frames.dump"))]
        pressure = [(s * h, p) for s, p in lammps_pressure(log)]
        os.remove(os.path.join(run_dir, "frames.dump"))
    else:
        deck = os.path.join(run_dir, "run.toml")
        write_deck(deck, state, eps, WRITER, engine_method(method)[0], h, n, t_end, args.thermo_every)
        cmd = with_splitting([args.stiffmd, "run", deck, "--no-progress", "-o", run_dir,
                              "--set", 'thermostat.style="langevin"', "--set", f"thermostat.temperature={fmt(KT)}",
                              "--set", f"thermostat.damp={fmt(DAMP)}", "--set", f"thermostat.seed={seed}",
                              "--set", 'output.xyz="frames.xyz"', "--set", f"output.xyz_interval={fmt(args.frame_every)}",
                              "--set", "output.checkpoint_interval=0"], method, run_dir)
        code = 0 if finished_earlier(run_dir, h, steps) else run_measured(cmd, run_dir, 1)[0]
        if code != 0:
            row["status"] = f"failed (exit {code})"
            return row
        row["cpu_seconds"] = read_summary(run_dir)["cpu_seconds"]
        frames = list(xyz_frames(os.path.join(run_dir, "frames.xyz")))
        with open(os.path.join(run_dir, "thermo.csv")) as f:
            pressure = [(float(r["time"]), float(r["pressure"])) for r in csv.DictReader(f)]
        for name in ("frames.xyz", "checkpoint.bin"):
            if os.path.exists(os.path.join(run_dir, name)):
                os.remove(os.path.join(run_dir, name))
    frames = [chains.measure(x) for t, x in frames if t > args.discard + 1e-9]
    pressure = [p for t, p in pressure if t > args.discard + 1e-9]
    row["frames"] = len(frames)
    if len(frames) < 2 or len(pressure) < 2:
        raise RunFailed(f"{run_dir}: {len(frames)} frames, {len(pressure)} thermo rows after t = {args.discard}: "
                        "lengthen --t-run or shorten --discard, --frame-every, --thermo-every")
    # The run's time averages: one draw each of the random variables the criterion compares.
    row["cos"] = float(np.mean([f[0] for f in frames]))
    row["cos2"] = float(np.mean([f[1] for f in frames]))
    row["rg"] = float(np.mean([f[2].mean() for f in frames]))  # the mean over chains, averaged over the frames
    row["pressure"] = float(np.mean(pressure))
    if not all(math.isfinite(row[q]) for q in OBSERVABLES):
        row["status"] = "failed (non-finite)"
    return row


def setting(args, eps, method, h, seeds, state, chains, work, reference=False):
    """A setting run with `seeds` seeds (stopping at the first failing seed); its row of ladder.csv
    before the judgement: the per-seed values, their mean and s/√K, the status."""
    runs = []
    for k in range(seeds):
        r = run_one(args, eps, method, h, state, chains, work, k, reference)
        runs.append(r)
        if r["status"] != "ok":
            break
    first = runs[0]
    row = {"eps": eps, "method": method, "h": first["h"], "n": first["n"], "t_end": first["t_end"],
           "seeds": len(runs), "status": "ok", "thermostat_seeds": ";".join(str(r["seed"]) for r in runs),
           "frames": min(r.get("frames", 0) for r in runs), "cpu_seconds": sum(r.get("cpu_seconds", 0.0) for r in runs)}
    bad = next((k for k, r in enumerate(runs) if r["status"] != "ok"), None)
    if bad is not None:
        row["status"] = f"{runs[bad]['status']} at seed {bad}"
    ok = [r for r in runs if r["status"] == "ok"]
    stats = seed_statistics.ensemble(ok, OBSERVABLES) if len(ok) > 1 else None
    for q in OBSERVABLES:
        row[q + "_per_seed"] = [r[q] for r in ok]
        row[q + "_seeds"] = ";".join(repr(r[q]) for r in ok)
        row[q], row[q + "_err"] = stats[q] if stats else (float("nan"), float("nan"))
    return row


def judge(row, ref, args):
    """The criterion: per observable z = (mean − reference mean) / the pooled seed standard error
    s_p √(1/K + 1/K_ref); the setting passes when it finished and every |z| ≤ the Student-t limit of
    --sigma with K + K_ref − 2 degrees of freedom (seed_statistics.sigma_threshold)."""
    row["limit"] = seed_statistics.sigma_threshold(args.sigma, row["seeds"] + ref["seeds"] - 2)
    if row["status"] != "ok":
        row["passed"] = False
        return row
    for q in OBSERVABLES:
        row[q + "_err"] = seed_statistics.pooled_se(row[q + "_per_seed"], ref[q + "_per_seed"])
        row[q + "_z"] = seed_statistics.pooled_z(row[q + "_per_seed"], ref[q + "_per_seed"])
    row["passed"] = seed_statistics.within([row[q + "_z"] for q in OBSERVABLES], row["limit"])
    return row


def ladder_of(args, eps, method):
    if method == "velocity-verlet":
        return [r * eps for r in args.vv_ladder]
    return args.micro_ladder if method in MICRO else args.ladder


def climb(args, eps, method, ref, state, chains, work, log):
    """Runs the method up its ladder until the first failing step; returns the rows."""
    rows = []
    if method == "velocity-verlet":  # the reference is the first step
        rows.append(dict(ref, passed=True, limit="", **{q + "_z": 0.0 for q in OBSERVABLES}))
    for h in ladder_of(args, eps, method):
        row = judge(setting(args, eps, method, h, args.seeds, state, chains, work), ref, args)
        rows.append(row)
        log(f"eps {eps:g} {method:18s} h {h:.4g} n {row['n']}: {row['status']}, "
            + ("PASS" if row["passed"] else "fail")
            + "".join(f" {q} {row.get(q + '_z', float('nan')):+.1f}" for q in OBSERVABLES)
            + f" (|z| ≤ {row['limit']:.2f}, {row['seeds']}+{ref['seeds']} seeds)")
        if not row["passed"]:
            break
    return rows


def passing_steps(rows):
    """[(h, n)] of the passing steps before the first failure, largest first; else [the first step]."""
    passing = []
    for r in rows:
        if not r["passed"]:
            break
        passing.append((r["h"], r["n"]))
    return passing[::-1] or [(rows[0]["h"], rows[0]["n"])]


def largest_step(rows):
    """(h, n, passed) of the largest passing step before the first failure, else the first step tried."""
    best = None
    for r in rows:
        if not r["passed"]:
            break
        best = r
    if best is None:
        return rows[0]["h"], rows[0]["n"], False
    return best["h"], best["n"], True


# ------------------------------------------------------------------------------------------ cost

def kept_result(run_dir, name, key, compute):
    """compute()'s result, kept in run_dir/name with its settings (key) and reused by a rerun with the
    same settings (so that ε subsets can be run apart and assembled by the full command)."""
    os.makedirs(run_dir, exist_ok=True)
    cached = os.path.join(run_dir, name)
    if os.path.exists(cached):
        with open(cached) as f:
            kept = json.load(f)
        if kept["key"] == key:
            return kept["row"]
    row = compute()
    with open(cached, "w") as f:
        json.dump({"key": key, "row": row}, f)
    return row


def stiffmd_on_timing_system(args, deck, run_dir, seed):
    """The stiffmd command of a run of deck on the timing system: Langevin at kT, damp, seed."""
    return [args.stiffmd, "run", deck, "--no-progress", "-o", run_dir,
            "--set", 'thermostat.style="langevin"', "--set", f"thermostat.temperature={fmt(KT)}",
            "--set", f"thermostat.damp={fmt(DAMP)}", "--set", f"thermostat.seed={seed}",
            "--set", "output.checkpoint_interval=0"]


def timed_run(args, eps, method, h, n, state, work, repeat):
    """One timed run; its row is kept in its directory (timed.json)."""
    steps = max(10, math.ceil(args.timed_micro / n)) if method in MICRO else args.timed_steps
    run_dir = os.path.join(work, "timed", f"eps{eps:g}_{method}_h{h:.6g}_r{repeat}")
    key = {"eps": eps, "method": method, "h": h, "n": n, "steps": steps, "state": os.path.abspath(state)}
    return kept_result(run_dir, "timed.json", key,
                       lambda: timed_measure(args, eps, method, h, n, steps, state, run_dir, repeat))


def stable_on_timing_system(args, eps, method, h, n, state, work):
    """Whether a method without micro steps runs max(--timed-steps, min(--stable-time / h,
    --stable-steps)) steps at h on the timing system without a numerical failure (exit 3), on two
    threads (not timed; the verdict is not a timing); kept in work/stable/…/stable.json like the timed
    runs. Micro-step methods are not checked (True)."""
    if method in MICRO:
        return True
    steps = max(args.timed_steps, min(math.ceil(args.stable_time / h - 1e-9), args.stable_steps))
    run_dir = os.path.join(work, "stable", f"eps{eps:g}_{method}_h{h:.6g}")
    key = {"eps": eps, "method": method, "h": h, "n": n, "steps": steps, "state": os.path.abspath(state)}

    def run():
        deck = os.path.join(run_dir, "run.toml")
        write_deck(deck, state, eps, WRITER, engine_method(method)[0], h, n, steps * h, steps * h)
        cmd = with_splitting(stiffmd_on_timing_system(args, deck, run_dir, 4713), method, run_dir)
        code, _, _ = run_measured(cmd, run_dir, 2)
        if code not in (0, 3):
            raise RunFailed(f"stability run failed (exit {code}): {shlex.join(cmd)}")
        if os.path.exists(os.path.join(run_dir, "checkpoint.bin")):
            os.remove(os.path.join(run_dir, "checkpoint.bin"))
        return {"stable": code == 0, "steps": steps}

    return kept_result(run_dir, "stable.json", key, run)["stable"]


def timed_measure(args, eps, method, h, n, steps, state, run_dir, repeat):
    if method == "lammps-respa":
        lmp_in = os.path.join(run_dir, "in.run")
        write_lammps_input(lmp_in, state, eps, h, n, steps, steps, WRITER, langevin=(KT, DAMP, 4711))
        cmd = [args.lmp, "-in", lmp_in, "-log", "log.lammps", "-screen", "none", "-echo", "none", "-nocite"]
        code, _, _ = run_measured(cmd, run_dir, 1)
        if code != 0:
            return failed_timing(eps, method, h, n, repeat, f"LAMMPS exit {code}")
        loop, done, cpu_percent, _, _, _ = parse_lammps_log(os.path.join(run_dir, "log.lammps"))
        # LAMMPS prints its CPU use with one decimal; a loop too short for its clock reads 0.0 %
        # (the --quick runs): then the loop's wall time stands for its CPU time.
        wall, cpu = loop, (loop * cpu_percent / 100.0 if cpu_percent > 0 else loop)
    else:
        deck = os.path.join(run_dir, "run.toml")
        write_deck(deck, state, eps, WRITER, engine_method(method)[0], h, n, steps * h, steps * h)
        cmd = with_splitting(stiffmd_on_timing_system(args, deck, run_dir, 4711), method, run_dir)
        code, _, _ = run_measured(cmd, run_dir, 1)
        if code == 3:  # a numerical failure at this step on the larger system: the caller steps down
            return failed_timing(eps, method, h, n, repeat, "exit 3")
        if code != 0:
            raise RunFailed(f"timed run failed (exit {code}): {shlex.join(cmd)}")
        s = read_summary(run_dir)
        wall, cpu, done = s["wall_seconds"], s["cpu_seconds"], s["steps"]
        if os.path.exists(os.path.join(run_dir, "checkpoint.bin")):
            os.remove(os.path.join(run_dir, "checkpoint.bin"))
    return {"eps": eps, "method": method, "h": h, "n": n, "steps": done, "repeat": repeat, "status": "ok",
            "cpu_per_time": cpu / (done * h), "wall_per_time": wall / (done * h)}


def failed_timing(eps, method, h, n, repeat, why):
    """The row of a timed run that did not finish (NaN costs)."""
    return {"eps": eps, "method": method, "h": h, "n": n, "steps": 0, "repeat": repeat, "status": f"failed ({why})",
            "cpu_per_time": float("nan"), "wall_per_time": float("nan")}


# ----------------------------------------------------------------------------------- the outputs

def read_csv(path):
    with open(path) as f:
        return list(csv.DictReader(f))


def summarise(ladder_rows, cost_rows, args):
    """One row per (ε, method): largest step, pass/fail and the median cost."""
    out = []
    for eps in sorted({float(r["eps"]) for r in ladder_rows}, reverse=True):
        for m in METHODS:
            rows = [r for r in ladder_rows if float(r["eps"]) == eps and r["method"] == m]
            if not rows:
                continue
            rows = [dict(r, passed=str(r["passed"]) == "True", h=float(r["h"]), n=int(r["n"])) for r in rows]
            h, n, ok = largest_step(rows)
            timed = [r for r in cost_rows if float(r["eps"]) == eps and r["method"] == m]
            costs = [r for r in timed if r.get("status", "ok") == "ok"]
            # Steps that kept the observables on the small melt but failed (exit 3) on the timing
            # system: the largest step is the largest that also ran there.
            unstable = sorted({float(r["h"]) for r in timed if r.get("status", "ok") != "ok"}, reverse=True)
            if costs:
                h, n = float(costs[0]["h"]), int(costs[0]["n"])
            cpu = statistics.median(float(r["cpu_per_time"]) for r in costs) if costs else float("nan")
            wall = statistics.median(float(r["wall_per_time"]) for r in costs) if costs else float("nan")
            first_fail = next((r for r in rows if not r["passed"]), None)
            out.append({"eps": eps, "method": m, "h": h, "n": n, "passed": ok, "cpu": cpu, "wall": wall,
                        "natoms": int(costs[0]["natoms"]) if costs else 0,
                        "unstable": unstable,
                        "stopped": "; ".join(
                            [f"{u:.4g}: exit 3 on the timing system" for u in unstable] +
                            ([] if first_fail is None else [f"{first_fail['h']:.4g}: " + failing(first_fail, args.sigma)]))})
    return out


def failing(row, sigma):
    """What failed a ladder step: its status, or its observables beyond the limit (z, the limit; a
    ladder.csv written before the limit column had its limit at --sigma)."""
    if row["status"] != "ok":
        return row["status"]
    limit = float(row.get("limit") or sigma)
    return ", ".join(f"{q} {float(row[q + '_z']):+.1f}" for q in OBSERVABLES
                     if not abs(float(row[q + "_z"])) <= limit) + f" (|z| > {limit:.2f})"


def markdown(summary, args):
    lines = [f"Largest step: on a melt of {args.chains} chains × {args.beads} beads, every setting {args.seeds} "
             f"independent thermostat seeds ({args.ref_seeds} for the reference, velocity Verlet at h = "
             f"{args.ref_h:g} ε) from one start, each run {args.t_run:g} time units averaged after {args.discard:g}; "
             f"pass = every observable's z = Δ / (pooled seed standard error) within the Student-t limit of "
             f"{args.sigma:g} σ ({math.erfc(args.sigma / math.sqrt(2)):.2g} two-sided) with K + K_ref − 2 degrees "
             f"of freedom ({seed_statistics.sigma_threshold(args.sigma, args.seeds + args.ref_seeds - 2):.2f} here). "
             f"Cost: CPU (wall) s per unit time, one thread, median of {args.repeats}, on "
             f"{summary[0]['natoms'] if summary else '?'} beads.", "",
             "| ε | method | largest step h (n) | observables | CPU s / time unit | wall s / time unit | "
             "÷ velocity Verlet (CPU) | first failing step |",
             "|---|---|--:|---|--:|--:|--:|---|"]
    for s in summary:
        vv = next((t["cpu"] for t in summary if t["eps"] == s["eps"] and t["method"] == "velocity-verlet"), None)
        n = f" ({s['n']})" if s["method"] in MICRO else ""
        lines.append(f"| {s['eps']:g} | {s['method']} | {s['h']:.4g}{n} | {'kept' if s['passed'] else '**FAILS**'} "
                     f"| {s['cpu']:.3g} | {s['wall']:.3g} | {vv / s['cpu'] if vv else float('nan'):.2f} | "
                     f"{s['stopped'] or '–'} |")
    return "\n".join(lines) + "\n"


def figure(summary, path):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    style = {"velocity-verlet": ("k", "o"), "impulse": ("tab:orange", "v"), "projected-impulse": ("tab:green", "^"),
             "mollified-impulse": ("tab:olive", "D"), "rattle": ("tab:red", "s"), "fixman": ("tab:blue", "*"),
             "rattle-obabo": ("tab:pink", "s"), "fixman-obabo": ("tab:cyan", "*"), "lammps-respa": ("tab:purple", "P")}
    fig, ax = plt.subplots(figsize=(7.0, 5.0))
    for m in METHODS:
        pts = [s for s in summary if s["method"] == m and math.isfinite(s["cpu"])]
        if not pts:
            continue
        colour, marker = style[m]
        ax.plot([s["eps"] for s in pts], [s["cpu"] for s in pts], color=colour, ls="-" if all(
            s["passed"] for s in pts) else ":", lw=1.2, label=m + ("" if all(s["passed"] for s in pts) else " (× fails)"))
        for s in pts:
            ax.plot(s["eps"], s["cpu"], marker=marker if s["passed"] else "x", color=colour, ms=8 if s["passed"] else 9,
                    mfc=colour if s["passed"] else "none", ls="")
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("ε (stiff bonds, ω_max = 2α/ε)")
    ax.set_ylabel("CPU seconds per unit simulated time (one thread)")
    ax.set_title("stiff melt in NVT: each method at its largest step keeping the observables\n"
                 "(step found on a 3000-bead melt, cost measured on data.chain, 32 000 beads)", fontsize=9)
    ax.legend(fontsize=8)
    ax.grid(True, which="both", alpha=0.3)
    fig.tight_layout()
    os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
    fig.savefig(path, dpi=120)


# ------------------------------------------------------------------------------------------ main

def parse_args():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--eps", default="1e-2,3e-3,1e-3,3e-4,1e-4")
    ap.add_argument("--methods", default=",".join(METHODS))
    ap.add_argument("--chains", type=int, default=30)
    ap.add_argument("--beads", type=int, default=100)
    ap.add_argument("--t-equil", type=float, default=10.0)
    ap.add_argument("--t-run", type=float, default=2.0, help="the length of every run, the reference's too")
    ap.add_argument("--discard", type=float, default=0.5, help="left out of every run's time averages")
    ap.add_argument("--seeds", type=int, default=4, help="thermostat seeds per ladder step")
    ap.add_argument("--ref-seeds", type=int, default=8, help="thermostat seeds of the reference")
    ap.add_argument("--sigma", type=float, default=3.0,
                    help="the criterion's normal-equivalent σ: the limit on |z| is the Student-t quantile "
                         "with K + K_ref − 2 degrees of freedom at the two-sided tail of a σ normal test")
    ap.add_argument("--frame-every", type=float, default=0.05)
    ap.add_argument("--thermo-every", type=float, default=0.01)
    ap.add_argument("--micro-per-eps", type=float, default=10.0, help="micro step δ = ε / this")
    ap.add_argument("--ref-h", type=float, default=0.2, help="the reference's h / ε")
    ap.add_argument("--vv-ladder", default="0.283,0.4,0.566,0.8,0.9", help="velocity Verlet's steps / ε (its stability limit is ε: h ω_max < 2, ω_max = 2α/ε)")
    ap.add_argument("--ladder", default="0.0025,0.0035,0.005,0.007,0.01,0.014,0.02,0.028",
                    help="rattle's and fixman's steps")
    ap.add_argument("--micro-ladder", default="0.0025,0.005,0.01,0.02", help="the micro-step methods' macro steps")
    ap.add_argument("--timing", choices=["data.chain", "small"], default="data.chain",
                    help="the system the cost is measured on")
    ap.add_argument("--timed-steps", type=int, default=150)
    ap.add_argument("--timed-micro", type=int, default=1500)
    ap.add_argument("--stable-time", type=float, default=20.0,
                    help="time units a method without micro steps must run on the timing system before it is timed")
    ap.add_argument("--stable-steps", type=int, default=2000, help="at most this many steps of that run")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--jobs", type=int, default=2, help="ladder runs at once (the timed runs are serial)")
    ap.add_argument("--quick", action="store_true",
                    help="CI size: 8 chains of 20, ε 1e-2 and 3e-3, short runs, cost on the small melt")
    ap.add_argument("--stiffmd", default=os.path.join(ROOT, "build", "stiffmd"))
    ap.add_argument("--lmp", default="lmp")
    ap.add_argument("--out", default=os.path.join(ROOT, "sweeps", "cost_vs_eps"))
    ap.add_argument("--figure", default=os.path.join(ROOT, "docs", "figures", "cost_vs_eps.png"))
    ap.add_argument("--plot-only", action="store_true")
    ap.add_argument("--timing-only", action="store_true", help="the timed runs at the steps of OUT/ladder.csv")
    ap.add_argument("--no-timing", action="store_true", help="the ladders only (OUT/ladder.csv)")
    args = ap.parse_args()
    if args.quick:
        args.eps = "1e-2,3e-3" if args.eps == ap.get_default("eps") else args.eps
        args.chains, args.beads, args.t_equil, args.t_run, args.discard = 8, 20, 0.5, 0.3, 0.05
        args.frame_every, args.thermo_every, args.timing = 0.025, 0.01, "small"
        args.seeds = 3 if args.seeds == ap.get_default("seeds") else args.seeds
        args.ref_seeds = 3 if args.ref_seeds == ap.get_default("ref_seeds") else args.ref_seeds
        args.ladder, args.micro_ladder, args.vv_ladder = "0.005,0.01", "0.005,0.01", "0.4"
        args.timed_steps, args.timed_micro, args.repeats = 20, 100, 1
        args.stable_time = 0.5 if args.stable_time == ap.get_default("stable_time") else args.stable_time
    args.eps = split_floats(args.eps)
    args.methods = [m for m in args.methods.replace(",", " ").split()]
    args.vv_ladder, args.ladder, args.micro_ladder = (split_floats(v) for v in (args.vv_ladder, args.ladder,
                                                                                 args.micro_ladder))
    bad = [m for m in args.methods if m not in METHODS]
    if bad:
        ap.error(f"unknown method(s) {bad}; expected some of {METHODS}")
    if "velocity-verlet" not in args.methods:
        args.methods.insert(0, "velocity-verlet")  # the reference of every criterion
    for name in ("vv_ladder", "ladder", "micro_ladder"):
        v = getattr(args, name)
        if not v or any(b <= a for a, b in zip(v, v[1:])) or v[0] <= 0:
            ap.error(f"--{name.replace('_', '-')}: expected increasing positive steps, got {v}")
    if args.seeds < 2 or args.ref_seeds < 2:
        ap.error("--seeds and --ref-seeds must be at least 2 (the error is their spread)")
    if not args.discard < args.t_run:
        ap.error("--discard must be shorter than --t-run")
    if args.vv_ladder[0] <= args.ref_h:
        ap.error("--vv-ladder must start above --ref-h (the reference is velocity Verlet's first step)")
    return args


def main():
    args = parse_args()
    args.out = os.path.abspath(args.out)
    args.stiffmd = os.path.abspath(args.stiffmd)  # runs execute in their own directories
    work = os.path.join(args.out, "work")
    os.makedirs(work, exist_ok=True)
    lock = threading.Lock()

    def log(text):
        with lock:
            print(text, flush=True)

    if not args.plot_only:
        if not os.access(args.stiffmd, os.X_OK):
            print(f"cost_vs_eps: no stiffmd binary at {args.stiffmd}", file=sys.stderr)
            return 2
        lmp = shutil.which(args.lmp)
        if lmp is None and "lammps-respa" in args.methods:
            log(f"cost_vs_eps: LAMMPS ('{args.lmp}') not found: no lammps-respa line")
            args.methods.remove("lammps-respa")
        args.lmp = lmp
        with open(os.path.join(args.out, "command.txt"), "w") as f:
            f.write(shlex.join([sys.executable] + sys.argv) + "\n")
        try:
            equilibrated = equilibrated_melt(args, work)
            src = source_deck(os.path.join(work, "small_source.toml"), equilibrated)
            states = {e: prepare_state(args.stiffmd, e, os.path.join(work, f"small_eps{e:g}.data"), deck=src)
                      for e in args.eps}
            chains = Chains(states[args.eps[0]])
            log(f"small melt: {chains.natoms} beads, {len(chains.starts)} chains, box {chains.box:.4g}")
            if not args.timing_only:  # else: the ladder.csv of an earlier run
                ladder_rows = []
                with concurrent.futures.ThreadPoolExecutor(args.jobs) as pool:
                    # Every seed of every reference a task of its own, queued before any ladder (the
                    # queue is first in, first out: a ladder waiting for its reference never waits
                    # for a task queued behind it).
                    ref_runs = {e: [pool.submit(run_one, args, e, "velocity-verlet", args.ref_h * e, states[e], chains,
                                                work, k, True) for k in range(args.ref_seeds)]
                                for e in sorted(args.eps)}
                    refs, ref_locks = {}, {e: threading.Lock() for e in args.eps}

                    def reference(e):
                        with ref_locks[e]:
                            if e not in refs:
                                for f in ref_runs[e]:
                                    f.result()  # finished: setting() reads their cached rows
                                refs[e] = setting(args, e, "velocity-verlet", args.ref_h * e, args.ref_seeds,
                                                  states[e], chains, work, reference=True)
                                if refs[e]["status"] != "ok":
                                    raise RunFailed(f"the reference at eps {e:g} failed: {refs[e]['status']}")
                            return refs[e]

                    def task(e, m):
                        return climb(args, e, m, reference(e), states[e], chains, work, log)

                    ladders = [pool.submit(task, e, m) for e in sorted(args.eps, reverse=True) for m in args.methods]
                    for f in ladders:
                        ladder_rows += f.result()
                with open(os.path.join(args.out, "ladder.csv"), "w", newline="") as f:
                    w = csv.DictWriter(f, fieldnames=LADDER_FIELDS, extrasaction="ignore")
                    w.writeheader()
                    w.writerows(ladder_rows)
            ladder_rows = read_csv(os.path.join(args.out, "ladder.csv"))
            if args.no_timing:
                return 0
            chosen = summarise(ladder_rows, [], args)

            cost_rows = []
            timing_states = {}
            for e in args.eps:
                if args.timing == "small":
                    timing_states[e] = states[e]
                else:
                    timing_states[e] = prepare_state(args.stiffmd, e, os.path.join(work, f"datachain_eps{e:g}.data"))
            # Each (ε, method) is timed at its largest passing step; a step that fails there (exit 3:
            # the timing system has ten times the beads, so ten times the close encounters per unit
            # time) is recorded and the next smaller passing step is timed instead.
            ladders = {}
            for r in ladder_rows:
                ladders.setdefault((float(r["eps"]), r["method"]), []).append(
                    dict(r, passed=str(r["passed"]) == "True", h=float(r["h"]), n=int(r["n"])))
            unstable = set()
            for repeat in range(args.repeats):  # interleaved: slow drifts of the machine's load hit all alike
                for s in chosen:
                    e, m = s["eps"], s["method"]
                    for h, n in passing_steps(ladders[(e, m)]):
                        if (e, m, h) in unstable:
                            continue
                        if not stable_on_timing_system(args, e, m, h, n, timing_states[e], work):
                            r = failed_timing(e, m, h, n, repeat, "exit 3 in the stability run")
                            r["natoms"] = chains.natoms if args.timing == "small" else 32000
                            cost_rows.append(r)
                            unstable.add((e, m, h))
                            log(f"stability eps {e:g} {m:18s} h {h:.4g}: exit 3; the next smaller step")
                            continue
                        r = timed_run(args, e, m, h, n, timing_states[e], work, repeat)
                        r["natoms"] = chains.natoms if args.timing == "small" else 32000
                        cost_rows.append(r)
                        if r["status"] != "ok":
                            unstable.add((e, m, h))
                            log(f"timed eps {e:g} {m:18s} h {h:.4g} n {n}: {r['status']}; the next smaller step")
                            continue
                        log(f"timed eps {e:g} {m:18s} h {h:.4g} n {n}: "
                            f"{r['cpu_per_time']:.3g} CPU s / time unit ({r['wall_per_time']:.3g} wall)")
                        break
            with open(os.path.join(args.out, "cost.csv"), "w", newline="") as f:
                w = csv.DictWriter(f, fieldnames=COST_FIELDS)
                w.writeheader()
                w.writerows(cost_rows)
        except RunFailed as e:
            print(f"cost_vs_eps: {e}", file=sys.stderr)
            return 2
    summary = summarise(read_csv(os.path.join(args.out, "ladder.csv")), read_csv(os.path.join(args.out, "cost.csv")),
                        args)
    table = markdown(summary, args)
    with open(os.path.join(args.out, "cost_vs_eps.md"), "w") as f:
        f.write(table)
    print(table)
    figure(summary, args.figure)
    print("figure:", args.figure)
    return 0


if __name__ == "__main__":
    sys.exit(main())
