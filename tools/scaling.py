#!/usr/bin/python3
"""Speed-up with threads: systems × methods × thread counts → ms per step, speed-up, efficiency, serial share.

    /usr/bin/python3 tools/scaling.py                                  # the 256 000-bead melts, 1 and 2 threads
    /usr/bin/python3 tools/scaling.py --systems stiff-32k,kg-32k --threads 1,2,4,8,16 --repeats 2
    /usr/bin/python3 tools/scaling.py --systems stiff-256k --methods fixman,rattle --steps 30 --repeats 7
    /usr/bin/python3 tools/scaling.py --deck inputs/polymer_melt.toml --methods rattle,fixman --h 0.01

Systems (--systems; or --deck PATH: that deck with each method as integrator.method, at --h):
  kg-32k, kg-256k      LAMMPS's in.chain as inputs/kremer_grest.toml (FENE + LJ, velocity Verlet with
                       LAMMPS's Langevin, h = 0.012); 256k: data.chain replicated 2 × 2 × 2
                       (tools/chain_melt.py tile_data). Method: velocity-verlet only.
  stiff-32k, stiff-256k  inputs/lammps_chain.toml prepared at --eps (projected, thermal; tools/chain_melt.py),
                       stiff bonds + WCA under Langevin kT = 1, damp = 1; 256k: the prepared state
                       replicated 2 × 2 × 2. Methods and their steps (METHODS below): velocity-verlet at
                       0.9 ε, impulse at 0.005 with 50 micro steps, rattle and fixman at 0.02 (BAOAB;
                       rattle-obabo, fixman-obabo with OBABO), effective at 0.02.

Every run is --steps steps with OMP_NUM_THREADS = the thread count, no checkpoints, one thermo sample
at the end (the step loop is what is timed). Runs are interleaved: each repeat runs every system,
method and thread count in turn (thread counts in alternating order from one repeat to the next), so
a drift of the machine's speed hits all alike. Per (system, method, threads): the median over repeats
of summary.json's wall_seconds / steps (ms/step); the speed-up over the fewest threads t₀ is the median
over repeats of the ratio of the two runs of the same repeat, × t₀; efficiency = speed-up / threads.
The serial share is the median of summary.json's "serial_share" where the engine writes it (the share
of the step loop's wall time outside parallel loops), '—' otherwise.

A shared machine: "others" is the median number of cores other processes kept busy during a row's
runs (/proc/stat's busy time less the run's own CPU time, over its wall time); with two threads on
two cores any of it slows the run. --wait-idle S waits before each repeat's runs (at most S
seconds) until other processes use less than 0.2 cores over a second.

Outputs in --out (default sweeps/scaling): scaling.md (the table, also printed), runs.csv (every run),
work/ (states, decks, runs).
"""
import argparse
import csv
import json
import os
import resource
import shutil
import statistics
import sys
import time

from bench_lammps import check_exit, run_measured  # tools/ is the script's directory
from chain_melt import RunFailed, engine_method, fmt, prepare_state, tile_data, write_deck

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
DATA_CHAIN = "/usr/share/lammps/examples/COUPLE/multiple/data.chain"
KG_DECK = os.path.join(ROOT, "inputs", "kremer_grest.toml")

# Stiff melt: method → (h as a function of ε, micro steps). The settings at ε = 1e-3.
METHODS = {
    "velocity-verlet": (lambda eps: 0.9 * eps, 1),
    "impulse": (lambda eps: 0.005, 50),
    "mollified-impulse": (lambda eps: 0.005, 50),
    "rattle": (lambda eps: 0.02, 1),
    "fixman": (lambda eps: 0.02, 1),
    "rattle-obabo": (lambda eps: 0.02, 1),
    "fixman-obabo": (lambda eps: 0.02, 1),
    "effective": (lambda eps: 0.02, 1),
}
SYSTEMS = ("kg-32k", "kg-256k", "stiff-32k", "stiff-256k")
LANGEVIN = ['thermostat.style="langevin"', "thermostat.temperature=1.0", "thermostat.damp=1.0", "thermostat.seed=3"]


def split(text):
    return [w for w in text.replace(",", " ").split() if w]


