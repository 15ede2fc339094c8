#!/usr/bin/python3
"""Action jumps at passages through a resonance ω_b = ratio · ω_a, against ε.

Runs a deck (default inputs/hard/resonance_1to2.toml, the double pendulum passing ω2 = 2ω1)
for several ε with a fine-step reference method (default: velocity Verlet on the full stiff
system with step ε/100), finds the passages through the resonance in the thermo output
(sign changes of ω_b/ω_a − ratio), and measures the jump of the actions at each passage as the
mean action over a window after the passage minus the mean over a window before it:

    passage zone  t_c ± d,  d = k √(ε / (ω_a |dr/dt|))   (k = --exclude; the resonance lasts
                                                         ~√(ε/ṙ) in time), clamped to
                                                         [3 fast periods, --max-exclude]
    before        [zone start − W, zone start],  after  [zone end, zone end + W]   (W = --window)

Passages whose zones overlap are merged into one event (a tangential passage gives two
crossings close together); windows are clipped at the neighbouring zones, and an event whose
window would be shorter than W/2 is skipped. The same difference taken at the midpoints between
passages ("control", only where |ω_b/ω_a − ratio| ≥ 3√ε throughout) is the noise floor of the
measurement: the O(ε) wobble of the computed actions and any drift not due to the resonance.
Near misses — ω_b/ω_a turning back just short of the ratio — also move the actions but are not
counted as passages (no crossing).

Per ε: the RMS of the jump |ΔI| = ‖(ΔI_a, ΔI_b)‖ over the passages; the fit log10 RMS|ΔI| =
log10 C + s log10 ε (theory: s = 1/2). Also reported: Δ(q I_a + p I_b) for ratio = p/q (the
resonance's conserved combination, I_1 + 2 I_2 for 1:2), which should be small against the jump.

Writes DIR/action_jumps.csv (one row per passage), DIR/action_jumps_fit.csv (one row per ε and
the slope) and the figure (default docs/figures/action_jumps.png); the runs stay in DIR/runs/.

Example:
    /usr/bin/python3 tools/action_jumps.py                                   # ≈ 10 s
    /usr/bin/python3 tools/action_jumps.py --eps 1e-2,1e-3 --t-end 5 -o /tmp/aj --png /tmp/aj.png
    /usr/bin/python3 tools/action_jumps.py --method projected-impulse --step 0.015625 --micro-dt eps/100
"""
import argparse
import csv
import math
import os
import sys
from concurrent.futures import ThreadPoolExecutor
from fractions import Fraction

import numpy as np

from engines import read_summary, read_thermo, run_stiffmd, whole_steps_t_end  # tools/ is the script's directory

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def eval_eps(expr, eps):
    """'eps/100' or '1e-5' -> a float, with eps bound (and pi, sqrt)."""
    return float(eval(expr, {"__builtins__": {}}, {"eps": eps, "pi": math.pi, "sqrt": math.sqrt}))


def run_deck(exe, deck, out_dir, sets):
    """One run (one thread unless OMP_NUM_THREADS says otherwise); its summary.json. A failure stops the tool."""
    run_stiffmd(exe, deck, out_dir, sets, threads=os.environ.get("OMP_NUM_THREADS", "1"),
                fail=lambda m: sys.exit(f"action_jumps: {m}"))
    return read_summary(out_dir)


def moving_average(y, n):
    if n <= 1:
        return y.copy()
    k = np.ones(n) / n
    pad = n // 2
    yp = np.concatenate([np.full(pad, y[0]), y, np.full(n - 1 - pad, y[-1])])
    return np.convolve(yp, k, mode="valid")


