#!/usr/bin/python3
"""Multiple time stepping with long-range electrostatics on the slow level: the largest outer (PPPM)
step at a given energy drift on LAMMPS's peptide example, for stiffmd's impulse, mollified-impulse
and projected-impulse (flexible X–H bonds on micro steps; the method's kick on both slower levels),
the mollified and projected kick on the PPPM level only (the middle level kicked plainly:
[[integrator.levels]] kick = "plain"), stiffmd rattle (rigid X–H bonds and water, the reference)
and LAMMPS `run_style respa` on the same state and force field.

    /usr/bin/python3 tools/mts_electrostatics.py                 # 56 runs, ≈ 20 min on one idle core
    /usr/bin/python3 tools/mts_electrostatics.py --h "2 4" --methods impulse --no-lammps --t-end 480  # smoke

The scene is inputs/peptide.toml (2004 atoms, CHARMM22, lj/charmm/coul/long 8/10 Å, PPPM 1e-4) with
every bond flexible except under rattle: the stiff-harmonic X–H bonds (½(α/ε)²(r − r0)² = LAMMPS's
harmonic K(r − r0)²) are the constraint-defining term and the water angle is the file's charmm angle
(flexible TIP3P, as LAMMPS without SHAKE). Three levels, innermost first, as LAMMPS's
`run_style respa 3 2 H bond 1 angle 2 dihedral 2 improper 2 pair 2 kspace 3` (H = outer step in fs):

    bonds   0.5 fs   the stiff X–H bonds and the other harmonic bonds
    bonded  1 fs     angles, dihedrals, impropers and the real-space pair (LJ + erfc Coulomb)
    long    H fs     PPPM (reciprocal space) only

The middle level is fixed at 1 fs on purpose: with it at 2 fs the impulse kicks of the real-space
pair on the flexible O–H bonds alone drift by ≈ 0.15 kcal/mol/atom/ns·10³ whatever the PPPM step
(measured: −58 kcal/mol in 200 fs at 2 fs, −17 at 1 fs, −5.9 at 0.5 fs, the velocity-Verlet floor),
so only the PPPM step varies here. Every run starts from one prepared state (PREP below: the flexible
model thermalised for --t-prep fs at 275 K with Langevin, impulse 0.5/1/1 fs, written as a LAMMPS
data file that both engines read), then runs --t-end fs in NVE. Drift = least-squares slope of the
total energy against time over the whole run, per atom, in kcal/mol/atom/ns; |ΔE|max is
max_t |E(t) − E(0)| per atom. Unstable: stiffmd exit 3 (non-finite state, failed projection), a
LAMMPS error after the run started or a non-finite energy, or a run past --timeout.

Outputs in --out (default /tmp/mts_electrostatics): results.csv, work/; the summary is printed
(--summary-only: again from results.csv, e.g. with another --threshold).
All runs serial, one at a time, OMP_NUM_THREADS = 1.
"""
import argparse
import csv
import math
import os
import re
import shlex
import shutil
import sys
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from engines import TIMEOUT, read_summary, read_thermo, run_engine, run_lammps  # noqa: E402

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
DECK = os.path.join(ROOT, "inputs", "peptide.toml")
DATA = os.path.join(ROOT, "inputs", "peptide_solvated.data")
# code: (method, the middle level's kick, or None for the method's own)
VARIANTS = {
    "impulse": ("impulse", None),
    "mollified-impulse": ("mollified-impulse", None),
    "projected-impulse": ("projected-impulse", None),
    "mollified-pppm-only": ("mollified-impulse", "plain"),
    "projected-pppm-only": ("projected-impulse", "plain"),
    "rattle": ("rattle", None),
}
METHODS = list(VARIANTS)
INNER, MIDDLE = 0.5, 1.0  # fs
FIELDS = ["code", "h", "status", "drift", "max_abs_de", "wall_s", "wall_per_ps", "final_T", "note"]


def log(msg):
    print(msg, file=sys.stderr, flush=True)