def system_runs(system, methods, args, work):
    """[(system, method, deck, --set overrides)] of one named system."""
    if system.startswith("kg-"):
        data = DATA_CHAIN
        if system == "kg-256k":
            data = os.path.join(work, "kg256k.data")
            if not os.path.exists(data):
                tile_data(DATA_CHAIN, data)
        bad = [m for m in methods if m != "velocity-verlet"]
        if bad:
            raise RunFailed(f"{system} runs velocity-verlet only (no stiff bonds for {', '.join(bad)})")
        t_end = 0.012 * args.steps
        sets = [f'import.lammps_data="{data}"', f"run.t_end={fmt(t_end)}", f"output.thermo_interval={fmt(t_end)}",
                f"output.screen_interval={fmt(t_end)}"]
        return [(system, "velocity-verlet", KG_DECK, sets)]
    state = os.path.join(work, f"stiff32k_eps{args.eps:g}.data")
    if not os.path.exists(state):
        prepare_state(args.stiffmd, args.eps, state)
    if system == "stiff-256k":
        tiled = os.path.join(work, f"stiff256k_eps{args.eps:g}.data")
        if not os.path.exists(tiled):
            tile_data(state, tiled)
        state = tiled
    runs = []
    for m in methods:
        if m not in METHODS:
            raise RunFailed(f"unknown method {m!r} for {system}: one of {', '.join(METHODS)}")
        h = METHODS[m][0](args.eps)
        micro = METHODS[m][1]
        t_end = h * args.steps
        deck = os.path.join(work, f"{system}_{m}.toml")
        write_deck(deck, state, args.eps, "tools/scaling.py", engine_method(m)[0], h, micro, t_end, t_end)
        runs.append((system, m, deck, LANGEVIN + engine_method(m)[1]))
    return runs


def deck_runs(deck, methods, args):
    """A deck of the user's, each method as integrator.method, --steps steps of --h, one thermo sample."""
    t_end = fmt(args.h * args.steps)
    runs = []
    for m in methods:
        name, sets = engine_method(m)
        runs.append((os.path.basename(deck), m, os.path.abspath(deck),
                     [f'integrator.method="{name}"', f"integrator.h={fmt(args.h)}", f"run.t_end={t_end}",
                      f"output.thermo_interval={t_end}", f"output.screen_interval={t_end}"] + sets))
    return runs


def busy_seconds():
    """CPU seconds the whole machine has been busy (all cores; /proc/stat), or None off Linux."""
    try:
        with open("/proc/stat") as f:
            ticks = [int(w) for w in f.readline().split()[1:9]]
    except (OSError, ValueError):
        return None
    return (sum(ticks) - ticks[3] - ticks[4]) / os.sysconf("SC_CLK_TCK")  # less idle and iowait


def wait_idle(limit):
    """Waits until other processes use < 0.2 cores over a second, at most `limit` seconds."""
    start = time.monotonic()
    while time.monotonic() - start < limit:
        before = busy_seconds()
        if before is None:
            return
        time.sleep(1.0)
        if busy_seconds() - before < 0.2:
            return


def run_once(args, deck, sets, threads, run_dir):
    """(ms per step of the step loop's wall time, serial share or None, cores other processes kept
    busy meanwhile or None) of one run."""
    shutil.rmtree(run_dir, ignore_errors=True)
    os.makedirs(run_dir)
    cmd = [args.stiffmd, "run", deck, "--no-progress", "-o", run_dir, "--set", "output.checkpoint_interval=0"]
    for kv in sets + args.set:
        cmd += ["--set", kv]
    busy0, own0, t0 = busy_seconds(), resource.getrusage(resource.RUSAGE_CHILDREN), time.monotonic()
    code, _, _ = run_measured(cmd, run_dir, threads)
    busy1, own1, t1 = busy_seconds(), resource.getrusage(resource.RUSAGE_CHILDREN), time.monotonic()
    check_exit(code, cmd, run_dir, log="stderr.txt")
    with open(os.path.join(run_dir, "summary.json")) as f:
        s = json.load(f)
    if s["steps"] < 1:
        raise RunFailed(f"{run_dir}: no steps run")
    others = None
    if busy0 is not None:
        own = (own1.ru_utime + own1.ru_stime) - (own0.ru_utime + own0.ru_stime)
        others = max(0.0, (busy1 - busy0 - own) / (t1 - t0))
    return 1e3 * s["wall_seconds"] / s["steps"], s.get("serial_share"), others


