#!/usr/bin/env python3
"""What holding water rigid costs per molecule and step: stiffmd's general constraint solver on
inputs/spce_water.toml (512 SPC/E waters, each a triangle of three constraints solved as one
cluster) against an analytic SETTLE and LAMMPS's fix rattle on the same box.

    /usr/bin/python3 tools/water_constraints.py [--steps 500] [--out /tmp/water_constraints]

1. A 300 K state: stiffmd runs the deck as it is (Langevin, 2 ps) and writes its final state as a
   LAMMPS data file.
2. From that state, one thread each, --steps steps of 2 fs under `perf record -e cpu-clock`:
     stiffmd NVE    (rattle without the thermostat: one SHAKE and one velocity projection a step)
     stiffmd BAOAB  (the deck's Langevin: two SHAKEs, the projections merged into one, the O step's
                     normal kinetic energy)
     LAMMPS NVE     (fix nve + fix rattle 1e-10 200 0 b 1 a 1, the styles of tools/spce_compare.py)
   The constraint work is the CPU time (cpu-clock periods) of the symbols in CONSTRAINTS, the step
   the CPU time of the step loop (stiffmd: summary.json's cpu_seconds; LAMMPS: the log's Loop time
   times its CPU use): both per water and step, and the constraint share of the step.
3. build/tools/benchmarks/stiffmd_bench --benchmark_filter=WaterConstraints: the constraint calls
   of a force-free RATTLE step alone, by the general solver and by SETTLE (tools/benchmarks/
   settle.hpp), ns per water (median of 3).
docs/performance.md, "Rigid water: the general solver against SETTLE and LAMMPS", has the numbers.
"""
import argparse
import json
import os
import re
import subprocess
import sys

from engines import engine_env, read_summary, run_stiffmd  # tools/ is the script's directory
from spce_lammps import COEFFS, STYLES

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
WATERS = 512
H = 2.0  # fs
# The constraint work by symbol: stiffmd's toolbox (SHAKE, the projections, the cluster solvers:
# a triangle is a small dense cluster, Eigen's LLT for S and LU for SHAKE's Newton matrix; memcmp
# is its comparison of x with its kept configuration), LAMMPS's fix shake / fix rattle.
CONSTRAINTS = {
    "stiffmd": r"ConstraintToolbox|constraint_detail|Eigen::LLT|llt_inplace|PartialPivLU|partial_lu_impl|"
               r"triangular_solve|memcmp",
    "lammps": r"FixShake|FixRattle",
}

LAMMPS_INPUT = STYLES + "read_data {data}\n" + COEFFS + """fix i all nve
fix r all rattle 1e-10 200 0 b 1 a 1
thermo 100
run {steps}
"""


def perf_split(perf, data, pattern):
    """(CPU seconds in symbols matching pattern, CPU seconds in all) from a cpu-clock perf.data."""
    p = subprocess.run([perf, "report", "-i", data, "--no-children", "--sort", "symbol", "--stdio", "-F",
                        "period,sym"], capture_output=True, text=True, check=True)
    part = total = 0
    for line in p.stdout.splitlines():
        m = re.match(r"\s+(\d+)\s+\[[.k]\]\s+(.*)", line)
        if m:
            total += int(m.group(1))
            part += int(m.group(1)) if re.search(pattern, m.group(2)) else 0
    return part * 1e-9, total * 1e-9


