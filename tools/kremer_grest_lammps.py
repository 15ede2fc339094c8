#!/usr/bin/python3
"""stiffmd against LAMMPS on Kremer–Grest melts (inputs/kremer_grest.toml = LAMMPS's in.chain).

Runs the deck and the equivalent LAMMPS input (FENE 30/1.5, LJ cut 1.12 shifted, special_bonds fene,
fix nve + fix langevin 1.0 1.0 10.0, timestep 0.012) for the same number of steps from the same
state, and compares ensemble averages after a discarded equilibration — temperature, pressure (thermo
rows), and from frames of both codes read the same way: the mean bond length, ⟨Rg²⟩ and the
end-to-end ⟨R²⟩ per chain —, each with its block standard error, and the loop time per step.

Two melts:
  --melt chain   LAMMPS's data.chain: 320 chains of 100 at density 0.85, its own positions and
                 velocities (in.chain itself). Rg of chains of 100 relaxes over ~10^4 time units,
                 far longer than a run of minutes: its averages are not equilibrium values.
  --melt short   100 chains of 20 at density 0.85 built by stiffmd (`check --write-data`), then
                 pre-equilibrated by LAMMPS (--equilibrate steps, write_data): both codes start
                 from that state. Rg relaxes within a few hundred time units here.

stiffmd runs with each Langevin splitting of --splittings: "lammps" (the friction and noise force
inside velocity Verlet, LAMMPS's own scheme: equal discretisation) and/or "baoab" (the default).
The trajectories differ from the first step (different random streams), so only averages compare.

Errors: temperature and pressure over 20 blocks. The frame quantities over blocks at least 10
integrated autocorrelation times long (Sokal's window estimate on each run's series; the largest
τ_int of all runs sets the blocks, at most 20, at least 4 — fewer than 10 τ_int per block is
reported), so that the block means are independent. "σ" is the combined error of a difference.

LAMMPS's temperature counts 3N - 3 degrees of freedom (compute temp), stiffmd's 3N under Langevin
noise (momentum is not conserved); LAMMPS's is rescaled by (3N - 3)/(3N) here.

    bash tools/setup.sh --bench            # Debian's lammps
    /usr/bin/python3 tools/kremer_grest_lammps.py --steps 30000 --discard 2000 --splittings lammps
    /usr/bin/python3 tools/kremer_grest_lammps.py --melt short --steps 300000 --discard 20000 \\
        --frame-every 100 --out out/kg_short
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

# tools/ is the script's directory
from chain_melt import (autocorrelation_time, block_mean, chain_shapes, count_atoms, lammps_dump_frames,
                        linear_chains, read_bonds, read_box, xyz_frames)
from engines import failure, read_summary, read_thermo, run_lammps, run_stiffmd

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
DECK = os.path.join(ROOT, "inputs", "kremer_grest.toml")
CHAIN_DATA = "/usr/share/lammps/examples/COUPLE/multiple/data.chain"
H = 0.012  # in.chain's timestep; --h changes both codes' step

# The potentials and the thermostat of in.chain (LAMMPS bench); {run} is the run's own part.
LAMMPS_SETUP = """units           lj
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
fix             2 all langevin 1.0 1.0 10.0 {seed}
timestep        {h}
"""

LAMMPS_RUN = """thermo_style    custom step temp press
thermo_modify   norm no
thermo          {every}
dump            frames all custom {frame_every} frames.lammpstrj id x y z
dump_modify     frames sort id format float %.10g
run             {steps}
"""

# The short-chain melt as a stiffmd build deck (the potentials are the run deck's, kremer_grest.toml).
SHORT_BUILD = """# Written by tools/kremer_grest_lammps.py: the start of the short-chain Kremer-Grest melt.
[types.bead]
mass = 1.0
[[build]]
style = "linear-chains"
type = "bead"
chains = {chains}
beads = {beads}
bond_length = 0.97
bond_type = "fene"
density = 0.85
min_distance = 0.9
seed = 21
[velocities]
temperature = 1.0
seed = 22
[forces.fene]
style = "fene"
bond_types.fene = {{ K = 30.0, R0 = 1.5, epsilon = 1.0, sigma = 1.0 }}
[forces.lj]
style = "lj"
epsilon = 1.0
sigma = 1.0
cutoff = 1.12
special_bonds = [0.0, 1.0]
skin = 0.4
[integrator]
method = "velocity-verlet"
h = 0.012
[run]
t_end = 1.2
"""


def lammps(args, folder, text, log_name):
    """Runs LAMMPS on `text` in `folder` (one core); returns the log's path."""
    os.makedirs(folder, exist_ok=True)
    inp = os.path.join(folder, log_name + ".in")
    with open(inp, "w") as f:
        f.write(text)
    log = os.path.join(folder, log_name + ".log")
    p = run_lammps(args.lmp, inp, log, cwd=folder)
    if p.code != 0:
        sys.exit(failure(p, "LAMMPS"))
    return log