def deck_text(method, h, t_end, data, thermo, thermostat=False, rigid_water=False, middle_kick=None):
    """inputs/peptide.toml as a 3-level NVE deck (see the module doc) reading `data`; middle_kick: the
    bonded level's `kick` (None: the method's)."""
    t = open(DECK).read()
    t = t.replace('lammps_data = "peptide_solvated.data"', f'lammps_data = "{os.path.abspath(data)}"')
    t = re.sub(r'\[thermostat\].*?\n\n', '', t, flags=re.S)
    if not rigid_water:  # flexible TIP3P: the water angle from the file's charmm angle, as LAMMPS without SHAKE
        t = t.replace('angle_types."31" = { theta0 = 104.52, alpha = 1.5 }\n', '')
    # fix shake's tolerance is the rigid methods' (the impulse family has no SHAKE per step); rattle here
    # solves SHAKE to max |g| <= 1e-12, as the drifts of docs/performance.md were measured.
    t = re.sub(r'shake_tolerance = .*\n', '', t)
    t = t.replace('level = "slow"', 'level = "bonded"')
    t = t.replace('style = "harmonic-bond"', 'style = "harmonic-bond"\nlevel = "bonds"')
    for s in ["charmm-angle", "charmm-dihedral", "harmonic-improper"]:
        t = t.replace(f'style = "{s}"', f'style = "{s}"\nlevel = "bonded"')
    t = t.replace('style = "pppm"', 'style = "pppm"\nlevel = "long"')
    t = re.sub(r'\[integrator\].*', '', t, flags=re.S)
    if thermostat:
        t += '[thermostat]\nstyle = "langevin"\ntemperature = 275.0\ndamp = 100.0\nseed = 3\n\n'
    sub_bonded, sub_long = round(MIDDLE / INNER), round(h / MIDDLE)
    t += (f'[integrator]\nmethod = "{method}"\nh = {h}\n[[integrator.levels]]\nname = "bonds"\n'
          f'[[integrator.levels]]\nname = "bonded"\nsubsteps = {sub_bonded}\n'
          + (f'kick = "{middle_kick}"\n' if middle_kick else '') +
          f'[[integrator.levels]]\nname = "long"\nsubsteps = {sub_long}\n\n'
          f'[run]\nt_end = {t_end}\n\n[output]\nthermo_interval = {thermo}\nxyz_interval = {t_end}\n')
    return t


def lammps_input(data, h, t_end, thermo):
    sub_long = round(h / MIDDLE)
    return f"""units real
atom_style full
pair_style lj/charmm/coul/long 8.0 10.0 10.0
bond_style harmonic
angle_style charmm
dihedral_style charmm
improper_style harmonic
kspace_style pppm 1e-4
read_data {os.path.abspath(data)}
neighbor 2.0 bin
neigh_modify delay 0 every 1 check yes
run_style respa 3 {round(MIDDLE / INNER)} {sub_long} bond 1 angle 2 dihedral 2 improper 2 pair 2 kspace 3
timestep {h}
fix 1 all nve
thermo_style custom step time temp etotal
thermo_modify format float %.12g norm no
thermo {max(1, round(thermo / h))}
run {round(t_end / h)}
"""


def read_lammps_log(path):
    """(time, temp, etotal) rows of the thermo block, stopping at the first non-numeric line."""
    rows, on = [], False
    for line in open(path, errors="replace"):
        w = line.split()
        if w[:4] == ["Step", "Time", "Temp", "TotEng"]:
            on = True
            continue
        if on:
            try:
                rows.append([float(v) for v in w[1:4]])
            except ValueError:
                break
            if len(w) != 4:
                break
    return np.array(rows).reshape(-1, 3)


def measure(t, e, n_atoms):
    if len(t) < 3 or not np.all(np.isfinite(e)):
        return math.nan, math.nan
    slope = np.polyfit(t, e, 1)[0]  # kcal/mol per fs
    return slope * 1e6 / n_atoms, np.max(np.abs(e - e[0])) / n_atoms


def fmt(v, spec=".3g"):
    return "—" if v is None or (isinstance(v, float) and math.isnan(v)) else format(v, spec)


