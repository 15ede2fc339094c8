#!/usr/bin/env python3
"""A TraPPE-UA polyethylene melt (n-alkane chains, CH3 ends, CH2 inside) in LAMMPS real units.

  trappe_pe.py build OUT [--chains 40 --carbons 24 --density 0.72 --equilibrate-ps 20]
      grows the chains (bonds 1.54 Å, angles 114°, torsions trans/gauche) into a periodic box at the
      density, writes OUT/raw.data, then lets LAMMPS push the overlaps apart (soft pairs), switch on
      the force field and thermalise at 450 K (Langevin): OUT/trappe_pe.data (with velocities, Å/fs)
      is the state both codes start from; OUT/in.equilibrate is the LAMMPS input that made it.

  trappe_pe.py compare DATA OUT [--ps 20 --seeds 4 --reference-seeds 8 --lammps 1,2,3,4,5,6
                                 --respa "3 4 2" --stiffmd METHOD=h1,h2,... --reference lammps|stiffmd
                                 --figure PNG]
      NVT at 450 K (Langevin, damp 100 fs) from DATA with both codes, each run --ps picoseconds:
      a small-step reference (LAMMPS velocity Verlet at 1 fs, or with --reference stiffmd stiffmd's
      velocity Verlet at 1 fs, which needs no LAMMPS), LAMMPS `run_style respa N n1 n2 bond 1 angle
      2 dihedral 2 pair 3` at a ladder of outer steps for each --respa "N n1 n2" (default "3 4 2", the
      loop factors of inputs/trappe_pe.toml's levels: bonds every h/8, angles and torsions every h/2;
      "3 2 2" is the common LAMMPS choice, bonds every h/4), and stiffmd's methods on
      inputs/trappe_pe.toml at theirs. Observables of a run (time averages after --skip-ps): the non-bonded-plus-bending-
      plus-torsion energy per site, the pressure, the trans fraction of the torsions (|φ| > 120°),
      ⟨R²⟩ (end to end) and ⟨Rg²⟩.

      The criterion: every setting runs from the same start with --seeds independent thermostat
      seeds (the reference with --reference-seeds), and the statistic of a setting is the mean over
      its seeds with the seed-to-seed spread as its error. That error is honest whatever the
      observable's relaxation time: a run's average of ⟨R²⟩ over 20 ps from a common start is one
      draw of a random variable whose law any correct sampler of the same dynamics reproduces, so
      its spread over seeds is what a difference must be measured against (block errors within one
      run are not: ⟨R²⟩ of C24 relaxes over hundreds of ps). A setting "keeps the statistics" when
      every observable's mean is within 3 pooled standard errors of the reference's,
      |Δ| ≤ 3 s_p √(1/K + 1/K_ref) with s_p² the pooled seed variance (K + K_ref − 2 degrees of
      freedom; with 4 and 8 seeds a correct method fails one observable by chance with probability
      ≈ 1.3 %, one of five ≈ 6 %; the statistics are tools/seed_statistics.py's). What it compares
      is the law of 20-ps trajectories from this start, not ⟨R²⟩'s equilibrium value. Writes
      OUT/results.json (per-seed values too) and OUT/table.md, and with --figure PATH the figure.

Why a Python builder and LAMMPS rather than an engine [[build]]: the chains need their bond angles
and torsions from the start (a bead-spring random walk would start far up the angle potential), the
packing at a melt density needs a soft push-off, and the comparison wants one state, written once,
that both codes read.

The force field (Martin & Siepmann, J. Phys. Chem. B 102, 2569 (1998); the torsion from Jorgensen,
Madura & Swenson, JACS 106, 6638 (1984)), as FF below:
  LJ      ε/k_B = 98 K (CH3), 46 K (CH2); σ = 3.75, 3.95 Å; Lorentz–Berthelot mixing; between sites
          more than three bonds apart (special_bonds lj 0 0 0); cut at 10 Å and shifted (TraPPE uses
          14 Å with tail corrections: 10 Å keeps this comparison cheap; both codes use the same)
  bond    1.54 Å (TraPPE keeps it fixed); here a stiff harmonic bond with LAMMPS K = 268 kcal/(mol Å²),
          E = K(r − r0)², i.e. k = 536 kcal/(mol Å²): the OPLS-AA CT–CT stretch (Jorgensen, Maxwell &
          Tirado-Rives, JACS 118, 11225 (1996)); period 2π√(μ/k) ≈ 35 fs for CH2–CH2
  angle   θ0 = 114°, E = ½ k_θ (θ − θ0)², k_θ/k_B = 62 500 K/rad² (LAMMPS harmonic K = k_θ/2)
  torsion c1 (1 + cos φ) + c2 (1 − cos 2φ) + c3 (1 + cos 3φ), c1/k_B = 355.03 K, c2 = −68.19 K,
          c3 = 791.32 K, trans at φ = 180° (LAMMPS opls K_n = 2 c_n)
  masses  CH3 15.035, CH2 14.027 g/mol
The density: 0.72 g/cm³, the range the literature gives for molten C24 near 450 K (≈ 0.70–0.73); it
only fixes the NVT state both codes run, and was not tuned to TraPPE's own equation of state.
"""
import argparse
import json
import math
import os
import shutil
import subprocess
import sys

