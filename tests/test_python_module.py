#!/usr/bin/python3
"""The Python module `stiffmd` (python/stiffmd_py.cpp), run by ctest on Debian's python3 with the
module's build directory on PYTHONPATH:
  - the double pendulum stepped from Python ends exactly where `stiffmd run` ends (bit for bit: the
    final H5MD frame's positions and velocities, summary.json's energies), for several methods, from
    the file and from the same deck as TOML text; so does a deck with pairs on a neighbour list,
    with thermo() or forces() called after every step, and SPC/E water (charges, PPPM, real units);
  - forces by level sum to the total and are −∇ of the level's energy (central differences) on a
    small deck with stiff bonds (fast), angles and Lennard-Jones pairs (slow); named r-RESPA levels
    ([[integrator.levels]]) are addressed by their names;
  - setting positions and velocities, then stepping, is bit for bit a deck that starts there (for
    RATTLE after sim.prepare(), which projects as the deck's start does);
  - the README's example runs as written;
  - one of several processes started by a launcher (mpiexec -n N python3 …) is refused with the
    command that runs the deck on N ranks, before any file is written;
  - bad input: a misspelt override raises ValueError naming the key, a TOML error names the line,
    a wrong shape is refused, a blow-up raises stiffmd.NumericalError (a RuntimeError);
  - a real-units deck (inputs/trappe_pe.toml, 5 steps of 4 fs under Langevin) speaks the deck's units,
    as the CLI does: h, t_end, time and run_to in fs, the thermo row as thermo.csv and the H5MD
    observables write it (K, atm, kcal/mol; with thermo_norm per atom), velocities in Å/fs as the
    final LAMMPS data file writes them, and velocities set in Å/fs; after a set the temperature reads
    the state's ½vᵀMv (impulse, RATTLE), not the last O step's kinetic energy.
Usage: test_python_module.py STIFFMD_EXE"""
import gzip
import json
import os
import subprocess
import sys
import tempfile

import h5py
import numpy as np
import stiffmd

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
from checklist import finish, test  # noqa: E402  (tests/ is the script's directory)
EXE = sys.argv[1]
PENDULUM = os.path.join(ROOT, "inputs", "double_pendulum.toml")


def cli_final_state(deck, out, sets):
    """`stiffmd run` with the overrides; the final frame (positions, velocities) and summary.json."""
    cmd = [EXE, "run", deck, "-o", out, "--no-progress", "--set", "output.h5md_velocity=true"]
    for key, value in sets.items():
        cmd += ["--set", f"{key}={value}"]
    subprocess.run(cmd, capture_output=True, text=True, check=True)
    with h5py.File(os.path.join(out, "trajectory.h5md"), "r") as f:
        x = f["particles/all/position/value"][-1]
        v = f["particles/all/velocity/value"][-1]
        step = f["particles/all/position/step"][-1]
    with open(os.path.join(out, "summary.json")) as f:
        return x, v, int(step), json.load(f)


@test
def pendulum_equals_the_command_line_bit_for_bit():
    for method in ("projected-impulse", "impulse", "rattle", "effective", "velocity-verlet"):
        sets = {"integrator.method": method, "run.t_end": 1.0}
        if method == "velocity-verlet":  # the full stiff system: a step that resolves ε
            sets.update({"variables.eps": 0.01, "integrator.h": 1e-4})
        with tempfile.TemporaryDirectory() as out:
            x, v, step, summary = cli_final_state(PENDULUM, out, sets)
        with open(PENDULUM) as f:
            text = f.read()
        for sim in (stiffmd.Simulation(PENDULUM, set=sets), stiffmd.Simulation.from_toml(text, set=sets)):
            assert sim.method == method
            sim.run_to(sim.t_end)
            assert sim.step == step == summary["steps"], (method, sim.step, step)
            assert np.array_equal(sim.positions, x), (method, np.abs(sim.positions - x).max())
            assert np.array_equal(sim.velocities, v), (method, np.abs(sim.velocities - v).max())
            row = sim.thermo()
            assert row["total"] == summary["final_energy"], (method, row["total"], summary["final_energy"])
            assert row["max_violation"] == summary["final_max_violation"], method
            assert row["potential_slow"] == sim.energy("slow"), method
            if method != "effective":  # its potential_stiff is W(I, x), the model potential
                assert row["potential_stiff"] == sim.energy("fast"), method


