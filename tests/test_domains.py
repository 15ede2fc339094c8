#!/usr/bin/python3
"""Domain decomposition: a run on N ranks writes the serial run's outputs (run by ctest, label mpi).

    test_domains.py STIFFMD MPIEXEC NUMPROC_FLAG N CASE

CASE is one of
    kremer_grest              inputs/kremer_grest.toml (32 000 beads, velocity Verlet, Langevin)
    kremer_grest:threads      the same at 2 threads per rank, against one process at 2 threads: to
                              round-off (1e-10), not bit for bit (the pair loop's thread buffers
                              add up in another order on another particle set)
    stiff_melt:METHOD         inputs/stiff_melt_nvt.toml (3 000 beads, eps = 1e-3, Langevin) with
                              integrator.method = METHOD (every method of integrators/methods.hpp)
    stiff_melt:METHOD:csvr    the same under the csvr thermostat instead of Langevin
    stiff_melt_npt:METHOD     inputs/stiff_melt_npt.toml (1 000 beads, the C-rescale barostat every 10
                              steps): the box moves, the domains follow it, and the trajectory and the
                              box of every frame are the serial run's bit for bit
    straddle                  inputs/domain_straddle.toml (chains crossing every domain face)
    migrate                   the same, a field driving the chains across the domains: molecules migrate
    migrate_fast              the same field four times stronger (molecules migrate within 50 steps)
    melt_halo_once            inputs/melt_halo_once.toml: a built Kremer–Grest melt whose deck sets
                              halo_pairs = "once" (as CASE:once)
    CASE:once                 any of these with [parallel] halo_pairs = "once" (each pair of a home bead and
                              a halo bead computed on one rank, the halo's forces sent back): to round-off
                              (1e-10), not bit for bit
    built_melt                tests/decks/melt_million.toml at 40 chains (4 000 beads, the engine's
                              builder, no [prepare]): no rank lists the pairs of the whole system
    chains_by_parts           tests/decks/chains_by_parts.toml: chains built by molecule, velocities by
                              particle; on several ranks each starts from its own molecules made by
                              the builder (summary.json domains.setup = "parts", engine/domain/part_load.hpp)
    minimize_by_parts         inputs/melt_minimize_by_parts.toml: overlapping chains built by molecule,
                              [minimize] (FIRE, max_force) on the parts after the start, velocity Verlet
                              and Langevin: the serial run's bits, domains.setup = "parts"
    minimize_by_parts:cg      the same minimised by conjugate gradient (its line searches on the parts)
    trappe                    inputs/trappe_pe.toml: real units, angles, dihedrals, r-RESPA levels
    trappe:scaled             the same with special_bonds [0, 0.5, 0.5]: the scaled 1-3 and 1-4 pairs
    trappe:charged            the same with charges (CH3 +0.22, CH2 −0.02) and lj/cut/coul/debye (κ = 0.1/Å,
                              special_coul [0, 0.3, 0.6]): the charges follow the beads onto the pair sets
    water                     inputs/spce_water.toml: charges, lj/cut/coul/long and PPPM (the reciprocal
                              sum over every rank's charges: the mesh distributed over the ranks, each
                              plane the ranks' charges added up, the FFTs in slabs, so to round-off
                              (1e-10), not bit for bit), rigid water triangles, 50 steps
    polyelectrolyte           inputs/polyelectrolyte.toml: charged chains and counterions, lj/cut/coul/long
                              and PPPM on the macro step of the projected impulse, stiff bonds (to
                              round-off, as water), 200 macro steps
    charged_pppm              tests/decks/charged_chains_pppm.toml: charged chains built by molecule,
                              coul/long and PPPM; the parameters chosen from the scene's description
                              (the counted beads' charge sums), no rank loads the whole scene
                              (domains.scene = "description"), to round-off as water (the mesh sums)
    charged_ewald             the same with the exact Ewald sum (the ranks' structure factors summed)
    one_chain                 inputs/hanging_chain.toml: one molecule (a pinned chain, a tether), ranks
                              without a particle
    pinned_cores              tests/decks/pinned_cores.toml, the effective dynamics: molecules whose pinned
                              core joins two stiff arms that are two constraint clusters, listed apart in
                              the clusters' order (each rank's actions are those of its own modes)
    half_melt                 inputs/half_melt.toml: a melt filling half the box beside vacuum, the domains
                              recut (the load balance, on by default); on 4 ranks summary.json's home
                              beads max/mean must be > 1.5 on the equal slabs and <= 1.1 after
    bad_grid                  a [parallel] grid of N + 1 domains on N ranks: refused (exit 2)
    kill                      the Kremer–Grest melt on N ranks writing an H5MD frame every 20 steps,
                              every rank killed (SIGKILL) mid-run: the file opens as a one-process
                              writer's killed file does, its complete frames (len(position/step))
                              the serial run's bit for bit
    restart:A:B               the straddle deck: 100 steps on A ranks, then --restart on B ranks to
                              step 200 into the same folder (N is not used; ctest passes max(A, B))
    restart_water:A:B         the same on inputs/spce_water.toml (PPPM), 25 + 25 steps, to round-off
    restart_npt:A:B           the same on inputs/stiff_melt_npt.toml (fixman): the barostat's box in
                              the checkpoint
    restart_half_melt:A:B     the same on inputs/half_melt.toml: the domains recut on A ranks and again
                              on B (the cuts are not in the checkpoint; the trajectory does not depend
                              on them)
    restart_parts:A:B         tests/decks/chains_by_parts.toml (by-molecule chains, Langevin): 20 steps on
                              A ranks, then --restart on B ranks by parts (each rank reads its rows of
                              the checkpoint; summary.json domains.setup "parts") to step 40: thermo.csv
                              the bytes of the uninterrupted run on A ranks; a checkpoint with one byte
                              flipped is refused with one line, exit 2
    restart_prepare:A:B       the same on inputs/stiff_melt_by_parts.toml under fixman: the parts
                              prepared ([prepare], [minimize]) and projected on A ranks, restarted on B

Each case runs the serial reference, `STIFFMD run DECK -o REF` (no launcher), and
`MPIEXEC NUMPROC_FLAG N STIFFMD run DECK -o OUT`, both with OMP_NUM_THREADS=1 (another thread count
sums the pair forces in another order), `-q --no-progress`, and the overrides of `overrides()`: 200
macro steps (run.t_end = 200 h, h given explicitly), an H5MD file with velocities and forces every
50 steps (frames 0, 50, 100, 150, 200), thermo every 10 steps, no XYZ. Open MPI as root and with more ranks
than cores wants permission: given by its environment variables (OMPI_ALLOW_RUN_AS_ROOT,
OMPI_MCA_rmaps_base_oversubscribe), which MPICH's launcher ignores where it would reject
--allow-run-as-root --oversubscribe.

Then the N-rank outputs must be the serial ones to round-off:
  - trajectory.h5md: the same datasets (paths, shapes, dtypes) and attributes, valid H5MD
    (tests/h5md_spec.py); steps and the static datasets (id, species, mass, bonds, box) equal;
    unwrapped positions (position + image·L, so that a bead wrapped across a face by round-off does
    not count), velocities and forces of every frame, matched by particle id, within 1e-10 of the
    serial file's largest |value|; the observables as the thermo columns below; written by every
    rank (summary.json domains.h5md_writers = N) when `STIFFMD --version` says the build can
    (parallel HDF5), else by rank 0;
  - thermo.csv: the same header and rows (steps), every column within 1e-10 of its scale
    (`column_scale`);
  - summary.json: method, steps, force evaluations equal; energies to the same tolerance;
  - MDAnalysis opens the N-rank H5MD with the N-rank run's topology.data: the serial topology
    (molecules, masses, bonds), the serial number of frames and the serial positions (float32).
The straddle deck's claim is checked on the serial run: every plane where 1–4 ranks put a domain
face (the periodic faces, the mid-planes and the thirds of each axis) is crossed by chains in every
frame, and chains' anchors (wrapped centres of mass) change domain during the run.

And more: at one thread per rank the trajectory is the serial one bit for bit (docs/parallel.md),
so the H5MD position, image, velocity and force datasets of every frame must be equal to the last
bit.
The thermo columns stay at 1e-10: each rank sums its part's energies (a pair with a ghost counted
half), virials and the integrator's own sums, and the ranks' sums are added up, in another order
than one process sums them.

A failure prints every deviation over the tolerance with the largest (frame, particle id and axis;
column and step) and exits 1.
"""
import csv
import filecmp
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time