import numpy as np

import seed_statistics  # tools/ is the script's directory
from engines import read_summary, read_thermo, run_lammps, run_stiffmd

KB = 0.0019872067  # kcal/(mol K), LAMMPS real
AVOGADRO = 6.02214076e23
FF = {
    "mass": {"CH3": 15.035, "CH2": 14.027},
    "epsilon": {"CH3": 98.0 * KB, "CH2": 46.0 * KB},  # kcal/mol
    "sigma": {"CH3": 3.75, "CH2": 3.95},  # Å
    "cutoff": 10.0,
    "bond_length": 1.54,
    "bond_K": 268.0,  # LAMMPS harmonic: E = K (r − r0)²
    "theta0": 114.0,
    "angle_k": 62500.0 * KB,  # E = ½ k (θ − θ0)²; LAMMPS K = k/2
    "c": (355.03 * KB, -68.19 * KB, 791.32 * KB),  # TraPPE c1, c2, c3 in kcal/mol
}
TYPES = ("CH3", "CH2")  # LAMMPS atom types 1, 2


def lb_mix(a, b):
    """Lorentz–Berthelot: σ arithmetic, ε geometric (LAMMPS pair_modify mix arithmetic)."""
    return math.sqrt(FF["epsilon"][a] * FF["epsilon"][b]), 0.5 * (FF["sigma"][a] + FF["sigma"][b])


def box_length(chains, carbons, density):
    """The cube side (Å) holding `chains` C_n chains at `density` g/cm³."""
    grams = chains * ((carbons - 2) * FF["mass"]["CH2"] + 2 * FF["mass"]["CH3"]) / AVOGADRO
    return (grams / density * 1e24) ** (1.0 / 3.0)


def grow_chains(chains, carbons, length, seed, min_distance=2.5, tries=200):
    """Chains grown site by site with the bond length and angle, torsions drawn from
    trans (60 %) and gauche± (20 % each), each new site at least min_distance (minimum image) from
    every site of other chains and every site of its own chain more than three bonds back."""
    rng = np.random.default_rng(seed)
    b, theta = FF["bond_length"], math.radians(FF["theta0"])
    placed = np.zeros((0, 3))
    chain_list = []

    def clear(p, own, k):
        others = placed if len(own) == 0 else np.vstack([placed] + ([np.array(own[:max(k - 3, 0)])] if k > 3 else []))
        if len(others) == 0:
            return True
        d = others - p
        d -= length * np.round(d / length)
        return np.min(np.einsum("ij,ij->i", d, d)) >= min_distance**2

    def next_site(a, bb, c, phi):
        """The site d with |cd| = b, angle bcd = θ and dihedral abcd = φ (trans: φ = 180°)."""
        bc = c - bb
        bc /= np.linalg.norm(bc)
        n = np.cross(bb - a, bc)
        n /= np.linalg.norm(n)
        m = np.cross(n, bc)
        d2 = np.array([-b * math.cos(theta), b * math.sin(theta) * math.cos(phi), b * math.sin(theta) * math.sin(phi)])
        return c + d2[0] * bc + d2[1] * m + d2[2] * n

    for _ in range(chains):
        for attempt in range(tries):
            own = [rng.uniform(0, length, 3)]
            if not clear(own[0], [], 0):
                continue
            u = rng.normal(size=3)
            u /= np.linalg.norm(u)
            own.append(own[0] + b * u)
            # Third site: any direction at the bond angle.
            w = np.cross(u, rng.normal(size=3))
            w /= np.linalg.norm(w)
            own.append(own[1] - b * math.cos(theta) * u + b * math.sin(theta) * w)
            ok = True
            for k in range(3, carbons):
                for _ in range(tries):
                    phi = math.pi if rng.random() < 0.6 else math.pi + rng.choice((-1, 1)) * math.radians(120)
                    phi += rng.normal(0, math.radians(10))
                    p = next_site(own[k - 3], own[k - 2], own[k - 1], phi)
                    if clear(p, own, k):
                        own.append(p)
                        break
                else:
                    ok = False
                    break
            if ok:
                break
        else:
            sys.exit(f"could not place chain {len(chain_list) + 1}: lower the density or min_distance")
        chain_list.append(np.array(own))
        placed = np.vstack([placed, own])
    return chain_list