@test
def charged_water_with_pppm_equals_the_command_line():
    # SPC/E water (real units: charges, lj/cut/coul/long, PPPM, rigid triangles) for 10 steps of
    # 2 fs: the same final state as `stiffmd run`, bit for bit, and the thermo's evdwl, ecoul and elong.
    deck = os.path.join(ROOT, "inputs", "spce_water.toml")
    sets = {"run.t_end": 20.0, "output.h5md": '"trajectory.h5md"', "output.h5md_interval": 20.0}
    with tempfile.TemporaryDirectory() as out:
        _, v, step, summary = cli_final_state(deck, out, sets)  # H5MD positions are wrapped
        rows = np.genfromtxt(os.path.join(out, "thermo.csv"), delimiter=",", names=True)
    sim = stiffmd.Simulation(deck, set={"run.t_end": 20.0})
    sim.run_to(sim.t_end)
    assert sim.step == step == 10, (sim.step, step)
    # H5MD's velocities are in Å/ps (its unit attribute), the module's in the deck's Å/fs.
    assert np.allclose(1000.0 * sim.velocities, v, rtol=1e-13, atol=0), np.abs(1000.0 * sim.velocities - v).max()
    row = sim.thermo()
    assert row["total"] == summary["final_energy"], (row["total"], summary["final_energy"])  # x, v to the bit
    for column in ("evdwl", "ecoul", "elong"):
        assert np.isclose(row[column], rows[column][-1], rtol=1e-10, atol=0), (column, row[column], rows[column][-1])
        assert row[column] != 0.0, column


@test
def pair_deck_equals_the_command_line_whatever_is_evaluated_between_steps():
    # WCA pairs on a neighbour list (about 100 rebuilds in 500 steps) under impulse. A method that
    # evaluates the forces at the positions that end its step (all but mollified-impulse, README)
    # has shown the list those positions: evaluations between steps (the CLI's thermo samples,
    # the calls below) rebuild nothing the run would not.
    deck = os.path.join(ROOT, "inputs", "morse_dimers.toml")
    with tempfile.TemporaryDirectory() as out:
        cmd = [EXE, "run", deck, "-o", out, "--no-progress", "--set", "output.h5md=t.h5md",
               "--set", "output.h5md_velocity=true"]
        subprocess.run(cmd, capture_output=True, text=True, check=True)
        with h5py.File(os.path.join(out, "t.h5md"), "r") as f:
            v = f["particles/all/velocity/value"][-1]
        with open(os.path.join(out, "summary.json")) as f:
            summary = json.load(f)
    assert summary["neighbor_rebuilds"] > 50, summary["neighbor_rebuilds"]
    for probe in (None, "thermo", "forces"):
        sim = stiffmd.Simulation(deck)
        while sim.step < summary["steps"]:
            sim.run(1 if probe else summary["steps"])
            if probe == "thermo":
                sim.thermo()
            elif probe == "forces":
                sim.forces("slow"), sim.energy()
        assert np.array_equal(sim.velocities, v), (probe, np.abs(sim.velocities - v).max())
        assert sim.thermo()["total"] == summary["final_energy"], probe  # the positions, to the bit


@test
def steps_and_times():
    sim = stiffmd.Simulation(PENDULUM)
    h = sim.h
    assert h == 1 / 64 and sim.step == 0 and sim.time == 0.0 and sim.units == "lj"
    sim.run(3)
    assert sim.step == 3 and sim.time == 3 * h
    sim.run_to(0.5)  # 32 steps
    assert sim.step == 32 and sim.time == 0.5
    sim.run_to(0.5)  # already there: no step
    assert sim.step == 32
    sim.run(0)
    assert sim.step == 32
    coarse = stiffmd.Simulation(PENDULUM, set={"integrator.h": 0.1})
    for _ in range(10):
        coarse.run(1)
    assert coarse.time == 10 * 0.1 == 1.0  # t_k = k h, not a sum of h (0.9999999999999999)
    try:
        sim.run_to(0.25)
        raise AssertionError("run_to into the past was accepted")
    except ValueError as e:
        assert "before the current time" in str(e), e
    assert "projected-impulse" in stiffmd.methods() and "rattle" in stiffmd.methods()
    m = sim.masses
    assert m[0] == np.inf and m[1] == 1.0 and m[2] == 1.0 and sim.num_particles == 3
    # Copies: changing the returned array does not change the simulation.
    x = sim.positions
    x[1, 0] += 1.0
    assert not np.array_equal(sim.positions, x)


