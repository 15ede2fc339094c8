#!/usr/bin/python3
"""Stability maps: run a deck over methods × macro steps h (× ε) on a long horizon and decide,
run by run, whether the integration stayed bounded.

Per run (one row of DIR/stability.csv):

    energy_error   max_t |E(t) − E(0)| / E_scale, from summary.json (every step). E_scale = |E(0)|,
                   or K(0) + |U(0)| + V_stiff(0) when |E(0)| is below a tenth of that (E(0) ≈ 0).
    violation      max over the thermo rows of max_b |g_b(x)| (bond-length error).
    action_drift   max_t |Σ_k I_k(t) − Σ_k I_k(0)| / Σ_k I_k(0), the total action of the stiff
                   modes (thermo action_k), when observed and Σ_k I_k(0) > 0 — empty for rattle and
                   effective, whose states carry no vibration. The total, not each I_k: on chains
                   the actions are exchanged between near-degenerate modes even in the exact
                   dynamics, but a resonance instability pumps the total. Where the exact dynamics
                   is not adiabatic (ε not small, tiny initial actions) it moves too: pass
                   --action-tol inf to leave the actions out of the decision.
    status         "unstable"  — the engine stopped with exit 3 (non-finite state, SHAKE failure);
                   "unbounded" — it finished but energy_error > --energy-tol, or violation >
                                 --violation-factor · max(violation at t = 0, ε), or action_drift
                                 > --action-tol (column 'reason' says which);
                   "bounded"   — otherwise.

The largest stable macro step, per method and ε, is the largest h of the grid such that the run at
h and every run at a smaller h of the grid are bounded (DIR/largest_stable_h.csv and .md; "< h_min"
when the smallest h already fails). h_over_period = h / (2π ε / ω_max) with --omega-max, or
h / T_fast with --fast-period (an expression in eps).

The impulse family uses the micro step --micro-dt (default eps/40: n = ceil(h/δ) micro steps);
velocity Verlet runs on its own grid of small steps (--vv-h, expressions in eps). Figures: one PNG
per deck (--png), a panel per method: x = h (log), y = ε, colour = log10 energy_error, "x" =
unstable (exit 3), open circle = unbounded; dotted lines at h = the fastest period and its half
(when known); a white bar at each ε's largest stable h.

Example (the double pendulum, ≈ 2 minutes):
    /usr/bin/python3 tools/stability_map.py inputs/double_pendulum.toml -o sweeps/stability_pendulum \\
        --eps 1e-2,3e-3,1e-3 --h 1/256:1/2 --t-end 100 --omega-max 1.618 \\
        --png docs/figures/stability_pendulum.png --jobs 2
Re-plot without running: add --plot-only.
"""
import argparse
import csv
import math
import os
import shutil
import subprocess
import sys
import time
from concurrent.futures import ThreadPoolExecutor

import numpy as np

from engines import read_summary, read_thermo, run_stiffmd, whole_steps_t_end  # tools/ is the script's directory

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
ALL_METHODS = ["impulse", "mollified-impulse", "projected-impulse", "rattle", "effective", "velocity-verlet"]
CSV_COLUMNS = ["eps", "method", "h", "micro_steps", "h_over_period", "energy_error", "violation",
               "violation_threshold", "action_drift", "status", "reason", "exit_code", "steps", "cpu_seconds",
               "wall_seconds", "message"]


def eval_expr(expr, eps):
    """'eps/40', '2*pi*eps/1.618', '1/64' -> float (eps, pi, sqrt bound)."""
    return float(eval(str(expr), {"__builtins__": {}}, {"eps": eps, "pi": math.pi, "sqrt": math.sqrt}))


def grid(spec, eps=None, factor=2.0):
    """'A:B' -> A, A/factor, ... down to B (A > B) or up to B; 'A:B:n' -> n geometric points;
    'a,b,c' -> the list. Entries are expressions (in eps when given)."""
    def ev(text):
        return eval_expr(text, eps if eps is not None else float("nan"))

    if ":" in spec:
        parts = spec.split(":")
        a, b = ev(parts[0]), ev(parts[1])
        lo, hi = min(a, b), max(a, b)
        if len(parts) == 3:
            return sorted(float(x) for x in np.geomspace(lo, hi, int(parts[2])))
        out, x = [], hi
        while x >= lo * (1 - 1e-9):
            out.append(x)
            x /= factor
        return sorted(out)
    return sorted(ev(s) for s in spec.split(",") if s.strip())