def topology(chains, carbons):
    """Types (1 = CH3, 2 = CH2), molecule ids, bonds, angles and dihedrals, 1-based atom ids."""
    types, mol, bonds, angles, dihedrals = [], [], [], [], []
    for c in range(chains):
        first = c * carbons + 1
        for k in range(carbons):
            types.append(1 if k in (0, carbons - 1) else 2)
            mol.append(c + 1)
        ids = list(range(first, first + carbons))
        bonds += [(ids[k], ids[k + 1]) for k in range(carbons - 1)]
        angles += [(ids[k], ids[k + 1], ids[k + 2]) for k in range(carbons - 2)]
        dihedrals += [tuple(ids[k:k + 4]) for k in range(carbons - 3)]
    return types, mol, bonds, angles, dihedrals


def write_data(path, x, length, chains, carbons, title):
    types, mol, bonds, angles, dihedrals = topology(chains, carbons)
    with open(path, "w") as f:
        f.write(f"{title}\n\n{len(x)} atoms\n{len(bonds)} bonds\n{len(angles)} angles\n{len(dihedrals)} dihedrals\n\n")
        f.write("2 atom types\n1 bond types\n1 angle types\n1 dihedral types\n\n")
        for a in "xyz":
            f.write(f"0 {length:.10f} {a}lo {a}hi\n")
        f.write(f"\nMasses\n\n1 {FF['mass']['CH3']}  # CH3\n2 {FF['mass']['CH2']}  # CH2\n\nAtoms # molecular\n\n")
        for i, p in enumerate(x):
            f.write(f"{i + 1} {mol[i]} {types[i]} {p[0]:.10f} {p[1]:.10f} {p[2]:.10f}\n")
        for name, items in (("Bonds", bonds), ("Angles", angles), ("Dihedrals", dihedrals)):
            f.write(f"\n{name}\n\n")
            for k, ids in enumerate(items):
                f.write(f"{k + 1} 1 " + " ".join(map(str, ids)) + "\n")


def lammps_force_field(pair=True):
    """The LAMMPS lines of the force field (after read_data)."""
    K1, K2, K3 = (2 * c for c in FF["c"])
    lines = ["special_bonds lj 0.0 0.0 0.0",
             "bond_style harmonic", f"bond_coeff 1 {FF['bond_K']} {FF['bond_length']}",
             "angle_style harmonic", f"angle_coeff 1 {FF['angle_k'] / 2:.10g} {FF['theta0']}",
             "dihedral_style opls", f"dihedral_coeff 1 {K1:.10g} {K2:.10g} {K3:.10g} 0.0"]
    if pair:
        lines += [f"pair_style lj/cut {FF['cutoff']}", "pair_modify mix arithmetic shift yes"]
        for t, name in enumerate(TYPES, 1):
            lines.append(f"pair_coeff {t} {t} {FF['epsilon'][name]:.10g} {FF['sigma'][name]}")
    return "\n".join(lines) + "\n"


