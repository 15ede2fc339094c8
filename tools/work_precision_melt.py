#!/usr/bin/python3
"""Work–precision and step-size resonance of the impulse family on the LAMMPS chain melt.

Regenerate the figures (docs/figures/work_precision_melt.png, docs/figures/resonance_melt.png), the
CSVs in sweeps/melt/ and the markdown summary (sweeps/melt/summary.md, also printed) with one command:

    /usr/bin/python3 tools/work_precision_melt.py

That is ε = 0.01 and 0.003 with every phase at its default, ≈ 1–1.5 h of CPU on one core. Measured
for ε = 0.01 (step-loop CPU; wall on a busy 2-core machine in brackets): short-horizon errors 35 s
(70 s), energy drift to t = 2 113 s (3 min) — so ≈ 10 min (15 min) to the default t = 10 —, resonance
scan to t = 2 155 s (7 min; most runs past h ≈ 0.8 T_min blow up early); ε = 0.003 costs ≈ 3.5× as
much per run (the micro step is ε/40). Cheaper variants:

    /usr/bin/python3 tools/work_precision_melt.py --eps 0.01 --t-long 2     # ≈ 10 min
    /usr/bin/python3 tools/work_precision_melt.py --eps 0.01 --skip-long --skip-scan   # ≈ 1 min
    /usr/bin/python3 tools/work_precision_melt.py --quick --eps 0.01 --out /tmp/wp --figures /tmp/wp  # smoke, ≈ 15 s
    /usr/bin/python3 tools/work_precision_melt.py --plot-only      # figures + summary from the CSVs in --out

The figures in docs/figures were made by the ≈ 10 min run above, then (≈ 8 min)
    /usr/bin/python3 tools/work_precision_melt.py --eps 0.003 --skip-scan --t-long 2
and (≈ 4 min; its CPU times with both cores busy)
    /usr/bin/python3 tools/work_precision_melt.py --eps 0.01 --skip-short --skip-scan --t-long 10 --jobs 2
and (≈ 6 min)
    /usr/bin/python3 tools/work_precision_melt.py --eps 0.003 --skip-short --skip-long --t-scan 0.5 \
        --scan "0.45 0.5 0.55 0.75 0.95 1.0 1.05 1.45 1.5 1.95 2.0 2.5"
and --plot-only; each CSV's command is in the .command.txt beside it and in summary.md.

The scene is inputs/lammps_chain.toml (LAMMPS's data.chain: 32 000 beads in 320 chains of 100,
stiff harmonic bonds ℓ = 0.97, α = 1, energy ½(α/ε)²(r − ℓ)², WCA between non-bonded pairs).
For every ε, `stiffmd check … --write-data` prepares the t = 0 state once (projected onto the bonds,
T = 1 velocities, thermal bond vibrations) and every run below starts from that file.

1. Short-horizon error (t = --t-short, default 0.5). Reference: velocity Verlet with δ = ε/100
   (--ref-dt). Runs: impulse, mollified-impulse, projected-impulse at every macro step of --h
   (default 0.0025 0.005 0.01 0.02 — the same for every ε: the macro step is limited by the slow
   WCA force, not by ε; the micro step is δ = h/n with n = ceil(h/(ε/40)), --micro-dt, so the bonds
   are resolved alike in every run and at every ε), and velocity Verlet at δ = ε × each of --vv-dt
   (default 1/2 1/3 1/5 1/10 1/20 1/40: the coarse ones reach the impulse family's error range).
   Every step is rounded down so that it divides t_short exactly. Errors, from the final states
   (output.lammps_data, minimum image): RMS over atoms of |x − x_ref|, its max over atoms, and the
   RMS over chains of the centre-of-mass error (a slow observable: the bond forces are internal to a
   chain, and the projected kick keeps each chain's total slow force). Cost = summary.json
   cpu_seconds (the step loop only). The summary gives, per method, the cheapest run reaching RMS
   errors 3e-2, 1e-2, 1e-3, 1e-4 and the speed ratio CPU(velocity Verlet)/CPU(method) at matched RMS
   error (log–log interpolation along each method's cost–error envelope).
2. Energy drift over --t-long (default 10): the same runs (or the subsets --long-h, --long-vv-dt);
   |E(t_long) − E(0)|/N and max_t |E(t) − E(0)|/N from thermo.csv (≈ 200 rows per run).
3. Step-size resonance scan over --t-scan (default 2): macro steps h = r T_min for r in --scan
   (h/T_min, default 23 points in 0.3…3, denser near 0.5, 1, 1.5, 2), T_min = 2π/ω_max,
   ω_max = 2α/ε (the fastest bond mode of a harmonic chain with unit masses; a dimer's is √2 α/ε),
   the micro step fixed near ε/40 (n = round(h/δ)): LAMMPS `run_style respa 2 n bond 1 pair 2`
   and stiffmd impulse, projected-impulse, mollified-impulse — plus stiffmd rattle (rigid bonds: no
   bond vibrations, so no resonance; where it fails as well, h is past the WCA force's own step
   limit, ≈ 0.025 on this melt, which at ε = 0.01 is already h/T_min ≈ 0.8). Recorded:
   max_t |E(t) − E(0)|/N, |E(end) − E(0)|/N, the final temperature, stable/unstable.
   A run is "unstable" when stiffmd exits 3 (non-finite state, failed SHAKE/projection), when LAMMPS
   stops with an error after its run started (e.g. "Lost atoms", "Bond atoms missing") or prints a
   non-finite energy, or when a run exceeds --timeout.

Outputs: --out (default sweeps/melt): short_eps<ε>.csv, long_eps<ε>.csv, scan_eps<ε>.csv,
summary.md, work/ (prepared states, decks, LAMMPS inputs, each run's thermo and summary; the
final-state data files are deleted unless --keep-states). Figures in --figures (default
docs/figures): work_precision_melt.png (per ε a column: RMS position error and chain centre-of-mass
error at t_short vs CPU seconds, energy drift to t_long vs CPU seconds, log–log), resonance_melt.png
(per ε: max energy drift per atom vs h/T_min, unstable runs as × at the top).

All runs are serial (OMP_NUM_THREADS = 1, OMP_WAIT_POLICY = passive); --jobs N runs N at once
(CPU seconds stay meaningful on an idle machine with ≥ N cores; on a busy one keep --jobs 1).
"""
import argparse
import csv
import math
import os
import shlex
import shutil
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from fractions import Fraction

