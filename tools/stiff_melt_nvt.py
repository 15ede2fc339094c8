#!/usr/bin/python3
"""Stiff springs, rigid bonds and the thermal stiff limit on a melt at constant temperature.

The scene is inputs/lammps_chain.toml (LAMMPS's data.chain: 32 000 beads in 320 chains of 100,
stiff harmonic bonds l = 0.97, alpha = 1, WCA between non-bonded pairs) at eps = --eps (1e-3), under
Langevin dynamics (kT = 1, damp = --damp). Three runs from the same prepared state:

  velocity-verlet  h = --h-vv (2e-4: h omega_max = 0.4; BAOAB)   the stiff springs: the reference
  rattle           h = --h-rigid (0.005; constrained BAOAB)       rigid bonds: expected to differ
  fixman           h = --h-rigid (RATTLE on U + Fixman's U_F)     thermal stiff limit: expected to agree

Measured after --discard time units: the bond-angle distribution (angle i-j-k of consecutive
bonds, 180 deg = straight) from frames every --frame-every, <cos theta> and <cos^2 theta>; the
mean radius of gyration and the pressure from thermo.csv; block standard errors over --blocks
blocks; cost per unit simulated time (summary.json: wall and CPU of the step loop, one thread).
Chains of 100 relax over far longer times than these runs: Rg compares runs from the same start,
not equilibrium values. Figure: docs/figures/stiff_melt_nvt_angles.png; table: OUT/summary.md.

    /usr/bin/python3 tools/stiff_melt_nvt.py                    # docs/performance.md §3 (5-10 min on 2 cores)
    /usr/bin/python3 tools/stiff_melt_nvt.py --plot-only        # figure and table from OUT
"""
import argparse
import concurrent.futures
import math
import os
import sys

import numpy as np

from chain_melt import block_mean, read_bonds, xyz_frames  # tools/ is the script's directory
from engines import failure, read_summary, read_thermo, run_engine, stiffmd_command

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
DECK = os.path.join(ROOT, "inputs", "lammps_chain.toml")
LABEL = {"velocity-verlet": "velocity Verlet (stiff springs)", "rattle": "rattle (rigid bonds)",
         "fixman": "fixman (thermal stiff limit)"}


def run(args, method, h):
    out = os.path.join(args.out, method)
    cmd = stiffmd_command(args.stiffmd, DECK, out, [
        f"variables.eps={args.eps!r}", f'integrator.method="{method}"', f"integrator.h={h!r}",
        "integrator.micro_steps=1", f"run.t_end={args.t_end!r}", 'thermostat.style="langevin"',
        "thermostat.temperature=1.0", f"thermostat.damp={args.damp!r}", f"thermostat.seed={args.seed}",
        'output.xyz="frames.xyz"', f"output.xyz_interval={args.frame_every!r}",
        f"output.thermo_interval={args.frame_every / 5!r}"])
    with open(os.path.join(args.out, method + ".command.txt"), "w") as f:
        f.write(" ".join(cmd) + "\n")
    p = run_engine(cmd)
    if p.code != 0:
        sys.exit(failure(p, method))
    return method


def angle_triples(bonds, n):
    neighbours = [[] for _ in range(n)]
    for i, j in bonds:
        neighbours[i].append(j)
        neighbours[j].append(i)
    return np.array([(nb[0], j, nb[1]) for j, nb in enumerate(neighbours) if len(nb) == 2])