def build(args):
    os.makedirs(args.out, exist_ok=True)
    length = box_length(args.chains, args.carbons, args.density)
    chains = grow_chains(args.chains, args.carbons, length, args.seed)
    x = np.vstack(chains)
    title = f"TraPPE-UA C{args.carbons} melt: {args.chains} chains, {args.density} g/cm3 (tools/trappe_pe.py)"
    write_data(os.path.join(args.out, "raw.data"), x, length, args.chains, args.carbons, title + ", as grown")
    steps = int(round(args.equilibrate_ps * 1000))
    with open(os.path.join(args.out, "in.equilibrate"), "w") as f:
        f.write(f"""# tools/trappe_pe.py build: push the grown chains apart, then thermalise at {args.temperature} K
units real
atom_style molecular
boundary p p p
read_data raw.data
{lammps_force_field(pair=False)}pair_style soft {FF['cutoff'] / 3:.4g}
pair_coeff * * 0.0
variable A equal ramp(0.0,30.0)
fix push all adapt 1 pair soft a * * v_A
neighbor 2.0 bin
fix limit all nve/limit 0.05
fix bath all langevin {args.temperature} {args.temperature} 100.0 {args.seed}
timestep 1.0
thermo 1000
run 4000
unfix push
{lammps_force_field()}run 4000
unfix limit
fix nve all nve
velocity all create {args.temperature} {args.seed + 1} dist gaussian
run {steps}
write_data trappe_pe.data nocoeff
""")
    lmp = shutil.which(args.lmp) or sys.exit(f"{args.lmp}: not found")
    r = subprocess.run([lmp, "-in", "in.equilibrate", "-log", "log.equilibrate", "-screen", "none"], cwd=args.out)
    if r.returncode != 0:
        sys.exit(f"LAMMPS failed: see {args.out}/log.equilibrate")
    print(f"{args.out}/trappe_pe.data: {len(x)} sites, box {length:.4f} A, equilibrated {args.equilibrate_ps} ps "
          f"at {args.temperature} K")


# ---- the comparison ----

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
DECK = os.path.join(ROOT, "inputs", "trappe_pe.toml")
TEMPERATURE, DAMP = 450.0, 100.0  # K, fs
THERMO_FS = 50.0  # thermo rows every ... (frames every --frame-fs)
OBSERVABLES = ("energy", "pressure", "trans", "r2", "rg2")
LABELS = {"energy": "E_ang+dih+LJ / site (kcal/mol)", "pressure": "p (atm)", "trans": "trans fraction",
          "r2": "<R^2> (A^2)", "rg2": "<Rg^2> (A^2)"}


def read_data_topology(path):
    """Molecule id per atom (0-based order of ids) and the dihedrals (0-based quadruples)."""
    mol, dihedrals, section = {}, [], None
    with open(path) as f:
        for line in f:
            s = line.split("#")[0].strip()
            if not s:
                continue
            w = s.split()
            if not w[0].lstrip("-").replace(".", "").isdigit():
                section = s
                continue
            if section == "Atoms":
                mol[int(w[0])] = int(w[1])
            elif section == "Dihedrals":
                dihedrals.append([int(v) - 1 for v in w[2:6]])
    ids = sorted(mol)
    return np.array([mol[i] for i in ids]), np.array(dihedrals)


def chain_observables(x, mol, dihedrals):
    """trans fraction, <R^2>, <Rg^2> of one frame of unwrapped positions x (N × 3)."""
    b1 = x[dihedrals[:, 1]] - x[dihedrals[:, 0]]
    b2 = x[dihedrals[:, 2]] - x[dihedrals[:, 1]]
    b3 = x[dihedrals[:, 3]] - x[dihedrals[:, 2]]
    n1, n2 = np.cross(b1, b2), np.cross(b2, b3)
    m = np.cross(n1, b2 / np.linalg.norm(b2, axis=1)[:, None])
    phi = np.degrees(np.arctan2(np.einsum("ij,ij->i", m, n2), np.einsum("ij,ij->i", n1, n2)))
    trans = np.mean(np.abs(phi) > 120.0)
    r2, rg2 = [], []
    for c in np.unique(mol):
        xc = x[mol == c]
        r2.append(np.sum((xc[-1] - xc[0]) ** 2))
        rg2.append(np.mean(np.sum((xc - xc.mean(axis=0)) ** 2, axis=1)))
    return trans, float(np.mean(r2)), float(np.mean(rg2))


