#!/usr/bin/python3
"""stiffmd against LAMMPS on LAMMPS's own chain benchmark in.chain (inputs/kremer_grest.toml).

Runs the deck and the equivalent LAMMPS input (data.chain, FENE 30/1.5, LJ cut 1.12 shifted,
special_bonds fene, fix nve + fix langevin 1.0 1.0 10.0 904297, timestep 0.012) for the same number
of steps from the same state, and compares ensemble averages after a discarded equilibration —
temperature, pressure, mean bond length, mean radius of gyration per chain — each with its block
standard error (20 blocks), and the loop time per step of both codes on one core.

The trajectories differ from the first step (different random streams and Langevin splittings:
see the deck's header), so only averages compare; "agree" means |difference| < 4 combined standard
errors. The radius of gyration of chains of 100 relaxes over ~10^3-10^4 time units, far longer than a
short run: both codes start from the same state, so its averages compare, but they are not
equilibrium values.

LAMMPS's temperature counts 3N - 3 degrees of freedom (compute temp), stiffmd's 3N under Langevin
noise (momentum is not conserved); LAMMPS's is rescaled by (3N - 3)/(3N) here.

    bash tools/setup.sh --bench            # Debian's lammps
    /usr/bin/python3 tools/kremer_grest_lammps.py --steps 10000 --discard 2000 --out out/kg_lammps
"""
import argparse
import concurrent.futures
import json
import math
import os
import re
import shutil
import subprocess
import sys

import numpy as np

from chain_melt import block_mean, read_bonds, xyz_frames  # tools/ is the script's directory

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
DECK = os.path.join(ROOT, "inputs", "kremer_grest.toml")
DATA = "/usr/share/lammps/examples/COUPLE/multiple/data.chain"
H = 0.012  # in.chain's timestep; --h changes both codes' step

LAMMPS_INPUT = """# in.chain (LAMMPS bench) with observables for tools/kremer_grest_lammps.py
units           lj
atom_style      bond
special_bonds   fene
read_data       {data}
neighbor        0.4 bin
neigh_modify    every 1 delay 1
bond_style      fene
bond_coeff      1 30.0 1.5 1.0 1.0
pair_style      lj/cut 1.12
pair_modify     shift yes
pair_coeff      1 1 1.0 1.0 1.12
fix             1 all nve
fix             2 all langevin 1.0 1.0 10.0 904297
compute         chains all chunk/atom molecule
compute         rgm all gyration/chunk chains
variable        rg equal ave(c_rgm)
compute         bl all bond/local dist
compute         blave all reduce ave c_bl
thermo_style    custom step temp press v_rg c_blave
thermo_modify   norm no
thermo          {every}
timestep        {h}
run             {steps}
"""


def block(series, blocks=20):
    m, se = block_mean(series, blocks)
    return float(m), float(se)


def xyz_bond_lengths(path, bonds, box, first_time):
    """Mean bond length per frame at t >= first_time (minimum image)."""
    i, j = (np.array(c) for c in zip(*bonds))
    out = []
    for t, x in xyz_frames(path):
        if t < first_time - 1e-9:
            continue
        d = x[i] - x[j]
        d -= box * np.round(d / box)
        out.append(float(np.linalg.norm(d, axis=1).mean()))
    return out


def run_stiffmd(args, out):
    t_end = args.steps * H
    every = args.every * H
    cmd = [args.stiffmd, "run", DECK, "--no-progress", "-o", out, "--set", f"run.t_end={t_end!r}",
           "--set", f"integrator.h={H!r}",
           "--set", f"output.thermo_interval={every!r}", "--set", 'output.xyz="frames.xyz"',
           "--set", f"output.xyz_interval={args.frame_every * H!r}"]
    env = dict(os.environ, OMP_NUM_THREADS="1")
    p = subprocess.run(cmd, capture_output=True, text=True, env=env)
    if p.returncode != 0:
        sys.exit(f"stiffmd failed ({p.returncode}): {p.stderr[-2000:]}")
    with open(os.path.join(out, "thermo.csv")) as f:
        header = f.readline().strip().split(",")
        rows = [list(map(float, line.split(","))) for line in f if line.strip()]
    col = {k: i for i, k in enumerate(header)}
    keep = [r for r in rows if r[col["step"]] > args.discard]
    with open(os.path.join(out, "summary.json")) as f:
        summary = json.load(f)
    bonds = read_bonds(DATA)
    box = 33.592
    bl = xyz_bond_lengths(os.path.join(out, "frames.xyz"), bonds, box, args.discard * H)
    return {"temperature": [r[col["temperature"]] for r in keep], "pressure": [r[col["pressure"]] for r in keep],
            "rg": [r[col["rg"]] for r in keep], "bond_length": bl,
            "ms_per_step": 1e3 * summary["wall_seconds"] / summary["steps"],
            "cpu_ms_per_step": 1e3 * summary["cpu_seconds"] / summary["steps"]}