def find_events(th, eps, a, b, ratio, k_exclude, max_exclude, window):
    """Passages through ω_b = ratio ω_a, merged into events; returns (events, controls, r)."""
    t = th["time"]
    wa, wb = th[f"omega_{a}"], th[f"omega_{b}"]
    dt = float(np.median(np.diff(t)))
    period = 2 * math.pi * eps / max(float(np.mean(wa)), 1e-12)  # fast period of mode a
    r = moving_average(wb / wa - ratio, max(1, int(round(period / dt))))
    rdot = np.gradient(r, t)
    s = np.sign(r)
    idx = np.where(s[:-1] * s[1:] < 0)[0]
    crossings = []
    for i in idx:
        tc = t[i] - r[i] * (t[i + 1] - t[i]) / (r[i + 1] - r[i])
        rate = abs(0.5 * (rdot[i] + rdot[i + 1]))
        wa_c = 0.5 * (wa[i] + wa[i + 1])
        d = k_exclude * math.sqrt(eps / max(wa_c * rate, 1e-12))
        d = min(max(d, 3 * period), max_exclude)
        crossings.append([tc, d, rate])
    # Merge crossings whose zones overlap.
    events = []
    for tc, d, rate in crossings:
        lo, hi = tc - d, tc + d
        if events and lo <= events[-1]["zone"][1]:
            e = events[-1]
            e["zone"][1] = max(e["zone"][1], hi)
            e["n"] += 1
            e["times"].append(tc)
        else:
            events.append({"zone": [lo, hi], "n": 1, "times": [tc], "rate": rate})
    t0, t1 = float(t[0]), float(t[-1])
    for k, e in enumerate(events):
        prev_end = events[k - 1]["zone"][1] if k > 0 else t0
        next_start = events[k + 1]["zone"][0] if k + 1 < len(events) else t1
        lo, hi = e["zone"]
        e["before"] = (max(lo - window, prev_end, t0), lo)
        e["after"] = (hi, min(hi + window, next_start, t1))
        ok = (lo > t0 and hi < t1 and e["before"][1] - e["before"][0] >= window / 2
              and e["after"][1] - e["after"][0] >= window / 2)
        e["status"] = "ok" if ok else "skipped"
    # Controls: at the midpoints of the gaps between zones, where a whole window fits each side
    # and the frequencies stay away from the resonance (|r| ≥ 3√ε: near misses, where r turns
    # back just short of the resonance, move the actions too and are no control).
    controls = []
    edges = [t0] + [x for e in events for x in e["zone"]] + [t1]
    for g0, g1 in zip(edges[0::2], edges[1::2]):
        if g1 - g0 >= 2 * window + 4 * period:
            m = 0.5 * (g0 + g1)
            c = {"at": m, "before": (m - window - period, m - period), "after": (m + period, m + window + period)}
            inside = (t >= c["before"][0]) & (t <= c["after"][1])
            if np.min(np.abs(r[inside])) >= 3 * math.sqrt(eps):
                controls.append(c)
    return events, controls, r


def window_mean(t, y, w):
    m = (t >= w[0]) & (t <= w[1])
    return float(np.mean(y[m])) if m.any() else float("nan")


def conserved_weights(ratio):
    """ω_b = (p/q) ω_a: q ω_b − p ω_a = 0 keeps q I_a + p I_b."""
    fr = Fraction(ratio).limit_denominator(12)
    return fr.denominator, fr.numerator


def fit_loglog(x, y):
    lx, ly = np.log10(x), np.log10(y)
    A = np.vstack([np.ones_like(lx), lx]).T
    coef, res, *_ = np.linalg.lstsq(A, ly, rcond=None)
    n = len(lx)
    if n > 2:
        resid = ly - A @ coef
        s2 = float(resid @ resid) / (n - 2)
        cov = s2 * np.linalg.inv(A.T @ A)
        err = math.sqrt(cov[1, 1])
    else:
        err = float("nan")
    return float(coef[1]), float(10 ** coef[0]), err