SMALL = """
[box]
lengths = [8, 8, 8]
[types.bead]
mass = 1.5
[[build]]
style = "linear-chains"
type = "bead"
chains = 3
beads = 4
bond_length = 1.0
bond_type = "b"
angle_type = "a"
min_distance = 0.9
seed = 7
[velocities]
temperature = 1.0
seed = 2
[forces.bonds]
style = "stiff-harmonic"
level = "fast"
epsilon = 0.1
bond_types.b = { length = 1.0, alpha = 1.0 }
[forces.bend]
style = "harmonic-angle"
angle_types.a = { k = 3.0, theta0 = 110 }
[forces.pairs]
style = "lj"
cutoff = 2.5
special_bonds = [0.0, 0.5]
[integrator]
method = "impulse"
h = 0.005
micro_steps = 5
[run]
t_end = 0.05
"""


@test
def forces_by_level_are_minus_the_gradient_of_their_energy():
    sim = stiffmd.Simulation.from_toml(SMALL)
    rng = np.random.default_rng(1)
    x0 = sim.positions + rng.uniform(-0.05, 0.05, sim.positions.shape)  # stretch the stiff bonds
    sim.positions = x0
    fast, slow, total = sim.forces("fast"), sim.forces("slow"), sim.forces()
    assert np.abs(fast).max() > 1.0 and np.abs(slow).max() > 0.1  # both levels act
    assert np.allclose(fast + slow, total, rtol=1e-13, atol=1e-13 * np.abs(total).max())
    assert sim.energy() == sim.energy("fast") + sim.energy("slow")
    d = 1e-5
    for level, f in (("fast", fast), ("slow", slow)):
        grad = np.zeros_like(x0)
        for i in range(x0.shape[0]):
            for a in range(3):
                for sign in (1, -1):
                    x = x0.copy()
                    x[i, a] += sign * d
                    sim.positions = x
                    grad[i, a] += sign * sim.energy(level) / (2 * d)
        err = np.abs(f + grad).max()
        assert err < 1e-6 * max(1.0, np.abs(f).max()), (level, err)
    try:
        sim.energy("medium")
        raise AssertionError("an unknown level was accepted")
    except ValueError as e:
        assert "fast" in str(e)


@test
def named_levels_give_energies_and_forces_by_name():
    """inputs/respa_chains.toml: three named r-RESPA levels, innermost first."""
    sim = stiffmd.Simulation(os.path.join(ROOT, "inputs", "respa_chains.toml"), set={"prepare.relax_steps": 0})
    assert sim.levels == ["bonds", "angles", "pair"], sim.levels
    energies = [sim.energy(name) for name in sim.levels]
    assert sim.energy() == (energies[0] + energies[1]) + energies[2]
    row = sim.thermo()
    for name, u in zip(sim.levels, energies):
        assert row["potential_" + name] == u, name
    assert row["potential_stiff"] == energies[0]
    forces = [sim.forces(name) for name in sim.levels]
    assert all(np.abs(f).max() > 0 for f in forces)
    total = sim.forces()
    assert np.allclose(sum(forces), total, rtol=1e-12, atol=1e-12 * np.abs(total).max())
    try:
        sim.energy("slow")
        raise AssertionError("a level the deck does not name was accepted")
    except ValueError as e:
        assert '"angles"' in str(e), str(e)


def deck_starting_at(x, v):
    """Three chains of four beads with stiff bonds and LJ pairs, starting at x, v (given at full
    precision: repr round-trips)."""
    text = "[box]\nlengths = [8, 8, 8]\n[types.bead]\nmass = 1.5\n"
    for xi, vi in zip(x, v):
        text += (f"[[particles]]\ntype = \"bead\"\nposition = [{', '.join(map(repr, map(float, xi)))}]\n"
                 f"velocity = [{', '.join(map(repr, map(float, vi)))}]\n")
    for c in range(3):
        for b in range(3):
            text += f"[[bonds]]\nparticles = [{4 * c + b}, {4 * c + b + 1}]\ntype = \"b\"\n"
    return text + SMALL.split("[forces.bend]")[0].split("seed = 2\n")[1] + "[forces.pairs]" + SMALL.split(
        "[forces.pairs]")[1]


