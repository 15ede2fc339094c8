#!/usr/bin/python3
"""Benchmark stiffmd against LAMMPS r-RESPA on the same stiff-bond polymer melt; print a table.

Rerun (the defaults; a few minutes on two cores):

    /usr/bin/python3 tools/bench_lammps.py                # ε = 0.01 and 0.003, 200 steps, 3 repeats
    /usr/bin/python3 tools/bench_lammps.py --eps 0.01 --repeats 1 --steps 100

For every ε:

1. `stiffmd check inputs/lammps_chain.toml --set variables.eps=ε --write-data` prepares the state
   (LAMMPS's data.chain, 32 000 beads in 320 chains; stiff harmonic bonds ℓ = 0.97, α = 1, energy
   ½ α²/ε² (r − ℓ)²; projected onto the bonds; T = 1 velocities and thermal bond vibrations) and
   writes it as a LAMMPS data file with velocities.
2. Both codes start from that file with the same potentials: LAMMPS `bond_style harmonic` with
   K = α²/(2ε²) (LAMMPS's harmonic is K(r − r0)²) and `lj/cut` at 2^(1/6) with `pair_modify shift
   yes` (WCA), special_bonds lj 0 1 1, skin 0.3.
3. Timed runs, each --repeats times, interleaved (the median is reported): LAMMPS `run_style respa
   2 n bond 1 pair 2` (serial), and stiffmd impulse, projected-impulse and mollified-impulse
   (macro step h, n micro steps) and velocity-verlet at the micro step h/n, each for every thread
   count in --threads (OMP_NUM_THREADS).

Time per macro step: LAMMPS's "Loop time" / steps, stiffmd's summary.json wall_seconds (the step
loop) / macro steps; for velocity Verlet the time of the n steps that cover one macro step h.
Peak memory is each process's own max RSS (os.wait4). Energy drift: |E(end) − E(0)| and
max_t |E(t) − E(0)| over the thermo rows, per atom (LJ units) and relative to |E(0)|.

Outputs in --out (default sweeps/bench): bench_eps<ε>.md (the table), bench.csv (every repeat),
work/ (the prepared states, decks, LAMMPS inputs and each run's log and thermo output).
"""
import argparse
import csv
import os
import platform
import shlex
import shutil
import statistics
import subprocess
import sys
import time

from chain_melt import count_atoms, fmt, prepare_state, write_deck, write_lammps_input
from engines import (RunFailed, check_exit, lammps_command, read_summary, read_thermo, run_measured,
                     stiffmd_command)

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
STIFFMD_METHODS = ["impulse", "projected-impulse", "mollified-impulse", "velocity-verlet"]
ALL_METHODS = ["lammps-respa"] + STIFFMD_METHODS
CSV_FIELDS = ["eps", "code", "method", "threads", "h", "n", "steps", "repeat", "natoms", "loop_seconds",
              "ms_per_macro_step", "cpu_percent", "cpu_ms_per_macro_step", "process_seconds", "max_rss_mib",
              "e0", "e_end", "drift_end_per_atom", "drift_max_per_atom", "drift_end_rel", "drift_max_rel"]


# ---------------------------------------------------------------------------------------- helpers

def split_list(values):
    """['0.01 0.003'] or ['0.01,0.003'] or ['0.01', '0.003'] -> ['0.01', '0.003']."""
    return [v for item in values for v in item.replace(",", " ").split()]


def machine_description():
    model = "unknown CPU"
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("model name"):
                    model = line.split(":", 1)[1].strip()
                    break
    except OSError:
        pass
    return f"{model}, nproc {len(os.sched_getaffinity(0))}, {platform.node()}, {platform.platform()}"


def git_revision():
    try:
        rev = subprocess.run(["git", "-C", ROOT, "rev-parse", "--short", "HEAD"], capture_output=True, text=True,
                             check=True).stdout.strip()
        dirty = subprocess.run(["git", "-C", ROOT, "status", "--porcelain", "--untracked-files=no"],
                               capture_output=True, text=True).stdout.strip()
        return rev + (" (with uncommitted changes)" if dirty else "")
    except (OSError, subprocess.CalledProcessError):
        return "unknown"


def binary_date(path):
    try:
        return time.strftime("%Y-%m-%d %H:%M:%S", time.localtime(os.path.getmtime(path)))
    except OSError:
        return "missing"


def energy_drift(energies, natoms):
    e0 = energies[0]
    d_end = abs(energies[-1] - e0)
    d_max = max(abs(e - e0) for e in energies)
    return {"e0": e0, "e_end": energies[-1], "drift_end_per_atom": d_end / natoms,
            "drift_max_per_atom": d_max / natoms, "drift_end_rel": d_end / abs(e0), "drift_max_rel": d_max / abs(e0)}