def short_melt_start(args):
    """The short-chain melt: built by stiffmd, pre-equilibrated by LAMMPS; returns its data file."""
    folder = os.path.join(args.out, "start")
    os.makedirs(folder, exist_ok=True)
    deck = os.path.join(folder, "build.toml")
    with open(deck, "w") as f:
        f.write(SHORT_BUILD.format(chains=args.chains, beads=args.beads))
    built = os.path.join(folder, "built.data")
    p = subprocess.run([args.stiffmd, "check", deck, "--write-data", built], capture_output=True, text=True)
    if p.returncode != 0:
        sys.exit(f"stiffmd check failed ({p.returncode}): {p.stderr[-2000:]}")
    equilibrated = os.path.join(folder, "equilibrated.data")
    lammps(args, folder, LAMMPS_SETUP.format(data=built, seed=1234, h=H) +
           f"thermo 1000\nrun {args.equilibrate}\nwrite_data {equilibrated} nocoeff\n", "equilibrate")
    return equilibrated


def frame_quantities(frames, chains, box, first):
    """Mean bond length, ⟨Rg²⟩, ⟨R²⟩ per frame at time index >= first."""
    out = {"bond_length": [], "rg2": [], "r2": []}
    for t, x in frames:
        if t < first - 1e-9:
            continue
        b, rg2, r2 = chain_shapes(x, chains, box)
        out["bond_length"].append(b)
        out["rg2"].append(rg2)
        out["r2"].append(r2)
    return out


def sample_stiffmd(args, data, splitting, out):
    """The stiffmd run of the comparison (one Langevin splitting): its samples and cost per step."""
    t_end = args.steps * H
    run_stiffmd(args.stiffmd, DECK, out, [f"import.lammps_data={json.dumps(data)}",
                                          f"thermostat.splitting={json.dumps(splitting)}",
                                          f"run.t_end={t_end!r}", f"integrator.h={H!r}",
                                          f"output.thermo_interval={args.every * H!r}", 'output.xyz="frames.xyz"',
                                          f"output.xyz_interval={args.frame_every * H!r}"], fail=sys.exit)
    th = read_thermo(os.path.join(out, "thermo.csv"))
    keep = th["step"] > args.discard
    summary = read_summary(out)
    result = {"temperature": [float(v) for v in th["temperature"][keep]],
              "pressure": [float(v) for v in th["pressure"][keep]],
              "ms_per_step": 1e3 * summary["wall_seconds"] / summary["steps"],
              "cpu_ms_per_step": 1e3 * summary["cpu_seconds"] / summary["steps"]}
    chains = linear_chains(read_bonds(data), count_atoms(data))
    result.update(frame_quantities(((round(t / H), x) for t, x in xyz_frames(os.path.join(out, "frames.xyz"))),
                                   chains, read_box(data), args.discard + 1))
    return result