import numpy as np

from chain_melt import ALPHA, count_atoms, fmt, prepare_state, write_deck, write_lammps_input
from engines import TIMEOUT, RunFailed, engine_env, read_summary, read_thermo, run_lammps, run_stiffmd

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
IMPULSE_METHODS = ["impulse", "mollified-impulse", "projected-impulse"]
# rattle: rigid bonds, no bond vibrations and so no resonance — where it fails too, the macro step is
# past the slow (WCA) force's own stability limit.
SCAN_CODES = ["lammps-respa", "impulse", "projected-impulse", "mollified-impulse", "rattle"]
DEFAULT_SCAN = ("0.3 0.4 0.45 0.5 0.55 0.6 0.75 0.9 0.95 1.0 1.05 1.1 1.25 1.4 1.45 1.5 1.55 1.75 1.95 2.0 2.05 "
                "2.5 3.0")
ERROR_LEVELS = (3e-2, 1e-2, 1e-3, 1e-4)
STYLE = {  # colour, marker per method/code (figures)
    "impulse": ("tab:red", "s"), "mollified-impulse": ("tab:blue", "^"), "projected-impulse": ("tab:green", "o"),
    "velocity-verlet": ("black", "D"), "lammps-respa": ("tab:orange", "v"), "rattle": ("tab:gray", "P")}

SHORT_FIELDS = ["eps", "method", "h", "n", "micro_dt", "steps", "t_end", "cpu_seconds", "wall_seconds", "err_rms",
                "err_max", "err_com_rms", "max_energy_error_per_atom", "status", "note"]
LONG_FIELDS = ["eps", "method", "h", "n", "micro_dt", "steps", "t_end", "cpu_seconds", "wall_seconds",
               "drift_end_per_atom", "drift_max_per_atom", "final_temperature", "t_last", "status", "note"]
SCAN_FIELDS = ["eps", "code", "method", "h", "h_over_tmin", "n", "micro_dt", "steps", "t_end", "cpu_seconds",
               "wall_seconds", "drift_end_per_atom", "drift_max_per_atom", "final_temperature", "t_last", "status",
               "note"]


# ---------------------------------------------------------------------------------------- helpers

def split_list(text):
    """'0.01 0.003' or '0.01,0.003' (or a list of such) -> ['0.01', '0.003']."""
    items = text if isinstance(text, list) else [text]
    return [v for item in items for v in item.replace(",", " ").split()]


def fraction_list(text):
    """'1/5 1/10' or '0.2,0.1' -> [0.2, 0.1]."""
    return [float(Fraction(v)) for v in split_list(text)]


def t_min(eps):
    """Period of the fastest bond mode of a harmonic chain, unit masses: ω_max = 2α/ε."""
    return 2.0 * math.pi / (2.0 * ALPHA / eps)


def dividing_step(t_end, step):
    """The largest step ≤ `step` that divides t_end into whole steps; returns (step, count)."""
    count = max(1, math.ceil(t_end / step - 1e-9))
    return t_end / count, count


def micro_count(h, delta):
    """n = ceil(h/δ) micro steps, so that h/n ≤ δ."""
    return max(1, math.ceil(h / delta - 1e-9))


def tail_text(text, lines=12):
    return "\n".join(text.strip().splitlines()[-lines:])


def command_line(argv=None):
    return shlex.join(["/usr/bin/python3", os.path.relpath(os.path.abspath(__file__), ROOT)]
                      + (sys.argv[1:] if argv is None else list(argv)))


def provenance_path(csv_path):
    """Beside each CSV: the command that wrote it, when, how long, which binary."""
    return csv_path[:-len(".csv")] + ".command.txt"


def binary_date(path):
    try:
        return time.strftime("%Y-%m-%d %H:%M", time.localtime(os.path.getmtime(path)))
    except OSError:
        return "?"


def log(msg):
    print(msg, file=sys.stderr, flush=True)


def fresh_dir(path):
    if os.path.isdir(path):
        shutil.rmtree(path)
    os.makedirs(path)


def read_data_positions(path):
    """The Atoms section of a LAMMPS data file (atom_style bond: id mol type x y z [ix iy iz]) in id
    order, image flags applied; returns (x [N,3], molecule ids [N], box lengths [3])."""
    lengths = np.zeros(3)
    rows = []
    with open(path) as f:
        lines = iter(f)
        for line in lines:
            words = line.split()
            if len(words) == 4 and words[2:] in (["xlo", "xhi"], ["ylo", "yhi"], ["zlo", "zhi"]):
                lengths["xyz".index(words[2][0])] = float(words[1]) - float(words[0])
            elif words[:1] == ["Atoms"]:
                next(lines)  # blank line
                for line in lines:
                    w = line.split("#")[0].split()
                    if not w:
                        break
                    rows.append(w[:9])
                break
    if not rows:
        raise RunFailed(f"{path}: no Atoms section")
    a = np.array(rows, dtype=float)
    order = np.argsort(a[:, 0].astype(np.int64))
    x = a[:, 3:6] + (a[:, 6:9] * lengths if a.shape[1] >= 9 else 0.0)
    return x[order], a[order, 1].astype(np.int64), lengths


def position_error(x, x_ref, mol, lengths):
    """RMS over atoms of |x − x_ref|, its max over atoms, and the RMS over molecules of the
    centre-of-mass difference (equal masses), minimum image on each atom's difference."""
    d = x - x_ref
    d -= lengths * np.round(d / lengths)
    r2 = np.sum(d * d, axis=1)
    _, inverse, counts = np.unique(mol, return_inverse=True, return_counts=True)
    com = np.zeros((counts.size, 3))
    np.add.at(com, inverse, d)
    com /= counts[:, None]
    return float(np.sqrt(np.mean(r2))), float(np.sqrt(np.max(r2))), float(np.sqrt(np.mean(np.sum(com * com, axis=1))))


def drift_stats(energies, e0, natoms):
    e = np.asarray(energies, dtype=float)
    if e.size == 0 or not np.all(np.isfinite(e)):
        return float("inf"), float("inf")
    return float(abs(e[-1] - e0) / natoms), float(np.max(np.abs(e - e0)) / natoms)


# ------------------------------------------------------------------------------------ preparation

# ------------------------------------------------------------------------------------------- runs