def run_one(a, deck, eps, method, h, out_dir):
    sets = [f"integrator.method={method}", f"integrator.h={h!r}", f"run.t_end={whole_steps_t_end(a.t_end, h)}",
            "output.xyz=", "output.h5md=", "output.thermo=thermo.csv", f"output.thermo_interval={a.sample or a.t_end / 200!r}"]
    if eps is not None:
        sets.append(f"variables.eps={eps!r}")
    if a.actions:
        sets.append("observables.actions=true")
    micro_steps = 1
    if "impulse" in method:
        micro = eval_expr(a.micro_dt, eps if eps is not None else a.deck_eps)
        sets.append(f"integrator.micro_dt={min(micro, h)!r}")
        micro_steps = int(math.ceil(h / min(micro, h) - 1e-9))
    if os.path.isdir(out_dir):
        shutil.rmtree(out_dir)
    p = run_stiffmd(a.stiffmd, deck, out_dir, sets + a.set, threads=os.environ.get("OMP_NUM_THREADS", "1"),
                    accept=(0, 3), fail=lambda m: sys.exit(f"stability_map: {m}"))
    row = {"method": method, "h": h, "micro_steps": micro_steps, "exit_code": p.code, "wall_seconds": p.seconds}
    if p.code == 3:
        lines = [ln for ln in p.stderr.splitlines() if ln.startswith("error")]
        row.update(status="unstable", reason="exit 3", message=(lines[-1] if lines else p.stderr.strip()[-300:]))
        return row, None
    s = read_summary(out_dir)
    th = read_thermo(os.path.join(out_dir, "thermo.csv"))
    e0 = s["initial_energy"]
    parts = abs(th["kinetic"][0]) + abs(th["potential_slow"][0]) + abs(th["potential_stiff"][0])
    if "potential_fixman" in th:  # fixman: Fixman's potential, in the total
        parts += abs(th["potential_fixman"][0])
    scale = abs(e0) if abs(e0) >= 0.1 * parts else parts
    eps_run = s.get("epsilon", eps)
    viol = float(max(np.max(th["max_violation"]), s.get("final_max_violation", 0.0)))
    v_thr = a.violation_factor * max(float(th["max_violation"][0]), eps_run or 0.0)
    acts = [k for k in th if k.startswith("action_")]
    drift = float("nan")
    if acts:
        total = np.sum([th[k] for k in acts], axis=0)
        if total[0] > 1e-12:
            drift = float(np.max(np.abs(total - total[0])) / total[0])
    energy_error = s["max_energy_error"] / scale if scale > 0 else float("inf")
    reasons = []
    if not energy_error <= a.energy_tol:
        reasons.append("energy")
    if not viol <= v_thr:
        reasons.append("violation")
    if not (math.isnan(drift) or drift <= a.action_tol):
        reasons.append("actions")
    row.update(energy_error=energy_error, violation=viol, violation_threshold=v_thr, action_drift=drift,
               steps=s["steps"], cpu_seconds=s["cpu_seconds"], status="unbounded" if reasons else "bounded",
               reason="+".join(reasons), message="")
    if not a.keep_runs:
        for name in ("thermo.csv", "checkpoint.bin", "histograms.csv"):
            try:
                os.remove(os.path.join(out_dir, name))
            except FileNotFoundError:
                pass
    return row, eps_run


def largest_stable(rows):
    """{(method, eps): (h_max or None, h_min, first failing h or None)}"""
    out = {}
    keys = sorted({(r["method"], float(r["eps"])) for r in rows})
    for m, e in keys:
        rs = sorted((r for r in rows if r["method"] == m and float(r["eps"]) == e), key=lambda r: float(r["h"]))
        best, fail = None, None
        for r in rs:
            if r["status"] != "bounded":
                fail = float(r["h"])
                break
            best = float(r["h"])
        out[(m, e)] = (best, float(rs[0]["h"]), fail)
    return out


def fmt(x):
    return "" if x is None or (isinstance(x, float) and math.isnan(x)) else f"{x:.4g}"


