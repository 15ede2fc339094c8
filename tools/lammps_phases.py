#!/usr/bin/python3
"""One core, phase by phase: a deck in stiffmd against its LAMMPS input, the two timing tables side by side.

    /usr/bin/python3 tools/lammps_phases.py                               # in.chain, 500 steps, 3 repeats
    /usr/bin/python3 tools/lammps_phases.py --case peptide --steps 300
    /usr/bin/python3 tools/lammps_phases.py --steps 20 --repeats 1 --json phases.json
    /usr/bin/python3 tools/lammps_phases.py --stiffmd /tmp/before/stiffmd build/stiffmd --repeats 5   # before/after
    git show main:inputs/peptide.toml > /tmp/main_peptide.toml    # an older build with its own deck
    /usr/bin/python3 tools/lammps_phases.py --case peptide --stiffmd /work/main/build/stiffmd build/stiffmd \
        --decks /tmp/main_peptide.toml inputs/peptide.toml --repeats 3

Cases (each engine from the same data file, with the same potentials, thermostat and step):
  chain    inputs/kremer_grest.toml against LAMMPS's in.chain (bench/in.chain: data.chain's 32 000 beads in
           320 chains of 100, FENE, LJ cut 1.12 shifted, fix nve + fix langevin, 0.012 τ), the LAMMPS text
           tools/kremer_grest_lammps.py holds; data.chain from Debian's lammps-examples.
  peptide  inputs/peptide.toml against LAMMPS's examples/peptide/in.peptide (2004 atoms, CHARMM22,
           lj/charmm/coul/long 8/10 Å, PPPM 1e-4, SHAKE on the bonds to hydrogen and the water angle,
           2 fs, 275 K), its text below, on the data file tools/peptide_deck.py made the deck from. The
           thermostats differ (stiffmd Langevin, LAMMPS Nosé–Hoover): both are in "integrate/thermostat".
           Both stop SHAKE at fix shake's tolerance 1e-4 (the deck's shake_tolerance). The data file is
           set by --set import.lammps_data, so that a deck from elsewhere (--decks) reads the same file.

Both run on one core (OMP_NUM_THREADS=1), interleaved (stiffmd, LAMMPS, stiffmd, LAMMPS, ...),
--repeats times each; every time printed is the median of the repeats (so the rows' medians need not
add up to the median total), every ratio the median of the ratios taken within one repeat (on a machine
whose speed drifts within minutes, the figure to read). With several --stiffmd binaries (a build before
and after a change) each runs in every repeat, in turn, and has its own columns.

The thermo rows are matched: stiffmd's output.thermo_interval is set to LAMMPS's `thermo` (every 100
steps for in.chain, 50 for in.peptide), since each row is an energy-and-virial pass over the pairs in
both codes (inputs/kremer_grest.toml's own interval is every 10 steps); --set adds stiffmd overrides. The machine: the CPU model and the load average (1, 5, 15 min) before and
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
thermo          {thermo}
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


THERMO_EVERY = {"chain": 100, "peptide": 50}  # LAMMPS's `thermo` of each input, in steps
STEP = {"chain": CHAIN_H, "peptide": 2.0}     # the step of both (τ; fs)


def case_inputs(case, steps):
    """(stiffmd deck, its --set overrides, LAMMPS input text, the data file both read) of a case."""
    thermo = f"output.thermo_interval={THERMO_EVERY[case] * STEP[case]:.12g}"
    if case == "chain":
        text = CHAIN_SETUP.format(data=CHAIN_DATA, seed=904297, h=CHAIN_H) + \
            f"thermo          {THERMO_EVERY[case]}\nrun {steps}\n"
        deck = os.path.join(ROOT, "inputs", "kremer_grest.toml")
        return deck, [f"run.steps={steps}", thermo, f"import.lammps_data={json.dumps(CHAIN_DATA)}"], text, CHAIN_DATA
    deck = os.path.join(ROOT, "inputs", "peptide.toml")
    return deck, [f"run.steps={steps}", thermo, f"import.lammps_data={json.dumps(PEPTIDE_DATA)}"], \
        PEPTIDE_LAMMPS.format(data=PEPTIDE_DATA, steps=steps, thermo=THERMO_EVERY[case]), PEPTIDE_DATA


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


def engine_names(binaries):
    """A column name per stiffmd binary: "stiffmd", or with several "stiffmd 1", "stiffmd 2", ... in the
    order given (the printed legend names their paths)."""
    return ["stiffmd"] if len(binaries) == 1 else [f"stiffmd {k + 1}" for k in range(len(binaries))]


def measure(args, work):
    """Runs LAMMPS and every stiffmd binary --repeats times, interleaved; returns {engine: {row: [seconds
    per repeat]}}."""
    deck, sets, text, data = case_inputs(args.case, args.steps)
    sets += args.set
    if not os.path.exists(data):
        raise SystemExit(f"{data} not found: bash tools/setup.sh --bench (Debian's lammps-examples)")
    lammps_dir = os.path.join(work, "lammps")
    os.makedirs(lammps_dir, exist_ok=True)
    lammps_input = os.path.join(lammps_dir, f"in.{args.case}")
    with open(lammps_input, "w") as f:
        f.write(text)
    names = engine_names(args.stiffmd)
    runs = {name: {r: [] for r in ROWS} for name in names + ["LAMMPS"]}
    decks = args.decks or [deck] * len(args.stiffmd)
    for k in range(args.repeats):
        for b, (exe, name) in enumerate(zip(args.stiffmd, names)):
            out = os.path.join(work, f"stiffmd{b}_{k}")
            run = run_engine(stiffmd_command(exe, decks[b], out, sets) + ["-q"], threads=1)
            if run.code != 0:
                raise SystemExit(failure(run))
            for row, seconds in stiffmd_rows(read_summary(out)).items():
                runs[name][row].append(seconds)
        log = os.path.join(lammps_dir, f"log_{k}.lammps")
        run = run_engine(lammps_command(args.lmp, lammps_input, log), threads=1, cwd=lammps_dir)
        if run.code != 0:
            raise SystemExit(failure(run, "LAMMPS"))
        for row, seconds in lammps_rows(lammps_breakdown(log)).items():
            runs["LAMMPS"][row].append(seconds)
    return runs


def ratios(runs, name):
    """{row: the median over repeats of stiffmd's seconds ÷ LAMMPS's in the same repeat} (None where
    LAMMPS spent no time on the row)."""
    out = {}
    for row in ROWS:
        pairs = [(s, l) for s, l in zip(runs[name][row], runs["LAMMPS"][row]) if l > 0]
        out[row] = statistics.median(s / l for s, l in pairs) if pairs else None
    return out


def table(result, runs, names):
    """The side-by-side table (markdown): each engine's median seconds, each stiffmd's ratio to LAMMPS,
    and each engine's share of its loop."""
    l = result["LAMMPS"]
    head = [f"{n} (s)" for n in names] + ["LAMMPS (s)"] + [f"{n} / LAMMPS" for n in names] + \
        [f"{n} %" for n in names] + ["LAMMPS %"]
    lines = ["| phase | " + " | ".join(head) + " |", "|---|" + "---:|" * len(head)]
    r = {n: ratios(runs, n) for n in names}
    for row in ROWS:
        cells = [f"{result[n][row]:.4f}" for n in names] + [f"{l[row]:.4f}"]
        cells += [f"{r[n][row]:.2f}" if r[n][row] is not None else "—" for n in names]
        cells += [f"{100 * result[n][row] / result[n]['total (loop)']:.1f}" for n in names]
        cells.append(f"{100 * l[row] / l['total (loop)']:.1f}")
        lines.append(f"| {row} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--case", choices=("chain", "peptide"), default="chain")
    ap.add_argument("--steps", type=int, default=None, help="steps of both runs (default: in.chain's 500, in.peptide's 300)")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--stiffmd", nargs="+", default=[os.path.join(ROOT, "build", "stiffmd")],
                    help="one or more stiffmd binaries (e.g. a build before and after a change)")
    ap.add_argument("--decks", nargs="+", default=None,
                    help="one deck per --stiffmd binary, in their order (default: the case's deck for each; "
                         "e.g. an older build with the deck of its own commit)")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                    help="a stiffmd override, as stiffmd run --set (repeatable)")
    ap.add_argument("--lmp", default="lmp")
    ap.add_argument("--out", default=None, help="keep the runs here (default: a temporary folder)")
    ap.add_argument("--json", default=None, help="also write the medians, every repeat and the machine as JSON")
    args = ap.parse_args()
    if args.steps is None:
        args.steps = 500 if args.case == "chain" else 300
    if args.repeats < 1 or args.steps < 1:
        ap.error("--steps and --repeats must be positive")
    args.stiffmd = [os.path.abspath(b) for b in args.stiffmd]
    if args.decks is not None:
        if len(args.decks) != len(args.stiffmd):
            ap.error("--decks needs one deck per --stiffmd binary")
        args.decks = [os.path.abspath(d) for d in args.decks]
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
    names = engine_names(args.stiffmd)
    if len(names) > 1:
        for name, exe in zip(names, args.stiffmd):
            print(f"{name}: {exe}")
    print(table(result, runs, names))
    if args.json:
        with open(args.json, "w") as f:
            json.dump({**info, "binaries": dict(zip(names, args.stiffmd)), "medians": result, "ratios": {n: ratios(runs, n) for n in names},
                       "repeats_seconds": runs}, f, indent=2)


if __name__ == "__main__":
    main()