import h5py
import numpy as np
from h5md_spec import h5md_problems

ROOT = os.path.normpath(os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))
TOL = 1e-10
STEPS = 200
THREADS = 1  # per rank and of the serial run (kremer_grest:threads: 2)
BITWISE = True  # the trajectory the serial one bit for bit (not with threads, nor a k-space sum)
H5MD = "trajectory.h5md"
P = "particles/all"
SKIP = 77  # ctest: skipped (the Kremer–Grest data file not installed)

STIFF_MELT = os.path.join(ROOT, "inputs", "stiff_melt_nvt.toml")
STIFF_BY_PARTS = os.path.join(ROOT, "inputs", "stiff_melt_by_parts.toml")
# The stiff melt's step by method at eps = 1e-3 (bond period ≈ 0.004): the rigid limits take the
# deck's h = 0.02; the impulse family h = 0.005 with 20 micro steps of 2.5e-4 (16 per bond period);
# velocity Verlet resolves the bonds, h = eps/2.
MACRO = {"integrator.h": 0.005, "integrator.micro_steps": 20}
STIFF_MELT_STEPS = {
    "fixman": {"integrator.h": 0.02},
    "rattle": {"integrator.h": 0.02},
    "effective": {"integrator.h": 0.02},
    "impulse": MACRO,
    "projected-impulse": MACRO,
    "mollified-impulse": MACRO,
    "velocity-verlet": {"integrator.h": 0.0005},
}
CSVR = '{ style = "csvr", temperature = 1.0, tau = 0.5, seed = 14 }'
STRADDLE = os.path.join(ROOT, "inputs", "domain_straddle.toml")
STIFF_MELT_NPT = os.path.join(ROOT, "inputs", "stiff_melt_npt.toml")
HALF_MELT = os.path.join(ROOT, "inputs", "half_melt.toml")
MELT_MILLION = os.path.join(ROOT, "tests", "decks", "melt_million.toml")


class Skip(Exception):
    pass


class Deviations:
    """The comparisons over tolerance, each with its worst place; `ok` when there are none."""

    def __init__(self):
        self.failures = []
        self.largest = (0.0, "nothing")  # the largest |Δ| / scale seen, and of what
        self.last = 0.0  # |Δ| / scale of the last `close`
        self.growth = []  # lines: |Δ| / scale frame by frame, to tell round-off grown by chaos from a bug

    def fail(self, what):
        self.failures.append(what)

    def close(self, what, ref, got, scale, where):
        """|got - ref| <= TOL * scale everywhere (scale 0: exactly equal); `where(index)` names the
        place of the largest deviation."""
        ref, got = np.atleast_1d(np.asarray(ref, dtype=float)), np.atleast_1d(np.asarray(got, dtype=float))
        if ref.shape != got.shape:
            self.fail(f"{what}: shape {got.shape}, serial {ref.shape}")
            return
        if ref.size == 0:
            return
        d = np.abs(got - ref)
        d[np.isnan(ref) & np.isnan(got)] = 0.0
        d[np.isnan(d)] = np.inf
        worst = np.unravel_index(np.argmax(d), d.shape)
        rel = d[worst] / scale if scale > 0 else (0.0 if d[worst] == 0 else np.inf)
        self.last = rel
        if rel > self.largest[0]:
            self.largest = (rel, f"{what} at {where(worst)}")
        if rel > TOL:
            self.fail(f"{what}: max |Δ| = {d[worst]:.3e} = {rel:.3e} × scale {scale:.6g} at {where(worst)} "
                      f"(serial {ref[worst]!r}, N ranks {got[worst]!r})")

    def equal(self, what, ref, got):
        if isinstance(ref, np.ndarray) or isinstance(got, np.ndarray):
            ref, got = np.asarray(ref), np.asarray(got)
            if ref.shape != got.shape:
                self.fail(f"{what}: shape {got.shape} on N ranks, serial {ref.shape}")
            elif not np.array_equal(ref, got):
                first = tuple(int(i) for i in np.argwhere(ref != got)[0]) if ref.ndim else ()
                self.fail(f"{what}: first difference at index {first}: {short(got[first])} on N ranks, "
                          f"serial {short(ref[first])}")
        elif ref != got:
            self.fail(f"{what}: {short(got)} on N ranks, serial {short(ref)}")


def short(value):
    s = repr(value)
    return s if len(s) < 200 else s[:200] + "…"


# ---------------------------------------------------------------- running

def environment():
    return dict(os.environ, OMP_NUM_THREADS=str(THREADS), OMPI_ALLOW_RUN_AS_ROOT="1", OMPI_ALLOW_RUN_AS_ROOT_CONFIRM="1",
                OMPI_MCA_rmaps_base_oversubscribe="1")


def number(x):
    return f"{x:.15g}"


def overrides(h, steps, extra):
    """--set arguments: `steps` macro steps of h, H5MD with velocities every 50 steps, thermo every
    10, no XYZ (not compared; the Kremer–Grest melt's would dominate the time)."""
    sets = dict(extra)
    sets.update({"integrator.h": number(h), "run.t_end": number(steps * h), "output.xyz": '""',
                 "output.h5md": f'"{H5MD}"', "output.h5md_interval": number(50 * h),
                 "output.h5md_velocity": "true", "output.h5md_force": "true",
                 "output.thermo_interval": number(10 * h)})
    args = []
    for key, value in sets.items():
        args += ["--set", f"{key}={value}"]
    return args


def run(cmd, ranks, extra_env=None):
    """Runs cmd (OMP_NUM_THREADS=1, Open MPI's permissions, and extra_env)."""
    print("$ " + " ".join(cmd), flush=True)
    start = time.monotonic()
    r = subprocess.run(cmd, capture_output=True, text=True, timeout=600, env=dict(environment(), **(extra_env or {})))
    seconds = time.monotonic() - start
    if r.returncode != 0:
        sys.stderr.write(r.stdout[-3000:] + r.stderr[-3000:])
        raise SystemExit(f"FAIL: exit {r.returncode} from: {' '.join(cmd)}")
    print(f"  {seconds:.2f} s", flush=True)
    return r


def launch(mpiexec, numproc_flag, ranks, stiffmd):
    return [mpiexec, numproc_flag, str(ranks), stiffmd]


