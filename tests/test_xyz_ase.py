#!/usr/bin/python3
"""ASE reads stiffmd's extended XYZ as it is: positions, times, species, cell, pbc, velocities
(run by ctest on Debian's python3 with python3-ase)."""
import os
import subprocess
import sys
import tempfile

import numpy as np
from ase.io import read

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
failures = []
checks = 0


def check(name, ok, detail=""):
    global checks
    checks += 1
    print(f"{'ok  ' if ok else 'FAIL'} {name} {detail}")
    if not ok:
        failures.append(name)


def run(exe, deck, out, *sets):
    cmd = [exe, "run", deck, "-o", out, "--no-progress"] + [a for s in sets for a in ("--set", s)]
    subprocess.run(cmd, check=True, capture_output=True)


def main():
    exe = sys.argv[1]
    with tempfile.TemporaryDirectory() as d:
        # The pendulum, with the state output as an independent record of x at each frame time.
        run(exe, os.path.join(ROOT, "inputs", "double_pendulum.toml"), d, "run.t_end=0.5", "integrator.h=0.0125",
            "output.xyz_interval=0.05", "output.state=state.csv", "output.state_interval=0.05")
        frames = read(os.path.join(d, "trajectory.xyz"), index=":")
        state = np.loadtxt(os.path.join(d, "state.csv"), delimiter=",", skiprows=1)
        check("pendulum frame count", len(frames) == len(state), f"{len(frames)} vs {len(state)}")
        x = np.array([f.get_positions() for f in frames])
        check("pendulum positions", np.allclose(x.reshape(len(frames), -1), state[:, 1:10], atol=1e-10))
        times = np.array([f.info["time"] for f in frames])
        check("pendulum times", np.allclose(times, state[:, 0]))
        check("pendulum species", frames[0].get_chemical_symbols() == ["Fe", "C", "C"])
        check("pendulum open box", not any(frames[0].pbc))

        # Periodic, with velocities, gzip-compressed.
        run(exe, os.path.join(ROOT, "tests", "decks", "periodic_free.toml"), d, "output.xyz=traj.xyz.gz")
        frames = read(os.path.join(d, "traj.xyz.gz"), index=":")
        check("periodic frame count", len(frames) == 9, str(len(frames)))
        f = frames[-1]
        check("periodic cell", np.allclose(f.cell.array, np.diag([3.0, 4.0, 5.0])))
        check("periodic pbc", list(f.pbc) == [True, True, False])
        v0 = np.array([[2.0, 0, 0], [0, 3.0, 0.1], [-1.5, -2.5, 0], [0.3, 0.2, -0.1]])
        x0 = np.array([[0.5, 0.5, 0.5], [2.5, 3.5, 1.0], [1.0, 1.0, 2.0], [1.5, 2.0, 3.0]])
        # ASE keeps the velo column as an array of that name (OVITO maps it to velocities).
        check("periodic velocities", np.allclose(f.arrays["velo"], v0))
        # Free flight: the (unwrapped) positions at t = 2 are x0 + 2 v0.
        check("periodic positions", np.allclose(f.get_positions(), x0 + 2.0 * v0, atol=1e-9))
        check("periodic species", f.get_chemical_symbols() == ["Ar", "Ar", "Ne", "Ne"])
        check("periodic time", abs(f.info["time"] - 2.0) < 1e-12)
    print(f"{checks - len(failures)} passed, {len(failures)} failed")
    sys.exit(1 if failures else 0)


if __name__ == "__main__":
    main()
