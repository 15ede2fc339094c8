#!/usr/bin/python3
"""End to end: tools/work_precision_melt.py --quick on the LAMMPS chain melt (≈ 20 s).

Usage: test_work_precision_tool.py [STIFFMD]   (default build/stiffmd)

Checks that the short-horizon, energy-drift and resonance-scan CSVs have the expected rows with
positive finite numbers, that the summary is written and that both figures land in the directory
given by --figures (never docs/figures). The LAMMPS part of the scan runs when `lmp` is on PATH.
"""
import csv
import math
import os
import shutil
import subprocess
import sys
import tempfile
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
TOOL = os.path.join(ROOT, "tools", "work_precision_melt.py")
IMPULSE = ["impulse", "mollified-impulse", "projected-impulse"]


def rows_of(path):
    assert os.path.exists(path), f"missing {path}"
    with open(path) as f:
        return list(csv.DictReader(f))


def positive_finite(row, keys, where):
    for k in keys:
        v = float(row[k])
        assert math.isfinite(v) and v > 0, f"{where}: {k} = {row[k]!r} in {row}"


def main():
    exe = sys.argv[1] if len(sys.argv) > 1 else os.path.join(ROOT, "build", "stiffmd")
    have_lmp = shutil.which("lmp") is not None
    start = time.monotonic()
    with tempfile.TemporaryDirectory() as d:
        out, figs = os.path.join(d, "out"), os.path.join(d, "figs")
        p = subprocess.run(["/usr/bin/python3", TOOL, "--quick", "--eps", "0.01", "--stiffmd", exe, "--out", out,
                            "--figures", figs], capture_output=True, text=True)
        assert p.returncode == 0, f"exit {p.returncode}\n{p.stdout[-3000:]}\n{p.stderr[-3000:]}"

        # Short horizon: the reference, 3 impulse methods at the one macro step, velocity Verlet at one δ.
        short = rows_of(os.path.join(out, "short_eps0.01.csv"))
        assert [r["method"] for r in short] == ["reference-vv"] + IMPULSE + ["velocity-verlet"], short
        for r in short:
            assert r["status"] == "ok", r
            assert abs(float(r["t_end"]) - 0.01) < 1e-12, r
        for r in short[1:]:
            positive_finite(r, ["h", "n", "micro_dt", "steps", "cpu_seconds", "err_rms", "err_max", "err_com_rms"],
                            "short")
            assert float(r["err_rms"]) <= float(r["err_max"]) < 0.1, r  # errors after 0.01 time units are tiny
            if r["method"] in IMPULSE:
                assert float(r["micro_dt"]) <= 0.01 / 40 * (1 + 1e-9), r
        positive_finite(short[0], ["h", "cpu_seconds"], "reference")

        # Energy drift: the same 4 runs.
        long_rows = rows_of(os.path.join(out, "long_eps0.01.csv"))
        assert sorted(r["method"] for r in long_rows) == sorted(IMPULSE + ["velocity-verlet"]), long_rows
        for r in long_rows:
            assert r["status"] == "ok", r
            positive_finite(r, ["h", "steps", "cpu_seconds", "drift_max_per_atom", "final_temperature"], "long")
            assert float(r["drift_max_per_atom"]) < 0.1 and 0.5 < float(r["final_temperature"]) < 2, r

        # Resonance scan: 3 values of h/T_min × (LAMMPS respa +) 4 stiffmd methods.
        scan = rows_of(os.path.join(out, "scan_eps0.01.csv"))
        codes = (["respa"] if have_lmp else []) + ["impulse", "projected-impulse", "mollified-impulse", "rattle"]
        assert len(scan) == 3 * len(codes), scan
        assert sorted({float(r["h_over_tmin"]) for r in scan}) == [0.25, 0.5, 1.0], scan
        assert sorted({r["method"] for r in scan}) == sorted(codes), scan
        for r in scan:
            assert r["status"] == "ok", r
            positive_finite(r, ["h", "n", "steps", "t_end", "drift_max_per_atom", "final_temperature"], "scan")
            if r["method"] != "respa":
                positive_finite(r, ["cpu_seconds"], "scan")
        if have_lmp:
            # LAMMPS respa and stiffmd impulse are the same algorithm on the same state: same energies.
            for q in (0.25, 0.5, 1.0):
                pair = {r["method"]: float(r["drift_max_per_atom"]) for r in scan if float(r["h_over_tmin"]) == q}
                assert abs(pair["respa"] - pair["impulse"]) <= 1e-6 * max(1.0, pair["impulse"]) + 1e-9, pair

        summary = open(os.path.join(out, "summary.md")).read()
        for text in ("## ε = 0.01", "Cheapest run", "Energy drift", "Resonance scan"):
            assert text in summary, text
        for name in ("work_precision_melt.png", "resonance_melt.png"):
            path = os.path.join(figs, name)
            assert os.path.getsize(path) > 20000, path
        assert "figure: " + os.path.join(figs, "work_precision_melt.png") in p.stdout, p.stdout[-2000:]
    seconds = time.monotonic() - start
    assert seconds < 90, f"took {seconds:.0f} s"
    print(f"work_precision tool: 1 passed, 0 failed ({seconds:.0f} s)")


if __name__ == "__main__":
    main()