def check_domain_summary(stiffmd, out, ranks):
    """A build with parallel HDF5 has every rank write its particles' rows of the one H5MD file
    (docs/parallel.md); without it rank 0 writes the whole file. And the timing by phase has its
    mean and max over the ranks."""
    if ranks == 1:
        return
    version = subprocess.run([stiffmd, "--version"], capture_output=True, text=True).stdout
    expected = ranks if "H5MD written by every rank: yes" in version else 1
    with open(os.path.join(out, "summary.json")) as f:
        summary = json.load(f)
    writers = summary["domains"]["h5md_writers"]
    if writers != expected:
        raise SystemExit(f"FAIL: the H5MD file was written by {writers} ranks, expected {expected} ({version.strip()})")
    print(f"H5MD written by {writers} of {ranks} ranks")
    # The ranks rebuild their neighbour lists together (one rebuilding alone keeps the others
    # waiting): every rank the same number of times.
    d = summary["domains"]
    if d["neighbor_rebuilds_min"] != d["neighbor_rebuilds_max"]:
        raise SystemExit(f"FAIL: the ranks rebuilt their neighbour lists {d['neighbor_rebuilds_min']} to "
                         f"{d['neighbor_rebuilds_max']} times: not together")
    # Each rank's peak resident set, its max and mean over the ranks; rank 0's is one of them.
    rss, rss_max, rss_mean = summary["peak_rss_mib"], d["peak_rss_mib_max"], d["peak_rss_mib_mean"]
    if not (0 < rss <= rss_max and 0 < rss_mean <= rss_max):
        raise SystemExit(f"FAIL: peak_rss_mib {rss}, domains.peak_rss_mib_max {rss_max}, _mean {rss_mean}: "
                         f"expected 0 < rank 0's <= max and 0 < mean <= max")
    # The time each rank's step loop spent inside MPI's exchanges and reductions (waits for the
    # other ranks included): measured (every step of a decomposed run has a reduction), part of the
    # loop, and each max at least its mean.
    loop = d["rank_loop_seconds_max"]
    for kind in ("exchange", "reduction"):
        mean, most = d[f"{kind}_seconds_mean"], d[f"{kind}_seconds_max"]
        if not (0 <= mean <= most <= loop):
            raise SystemExit(f"FAIL: {kind}_seconds mean {mean}, max {most} against the loop's {loop}: "
                             "expected 0 <= mean <= max <= loop")
    if summary["steps"] > 0 and d["reduction_seconds_max"] <= 0:
        raise SystemExit(f"FAIL: {summary['steps']} steps on {ranks} ranks spent no time in a reduction")
    # What a rank's pair forces hold is its part's (docs/parallel.md, "What a rank holds"): no rank
    # keeps a neighbour list of the whole system (one that [prepare] relaxed with, or a restart's
    # checkpoint restored, is dropped once the parts exist), unless rank 0 samples the gathered state
    # (the actions, a barostat's molecular pressure: the thermo row of the whole state).
    with open(os.path.join(out, "thermo.csv")) as f:
        header = f.readline()
    whole_sample = "action_1" in header or "molecular_pressure" in header
    if not whole_sample and d["whole_list_pairs_max"] != 0:
        raise SystemExit(f"FAIL: a rank listed {d['whole_list_pairs_max']} pairs of the whole system's particles: "
                         "its pair forces hold the whole system, not its part")
    print(f"largest pair set {d['pair_set_max']} of {d['particles']} particles; "
          f"whole-system list pairs {d['whole_list_pairs_max']}{' (rank 0 samples the whole state)' if whole_sample else ''}")
    # The timing by phase (systems timed by parts) comes with its mean and max over the ranks.
    if summary["timing"]:
        mean, most = summary["domains"].get("timing_mean"), summary["domains"].get("timing_max")
        if mean is None or most is None or set(mean) != set(summary["timing"]) or set(most) != set(mean) or \
                any(most[k] < mean[k] or most[k] < 0 for k in mean):
            raise SystemExit(f"FAIL: domains.timing_mean/timing_max missing or not max >= mean >= 0 per phase: "
                             f"{mean}, {most} (timing {summary['timing']})")


def case_setup(case):
    """(deck, h, extra --set) of a non-restart case."""
    parts = case.split(":")
    if case in ("kremer_grest", "kremer_grest:threads"):
        data = "/usr/share/lammps/examples/COUPLE/multiple/data.chain"
        if not os.path.exists(data):
            raise Skip(f"{data} not installed (Debian package lammps-examples)")
        return os.path.join(ROOT, "inputs", "kremer_grest.toml"), 0.012, {}
    if parts[0] == "stiff_melt" and len(parts) in (2, 3) and parts[1] in STIFF_MELT_STEPS:
        steps = dict(STIFF_MELT_STEPS[parts[1]])
        h = steps.pop("integrator.h")
        extra = {"integrator.method": parts[1], **{k: str(v) for k, v in steps.items()}}
        if len(parts) == 3:
            if parts[2] != "csvr":
                raise SystemExit(f"unknown thermostat {parts[2]!r} in {case!r} (csvr; Langevin is the deck's)")
            extra["thermostat"] = CSVR
        return STIFF_MELT, h, extra
    if parts[0] == "stiff_melt_npt" and len(parts) == 2 and parts[1] in STIFF_MELT_STEPS:
        steps = dict(STIFF_MELT_STEPS[parts[1]])
        h = steps.pop("integrator.h")
        return STIFF_MELT_NPT, h, {"integrator.method": parts[1], **{k: str(v) for k, v in steps.items()}}
    if case == "straddle":
        return STRADDLE, 0.02, {}
    if case == "built_melt":  # the engine's builder and no [prepare]: no rank lists the whole system's pairs
        return MELT_MILLION, 0.002, {"build.0.chains": "40"}
    if case == "chains_by_parts":  # each rank builds its own molecules: the start from the source's parts
        return os.path.join(ROOT, "tests", "decks", "chains_by_parts.toml"), 0.005, {"observables.histograms": "true"}
    if case == "minimize_by_parts":  # each rank builds its own molecules, FIRE relaxes them on the parts
        return os.path.join(ROOT, "inputs", "melt_minimize_by_parts.toml"), 0.005, {}
    if case == "minimize_by_parts:cg":  # the same by conjugate gradient
        return os.path.join(ROOT, "inputs", "melt_minimize_by_parts.toml"), 0.005, {"minimize.style": '"cg"'}
    if case == "prepare_by_parts":  # each rank builds, prepares ([prepare], [minimize]) and runs its own molecules
        return STIFF_BY_PARTS, 0.005, {}
    if case == "prepare_by_parts:fixman":  # the same with a rigid method, which projects the parts at the start
        return STIFF_BY_PARTS, 0.02, {"integrator.method": '"fixman"', "prepare.vibrational_temperature": "0"}
    if case in ("charged_pppm", "charged_ewald"):  # k-space terms chosen from the description's charge sums
        return (os.path.join(ROOT, "tests", "decks", "charged_chains_pppm.toml"), 0.004,
                {"forces.mesh.style": '"' + case.split("_")[1] + '"'})
    if case == "half_melt":  # a melt beside vacuum: the domains recut
        return HALF_MELT, 0.01, {}
    if case == "trappe":  # real units (fs, Å, kcal/mol), angles and dihedrals, r-RESPA levels
        return os.path.join(ROOT, "inputs", "trappe_pe.toml"), 4.0, {}
    if case == "trappe:scaled":  # 1-3 and 1-4 pairs at half weight: the scaled special pairs
        return os.path.join(ROOT, "inputs", "trappe_pe.toml"), 4.0, {"forces.lj.special_bonds": "[0.0, 0.5, 0.5]"}
    if case == "trappe:charged":  # charges that follow the beads: lj/cut/coul/debye, its own Coulomb weights
        return os.path.join(ROOT, "inputs", "trappe_pe.toml"), 4.0, {
            "types.CH3.charge": "0.22", "types.CH2.charge": "-0.02", "forces.lj.style": '"lj/cut/coul/debye"',
            "forces.lj.kappa": "0.1", "forces.lj.special_bonds": "[0.0, 0.5, 0.5]",
            "forces.lj.special_coul": "[0.0, 0.3, 0.6]"}
    if case == "water":  # charges, Ewald real space and the PPPM mesh distributed over the ranks; rigid triangles
        return os.path.join(ROOT, "inputs", "spce_water.toml"), 2.0, {}
    if case == "polyelectrolyte":  # PPPM with molecules of 32 beads that reach across domains
        return os.path.join(ROOT, "inputs", "polyelectrolyte.toml"), 0.01, {}
    if case == "one_chain":  # one molecule: every rank but one owns nothing
        return os.path.join(ROOT, "inputs", "hanging_chain.toml"), 0.01, {}
    if case == "pinned_cores":  # a pinned bead splits a molecule into two constraint clusters
        return os.path.join(ROOT, "tests", "decks", "pinned_cores.toml"), 0.02, {}
    if case == "migrate":  # a field drives the chains (Langevin: 3 σ per time unit along z) across the domains
        return STRADDLE, 0.02, {"forces.drift": '{ style = "gravity", g = [1.0, 1.0, 3.0] }'}
    if case == "melt_halo_once":  # the deck of the halo pairs once ([parallel] halo_pairs = "once" in it)
        return os.path.join(ROOT, "inputs", "melt_halo_once.toml"), 0.012, {}
    if case == "migrate_fast":  # the same four times faster: molecules migrate within 50 steps
        return STRADDLE, 0.02, {"forces.drift": '{ style = "gravity", g = [4.0, 4.0, 12.0] }'}
    raise SystemExit(f"unknown case {case!r}: kremer_grest[:threads], stiff_melt:METHOD[:csvr] (METHOD one of "
                     f"{', '.join(STIFF_MELT_STEPS)}), straddle, migrate, trappe[:scaled|:charged], water, polyelectrolyte, one_chain, pinned_cores, restart:A:B")


# ---------------------------------------------------------------- comparing

