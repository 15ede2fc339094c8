#!/usr/bin/python3
"""Where a constrained macro step spends its time on data.chain: constraint work against the slow force.

    /usr/bin/python3 tools/profile_step.py                       # rattle and fixman, ε = 1e-3, h = 0.005
    /usr/bin/python3 tools/profile_step.py --methods fixman --steps 100
    /usr/bin/python3 tools/profile_step.py --methods rattle,fixman,rattle-obabo,fixman-obabo --h 0.02

rattle-obabo and fixman-obabo are rattle and fixman with thermostat.splitting = "obabo" (one SHAKE
per step instead of constrained BAOAB's two).

The state is inputs/lammps_chain.toml prepared at --eps (tools/chain_melt.py: 32 000 beads, 320 chains
of 100, stiff bonds ℓ = 0.97, WCA), run under Langevin (kT = 1, damp = 1), one thread, --steps macro
steps of --h. Two measurements:

1. Cost per macro step: --repeats interleaved runs of every method, the median of summary.json's
   cpu_seconds / steps (the step loop only); the ratio of each method to the first (rattle).
2. The split of one run of each method: `perf record -F 999` (user-space samples of this process),
   self time per symbol, grouped by the name patterns in GROUPS below: the constraint toolbox (SHAKE,
   RATTLE velocity projections: ConstraintToolbox, TridiagonalSolver, the constraint force), the
   slow force (the WCA pair loop and the neighbour list), Fixman's U_F and its gradient (with the band
   of S⁻¹ the toolbox computes for it from its factors: ConstraintToolbox::chain_inverse_band), the Langevin
   O step (the Gaussians: log, sin, cos), kick and drift, and the start-up (reading data.chain, the
   neighbour list's first build, topology) which is left out of the shares. ms per step = share of
   the step's samples × the step loop's CPU seconds / steps.

The target: constraint work per macro step ≤ the slow force's (WCA + neighbour list).
"""
import argparse
import os
import re
import shutil
import statistics
import subprocess
import sys

from chain_melt import engine_method, prepare_state, write_deck  # tools/ is the script's directory
from engines import RunFailed, read_summary, run_measured

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
GROUPS = [  # (group, regular expression on the symbol); the first match wins
    # U_F's band of S⁻¹ is computed by the toolbox from its factors (chain_inverse_band): U_F's work.
    ("Fixman U_F", r"FixmanPotential|tridiagonal_inverse_band|chain_inverse_band|inverse_band_group"),
    # constraint_detail: the toolbox's private helpers outside ConstraintToolbox's name (the cluster
    # solvers, ChainLdlt's lockstep templates, the path walks; integrators/constraint_toolbox_impl.hpp);
    # memcmp: the toolbox's comparison of x with its kept configuration (its only user in a step).
    ("constraints", r"ConstraintToolbox|constraint_detail|TridiagonalSolver|ChainLdlt|Rattle::add_constraint_force|"
                    r"memcmp"),
    ("slow force", r"accumulate_pair_rows|NeighborList|PairTerm|pair_loop|ForceField::compute"),
    ("Langevin O step", r"LangevinNoise|ziggurat|__ieee754_log|__cos|__sin|^log@|^cos@|^sin@"),
    ("kick, drift", r"\bkick\b|\bdrift\b|Rattle::|check_finite|memset|memmove|memcpy"),
    ("start-up", r"DataReader|from_chars|special_pairs|find_clusters|cluster_path|bonds_at_mobile|split_ws|Rb_tree|"
                 r"introsort|unrealisable_cycle|_dl_|strtod|Deck|toml|Scene|load_|read_|prepare|NeighborList::build|"
                 # the step loop allocates nothing (perf --call-graph dwarf: every malloc under the
                 # constructors of the toolbox and Fixman's potential)
                 r"malloc|_int_free|^cfree|unlink_chunk|find_stiff_bond_problem|parse_long"),
]


def timed(args, method, deck, run_dir):
    """The command of one run under Langevin."""
    cmd = [args.stiffmd, "run", deck, "--no-progress", "-o", run_dir, "--set", 'thermostat.style="langevin"',
           "--set", "thermostat.temperature=1.0", "--set", "thermostat.damp=1.0", "--set", "thermostat.seed=3",
           "--set", "output.checkpoint_interval=0"]
    for o in engine_method(method)[1]:
        cmd += ["--set", o]
    return cmd


def cpu_per_step(run_dir):
    s = read_summary(run_dir)
    return s["cpu_seconds"] / s["steps"], s["steps"]


