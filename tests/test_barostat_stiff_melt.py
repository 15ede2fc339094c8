"""The stiff melt at eps = 1e-3 under the C-rescale barostat (inputs/stiff_melt_npt.toml, P = 5, kT = 1).

The thermal stiff limit (fixman, h = 0.01) must find the density velocity Verlet finds on the stiff
springs themselves (h = eps/2 = 5e-4, every vibration resolved), and the same bond-angle law — the
mean cosine of the bond angles, sampled every time unit from the H5MD frames — each within 3
combined standard errors (batch means, 20 batches over t = 20 … 200). The barostat reads the
molecular pressure, in which the springs and the constraint forces drop out (docs/design.md §5b),
so the two methods' densities agree although their atomic pressures do not.

    test_barostat_stiff_melt.py STIFFMD
"""
import os
import pathlib
import subprocess
import sys
import tempfile

import h5py
import numpy as np

ROOT = pathlib.Path(__file__).resolve().parent.parent
DECK = ROOT / "inputs" / "stiff_melt_npt.toml"
BEADS = 5  # per chain, the deck's
BATCHES = 20


def batch(series):
    b = series[: len(series) // BATCHES * BATCHES].reshape(BATCHES, -1).mean(axis=1)
    return series.mean(), b.std(ddof=1) / np.sqrt(BATCHES)


def measure(out):
    thermo = np.genfromtxt(out / "thermo.csv", delimiter=",", names=True)
    density = batch(thermo["density"][thermo["time"] >= 20.0])
    with h5py.File(out / "t.h5", "r") as f:
        p = f["particles/all"]
        t = f["particles/all/position/time"][()]
        keep = t >= 20.0
        x = p["position/value"][keep] + p["image/value"][keep] * np.diagonal(p["box/edges/value"][keep], axis1=1,
                                                                              axis2=2)[:, None, :]
    x = x.reshape(len(x), -1, BEADS, 3)
    a, b = x[:, :, :-2] - x[:, :, 1:-1], x[:, :, 2:] - x[:, :, 1:-1]
    cos = (a * b).sum(-1) / (np.linalg.norm(a, axis=-1) * np.linalg.norm(b, axis=-1))
    return density, batch(cos.reshape(len(cos), -1).mean(axis=1))


def main():
    stiffmd = sys.argv[1]
    env = dict(os.environ, OMP_NUM_THREADS="1")
    common = ["--quiet", "--set", "run.t_end=200", "--set", "output.thermo_interval=0.5", "--set",
              'output.h5md="t.h5"', "--set", "output.h5md_interval=1.0"]
    runs = {"velocity-verlet": ["--set", 'integrator.method="velocity-verlet"', "--set", "integrator.h=0.0005"],
            "fixman": []}
    with tempfile.TemporaryDirectory() as tmp:
        procs = {m: subprocess.Popen([stiffmd, "run", str(DECK), "-o", str(pathlib.Path(tmp) / m)] + common + extra,
                                     env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
                 for m, extra in runs.items()}
        results = {}
        for m, proc in procs.items():
            _, err = proc.communicate()
            if proc.returncode != 0:
                print(f"{m} failed (exit {proc.returncode}): {err}")
                return 1
            results[m] = measure(pathlib.Path(tmp) / m)
    ok = True
    for k, name in enumerate(("density", "mean cos(bond angle)")):
        (a, sa), (b, sb) = results["velocity-verlet"][k], results["fixman"][k]
        sigma = np.hypot(sa, sb)
        print(f"{name}: velocity Verlet {a:.5f} ± {sa:.5f}, fixman {b:.5f} ± {sb:.5f}: "
              f"difference {(b - a) / sigma:+.2f} σ")
        ok = ok and abs(b - a) < 3 * sigma
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
