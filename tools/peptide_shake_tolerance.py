#!/usr/bin/python3
"""What LAMMPS's SHAKE tolerance costs in accuracy: the peptide example in NVE, stiffmd's SHAKE at
fix shake's 1e-4 (inputs/peptide.toml's shake_tolerance) and to max |g| <= 1e-12 (no
shake_tolerance), against LAMMPS's fix shake 1e-4.

    /usr/bin/python3 tools/peptide_shake_tolerance.py                  # 1000 steps of 2 fs, one core
    /usr/bin/python3 tools/peptide_shake_tolerance.py --steps 200 --json out.json

Every run starts from the example's data file (inputs/peptide_solvated.data, its velocities) with
the example's styles (lj/charmm/coul/long 8/10 Å, PPPM 1e-4, bonds to hydrogen and the water angle
rigid, 2 fs) and no thermostat: stiffmd inputs/peptide.toml without its [thermostat] table (RATTLE),
LAMMPS in.peptide with `fix nve` in place of its `fix nvt` (tools/lammps_phases.py's text). Printed
per run: the total energy's drift (least-squares slope over the run, kcal/mol per atom per ps) and
its largest excursion max |E − E(0)| per atom, the constraint violation, and the constraint
solver's time. The violation: stiffmd's thermo max_violation (max_b |r_b − ℓ_b| on the thermo
rows, Å), its largest over the run; LAMMPS's "SHAKE stats" (every 100 steps: per bond type the
spread max − min of the lengths, whose half bounds max |r_b − ℓ_b| from below), the largest over
the types and the run, halved. The solver's time: stiffmd's summary.json timing.constraints, LAMMPS's
Modify (fix nve and fix shake together).
"""
import argparse
import json
import os
import re
import sys
import tempfile

import numpy as np

# tools/ is the script's directory
from engines import failure, lammps_command, read_summary, read_thermo, run_engine, stiffmd_command
from lammps_phases import PEPTIDE_DATA, PEPTIDE_LAMMPS, lammps_breakdown

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
DECK = os.path.join(ROOT, "inputs", "peptide.toml")
H = 2.0  # fs
N_ATOMS = 2004


def stiffmd_deck(tolerance, steps, thermo_every):
    """inputs/peptide.toml in NVE; tolerance None: no shake_tolerance (SHAKE to max |g| <= 1e-12)."""
    t = open(DECK).read()
    t = t.replace('lammps_data = "peptide_solvated.data"', f'lammps_data = {json.dumps(PEPTIDE_DATA)}')
    t = re.sub(r"\[thermostat\].*?\n\n", "", t, flags=re.S)
    t = re.sub(r"shake_tolerance = .*\n", "" if tolerance is None else f"shake_tolerance = {tolerance!r}\n", t)
    t = re.sub(r"steps = \d+", f"steps = {steps}", t)
    t = re.sub(r"thermo_interval = [0-9.]+", f"thermo_interval = {thermo_every * H!r}", t)
    return t


def lammps_input(tolerance, steps, thermo_every):
    text = PEPTIDE_LAMMPS.format(data=PEPTIDE_DATA, steps=steps, thermo=thermo_every)
    text = text.replace("fix             1 all nvt temp 275.0 275.0 100.0 tchain 1", "fix             1 all nve")
    text = text.replace("fix             2 all shake 0.0001 10 100", f"fix             2 all shake {tolerance!r} 10 100")
    text = text.replace("thermo_style    multi", "thermo_style    custom step time etotal\nthermo_modify   norm no format float %.12g")
    assert "fix             1 all nve" in text and "custom step time etotal" in text
    return text


def drift(t_fs, e):
    """(least-squares slope in kcal/mol per atom per ps, max |E − E(0)| per atom)."""
    slope = np.polyfit(np.asarray(t_fs) / 1000.0, e, 1)[0]
    return slope / N_ATOMS, float(np.max(np.abs(np.asarray(e) - e[0]))) / N_ATOMS