def summarise(energy, pressure, frames, mol, dihedrals, sites, cpu_seconds):
    """One run's time averages (its error comes from the spread over seeds, see `ensemble`)."""
    if len(frames) == 0 or len(energy) == 0:
        sys.exit("a run left no frame or thermo row after --skip-ps: lengthen --ps or shorten --frame-fs")
    per_frame = np.array([chain_observables(x, mol, dihedrals) for x in frames])
    return {"energy": float(np.mean(energy) / sites), "pressure": float(np.mean(pressure)),
            "trans": float(per_frame[:, 0].mean()), "r2": float(per_frame[:, 1].mean()),
            "rg2": float(per_frame[:, 2].mean()), "frames": len(frames), "cpu_seconds": cpu_seconds}


def measure_lammps(args, out, h, respa, seed):
    """One LAMMPS run's result (see summarise), None when it blew up. respa: None (velocity Verlet) or the loop factors "N n1 n2" of run_style respa."""
    os.makedirs(out, exist_ok=True)
    steps = int(round(args.ps * 1000 / h))
    style = f"run_style respa {respa} bond 1 angle 2 dihedral 2 pair 3" if respa else "run_style verlet"
    with open(os.path.join(out, "in.run"), "w") as f:
        f.write(f"""units real
atom_style molecular
boundary p p p
read_data {os.path.abspath(args.data)}
{lammps_force_field()}neighbor 2.0 bin
neigh_modify delay 0 every 1 check yes
fix nve all nve
fix bath all langevin {TEMPERATURE} {TEMPERATURE} {DAMP} {seed}
{style}
timestep {h!r}
thermo_style custom step time temp press pe ebond
thermo_modify format float %.10g norm no
thermo {int(round(THERMO_FS / h))}
dump frames all custom {int(round(args.frame_fs / h))} frames.dump id xu yu zu
dump_modify frames sort id format float %.8g
run {steps}
""")
    p = run_lammps(args.lmp, "in.run", "log.lammps", cwd=out, echo=True)
    rows, cpu, cpu_percent = [], None, 100.0
    with open(os.path.join(out, "log.lammps")) as f:
        on = False
        for line in f:
            w = line.split()
            if line.strip().endswith("% CPU use with 1 MPI tasks x 1 OpenMP threads"):
                cpu_percent = float(w[0].rstrip("%"))
            if w[:2] == ["Step", "Time"]:
                on = True
                continue
            if line.startswith("Loop time"):
                cpu = float(w[3])
                on = False
            if on and len(w) == 6:
                try:
                    rows.append([float(v) for v in w])
                except ValueError:
                    on = False
    if p.code != 0 or cpu is None or not rows or not all(map(math.isfinite, np.ravel(rows))):
        return None  # LAMMPS stopped (lost atoms, a bond too long) or produced NaN: unstable
    rows = np.array(rows)
    keep = rows[:, 1] >= args.skip_ps * 1000
    frames = []
    with open(os.path.join(out, "frames.dump")) as f:
        lines = f.read().splitlines()
    k = 0
    while k < len(lines):
        t = int(lines[k + 1]) * h
        n = int(lines[k + 3])
        if t >= args.skip_ps * 1000:
            frames.append(np.array([[float(v) for v in line.split()[1:4]] for line in lines[k + 9:k + 9 + n]]))
        k += 9 + n
    mol, dih = read_data_topology(args.data)
    r = summarise(rows[keep, 4] - rows[keep, 5], rows[keep, 3], frames, mol, dih, len(mol), cpu * cpu_percent / 100)
    r["temperature"] = float(rows[keep, 2].mean())
    return r


