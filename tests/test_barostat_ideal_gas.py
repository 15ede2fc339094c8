"""The C-rescale barostat on an ideal gas of N rigid trimers (tests/decks/ideal_gas_npt.toml).

No pair forces: the molecular virial is zero and the molecules' centres are an ideal gas, whose
isothermal-isobaric volume law for the measure dV is p(V) ∝ V^N exp(−P₀V/kT) (docs/design.md,
"Constant pressure"): ⟨V⟩ = (N+1) kT/P₀, Var V = (N+1) (kT/P₀)². The measured mean and variance
must be within 3 standard errors (batch means) of the law, for the method and coupling given.

Per axis (anisotropic), the volume obeys the same law, but nothing holds the box's shape: for an
ideal gas the log-aspect ratios diffuse freely (rate 2/(3(N+1)) per τ_p), the lengths drift over
decades and the coordinates with them. So that run is 400 τ_p (20 batches) instead of 4000 (40),
and the test also asks that each axis moved on its own.

    test_barostat_ideal_gas.py STIFFMD METHOD COUPLING
"""
import pathlib
import subprocess
import sys
import tempfile

import numpy as np

HERE = pathlib.Path(__file__).resolve().parent
DECK = HERE / "decks" / "ideal_gas_npt.toml"
N, KT, P0 = 20, 1.0, 0.1  # the deck's molecules, temperature and pressure


def main():
    stiffmd, method, coupling = sys.argv[1:4]
    t_end, batches = (4000, 40) if coupling == "isotropic" else (400, 20)
    with tempfile.TemporaryDirectory() as out:
        run = subprocess.run([stiffmd, "run", str(DECK), "-o", out, "--quiet", "--set", f"integrator.method=\"{method}\"",
                              "--set", f"barostat.coupling=\"{coupling}\"", "--set", f"run.t_end={t_end}"],
                             capture_output=True, text=True)
        if run.returncode != 0:
            print(run.stdout, run.stderr)
            return 1
        d = np.genfromtxt(pathlib.Path(out) / "thermo.csv", delimiter=",", names=True)
    v = d["volume"][d["time"] >= 20.0]  # the first 20 τ_p: the approach from the deck's box
    v = v[: len(v) // batches * batches].reshape(batches, -1)
    means, variances = v.mean(axis=1), v.var(axis=1)
    mean, mean_se = means.mean(), means.std(ddof=1) / np.sqrt(batches)
    var, var_se = v.var(), variances.std(ddof=1) / np.sqrt(batches)
    want_mean, want_var = (N + 1) * KT / P0, (N + 1) * (KT / P0) ** 2
    print(f"{method} {coupling}: <V> = {mean:.2f} ± {mean_se:.2f} (law {want_mean:.1f}), "
          f"Var V = {var:.0f} ± {var_se:.0f} (law {want_var:.0f})")
    ok = abs(mean - want_mean) < 3 * mean_se and abs(var - want_var) < 3 * var_se
    ratios = [np.ptp(np.log(d[a] / d["lx"])) for a in ("ly", "lz")]
    if coupling == "isotropic":  # one factor for all three axes: the shape is the deck's
        ok = ok and max(ratios) < 1e-9
    else:
        ok = ok and min(ratios) > 0.1
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