def perf_run(perf, data, cmd, cwd):
    """cmd under perf record (cpu-clock), one thread."""
    subprocess.run([perf, "record", "-q", "-e", "cpu-clock", "-F", "999", "-o", data, "--"] + cmd, cwd=cwd,
                   env=engine_env(1), check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--steps", type=int, default=500)
    ap.add_argument("--out", default="/tmp/water_constraints")
    ap.add_argument("--stiffmd", default=os.path.join(ROOT, "build", "stiffmd"))
    ap.add_argument("--bench", default=os.path.join(ROOT, "build", "tools", "benchmarks", "stiffmd_bench"))
    ap.add_argument("--lmp", default="lmp")
    ap.add_argument("--perf", default="perf")
    a = ap.parse_args()
    os.makedirs(a.out, exist_ok=True)
    deck = os.path.join(ROOT, "inputs", "spce_water.toml")
    quiet = ['output.xyz=""', "output.checkpoint_interval=0", "output.thermo_interval=200.0"]
    data = os.path.join(a.out, "equilibrate", "equilibrated.data")
    if not os.path.exists(data):
        run_stiffmd(a.stiffmd, deck, os.path.join(a.out, "equilibrate"), quiet + ['output.lammps_data="equilibrated.data"'],
                    fail=sys.exit)
    nve_deck = os.path.join(a.out, "nve.toml")
    text = open(deck).read()
    text = text.split("[thermostat]")[0] + "[integrator]" + text.split("[integrator]")[1]  # no thermostat
    open(nve_deck, "w").write(text.replace('lammps_data = "spce_water.data"', f'lammps_data = "{data}"'))
    rows = []
    for name, path, sets in [("stiffmd NVE", nve_deck, []),
                             ("stiffmd BAOAB", deck, [f'import.lammps_data="{data}"'])]:
        run_dir = os.path.join(a.out, name.replace(" ", "_"))
        cmd = [a.stiffmd, "run", path, "-o", run_dir, "-q", "--no-progress", "--set", f"run.steps={a.steps}"]
        for s in quiet + sets:
            cmd += ["--set", s]
        perf_run(a.perf, os.path.join(a.out, name.replace(" ", "_") + ".perf"), cmd, a.out)
        loop = read_summary(run_dir)["cpu_seconds"]
        part, _ = perf_split(a.perf, os.path.join(a.out, name.replace(" ", "_") + ".perf"), CONSTRAINTS["stiffmd"])
        rows.append((name, part, loop))
    with open(os.path.join(a.out, "in.nve"), "w") as f:
        f.write(LAMMPS_INPUT.format(data=data, steps=a.steps))
    perf_run(a.perf, os.path.join(a.out, "lammps.perf"),
             [a.lmp, "-in", "in.nve", "-log", "lammps.log", "-screen", "none", "-nocite"], a.out)
    log = open(os.path.join(a.out, "lammps.log")).read()
    # The loop's CPU time: its wall time times the CPU use LAMMPS reports (below 100 % on a busy machine).
    loop = float(re.search(r"Loop time of ([0-9.eE+-]+) on 1 procs", log).group(1))
    loop *= float(re.search(r"([0-9.]+)% CPU use", log).group(1)) / 100.0
    part, _ = perf_split(a.perf, os.path.join(a.out, "lammps.perf"), CONSTRAINTS["lammps"])
    rows.append(("LAMMPS NVE (fix rattle)", part, loop))
    per = 1e9 / (a.steps * WATERS)
    print(f"{a.steps} steps of {H} fs, {WATERS} waters, one thread; ns per water and step")
    print(f"{'run':26s} {'constraints':>12s} {'step':>10s} {'share':>7s}")
    for name, part, loop in rows:
        print(f"{name:26s} {part * per:12.0f} {loop * per:10.0f} {100 * part / loop:6.1f}%")
    bench = subprocess.run([a.bench, "--benchmark_filter=WaterConstraints", "--benchmark_repetitions=3",
                            "--benchmark_min_time=1", "--benchmark_report_aggregates_only=true",
                            "--benchmark_format=json"], capture_output=True, text=True, env=engine_env(1), check=True)
    print("stiffmd_bench BM_WaterConstraints (medians of 3; positions + velocities = constraints):")
    for b in json.loads(bench.stdout)["benchmarks"]:
        if b.get("aggregate_name") == "median":
            print(f"  {b['run_name']:36s} positions {b['ns_per_water_positions']:6.0f}  velocities "
                  f"{b['ns_per_water_velocities']:6.0f}  constraints {b['ns_per_water_constraints']:6.0f}  "
                  f"(difference after 100 steps {b['difference_100_steps']:.1e} Å)")


if __name__ == "__main__":
    main()