def read_thermo(path):
    with open(path) as f:
        rows = list(csv.reader(f))
    header, values = rows[0], np.array([[float(v) for v in r] for r in rows[1:]])
    return header, {name: values[:, k] for k, name in enumerate(header)}


def column_scale(name, columns, position_scale):
    """The scale a thermo column's round-off is measured against; None: must be equal exactly.

    time, step and the alert count are exact. Most columns (energies, temperature, pressure, Rg,
    end-to-end, actions) are sums over particles or molecules: their round-off is relative to their
    size, so the scale is the column's largest |value| over the serial run (for the pressure the
    kinetic and virial parts partly cancel, but both are of the pressure's size in these decks).
    Three columns are differences of larger numbers and carry those numbers' round-off:
    energy_drift = E(t) − E(0) and ecouple (the thermostat's heat, each step's a difference of
    kinetic energies), scaled by the total energy; max_violation = max | |x_i − x_j| − ℓ |,
    round-off of coordinates (for the rigid methods its value is all round-off, ~1e-12), scaled by
    the positions' scale; and potential_stiff under rigid constraints (all round-off, ~1e-21),
    scaled by the total energy."""
    base = name[:-len("_per_atom")] if name.endswith("_per_atom") else name
    if base in ("time", "step", "alerts"):
        return None
    if base in ("energy_drift", "ecouple"):
        return float(np.abs(columns[name.replace(base, "total")]).max())
    if base == "max_violation":
        return position_scale
    own = float(np.abs(columns[name]).max())
    # The stiff potential of rigid constraints (rattle) is ½(α/ε)² g² with g round-off: its value
    # is all round-off, measured against the total energy as energy_drift is.
    if base == "potential_stiff" and "total" in columns:
        return max(own, float(np.abs(columns["total"]).max()) if own < 1e-12 * float(np.abs(columns["total"]).max()) else own)
    return own


def compare_columns(dev, what, ref, got, position_scale, steps):
    for name, values in ref.items():
        scale = column_scale(name, ref, position_scale)
        if scale is None:
            dev.equal(f"{what} {name}", values, got[name])
        else:
            dev.close(f"{what} {name}", values, got[name], scale, lambda i, n=name: f"step {int(steps[i[0]])}")


def compare_thermo(dev, ref_dir, out_dir, position_scale):
    ref_header, ref = read_thermo(os.path.join(ref_dir, "thermo.csv"))
    header, got = read_thermo(os.path.join(out_dir, "thermo.csv"))
    if header != ref_header:
        dev.fail(f"thermo.csv header {header}, serial {ref_header}")
        return
    if not np.array_equal(ref["step"], got["step"]):
        dev.fail(f"thermo.csv rows at steps {got['step'].astype(int).tolist()}, serial {ref['step'].astype(int).tolist()}")
        return
    compare_columns(dev, "thermo.csv", ref, got, position_scale, ref["step"])


def objects(f):
    """Every object of the file by every path that names it (hard links included, unlike visititems)."""
    out = {}

    def walk(group, prefix):
        for name in group:
            link = group.get(name, getlink=True)
            if not isinstance(link, h5py.HardLink):
                continue
            obj = group[name]
            path = prefix + "/" + name
            out[path] = obj
            if isinstance(obj, h5py.Group):
                walk(obj, path)
    out["/"] = f
    walk(f, "")
    return out


def attribute(f, value):
    return f[value].name if isinstance(value, h5py.Reference) else value


def unwrapped(f, frame):
    x = f[P + "/position/value"][frame]
    if P + "/image" in f:
        x = x + f[P + "/image/value"][frame] * np.diag(f[P + "/box/edges/value"][frame])
    return x


def particle_ids(f, frame):
    ids = f[P + "/id"]
    return ids["value"][frame] if isinstance(ids, h5py.Group) else ids[()]


def by_id(f, frame, values):
    """values (per particle, in file order) ordered by particle id, and the sorted ids."""
    ids = particle_ids(f, frame)
    order = np.argsort(ids, kind="stable")
    return values[order], ids[order]


def compare_h5md(dev, ref_path, got_path):
    """The N-rank file against the serial one; returns the positions' scale (for max_violation)."""
    with h5py.File(ref_path, "r") as ref, h5py.File(got_path, "r") as got:
        for problem in h5md_problems(got):
            dev.fail(f"{got_path}: {problem}")
        frames = ref[P + "/position/value"].shape[0]
        position_scale = max(float(np.abs(unwrapped(ref, k)).max()) for k in range(frames))
        a, b = objects(ref), objects(got)
        if set(a) != set(b):
            dev.fail(f"H5MD objects: missing {sorted(set(a) - set(b))}, extra {sorted(set(b) - set(a))}")
        for path in sorted(set(a) & set(b)):
            oa, ob = a[path], b[path]
            dev.equal(f"H5MD {path}: attributes", sorted(oa.attrs), sorted(ob.attrs))
            for key in set(oa.attrs) & set(ob.attrs):
                dev.equal(f"H5MD {path}@{key}", np.asarray(attribute(ref, oa.attrs[key])),
                          np.asarray(attribute(got, ob.attrs[key])))
            if isinstance(oa, h5py.Dataset) and isinstance(ob, h5py.Dataset):
                dev.equal(f"H5MD {path}: shape", oa.shape, ob.shape)
                dev.equal(f"H5MD {path}: dtype", oa.dtype, ob.dtype)
        if dev.failures:  # the values of a file of another layout are not compared
            return position_scale
        steps = ref[P + "/position/step"][()]
        time_dependent = {p for p in a if p.endswith(("/step", "/time", "/value"))}
        # Static datasets (id, species, mass, box offset, bonds, VMD's structure): the same.
        for path in sorted(p for p in a if isinstance(a[p], h5py.Dataset) and p not in time_dependent):
            dev.equal(f"H5MD {path}", a[path][()], b[path][()])
        for path in sorted(p for p in time_dependent if p.endswith("/step")):
            dev.equal(f"H5MD {path}", a[path][()], b[path][()])
        dev.close("H5MD time", ref[P + "/position/time"][()], got[P + "/position/time"][()],
                  float(np.abs(ref[P + "/position/time"][()]).max()), lambda i: f"frame {i[0]}")
        if P + "/box/edges" in ref:
            dev.equal("H5MD box edges", ref[P + "/box/edges/value"][()], got[P + "/box/edges/value"][()])
        for element in ("position", "velocity", "force"):
            if P + "/" + element not in ref:
                continue
            series = [unwrapped(f, k) if element == "position" else f[P + f"/{element}/value"][k]
                      for f in (ref, got) for k in range(frames)]
            scale = max(float(np.abs(s).max()) for s in series[:frames])
            by_frame = []
            for k in range(frames):
                x_ref, ids = by_id(ref, k, series[k])
                x_got, ids_got = by_id(got, k, series[frames + k])
                dev.equal(f"H5MD particle ids (frame {k})", ids, ids_got)
                what = f"H5MD {element} (unwrapped)" if element == "position" else f"H5MD {element}"
                dev.close(f"{what}, frame {k} (step {steps[k]})", x_ref, x_got, scale,
                          lambda i, ids=ids: f"particle id {ids[i[0]]}, axis {'xyz'[i[1]]}")
                by_frame.append(f"{dev.last:.1e}")
            dev.growth.append(f"{element} max |Δ| / scale at steps {', '.join(str(k) for k in steps)}: "
                              f"{', '.join(by_frame)}")
        # Bit for bit at one thread per rank: the datasets as written (by particle id, the serial
        # file's order).
        for element in ("position", "image", "velocity", "force") if BITWISE else ():
            path = P + f"/{element}/value"
            if path in ref:
                dev.equal(f"H5MD {element} (bit for bit)", ref[path][()], got[path][()])
        observables = {name: ref[f"observables/{name}/value"][()] for name in ref.get("observables", {})}
        got_observables = {name: got[f"observables/{name}/value"][()] for name in observables}
        compare_columns(dev, "H5MD observable", observables, got_observables, position_scale, steps)
        return position_scale


