#!/usr/bin/python3
"""One core, phase by phase: a deck in stiffmd against its LAMMPS input, the two timing tables side by side.

    /usr/bin/python3 tools/lammps_phases.py                               # in.chain, 500 steps, 3 repeats
    /usr/bin/python3 tools/lammps_phases.py --case peptide --steps 300
    /usr/bin/python3 tools/lammps_phases.py --steps 20 --repeats 1 --json phases.json

Cases (each engine from the same data file, with the same potentials, thermostat and step):
  chain    inputs/kremer_grest.toml against LAMMPS's in.chain (bench/in.chain: data.chain's 32 000 beads in
           320 chains of 100, FENE, LJ cut 1.12 shifted, fix nve + fix langevin, 0.012 τ), the LAMMPS text
           tools/kremer_grest_lammps.py holds; data.chain from Debian's lammps-examples.
  peptide  inputs/peptide.toml against LAMMPS's examples/peptide/in.peptide (2004 atoms, CHARMM22,
           lj/charmm/coul/long 8/10 Å, PPPM 1e-4, SHAKE on the bonds to hydrogen and the water angle,
           2 fs, 275 K), its text below, on the data file tools/peptide_deck.py made the deck from. The
           thermostats differ (stiffmd Langevin, LAMMPS Nosé–Hoover): both are in "integrate/thermostat".

Both run on one core (OMP_NUM_THREADS=1), interleaved (stiffmd, LAMMPS, stiffmd, LAMMPS, ...),
--repeats times each; every number printed is the median of the repeats (so the rows' medians need not
add up to the median total). The machine: the CPU model and the load average (1, 5, 15 min) before and
after; on a loaded machine the ratios of interleaved runs are what to read, not the seconds.

The common rows, from LAMMPS's "MPI task timing breakdown" (avg time) and stiffmd's summary.json
`timing` (seconds per phase of the step loop, engine/run/run.cpp; a run is timed by phase from 4096
particles, or at any size with a k-space term):

  row                    LAMMPS                    stiffmd
  pair                   Pair                      pair
  bond                   Bond                      bonded
  neighbour              Neigh                     neighbor
  integrate/thermostat   Modify (the fixes: nve,   integrate + thermostat + constraints
                         langevin, nvt, shake)
  kspace                 Kspace                    kspace
  other                  Comm + Output + Other     output + domain + other
  total (loop)           Loop time                 loop_seconds (wall_seconds)
  CPU (loop)             Loop time × % CPU use     cpu_seconds (the step loop's process CPU time)

The phases are wall-clock times; the CPU row is the loop's CPU time, whose percentage columns are the
CPU use (CPU / wall): below 100 % the process waited for the core, and the wall times of that run are
inflated by the wait. Modify ≈ integrate + thermostat: LAMMPS's time integration and thermostat are fixes, and so is its SHAKE
(fix shake), whose counterpart is stiffmd's constraints phase. Comm on one core is LAMMPS's update of
its ghost atoms (the periodic images); stiffmd has no phase of its own for the images on one process
(its domain phase is a decomposed run's halo), so Comm goes to "other".
"""
import argparse
import json
import os
import platform
import shutil
import statistics
import sys
import tempfile

# tools/ is the script's directory
from engines import failure, lammps_command, read_summary, run_engine, stiffmd_command
from kremer_grest_lammps import CHAIN_DATA, H as CHAIN_H, LAMMPS_SETUP as CHAIN_SETUP

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
PEPTIDE_DATA = os.path.join(ROOT, "inputs", "peptide_solvated.data")  # LAMMPS's data.peptide, unchanged

# LAMMPS's examples/peptide/in.peptide (its dumps, commented out there, left out), {data} and {steps} filled in.
PEPTIDE_LAMMPS = """units           real
atom_style      full
pair_style      lj/charmm/coul/long 8.0 10.0 10.0
bond_style      harmonic
angle_style     charmm
dihedral_style  charmm
improper_style  harmonic
kspace_style    pppm 0.0001
read_data       {data}
neighbor        2.0 bin
neigh_modify    delay 5
timestep        2.0
thermo_style    multi
thermo          50
fix             1 all nvt temp 275.0 275.0 100.0 tchain 1
fix             2 all shake 0.0001 10 100 b 4 6 8 10 12 14 18 a 31
group           peptide type <= 12
run             {steps}
"""