@test
def setting_the_state_then_stepping_is_a_deck_that_starts_there():
    for method in ("impulse", "projected-impulse", "rattle"):
        sets = {"integrator.method": method}
        built = stiffmd.Simulation.from_toml(SMALL)
        sim = stiffmd.Simulation.from_toml(deck_starting_at(built.positions, built.velocities), set=sets)
        sim.run(4)
        rng = np.random.default_rng(3)
        x = sim.positions + rng.uniform(-0.02, 0.02, sim.positions.shape)
        v = sim.velocities * 0.5
        sim.positions, sim.velocities = x, v
        assert np.array_equal(sim.positions, x) and np.array_equal(sim.velocities, v)
        sim.prepare()  # what a fresh run does first (RATTLE projects; the impulse family: nothing)
        fresh = stiffmd.Simulation.from_toml(deck_starting_at(x, v), set=sets)
        assert np.array_equal(fresh.positions, sim.positions), method
        assert np.array_equal(fresh.velocities, sim.velocities), method
        sim.run(6)
        fresh.run(6)
        assert np.array_equal(fresh.positions, sim.positions), (method, np.abs(fresh.positions - sim.positions).max())
        assert np.array_equal(fresh.velocities, sim.velocities), method
        assert fresh.thermo()["energy_drift"] == sim.thermo()["energy_drift"], method  # E(0) from the set state


@test
def bad_input_raises_value_error_naming_the_key():
    try:
        stiffmd.Simulation(PENDULUM, set={"integrator.metod": "rattle"})
        raise AssertionError("a misspelt key was accepted")
    except ValueError as e:
        assert "integrator.metod" in str(e) and "\n" not in str(e), e
    try:
        stiffmd.Simulation(PENDULUM, set={"integrator.h": -1})
        raise AssertionError("h < 0 was accepted")
    except ValueError as e:
        assert "integrator.h" in str(e), e
    try:
        stiffmd.Simulation.from_toml("[run]\nt_end = 1\n[integrator\n", name="mine.toml")
        raise AssertionError("a TOML syntax error was accepted")
    except ValueError as e:
        assert str(e).startswith("mine.toml:3:"), e
    try:
        stiffmd.Simulation(os.path.join(ROOT, "inputs", "no_such_deck.toml"))
        raise AssertionError("a missing deck was accepted")
    except ValueError as e:
        assert "no_such_deck.toml" in str(e), e
    sim = stiffmd.Simulation(PENDULUM)
    for bad in (np.zeros((2, 3)), np.zeros((3, 2)), [[0, 0, np.nan]] * 3):
        try:
            sim.positions = bad
            raise AssertionError(f"positions {bad} accepted")
        except ValueError:
            pass


@test
def a_blow_up_raises_numerical_error():
    # Velocity Verlet with h = 1/64 ≫ ε on the stiff springs is unstable: the state overflows.
    sim = stiffmd.Simulation(PENDULUM, set={"integrator.method": "velocity-verlet"})
    try:
        sim.run_to(sim.t_end)
        raise AssertionError("the blow-up went unnoticed")
    except stiffmd.NumericalError as e:
        assert isinstance(e, RuntimeError) and "non-finite" in str(e), e
        assert 0 < sim.step < 640


TRAPPE = os.path.join(ROOT, "inputs", "trappe_pe.toml")


def read_data_velocities(path):
    """The Velocities section of a LAMMPS data file, by atom id (1…N), as an N×3 array."""
    with open(path) as f:
        lines = f.read().split("\nVelocities\n\n")[1].split("\n\n")[0].splitlines()
    v = np.zeros((len(lines), 3))
    for line in lines:
        fields = line.split()
        v[int(fields[0]) - 1] = [float(w) for w in fields[1:4]]
    return v