def run_lammps(args, out):
    os.makedirs(out, exist_ok=True)
    inp = os.path.join(out, "in.chain")
    with open(inp, "w") as f:
        f.write(LAMMPS_INPUT.format(data=DATA, every=args.every, h=H, steps=args.steps))
    log = os.path.join(out, "log.lammps")
    cmd = [args.lmp, "-in", inp, "-log", log, "-screen", "none", "-echo", "none", "-nocite"]
    env = dict(os.environ, OMP_NUM_THREADS="1")
    p = subprocess.run(cmd, capture_output=True, text=True, env=env, cwd=out)
    if p.returncode != 0:
        sys.exit(f"LAMMPS failed ({p.returncode}): {p.stderr[-2000:]}")
    rows, loop, natoms, in_thermo, cpu_percent = [], None, None, False, 100.0
    with open(log) as f:
        for line in f:
            w = line.split()
            if line.strip().endswith(" atoms") and w and w[0].isdigit() and natoms is None:
                natoms = int(w[0])
            if w[:2] == ["Step", "Temp"]:
                in_thermo = True
                continue
            if line.startswith("Loop time"):
                loop = float(w[3]), int(w[8])
                in_thermo = False
                continue
            m = re.match(r"\s*([0-9.]+)% CPU use", line)
            if m:
                cpu_percent = float(m.group(1))
            if in_thermo and w and w[0].isdigit():
                rows.append(list(map(float, w)))
    keep = [r for r in rows if r[0] > args.discard]
    dof_ratio = (3 * natoms - 3) / (3 * natoms)
    bl_frames = [r[4] for r in keep if int(r[0]) % args.frame_every == 0]
    return {"temperature": [r[1] * dof_ratio for r in keep], "pressure": [r[2] for r in keep],
            "rg": [r[3] for r in keep], "bond_length": bl_frames, "ms_per_step": 1e3 * loop[0] / loop[1],
            "cpu_ms_per_step": 1e3 * loop[0] / loop[1] * cpu_percent / 100}


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--stiffmd", default=os.path.join(ROOT, "build", "stiffmd"))
    ap.add_argument("--lmp", default="lmp")
    ap.add_argument("--steps", type=int, default=10000)
    ap.add_argument("--discard", type=int, default=2000, help="steps of equilibration left out")
    ap.add_argument("--every", type=int, default=50, help="thermo sample every this many steps")
    ap.add_argument("--frame-every", type=int, default=500, help="stiffmd frames (bond lengths) every N steps")
    ap.add_argument("--out", default=os.path.join(ROOT, "out", "kremer_grest_lammps"))
    ap.add_argument("--h", type=float, default=H, help="time step of both codes (in.chain: 0.012)")
    args = ap.parse_args()
    args.out = os.path.abspath(args.out)  # LAMMPS runs in its own folder
    globals()["H"] = args.h
    lmp = shutil.which(args.lmp)
    if lmp is None:
        sys.exit(f"LAMMPS ('{args.lmp}') not found: bash tools/setup.sh --bench")
    args.lmp = lmp
    if not os.path.exists(DATA):
        sys.exit(f"{DATA} not found: bash tools/setup.sh")
    # The two codes run at once, one core each (both single-threaded).
    with concurrent.futures.ThreadPoolExecutor(2) as pool:
        fs = pool.submit(run_stiffmd, args, os.path.join(args.out, "stiffmd"))
        fl = pool.submit(run_lammps, args, os.path.join(args.out, "lammps"))
        s, l = fs.result(), fl.result()
    result = {"h": H, "steps": args.steps, "discard": args.discard, "quantities": {}}
    print(f"{'quantity':<12} {'stiffmd':>22} {'LAMMPS':>22} {'diff/sigma':>10}")
    for q in ("temperature", "pressure", "bond_length", "rg"):
        blocks = 20 if min(len(s[q]), len(l[q])) >= 40 else 4
        (ms, es), (ml, el) = block(s[q], blocks), block(l[q], blocks)
        z = (ms - ml) / math.sqrt(es * es + el * el) if es + el > 0 else float("inf")
        result["quantities"][q] = {"stiffmd": [ms, es], "lammps": [ml, el], "z": z}
        print(f"{q:<12} {ms:>12.5f} ± {es:<8.5f} {ml:>12.5f} ± {el:<8.5f} {z:>10.2f}")
    result["ms_per_step"] = {"stiffmd": s["ms_per_step"], "lammps": l["ms_per_step"]}
    result["cpu_ms_per_step"] = {"stiffmd": s["cpu_ms_per_step"], "lammps": l["cpu_ms_per_step"]}
    # Wall time suffers from other processes on a shared machine; CPU time per step less so.
    print(f"time per step (1 core): stiffmd {s['ms_per_step']:.2f} ms wall, {s['cpu_ms_per_step']:.2f} ms CPU; "
          f"LAMMPS {l['ms_per_step']:.2f} ms wall, {l['cpu_ms_per_step']:.2f} ms CPU")
    with open(os.path.join(args.out, "comparison.json"), "w") as f:
        json.dump(result, f, indent=2)


if __name__ == "__main__":
    main()