# ------------------------------------------------------------------------------------ preparation

# ------------------------------------------------------------------------------------------- runs

def time_stiffmd(stiffmd, deck, method, threads, args, run_dir, natoms):
    """One timed stiffmd run of the benchmark: its row of bench.csv."""
    h = args.h / args.micro_steps if method == "velocity-verlet" else args.h
    cmd = stiffmd_command(stiffmd, deck, run_dir, [f"integrator.method={method}", f"integrator.h={fmt(h)}"])
    code, seconds, rss = run_measured(cmd, run_dir, threads)
    check_exit(code, cmd, run_dir)
    summary = read_summary(run_dir)
    expected_steps = args.steps * (args.micro_steps if method == "velocity-verlet" else 1)
    if summary["steps"] != expected_steps:
        raise RunFailed(f"stiffmd ran {summary['steps']} steps, expected {expected_steps}: {shlex.join(cmd)}")
    energies = [float(e) for e in read_thermo(os.path.join(run_dir, "thermo.csv"))["total"]]
    energies[0] = summary["initial_energy"]  # the same E(0), with all 17 digits
    checkpoint = os.path.join(run_dir, "checkpoint.bin")  # always written; not needed here
    if os.path.exists(checkpoint):
        os.remove(checkpoint)
    return {"code": "stiffmd", "method": method, "threads": threads, "h": h,
            "n": 1 if method == "velocity-verlet" else args.micro_steps, "steps": summary["steps"],
            "loop_seconds": summary["wall_seconds"], "ms_per_macro_step": 1e3 * summary["wall_seconds"] / args.steps,
            "cpu_percent": 100.0 * summary["cpu_seconds"] / summary["wall_seconds"],
            "process_seconds": seconds, "max_rss_mib": rss, **energy_drift(energies, natoms)}


def parse_lammps_log(path):
    """(loop seconds, steps, CPU use %, total energies of the thermo rows, warnings, version) from a LAMMPS log."""
    loop, cpu_percent = None, float("nan")
    energies, warnings, version = [], [], "LAMMPS"
    columns = None
    with open(path, errors="replace") as f:
        for line in f:
            words = line.split()
            if line.startswith("LAMMPS ("):
                version = line.strip()
            elif line.startswith("WARNING"):
                warnings.append(line.strip())
            elif words[:1] == ["Step"]:
                columns = words
            elif line.startswith("Loop time of"):
                loop = (float(words[3]), int(words[8]))
                columns = None
            elif "% CPU use with" in line:
                cpu_percent = float(words[0].rstrip("%"))
            elif columns and len(words) == len(columns):
                try:
                    energies.append(float(words[columns.index("TotEng")]))
                except ValueError:
                    columns = None
    if loop is None or not energies:
        raise RunFailed(f"{path}: no 'Loop time' line or no thermo rows")
    return loop[0], loop[1], cpu_percent, energies, warnings, version


def time_lammps(lmp, lammps_input, args, run_dir, natoms):
    """One timed LAMMPS r-RESPA run of the benchmark: its row of bench.csv."""
    log = os.path.join(run_dir, "log.lammps")
    cmd = lammps_command(lmp, lammps_input, log)
    code, seconds, rss = run_measured(cmd, run_dir, 1)
    check_exit(code, cmd, run_dir, log="log.lammps")
    loop_seconds, steps, cpu_percent, energies, warnings, version = parse_lammps_log(log)
    if steps != args.steps:
        raise RunFailed(f"LAMMPS ran {steps} steps, expected {args.steps}: {log}")
    return {"code": "lammps", "method": "respa", "threads": 1, "h": args.h, "n": args.micro_steps, "steps": steps,
            "loop_seconds": loop_seconds, "ms_per_macro_step": 1e3 * loop_seconds / steps, "cpu_percent": cpu_percent,
            "process_seconds": seconds, "max_rss_mib": rss, "warnings": warnings, "version": version,
            **energy_drift(energies, natoms)}