def cli_real_run(out, norm):
    """`stiffmd run` on the TraPPE-UA deck for 20 fs (5 steps), writing the thermo row, an H5MD file
    with velocities and the final state as a LAMMPS data file; (thermo.csv header and last row as
    text, H5MD observables' last values, H5MD positions unwrapped (x = r + image L) and velocities,
    data-file velocities, summary.json)."""
    cmd = [EXE, "run", TRAPPE, "-o", out, "--no-progress", "--set", "run.t_end=20", "--set", "output.h5md=t.h5md",
           "--set", "output.h5md_velocity=true", "--set", "output.lammps_data=final.data",
           "--set", f"output.thermo_norm={'true' if norm else 'false'}"]
    subprocess.run(cmd, capture_output=True, text=True, check=True)
    with open(os.path.join(out, "thermo.csv")) as f:
        rows = f.read().splitlines()
    header, last = rows[0].split(","), rows[-1].split(",")
    with h5py.File(os.path.join(out, "t.h5md"), "r") as f:
        observables = {name: f["observables"][name]["value"][-1] for name in f["observables"]}
        edges = np.diag(f["particles/all/box/edges/value"][-1])  # the box's edge vectors: a diagonal
        x = f["particles/all/position/value"][-1] + f["particles/all/image/value"][-1] * edges
        v_ps = f["particles/all/velocity/value"][-1]
    with open(os.path.join(out, "summary.json")) as f:
        summary = json.load(f)
    return dict(zip(header, last)), observables, x, v_ps, read_data_velocities(os.path.join(out, "final.data")), summary


@test
def real_units_deck_speaks_the_decks_units_as_the_command_line():
    sets = {"run.t_end": 20.0}
    sim = stiffmd.Simulation(TRAPPE, set=sets)
    assert sim.units == "real"
    assert abs(sim.h - 4.0) <= 1e-15 * 4.0, sim.h  # the deck's 4 fs (4 × (1/τ) × τ: to round-off)
    assert abs(sim.t_end - 20.0) <= 1e-15 * 20.0, sim.t_end
    sim.run_to(8.0)  # 8 fs: step 2
    assert sim.step == 2 and abs(sim.time - 8.0) <= 1e-15 * 8.0, (sim.step, sim.time)
    assert "units real" in repr(sim), repr(sim)
    cli = {}
    for norm in (False, True):
        with tempfile.TemporaryDirectory() as out:
            cli[norm] = csv, observables, x, v_ps, v_data, summary = cli_real_run(out, norm)
        sim = stiffmd.Simulation(TRAPPE, set=dict(sets, **{"output.thermo_norm": norm}))
        assert sim.h == summary["h"] and sim.t_end == summary["t_end"], (sim.h, sim.t_end, summary)
        sim.run_to(sim.t_end)
        assert sim.step == summary["steps"] == 5, (sim.step, summary["steps"])
        assert np.abs(sim.positions - x).max() < 1e-12, np.abs(sim.positions - x).max()  # Å (to the wrap's round-off)
        # Velocities in Å/fs: those of the final data file to the bit, the H5MD file's Å/ps to round-off.
        v = sim.velocities
        assert np.array_equal(v, v_data), np.abs(v / v_data - 1).max()
        assert np.allclose(1000.0 * v, v_ps, rtol=1e-15, atol=0), np.abs(1000.0 * v / v_ps - 1).max()
        row = sim.thermo()
        assert sorted(row) == sorted(c for c in csv if c != "alerts"), (sorted(row), sorted(csv))
        assert ("kinetic_per_atom" in row) == norm and ("kinetic" in row) != norm, sorted(row)
        for column, value in row.items():
            assert f"{value:.12g}" == csv[column], (norm, column, value, csv[column])  # as thermo.csv writes it
            if column not in ("time", "step"):  # H5MD keeps those on its own grid
                assert value == observables[column], (norm, column, value, observables[column])  # to the bit
        assert row["time"] == sim.time
        assert 400 < row["temperature"] < 500 and 1 < abs(row["pressure"]) < 1e4, row  # K, atm
        if not norm:
            assert row["total"] == summary["final_energy"], (row["total"], summary["final_energy"])
            assert row["potential_pair"] == sim.energy("pair")  # kcal/mol, no conversion
            final_row = row
    # Velocities set in Å/fs: the CLI's final state given to a fresh simulation has the run's kinetic
    # energy and reads back to round-off (the deck's import factor, then the output's). The
    # temperature then reads ½vᵀMv, as at the start, not the last O step's kinetic energy.
    csv, observables, x, v_ps, v_data, summary = cli[False]
    fresh = stiffmd.Simulation(TRAPPE, set=sets)
    start = fresh.thermo()
    fresh.positions, fresh.velocities = x, v_data
    assert np.allclose(fresh.velocities, v_data, rtol=1e-15, atol=0), np.abs(fresh.velocities / v_data - 1).max()
    row = fresh.thermo()
    assert abs(row["kinetic"] / final_row["kinetic"] - 1) < 1e-14, (row["kinetic"], final_row["kinetic"])
    ratio = start["temperature"] / start["kinetic"]  # 2/(dof k_B)
    assert abs(row["temperature"] / row["kinetic"] / ratio - 1) < 1e-14, (row["temperature"], row["kinetic"])
    assert abs(final_row["temperature"] / final_row["kinetic"] / ratio - 1) > 1e-6  # the run's read the O step
    # The same after steps (the O step's kinetic energy is forgotten), with the impulse family and RATTLE.
    for method in ("impulse", "rattle"):
        sim = stiffmd.Simulation(TRAPPE, set=dict(sets, **{"integrator.method": method}))
        row = sim.thermo()
        ratio = row["temperature"] / row["kinetic"]
        sim.run(2)
        row = sim.thermo()
        assert abs(row["temperature"] / row["kinetic"] / ratio - 1) > 1e-6, method  # the O step's
        sim.velocities = sim.velocities
        row = sim.thermo()
        assert abs(row["temperature"] / row["kinetic"] / ratio - 1) < 1e-14, (method, row)