def plot(path, per_eps, rows, fit, example, a, b, ratio):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(11.5, 4.4))
    ax = axes[0]
    pts = [(float(r["eps"]), float(r["jump"])) for r in rows if r["status"] == "ok" and float(r["jump"]) > 0]
    if pts:
        e, j = zip(*pts)
        ax.loglog(e, j, ".", color="0.6", ms=5, label="one passage |ΔI|")
    eps = np.array([p["eps"] for p in per_eps if p["measured"] > 0])
    rms = np.array([p["rms_jump"] for p in per_eps if p["measured"] > 0])
    ctl = np.array([p["control_rms"] for p in per_eps if p["measured"] > 0])
    ax.loglog(eps, rms, "ko", ms=7, label="RMS over passages")
    okc = np.isfinite(ctl) & (ctl > 0)
    if okc.any():
        ax.loglog(eps[okc], ctl[okc], "bx", ms=7, label="control (no passage)")
    if fit and np.isfinite(fit["slope"]):
        g = np.array([eps.min(), eps.max()])
        ax.loglog(g, fit["prefactor"] * g ** fit["slope"], "r-", lw=1.2,
                  label=f"fit: slope {fit['slope']:.2f} ± {fit['slope_err']:.2f}")
        c = 0.5 * math.exp(np.mean(np.log(rms) - 0.5 * np.log(eps)))  # a guide, offset below the data
        ax.loglog(g, c * np.sqrt(g), "k:", lw=1, label="∝ √ε (guide)")
    ax.set_xlabel("ε")
    ax.set_ylabel(f"action jump |(ΔI_{a}, ΔI_{b})|")
    ax.set_title(f"jumps at passages ω_{b} = {ratio:g} ω_{a}", fontsize=10)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    ax = axes[1]
    if example:
        th, events, eps_ex = example
        t = th["time"]
        ax.plot(t, th[f"action_{a}"], lw=0.8, label=f"I_{a}")
        ax.plot(t, th[f"action_{b}"], lw=0.8, label=f"I_{b}")
        for k, e in enumerate(events):
            for tc in e["times"]:
                ax.axvline(tc, color="k", ls="--", lw=0.6)
            if e["status"] == "ok":
                ax.axvspan(*e["before"], color="tab:green", alpha=0.15, lw=0)
                ax.axvspan(*e["after"], color="tab:red", alpha=0.15, lw=0)
        ax.set_title(f"ε = {eps_ex:g}: passages (dashed), windows before (green) / after (red)", fontsize=10)
        ax.set_xlabel("t")
        ax.set_ylabel("action")
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("deck", nargs="?", default=os.path.join(ROOT, "inputs", "hard", "resonance_1to2.toml"))
    ap.add_argument("-o", "--out", default=os.path.join(ROOT, "sweeps", "action_jumps"), help="output directory")
    ap.add_argument("--eps", default="1e-2,3e-3,1e-3,3e-4,1e-4", help="comma-separated ε (deck variable 'eps')")
    ap.add_argument("--t-end", type=float, default=20.0)
    ap.add_argument("--method", default="velocity-verlet")
    ap.add_argument("--step", default="eps/100", help="integrator.h as an expression in eps (default eps/100)")
    ap.add_argument("--micro-dt", default="eps/100", help="micro step of the impulse family (expression in eps)")
    ap.add_argument("--sample", type=float, default=0.002, help="thermo interval")
    ap.add_argument("--modes", default="1,2", help="the two modes a,b (thermo omega_/action_ indices)")
    ap.add_argument("--ratio", type=float, default=2.0, help="the resonance ω_b = ratio ω_a")
    ap.add_argument("--window", type=float, default=0.25, help="averaging window W before and after a passage")
    ap.add_argument("--exclude", type=float, default=3.0, help="k: passage zone t_c ± k √(ε/(ω_a |ṙ|))")
    ap.add_argument("--max-exclude", type=float, default=0.5, help="largest zone half-width")
    ap.add_argument("--alphas", default="1,1",
                    help="α1,α2 of a two-bond pendulum with fixed pivot and unit masses, to report |cos| "
                         "between the rods at each passage (c² = 2 − (ω1ω2)²/(α1α2)²); 'none' to skip")
    ap.add_argument("--csv", help="per-passage CSV (default DIR/action_jumps.csv)")
    ap.add_argument("--png", default=os.path.join(ROOT, "docs", "figures", "action_jumps.png"))
    ap.add_argument("--example-eps", type=float, help="ε of the actions-vs-time panel (default: the middle one)")
    ap.add_argument("--set", action="append", default=[], help="extra deck overrides")
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--stiffmd", default=os.path.join(ROOT, "build", "stiffmd"))
    a = ap.parse_args()

    ma, mb = (int(s) for s in a.modes.split(","))
    eps_texts = [s.strip() for s in a.eps.split(",") if s.strip()]
    os.makedirs(os.path.join(a.out, "runs"), exist_ok=True)
    alphas = None if a.alphas == "none" else [float(s) for s in a.alphas.split(",")]

    def one(eps_text):
        eps = float(eps_text)
        d = os.path.join(a.out, "runs", f"{a.method}_eps{eps_text}")
        sets = [f"variables.eps={eps_text}", f"integrator.method={a.method}",
                f"integrator.h={eval_eps(a.step, eps)!r}",
                f"run.t_end={whole_steps_t_end(a.t_end, eval_eps(a.step, eps))}", "observables.actions=true",
                "output.xyz=", "output.h5md=", "output.thermo=thermo.csv", f"output.thermo_interval={a.sample!r}"]
        if "impulse" in a.method:
            sets.append(f"integrator.micro_dt={eval_eps(a.micro_dt, eps)!r}")
        summary = run_deck(a.stiffmd, a.deck, d, sets + a.set)
        return eps_text, summary, read_thermo(os.path.join(d, "thermo.csv"))

    with ThreadPoolExecutor(max_workers=max(1, a.jobs)) as pool:
        results = list(pool.map(one, eps_texts))

    q, p = conserved_weights(a.ratio)
    rows, per_eps, examples = [], [], {}
    for eps_text, summary, th in results:
        eps = float(eps_text)
        events, controls, _ = find_events(th, eps, ma, mb, a.ratio, a.exclude, a.max_exclude, a.window)
        t, Ia, Ib = th["time"], th[f"action_{ma}"], th[f"action_{mb}"]
        jumps, cons = [], []
        for k, e in enumerate(events):
            row = {"eps": eps, "method": a.method, "event": k + 1, "t_cross": e["times"][0], "n_crossings": e["n"],
                   "zone_start": e["zone"][0], "zone_end": e["zone"][1], "status": e["status"]}
            if alphas:
                i = int(np.argmin(np.abs(t - e["times"][0])))
                c2 = 2 - (th["omega_1"][i] * th["omega_2"][i]) ** 2 / (alphas[0] * alphas[1]) ** 2
                row["abs_cos"] = math.sqrt(max(c2, 0.0))
            if e["status"] == "ok":
                ia0, ia1 = window_mean(t, Ia, e["before"]), window_mean(t, Ia, e["after"])
                ib0, ib1 = window_mean(t, Ib, e["before"]), window_mean(t, Ib, e["after"])
                dA, dB = ia1 - ia0, ib1 - ib0
                row.update(Ia_before=ia0, Ia_after=ia1, Ib_before=ib0, Ib_after=ib1, dIa=dA, dIb=dB,
                           jump=math.hypot(dA, dB), conserved_change=q * dA + p * dB)
                jumps.append(row["jump"])
                cons.append(abs(row["conserved_change"]))
            rows.append(row)
        ctl = []
        for c in controls:
            dA = window_mean(t, Ia, c["after"]) - window_mean(t, Ia, c["before"])
            dB = window_mean(t, Ib, c["after"]) - window_mean(t, Ib, c["before"])
            ctl.append(math.hypot(dA, dB))
        jumps = np.array(jumps)
        per_eps.append({
            "eps": eps, "method": a.method, "step": eval_eps(a.step, eps), "passages": sum(e["n"] for e in events),
            "events": len(events), "measured": len(jumps),
            "rms_jump": float(np.sqrt(np.mean(jumps ** 2))) if len(jumps) else float("nan"),
            "median_jump": float(np.median(jumps)) if len(jumps) else float("nan"),
            "max_jump": float(np.max(jumps)) if len(jumps) else float("nan"),
            "rms_jump_over_sqrt_eps": float(np.sqrt(np.mean(jumps ** 2)) / math.sqrt(eps)) if len(jumps) else float("nan"),
            "mean_abs_conserved_change": float(np.mean(cons)) if cons else float("nan"),
            "control_rms": float(np.sqrt(np.mean(np.square(ctl)))) if ctl else float("nan"), "controls": len(ctl),
            "initial_actions": " ".join(f"{x:.6g}" for x in summary.get("initial_actions", [])),
            "cpu_seconds": summary.get("cpu_seconds", float("nan"))})
        examples[eps] = (th, events, eps)

    good = [r for r in per_eps if r["measured"] > 0 and r["rms_jump"] > 0]
    fit = None
    if len(good) >= 2:
        slope, pref, err = fit_loglog(np.array([r["eps"] for r in good]), np.array([r["rms_jump"] for r in good]))
        pts = [(float(r["eps"]), float(r["jump"])) for r in rows if r["status"] == "ok" and r["jump"] > 0]
        s_all, _, e_all = fit_loglog(np.array([x for x, _ in pts]), np.array([y for _, y in pts]))
        fit = {"slope": slope, "prefactor": pref, "slope_err": err, "slope_all": s_all, "slope_all_err": e_all}

    csv_path = a.csv or os.path.join(a.out, "action_jumps.csv")
    cols = ["eps", "method", "event", "t_cross", "n_crossings", "abs_cos", "zone_start", "zone_end", "Ia_before",
            "Ia_after", "Ib_before", "Ib_after", "dIa", "dIb", "jump", "conserved_change", "status"]
    with open(csv_path, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=cols, restval="", extrasaction="ignore")
        w.writeheader()
        w.writerows(rows)
    fit_path = os.path.join(os.path.dirname(csv_path) or ".", "action_jumps_fit.csv")
    fcols = ["eps", "method", "step", "passages", "events", "measured", "rms_jump", "median_jump", "max_jump",
             "rms_jump_over_sqrt_eps", "mean_abs_conserved_change", "control_rms", "controls", "initial_actions",
             "cpu_seconds"]
    with open(fit_path, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=fcols + ["slope", "slope_err", "prefactor"], restval="")
        w.writeheader()
        w.writerows(per_eps)
        if fit:
            w.writerow({"eps": "fit", "method": a.method, "slope": fit["slope"], "slope_err": fit["slope_err"],
                        "prefactor": fit["prefactor"]})

    ex_eps = a.example_eps if a.example_eps is not None else sorted(examples)[len(examples) // 2]
    ex = examples.get(min(examples, key=lambda e: abs(math.log(e / ex_eps))))
    if a.png:
        os.makedirs(os.path.dirname(os.path.abspath(a.png)), exist_ok=True)
        plot(a.png, per_eps, rows, fit, ex, ma, mb, a.ratio)

    print(f"action_jumps: {a.deck}, method {a.method}, step {a.step}, t_end {a.t_end:g}, "
          f"resonance ω_{mb} = {a.ratio:g} ω_{ma}")
    print(f"{'eps':>8} {'passages':>8} {'measured':>8} {'rms|dI|':>10} {'median':>10} {'max':>10} "
          f"{'rms/sqrt(eps)':>13} {'|d(qIa+pIb)|':>12} {'control':>10}")
    for r in per_eps:
        print(f"{r['eps']:8.1e} {r['passages']:8d} {r['measured']:8d} {r['rms_jump']:10.4g} {r['median_jump']:10.4g} "
              f"{r['max_jump']:10.4g} {r['rms_jump_over_sqrt_eps']:13.4g} {r['mean_abs_conserved_change']:12.4g} "
              f"{r['control_rms']:10.4g}")
    if fit:
        print(f"fit: RMS|dI| = {fit['prefactor']:.3g} * eps^{fit['slope']:.3f} (slope ± {fit['slope_err']:.3f}; "
              f"over single passages {fit['slope_all']:.3f} ± {fit['slope_all_err']:.3f}); theory: slope 0.5")
    print(f"action_jumps: {csv_path}, {fit_path}" + (f", {a.png}" if a.png else ""))


if __name__ == "__main__":
    main()
