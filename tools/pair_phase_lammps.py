#!/usr/bin/python3
"""stiffmd's pair phase against LAMMPS's Pair time on in.chain, one core, interleaved repeats.

    /usr/bin/python3 tools/pair_phase_lammps.py [--repeats 5] [--stiffmd build/stiffmd ...]

Each repeat runs LAMMPS's in.chain (32 000 beads of data.chain, lj/cut 1.12 shifted, FENE bonds,
fix nve + fix langevin, skin 0.4, 500 steps of 0.012; `OMP_NUM_THREADS=1 lmp -in in.chain`) and then
each given stiffmd binary on inputs/kremer_grest.toml, the same model, with
`--set run.t_end=6` (500 steps; OMP_NUM_THREADS=1). It reads LAMMPS's "Pair" row of the "MPI task
timing breakdown" and stiffmd's summary.json `timing.pair` (the pair phase: the pair loop, the wrap of
the positions into the box, and the thermo rows' energy and virial passes). On a shared machine
whose speed drifts within minutes, the number to read is the median over repeats of each ratio taken
within one repeat (stiffmd ÷ LAMMPS), printed with the medians of the times.

--thermo-interval T sets the deck's output.thermo_interval (the deck's own is 0.12, a thermo row every
10 steps, each an energy-and-virial pass over the pairs; in.chain's `thermo 100` is every 100 steps:
--thermo-interval 1.2 matches it).
"""
import argparse
import json
import os
import re
import shutil
import statistics
import subprocess
import tempfile

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
DATA = "/usr/share/lammps/examples/COUPLE/multiple/data.chain"
IN_CHAIN = """units		lj
atom_style	bond
special_bonds	fene
read_data	data.chain
neighbor	0.4 bin
neigh_modify	every 1 delay 1
bond_style	fene
bond_coeff	1 30.0 1.5 1.0 1.0
pair_style	lj/cut 1.12
pair_modify	shift yes
pair_coeff	1 1 1.0 1.0 1.12
fix		1 all nve
fix		2 all langevin 1.0 1.0 10.0 904297
thermo          100
timestep	0.012
run		500
"""


def lammps_pair(work):
    env = dict(os.environ, OMP_NUM_THREADS="1")
    subprocess.run(["lmp", "-in", "in.chain", "-log", "log.lammps", "-screen", "none"], cwd=work, env=env, check=True)
    text = open(os.path.join(work, "log.lammps")).read()
    m = re.search(r"^Pair\s*\|\s*([0-9.eE+-]+)", text, re.M)
    if not m:
        raise RuntimeError("no Pair row in LAMMPS's log")
    return float(m.group(1))


def stiffmd_pair(binary, work, thermo_interval):
    out = os.path.join(work, "stiffmd")
    shutil.rmtree(out, ignore_errors=True)
    cmd = [binary, "run", os.path.join(ROOT, "inputs", "kremer_grest.toml"), "-o", out, "-q", "--no-progress",
           "--set", "run.t_end=6", "--set", "output.checkpoint_interval=0"]
    if thermo_interval:
        cmd += ["--set", f"output.thermo_interval={thermo_interval}"]
    subprocess.run(cmd, env=dict(os.environ, OMP_NUM_THREADS="1"), check=True, stdout=subprocess.DEVNULL)
    with open(os.path.join(out, "summary.json")) as f:
        return json.load(f)["timing"]["pair"]


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--stiffmd", nargs="+", default=[os.path.join(ROOT, "build", "stiffmd")])
    ap.add_argument("--thermo-interval", default=None)
    args = ap.parse_args()
    work = tempfile.mkdtemp(prefix="pair_phase_lammps_")
    shutil.copy(DATA, os.path.join(work, "data.chain"))
    with open(os.path.join(work, "in.chain"), "w") as f:
        f.write(IN_CHAIN)
    lmp, times, ratios = [], {b: [] for b in args.stiffmd}, {b: [] for b in args.stiffmd}
    for r in range(args.repeats):
        lmp.append(lammps_pair(work))
        row = [f"repeat {r + 1}: LAMMPS Pair {lmp[-1]:.3f} s"]
        for b in args.stiffmd:
            t = stiffmd_pair(b, work, args.thermo_interval)
            times[b].append(t)
            ratios[b].append(t / lmp[-1])
            row.append(f"{b} pair {t:.3f} s ({t / lmp[-1]:.3f}x)")
        print("; ".join(row), flush=True)
    print(f"LAMMPS Pair median {statistics.median(lmp):.3f} s")
    for b in args.stiffmd:
        print(f"{b}: pair median {statistics.median(times[b]):.3f} s, stiffmd / LAMMPS median of ratios "
              f"{statistics.median(ratios[b]):.3f} (range {min(ratios[b]):.3f} … {max(ratios[b]):.3f})")
    shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    main()