@test
def readme_example_runs():
    with open(os.path.join(ROOT, "README.md")) as f:
        section = f.read().split("\n## Python\n")[1].split("\n## ")[0]
    code = section.split("```python\n")[1].split("```")[0]
    cwd = os.getcwd()
    os.chdir(ROOT)  # the example's paths are relative to the repository
    try:
        namespace = {}
        exec(compile(code, "README.md (Python)", "exec"), namespace)  # noqa: S102 - our own README
    finally:
        os.chdir(cwd)
    sim, eff = namespace["sim"], namespace["eff"]
    assert sim.method == "rattle" and sim.time == 2.0 and sim.step == 128
    assert eff.method == "effective"



def same_run_directories(a, b):
    """Every file of two run directories equal: byte for byte (gzip files once decompressed: a
    restart appends a gzip member), H5MD datasets value for value, summary.json but for its
    timings and paths."""
    names = sorted(os.listdir(a))
    assert names == sorted(os.listdir(b)), (names, sorted(os.listdir(b)))
    for name in names:
        pa, pb = os.path.join(a, name), os.path.join(b, name)
        if name == "summary.json":
            with open(pa) as fa, open(pb) as fb:
                ja, jb = json.load(fa), json.load(fb)
            for k in ("wall_seconds", "cpu_seconds", "outputs", "loop_seconds", "timing", "serial_share", "peak_rss_mib",
                      "setup_seconds"):
                ja.pop(k, None), jb.pop(k, None)
            assert ja == jb, (ja, jb)
        elif name.endswith(".h5md"):
            with h5py.File(pa, "r") as fa, h5py.File(pb, "r") as fb:
                sets = []
                fa.visititems(lambda n, o: sets.append(n) if isinstance(o, h5py.Dataset) else None)
                for n in sets:
                    assert np.array_equal(fa[n][()], fb[n][()]), (name, n)
        else:
            opener = gzip.open if name.endswith(".gz") else open
            with opener(pa, "rb") as fa, opener(pb, "rb") as fb:
                assert fa.read() == fb.read(), name