def write_example_deck():
    """inputs/peptide_mts.toml: the variant that reached the largest outer step, as a deck to run."""
    body = deck_text("mollified-impulse", 5.0, 300.0, "peptide_solvated.data", 15.0, thermostat=True,
                     middle_kick="plain")
    body = body.replace(f'lammps_data = "{os.path.abspath("peptide_solvated.data")}"',
                        'lammps_data = "peptide_solvated.data"')
    body = body[body.index('units = '):]  # peptide.toml's header comment describes that deck, not this one
    # The bonds to hydrogen chosen as LAMMPS's `fix shake … m 1.008` chooses them (the same bonds,
    # lengths and stiffnesses as peptide.toml's bond types: PeptideShake.*).
    lines = body.split("\n")
    first = next(k for k, l in enumerate(lines) if l.startswith('bond_types."'))
    lines = [l for l in lines if not l.startswith('bond_types."')]
    lines.insert(first, "masses = [1.008]               # every bond with a hydrogen (LAMMPS: fix shake … m 1.008)")
    body = "\n".join(lines)
    head = """# Written by tools/mts_electrostatics.py --write-deck from inputs/peptide.toml: do not edit by hand.
# LAMMPS's peptide (CHARMM22 + flexible TIP3P, lj/charmm/coul/long, PPPM 1e-4) on three r-RESPA
# levels: the bonds at 0.5 fs (the X–H bonds stiff-harmonic), the angles, dihedrals, impropers and
# real-space pairs at 1 fs, the PPPM mesh at the outer step of 5 fs. The mollified kick acts on the
# PPPM level alone ([[integrator.levels]] kick = "plain" on the middle level): the combination that
# reached the largest outer step at a fixed energy drift, 5-6 fs where LAMMPS's run_style respa
# reaches 4 fs (docs/performance.md, "Multiple time stepping with electrostatics"). Langevin at 275 K.
#   stiffmd run inputs/peptide_mts.toml
"""
    with open(os.path.join(ROOT, "inputs", "peptide_mts.toml"), "w") as f:
        f.write(head + body)
    print("wrote inputs/peptide_mts.toml")


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--stiffmd", default=os.path.join(ROOT, "build", "stiffmd"))
    ap.add_argument("--lmp", default="lmp")
    ap.add_argument("--h", default="2 3 4 5 6 8 10 12",
                    help="outer (PPPM) steps, fs, multiples of 1 that divide --t-end")
    ap.add_argument("--methods", default=" ".join(METHODS), help="codes among: " + " ".join(METHODS))
    ap.add_argument("--no-lammps", action="store_true")
    ap.add_argument("--t-end", type=float, default=960.0, help="NVE run length, fs (a multiple of every h)")
    ap.add_argument("--t-prep", type=float, default=2000.0, help="Langevin preparation, fs")
    ap.add_argument("--thermo", type=float, default=24.0, help="energy sampling interval, fs")
    ap.add_argument("--threshold", type=float, default=0.5,
                    help="|drift| threshold, kcal/mol/atom/ns (0.5: above the ≈ 0.1 noise of a 1 ps fit, below the "
                         "first resonant runs)")
    ap.add_argument("--timeout", type=float, default=300.0)
    ap.add_argument("--out", default="/tmp/mts_electrostatics")
    ap.add_argument("--summary-only", action="store_true", help="the summary from --out's results.csv, no runs")
    ap.add_argument("--write-deck", action="store_true",
                    help="write inputs/peptide_mts.toml (the best variant as a runnable deck) and stop")
    a = ap.parse_args()
    hs = [float(v) for v in a.h.replace(",", " ").split()]
    if a.write_deck:
        write_example_deck()
        return
    if a.summary_only:
        with open(os.path.join(a.out, "results.csv")) as f:
            rows = [dict(r, h=float(r["h"]), drift=float(r["drift"] or "nan"), max_abs_de=float(r["max_abs_de"] or "nan"), wall_per_ps=float(r["wall_per_ps"] or "nan"))
                    for r in csv.DictReader(f)]
        codes = list(dict.fromkeys(r["code"] for r in rows))
        print(summary(rows, codes, sorted({r["h"] for r in rows}), a))
        return
    work = os.path.join(a.out, "work")
    os.makedirs(work, exist_ok=True)
    n_atoms = 2004

    prepared = os.path.join(work, "prep", "prepared.data")
    if not os.path.exists(prepared):
        log(f"preparing the state: {a.t_prep} fs Langevin 275 K")
        deck = os.path.join(work, "prep.toml")
        open(deck, "w").write(deck_text("impulse", 1.0, a.t_prep, DATA, 100.0, thermostat=True)
                              + 'lammps_data = "prepared.data"\n')
        run = run_engine([a.stiffmd, "run", deck, "-o", os.path.join(work, "prep"), "--no-progress"])
        if run.code != 0:
            sys.exit(f"preparation failed:\n{run.stderr[-2000:]}")

    rows = []
    codes = [m for m in a.methods.split()] + ([] if a.no_lammps else ["lammps-respa"])
    for c in codes:
        if c not in VARIANTS and c != "lammps-respa":
            ap.error(f"unknown code {c!r} (known: {' '.join(METHODS)})")
    for h in hs:
        if abs(a.t_end / h - round(a.t_end / h)) > 1e-9:
            ap.error(f"--t-end {a.t_end:g} is not a whole number of outer steps of {h:g} fs")
    for code in codes:
        for h in hs:
            name = f"{code}_h{h:g}"
            d = os.path.join(work, name)
            shutil.rmtree(d, ignore_errors=True)
            os.makedirs(d)
            row = {"code": code, "h": h, "note": ""}
            if code == "lammps-respa":
                inp = os.path.join(d, "in.lmp")
                open(inp, "w").write(lammps_input(prepared, h, a.t_end, a.thermo))
                run = run_lammps(a.lmp, inp, os.path.join(d, "log.lammps"), cwd=d, timeout=a.timeout)
                data = read_lammps_log(os.path.join(d, "log.lammps")) if run.code != TIMEOUT else np.zeros((0, 3))
                t, temp, e = data[:, 0], data[:, 1], data[:, 2]
                done = run.code == 0 and len(t) and abs(t[-1] - a.t_end) < 1e-6 and np.all(np.isfinite(e))
                if not done:
                    row["note"] = (open(os.path.join(d, "log.lammps"), errors="replace").read().strip().splitlines()
                                   or ["timeout"])[-1][:80] if run.code != TIMEOUT else "timeout"
            else:
                deck = os.path.join(d, "deck.toml")
                method, middle_kick = VARIANTS[code]
                open(deck, "w").write(deck_text(method, h, a.t_end, prepared, a.thermo,
                                                rigid_water=(method == "rattle"), middle_kick=middle_kick))
                run = run_engine([a.stiffmd, "run", deck, "-o", os.path.join(d, "out"), "--no-progress"],
                                 timeout=a.timeout)
                th = read_thermo(os.path.join(d, "out", "thermo.csv"), missing_ok=True)
                t, e, temp = (th.get("time", np.zeros(0)), th.get("total", np.zeros(0)), th.get("temperature", np.zeros(0)))
                done = run.code == 0
                if run.code not in (0,):
                    row["note"] = "timeout" if run.code == TIMEOUT else f"exit {run.code}: " + (run.stderr.strip().splitlines() or [""])[-1][:80]
                    if run.code not in (3, TIMEOUT):
                        log(run.stderr[-2000:])
            row["wall_s"] = run.seconds
            if done:
                row["status"] = "stable"
                row["drift"], row["max_abs_de"] = measure(t, e, n_atoms)
                row["final_T"] = temp[-1]
                row["wall_per_ps"] = run.seconds / (a.t_end / 1000.0)
            else:
                row["status"] = "unstable"
                row["drift"] = row["max_abs_de"] = row["final_T"] = row["wall_per_ps"] = math.nan
            log(f"{name}: {row['status']} drift {fmt(row['drift'])} kcal/mol/atom/ns, |dE|max {fmt(row['max_abs_de'])}, "
                f"{run.seconds:.1f} s {row['note']}")
            rows.append(row)
            with open(os.path.join(a.out, "results.csv"), "w", newline="") as f:
                w = csv.DictWriter(f, FIELDS)
                w.writeheader()
                w.writerows(rows)
    print(summary(rows, codes, hs, a))