def compare_summary(dev, ref_dir, out_dir, position_scale):
    """summary.json: what the run did equal, its energies to round-off (its times and the neighbour
    list's rebuild count, which depends on how the ranks share the skin test, are not compared)."""
    with open(os.path.join(ref_dir, "summary.json")) as f:
        ref = json.load(f)
    with open(os.path.join(out_dir, "summary.json")) as f:
        got = json.load(f)
    for key in ("method", "units", "h", "micro_steps", "epsilon", "steps", "t_end", "slow_evaluations",
                "fast_evaluations", "level_evaluations"):
        dev.equal(f"summary.json {key}", ref.get(key), got.get(key))
    energy = max(abs(ref["initial_energy"]), abs(ref["final_energy"]))
    for key in ("initial_energy", "final_energy", "max_energy_error"):
        dev.close(f"summary.json {key}", ref[key], got[key], energy, lambda i: "")
    dev.close("summary.json final_max_violation", ref["final_max_violation"], got["final_max_violation"],
              position_scale, lambda i: "")
    dev.close("summary.json actions", ref["initial_actions"] + ref["final_actions"],
              got["initial_actions"] + got["final_actions"],
              max([abs(v) for v in ref["initial_actions"] + ref["final_actions"]] + [0.0]), lambda i: f"action {i}")


def universe(directory):
    import MDAnalysis as mda
    return mda.Universe(os.path.join(directory, "topology.data"), os.path.join(directory, H5MD),
                        topology_format="DATA", atom_style="id resid type x y z", format="H5MD",
                        convert_units=False)


def compare_mdanalysis(dev, ref_dir, out_dir):
    """MDAnalysis reads the N-rank H5MD with the N-rank topology.data as it reads the serial run:
    the serial topology, frame count and positions (float32, wrapped: compared modulo the box)."""
    import warnings
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        serial, mine = universe(ref_dir), universe(out_dir)
    dev.equal("MDAnalysis molecules (resids)", serial.atoms.resids, mine.atoms.resids)
    dev.equal("MDAnalysis masses", serial.atoms.masses, mine.atoms.masses)
    dev.equal("MDAnalysis bonds", serial.bonds.indices, mine.bonds.indices)
    dev.equal("MDAnalysis frames", len(serial.trajectory), len(mine.trajectory))
    with h5py.File(os.path.join(ref_dir, H5MD), "r") as f:
        stored = f[P + "/position/value"][()]
    for ts in mine.trajectory[:len(stored)]:
        k = ts.frame
        lengths = ts.dimensions[:3] if ts.dimensions is not None else None
        d = ts.positions.astype(float) - stored[k]
        if lengths is not None:
            d -= lengths * np.round(d / lengths)  # a bead wrapped to the other face by round-off
        scale = max(1.0, float(np.abs(stored[k]).max()))
        worst = np.unravel_index(np.argmax(np.abs(d)), d.shape)
        if abs(d[worst]) > 1e-6 * scale:  # float32: 6e-8 relative
            dev.fail(f"MDAnalysis positions, frame {k}: |Δ| = {abs(d[worst]):.3e} at atom index {worst[0]} axis {'xyz'[worst[1]]}")
    serial.trajectory.close()
    mine.trajectory.close()


def compare_runs(ref_dir, out_dir, what):
    dev = Deviations()
    position_scale = compare_h5md(dev, os.path.join(ref_dir, H5MD), os.path.join(out_dir, H5MD))
    compare_thermo(dev, ref_dir, out_dir, position_scale)
    compare_summary(dev, ref_dir, out_dir, position_scale)
    compare_mdanalysis(dev, ref_dir, out_dir)
    if dev.failures:
        print(f"FAIL: {what} differs from the serial run ({len(dev.failures)} comparisons over {TOL:g} of "
              "their scale; the largest deviation of each):")
        for line in dev.failures[:40]:
            print("  " + line)
        for line in dev.growth:
            print("  " + line)
        sys.exit(1)
    print(f"{what}: positions, velocities, thermo, summary and H5MD layout equal the serial run's to "
          f"{TOL:g} (largest |Δ| / scale {dev.largest[0]:.2e}: {dev.largest[1]}); MDAnalysis reads the same frames")


# ---------------------------------------------------------------- the straddle deck's geometry

def check_straddle_geometry(ref_dir):
    """Every plane where 1–4 ranks put a domain face — the periodic face (0), the mid-plane (1/2)
    and the thirds (1/3, 2/3) of each axis — is crossed by chains in every frame of the serial run,
    and chains' anchors (wrapped centres of mass) cross one such plane during the run (migrate)."""
    import warnings
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        u = universe(ref_dir)
    molecules = u.atoms.resids
    u.trajectory.close()
    fractions = (0.0, 1 / 3, 1 / 2, 2 / 3)
    with h5py.File(os.path.join(ref_dir, H5MD), "r") as f:
        origin = f[P + "/box/offset"][()]
        frames = f[P + "/position/value"].shape[0]
        anchors, least = [], None
        for k in range(frames):
            lengths = np.diag(f[P + "/box/edges/value"][k])
            x = unwrapped(f, k)
            spans = np.array([[x[molecules == m].min(axis=0), x[molecules == m].max(axis=0)] for m in np.unique(molecules)])
            anchors.append((np.array([x[molecules == m].mean(axis=0) for m in np.unique(molecules)]) - origin) % lengths / lengths)
            for a in range(3):
                for frac in fractions:
                    plane = origin[a] + frac * lengths[a]
                    # an image of the plane, plane + j L, within [lo, hi]
                    crossing = int(np.sum(np.floor((spans[:, 1, a] - plane) / lengths[a]) >=
                                          np.ceil((spans[:, 0, a] - plane) / lengths[a])))
                    least = crossing if least is None else min(least, crossing)
                    assert crossing > 0, f"frame {k}: no chain crosses the plane {'xyz'[a]} = {frac:.3f} L"
    migrations = sum(int(np.sum(np.floor(anchors[k] * n) != np.floor(anchors[k + 1] * n)))
                     for n in (2, 3) for k in range(frames - 1))
    assert migrations > 0, "no chain's anchor crosses a mid-plane or a third of an axis between frames"
    print(f"straddle deck: every face, mid-plane and third of each axis crossed by at least {least} chains "
          f"in each of {frames} frames; {migrations} anchor crossings of those planes between frames")


# ---------------------------------------------------------------- cases

# The cases whose decks a source makes by parts (engine/domain/part_load.hpp, part_source): on
# several ranks each rank starts from its own molecules (summary.json domains.setup = "parts").
BY_PARTS = {"chains_by_parts": "the builder", "minimize_by_parts": "the builder, minimised by FIRE on the parts,",
            "minimize_by_parts:cg": "the builder, minimised by CG on the parts,",
            "prepare_by_parts": "the builder, prepared and minimised on the parts,",
            "prepare_by_parts:fixman": "the builder, prepared, minimised and projected on the parts,",
            "charged_pppm": "the builder", "charged_ewald": "the builder",
            "kremer_grest": "the data file read by blocks", "half_melt": "the data file read by blocks",
            "trappe": "the data file read by blocks", "trappe:scaled": "the data file read by blocks",
            "trappe:charged": "the data file read by blocks"}


# Of those, the decks whose scene every rank loads as its description only (summary.json
# domains.scene = "description"): the builder's by-molecule chains, with Ewald or PPPM too, with
# stiff bonds (prepared, minimised and projected on the parts), and
# the data files of kremer_grest and half_melt (counted by one streaming pass:
# engine/scene/scene.hpp). TraPPE's stiff-harmonic term reads every particle's mass: its deck
# loads whole.
DESCRIBED = ("chains_by_parts", "minimize_by_parts", "minimize_by_parts:cg", "prepare_by_parts", "prepare_by_parts:fixman", "charged_pppm",
             "charged_ewald", "kremer_grest", "half_melt")


def check_checkpoint_blocks(out, ranks):
    """The checkpoint the ranks wrote together, each its block of particles, is byte for byte the
    one-process writer's of the gathered state (engine/run/checkpoint.hpp)."""
    together = os.path.join(out, "checkpoint.bin")
    if ranks == 1:  # one process: the serial run, no second checkpoint
        return
    if not filecmp.cmp(together, together + ".gathered", shallow=False):
        raise SystemExit(f"FAIL: the checkpoint written by {ranks} ranks differs from one process's of the same state")
    print(f"checkpoint written by {ranks} ranks: the one-process writer's bytes ({os.path.getsize(together)} bytes)")


