#!/usr/bin/python3
"""stiffmd's C-rescale barostat against LAMMPS's Nosé–Hoover barostat on a Kremer–Grest melt.

The melt: linear chains of --beads FENE beads (30/1.5, with its WCA part), WCA between all other
pairs (lj/cut 2^(1/6), shifted; special_bonds fene), --chains of them, built by stiffmd at density
0.85 and written with `stiffmd check --write-data`: both engines start from that file, positions and
velocities. Chains short enough to stay below half the box (the barostat scales molecules by their
centres of mass and refuses longer ones, docs/design.md §5b). At kT = 1 and P = 5:

  stiffmd   velocity-verlet (h = --h), Langevin (BAOAB, damp --damp), [barostat] c-rescale
            (tau --tau-p, compressibility --compressibility, interval --interval)
  LAMMPS    --lammps npt (default): fix npt temp 1 1 --tdamp iso 5 5 --pdamp, the Nosé–Hoover chain
            thermostat and the MTK barostat of LAMMPS's own NPT (Shinoda et al., Phys. Rev. B 69,
            134103 (2004)): the standard LAMMPS NPT, deterministic, exact in law up to its step;
            --lammps nph-langevin: fix nph iso 5 5 --pdamp with fix langevin 1 1 --damp: the same
            barostat with stiffmd's bath, a second LAMMPS estimate when the first disagrees.

Both run the same number of steps of the same h. From the thermo rows after --discard (time units):
⟨ρ⟩ (mass density) with its batch-means standard error (--batches batches), and the isothermal
compressibility from the volume fluctuations, κ_T = Var(V)/(kT⟨V⟩), its error by the jackknife over
the same batches; ⟨P⟩ (the atomic pressure; stiffmd's molecular one too), ⟨T⟩ and the volume's
integrated autocorrelation time τ_int (each batch should hold ≫ τ_int). Targets: ⟨ρ⟩ within 0.5 % of
LAMMPS, κ_T within 10 %. Writes OUT/comparison.json.

--cost: the barostat's cost on a 32 000-bead melt of short chains (--cost-chains × --cost-beads),
velocity Verlet + Langevin at h, one thread: a stiffmd NPT run equilibrates the built melt
(--cost-equilibrate time units) and writes its final state; from it, runs of --cost-steps steps
without [barostat] and with it at each --intervals, interleaved (--repeats rounds, every setting once
per round in turn), thermo only at the start and the end. Reports the median step time (wall and CPU),
the barostat's overhead in % of the step without it, the cost of one cell move, the extra force
evaluations and neighbour-list rebuilds per step, and the step's phases (summary.json `timing`: the
move's molecular pressure falls under `thermostat`, the fresh forces under `pair` and `bonded`, the
extra rebuilds under `neighbor`). Writes OUT/cost.json.

    bash tools/setup.sh --bench        # Debian's lammps (/usr/bin/lmp)
    /usr/bin/python3 tools/npt_lammps.py --quick                       # plumbing, ≈ 20 s
    /usr/bin/python3 tools/npt_lammps.py --t-end 3000 --discard 100    # the comparison (docs/performance.md)
    /usr/bin/python3 tools/npt_lammps.py --cost --repeats 5            # the barostat's cost
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
from chain_melt import autocorrelation_time, fmt
from engines import failure, read_summary, read_thermo, run_lammps, run_stiffmd, whole_steps_t_end

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
KT, PRESSURE = 1.0, 5.0
WCA_CUTOFF = 2.0 ** (1.0 / 6.0)
TARGET_DENSITY, TARGET_KAPPA = 0.005, 0.10  # relative: ⟨ρ⟩ within 0.5 %, κ_T within 10 % of LAMMPS

# The melt's potentials, shared by the build and the run decks.
FORCES = """[forces.fene]
style = "fene"
bond_types.fene = { K = 30.0, R0 = 1.5, epsilon = 1.0, sigma = 1.0 }