def analyse(args, method, bins):
    out = os.path.join(args.out, method)
    box = 33.592
    bonds = np.array(read_bonds(os.path.join(out, "topology.data")))
    triples = None
    cos1, cos2, hist = [], [], []
    for t, x in xyz_frames(os.path.join(out, "frames.xyz")):
        if t < args.discard - 1e-9:
            continue
        if triples is None:
            triples = angle_triples(bonds, len(x))
        a = x[triples[:, 0]] - x[triples[:, 1]]
        b = x[triples[:, 2]] - x[triples[:, 1]]
        a -= box * np.round(a / box)
        b -= box * np.round(b / box)
        c = np.einsum("ij,ij->i", a, b) / np.linalg.norm(a, axis=1) / np.linalg.norm(b, axis=1)
        cos1.append(c.mean())
        cos2.append((c * c).mean())
        theta = np.degrees(np.arccos(np.clip(c, -1, 1)))
        hist.append(np.histogram(theta, bins=bins)[0] / len(theta))
    th = read_thermo(os.path.join(out, "thermo.csv"))
    keep = th["time"] > args.discard + 1e-9
    summary = read_summary(out)
    nb = args.blocks
    r = {"frames": len(cos1), "cos": block_mean(cos1, nb), "cos2": block_mean(cos2, nb),
         "hist": block_mean(hist, nb), "rg": block_mean(th["rg"][keep], nb),
         "pressure": block_mean(th["pressure"][keep], nb), "temperature": block_mean(th["temperature"][keep], nb),
         "wall_per_time": summary["wall_seconds"] / summary["t_end"],
         "cpu_per_time": summary["cpu_seconds"] / summary["t_end"], "h": summary["h"]}
    return r


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--stiffmd", default=os.path.join(ROOT, "build", "stiffmd"))
    ap.add_argument("--eps", type=float, default=1e-3)
    ap.add_argument("--h-vv", type=float, default=2e-4)
    ap.add_argument("--h-rigid", type=float, default=0.005)
    ap.add_argument("--t-end", type=float, default=11.0)
    ap.add_argument("--discard", type=float, default=1.0)
    ap.add_argument("--frame-every", type=float, default=0.05)
    ap.add_argument("--damp", type=float, default=1.0)
    ap.add_argument("--seed", type=int, default=11)
    ap.add_argument("--blocks", type=int, default=10)
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--out", default=os.path.join(ROOT, "out", "stiff_melt_nvt"))
    ap.add_argument("--figure", default=os.path.join(ROOT, "docs", "figures", "stiff_melt_nvt_angles.png"))
    ap.add_argument("--plot-only", action="store_true")
    ap.add_argument("--methods", default="velocity-verlet,rattle,fixman", help="which runs to (re)do")
    args = ap.parse_args()
    os.makedirs(args.out, exist_ok=True)
    runs = [("velocity-verlet", args.h_vv), ("rattle", args.h_rigid), ("fixman", args.h_rigid)]
    if not args.plot_only:
        with concurrent.futures.ThreadPoolExecutor(args.jobs) as pool:
            for f in [pool.submit(run, args, m, h) for m, h in runs if m in args.methods.split(",")]:
                f.result()
    bins = np.linspace(0.0, 180.0, 91)
    res = {m: analyse(args, m, bins) for m, _ in runs}

    lines = [f"eps = {args.eps}, kT = 1, damp = {args.damp}, t = {args.discard}..{args.t_end} "
             f"(frames every {args.frame_every}), errors: {args.blocks} blocks", "",
             "| method | h | <cos theta> | <cos^2 theta> | Rg | pressure | T | wall s / time unit | CPU s / time unit |",
             "|---|---|---|---|---|---|---|---|---|"]
    for m, _ in runs:
        r = res[m]
        f = lambda q, d: f"{r[q][0]:.{d}f} ± {r[q][1]:.{d}f}"
        lines.append(f"| {m} | {r['h']:g} | {f('cos', 5)} | {f('cos2', 5)} | {f('rg', 4)} | {f('pressure', 3)} | "
                     f"{f('temperature', 4)} | {r['wall_per_time']:.1f} | {r['cpu_per_time']:.1f} |")
    ref = res["velocity-verlet"]
    lines.append("")
    for m in ("rattle", "fixman"):
        parts = []
        for q in ("cos", "cos2", "rg", "pressure"):
            d = res[m][q][0] - ref[q][0]
            s = math.hypot(res[m][q][1], ref[q][1])
            parts.append(f"{q} {d:+.5f} ({d / s:+.1f} sigma)")
        lines.append(f"{m} - velocity-verlet: " + ", ".join(parts))
    text = "\n".join(lines)
    print(text)
    with open(os.path.join(args.out, "summary.md"), "w") as f:
        f.write(text + "\n")

    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    centres = 0.5 * (bins[1:] + bins[:-1])
    width = bins[1] - bins[0]
    fig, (ax, dx) = plt.subplots(2, 1, figsize=(6.4, 6.4), sharex=True, gridspec_kw={"height_ratios": [2, 1]})
    styles = {"velocity-verlet": ("k", "-"), "rattle": ("tab:red", "--"), "fixman": ("tab:blue", ":")}
    for m, _ in runs:
        mean, err = res[m]["hist"]
        colour, ls = styles[m]
        ax.plot(centres, mean / width, color=colour, ls=ls, label=LABEL[m])
        if m != "velocity-verlet":
            d = (mean - ref["hist"][0]) / width
            e = np.hypot(err, ref["hist"][1]) / width
            dx.errorbar(centres, d, yerr=e, color=colour, ls="", marker=".", ms=3, label=LABEL[m])
    dx.axhline(0, color="k", lw=0.5)
    ax.set_ylabel("p(theta) (1/deg)")
    ax.set_title(f"bond angles, data.chain melt, eps = {args.eps:g}, Langevin kT = 1")
    ax.legend()
    dx.set_xlabel("bond angle theta (deg; 180 = straight)")
    dx.set_ylabel("minus stiff springs")
    dx.legend(fontsize=8)
    ax.set_xlim(40, 180)
    fig.tight_layout()
    os.makedirs(os.path.dirname(args.figure), exist_ok=True)
    fig.savefig(args.figure, dpi=120)
    print("figure:", args.figure)


if __name__ == "__main__":
    main()