def plain_case(stiffmd, mpiexec, numproc_flag, n, case, tmp):
    global THREADS, BITWISE
    # [parallel] halo_pairs = "once" (a case's suffix, or the deck's own key): to round-off.
    once = case.endswith(":once") or case == "melt_halo_once"
    if case.endswith(":once"):
        case = case[:-len(":once")]
    THREADS = 2 if case.endswith(":threads") else 1
    BITWISE = THREADS == 1 and not once and case not in ("water", "polyelectrolyte", "charged_pppm", "charged_ewald")
    deck, h, extra = case_setup(case)
    if once:
        extra = {**extra, "parallel.halo_pairs": '"once"'}
    # At 2 threads the runs differ by round-off, which the melt's chaos grows (about 100× per 100
    # steps here, to 6e-11 of the scale by step 200): 100 steps keep it well inside TOL. Water's
    # mesh sums differ in their order on N ranks, and its chaos is faster: 50 steps.
    # The halo pairs once sum each force in another order from the first step: on the straddle's
    # stiff chains its round-off grows to 1e-10 of the forces' scale by step 100, so 50 steps.
    steps = STEPS // 4 if once or case == "water" else STEPS // 2 if THREADS > 1 else STEPS
    args = ["run", deck, "-q", "--no-progress"] + overrides(h, steps, extra)
    ref, out = os.path.join(tmp, "serial"), os.path.join(tmp, f"ranks_{n}")
    # The N-rank run first: while N > 1 is refused, a skipped case costs only the launcher's start.
    # STIFFMD_GATHERED_CHECKPOINT: rank 0 also writes the checkpoint as one process writes it, from
    # the gathered state, beside the one every rank wrote its block of.
    run(launch(mpiexec, numproc_flag, n, stiffmd) + args[:2] + ["-o", out] + args[2:], n,
        {"STIFFMD_GATHERED_CHECKPOINT": "1"})
    check_domain_summary(stiffmd, out, n)
    check_checkpoint_blocks(out, n)
    run([stiffmd] + args[:2] + ["-o", ref] + args[2:], 1)
    if case == "straddle":
        check_straddle_geometry(ref)
    if case in ("migrate", "migrate_fast") and n > 1:  # the case is there to move molecules between ranks
        with open(os.path.join(out, "summary.json")) as f:
            moved = json.load(f)["domains"]["migrated_molecules"]
        if moved == 0:
            raise SystemExit(f"FAIL: no molecule migrated on {n} ranks")
        print(f"{moved} molecules migrated")
    if case == "half_melt" and n == 4:
        check_balance(out)
    if case in BY_PARTS and n > 1:  # the run started from the source's parts
        with open(os.path.join(out, "summary.json")) as f:
            setup = json.load(f)["domains"]["setup"]
        if setup != "parts":
            raise SystemExit(f"FAIL: domains.setup = {setup!r} on {n} ranks: expected 'parts'")
        print(f"the parts made by {BY_PARTS[case]} on every rank")
        # The builder's decks and the data files without a term that reads every particle load
        # the scene's description only (no rank builds or reads the whole scene:
        # engine/scene/scene.hpp SceneContent::description); the others, the whole scene.
        with open(os.path.join(out, "summary.json")) as f:
            scene = json.load(f)["domains"]["scene"]
        expected = "description" if case in DESCRIBED else "whole"
        if scene != expected:
            raise SystemExit(f"FAIL: domains.scene = {scene!r} on {n} ranks: expected {expected!r}")
        print(f"every rank loaded the {'description' if scene == 'description' else 'whole scene'}")
    if once and n > 1:
        check_halo_pairs_once(ref, out)
    if os.path.exists(os.path.join(ref, "histograms.csv")):  # summed by parts on a description
        if BITWISE:
            if not filecmp.cmp(os.path.join(ref, "histograms.csv"), os.path.join(out, "histograms.csv"), shallow=False):
                raise SystemExit(f"FAIL: histograms.csv of {case} on {n} ranks differs from the serial run's")
            print("histograms.csv: the serial run's bytes")
        else:
            compare_histograms(os.path.join(ref, "histograms.csv"), os.path.join(out, "histograms.csv"))
    compare_runs(ref, out, f"{case} on {n} ranks")


def check_halo_pairs_once(ref, out):
    """The halo pairs once: summary.json says so, and the ranks' lists hold each pair once — their
    pairs summed within 1 % of one process's list (built at other times: a few pairs at the list
    radius come and go), where computing them on both homes lists 1.02-1.07 × (docs/parallel.md)."""
    with open(os.path.join(out, "summary.json")) as f:
        got = json.load(f)
    with open(os.path.join(ref, "summary.json")) as f:
        serial = json.load(f)
    if got["domains"].get("halo_pairs") != "once":
        raise SystemExit(f"FAIL: summary.json domains.halo_pairs = {got['domains'].get('halo_pairs')!r}: expected 'once'")
    ratio = got["neighbor_pairs"] / serial["neighbor_pairs"]
    if not 0.99 <= ratio <= 1.01:
        raise SystemExit(f"FAIL: the ranks list {got['neighbor_pairs']} pairs against one process's "
                         f"{serial['neighbor_pairs']} ({ratio:.4f} ×): each pair of the halo should be listed once")
    print(f"halo pairs once: the ranks list {ratio:.4f} × one process's pairs")


def compare_histograms(ref_path, got_path):
    """Histograms of runs that agree to round-off: the same quantities and bins, the bin edges (from
    the values' range) within TOL of their scale, each quantity's total count the same, and a count
    moved to a neighbouring bin at most once per quantity (a value within round-off of an edge)."""
    def rows(path):
        with open(path) as f:
            return list(csv.DictReader(f))
    ref, got = rows(ref_path), rows(got_path)
    if [r["quantity"] for r in ref] != [g["quantity"] for g in got]:
        raise SystemExit("FAIL: histograms.csv: other quantities or bins than the serial run's")
    moved = {}
    for r, g in zip(ref, got):
        q = r["quantity"]
        for edge in ("bin_low", "bin_high"):  # written to 10 significant digits: a last digit apart
            a, b = float(r[edge]), float(g[edge])
            if abs(a - b) > 1e-9 * max(1.0, abs(a)):
                raise SystemExit(f"FAIL: histograms.csv {q} {edge} {b} against the serial {a}")
        moved[q] = moved.get(q, 0) + abs(int(r["count"]) - int(g["count"]))
    for q in moved:
        total_ref = sum(int(r["count"]) for r in ref if r["quantity"] == q)
        total_got = sum(int(g["count"]) for g in got if g["quantity"] == q)
        if total_ref != total_got or moved[q] > 2:
            raise SystemExit(f"FAIL: histograms.csv {q}: {total_got} counts against the serial {total_ref}, "
                             f"{moved[q]} moved between bins (at most one count moved: 2)")
    print(f"histograms.csv: the serial run's to round-off ({sum(moved.values()) // 2} counts moved a bin)")


def check_balance(out):
    """The load balance's target (docs/parallel.md, "Load balance"): the melt beside vacuum on 4 ranks,
    2 x 1 x 2 domains, is more than 1.5 home beads max/mean on equal slabs (1.69) and <= 1.1 on the
    recut ones at the end of the run."""
    with open(os.path.join(out, "summary.json")) as f:
        d = json.load(f)["domains"]
    before, after, recuts, cuts = d["imbalance_before"], d["imbalance_after"], d["recuts"], d["cuts"]
    if not (before > 1.5 and after <= 1.1 and recuts >= 1):
        raise SystemExit(f"FAIL: home beads max/mean {before} on equal slabs, {after} at the end after {recuts} "
                         f"recuts: expected > 1.5, <= 1.1 and a recut")
    if d["grid"] != [2, 1, 2] or len(cuts[0]) != 3 or not 0.1 < cuts[0][1] < 0.5:
        raise SystemExit(f"FAIL: grid {d['grid']}, cuts {cuts}: expected 2 x 1 x 2 with the x cut inside the melt "
                         f"(x < 0.5 of the box)")
    print(f"load balance: home beads max/mean {before:.3f} on equal slabs, {after:.3f} at the end "
          f"({recuts} recuts, x cut at {cuts[0][1]:.3f} of the box)")