def measure_stiffmd(args, out, method, h, seed, extra=()):
    """One stiffmd run's result (see summarise), None when it blew up (exit 3)."""
    os.makedirs(out, exist_ok=True)
    t_end = args.ps * 1000
    sets = [f'integrator.method="{method}"', f"integrator.h={h!r}", f"run.t_end={t_end!r}",
            f"output.thermo_interval={THERMO_FS!r}", f"output.xyz_interval={args.frame_fs!r}",
            f"import.lammps_data=\"{os.path.abspath(args.data)}\"", f"thermostat.seed={seed}", *extra]
    if run_stiffmd(args.stiffmd, DECK, out, sets, accept=(0, 3), fail=sys.exit).code == 3:
        return None  # numerical blow-up
    th = read_thermo(os.path.join(out, "thermo.csv"))
    keep = th["time"] >= args.skip_ps * 1000
    # The potential without the C–C bonds: potential_slow, the sum of every level but the innermost
    # (the per-level columns potential_<name> of [[integrator.levels]] add up to the same).
    energy = th["potential_slow"][keep]
    frames = []
    with open(os.path.join(out, "trajectory.xyz")) as f:
        lines = f.read().splitlines()
    k = 0
    while k < len(lines):
        n = int(lines[k])
        t = float(lines[k + 1].split("time=")[1].split()[0])
        if t >= args.skip_ps * 1000:
            frames.append(np.array([[float(v) for v in line.split()[1:4]] for line in lines[k + 2:k + 2 + n]]))
        k += 2 + n
    cpu = read_summary(out)["cpu_seconds"]
    mol, dih = read_data_topology(args.data)
    r = summarise(energy, th["pressure"][keep], frames, mol, dih, len(mol), cpu)
    r["temperature"] = float(th["temperature"][keep].mean())
    return r


def cached(args, name, seed, run):
    """A run's result, from OUT/NAME/result.json when an earlier compare with the same settings made it
    (so that a ladder can be extended run by run); `run(directory)` otherwise."""
    d = os.path.join(args.out, name)
    path = os.path.join(d, "result.json")
    key = {"ps": args.ps, "skip_ps": args.skip_ps, "data": os.path.abspath(args.data), "seed": seed,
           "set": args.set, "frame_fs": args.frame_fs}
    if os.path.exists(path):
        with open(path) as f:
            stored = json.load(f)
        if stored.get("key") == key:
            return stored["result"]
    r = run(d)
    os.makedirs(d, exist_ok=True)
    with open(path, "w") as f:
        json.dump({"key": key, "result": r}, f)
    return r


def ensemble(per_seed):
    """A setting's statistics from its runs with independent seeds: per observable the mean over
    seeds and its standard error s/√K, and the per-seed values; None when any seed blew up."""
    return seed_statistics.ensemble(per_seed, OBSERVABLES, averaged=("temperature", "cpu_seconds"))


def pooled_z(r, ref, o):
    """(mean − reference mean) / its pooled standard error, s_p² = ((K−1)s² + (K_ref−1)s_ref²)/(K+K_ref−2)."""
    return seed_statistics.pooled_z(r["per_seed"][o], ref["per_seed"][o])


def keeps_statistics(r, ref, sigmas=3.0):
    """Every observable within `sigmas` pooled standard errors: a plain 3, whose false-alarm rate
    with K + K_ref − 2 degrees of freedom the docstring states (tools/cost_vs_eps.py instead takes
    the Student-t quantile of seed_statistics.sigma_threshold)."""
    if r is None:
        return False
    return seed_statistics.within([pooled_z(r, ref, o) for o in OBSERVABLES], sigmas)


def seeded(args, name, seeds, run):
    """A setting run with `seeds` thermostat seeds (args.seed + k), each cached in OUT/NAME/seedK;
    `run(directory, seed)` makes one. The ensemble of their results."""
    return ensemble([cached(args, os.path.join(name, f"seed{k}"), args.seed + k,
                            lambda d, s=args.seed + k: run(d, s)) for k in range(seeds)])