def drift_stiffmd(args, deck, run_dir, method, h, n, t_end, thermo_interval, natoms, final_data=False):
    """One stiffmd run in a fresh run_dir. Returns a dict with status 'ok' or 'unstable', cpu/wall
    seconds, drift statistics, final temperature; 'final' = the final-state data path (if asked)."""
    fresh_dir(run_dir)
    sets = [f"integrator.method={method}", f"integrator.h={fmt(h)}", f"run.t_end={fmt(t_end)}",
            f"output.thermo_interval={fmt(thermo_interval)}"]
    if method in IMPULSE_METHODS:
        sets.append(f"integrator.micro_steps={n}")
    if final_data:
        sets.append('output.lammps_data="final.data"')
    p = run_stiffmd(args.stiffmd, deck, run_dir, sets, timeout=args.timeout, accept=(0, 3, TIMEOUT))
    code, stderr, wall = p.code, p.stderr, p.seconds
    with open(os.path.join(run_dir, "stderr.txt"), "w") as f:
        f.write(stderr)
    th = read_thermo(os.path.join(run_dir, "thermo.csv"), missing_ok=True)  # a run stopped early may have none
    times, energies, temps = (list(map(float, th.get(k, []))) for k in ("time", "total", "temperature"))
    for junk in ("checkpoint.bin", "histograms.csv"):
        if os.path.exists(os.path.join(run_dir, junk)):
            os.remove(os.path.join(run_dir, junk))
    r = {"steps": round(t_end / h), "t_end": t_end, "t_last": times[-1] if times else 0.0}
    if code == 0:
        s = read_summary(run_dir)
        e0 = s["initial_energy"]
        d_end, d_max = drift_stats(energies + [s["final_energy"]], e0, natoms)
        r.update(status="ok", note="", steps=s["steps"], cpu_seconds=s["cpu_seconds"], wall_seconds=s["wall_seconds"],
                 drift_end_per_atom=d_end, drift_max_per_atom=max(d_max, s["max_energy_error"] / natoms),
                 max_energy_error_per_atom=s["max_energy_error"] / natoms,
                 final_temperature=temps[-1] if temps else float("nan"),
                 final=os.path.join(run_dir, "final.data") if final_data else None)
        if not all(math.isfinite(v) for v in (d_end, d_max)):
            r.update(status="unstable", note="non-finite energy")
    else:
        last = [line for line in stderr.splitlines() if "numerical failure" in line]
        note = "timeout" if code == TIMEOUT else (last[-1].strip() if last else f"exit {code}")
        r.update(status="unstable", note=note[:200], cpu_seconds=float("nan"), wall_seconds=wall,
                 drift_end_per_atom=float("inf"), drift_max_per_atom=float("inf"), max_energy_error_per_atom=float("inf"),
                 final_temperature=float("nan"), final=None)
    return r


def parse_lammps_log(path):
    """(rows [(step, temp, etotal)], loop seconds or None, CPU %, first ERROR line or '')."""
    rows, loop, cpu, error = [], None, 100.0, ""
    columns = None
    with open(path, errors="replace") as f:
        for line in f:
            words = line.split()
            if words[:1] == ["Step"]:
                columns = words
            elif line.startswith("Loop time of"):
                loop = float(words[3])
                columns = None
            elif "% CPU use with" in line:
                cpu = float(words[0].rstrip("%"))
            elif line.startswith("ERROR") and not error:
                error = line.strip()
                columns = None
            elif columns and len(words) == len(columns):
                try:
                    vals = [float(w) for w in words]
                except ValueError:
                    continue
                rows.append((vals[columns.index("Step")], vals[columns.index("Temp")],
                             vals[columns.index("TotEng")]))
    return rows, loop, cpu, error


def drift_lammps(args, data, eps, h, n, steps, thermo_every, run_dir, natoms):
    fresh_dir(run_dir)
    inp = os.path.join(run_dir, "in.respa")
    write_lammps_input(inp, data, eps, h, n, steps, thermo_every, "tools/work_precision_melt.py (resonance scan)")
    logf = os.path.join(run_dir, "log.lammps")
    p = run_lammps(args.lmp, inp, logf, cwd=run_dir, timeout=args.timeout)
    code, output, wall, cmd = p.code, p.stdout + p.stderr, p.seconds, p.cmd
    rows, loop, cpu, error = parse_lammps_log(logf) if os.path.exists(logf) else ([], None, 100.0, "")
    error = error or next((line.strip() for line in output.splitlines() if line.startswith("ERROR")), "")
    r = {"steps": steps, "t_end": steps * h, "t_last": rows[-1][0] * h if rows else 0.0}
    if code != 0 and not rows:
        raise RunFailed(f"LAMMPS failed before its run started (exit {code}): {shlex.join(cmd)}\n"
                        f"{error or tail_text(output)}")
    energies = [row[2] for row in rows]
    d_end, d_max = drift_stats(energies, energies[0], natoms)
    finished = code == 0 and rows and rows[-1][0] == steps
    if finished and math.isfinite(d_max):
        r.update(status="ok", note="", drift_end_per_atom=d_end, drift_max_per_atom=d_max,
                 final_temperature=rows[-1][1])
    else:
        note = "timeout" if code == TIMEOUT else (error or ("non-finite energy" if finished else f"exit {code}"))
        r.update(status="unstable", note=note[:200], drift_end_per_atom=float("inf"), drift_max_per_atom=float("inf"),
                 final_temperature=float("nan"))
    r.update(cpu_seconds=loop * cpu / 100.0 if loop is not None else float("nan"),
             wall_seconds=loop if loop is not None else wall)
    return r


def run_all(jobs, fn, n_parallel):
    """fn over jobs, n_parallel at once, in order; progress on stderr."""
    total = len(jobs)
    done = [0]

    def one(job):
        r = fn(job)
        done[0] += 1
        log(f"  [{done[0]}/{total}] {r.get('label', '')}")
        return r

    with ThreadPoolExecutor(max_workers=max(1, n_parallel)) as pool:
        return list(pool.map(one, jobs))


def write_csv(path, fields, rows):
    with open(path, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=fields, extrasaction="ignore", restval="")
        w.writeheader()
        for r in rows:
            w.writerow({k: (f"{v:.10g}" if isinstance(v, float) else v) for k, v in r.items()})