def table(rows, thread_counts):
    """The markdown table of the medians."""
    t0 = thread_counts[0]
    lines = ["| system | method | threads | ms/step | speed-up | efficiency | serial share | others |",
             "|---|---|--:|--:|--:|--:|--:|--:|"]
    for (system, method), by_threads in rows.items():
        base = by_threads[t0]
        for t in thread_counts:
            ms = by_threads[t]
            speedup = t0 * statistics.median(b / a for b, a in zip(base, ms))
            shares = [s for s in by_threads.get(("share", t), []) if s is not None]
            share = f"{100 * statistics.median(shares):.2f} %" if shares else "—"
            busy = [b for b in by_threads.get(("others", t), []) if b is not None]
            others = f"{statistics.median(busy):.2f}" if busy else "—"
            lines.append(f"| {system} | {method} | {t} | {statistics.median(ms):.2f} | {speedup:.2f} | "
                         f"{100 * speedup / t:.0f} % | {share} | {others} |")
    return "\n".join(lines)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--systems", default="kg-256k,stiff-256k", help=f"comma-separated, of {', '.join(SYSTEMS)}")
    ap.add_argument("--deck", help="a deck to run instead of the named systems")
    ap.add_argument("--methods", default="velocity-verlet,impulse,rattle,fixman",
                    help="for the stiff systems and --deck (kg-* run velocity-verlet)")
    ap.add_argument("--threads", default="1,2")
    ap.add_argument("--eps", type=float, default=1e-3, help="the stiff systems' ε")
    ap.add_argument("--h", type=float, default=0.005, help="--deck's step")
    ap.add_argument("--steps", type=int, default=50)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--set", action="append", default=[], help="KEY=VALUE for every run (repeatable)")
    ap.add_argument("--wait-idle", type=float, default=0.0, metavar="S",
                    help="before each repeat's runs, wait up to S seconds for other processes to go quiet")
    ap.add_argument("--stiffmd", default=os.path.join(ROOT, "build", "stiffmd"))
    ap.add_argument("--out", default=os.path.join(ROOT, "sweeps", "scaling"))
    args = ap.parse_args()
    try:
        thread_counts = sorted({int(t) for t in split(args.threads)})
    except ValueError:
        thread_counts = []
    if not thread_counts or thread_counts[0] < 1 or args.steps < 1 or args.repeats < 1 or not args.eps > 0 or \
            not args.h > 0:
        print("scaling: --threads must be integers >= 1, --steps and --repeats >= 1, --eps and --h > 0", file=sys.stderr)
        return 2
    args.stiffmd, args.out = os.path.abspath(args.stiffmd), os.path.abspath(args.out)
    work = os.path.join(args.out, "work")
    os.makedirs(work, exist_ok=True)
    methods = split(args.methods)
    try:
        if args.deck:
            if not os.path.isfile(args.deck):
                raise RunFailed(f"no deck {args.deck}")
            runs = deck_runs(args.deck, methods, args)
        else:
            runs = []
            for system in split(args.systems):
                if system not in SYSTEMS:
                    raise RunFailed(f"unknown system {system!r}: one of {', '.join(SYSTEMS)}")
                sys_methods = ["velocity-verlet"] if system.startswith("kg-") else methods
                runs += system_runs(system, sys_methods, args, work)
        rows, records = {}, []
        for r in range(args.repeats):
            order = thread_counts if r % 2 == 0 else thread_counts[::-1]
            for system, method, deck, sets in runs:
                by_threads = rows.setdefault((system, method), {})
                if args.wait_idle > 0:
                    wait_idle(args.wait_idle)
                for t in order:
                    run_dir = os.path.join(work, "runs", f"{system}_{method}_t{t}")
                    ms, share, others = run_once(args, deck, sets, t, run_dir)
                    by_threads.setdefault(t, []).append(ms)
                    by_threads.setdefault(("share", t), []).append(share)
                    by_threads.setdefault(("others", t), []).append(others)
                    records.append({"system": system, "method": method, "threads": t, "repeat": r,
                                    "ms_per_step": ms, "serial_share": "" if share is None else share,
                                    "others": "" if others is None else others})
    except RunFailed as e:
        print(f"scaling: {e}", file=sys.stderr)
        return 2
    head = (f"Wall ms per step of the step loop, {args.steps} steps, median of {args.repeats} interleaved repeats; "
            f"speed-up over {thread_counts[0]} thread(s) (median of the ratios within a repeat)")
    text = head + "\n\n" + table(rows, thread_counts) + "\n"
    with open(os.path.join(args.out, "scaling.md"), "w") as f:
        f.write(text)
    with open(os.path.join(args.out, "runs.csv"), "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(records[0]))
        w.writeheader()
        w.writerows(records)
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