def compare(args):
    os.makedirs(args.out, exist_ok=True)
    if args.reference == "lammps" or args.lammps:
        args.lmp = shutil.which(args.lmp) or sys.exit(f"{args.lmp}: not found (--reference stiffmd and no --lammps "
                                                      "run without LAMMPS)")
    if args.seeds < 2 or args.reference_seeds < 2:
        sys.exit("--seeds and --reference-seeds must be at least 2 (the error is their spread)")
    results = {"settings": {"ps": args.ps, "skip_ps": args.skip_ps, "temperature": TEMPERATURE, "damp_fs": DAMP,
                            "data": os.path.abspath(args.data), "seeds": args.seeds,
                            "reference_seeds": args.reference_seeds, "first_seed": args.seed,
                            "reference": args.reference}, "runs": []}
    runs = [(f"lammps respa {loops}", h, loops) for loops in (args.respa or ["3 4 2"]) for h in args.lammps]
    for spec in args.methods:
        method, hs = spec.split("=")
        runs += [(method, float(h), method) for h in hs.split(",")]
    t_fs = args.ps * 1000
    # stiffmd refuses a t_end that is not a whole number of steps (LAMMPS runs round(t/h) steps)
    uneven = [f"{label} {h:g} fs" for label, h, _ in runs + [("velocity-verlet", 1.0, None)]
              if not label.startswith("lammps") and abs(t_fs / h - round(t_fs / h)) > 1e-9 * t_fs / h]
    if uneven:  # refused before any run, not after an hour of them
        sys.exit(f"--ps {args.ps:g} is not a whole number of steps for: " + ", ".join(uneven))
    path = os.path.join(args.out, "results.json")
    print(f"reference ({args.reference} velocity Verlet, 1 fs) ...", flush=True)
    if args.reference == "lammps":
        ref = seeded(args, "lammps_verlet_1fs", args.reference_seeds, lambda d, s: measure_lammps(args, d, 1.0, None, s))
    else:
        ref = seeded(args, "stiffmd_verlet_1fs", args.reference_seeds,
                     lambda d, s: measure_stiffmd(args, d, "velocity-verlet", 1.0, s, args.set))
    if ref is None:
        sys.exit("the reference run failed")
    results["reference"] = ref
    for label, h, method in runs:
        name = label.replace(" ", "_") + f"_{h:g}fs"
        print(f"{label} h = {h:g} fs ...", flush=True)
        lammps = label.startswith("lammps respa")
        r = seeded(args, name, args.seeds, lambda d, s: measure_lammps(args, d, h, method, s) if lammps else
                   measure_stiffmd(args, d, method, h, s, args.set))
        results["runs"].append({"code": "LAMMPS" if lammps else "stiffmd", "method": label, "h": h,
                                "result": r, "keeps": keeps_statistics(r, ref),
                                "z": {o: pooled_z(r, ref, o) for o in OBSERVABLES} if r else None})
        with open(path, "w") as f:
            json.dump(results, f, indent=1)
    write_table(results, os.path.join(args.out, "table.md"))
    if args.figure:
        plot(results, args.figure)
    print(open(os.path.join(args.out, "table.md")).read())


def write_table(results, path):
    ref = results["reference"]
    fmt = {"energy": "{:.4f}±{:.4f}", "pressure": "{:.0f}±{:.0f}", "trans": "{:.4f}±{:.4f}", "r2": "{:.1f}±{:.1f}",
           "rg2": "{:.2f}±{:.2f}"}
    lines = ["| code | method | h (fs) | " + " | ".join(LABELS[o] for o in OBSERVABLES) + " | T (K) | CPU s | keeps |",
             "|---|---|---|" + "---|" * (len(OBSERVABLES) + 3)]
    row = lambda code, m, h, r, keeps: (f"| {code} | {m} | {h:g} | " + (
        " | ".join(fmt[o].format(*r[o]) for o in OBSERVABLES) + f" | {r['temperature']:.1f} | {r['cpu_seconds']:.0f} | "
        if r else "unstable | " * len(OBSERVABLES) + "– | – | ") + ("yes" if keeps else "no") + " |")
    ref_code = "LAMMPS" if results["settings"]["reference"] == "lammps" else "stiffmd"
    lines.append(row(ref_code, "velocity verlet (reference)", 1.0, ref, True))
    for run in results["runs"]:
        lines.append(row(run["code"], run["method"], run["h"], run["result"], run["keeps"]))
    largest = {}
    for run in results["runs"]:
        key = (run["code"], run["method"])
        largest.setdefault(key, None)
        if run["keeps"] and (largest[key] is None or run["h"] > largest[key]):
            largest[key] = run["h"]
    st = results["settings"]
    lines = [f"{st['ps']:g} ps per run ({st['skip_ps']:g} ps left out), {st['seeds']} thermostat seeds per setting, "
             f"{st['reference_seeds']} for the reference; mean over seeds ± its standard error. CPU s: per run.", ""] + lines
    lines += ["", "Failing observables (pooled z = Δ / s_p√(1/K + 1/K_ref), |z| > 3):", ""]
    for run in results["runs"]:
        if run["result"] is None:
            lines.append(f"- {run['code']} {run['method']} {run['h']:g} fs: unstable")
        elif not run["keeps"]:
            bad = [f"{o} {run['z'][o]:+.1f}" for o in OBSERVABLES if abs(run["z"][o]) > 3]
            lines.append(f"- {run['code']} {run['method']} {run['h']:g} fs: " + ", ".join(bad))
    lines += ["", "Largest outer step that keeps every statistic within 3 pooled standard errors:", ""]
    for (code, m), h in largest.items():
        lines.append(f"- {code} {m}: " + (f"{h:g} fs" if h else "none of the steps tried"))
    with open(path, "w") as f:
        f.write("\n".join(lines) + "\n")