def read_csv(path):
    if not os.path.exists(path):
        return []
    out = []
    with open(path) as f:
        for row in csv.DictReader(f):
            for k, v in row.items():
                if k not in ("method", "code", "status", "note", "eps"):
                    try:
                        row[k] = float(v)
                    except (TypeError, ValueError):
                        pass
            out.append(row)
    return out


# ----------------------------------------------------------------------------------------- phases

def short_phase(args, eps_text, eps, deck, work, natoms):
    t_end = args.t_short
    ref_dt, ref_steps = dividing_step(t_end, eps * args.ref_dt)
    log(f"eps {eps_text}: short-horizon reference, velocity Verlet δ = {ref_dt:.4g} ({ref_steps} steps to t = {t_end})")
    ref = drift_stiffmd(args, deck, os.path.join(work, "short", "reference"), "velocity-verlet", ref_dt, 1, t_end,
                      t_end / 10, natoms, final_data=True)
    if ref["status"] != "ok":
        raise RunFailed(f"the reference run (velocity Verlet δ = {ref_dt}) failed: {ref['note']}")
    x_ref, mol, lengths = read_data_positions(ref["final"])

    jobs = [(m, h) for m in IMPULSE_METHODS for h in args.h] + [("velocity-verlet", eps * f) for f in args.vv_dt]

    def one(job):
        method, nominal = job
        h, steps = dividing_step(t_end, nominal)
        n = 1 if method == "velocity-verlet" else micro_count(h, eps * args.micro_dt)
        d = os.path.join(work, "short", f"{method}_h{h:.6g}")
        r = drift_stiffmd(args, deck, d, method, h, n, t_end, t_end / 10, natoms, final_data=True)
        r.update(eps=eps_text, method=method, h=h, n=n, micro_dt=h / n, err_rms=float("inf"), err_max=float("inf"),
                 err_com_rms=float("inf"))
        if r["status"] == "ok":
            x, _, _ = read_data_positions(r["final"])
            r["err_rms"], r["err_max"], r["err_com_rms"] = position_error(x, x_ref, mol, lengths)
            if not args.keep_states:
                os.remove(r["final"])
        r["label"] = (f"eps {eps_text} short {method} h={h:.4g} n={n}: {r['status']}, cpu {r['cpu_seconds']:.3g} s, "
                      f"rms err {r['err_rms']:.3g}")
        return r

    rows = run_all(jobs, one, args.jobs)
    if not args.keep_states:
        os.remove(ref["final"])
    ref_row = dict(ref, eps=eps_text, method="reference-vv", h=ref_dt, n=1, micro_dt=ref_dt, err_rms=0.0, err_max=0.0,
                   err_com_rms=0.0)
    return [ref_row] + rows


def long_phase(args, eps_text, eps, deck, work, natoms):
    t_end = args.t_long
    hs = args.long_h if args.long_h is not None else args.h
    vv = args.long_vv_dt if args.long_vv_dt is not None else args.vv_dt
    jobs = [(m, h) for m in IMPULSE_METHODS for h in hs] + [("velocity-verlet", eps * f) for f in vv]
    log(f"eps {eps_text}: energy drift to t = {t_end}, {len(jobs)} runs")

    def one(job):
        method, nominal = job
        # The same steps as the short runs (they divide t_short), and t_end a whole number of them.
        h, _ = dividing_step(args.t_short, nominal)
        steps = max(1, round(t_end / h))
        n = 1 if method == "velocity-verlet" else micro_count(h, eps * args.micro_dt)
        d = os.path.join(work, "long", f"{method}_h{h:.6g}")
        r = drift_stiffmd(args, deck, d, method, h, n, steps * h, max(h, steps * h / 200), natoms)
        r.update(eps=eps_text, method=method, h=h, n=n, micro_dt=h / n)
        r["label"] = (f"eps {eps_text} long {method} h={h:.4g} n={n}: {r['status']}, cpu {r['cpu_seconds']:.3g} s, "
                      f"max drift/atom {r['drift_max_per_atom']:.3g}")
        return r

    return run_all(jobs, one, args.jobs)