def sample_lammps(args, data, out):
    """The LAMMPS run of the comparison: its samples and cost per step."""
    log = lammps(args, out, LAMMPS_SETUP.format(data=data, seed=904297, h=H) +
                 LAMMPS_RUN.format(every=args.every, frame_every=args.frame_every, steps=args.steps), "in.chain")
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
    result = {"temperature": [r[1] * dof_ratio for r in keep], "pressure": [r[2] for r in keep],
              "ms_per_step": 1e3 * loop[0] / loop[1], "cpu_ms_per_step": 1e3 * loop[0] / loop[1] * cpu_percent / 100}
    chains = linear_chains(read_bonds(data), natoms)
    result.update(frame_quantities(lammps_dump_frames(os.path.join(out, "frames.lammpstrj")), chains,
                                   read_box(data), args.discard + 1))
    return result


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--stiffmd", default=os.path.join(ROOT, "build", "stiffmd"))
    ap.add_argument("--lmp", default="lmp")
    ap.add_argument("--melt", choices=("chain", "short"), default="chain")
    ap.add_argument("--chains", type=int, default=100, help="short melt: number of chains")
    ap.add_argument("--beads", type=int, default=20, help="short melt: beads per chain")
    ap.add_argument("--equilibrate", type=int, default=40000, help="short melt: LAMMPS steps before the common start")
    ap.add_argument("--splittings", default="lammps,baoab", help="stiffmd's Langevin splittings, comma-separated")
    ap.add_argument("--steps", type=int, default=10000)
    ap.add_argument("--discard", type=int, default=2000, help="steps of equilibration left out")
    ap.add_argument("--every", type=int, default=50, help="thermo sample every this many steps")
    ap.add_argument("--frame-every", type=int, default=500, help="frames (bonds, Rg, R) every this many steps")
    ap.add_argument("--out", default=os.path.join(ROOT, "out", "kremer_grest_lammps"))
    ap.add_argument("--h", type=float, default=H, help="time step of both codes (in.chain: 0.012)")
    args = ap.parse_args()
    args.out = os.path.abspath(args.out)  # LAMMPS runs in its own folder
    globals()["H"] = args.h
    lmp = shutil.which(args.lmp)
    if lmp is None:
        sys.exit(f"LAMMPS ('{args.lmp}') not found: bash tools/setup.sh --bench")
    args.lmp = lmp
    splittings = [s for s in args.splittings.split(",") if s]
    if args.melt == "chain":
        if not os.path.exists(CHAIN_DATA):
            sys.exit(f"{CHAIN_DATA} not found: bash tools/setup.sh")
        data = CHAIN_DATA
    else:
        data = short_melt_start(args)
    # All runs at once, one core each (all single-threaded).
    with concurrent.futures.ThreadPoolExecutor(len(splittings) + 1) as pool:
        futures = {f"stiffmd {s}": pool.submit(sample_stiffmd, args, data, s, os.path.join(args.out, "stiffmd_" + s))
                   for s in splittings}
        futures["LAMMPS"] = pool.submit(sample_lammps, args, data, os.path.join(args.out, "lammps"))
        runs = {name: f.result() for name, f in futures.items()}
    names = list(runs)
    result = {"melt": args.melt, "data": data, "h": H, "steps": args.steps, "discard": args.discard,
              "quantities": {}, "blocks": {}}
    frame_dt = args.frame_every * H
    print(f"{args.melt} melt, h = {H}, {args.steps} steps, averages after step {args.discard}")
    print(f"{'quantity':<12}" + "".join(f"{n:>26}" for n in names) + "".join(
        f"{'(' + n + ' - LAMMPS)/σ':>24}" for n in names[:-1]))
    for q in ("temperature", "pressure", "bond_length", "rg2", "r2"):
        if q in ("temperature", "pressure"):
            blocks, note = 20, "20 blocks"
        else:
            tau = max(autocorrelation_time(runs[n][q]) for n in names)  # in frames
            samples = min(len(runs[n][q]) for n in names)
            blocks = int(max(4, min(20, samples // math.ceil(10 * tau))))
            per_block = samples // blocks
            note = (f"tau_int = {tau * frame_dt:.3g} time units; {blocks} blocks of {per_block * frame_dt:.3g}"
                    f" = {per_block / tau:.0f} tau_int")
        est = {n: [float(v) for v in block_mean(runs[n][q], blocks)] for n in names}
        ml, el = est["LAMMPS"]
        z = {n: (est[n][0] - ml) / math.sqrt(est[n][1] ** 2 + el ** 2) for n in names[:-1]}
        result["quantities"][q] = {"estimates": est, "z": z}
        result["blocks"][q] = note
        print(f"{q:<12}" + "".join(f"{est[n][0]:>15.5f} ± {est[n][1]:<8.5f}" for n in names) +
              "".join(f"{z[n]:>24.2f}" for n in names[:-1]) + f"   ({note})")
    result["ms_per_step"] = {n: runs[n]["ms_per_step"] for n in names}
    result["cpu_ms_per_step"] = {n: runs[n]["cpu_ms_per_step"] for n in names}
    # Wall time suffers from other processes on a shared machine; CPU time per step less so.
    print("time per step (1 core each, all at once): " + "; ".join(
        f"{n} {runs[n]['ms_per_step']:.3f} ms wall, {runs[n]['cpu_ms_per_step']:.3f} ms CPU" for n in names))
    with open(os.path.join(args.out, "comparison.json"), "w") as f:
        json.dump(result, f, indent=2)


if __name__ == "__main__":
    main()