ROWS = ["pair", "bond", "neighbour", "integrate/thermostat", "kspace", "other", "total (loop)", "CPU (loop)"]
LAMMPS_ROWS = {"pair": ["Pair"], "bond": ["Bond"], "neighbour": ["Neigh"], "integrate/thermostat": ["Modify"],
               "kspace": ["Kspace"], "other": ["Comm", "Output", "Other"]}
STIFFMD_ROWS = {"pair": ["pair"], "bond": ["bonded"], "neighbour": ["neighbor"],
                "integrate/thermostat": ["integrate", "thermostat", "constraints"], "kspace": ["kspace"],
                "other": ["output", "domain", "other"]}


def case_inputs(case, steps):
    """(stiffmd deck, its --set overrides, LAMMPS input text, the data file both read) of a case."""
    if case == "chain":
        text = CHAIN_SETUP.format(data=CHAIN_DATA, seed=904297, h=CHAIN_H) + f"thermo          100\nrun {steps}\n"
        deck = os.path.join(ROOT, "inputs", "kremer_grest.toml")
        return deck, [f"run.steps={steps}", f"import.lammps_data={json.dumps(CHAIN_DATA)}"], text, CHAIN_DATA
    deck = os.path.join(ROOT, "inputs", "peptide.toml")
    return deck, [f"run.steps={steps}"], PEPTIDE_LAMMPS.format(data=PEPTIDE_DATA, steps=steps), PEPTIDE_DATA


def lammps_breakdown(log):
    """{section: avg seconds} of a LAMMPS log's "MPI task timing breakdown", with "Loop" its loop time and
    "CPU use" its per cent CPU use."""
    out = {}
    with open(log) as f:
        lines = f.read().splitlines()
    for i, line in enumerate(lines):
        if line.startswith("Loop time of"):
            out["Loop"] = float(line.split()[3])
        if "% CPU use with" in line:
            out["CPU use"] = float(line.split("%")[0])
        if line.startswith("MPI task timing breakdown"):
            for row in lines[i + 3:]:  # the header and the rule, then one row per section
                cells = [c.strip() for c in row.split("|")]
                if len(cells) < 3 or not cells[0]:
                    break
                out[cells[0]] = float(cells[2])
    if "Loop" not in out or "Pair" not in out or "CPU use" not in out:
        raise RuntimeError(f"{log}: no loop time, CPU use or timing breakdown")
    return out


def stiffmd_rows(summary):
    """The common rows of a stiffmd summary.json (seconds)."""
    timing = summary.get("timing") or {}
    if not timing:
        raise RuntimeError("summary.json has no per-phase timing (fewer than 4096 particles and no k-space term)")
    rows = {row: sum(timing.get(p, 0.0) for p in phases) for row, phases in STIFFMD_ROWS.items()}
    rows["total (loop)"] = summary["loop_seconds"]
    rows["CPU (loop)"] = summary["cpu_seconds"]
    return rows


def lammps_rows(breakdown):
    """The common rows of a LAMMPS timing breakdown (seconds)."""
    rows = {row: sum(breakdown.get(s, 0.0) for s in sections) for row, sections in LAMMPS_ROWS.items()}
    rows["total (loop)"] = breakdown["Loop"]
    rows["CPU (loop)"] = breakdown["Loop"] * breakdown["CPU use"] / 100.0
    return rows


def cpu_model():
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def load_average():
    return tuple(round(v, 2) for v in os.getloadavg())