def write_tables(rows, out, title, omega_max, fast_period_expr):
    table = largest_stable(rows)
    methods = [m for m in ALL_METHODS if any(k[0] == m for k in table)]
    epss = sorted({k[1] for k in table}, reverse=True)
    recs = []
    for m in methods:
        for e in epss:
            if (m, e) not in table:
                continue
            best, hmin, fail = table[(m, e)]
            per = period(e, omega_max, fast_period_expr)
            recs.append({"deck": title, "method": m, "eps": e, "largest_stable_h": best if best is not None else "",
                         "below_grid": "" if best is not None else f"< {hmin:.4g}",
                         "first_failing_h": fail if fail is not None else "",
                         "largest_over_eps": best / e if best is not None else "",
                         "largest_over_period": best / per if (best is not None and per) else ""})
    with open(os.path.join(out, "largest_stable_h.csv"), "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(recs[0].keys()) if recs else ["deck"])
        w.writeheader()
        w.writerows(recs)
    lines = [f"Largest stable macro step ({title}): the largest h of the grid with it and every smaller h bounded",
             "", "| method | " + " | ".join(f"ε = {e:g}" for e in epss) + " |",
             "|---|" + "---|" * len(epss)]
    for m in methods:
        cells = []
        for e in epss:
            if (m, e) not in table:
                cells.append("")
                continue
            best, hmin, fail = table[(m, e)]
            per = period(e, omega_max, fast_period_expr)
            if best is None:
                cells.append(f"< {hmin:.4g}")
            else:
                c = f"{best:.4g}"
                if per:
                    c += f" ({best / per:.2g} T)"
                if fail is None:
                    c += " (grid max)"
                cells.append(c)
        lines.append(f"| {m} | " + " | ".join(cells) + " |")
    if omega_max or fast_period_expr:
        lines += ["", "T = the fastest bond period " + (f"2πε/ω_max, ω_max = {omega_max:g}" if omega_max
                                                       else f"{fast_period_expr}") + "."]
    text = "\n".join(lines) + "\n"
    with open(os.path.join(out, "largest_stable_h.md"), "w") as f:
        f.write(text)
    return text


def period(eps, omega_max, fast_period_expr):
    if fast_period_expr:
        return eval_expr(fast_period_expr, eps)
    if omega_max:
        return 2 * math.pi * eps / omega_max
    return None


def plot(rows, path, title, omega_max, fast_period_expr, energy_tol):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.colors import Normalize

    methods = [m for m in ALL_METHODS if any(r["method"] == m for r in rows)]
    n = len(methods)
    ncol = min(3, n)
    nrow = int(math.ceil(n / ncol))
    fig, axes = plt.subplots(nrow, ncol, figsize=(5.0 * ncol, 3.4 * nrow + 0.6), squeeze=False)
    finite = [float(r["energy_error"]) for r in rows if r["status"] != "unstable" and r["energy_error"] not in ("", None)]
    finite = [x for x in finite if x > 0 and math.isfinite(x)]
    lo = math.floor(math.log10(min(finite))) if finite else -6
    norm = Normalize(vmin=max(lo, -8), vmax=2)
    cmap = plt.get_cmap("viridis").copy()
    cmap.set_over("tab:red")
    table = largest_stable(rows)
    mesh = None
    for k, m in enumerate(methods):
        ax = axes[k // ncol][k % ncol]
        rs = [r for r in rows if r["method"] == m]
        # Velocity Verlet's steps are a grid in units of ε: plotted against h/ε.
        rel = m == "velocity-verlet"

        def xof(r):
            return float(r["h"]) / float(r["eps"]) if rel else float(r["h"])

        hs = sorted({round(xof(r), 12) for r in rs})
        es = sorted({float(r["eps"]) for r in rs})

        def edges(v):
            v = np.array(v)
            if len(v) == 1:
                return np.array([v[0] / 1.5, v[0] * 1.5])
            mid = np.sqrt(v[1:] * v[:-1])
            return np.concatenate([[v[0] ** 2 / mid[0]], mid, [v[-1] ** 2 / mid[-1]]])

        he, ee = edges(hs), edges(es)
        z = np.full((len(es), len(hs)), np.nan)
        for r in rs:
            i, j = es.index(float(r["eps"])), hs.index(round(xof(r), 12))
            if r["status"] != "unstable":
                z[i, j] = math.log10(max(float(r["energy_error"]), 1e-16))
        mesh = ax.pcolormesh(he, ee, np.ma.masked_invalid(z), cmap=cmap, norm=norm, shading="flat")
        for r in rs:
            x, y = round(xof(r), 12), float(r["eps"])
            if r["status"] == "unstable":
                ax.add_patch(plt.Rectangle((he[hs.index(x)], ee[es.index(y)]), he[hs.index(x) + 1] - he[hs.index(x)],
                                           ee[es.index(y) + 1] - ee[es.index(y)], color="0.85", zorder=1))
                ax.plot(x, y, "kx", ms=8, mew=2, zorder=3)
            elif r["status"] == "unbounded":
                ax.plot(x, y, "o", mfc="none", mec="w", ms=9, mew=1.6, zorder=3)
        for e in es:
            best = table[(m, e)][0]
            if best is not None:
                i = es.index(e)
                j = hs.index(round(best / e if rel else best, 12))
                ax.plot([he[j + 1], he[j + 1]], [ee[i], ee[i + 1]], color="w", lw=3, zorder=4)
        if omega_max or fast_period_expr:
            ee_fine = np.geomspace(ee[0], ee[-1], 50)
            for fac, lab in ((1.0, "T"), (0.5, "T/2")):
                hp = np.array([fac * period(e, omega_max, fast_period_expr) / (e if rel else 1.0) for e in ee_fine])
                ax.plot(hp, ee_fine, ":", color="w" if fac == 1 else "0.7", lw=1.2, zorder=2)
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlim(he[0], he[-1])
        ax.set_ylim(ee[0], ee[-1])
        ax.set_yticks(es)
        ax.set_yticklabels([f"{e:g}" for e in es])
        ax.tick_params(axis="y", which="minor", left=False)
        nice = [k * 10.0 ** p for p in range(-8, 4) for k in (1, 2, 5) if he[0] <= k * 10.0 ** p <= he[-1]]
        if len(nice) >= 2:
            ax.set_xticks(nice)
            ax.set_xticklabels([f"{x:g}" for x in nice], fontsize=8)
        ax.set_title(m, fontsize=10)
        ax.set_xlabel("step h / ε" if rel else "macro step h")
        ax.set_ylabel("ε")
    for k in range(n, nrow * ncol):
        axes[k // ncol][k % ncol].axis("off")
    fig.suptitle(f"{title}: log10 relative energy error (red: > 100; x: exit 3; o: over a threshold; "
                 f"white bar: largest stable h; dotted: h = T, T/2)", fontsize=9)
    fig.tight_layout(rect=(0, 0, 0.92, 0.95))
    cax = fig.add_axes((0.93, 0.15, 0.015, 0.7))
    cb = fig.colorbar(mesh, cax=cax, extend="max")
    cb.set_label("log10 energy error")
    cb.ax.axhline(math.log10(energy_tol), color="w", lw=1.5)
    fig.savefig(path, dpi=90)
    plt.close(fig)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("deck")
    ap.add_argument("-o", "--out", required=True, help="output directory (stability.csv, tables, runs/)")
    ap.add_argument("--methods", default=",".join(ALL_METHODS), help="comma-separated methods")
    ap.add_argument("--h", default="1/256:1/2",
                    help="macro steps: 'A:B' halving from the larger to the smaller, 'A:B:n' n geometric points, or "
                         "a list (expressions in eps allowed)")
    ap.add_argument("--vv-h", default="eps/32:2*eps", help="velocity-Verlet steps (same forms, expressions in eps)")
    ap.add_argument("--eps", default="", help="comma-separated ε (deck variable 'eps'); empty: the deck's own")
    ap.add_argument("--t-end", type=float, default=100.0)
    ap.add_argument("--sample", type=float, default=0.0, help="thermo interval (default t_end/200)")
    ap.add_argument("--micro-dt", default="eps/40", help="micro step of the impulse family (expression in eps)")
    ap.add_argument("--energy-tol", type=float, default=0.05, help="largest bounded relative energy error")
    ap.add_argument("--violation-factor", type=float, default=5.0,
                    help="bounded while max|g| <= factor * max(max|g| at t = 0, eps)")
    ap.add_argument("--action-tol", type=float, default=0.5, help="largest bounded relative drift of the total action")
    ap.add_argument("--no-actions", dest="actions", action="store_false", help="do not observe the actions")
    ap.add_argument("--omega-max", type=float, default=0.0, help="largest ω_k: fastest period 2πε/ω_max")
    ap.add_argument("--fast-period", default="", help="the fastest period as an expression in eps (instead of --omega-max)")
    ap.add_argument("--title", default="", help="figure title (default: the deck's name)")
    ap.add_argument("--png", default="", help="figure path (default DIR/stability.png)")
    ap.add_argument("--set", action="append", default=[], help="extra deck overrides for every run")
    ap.add_argument("--jobs", type=int, default=1, help="runs at once")
    ap.add_argument("--keep-runs", action="store_true", help="keep each run's thermo.csv and checkpoint")
    ap.add_argument("--plot-only", action="store_true", help="re-plot DIR/stability.csv, run nothing")
    ap.add_argument("--stiffmd", default=os.path.join(ROOT, "build", "stiffmd"))
    a = ap.parse_args()

    title = a.title or os.path.splitext(os.path.basename(a.deck))[0]
    png = a.png or os.path.join(a.out, "stability.png")
    csv_path = os.path.join(a.out, "stability.csv")
    os.makedirs(a.out, exist_ok=True)
    start = time.monotonic()
    if a.plot_only:
        with open(csv_path) as f:
            rows = list(csv.DictReader(f))
    else:
        methods = [m.strip() for m in a.methods.split(",") if m.strip()]
        for m in methods:
            if m not in ALL_METHODS:
                sys.exit(f"stability_map: unknown method '{m}' (known: {', '.join(ALL_METHODS)})")
        eps_list = [float(s) for s in a.eps.split(",") if s.strip()] or [None]
        a.deck_eps = None
        if eps_list == [None]:
            # The deck's own ε, for the expressions in eps: from a 'check' of the deck.
            p = subprocess.run([a.stiffmd, "check", a.deck] + sum((["--set", s] for s in a.set), []),
                               capture_output=True, text=True)
            for line in p.stdout.splitlines():
                if "stiff-harmonic" in line and "epsilon =" in line:
                    a.deck_eps = float(line.split("epsilon =")[1].split()[0].strip(",;)"))
            if a.deck_eps is None:
                sys.exit("stability_map: give --eps (could not read the deck's epsilon from 'stiffmd check')")
        jobs = []
        for e in eps_list:
            ev = e if e is not None else a.deck_eps
            for m in methods:
                hs = grid(a.vv_h, ev) if m == "velocity-verlet" else grid(a.h, ev)
                for h in hs:
                    jobs.append((e, m, h))

        def one(job):
            e, m, h = job
            tag = f"{m}_h{h:.6g}" + (f"_eps{e:g}" if e is not None else "")
            row, eps_run = run_one(a, a.deck, e, m, h, os.path.join(a.out, "runs", tag))
            row["eps"] = e if e is not None else (eps_run if eps_run is not None else a.deck_eps)
            per = period(float(row["eps"]), a.omega_max, a.fast_period)
            row["h_over_period"] = h / per if per else ""
            print(f"  {m:18s} eps={float(row['eps']):<8g} h={h:<10.4g} {row['status']:9s} "
                  f"E={fmt(row.get('energy_error'))} g={fmt(row.get('violation'))} "
                  f"I={fmt(row.get('action_drift'))} {row.get('reason', '')} ({row['wall_seconds']:.1f} s)", flush=True)
            return row

        with ThreadPoolExecutor(max_workers=max(1, a.jobs)) as pool:
            rows = list(pool.map(one, jobs))
        with open(csv_path, "w", newline="") as f:
            w = csv.DictWriter(f, fieldnames=CSV_COLUMNS, restval="", extrasaction="ignore")
            w.writeheader()
            w.writerows(rows)
        # Normalise to the CSV's text form for the tables and the plot.
        with open(csv_path) as f:
            rows = list(csv.DictReader(f))
    text = write_tables(rows, a.out, title, a.omega_max, a.fast_period)
    plot(rows, png, title, a.omega_max, a.fast_period, a.energy_tol)
    print(text)
    n_bad = sum(r["status"] != "bounded" for r in rows)
    print(f"stability_map: {len(rows)} runs ({n_bad} not bounded) in {time.monotonic() - start:.0f} s wall "
          f"-> {csv_path}, {os.path.join(a.out, 'largest_stable_h.md')}, {png}")


if __name__ == "__main__":
    main()
