#!/usr/bin/python3
"""Run a deck over methods × macro steps (× ε) and measure each run against a reference.

For every ε of the sweep this runs a reference solution (the effective dynamics with a tiny
step, or velocity Verlet with δ ≤ ε/200), then every method at every macro step h, and
writes DIR/sweep_eps<ε>.csv with one row per run:

    eps, method, h, micro_dt, steps, err_x, err_p, slow_evaluations, fast_evaluations,
    cpu_seconds, wall_seconds, max_energy_error, action_1.., status

err_x = max_n |x_n − X(t_n)|∞ and err_p = max_n |P(x_n)p_n − Y(t_n)|∞ over the macro times
t_n = n h (docs/design.md §7). Runs that blow up (exit 3) are kept with status "unstable".
Each run's thermo.csv (energies, actions) stays in DIR/runs/ for plotting.

Example (the paper's experiment, see tools/paper_experiment.sh):
    /usr/bin/python3 tools/sweep.py inputs/double_pendulum.toml -o sweeps/paper \\
        --eps 1e-4 --h 1/4:1/1024 --methods impulse,mollified-impulse,projected-impulse
"""
import argparse
import csv
import os
import sys
from concurrent.futures import ThreadPoolExecutor
from fractions import Fraction

import numpy as np

from engines import read_summary, run_stiffmd, whole_steps_t_end  # tools/ is the script's directory

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
ALL_METHODS = ["impulse", "mollified-impulse", "projected-impulse", "rattle", "effective", "velocity-verlet"]


def halvings(spec):
    """'1/4:1/1024' -> [1/4, 1/8, ..., 1/1024]; '0.1,0.05' -> the list as given."""
    if ":" in spec:
        hi, lo = (Fraction(s) for s in spec.split(":"))
        out = []
        h = hi
        while h >= lo * (1 - Fraction(1, 10**9)):
            out.append(h)
            h /= 2
        return out
    return [Fraction(s) for s in spec.split(",")]


def run(exe, deck, out_dir, sets):
    """(exit code, stderr) of one run; exit 3 (blown up) is a result, any other failure stops the sweep.
    The thread count is the caller's environment's (CPU times of one thread need OMP_NUM_THREADS=1)."""
    r = run_stiffmd(exe, deck, out_dir, sets, threads=None, accept=(0, 3), fail=lambda m: sys.exit(f"sweep: {m}"))
    return r.code, r.stderr