def measure(args, work):
    """Runs both engines --repeats times, interleaved; returns {engine: {row: [seconds per repeat]}}."""
    deck, sets, text, data = case_inputs(args.case, args.steps)
    if not os.path.exists(data):
        raise SystemExit(f"{data} not found: bash tools/setup.sh --bench (Debian's lammps-examples)")
    lammps_dir = os.path.join(work, "lammps")
    os.makedirs(lammps_dir, exist_ok=True)
    lammps_input = os.path.join(lammps_dir, f"in.{args.case}")
    with open(lammps_input, "w") as f:
        f.write(text)
    runs = {"stiffmd": {r: [] for r in ROWS}, "LAMMPS": {r: [] for r in ROWS}}
    for k in range(args.repeats):
        out = os.path.join(work, f"stiffmd_{k}")
        run = run_engine(stiffmd_command(args.stiffmd, deck, out, sets) + ["-q"], threads=1)
        if run.code != 0:
            raise SystemExit(failure(run))
        for row, seconds in stiffmd_rows(read_summary(out)).items():
            runs["stiffmd"][row].append(seconds)
        log = os.path.join(lammps_dir, f"log_{k}.lammps")
        run = run_engine(lammps_command(args.lmp, lammps_input, log), threads=1, cwd=lammps_dir)
        if run.code != 0:
            raise SystemExit(failure(run, "LAMMPS"))
        for row, seconds in lammps_rows(lammps_breakdown(log)).items():
            runs["LAMMPS"][row].append(seconds)
    return runs


def table(result):
    """The side-by-side table (markdown) of a result."""
    s, l = result["stiffmd"], result["LAMMPS"]
    lines = ["| phase | stiffmd (s) | LAMMPS (s) | stiffmd / LAMMPS | stiffmd % | LAMMPS % |",
             "|---|---:|---:|---:|---:|---:|"]
    for row in ROWS:
        ratio = f"{s[row] / l[row]:.2f}" if l[row] > 0 else "—"
        lines.append(f"| {row} | {s[row]:.4f} | {l[row]:.4f} | {ratio} | "
                     f"{100 * s[row] / s['total (loop)']:.1f} | {100 * l[row] / l['total (loop)']:.1f} |")
    return "\n".join(lines)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--case", choices=("chain", "peptide"), default="chain")
    ap.add_argument("--steps", type=int, default=None, help="steps of both runs (default: in.chain's 500, in.peptide's 300)")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--stiffmd", default=os.path.join(ROOT, "build", "stiffmd"))
    ap.add_argument("--lmp", default="lmp")
    ap.add_argument("--out", default=None, help="keep the runs here (default: a temporary folder)")
    ap.add_argument("--json", default=None, help="also write the medians, every repeat and the machine as JSON")
    args = ap.parse_args()
    if args.steps is None:
        args.steps = 500 if args.case == "chain" else 300
    if args.repeats < 1 or args.steps < 1:
        ap.error("--steps and --repeats must be positive")
    args.stiffmd = os.path.abspath(args.stiffmd)
    lmp = shutil.which(args.lmp)
    if lmp is None:
        sys.exit(f"LAMMPS ('{args.lmp}') not found: bash tools/setup.sh --bench")
    args.lmp = lmp
    before = load_average()
    if args.out:
        os.makedirs(args.out, exist_ok=True)
        runs = measure(args, os.path.abspath(args.out))
    else:
        with tempfile.TemporaryDirectory(prefix="lammps_phases_") as work:
            runs = measure(args, work)
    after = load_average()
    result = {engine: {row: statistics.median(v) for row, v in rows.items()} for engine, rows in runs.items()}
    info = {"case": args.case, "steps": args.steps, "repeats": args.repeats, "cpu": cpu_model(),
            "load_before": before, "load_after": after}
    print(f"{args.case}: {args.steps} steps, one core each, medians of {args.repeats} interleaved repeats")
    print(f"machine: {info['cpu']}, {os.cpu_count()} cores; load average (1/5/15 min) before "
          f"{' '.join(map(str, before))}, after {' '.join(map(str, after))}")
    print(table(result))
    if args.json:
        with open(args.json, "w") as f:
            json.dump({**info, "medians": result, "repeats_seconds": runs}, f, indent=2)


if __name__ == "__main__":
    main()