def scan_phase(args, eps_text, eps, deck, data, work, natoms):
    tm = t_min(eps)
    delta = eps * args.micro_dt
    jobs = [(code, r) for r in args.scan for code in args.scan_codes]
    log(f"eps {eps_text}: resonance scan, T_min = {tm:.5g}, {len(args.scan)} steps × {len(args.scan_codes)} codes "
        f"to t ≈ {args.t_scan}")

    def one(job):
        code, ratio = job
        h = ratio * tm
        n = 1 if code == "rattle" else max(1, round(h / delta))
        steps = max(1, round(args.t_scan / h))
        every = max(1, steps // 200)
        d = os.path.join(work, "scan", f"{code}_r{ratio:.4g}")
        if code == "lammps-respa":
            r = drift_lammps(args, data, eps, h, n, steps, every, d, natoms)
        else:
            r = drift_stiffmd(args, deck, d, code, h, n, steps * h, every * h, natoms)
        r.update(eps=eps_text, code="lammps" if code == "lammps-respa" else "stiffmd",
                 method="respa" if code == "lammps-respa" else code, h=h, h_over_tmin=ratio, n=n, micro_dt=h / n)
        r["label"] = (f"eps {eps_text} scan {code} h/T_min={ratio:.3g} n={n}: {r['status']}, "
                      f"max drift/atom {r['drift_max_per_atom']:.3g}, T_end {r['final_temperature']:.4g}"
                      + (f" ({r['note']})" if r["note"] else ""))
        return r

    return run_all(jobs, one, args.jobs)


# ------------------------------------------------------------------------------------ the summary

def pareto(points):
    """(cost, err) points -> the lower-left envelope, cost increasing and error decreasing."""
    front = []
    for c, e in sorted((c, e) for c, e in points if math.isfinite(c) and math.isfinite(e) and c > 0 and e > 0):
        if not front or e < front[-1][1]:
            front.append((c, e))
    return front


def cost_at(front, err):
    """Cost to reach `err` along a method's envelope, log–log interpolation; None outside its range."""
    if not front or err < front[-1][1] or err > front[0][1]:
        return None
    for (c0, e0), (c1, e1) in zip(front, front[1:]):
        if e1 <= err <= e0:
            if e0 == e1:
                return c0
            s = (math.log(err) - math.log(e0)) / (math.log(e1) - math.log(e0))
            return math.exp(math.log(c0) + s * (math.log(c1) - math.log(c0)))
    return front[0][0]


def method_label(row):
    m = row.get("method", "")
    return {"respa": "LAMMPS respa", "rattle": "rattle (rigid bonds)"}.get(m, m)


def summary_markdown(eps_text, short, long_rows, scan, made=()):
    out = [f"## ε = {eps_text}", ""]
    if made:
        out += ["Made by:", ""] + list(made) + [""]
    eps = float(eps_text)
    if short:
        ref = next((r for r in short if r["method"] == "reference-vv"), None)
        runs = [r for r in short if r["method"] != "reference-vv"]
        out.append(f"### Error at t = {runs[0]['t_end']:.4g} against velocity Verlet δ = {ref['h']:.4g} "
                   f"(cpu {ref['cpu_seconds']:.3g} s)" if ref else "### Error at t_short")
        out += ["", "| method | h | n | δ = h/n | steps | CPU s | RMS error | max error | chain-COM RMS error "
                "| max \\|ΔE\\|/N | status |",
                "|---|--:|--:|--:|--:|--:|--:|--:|--:|--:|---|"]
        for r in runs:
            out.append(f"| {r['method']} | {r['h']:.4g} | {int(r['n'])} | {r['micro_dt']:.3g} | {int(r['steps'])} "
                       f"| {r['cpu_seconds']:.3g} | {r['err_rms']:.3g} | {r['err_max']:.3g} | {r.get('err_com_rms', float('nan')):.3g} "
                       f"| {r['max_energy_error_per_atom']:.3g} | {r['status']} |")
        out += ["", "Cheapest run reaching an RMS error level (CPU seconds, h):", "",
                "| method | " + " | ".join(f"RMS ≤ {lv:g}" for lv in ERROR_LEVELS) + " |",
                "|---|" + "--:|" * len(ERROR_LEVELS)]
        methods = IMPULSE_METHODS + ["velocity-verlet"]
        fronts = {}
        for m in methods:
            rs = [r for r in runs if r["method"] == m and r["status"] == "ok"]
            fronts[m] = pareto([(r["cpu_seconds"], r["err_rms"]) for r in rs])
            cells = []
            for lv in ERROR_LEVELS:
                ok = [r for r in rs if r["err_rms"] <= lv]
                best = min(ok, key=lambda r: r["cpu_seconds"]) if ok else None
                cells.append(f"{best['cpu_seconds']:.3g} s (h = {best['h']:.3g})" if best else "not reached")
            out.append(f"| {m} | " + " | ".join(cells) + " |")
        vv = fronts["velocity-verlet"]
        out += ["", "Speed ratio at matched RMS error, CPU(velocity Verlet) / CPU(method), log–log interpolation "
                "along each method's cost–error envelope (n/a: the error lies outside one of the two curves):", ""]
        targets = sorted({float(f"{e:.2g}") for e in ERROR_LEVELS + tuple(e for m in IMPULSE_METHODS
                                                                          for _, e in fronts[m])}, reverse=True)
        out += ["| RMS error | " + " | ".join(IMPULSE_METHODS) + " |", "|--:|" + "--:|" * len(IMPULSE_METHODS)]
        for e in targets:
            cells = []
            for m in IMPULSE_METHODS:
                cv, cm = cost_at(vv, e), cost_at(fronts[m], e)
                cells.append(f"{cv / cm:.2f}" if cv and cm else "n/a")
            out.append(f"| {e:.3g} | " + " | ".join(cells) + " |")
        pf = fronts["projected-impulse"]
        matched = [(cost_at(vv, e) / cost_at(pf, e), e) for e in targets if cost_at(vv, e) and cost_at(pf, e)]
        if matched:
            best = max(matched)
            out += ["", f"Target projected-impulse ≥ 10× faster than velocity Verlet at matched error: "
                    f"{'met' if best[0] >= 10 else 'NOT met'} — best ratio {best[0]:.2f} (at RMS error {best[1]:.2g})."]
        elif pf and vv:
            out += ["", "Target projected-impulse ≥ 10× faster than velocity Verlet at matched error: not measurable "
                    f"— projected-impulse's RMS errors ({pf[-1][1]:.2g}…{pf[0][1]:.2g}) do not overlap velocity "
                    f"Verlet's ({vv[-1][1]:.2g}…{vv[0][1]:.2g}); cheapest runs: projected {pf[0][0]:.3g} s at "
                    f"{pf[0][1]:.2g}, velocity Verlet {vv[0][0]:.3g} s at {vv[0][1]:.2g}."]
        dom = [(c, e) for c, e in vv if pf and c <= pf[0][0] and e <= pf[-1][1]]
        if dom:
            out.append(f"Velocity Verlet dominates: its run at {dom[0][0]:.3g} s (error {dom[0][1]:.2g}) is cheaper "
                       f"than the cheapest projected-impulse run and more accurate than the most accurate one.")
        vv_rows = [r for r in runs if r["method"] == "velocity-verlet" and r["status"] == "ok"]
        if vv_rows and ref:
            fine = min(vv_rows, key=lambda r: r["h"])
            est = fine["err_rms"] * (ref["h"] / fine["h"]) ** 2 / (1 - (ref["h"] / fine["h"]) ** 2)
            out += ["", f"Velocity Verlet's RMS errors span {vv[-1][1]:.3g}…{vv[0][1]:.3g} (CPU {vv[0][0]:.3g}…"
                    f"{vv[-1][0]:.3g} s). If its error is ∝ δ², the reference (δ = {ref['h']:.3g}) is itself "
                    f"≈ {est:.2g} off (from the δ = {fine['h']:.3g} run)."]
        out.append("")
    if long_rows:
        out += [f"### Energy drift to t = {long_rows[0]['t_end']:.4g} (per atom)", "",
                "| method | h | n | CPU s | \\|E(end) − E(0)\\|/N | max \\|E(t) − E(0)\\|/N | T(end) | status |",
                "|---|--:|--:|--:|--:|--:|--:|---|"]
        for r in long_rows:
            out.append(f"| {r['method']} | {r['h']:.4g} | {int(r['n'])} | {r['cpu_seconds']:.3g} "
                       f"| {r['drift_end_per_atom']:.3g} | {r['drift_max_per_atom']:.3g} | {r['final_temperature']:.4g} "
                       f"| {r['status']}{' (' + r['note'] + ')' if r['note'] else ''} |")
        out.append("")
    if scan:
        codes = []
        for r in scan:
            if method_label(r) not in codes:
                codes.append(method_label(r))
        ratios = sorted({r["h_over_tmin"] for r in scan})
        tm = t_min(eps)
        out += [f"### Resonance scan: max_t |E(t) − E(0)|/N to t ≈ {scan[0]['t_end']:.3g}, T_min = {tm:.4g} "
                f"(ω_max = 2α/ε), micro step ≈ ε/{eps / scan[0]['micro_dt']:.0f}; ✗ = unstable", "",
                "| h/T_min | h | n | " + " | ".join(codes) + " |", "|--:|--:|--:|" + "--:|" * len(codes)]
        for q in ratios:
            rs = {method_label(r): r for r in scan if r["h_over_tmin"] == q}
            any_r = next((r for r in rs.values() if r["method"] != "rattle"), next(iter(rs.values())))
            cells = []
            for c in codes:
                r = rs.get(c)
                if r is None:
                    cells.append("")
                elif r["status"] != "ok":
                    cells.append(f"✗ (t = {r['t_last']:.3g})")
                else:
                    cells.append(f"{r['drift_max_per_atom']:.2e}")
            out.append(f"| {q:.3g} | {any_r['h']:.4g} | {int(any_r['n'])} | " + " | ".join(cells) + " |")
        out.append("")
        for c in codes:
            bad = [r for r in scan if method_label(r) == c and r["status"] != "ok"]
            ok = [r for r in scan if method_label(r) == c and r["status"] == "ok"]
            worst = max(ok, key=lambda r: r["drift_max_per_atom"]) if ok else None
            temps = [r["final_temperature"] for r in ok]
            out.append(f"- {c}: {len(bad)} unstable of {len(bad) + len(ok)}"
                       + (" (h/T_min = " + ", ".join(f"{r['h_over_tmin']:.3g}" for r in bad) + ")" if bad else "")
                       + (f"; largest drift {worst['drift_max_per_atom']:.2e}/atom at h/T_min = "
                          f"{worst['h_over_tmin']:.3g}; final T {min(temps):.3f}…{max(temps):.3f}" if worst else ""))
        out.append("")
    return "\n".join(out)


# ---------------------------------------------------------------------------------------- figures

def draw_figures(eps_list, data, fig_dir):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib import ticker

    os.makedirs(fig_dir, exist_ok=True)
    written = []
    all_eps = eps_list
    eps_list = [e for e in all_eps if data[e]["short"] or data[e]["long"]]
    panels = []  # (kind, column, y label, title)
    if any(data[e]["short"] for e in eps_list):
        panels += [("short", "err_rms", "RMS over atoms of |x − x_ref|", "position error at t = "),
                   ("short", "err_com_rms", "RMS over chains of the centre-of-mass error",
                    "chain centre-of-mass error at t = ")]
    if any(data[e]["long"] for e in eps_list):
        panels.append(("long", "drift_max_per_atom", "max_t |E(t) − E(0)| / N", "energy drift to t = "))
    if panels:
        fig, axes = plt.subplots(len(panels), len(eps_list), figsize=(5.6 * len(eps_list), 4.0 * len(panels)),
                                 squeeze=False)
        for j, e in enumerate(eps_list):
            for i, (kind, key, ylabel, title) in enumerate(panels):
                rows = data[e][kind]
                ax = axes[i][j]
                for m in IMPULSE_METHODS + ["velocity-verlet"]:
                    # Connected in order of the step, largest first (CPU times need not be monotone).
                    rs = sorted((r for r in rows if r["method"] == m and r["status"] == "ok"), key=lambda r: -r["h"])
                    col, mk = STYLE[m]
                    if rs:
                        ax.loglog([r["cpu_seconds"] for r in rs], [max(r[key], 1e-300) for r in rs], marker=mk,
                                  color=col, label=m + (" (δ)" if m == "velocity-verlet" else " (h)"), ms=5)
                    for r in rs:
                        lab = f"ε/{e_over(r, e):.3g}" if m == "velocity-verlet" else f"{r['h']:.3g}"
                        ax.annotate(lab, (r["cpu_seconds"], max(r[key], 1e-300)), fontsize=6, color=col,
                                    xytext=(3, 3), textcoords="offset points")
                    bad = [r for r in rows if r["method"] == m and r["status"] != "ok"]
                    if bad:
                        ax.text(0.02, 0.03 + 0.05 * IMPULSE_METHODS.index(m) if m in IMPULSE_METHODS else 0.18,
                                f"{m} unstable at " + ", ".join(f"{r['h']:.3g}" for r in bad), color=col, fontsize=7,
                                transform=ax.transAxes)
                if key == "err_rms":
                    for lv in ERROR_LEVELS:
                        ax.axhline(lv, color="0.6", lw=0.8, ls=":")
                t = rows[0]["t_end"] if rows else 0
                ax.set_title(f"ε = {e}: {title}{t:.3g}", fontsize=10)
                ax.set_xlabel("CPU seconds (step loop, 1 thread)")
                ax.set_ylabel(ylabel)
                ax.grid(True, which="both", alpha=0.3)
                ax.xaxis.set_major_formatter(ticker.FuncFormatter(lambda v, _: f"{v:g}"))
                ax.xaxis.set_minor_formatter(ticker.FuncFormatter(lambda v, _: f"{v:g}" if v > 0 and round(v / 10 ** math.floor(math.log10(v)), 6) in (2, 5) else ""))
                ax.tick_params(axis="x", which="minor", labelsize=7)
                if rows:
                    ax.legend(fontsize=7)
        micro = [float(e) / r["micro_dt"] for e in eps_list for k in ("short", "long") for r in data[e][k]
                 if r["method"] in IMPULSE_METHODS]
        fig.suptitle("LAMMPS chain melt (32 000 beads), stiff bonds; errors against velocity Verlet with δ = ε/100.\n"
                     f"Labels: macro step h (impulse family, micro step ≤ ε/{min(micro) if micro else 40:.3g}), "
                     "step δ (velocity Verlet).", fontsize=7)
        fig.tight_layout(rect=(0, 0, 1, 1 - 0.35 / (4.0 * len(panels))))
        path = os.path.join(fig_dir, "work_precision_melt.png")
        fig.savefig(path, dpi=130)
        plt.close(fig)
        written.append(path)

    eps_list = [e for e in all_eps if data[e]["scan"]]
    if eps_list:
        fig, axes = plt.subplots(1, len(eps_list), figsize=(6 * len(eps_list), 4.5), squeeze=False)
        for j, e in enumerate(eps_list):
            ax = axes[0][j]
            rows = data[e]["scan"]
            finite = [r["drift_max_per_atom"] for r in rows if r["status"] == "ok" and r["drift_max_per_atom"] > 0]
            top = 10 ** math.ceil(math.log10(max(finite))) * 3 if finite else 1.0
            rigid_bad = [r["h_over_tmin"] for r in rows if r["method"] == "rattle" and r["status"] != "ok"]
            if rigid_bad:
                ax.axvspan(min(rigid_bad) - 0.02, max(r["h_over_tmin"] for r in rows) + 0.05, color="0.92", zorder=0,
                           label="rigid bonds (rattle) unstable too:\nthe WCA force's own step limit")
            for k, (key, col_key) in enumerate((("respa", "lammps-respa"), ("impulse", "impulse"),
                                                ("projected-impulse", "projected-impulse"),
                                                ("mollified-impulse", "mollified-impulse"), ("rattle", "rattle"))):
                rs = sorted((r for r in rows if r["method"] == key), key=lambda r: r["h_over_tmin"])
                if not rs:
                    continue
                col, mk = STYLE[col_key]
                lab = {"respa": "LAMMPS respa", "rattle": "stiffmd rattle (rigid bonds)"}.get(key, f"stiffmd {key}")
                ok = [r for r in rs if r["status"] == "ok"]
                # LAMMPS respa is the impulse method: open markers, so that both stay visible when they agree.
                ax.semilogy([r["h_over_tmin"] for r in ok], [max(r["drift_max_per_atom"], 1e-300) for r in ok],
                            marker=mk, color=col, label=lab, ms=8 if key == "respa" else 4, lw=1,
                            ls="--" if key == "respa" else "-", mfc="none" if key == "respa" else col)
                bad = [r for r in rs if r["status"] != "ok"]
                if bad:
                    ax.plot([r["h_over_tmin"] for r in bad], [top * 1.8 ** k] * len(bad), "x", color=col, ms=8, mew=2,
                            label=f"{lab} unstable")
            hi = max((r["h_over_tmin"] for r in rows), default=3.0)
            for k in range(1, int(2 * hi) + 1):
                ax.axvline(k / 2, color="0.75", lw=0.8, ls=":")
            ax.axvline(math.sqrt(2) / 2, color="0.85", lw=0.8, ls="-.")
            t = float(np.median([r["t_end"] for r in rows])) if rows else 0.0
            ax.set_title(f"ε = {e}: T_min = 2π/(2α/ε) = {t_min(float(e)):.3g}, t ≈ {t:.3g}", fontsize=10)
            ax.set_xlabel("h / T_min  (dotted: multiples of ½; dash-dot: dimer's T/2)")
            ax.set_ylabel("max |E(t) − E(0)| / N")
            ax.grid(True, which="both", alpha=0.3)
            ax.legend(fontsize=6.5, loc="best")
        fig.suptitle("Step-size resonance on the melt, micro step ≈ ε/40; × = unstable", fontsize=9)
        fig.tight_layout()
        path = os.path.join(fig_dir, "resonance_melt.png")
        fig.savefig(path, dpi=130)
        plt.close(fig)
        written.append(path)
    return written


def e_over(row, eps_text):
    """ε/δ of a velocity-Verlet row."""
    return float(eps_text) / row["h"]


# ------------------------------------------------------------------------------------------- main

def parse_args(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--eps", nargs="+", default=["0.01 0.003"], help="ε values (default '0.01 0.003')")
    ap.add_argument("--t-short", type=float, default=None, help="horizon of the error runs (default 0.5)")
    ap.add_argument("--t-long", type=float, default=None, help="horizon of the energy-drift runs (default 10)")
    ap.add_argument("--t-scan", type=float, default=None, help="horizon of the resonance scan (default 2)")
    ap.add_argument("--h", nargs="+", default=None, help="macro steps (default '0.0025 0.005 0.01 0.02')")
    ap.add_argument("--vv-dt", nargs="+", default=None,
                    help="velocity-Verlet steps as fractions of ε (default '1/2 1/3 1/5 1/10 1/20 1/40')")
    ap.add_argument("--micro-dt", default="1/40", help="micro step of the impulse family as a fraction of ε (1/40)")
    ap.add_argument("--ref-dt", default="1/100", help="reference velocity-Verlet step as a fraction of ε (1/100)")
    ap.add_argument("--long-h", nargs="+", default=None, help="macro steps of the drift runs (default: all of --h)")
    ap.add_argument("--long-vv-dt", nargs="+", default=None,
                    help="velocity-Verlet steps of the drift runs, fractions of ε (default: all of --vv-dt)")
    ap.add_argument("--scan", nargs="+", default=None, help="h/T_min values of the resonance scan (default: 23 "
                    "points in 0.3…3.0, denser near 0.5, 1, 1.5, 2)")
    ap.add_argument("--scan-codes", nargs="+", default=[" ".join(SCAN_CODES)],
                    help="subset of: " + " ".join(SCAN_CODES))
    ap.add_argument("--skip-short", action="store_true", help="no short-horizon error runs")
    ap.add_argument("--skip-long", action="store_true", help="no energy-drift runs")
    ap.add_argument("--skip-scan", action="store_true", help="no resonance scan")
    ap.add_argument("--quick", action="store_true",
                    help="smoke test: t_short = t_long = 0.01, h = 0.005, VV δ = ε/10, scan h/T_min = 0.25 0.5 1 "
                         "to t = 0.02 (explicit options still win)")
    ap.add_argument("--plot-only", action="store_true", help="no runs: figures and summary from the CSVs in --out")
    ap.add_argument("--stiffmd", default=os.path.join(ROOT, "build", "stiffmd"), help="the engine binary")
    ap.add_argument("--lmp", default="lmp", help="the LAMMPS binary")
    ap.add_argument("--out", default=os.path.join(ROOT, "sweeps", "melt"), help="CSV/summary directory")
    ap.add_argument("--figures", default=os.path.join(ROOT, "docs", "figures"), help="figure directory")
    ap.add_argument("--jobs", type=int, default=1, help="runs at once (default 1: cleanest CPU times)")
    ap.add_argument("--timeout", type=float, default=3600.0, help="seconds per run before it counts as unstable")
    ap.add_argument("--keep-states", action="store_true", help="keep the final-state data files of the error runs")
    a = ap.parse_args(argv)

    q = a.quick
    a.eps = split_list(a.eps)
    a.t_short = a.t_short if a.t_short is not None else (0.01 if q else 0.5)
    a.t_long = a.t_long if a.t_long is not None else (0.01 if q else 10.0)
    a.t_scan = a.t_scan if a.t_scan is not None else (0.02 if q else 2.0)
    a.h = [float(v) for v in split_list(a.h if a.h is not None else ("0.005" if q else "0.0025 0.005 0.01 0.02"))]
    a.vv_dt = fraction_list(a.vv_dt if a.vv_dt is not None else ("1/10" if q else "1/2 1/3 1/5 1/10 1/20 1/40"))
    a.long_h = [float(v) for v in split_list(a.long_h)] if a.long_h is not None else None
    a.long_vv_dt = fraction_list(a.long_vv_dt) if a.long_vv_dt is not None else None
    a.scan = [float(v) for v in split_list(a.scan if a.scan is not None else ("0.25 0.5 1" if q else DEFAULT_SCAN))]
    a.scan_codes = split_list(a.scan_codes)
    a.micro_dt = float(Fraction(a.micro_dt))
    a.ref_dt = float(Fraction(a.ref_dt))
    bad = [c for c in a.scan_codes if c not in SCAN_CODES]
    if bad:
        ap.error(f"unknown scan code(s) {bad}; known: {SCAN_CODES}")
    try:
        [float(e) for e in a.eps]
    except ValueError:
        ap.error(f"bad --eps {a.eps}")
    if min(a.h + a.vv_dt + a.scan + [a.t_short, a.t_long, a.t_scan, a.micro_dt, a.ref_dt]) <= 0 or a.jobs < 1:
        ap.error("steps, horizons and fractions must be > 0, --jobs >= 1")
    return a


def main(argv=None):
    args = parse_args(argv)
    args.out = os.path.abspath(args.out)  # decks name their data files relative to their own directory
    if getattr(args, "figures", None):
        args.figures = os.path.abspath(args.figures)
    os.makedirs(args.out, exist_ok=True)
    data = {}
    started = time.monotonic()
    try:
        if not args.plot_only:
            if not os.access(args.stiffmd, os.X_OK):
                raise RunFailed(f"no stiffmd binary at {args.stiffmd} (cmake --build build -j2 --target stiffmd)")
            if not args.skip_scan and "lammps-respa" in args.scan_codes:
                lmp = shutil.which(args.lmp)
                if lmp is None:
                    log(f"work_precision_melt: LAMMPS ('{args.lmp}') not found: the scan runs stiffmd only")
                    args.scan_codes = [c for c in args.scan_codes if c != "lammps-respa"]
                else:
                    args.lmp = lmp
        for eps_text in args.eps:
            eps = float(eps_text)
            files = {k: os.path.join(args.out, f"{k}_eps{eps_text}.csv") for k in ("short", "long", "scan")}
            if args.plot_only:
                data[eps_text] = {k: read_csv(p) for k, p in files.items()}
                continue
            work = os.path.join(args.out, "work", f"eps{eps_text}")
            t0 = time.monotonic()
            state = prepare_state(args.stiffmd, eps_text, os.path.join(work, "state.data"), env=engine_env(1))
            natoms = count_atoms(state)
            deck = os.path.join(work, "deck.toml")
            write_deck(deck, state, eps, "tools/work_precision_melt.py", "velocity-verlet", eps / 40, 1, eps, eps)
            d = {"short": [], "long": [], "scan": []}
            phases = [("short", SHORT_FIELDS, lambda: short_phase(args, eps_text, eps, deck, work, natoms)),
                      ("long", LONG_FIELDS, lambda: long_phase(args, eps_text, eps, deck, work, natoms)),
                      ("scan", SCAN_FIELDS, lambda: scan_phase(args, eps_text, eps, deck, state, work, natoms))]
            for kind, fields, phase in phases:
                if getattr(args, f"skip_{kind}"):
                    continue
                t_phase = time.monotonic()
                d[kind] = phase()
                write_csv(files[kind], fields, d[kind])
                cpu = sum(r["cpu_seconds"] for r in d[kind] if math.isfinite(r.get("cpu_seconds", float("nan"))))
                with open(provenance_path(files[kind]), "w") as f:
                    f.write(f"{command_line(argv)}  ({time.strftime('%Y-%m-%d %H:%M')}, "
                            f"{time.monotonic() - t_phase:.0f} s wall, {cpu:.0f} s CPU in the step loops; "
                            f"stiffmd {args.stiffmd} built {binary_date(args.stiffmd)})\n")
            # Re-read, so that the summary and the figures see exactly what the CSVs hold.
            data[eps_text] = {k: read_csv(p) if d[k] else [] for k, p in files.items()}
            log(f"eps {eps_text}: done in {time.monotonic() - t0:.0f} s wall")
    except RunFailed as e:
        print(f"work_precision_melt: {e}", file=sys.stderr)
        return 2
    if args.plot_only:
        args.eps = [e for e in args.eps if any(data[e].values())]
        if not args.eps:
            print(f"work_precision_melt: no CSVs in {args.out}", file=sys.stderr)
            return 2

    text = ["# Work–precision and step-size resonance on the LAMMPS chain melt", "",
            f"This summary: `{command_line(argv)}`"
            + ("" if args.plot_only else f" ({time.monotonic() - started:.0f} s wall)"), ""]
    for eps_text in args.eps:
        made = []
        for kind in ("short", "long", "scan"):
            path = provenance_path(os.path.join(args.out, f"{kind}_eps{eps_text}.csv"))
            if data[eps_text][kind] and os.path.exists(path):
                with open(path) as f:
                    made.append(f"- {kind}_eps{eps_text}.csv: " + " ".join(f.read().split()))
        text.append(summary_markdown(eps_text, data[eps_text]["short"], data[eps_text]["long"], data[eps_text]["scan"],
                                     made))
    md = "\n".join(text)
    with open(os.path.join(args.out, "summary.md"), "w") as f:
        f.write(md + "\n")
    print(md)
    for path in draw_figures(args.eps, data, args.figures):
        print(f"figure: {path}")
    print(f"CSVs and summary.md: {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