def benchmark_eps(eps, args, lmp, work, raw_writer):
    """All runs for one ε; returns (one summary row per configuration, LAMMPS warnings/version)."""
    os.makedirs(work, exist_ok=True)
    data = prepare_state(args.stiffmd, eps, os.path.join(work, f"state_eps{eps}.data"))
    natoms = count_atoms(data)
    thermo_every = args.thermo_every or max(1, args.steps // 10)
    deck = os.path.join(work, f"bench_eps{eps}.toml")
    write_deck(deck, data, eps, "tools/bench_lammps.py", "impulse", args.h, args.micro_steps, args.steps * args.h,
               thermo_every * args.h)
    lammps_input = os.path.join(work, f"in.bench_eps{eps}")
    write_lammps_input(lammps_input, data, eps, args.h, args.micro_steps, args.steps, thermo_every,
                       "tools/bench_lammps.py")

    configs = []
    if lmp and "lammps-respa" in args.methods:
        configs.append(("lammps-respa", 1))
    configs += [(m, t) for m in STIFFMD_METHODS if m in args.methods for t in args.threads]
    runs = {c: [] for c in configs}
    lammps_info = {"warnings": [], "version": None}
    for repeat in range(args.repeats):  # interleaved, so that slow drifts of the machine's load hit all alike
        for method, threads in configs:
            run_dir = os.path.join(work, "runs", f"{method}_t{threads}_r{repeat}")
            os.makedirs(run_dir, exist_ok=True)
            print(f"  eps {eps}: {method}, {threads} thread(s), repeat {repeat + 1}/{args.repeats}", file=sys.stderr,
                  flush=True)
            if method == "lammps-respa":
                r = time_lammps(lmp, lammps_input, args, run_dir, natoms)
                lammps_info["warnings"] = sorted(set(lammps_info["warnings"]) | set(r.pop("warnings")))
                lammps_info["version"] = r.pop("version")
            else:
                r = time_stiffmd(args.stiffmd, deck, method, threads, args, run_dir, natoms)
            r.update(eps=eps, repeat=repeat, natoms=natoms,
                     cpu_ms_per_macro_step=r["ms_per_macro_step"] * r["cpu_percent"] / 100)
            raw_writer.writerow({k: r[k] for k in CSV_FIELDS})
            runs[(method, threads)].append(r)

    rows = []
    for (method, threads), rs in runs.items():
        first = rs[0]  # energies: from the first repeat (every repeat is in bench.csv)
        rows.append({**first, "label": method if method == "lammps-respa" else f"stiffmd {method}",
                     "method_key": method, "ms": statistics.median(r["ms_per_macro_step"] for r in rs),
                     "rss": max(r["max_rss_mib"] for r in rs),
                     "cpu": statistics.median(r["cpu_percent"] for r in rs)})
    return rows, lammps_info


# ------------------------------------------------------------------------------------------ table

def ratio(a, b):
    return f"{a / b:.2f}" if b else "n/a"


def markdown_table(eps, rows, args, lammps_info):
    def time_of(method, threads):
        return next((r["ms"] for r in rows if r["method_key"] == method and r["threads"] == threads), None)

    t_lammps = time_of("lammps-respa", 1)
    out = [f"## ε = {eps}: {rows[0]['natoms']} atoms, {args.steps} macro steps of h = {fmt(args.h)}, "
           f"n = {args.micro_steps} micro steps, median of {args.repeats} repeat(s)", ""]
    out.append("| code/method | threads | h | n | ms / macro step | ÷ LAMMPS respa | ÷ stiffmd impulse "
               "| CPU use | peak RSS (MiB) | drift/atom end | drift/atom max | max \\|ΔE\\|/\\|E(0)\\| |")
    out.append("|---|--:|--:|--:|--:|--:|--:|--:|--:|--:|--:|--:|")
    for r in rows:
        t_impulse = time_of("impulse", r["threads"])
        out.append(f"| {r['label']} | {r['threads']} | {r['h']:.6g} | {r['n']} | {r['ms']:.2f} "
                   f"| {ratio(r['ms'], t_lammps)} | {ratio(r['ms'], t_impulse)} | {r['cpu']:.0f}% | {r['rss']:.0f} "
                   f"| {r['drift_end_per_atom']:.2e} | {r['drift_max_per_atom']:.2e} | {r['drift_max_rel']:.2e} |")
    out.append("")
    out.append("ms / macro step: LAMMPS 'Loop time' or stiffmd's step-loop wall time, divided by the macro steps "
               "(velocity Verlet: the n steps of h/n that make one macro step h); ratios are time ÷ time, "
               "> 1 is slower. CPU use: CPU time ÷ wall time of the step loop (below 100% × threads: the machine "
               "was busy with other work, and the times are inflated; OpenMP threads suffer most, waiting at "
               "barriers for a thread that is not running). Drift: |E(end) − E(0)| and "
               "max_t |E(t) − E(0)| over the thermo rows, per atom (LJ units), from the first repeat.")
    e0 = {r["method_key"]: r["e0"] / r["natoms"] for r in rows}
    if "lammps-respa" in e0:
        others = [(m, e) for m, e in e0.items() if m != "lammps-respa"]
        worst = max((abs(e - e0["lammps-respa"]) / abs(e0["lammps-respa"]) for _, e in others), default=0.0)
        out.append("")
        out.append(f"E(0) per atom: LAMMPS {e0['lammps-respa']:.12g}, stiffmd "
                   + ", ".join(sorted({f'{e:.12g}' for _, e in others}))
                   + f"; largest relative difference {worst:.1e}"
                   + ("" if worst <= 1e-6 else " — MORE THAN 1e-6: the states or potentials differ"))
    else:
        out += ["", "LAMMPS not run: ratio columns n/a."]
    if lammps_info["version"]:
        out.append("")
        out.append(f"{lammps_info['version']}, warnings: {len(lammps_info['warnings']) or 'none'}")
        out += [f"- {w}" for w in lammps_info["warnings"]]
        if any("Communication cutoff" in w for w in lammps_info["warnings"]):
            out.append("  (harmless here: LAMMPS estimates 1.5 r0 + skin; the stiff bonds stay within a few % of "
                       "ℓ = 0.97, well inside the ghost cutoff 2^(1/6) + skin, and a missing bond atom would be "
                       "an error, not a warning)")
    return "\n".join(out) + "\n"


# ------------------------------------------------------------------------------------------- main

def parse_args():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--eps", nargs="+", default=["0.01 0.003"], help="ε values (space or comma separated)")
    ap.add_argument("--steps", type=int, default=200, help="macro steps per run (default 200)")
    ap.add_argument("--h", type=float, default=0.005, help="macro step (default 0.005)")
    ap.add_argument("--micro-steps", type=int, default=20, help="micro steps per macro step, n (default 20)")
    ap.add_argument("--repeats", type=int, default=3, help="runs of each configuration; the median is shown")
    ap.add_argument("--threads", nargs="+", default=["1 2"], help="stiffmd thread counts (OMP_NUM_THREADS)")
    ap.add_argument("--methods", nargs="+", default=[" ".join(ALL_METHODS)],
                    help="subset of: " + " ".join(ALL_METHODS))
    ap.add_argument("--thermo-every", type=int, default=0, help="thermo every K macro steps (default steps/10)")
    ap.add_argument("--stiffmd", default=os.path.join(ROOT, "build", "stiffmd"), help="the engine binary")
    ap.add_argument("--lmp", default="lmp", help="the LAMMPS binary")
    ap.add_argument("--out", default=os.path.join(ROOT, "sweeps", "bench"), help="output directory")
    args = ap.parse_args()
    args.eps = split_list(args.eps)
    args.threads = [int(t) for t in split_list(args.threads)]
    args.methods = split_list(args.methods)
    bad = [m for m in args.methods if m not in ALL_METHODS]
    try:
        [float(e) for e in args.eps]
    except ValueError:
        bad.append("--eps " + " ".join(args.eps))
    if bad or args.steps < 1 or args.micro_steps < 1 or args.repeats < 1 or args.h <= 0 or min(args.threads) < 1:
        ap.error("bad value(s): " + (", ".join(bad) or "steps, micro-steps, repeats, threads must be >= 1, h > 0"))
    return args


def main():
    args = parse_args()
    header = [f"command: {shlex.join([sys.executable] + sys.argv)}  (in {os.getcwd()})",
              f"machine: {machine_description()}",
              f"stiffmd: {args.stiffmd} (built {binary_date(args.stiffmd)}), git {git_revision()}"]
    print("\n".join(header), flush=True)
    if not os.access(args.stiffmd, os.X_OK):
        print(f"bench_lammps: no stiffmd binary at {args.stiffmd} (cmake --build build -j2 --target stiffmd)",
              file=sys.stderr)
        return 2
    lmp = shutil.which(args.lmp)
    if lmp is None and "lammps-respa" in args.methods:
        print(f"bench_lammps: LAMMPS ('{args.lmp}') not found: running the stiffmd part only (ratio columns n/a)",
              flush=True)
    args.out = os.path.abspath(args.out)  # runs execute in their own directories
    os.makedirs(args.out, exist_ok=True)
    try:
        with open(os.path.join(args.out, "bench.csv"), "w", newline="") as f:
            raw = csv.DictWriter(f, fieldnames=CSV_FIELDS)
            raw.writeheader()
            for eps in args.eps:
                rows, lammps_info = benchmark_eps(eps, args, lmp, os.path.join(args.out, "work"), raw)
                f.flush()
                table = markdown_table(eps, rows, args, lammps_info)
                with open(os.path.join(args.out, f"bench_eps{eps}.md"), "w") as md:
                    md.write("".join(f"    {line}\n" for line in header) + "\n" + table)
                print("\n" + table, flush=True)
    except RunFailed as e:
        print(f"bench_lammps: {e}", file=sys.stderr)
        return 2
    print(f"tables and raw numbers: {args.out}/bench_eps<ε>.md, {args.out}/bench.csv")
    return 0


if __name__ == "__main__":
    sys.exit(main())