def summary(rows, codes, hs, a):
    by = {(r["code"], r["h"]): r for r in rows}
    thr = a.threshold
    out = [f"Command: `{shlex.join(['/usr/bin/python3', 'tools/mts_electrostatics.py'] + sys.argv[1:])}`, "
           f"{time.strftime('%Y-%m-%d %H:%M')}; NVE {a.t_end:g} fs from the prepared state; inner 0.5 fs, middle 1 fs.",
           "", "Drift, kcal/mol/atom/ns / max_t |E(t) − E(0)| per atom, kcal/mol (wall s per ps):", "",
           "| outer step (fs) | " + " | ".join(codes) + " |", "|---|" + "---|" * len(codes)]
    for h in hs:
        cells = []
        for c in codes:
            r = by.get((c, h))
            cells.append("—" if r is None else "unstable" if r["status"] != "stable"
                         else f"{r['drift']:+.3g} / {r['max_abs_de']:.2g} ({r['wall_per_ps']:.1f})")
        out.append(f"| {h:g} | " + " | ".join(cells) + " |")
    out += ["", f"Largest outer step with |drift| ≤ {thr:.3g} kcal/mol/atom/ns:", ""]
    best = {}
    for c in codes:
        ok = [h for h in hs if (c, h) in by and by[(c, h)]["status"] == "stable" and abs(by[(c, h)]["drift"]) <= thr]
        best[c] = max(ok) if ok else None
        out.append(f"- {c}: {fmt(best[c], 'g')} fs")
    flex = [best[c] for c in codes if c not in ("rattle", "lammps-respa") and best[c]]
    if flex and best.get("lammps-respa"):
        out.append(f"- stiffmd best flexible / LAMMPS respa: {max(flex) / best['lammps-respa']:.2f}")
    return "\n".join(out)


if __name__ == "__main__":
    main()