def read_state(path):
    data = np.loadtxt(path, delimiter=",", skiprows=1, ndmin=2)
    n = (data.shape[1] - 1) // 6
    return data[:, 0], data[:, 1:1 + 3 * n], data[:, 1 + 3 * n:]


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("deck")
    ap.add_argument("-o", "--out", required=True, help="output directory")
    ap.add_argument("--methods", default=",".join(ALL_METHODS[:3]), help="comma-separated methods")
    ap.add_argument("--h", default="1/4:1/1024", help="macro steps: 'H1:H2' halving from H1 to H2, or a list")
    ap.add_argument("--eps", default="1e-4", help="comma-separated ε values (deck variable 'eps')")
    ap.add_argument("--t-end", default="10")
    ap.add_argument("--micro-dt", default="eps/100", help="micro step of the projected/mollified impulse methods")
    ap.add_argument("--micro-dt-impulse", default="eps/1000", help="micro step of the plain impulse method")
    ap.add_argument("--vv-steps", default="16:1024",
                    help="velocity-Verlet steps as divisors of the smallest h, 'D1:D2' doubling")
    ap.add_argument("--reference", default="effective", choices=["effective", "velocity-verlet"])
    ap.add_argument("--ref-divisor", type=int, default=0,
                    help="reference step = smallest h / this (default: 16 for effective, ≤ ε/200 for velocity-verlet)")
    ap.add_argument("--set", action="append", default=[], help="extra deck overrides for every run")
    ap.add_argument("--jobs", type=int, default=1, help="runs at once (CPU times are cleanest with 1)")
    ap.add_argument("--keep-states", action="store_true", help="keep each run's state.csv")
    ap.add_argument("--stiffmd", default=os.path.join(ROOT, "build", "stiffmd"))
    a = ap.parse_args()

    methods = [m.strip() for m in a.methods.split(",") if m.strip()]
    for m in methods:
        if m not in ALL_METHODS:
            sys.exit(f"sweep: unknown method '{m}' (known: {', '.join(ALL_METHODS)})")
    hs = halvings(a.h)
    h_min = min(hs)
    lo, hi = (int(s) for s in a.vv_steps.split(":"))
    vv_div = []
    d = lo
    while d <= hi:
        vv_div.append(d)
        d *= 2
    os.makedirs(a.out, exist_ok=True)

    for eps_text in a.eps.split(","):
        eps = float(eps_text)
        common = [f"variables.eps={eps_text}", f"run.t_end={a.t_end}", "output.xyz=", "observables.actions=true",
                  "output.state=state.csv", f"output.state_interval={float(h_min)!r}",
                  f"output.thermo_interval={float(h_min)!r}"] + a.set
        # Reference: its step divides the smallest macro step, so every macro time is on its grid.
        if a.reference == "effective":
            div = a.ref_divisor or 16
        else:
            div = a.ref_divisor or int(np.ceil(float(h_min) / (eps / 200)))
        ref_dir = os.path.join(a.out, "runs", f"reference_{a.reference}_eps{eps_text}")
        code, err = run(a.stiffmd, a.deck, ref_dir,
                                common + [f"integrator.method={a.reference}", f"integrator.h={float(h_min / div)!r}",
                                          f"run.t_end={whole_steps_t_end(a.t_end, h_min / div)}"])
        if code != 0:
            sys.exit(f"sweep: the reference run failed:\n{err}")
        rt, rx, rp = read_state(os.path.join(ref_dir, "state.csv"))

        jobs = []
        for m in methods:
            steps = [h_min / k for k in vv_div] if m == "velocity-verlet" else hs
            for h in steps:
                jobs.append((m, h))

        def one(job):
            m, h = job
            tag = f"{m}_h{float(h):.6g}_eps{eps_text}"
            d = os.path.join(a.out, "runs", tag)
            # States at the macro times n h; velocity Verlet's tiny steps are sampled on the
            # grid of the smallest macro step, like the reference.
            sets = common + [f"integrator.method={m}", f"integrator.h={float(h)!r}",
                             f"run.t_end={whole_steps_t_end(a.t_end, h)}",
                             f"output.state_interval={float(max(h, h_min))!r}"]
            micro = None
            if m in ("impulse", "mollified-impulse", "projected-impulse"):
                micro = a.micro_dt_impulse if m == "impulse" else a.micro_dt
                sets.append(f"integrator.micro_dt={micro}")
            code, err = run(a.stiffmd, a.deck, d, sets)
            row = {"eps": eps, "method": m, "h": float(h), "micro_dt": micro or "", "status": "ok"}
            if code != 0:
                row.update(status="unstable", err_x=float("inf"), err_p=float("inf"))
                return row
            s = read_summary(d)
            t, x, p = read_state(os.path.join(d, "state.csv"))
            # Macro times t_n = n h lie on the reference grid (spacing h_min).
            idx = np.rint(t / float(h_min)).astype(int)
            ok = (idx < len(rt)) & (np.abs(rt[np.minimum(idx, len(rt) - 1)] - t) < 1e-9 * max(1.0, float(a.t_end)))
            idx = idx[ok]
            row.update(steps=s["steps"], err_x=float(np.max(np.abs(x[ok] - rx[idx]))),
                       err_p=float(np.max(np.abs(p[ok] - rp[idx]))), slow_evaluations=s["slow_evaluations"],
                       fast_evaluations=s["fast_evaluations"], cpu_seconds=s["cpu_seconds"],
                       wall_seconds=s["wall_seconds"], max_energy_error=s["max_energy_error"])
            for k, I in enumerate(s["final_actions"]):
                row[f"action_{k + 1}"] = I
            if not a.keep_states:
                os.remove(os.path.join(d, "state.csv"))
            return row

        with ThreadPoolExecutor(max_workers=max(1, a.jobs)) as pool:
            rows = list(pool.map(one, jobs))
        cols = ["eps", "method", "h", "micro_dt", "steps", "err_x", "err_p", "slow_evaluations", "fast_evaluations",
                "cpu_seconds", "wall_seconds", "max_energy_error"]
        cols += sorted({k for r in rows for k in r if k.startswith("action_")}, key=lambda k: int(k[7:])) + ["status"]
        path = os.path.join(a.out, f"sweep_eps{eps_text}.csv")
        with open(path, "w", newline="") as f:
            w = csv.DictWriter(f, fieldnames=cols, restval="")
            w.writeheader()
            w.writerows(rows)
        if not a.keep_states:
            os.remove(os.path.join(ref_dir, "state.csv"))
        print(f"sweep: {len(rows)} runs at eps = {eps_text} -> {path}")


if __name__ == "__main__":
    main()