def lammps_log(log):
    """(times fs, energies, the largest SHAKE-stats spread max − min of a rigid length after step 0, Å). The stats
    rows ("TYPE AVE DELTA COUNT" after "SHAKE stats (type/ave/delta/count)") list the bond types,
    then the angle types, whose spread is in degrees: the water angle's is turned into its H–H
    distance's, Δr = 2ℓ cos(θ₀/2) · Δθ/2 (r = 2ℓ sin(θ/2), ℓ = 0.9572 Å, θ₀ = 104.52°)."""
    t, e, spread, mode = [], [], 0.0, None
    for line in open(log, errors="replace"):
        w = line.split()
        if w[:3] == ["Step", "Time", "TotEng"]:
            mode = "thermo"
            continue
        if line.startswith("SHAKE stats"):  # step 0's: the data file's lengths, before the first SHAKE
            mode = "stats" if int(w[-1]) > 0 else "stats0"
            continue
        if mode == "stats0" and len(w) == 4:
            continue
        if mode == "stats" and len(w) == 4:
            delta = float(w[2])
            if w[0] == "31":  # in.peptide's rigid angle type
                delta = 0.9572 * np.cos(np.radians(104.52 / 2)) * np.radians(delta)
            spread = max(spread, delta)
            continue
        if mode in ("thermo", "stats", "stats0") and len(w) == 3:
            try:
                t.append(float(w[1]))
                e.append(float(w[2]))
                mode = "thermo"
                continue
            except ValueError:
                pass
        if line.startswith("Loop time"):
            mode = None
    return t, e, spread


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--steps", type=int, default=1000)
    ap.add_argument("--thermo", type=int, default=10, help="thermo every this many steps (both engines)")
    ap.add_argument("--stiffmd", default=os.path.join(ROOT, "build", "stiffmd"))
    ap.add_argument("--lmp", default="lmp")
    ap.add_argument("--json", default=None)
    args = ap.parse_args()
    rows = {}
    with tempfile.TemporaryDirectory() as work:
        for name, tol in (("stiffmd, shake_tolerance 1e-4", 1e-4), ("stiffmd, to max \\|g\\| ≤ 1e-12", None)):
            deck = os.path.join(work, f"nve_{len(rows)}.toml")
            open(deck, "w").write(stiffmd_deck(tol, args.steps, args.thermo))
            out = os.path.join(work, f"out_{len(rows)}")
            run = run_engine(stiffmd_command(args.stiffmd, deck, out) + ["-q"], threads=1)
            if run.code != 0:
                sys.exit(failure(run))
            th = read_thermo(os.path.join(out, "thermo.csv"))
            slope, excursion = drift(th["time"], th["total"])
            s = read_summary(out)
            rows[name] = {"drift": slope, "excursion": excursion, "violation": float(np.max(th["max_violation"])),
                          "solver_seconds": s["timing"]["constraints"], "loop_seconds": s["loop_seconds"]}
        lammps_dir = os.path.join(work, "lammps")
        os.makedirs(lammps_dir)
        inp = os.path.join(lammps_dir, "in.nve")
        open(inp, "w").write(lammps_input(1e-4, args.steps, args.thermo))
        log = os.path.join(lammps_dir, "log.lammps")
        run = run_engine(lammps_command(args.lmp, inp, log), threads=1, cwd=lammps_dir)
        if run.code != 0:
            sys.exit(failure(run, "LAMMPS"))
        t, e, spread = lammps_log(log)
        slope, excursion = drift(t, e)
        b = lammps_breakdown(log)
        rows["LAMMPS, fix shake 1e-4"] = {"drift": slope, "excursion": excursion, "violation": 0.5 * spread,
                                          "solver_seconds": b["Modify"], "loop_seconds": b["Loop"]}
    print(f"peptide NVE, {args.steps} steps of {H} fs, one core, load average {os.getloadavg()[0]:.2f}\n")
    print("| run | drift (kcal/mol/atom/ps) | max \\|E − E(0)\\| / atom (kcal/mol) | max \\|g\\| (Å) | "
          "constraints (s) | loop (s) |")
    print("|---|---:|---:|---:|---:|---:|")
    for name, r in rows.items():
        print(f"| {name} | {r['drift']:.3e} | {r['excursion']:.3e} | {r['violation']:.2e} | "
              f"{r['solver_seconds']:.3f} | {r['loop_seconds']:.2f} |")
    if args.json:
        with open(args.json, "w") as f:
            json.dump({"steps": args.steps, "rows": rows}, f, indent=1)


if __name__ == "__main__":
    main()
