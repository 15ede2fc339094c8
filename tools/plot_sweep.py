#!/usr/bin/python3
"""Figures from a sweep directory (tools/sweep.py): PNGs next to the CSVs, or in --out.

  error_vs_h_eps<ε>.png        error in x and in P(x)p vs h per method, slope-2 guide (paper Figs. 1–3)
  actions_eps<ε>.png           actions vs time, impulse vs projected impulse at one h (paper Figs. 4–5)
  work_precision_eps<ε>.png    error vs CPU seconds and vs slow-force evaluations, every method
"""
import argparse
import csv
import glob
import os

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

STYLE = {
    "impulse": ("tab:red", "o"),
    "mollified-impulse": ("tab:blue", "s"),
    "projected-impulse": ("tab:green", "^"),
    "rattle": ("tab:purple", "v"),
    "effective": ("tab:gray", "D"),
    "velocity-verlet": ("tab:orange", "x"),
}


def read_rows(path):
    with open(path) as f:
        return list(csv.DictReader(f))


def by_method(rows):
    out = {}
    for r in rows:
        if r["status"] != "ok":
            continue
        out.setdefault(r["method"], []).append(r)
    for m in out:
        out[m].sort(key=lambda r: float(r["h"]))
    return out


def col(rs, key):
    return np.array([float(r[key]) for r in rs])


def error_vs_h(rows, eps, path):
    groups = by_method(rows)
    fig, axes = plt.subplots(1, 2, figsize=(10, 4.2))
    for ax, key, title in ((axes[0], "err_x", "positions: max |x_n - X(t_n)|"),
                           (axes[1], "err_p", "projected momenta: max |P(x_n)p_n - Y(t_n)|")):
        hmin, hmax = np.inf, 0
        for m, rs in groups.items():
            if m == "velocity-verlet":
                continue
            c, mk = STYLE.get(m, ("k", "."))
            h = col(rs, "h")
            ax.loglog(h, col(rs, key), marker=mk, color=c, label=m)
            hmin, hmax = min(hmin, h.min()), max(hmax, h.max())
        if hmax > 0:
            g = np.array([hmin, hmax])
            ax.loglog(g, 0.5 * g**2, "k-.", lw=1, label="slope 2")
        ax.axhline(2 * eps, color="k", ls=":", lw=0.8, label="2ε")
        ax.set_xlabel("macro step h")
        ax.set_title(title, fontsize=10)
        ax.grid(True, which="both", alpha=0.3)
    axes[0].legend(fontsize=8)
    fig.suptitle(f"stiff spring double pendulum, ε = {eps:g}: error vs step", fontsize=11)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def actions(sweep_dir, eps_text, h, path):
    """Top: I_k(t). Bottom: |I_k(t) − I_k(0)| on a log scale against ε (adiabatic invariance is O(ε))."""
    eps = float(eps_text)
    fig, axes = plt.subplots(2, 2, figsize=(10, 6.4), sharex=True, sharey="row")
    for j, m in enumerate(("impulse", "projected-impulse")):
        top, bottom = axes[0][j], axes[1][j]
        run = glob.glob(os.path.join(sweep_dir, "runs", f"{m}_h{h:.6g}_eps{eps_text}", "thermo.csv"))
        if not run:
            top.set_title(f"{m}: no run at h = {h:g}")
            continue
        data = np.genfromtxt(run[0], delimiter=",", names=True)
        for n in (n for n in data.dtype.names if n.startswith("action_")):
            label = n.replace("_", " ")
            top.plot(data["time"], data[n], lw=1, label=label)
            bottom.semilogy(data["time"], np.maximum(np.abs(data[n] - data[n][0]), 1e-12), lw=1, label=label)
        bottom.axhline(eps, color="k", ls=":", lw=0.8, label="ε")
        top.set_title(f"{m}, h = {h:g}", fontsize=10)
        bottom.set_xlabel("t")
        for ax in (top, bottom):
            ax.grid(True, alpha=0.3)
    axes[0][0].set_ylabel("action I_k")
    axes[1][0].set_ylabel("|I_k(t) - I_k(0)|")
    axes[0][0].legend(fontsize=8)
    axes[1][0].legend(fontsize=8)
    fig.suptitle(f"actions (adiabatic invariants), ε = {eps:g}", fontsize=11)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def work_precision(rows, eps, path):
    groups = by_method(rows)
    fig, axes = plt.subplots(1, 2, figsize=(10, 4.2), sharey=True)
    for m, rs in groups.items():
        c, mk = STYLE.get(m, ("k", "."))
        err = col(rs, "err_x")
        axes[0].loglog(np.maximum(col(rs, "cpu_seconds"), 1e-6), err, marker=mk, color=c, label=m)
        axes[1].loglog(col(rs, "slow_evaluations"), err, marker=mk, color=c, label=m)
    axes[0].set_xlabel("CPU seconds")
    axes[1].set_xlabel("slow-force evaluations")
    axes[0].set_ylabel("max position error")
    for ax in axes:
        ax.axhline(2 * eps, color="k", ls=":", lw=0.8)
        ax.grid(True, which="both", alpha=0.3)
    axes[0].legend(fontsize=8)
    fig.suptitle(f"work-precision, ε = {eps:g} (error against the reference of tools/sweep.py)", fontsize=11)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("sweep_dir")
    ap.add_argument("--out", help="directory for the PNGs (default: the sweep directory)")
    ap.add_argument("--actions-h", type=float, default=1 / 64, help="macro step of the actions figure")
    a = ap.parse_args()
    out = a.out or a.sweep_dir
    os.makedirs(out, exist_ok=True)
    files = sorted(glob.glob(os.path.join(a.sweep_dir, "sweep_eps*.csv")))
    if not files:
        raise SystemExit(f"plot_sweep: no sweep_eps*.csv in {a.sweep_dir}")
    for f in files:
        eps_text = os.path.basename(f)[len("sweep_eps"):-len(".csv")]
        eps = float(eps_text)
        rows = read_rows(f)
        written = [os.path.join(out, f"error_vs_h_eps{eps_text}.png"), os.path.join(out, f"actions_eps{eps_text}.png"),
                   os.path.join(out, f"work_precision_eps{eps_text}.png")]
        error_vs_h(rows, eps, written[0])
        actions(a.sweep_dir, eps_text, a.actions_h, written[1])
        work_precision(rows, eps, written[2])
        for w in written:
            print(f"plot_sweep: {w}")


if __name__ == "__main__":
    main()