def bad_grid_case(stiffmd, mpiexec, numproc_flag, n, tmp):
    """A [parallel] grid of another number of domains than ranks: exit 2, one line naming the key,
    no output directory."""
    out = os.path.join(tmp, "bad_grid")
    deck = os.path.join(ROOT, "inputs", "domain_straddle.toml")
    cmd = launch(mpiexec, numproc_flag, n, stiffmd) + ["run", deck, "-o", out, "-q", "--no-progress",
                                                        "--set", f"parallel.grid=[{n + 1}, 1, 1]"]
    r = subprocess.run(cmd, capture_output=True, text=True, timeout=300, env=environment())
    errors = [line for line in r.stderr.splitlines() if line.startswith("error")]
    if r.returncode != 2 or len(errors) != 1 or "parallel.grid" not in errors[0] or os.path.exists(out):
        raise SystemExit(f"FAIL: expected exit 2, one error line naming parallel.grid and no {out}; got exit "
                         f"{r.returncode}, stderr:\n{r.stderr}")
    print(errors[0])


OVERLAP = os.path.join(ROOT, "tests", "decks", "overlapping_chains_by_parts.toml")
# The deck's variants: chains whose random walks overlap; trimers whose only close pairs are
# their bonds, of special weight 0 (accepted) or 1 (refused).
OVERLAP_VARIANTS = {
    "overlapping": [],
    "bonds excluded": ["--set", "build.0.bond_length=0.45", "--set", "build.0.density=0.01", "--set", "build.0.beads=3",
                       "--set", "forces.lj.special_bonds=[0.0, 0.0, 1.0]"],
    "bonds counted": ["--set", "build.0.bond_length=0.45", "--set", "build.0.density=0.01", "--set", "build.0.beads=3",
                      "--set", "forces.lj.special_bonds=[1.0, 0.0, 1.0]"],
}


def overlap_case(stiffmd, mpiexec, numproc_flag, n, tmp):
    """Chains built by molecule that overlap at the start, with no [minimize]: one process refuses
    them from the whole scene (load_scene), n ranks from the description's parts at the start
    (engine/domain/part_overlaps.hpp) — the same exit code and the same one error line (the
    closest pair, the count of overlapping pairs), and no output directory; pairs of special
    weight 0 are not counted."""
    for name, extra in OVERLAP_VARIANTS.items():
        outcomes = []
        for ranks in (1, n):
            out = os.path.join(tmp, f"overlap_{ranks}_{len(outcomes)}_{name.replace(' ', '_')}")
            cmd = ([stiffmd] if ranks == 1 else launch(mpiexec, numproc_flag, ranks, stiffmd)) + \
                ["run", OVERLAP, "-o", out, "-q", "--no-progress"] + extra
            r = subprocess.run(cmd, capture_output=True, text=True, timeout=300, env=environment())
            errors = [line for line in r.stderr.splitlines() if line.startswith("error")]
            if ranks > 1 and r.returncode == 0:
                with open(os.path.join(out, "summary.json")) as f:
                    scene = json.load(f)["domains"]["scene"]
                if scene != "description":
                    raise SystemExit(f"FAIL: {name}: the run on {ranks} ranks loaded the {scene} scene, not its description")
            if r.returncode == 2 and (len(errors) != 1 or os.path.exists(out)):
                raise SystemExit(f"FAIL: {name} on {ranks} ranks: exit 2 with {len(errors)} error lines "
                                 f"(expected one) or an output directory; stderr:\n{r.stderr}")
            outcomes.append((r.returncode, errors))
            print(f"{name}, {ranks} rank(s): exit {r.returncode} {errors[0][:160] if errors else ''}")
        expected = 0 if name == "bonds excluded" else 2
        if outcomes[0][0] != expected or outcomes[0] != outcomes[1]:
            raise SystemExit(f"FAIL: {name}: expected exit {expected} alike on 1 and {n} ranks, got {outcomes}")


def xyz_case(stiffmd, mpiexec, numproc_flag, n, tmp):
    """The stiff melt's XYZ trajectory with velocities, which rank 0 writes block by block of 1 024
    global indices as the ranks send their rows (3 000 beads: three blocks, each with rows of every
    rank): byte for byte the serial run's. The state CSV, whose rows hold every particle, is refused
    on several ranks: exit 2, one error line naming output.state and saying to use output.h5md."""
    sets = ["--set", "integrator.h=0.02", "--set", "run.t_end=0.4", "--set", 'output.xyz="trajectory.xyz"',
            "--set", "output.xyz_interval=0.1", "--set", "output.xyz_velocities=true", "--set", 'output.h5md=""']
    base = ["run", STIFF_MELT, "-q", "--no-progress"]
    ref, out = os.path.join(tmp, "serial"), os.path.join(tmp, f"ranks_{n}")
    run(launch(mpiexec, numproc_flag, n, stiffmd) + base[:2] + ["-o", out] + base[2:] + sets, n)
    run([stiffmd] + base[:2] + ["-o", ref] + base[2:] + sets, 1)
    got, want = os.path.join(out, "trajectory.xyz"), os.path.join(ref, "trajectory.xyz")
    if not filecmp.cmp(got, want, shallow=False):
        raise SystemExit(f"FAIL: the XYZ file written on {n} ranks differs from the serial run's")
    print(f"XYZ on {n} ranks: the serial run's bytes ({os.path.getsize(got)} bytes, 5 frames)")
    refused = os.path.join(tmp, "refused")
    cmd = launch(mpiexec, numproc_flag, n, stiffmd) + base[:2] + ["-o", refused] + base[2:] + sets + [
        "--set", 'output.state="state.csv"']
    r = subprocess.run(cmd, capture_output=True, text=True, timeout=300, env=environment())
    errors = [line for line in r.stderr.splitlines() if line.startswith("error")]
    if (r.returncode != 2 or len(errors) != 1 or "output.state" not in errors[0] or "output.h5md" not in errors[0]
            or os.path.exists(refused)):
        raise SystemExit(f"FAIL: expected exit 2, one error line naming output.state and output.h5md, no {refused}; "
                         f"got exit {r.returncode}, stderr:\n{r.stderr}")
    print(errors[0])


def kill_case(stiffmd, mpiexec, numproc_flag, n, tmp):
    """The Kremer–Grest melt, a frame every 20 steps (so that the kill lands between frames, as a
    one-process writer's kill test does: a kill inside an HDF5 flush may leave the newest frames
    unreadable until a restart repairs them, README "Outputs")."""
    deck, h, _ = case_setup("kremer_grest")
    out, ref = os.path.join(tmp, f"killed_{n}"), os.path.join(tmp, "serial")
    every = 20
    frames = ["--set", f"output.h5md=\"{H5MD}\"", "--set", f"output.h5md_interval={number(every * h)}",
              "--set", "output.h5md_velocity=true", "--set", f"integrator.h={number(h)}",
              "--set", "output.xyz=\"\"", "--set", "output.checkpoint_interval=0"]
    cmd = launch(mpiexec, numproc_flag, n, stiffmd) + ["run", deck, "-o", out, "-q", "--no-progress",
                                                       "--set", f"run.t_end={number(100000 * h)}"] + frames
    print("$ " + " ".join(cmd), flush=True)
    job = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, env=environment())
    path = os.path.join(out, H5MD)
    deadline = time.monotonic() + 120
    while not os.path.exists(path) or os.path.getsize(path) < 8 << 20:  # 4 frames of 1.9 MB
        if job.poll() is not None or time.monotonic() > deadline:
            job.kill()
            raise SystemExit(f"FAIL: the run ended or wrote no 4 MB of {path} in time: {job.communicate()[1][-2000:]}")
        time.sleep(0.05)
    subprocess.run(["pkill", "-KILL", "-f", out])  # every rank (and the launcher): their command lines name out
    job.wait(timeout=60)
    # As a one-process writer's killed file (README "Outputs", tests/test_h5md.py): position/step
    # no longer than position/value, and that no longer than any other series; every series reads
    # up to the length of position/step.
    with h5py.File(path, "r") as f:
        values = {path: o for path, o in objects(f).items() if isinstance(o, h5py.Dataset) and path.endswith("/value")}
        steps = f[P + "/position/step"][()]
        kept = len(steps)
        position_frames = f[P + "/position/value"].shape[0]
        others = [o.shape[0] for path, o in values.items() if path != "/" + P + "/position/value"]
        if kept < 2 or not kept <= position_frames <= min(others):
            raise SystemExit(f"FAIL: after the kill {kept} steps, {position_frames} position frames, the other "
                             f"series {others}")
        for o in values.values():
            o[:kept]
        got = (f[P + "/position/value"][:kept], f[P + "/velocity/value"][:kept], steps)
    # The same frames from one process, run to the last complete frame's step.
    run([stiffmd, "run", deck, "-o", ref, "-q", "--no-progress", "--set",
         f"run.t_end={number(int(got[2][-1]) * h)}"] + frames, 1)
    with h5py.File(os.path.join(ref, H5MD), "r") as f:
        want = (f[P + "/position/value"][:kept], f[P + "/velocity/value"][:kept], f[P + "/position/step"][()])
    if not np.array_equal(got[2], want[2]) or not np.array_equal(got[0], want[0]) or not np.array_equal(got[1], want[1]):
        raise SystemExit(f"FAIL: the {kept} complete frames of the killed {n}-rank file differ from the serial run's")
    print(f"killed on {n} ranks after {kept} complete frames: they read as the serial run's, bit for bit")