def plot(results, path):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    ref = results["reference"]
    methods = []
    for run in results["runs"]:
        if (run["code"], run["method"]) not in methods:
            methods.append((run["code"], run["method"]))
    fig, axes = plt.subplots(1, len(OBSERVABLES), figsize=(4 * len(OBSERVABLES), 3.6))
    for ax, o in zip(axes, OBSERVABLES):
        ax.axhspan(ref[o][0] - 3 * ref[o][1], ref[o][0] + 3 * ref[o][1], color="0.85", label="reference ±3 s.e.")
        for k, (code, m) in enumerate(methods):
            pts = [(r["h"], r["result"][o]) for r in results["runs"]
                   if (r["code"], r["method"]) == (code, m) and r["result"]]
            if pts:
                h = np.array([p[0] for p in pts]) * (1 + 0.02 * (k - len(methods) / 2))
                ax.errorbar(h, [p[1][0] for p in pts], [p[1][1] for p in pts], marker="os^vDx<>"[k % 8],
                            ls="-", capsize=2, label=f"{code} {m}")
        ax.set_xlabel("outer step h (fs)")
        ax.set_title(LABELS[o], fontsize=9)
    axes[0].legend(fontsize=7)
    st = results["settings"]
    fig.suptitle(f"TraPPE-UA C24 melt, 450 K, NVT (Langevin): {st['ps']:g} ps per run, mean ± s.e. over "
                 f"{st['seeds']} seeds ({st['reference_seeds']} for the reference)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = ap.add_subparsers(dest="command", required=True)
    b = sub.add_parser("build")
    b.add_argument("out")
    b.add_argument("--chains", type=int, default=40)
    b.add_argument("--carbons", type=int, default=24)
    b.add_argument("--density", type=float, default=0.72, help="g/cm^3")
    b.add_argument("--temperature", type=float, default=450.0)
    b.add_argument("--equilibrate-ps", type=float, default=20.0)
    b.add_argument("--seed", type=int, default=2026)
    b.add_argument("--lmp", default="lmp")
    c = sub.add_parser("compare")
    c.add_argument("data", help="the start state (trappe_pe.py build's trappe_pe.data)")
    c.add_argument("out")
    c.add_argument("--ps", type=float, default=20.0, help="length of each run (ps)")
    c.add_argument("--frame-fs", type=float, default=250.0, help="chain observables every ... fs")
    c.add_argument("--seeds", type=int, default=4, help="thermostat seeds per setting")
    c.add_argument("--reference-seeds", type=int, default=8, help="thermostat seeds of the reference")
    c.add_argument("--reference", choices=("lammps", "stiffmd"), default="lammps",
                   help="the small-step reference: LAMMPS's or stiffmd's velocity Verlet at 1 fs")
    c.add_argument("--skip-ps", type=float, default=1.0, help="left out of the averages (ps)")
    c.add_argument("--lammps", type=lambda v: [float(h) for h in v.split(",") if h], default=[1.0, 2.0, 3.0, 4.0, 5.0, 6.0],
                   help="LAMMPS r-RESPA outer steps (fs); '' for none")
    c.add_argument("--respa", action="append", help='LAMMPS run_style respa loop factors, e.g. "3 4 2" (repeatable)')
    c.add_argument("--stiffmd", dest="methods", action="append", default=[], help="METHOD=h1,h2,... (fs)")
    c.add_argument("--set", action="append", default=[], help="a --set for every stiffmd run")
    c.add_argument("--figure")
    c.add_argument("--seed", type=int, default=4242)
    c.add_argument("--lmp", default="lmp")
    c.add_argument("--stiffmd-binary", dest="stiffmd", default=os.path.join(ROOT, "build", "stiffmd"))
    args = ap.parse_args()
    if args.command == "build":
        build(args)
    else:
        compare(args)


if __name__ == "__main__":
    main()