[forces.wca]
style = "wca"
epsilon = 1.0
sigma = 1.0
special_bonds = [0.0, 1.0]
skin = 0.4
"""

BUILD_DECK = """# Written by tools/npt_lammps.py: the start of the Kremer-Grest melt (stiffmd check --write-data).
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
seed = {seed}

[velocities]
temperature = 1.0
seed = {velocity_seed}

""" + FORCES.replace("{", "{{").replace("}", "}}") + """
[integrator]
method = "velocity-verlet"
h = 0.005

[run]
t_end = 0.005
"""

RUN_DECK = """# Written by tools/npt_lammps.py: the Kremer-Grest melt from {data}.
[types.bead]
mass = 1.0

[import]
lammps_data = "{data}"
atom_types = {{ "1" = "bead" }}
bond_types = {{ "1" = "fene" }}

""" + FORCES.replace("{", "{{").replace("}", "}}") + """
[thermostat]
style = "langevin"
temperature = 1.0
damp = {damp}
seed = {seed}
{barostat}
[integrator]
method = "velocity-verlet"
h = {h}

[run]
t_end = {t_end}

[output]
xyz = ""
thermo_interval = {every}
screen_interval = 0
{extra}
[observables]
histograms = false
"""

BAROSTAT = """
[barostat]
style = "c-rescale"
pressure = {pressure}
tau = {tau}
compressibility = {compressibility}
interval = {interval}
"""

# The same melt in LAMMPS. The styles come before read_data: the data file holds stiffmd's force
# field as Coeffs sections, which LAMMPS reads only for styles already defined.
LAMMPS_INPUT = """# Written by tools/npt_lammps.py: the Kremer-Grest melt at kT = 1, P = {pressure}.
units           lj
atom_style      bond
boundary        p p p
special_bonds   fene
bond_style      fene
pair_style      lj/cut {cutoff}
pair_modify     shift yes
read_data       {data}
neighbor        0.4 bin
neigh_modify    every 1 delay 0 check yes
timestep        {h}
{fixes}
thermo_style    custom step time temp press vol density pe
thermo_modify   norm no flush yes format float %.12g
thermo          {every}
run             {steps}
"""


def write(path, text):
    with open(path, "w") as f:
        f.write(text)
    return path


def build_start(args, folder, chains, beads):
    """The built melt as a LAMMPS data file (stiffmd check --write-data); returns its path."""
    os.makedirs(folder, exist_ok=True)
    deck = write(os.path.join(folder, "build.toml"), BUILD_DECK.format(chains=chains, beads=beads, seed=args.seed,
                                                                       velocity_seed=args.seed + 1))
    data = os.path.join(folder, "start.data")
    cmd = [args.stiffmd, "check", deck, "--write-data", data]
    p = subprocess.run(cmd, capture_output=True, text=True)
    if p.returncode != 0:
        sys.exit(f"stiffmd check failed (exit {p.returncode}): {' '.join(cmd)}\n{(p.stdout + p.stderr)[-2000:]}")
    return data


def run_deck(args, folder, data, t_end, every, barostat=True, interval=None, seed=None, extra=""):
    """A stiffmd run deck in folder (deck.toml) for the melt in data; returns its path."""
    b = BAROSTAT.format(pressure=fmt(PRESSURE), tau=fmt(args.tau_p), compressibility=fmt(args.compressibility),
                        interval=interval or args.interval) if barostat else ""
    text = RUN_DECK.format(data=os.path.abspath(data), damp=fmt(args.damp), seed=args.seed + 2 if seed is None else seed,
                           barostat=b, h=fmt(args.h), t_end=whole_steps_t_end(t_end, args.h), every=fmt(every),
                           extra=extra)
    os.makedirs(folder, exist_ok=True)
    return write(os.path.join(folder, "deck.toml"), text)


def steps_of(t, h):
    return int(round(float(whole_steps_t_end(t, h)) / h))


def sample_stiffmd(args, data, out):
    """The stiffmd NPT run: its thermo columns and time per step."""
    every = args.every_steps * args.h
    deck = run_deck(args, out, data, args.t_end, every)
    run_stiffmd(args.stiffmd, deck, out, args.set, fail=sys.exit)
    th = read_thermo(os.path.join(out, "thermo.csv"))
    s = read_summary(out)
    return {"time": th["time"], "volume": th["volume"], "density": th["density"], "pressure": th["pressure"],
            "molecular_pressure": th["molecular_pressure"], "temperature": th["temperature"],
            "steps": s["steps"], "ms_per_step": 1e3 * s["loop_seconds"] / s["steps"],
            "cpu_ms_per_step": 1e3 * s["cpu_seconds"] / s["steps"]}


def lammps_log(path):
    """A LAMMPS log's thermo rows as {column: array} (every run's rows, the column names of its
    thermo_style), its loop seconds, steps and CPU use (%), and its warnings."""
    rows, columns, names, loop, cpu, warnings = [], None, None, None, 100.0, []
    with open(path, errors="replace") as f:
        for line in f:
            w = line.split()
            if line.startswith("WARNING"):
                warnings.append(line.strip())
            elif w[:1] == ["Step"]:
                columns = names = w
            elif line.startswith("Loop time of"):
                loop = (float(w[3]), int(w[8]))
                columns = None
            elif re.match(r"\s*[0-9.]+% CPU use", line):
                cpu = float(w[0].rstrip("%"))
            elif columns and len(w) == len(columns):
                try:
                    rows.append([float(v) for v in w])
                except ValueError:
                    columns = None
    if not rows:
        return {}, loop, cpu, warnings
    data = np.array(rows, dtype=float).reshape(len(rows), len(names))
    return {n: data[:, k] for k, n in enumerate(names)}, loop, cpu, warnings


def sample_lammps(args, data, out):
    """The LAMMPS NPT run: its thermo columns and time per step."""
    os.makedirs(out, exist_ok=True)
    if args.lammps == "npt":
        fixes = f"fix             npt all npt temp {fmt(KT)} {fmt(KT)} {fmt(args.tdamp)} iso {fmt(PRESSURE)} " \
                f"{fmt(PRESSURE)} {fmt(args.pdamp)}"
    else:
        fixes = (f"fix             nph all nph iso {fmt(PRESSURE)} {fmt(PRESSURE)} {fmt(args.pdamp)}\n"
                 f"fix             bath all langevin {fmt(KT)} {fmt(KT)} {fmt(args.damp)} {args.seed + 3}")
    steps = steps_of(args.t_end, args.h)
    inp = write(os.path.join(out, "in.npt"), LAMMPS_INPUT.format(
        pressure=fmt(PRESSURE), cutoff=repr(WCA_CUTOFF), data=os.path.abspath(data), h=fmt(args.h), fixes=fixes,
        every=args.every_steps, steps=steps))
    log = os.path.join(out, "log.lammps")
    p = run_lammps(args.lmp, inp, log, cwd=out)
    if p.code != 0:
        sys.exit(failure(p, "LAMMPS") + "\n" + "".join(open(log, errors="replace").readlines()[-15:]))
    th, loop, cpu, warnings = lammps_log(log)
    if not th or loop is None:
        sys.exit(f"LAMMPS: no thermo rows or no 'Loop time' line in {log}")
    return {"time": th["Time"], "volume": th["Volume"], "density": th["Density"], "pressure": th["Press"],
            "temperature": th["Temp"], "steps": loop[1], "ms_per_step": 1e3 * loop[0] / loop[1],
            "cpu_ms_per_step": 1e3 * loop[0] / loop[1] * cpu / 100.0, "warnings": warnings[:10]}


def batch_means(x, batches):
    """Mean of x and its standard error from `batches` batch means."""
    per = len(x) // batches
    means = np.asarray(x[: per * batches], dtype=float).reshape(batches, per).mean(axis=1)
    return float(means.mean()), float(means.std(ddof=1) / math.sqrt(batches))


def compressibility(volume, kt):
    v = np.asarray(volume, dtype=float)
    return float(v.var() / (kt * v.mean()))


def analyse(run, discard, batches, dt, kt=KT):
    """The averages of one run after `discard`: (mean, standard error) of ρ, V, P (and the molecular
    P), T; κ_T = Var(V)/(kT⟨V⟩) with its jackknife error over the batches (kt: kT in the units of
    P·V); τ_int of V (time units)."""
    keep = run["time"] >= discard - 1e-9
    n = int(keep.sum())
    if n < 2 * batches:
        sys.exit(f"only {n} thermo rows after --discard {discard}: fewer than 2 per batch ({batches} batches)")
    per = n // batches
    v = run["volume"][keep][: per * batches]
    out = {"samples": per * batches, "batches": batches, "span": float(per * batches * dt)}
    for q in ("density", "volume", "pressure", "molecular_pressure", "temperature"):
        if q in run:
            out[q] = batch_means(run[q][keep], batches)
    kappa = compressibility(v, kt)
    blocks = v.reshape(batches, per)
    loo = np.array([compressibility(np.delete(blocks, i, axis=0).ravel(), kt) for i in range(batches)])
    out["kappa"] = (kappa, float(math.sqrt((batches - 1) / batches * ((loo - loo.mean()) ** 2).sum())))
    tau = autocorrelation_time(v) * dt
    out["tau_int_volume"] = tau
    out["batch_over_tau_int"] = float(per * dt / tau) if tau > 0 else float("inf")
    return out


def relative(a, b):
    """(a/b − 1, its standard error) from (mean, error) pairs a and b, errors independent."""
    r = a[0] / b[0]
    return r - 1.0, r * math.sqrt((a[1] / a[0]) ** 2 + (b[1] / b[0]) ** 2)


def verdict(d, target):
    """A difference d = (value, error) against a relative target: met, missed, or not resolved."""
    if abs(d[0]) <= target:
        return "met" if abs(d[0]) + 2 * d[1] <= target else "met (not resolved: |d| + 2σ > target)"
    return "missed" if abs(d[0]) - 2 * d[1] > target else "missed (not resolved: |d| - 2σ <= target)"


def compare(args):
    args.out = os.path.abspath(args.out)
    data = build_start(args, os.path.join(args.out, "start"), args.chains, args.beads)
    samplers = {"stiffmd": sample_stiffmd, "LAMMPS": sample_lammps}
    engines = [n for n in samplers if n.lower() in args.engines]
    with concurrent.futures.ThreadPoolExecutor(len(engines)) as pool:
        futures = {n: pool.submit(samplers[n], args, data, os.path.join(args.out, n.lower())) for n in engines}
        runs = {n: f.result() for n, f in futures.items()}
    dt = args.every_steps * args.h
    stats = {n: analyse(r, args.discard, args.batches, dt) for n, r in runs.items()}
    result = {
        "settings": {k: getattr(args, k) for k in ("chains", "beads", "h", "t_end", "discard", "batches", "damp",
                                                    "tau_p", "compressibility", "interval", "lammps", "tdamp",
                                                    "pdamp", "every_steps", "seed", "set")},
        "beads": args.chains * args.beads, "data": data, "steps": {n: runs[n]["steps"] for n in runs},
        "stats": stats,
        "ms_per_step": {n: runs[n]["ms_per_step"] for n in runs},
        "cpu_ms_per_step": {n: runs[n]["cpu_ms_per_step"] for n in runs},
    }
    if "LAMMPS" in runs:
        result["lammps_warnings"] = runs["LAMMPS"]["warnings"]
    if len(runs) == 2:
        d_rho = relative(stats["stiffmd"]["density"], stats["LAMMPS"]["density"])
        d_kappa = relative(stats["stiffmd"]["kappa"], stats["LAMMPS"]["kappa"])
        result["density_difference"] = {"relative": d_rho, "target": TARGET_DENSITY,
                                        "verdict": verdict(d_rho, TARGET_DENSITY)}
        result["kappa_difference"] = {"relative": d_kappa, "target": TARGET_KAPPA, "verdict": verdict(d_kappa, TARGET_KAPPA)}
    with open(os.path.join(args.out, "comparison.json"), "w") as f:
        json.dump(result, f, indent=2)
    lammps_name = {"npt": "fix npt", "nph-langevin": "fix nph + fix langevin"}[args.lammps]
    steps = next(iter(runs.values()))["steps"]
    print(f"Kremer-Grest melt, {args.chains} x {args.beads} beads, kT = {KT:g}, P = {PRESSURE:g}, h = {args.h:g}, "
          f"{steps} steps (t = {args.t_end:g}), averages over t >= {args.discard:g} in {args.batches} batches")
    print(f"stiffmd: velocity-verlet + Langevin (damp {args.damp:g}) + c-rescale (tau {args.tau_p:g}, compressibility "
          f"{args.compressibility:g}, interval {args.interval}); LAMMPS: {lammps_name} (Tdamp {args.tdamp:g}, "
          f"Pdamp {args.pdamp:g}" + (f", Langevin damp {args.damp:g})" if args.lammps == "nph-langevin" else ")"))
    print(f"{'':<22}" + "".join(f"{n:>26}" for n in runs))
    for q, label in (("density", "<rho>"), ("kappa", "kappa_T = Var V/kT<V>"), ("volume", "<V>"),
                     ("pressure", "<P> (atomic)"), ("molecular_pressure", "<P> (molecular)"),
                     ("temperature", "<T>")):
        cells = [f"{st[q][0]:.6g} ± {st[q][1]:.2g}" if q in st else "—" for st in stats.values()]
        print(f"{label:<22}" + "".join(f"{c:>26}" for c in cells))
    print(f"{'tau_int(V)':<22}" + "".join(f"{st['tau_int_volume']:>26.3g}" for st in stats.values()))
    print(f"{'batch / tau_int(V)':<22}" + "".join(f"{st['batch_over_tau_int']:>26.3g}" for st in stats.values()))
    print(f"{'ms per step (wall)':<22}" + "".join(f"{r['ms_per_step']:>26.4g}" for r in runs.values()))
    if len(runs) == 2:
        d_rho, d_kappa = result["density_difference"]["relative"], result["kappa_difference"]["relative"]
        print(f"density: stiffmd/LAMMPS - 1 = {100 * d_rho[0]:+.3f} % ± {100 * d_rho[1]:.3f} % "
              f"(target {100 * TARGET_DENSITY:g} %): {result['density_difference']['verdict']}")
        print(f"kappa_T: stiffmd/LAMMPS - 1 = {100 * d_kappa[0]:+.2f} % ± {100 * d_kappa[1]:.2f} % "
              f"(target {100 * TARGET_KAPPA:g} %): {result['kappa_difference']['verdict']}")
    for n, st in stats.items():
        if st["batch_over_tau_int"] < 10:
            print(f"note: {n}'s batches hold {st['batch_over_tau_int']:.1f} tau_int(V) (< 10): the errors are "
                  f"underestimated; run longer or use fewer batches")
    print(f"written: {os.path.join(args.out, 'comparison.json')}")


# ---- --cost ----

def cost(args):
    """Step time without and with the barostat at each interval on a large melt (see the docstring)."""
    args.out = os.path.abspath(args.out)
    data = build_start(args, os.path.join(args.out, "start"), args.cost_chains, args.cost_beads)
    # Equilibrate under the barostat and keep the final state: every timed run starts from it.
    eq = os.path.join(args.out, "equilibrate")
    deck = run_deck(args, eq, data, args.cost_equilibrate, args.cost_equilibrate,
                    extra='lammps_data = "final.data"\n')
    run_stiffmd(args.stiffmd, deck, eq, fail=sys.exit)
    start = os.path.join(eq, "final.data")
    t_end = args.cost_steps * args.h
    settings = [("none", None)] + [(f"interval {k}", k) for k in args.intervals]
    decks = {}
    for name, k in settings:
        folder = os.path.join(args.out, name.replace(" ", "_"))
        decks[name] = (folder, run_deck(args, folder, start, t_end, t_end, barostat=k is not None, interval=k))
    runs = {name: [] for name, _ in settings}
    for r in range(args.repeats):
        for name, _ in settings:
            folder, deck = decks[name]
            out = os.path.join(folder, f"run{r}")
            run_stiffmd(args.stiffmd, deck, out, fail=sys.exit)
            s = read_summary(out)
            runs[name].append({"ms": 1e3 * s["loop_seconds"] / s["steps"], "cpu_ms": 1e3 * s["cpu_seconds"] / s["steps"],
                               "steps": s["steps"], "evaluations": s["slow_evaluations"],
                               "rebuilds": s["neighbor_rebuilds"],
                               "timing": {k: 1e3 * v / s["steps"] for k, v in (s.get("timing") or {}).items()
                                          if isinstance(v, (int, float))}})
        print(f"round {r + 1}/{args.repeats}: " + ", ".join(f"{n} {runs[n][-1]['ms']:.3f} ms" for n, _ in settings),
              flush=True)
    med = lambda xs: float(np.median(xs))  # noqa: E731
    base = runs["none"]
    base_ms, base_cpu = med([x["ms"] for x in base]), med([x["cpu_ms"] for x in base])
    phases = sorted({k for rs in runs.values() for x in rs for k in x["timing"]})
    table = {}
    for name, k in settings:
        rs = runs[name]
        ms, cpu = med([x["ms"] for x in rs]), med([x["cpu_ms"] for x in rs])
        row = {"ms_per_step": ms, "cpu_ms_per_step": cpu, "all_ms": [x["ms"] for x in rs],
               "overhead_percent": 100 * (ms / base_ms - 1), "cpu_overhead_percent": 100 * (cpu / base_cpu - 1),
               "extra_evaluations_per_step": (med([x["evaluations"] for x in rs]) - med([x["evaluations"] for x in base]))
               / args.cost_steps,
               "extra_rebuilds_per_step": (med([x["rebuilds"] for x in rs]) - med([x["rebuilds"] for x in base]))
               / args.cost_steps,
               "rebuilds_per_step": med([x["rebuilds"] for x in rs]) / args.cost_steps,
               "phases_ms": {p: med([x["timing"].get(p, 0.0) for x in rs]) for p in phases}}
        if k is not None:
            row["ms_per_move"] = (ms - base_ms) * k
            row["move_phases_ms"] = {p: (row["phases_ms"][p] - med([x["timing"].get(p, 0.0) for x in base])) * k
                                     for p in phases}
        table[name] = row
    result = {"beads": args.cost_chains * args.cost_beads, "chains": args.cost_chains, "beads_per_chain": args.cost_beads,
              "h": args.h, "steps": args.cost_steps, "repeats": args.repeats, "settings": table,
              "target_percent": 3.0}
    print(f"{result['beads']} beads ({args.cost_chains} x {args.cost_beads}), velocity-verlet + Langevin, h = {args.h:g}, "
          f"{args.cost_steps} steps, median of {args.repeats} interleaved runs, 1 thread")
    print(f"{'setting':<14}{'ms/step':>10}{'overhead':>10}{'CPU ms':>10}{'CPU ovh':>10}{'ms/move':>10}"
          f"{'+evals/step':>12}{'rebuild/step':>13}   phases (ms/step)")
    for name, _ in settings:
        row = table[name]
        move = f"{row['ms_per_move']:.2f}" if "ms_per_move" in row else "—"
        print(f"{name:<14}{row['ms_per_step']:>10.3f}{row['overhead_percent']:>9.1f}%{row['cpu_ms_per_step']:>10.3f}"
              f"{row['cpu_overhead_percent']:>9.1f}%{move:>10}{row['extra_evaluations_per_step']:>12.3f}"
              f"{row['rebuilds_per_step']:>13.4f}   " + " ".join(f"{p} {v:.3f}" for p, v in row["phases_ms"].items() if v))
    for clock, key in (("wall", "overhead_percent"), ("CPU", "cpu_overhead_percent")):
        met = [k for name, k in settings if k is not None and table[name][key] <= 3.0]
        result[f"target_met_at_intervals_{clock.lower()}"] = met
        print(f"target <= 3 % of a step ({clock} time): " + (f"met at interval {', '.join(map(str, met))}" if met
                                                            else "missed at every interval"))
    with open(os.path.join(args.out, "cost.json"), "w") as f:
        json.dump(result, f, indent=2)
    print(f"written: {os.path.join(args.out, 'cost.json')}")


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--stiffmd", default=os.path.join(ROOT, "build", "stiffmd"))
    ap.add_argument("--lmp", default="/usr/bin/lmp")
    ap.add_argument("--out", default=None, help="output folder (default out/npt_lammps, out/npt_lammps_cost)")
    ap.add_argument("--quick", action="store_true", help="a plumbing run: 200 x 5 beads, t = 10 (≈ 20 s)")
    ap.add_argument("--cost", action="store_true", help="the barostat's cost on a 32 000-bead melt")
    ap.add_argument("--chains", type=int, default=200)
    ap.add_argument("--beads", type=int, default=10)
    ap.add_argument("--h", type=float, default=0.005, help="time step of both engines")
    ap.add_argument("--t-end", type=float, default=3000.0, help="length of each run (time units)")
    ap.add_argument("--discard", type=float, default=100.0, help="equilibration left out of the averages")
    ap.add_argument("--batches", type=int, default=20)
    ap.add_argument("--every-steps", type=int, default=40, help="a thermo row every this many steps")
    ap.add_argument("--damp", type=float, default=1.0, help="Langevin damp (stiffmd; LAMMPS nph-langevin)")
    ap.add_argument("--tau-p", type=float, default=1.0, help="stiffmd barostat tau")
    ap.add_argument("--compressibility", type=float, default=0.05, help="stiffmd barostat compressibility estimate")
    ap.add_argument("--interval", type=int, default=10, help="stiffmd barostat interval (steps per cell move)")
    ap.add_argument("--set", action="append", default=[], help="a --set for the stiffmd run of the comparison, "
                    'e.g. barostat.interval=40 (repeatable)')
    ap.add_argument("--engines", type=lambda v: [e.strip().lower() for e in v.split(",") if e.strip()],
                    default=["stiffmd", "lammps"], help="the engines to run: stiffmd,lammps (one alone: its numbers, "
                    "no comparison)")
    ap.add_argument("--lammps", choices=("npt", "nph-langevin"), default="npt")
    ap.add_argument("--tdamp", type=float, default=0.5, help="LAMMPS fix npt Tdamp")
    ap.add_argument("--pdamp", type=float, default=2.0, help="LAMMPS Pdamp")
    ap.add_argument("--seed", type=int, default=21)
    ap.add_argument("--cost-chains", type=int, default=3200)
    ap.add_argument("--cost-beads", type=int, default=10)
    ap.add_argument("--cost-steps", type=int, default=1000)
    ap.add_argument("--cost-equilibrate", type=float, default=20.0, help="NPT time before the timed runs")
    ap.add_argument("--intervals", type=lambda v: [int(k) for k in v.split(",") if k], default=[10, 25, 50, 100])
    ap.add_argument("--repeats", type=int, default=5)
    args = ap.parse_args()
    if args.quick:
        args.chains, args.beads, args.t_end, args.discard, args.batches, args.every_steps = 200, 5, 10.0, 2.0, 4, 20
        args.cost_chains, args.cost_beads, args.cost_steps, args.cost_equilibrate, args.repeats = 200, 5, 50, 0.5, 1
    if args.out is None:
        args.out = os.path.join(ROOT, "out", "npt_lammps_cost" if args.cost else "npt_lammps")
    if not os.path.exists(args.stiffmd):
        sys.exit(f"{args.stiffmd}: not found (build it: make -C build stiffmd)")
    if args.cost:
        cost(args)
        return
    if not args.engines or set(args.engines) - {"stiffmd", "lammps"}:
        sys.exit("--engines: stiffmd, lammps or both, comma-separated")
    if "lammps" in args.engines:
        lmp = shutil.which(args.lmp)
        if lmp is None:
            sys.exit(f"LAMMPS ('{args.lmp}') not found: bash tools/setup.sh --bench")
        args.lmp = lmp
    compare(args)


if __name__ == "__main__":
    main()