def restart_case(stiffmd, mpiexec, numproc_flag, first, second, tmp, deck=STRADDLE, h=0.02, steps=STEPS):
    """steps/2 on `first` ranks, continued from its checkpoint on `second` ranks to `steps` into the
    same folder: the files of the uninterrupted serial run."""
    ref, out = os.path.join(tmp, "serial"), os.path.join(tmp, f"ranks_{first}_then_{second}")
    base = ["run", deck, "-q", "--no-progress"]
    run(launch(mpiexec, numproc_flag, first, stiffmd) + base[:2] + ["-o", out] + base[2:] +
        overrides(h, steps // 2, {}), first)
    r = run(launch(mpiexec, numproc_flag, second, stiffmd) + base[:2] + ["-o", out, "--restart",
            os.path.join(out, "checkpoint.bin")] + base[2:] + overrides(h, steps, {}), second)
    # A fresh run to the end would also give the serial files: the second run must have continued.
    if f"at step {steps // 2} " not in r.stderr:
        raise SystemExit(f"FAIL: the run on {second} ranks did not say it continued at step {steps // 2}:\n{r.stderr}")
    check_domain_summary(stiffmd, out, second)
    run([stiffmd] + base[:2] + ["-o", ref] + base[2:] + overrides(h, steps, {}), 1)
    compare_runs(ref, out, f"{os.path.basename(deck)} on {first} ranks, restarted on {second}")


def restart_parts_case(stiffmd, mpiexec, numproc_flag, first, second, tmp, deck=None, extra=()):
    """docs/parallel.md, "A restart by parts": the restart of a deck made by parts reads its
    checkpoint by parts and continues the run bit for bit (thermo.csv's bytes)."""
    deck = deck or os.path.join(ROOT, "tests", "decks", "chains_by_parts.toml")
    sets = ["--set", "output.checkpoint_interval=0.05", "--set", "output.thermo_interval=0.01"] + list(extra)
    ref, out = os.path.join(tmp, "uninterrupted"), os.path.join(tmp, f"ranks_{first}_then_{second}")
    base = ["run", deck, "-q", "--no-progress"] + sets
    run(launch(mpiexec, numproc_flag, first, stiffmd) + base + ["-o", ref, "--set", "run.steps=40"], first)
    run(launch(mpiexec, numproc_flag, first, stiffmd) + base + ["-o", out, "--set", "run.steps=20"], first)
    checkpoint = os.path.join(tmp, "at_20.bin")
    shutil.copy(os.path.join(out, "checkpoint.bin"), checkpoint)
    r = run(launch(mpiexec, numproc_flag, second, stiffmd) + base + ["-o", out, "--set", "run.steps=40",
            "--restart", checkpoint], second)
    if "at step 20 " not in r.stderr:
        raise SystemExit(f"FAIL: the run on {second} ranks did not say it continued at step 20:\n{r.stderr}")
    with open(os.path.join(out, "summary.json")) as f:
        setup = json.load(f).get("domains", {}).get("setup")
    if second > 1 and setup != "parts":
        raise SystemExit(f"FAIL: the restart on {second} ranks set up from '{setup}', not by parts")
    with open(os.path.join(ref, "thermo.csv"), "rb") as a, open(os.path.join(out, "thermo.csv"), "rb") as b:
        if a.read() != b.read():
            raise SystemExit(f"FAIL: thermo.csv of the restart on {second} ranks differs from the uninterrupted run's")
    damaged = os.path.join(tmp, "damaged.bin")
    with open(checkpoint, "rb") as f:
        data = bytearray(f.read())
    data[len(data) // 3] ^= 0x10
    with open(damaged, "wb") as f:
        f.write(data)
    cmd = launch(mpiexec, numproc_flag, second, stiffmd) + base + ["-o", os.path.join(tmp, "damaged"), "--set",
                                                                   "run.steps=40", "--restart", damaged]
    r = subprocess.run(cmd, capture_output=True, text=True, timeout=600, env=environment())
    errors = [line for line in r.stderr.splitlines() if line.startswith("error")]
    if r.returncode != 2 or len(errors) != 1 or f"{damaged}: damaged checkpoint (crc32" not in errors[0]:
        raise SystemExit(f"FAIL: a damaged checkpoint on {second} ranks: exit {r.returncode}, stderr:\n{r.stderr}")
    print(f"restarted by parts on {second} ranks from {first}: thermo.csv the uninterrupted run's bytes; "
          f"a damaged checkpoint refused with one line")


def main(argv):
    if len(argv) != 6:
        raise SystemExit(__doc__)
    stiffmd, mpiexec, numproc_flag, n, case = argv[1], argv[2], argv[3], int(argv[4]), argv[5]
    tmp = tempfile.mkdtemp(prefix="stiffmd_domains_")
    start = time.monotonic()
    try:
        if case == "bad_grid":
            bad_grid_case(stiffmd, mpiexec, numproc_flag, n, tmp)
        elif case == "overlap":
            overlap_case(stiffmd, mpiexec, numproc_flag, n, tmp)
        elif case == "xyz":
            xyz_case(stiffmd, mpiexec, numproc_flag, n, tmp)
        elif case == "kill":
            kill_case(stiffmd, mpiexec, numproc_flag, n, tmp)
        elif case.startswith("restart:"):
            first, second = (int(r) for r in case.split(":")[1:])
            restart_case(stiffmd, mpiexec, numproc_flag, first, second, tmp)
        elif case.startswith("restart_parts:"):
            first, second = (int(r) for r in case.split(":")[1:])
            restart_parts_case(stiffmd, mpiexec, numproc_flag, first, second, tmp)
        elif case.startswith("restart_prepare:"):
            first, second = (int(r) for r in case.split(":")[1:])
            restart_parts_case(stiffmd, mpiexec, numproc_flag, first, second, tmp, STIFF_BY_PARTS,
                               ["--set", 'integrator.method="fixman"', "--set", "integrator.h=0.01",
                                "--set", "prepare.vibrational_temperature=0"])
        elif case.startswith("restart_npt:"):
            first, second = (int(r) for r in case.split(":")[1:])
            restart_case(stiffmd, mpiexec, numproc_flag, first, second, tmp, STIFF_MELT_NPT, 0.01)
        elif case.startswith("restart_half_melt:"):
            first, second = (int(r) for r in case.split(":")[1:])
            restart_case(stiffmd, mpiexec, numproc_flag, first, second, tmp, HALF_MELT, 0.01)
        elif case.startswith("restart_water:"):  # PPPM's distributed mesh: to round-off
            global BITWISE
            BITWISE = False
            first, second = (int(r) for r in case.split(":")[1:])
            restart_case(stiffmd, mpiexec, numproc_flag, first, second, tmp, os.path.join(ROOT, "inputs", "spce_water.toml"),
                         2.0, STEPS // 4)
        else:
            plain_case(stiffmd, mpiexec, numproc_flag, n, case, tmp)
    except Skip as e:
        print(f"SKIP: {case}: {e}")
        shutil.rmtree(tmp)
        return SKIP
    except BaseException:
        print(f"(outputs kept in {tmp})")
        raise
    shutil.rmtree(tmp)
    print(f"{case}: {time.monotonic() - start:.1f} s in all")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