@test
def the_run_from_python_is_the_command_lines_with_outputs_checkpoints_and_restart():
    # One Run (engine/run/run.hpp) behind `stiffmd run`, `stiffmd check` and the module: with an
    # output directory the module writes the CLI's files (trajectories, thermo with the monitor's
    # alerts, H5MD, checkpoint, summary.json), and a run finished halfway and restarted from its
    # checkpoint from Python writes the files of the uninterrupted run — on the melt with pairs (LJ
    # units, a monitor that alerts) and on the TraPPE alkanes (real units, Langevin).
    melt = os.path.join(ROOT, "inputs", "polymer_melt.toml")
    cases = [(melt, {"run.t_end": 0.2, "output.thermo_interval": 0.01, "output.xyz_interval": 0.05,
                     "output.h5md_interval": 0.05, "monitor.violation": 1e-9}, 0.1),
             (TRAPPE, {"run.t_end": 80.0, "output.thermo_interval": 8.0, "output.h5md": "t.h5md",
                       "output.h5md_interval": 16.0}, 40.0)]
    for deck, sets, half in cases:
        with tempfile.TemporaryDirectory() as tmp:
            cli = os.path.join(tmp, "cli")
            cmd = [EXE, "run", deck, "-o", cli, "--no-progress", "-q"]
            for key, value in sets.items():
                cmd += ["--set", f"{key}={json.dumps(value)}"]
            subprocess.run(cmd, capture_output=True, text=True, check=True)
            check = subprocess.run([EXE, "check", deck] + cmd[7:], capture_output=True, text=True)
            assert check.returncode == 0, check.stderr
            whole = os.path.join(tmp, "python")
            sim = stiffmd.Simulation(deck, set=sets, output=whole)
            sim.run_to(sim.t_end)
            summary = sim.finish()
            assert summary["steps"] == sim.step and summary["checkpoint"].endswith("checkpoint.bin")
            same_run_directories(cli, whole)
            halves = os.path.join(tmp, "halves")
            first = stiffmd.Simulation(deck, set=dict(sets, **{"run.t_end": half}), output=halves)
            first.run_to(first.t_end)
            first.finish()
            second = stiffmd.Simulation(deck, set=sets, output=halves,
                                        restart=os.path.join(halves, "checkpoint.bin"))
            assert second.step == first.step and "restart from" in second.log
            second.run_to(second.t_end)
            second.finish()
            same_run_directories(cli, halves)
            if deck == melt:  # the monitor ran from Python as on the command line
                with open(os.path.join(whole, "thermo.csv")) as f:
                    rows = f.read().splitlines()
                alerts = rows[0].split(",").index("alerts")
                assert any(float(r.split(",")[alerts]) > 0 for r in rows[1:])
    sim = stiffmd.Simulation(PENDULUM)
    sim.run(2)
    sim.finish()
    try:
        sim.run(1)
        raise AssertionError("stepped after finish()")
    except ValueError as e:
        assert "finished" in str(e)


@test
def an_ensemble_deck_is_refused_not_stepped_as_its_base():
    deck = os.path.join(ROOT, "inputs", "ensemble_seeds.toml")
    try:
        stiffmd.Simulation(deck)
        raise AssertionError("an [ensemble] deck was stepped as one run")
    except ValueError as e:
        assert "[ensemble] deck is" in str(e) and "stiffmd run" in str(e), str(e)


@test
def one_of_several_launched_processes_is_refused_with_the_mpiexec_command():
    # What mpiexec -n 3 python3 … gives each process: the launcher's size in the environment. Each
    # would otherwise run the whole deck into the same files; refused before any file is written.
    script = ("import sys, stiffmd\n"
              "try:\n"
              "    stiffmd.Simulation(sys.argv[1], output=sys.argv[2] if len(sys.argv) > 2 else None)\n"
              "except ValueError as e:\n"
              "    print(e)\n"
              "    raise SystemExit(2)\n")
    launched = ("OMPI_", "PMI", "SLURM_")
    with tempfile.TemporaryDirectory() as out:
        for size_variable in ("OMPI_COMM_WORLD_SIZE", "PMI_SIZE"):
            env = {k: v for k, v in os.environ.items() if not k.startswith(launched)}
            env[size_variable] = "3"
            r = subprocess.run([sys.executable, "-c", script, PENDULUM, out], env=env, capture_output=True, text=True)
            assert r.returncode == 2, (size_variable, r.returncode, r.stdout, r.stderr)
            assert f"mpiexec -n 3 stiffmd run {PENDULUM} -o DIR" in r.stdout, r.stdout
            assert os.listdir(out) == [], os.listdir(out)
    # One process under a launcher (mpiexec -n 1) is one process: it runs.
    env = {k: v for k, v in os.environ.items() if not k.startswith(launched)}
    env["OMPI_COMM_WORLD_SIZE"] = "1"
    r = subprocess.run([sys.executable, "-c", script, PENDULUM], env=env, capture_output=True, text=True)
    assert r.returncode == 0, (r.returncode, r.stdout, r.stderr)

finish()