def split(perf_data, perf):
    """Self-time percentages per group from `perf report`."""
    p = subprocess.run([perf, "report", "-i", perf_data, "--no-children", "--sort", "symbol", "--stdio",
                        "--percent-limit", "0"], capture_output=True, text=True)
    shares = {g: 0.0 for g, _ in GROUPS}
    shares["other"] = 0.0
    for line in p.stdout.splitlines():
        m = re.match(r"\s+([0-9.]+)%\s+\[[.k]\]\s+(.*)", line)
        if not m:
            continue
        share, symbol = float(m.group(1)), m.group(2).strip()
        group = next((g for g, rx in GROUPS if re.search(rx, symbol)), "other")
        shares[group] += share
    return shares


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--eps", type=float, default=1e-3)
    ap.add_argument("--h", type=float, default=0.005)
    ap.add_argument("--steps", type=int, default=200)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--methods", default="rattle,fixman")
    ap.add_argument("--stiffmd", default=os.path.join(ROOT, "build", "stiffmd"))
    ap.add_argument("--perf", default="perf")
    ap.add_argument("--out", default=os.path.join(ROOT, "sweeps", "profile_step"))
    args = ap.parse_args()
    args.stiffmd, args.out = os.path.abspath(args.stiffmd), os.path.abspath(args.out)
    methods = args.methods.replace(",", " ").split()
    os.makedirs(args.out, exist_ok=True)
    try:
        data = prepare_state(args.stiffmd, args.eps, os.path.join(args.out, f"datachain_eps{args.eps:g}.data"))
    except RunFailed as e:
        print(f"profile_step: {e}", file=sys.stderr)
        return 2
    decks = {}
    for m in methods:
        decks[m] = os.path.join(args.out, f"{m}.toml")
        write_deck(decks[m], data, args.eps, "tools/profile_step.py", engine_method(m)[0], args.h, 1, args.steps * args.h,
                   args.steps * args.h)
    per_step = {m: [] for m in methods}
    for r in range(args.repeats):  # interleaved: the machine's load drifts alike for all
        for m in methods:
            run_dir = os.path.join(args.out, f"{m}_r{r}")
            os.makedirs(run_dir, exist_ok=True)
            code, _, _ = run_measured(timed(args, m, decks[m], run_dir), run_dir, 1)
            if code != 0:
                print(f"profile_step: {m} failed (exit {code}) in {run_dir}", file=sys.stderr)
                return 2
            per_step[m].append(cpu_per_step(run_dir)[0])
    median = {m: statistics.median(v) for m, v in per_step.items()}
    lines = [f"data.chain at eps = {args.eps:g}, h = {args.h:g}, Langevin kT = 1, one thread, {args.steps} steps; "
             f"CPU ms per macro step, median of {args.repeats} interleaved runs", "",
             "| method | CPU ms / step | ÷ " + methods[0] + " |", "|---|--:|--:|"]
    lines += [f"| {m} | {1e3 * median[m]:.2f} | {median[m] / median[methods[0]]:.3f} |" for m in methods]
    perf = shutil.which(args.perf)
    if perf:
        lines += ["", "perf self-time split of one run each (start-up samples left out; ms = share × the median above):",
                  "", "| method | " + " | ".join(g for g, _ in GROUPS if g != "start-up") + " | other | constraints ÷ slow force |",
                  "|---|" + "--:|" * (len(GROUPS) + 1)]
        for m in methods:
            run_dir = os.path.join(args.out, f"{m}_perf")
            os.makedirs(run_dir, exist_ok=True)
            perf_data = os.path.join(run_dir, "perf.data")
            code, _, _ = run_measured([perf, "record", "-F", "999", "-o", perf_data, "--"] +
                                      timed(args, m, decks[m], run_dir), run_dir, 1)
            if code != 0:
                print(f"profile_step: perf record of {m} failed (exit {code}) in {run_dir}", file=sys.stderr)
                return 2
            shares = split(perf_data, perf)
            step_total = sum(v for g, v in shares.items() if g != "start-up")
            ms = {g: 1e3 * median[m] * v / step_total for g, v in shares.items() if g != "start-up"}
            cells = [f"{ms[g]:.2f} ({100 * shares[g] / step_total:.0f} %)" for g, _ in GROUPS if g != "start-up"]
            cells.append(f"{ms['other']:.2f} ({100 * shares['other'] / step_total:.0f} %)")
            lines.append(f"| {m} | " + " | ".join(cells) + f" | {ms['constraints'] / ms['slow force']:.2f} |")
    else:
        lines += ["", "perf not found: no split"]
    text = "\n".join(lines) + "\n"
    with open(os.path.join(args.out, "profile_step.md"), "w") as f:
        f.write(text)
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
