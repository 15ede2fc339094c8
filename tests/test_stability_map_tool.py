#!/usr/bin/python3
"""Smoke test of tools/stability_map.py (run by ctest; a few seconds): the double pendulum at
ε = 0.01, impulse and projected impulse at h = 1/64 and h = 2πε (one fast period of mode 1, the
impulse method's resonance), t_end = 10. Checks the CSV, the largest-stable-step table, the
figure, and --plot-only."""
import csv
import math
import os
import subprocess
import sys
import tempfile

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
COLUMNS = ["eps", "method", "h", "h_over_period", "energy_error", "violation", "action_drift", "status"]


def main():
    exe = sys.argv[1] if len(sys.argv) > 1 else os.path.join(ROOT, "build", "stiffmd")
    env = dict(os.environ, OMP_NUM_THREADS="1", OMP_WAIT_POLICY="passive")
    tool = os.path.join(ROOT, "tools", "stability_map.py")
    with tempfile.TemporaryDirectory() as d:
        png = os.path.join(d, "map.png")
        args = ["/usr/bin/python3", tool, os.path.join(ROOT, "inputs", "double_pendulum.toml"), "-o", d, "--stiffmd",
                exe, "--methods", "impulse,projected-impulse", "--h", "1/64,2*pi*eps", "--eps", "1e-2", "--t-end", "10",
                "--omega-max", "1.618", "--png", png, "--jobs", "2"]
        p = subprocess.run(args, capture_output=True, text=True, env=env)
        assert p.returncode == 0, p.stdout + p.stderr
        with open(os.path.join(d, "stability.csv")) as f:
            rows = list(csv.DictReader(f))
        assert len(rows) == 4, rows
        for c in COLUMNS:
            assert c in rows[0], f"missing column {c}"

        def row(method, h):
            return next(r for r in rows if r["method"] == method and abs(float(r["h"]) - h) < 1e-9)

        res = 2 * math.pi * 0.01
        for r in rows:
            assert abs(float(r["h_over_period"]) - float(r["h"]) / (2 * math.pi * 0.01 / 1.618)) < 1e-9, r
            assert float(r["energy_error"]) >= 0 and float(r["violation"]) > 0, r
        # The impulse method's resonance at h = 2πε (energy error ≈ 0.8); the projected kick's is not.
        bad = row("impulse", res)
        assert bad["status"] == "unbounded" and "energy" in bad["reason"], bad
        assert float(bad["energy_error"]) > 0.3, bad
        for r in (row("impulse", 1 / 64), row("projected-impulse", 1 / 64), row("projected-impulse", res)):
            assert r["status"] == "bounded", r
            assert float(r["energy_error"]) < 0.02 and float(r["action_drift"]) < 0.1, r
        with open(os.path.join(d, "largest_stable_h.csv")) as f:
            table = {r["method"]: r for r in csv.DictReader(f)}
        assert abs(float(table["impulse"]["largest_stable_h"]) - 1 / 64) < 1e-12, table
        assert abs(float(table["impulse"]["first_failing_h"]) - res) < 1e-9, table
        assert abs(float(table["projected-impulse"]["largest_stable_h"]) - res) < 1e-9, table
        assert "| impulse | 0.01562" in open(os.path.join(d, "largest_stable_h.md")).read()
        assert os.path.getsize(png) > 10000, png
        # Re-plot from the CSV alone.
        os.remove(png)
        p = subprocess.run(args + ["--plot-only"], capture_output=True, text=True, env=env)
        assert p.returncode == 0 and os.path.getsize(png) > 10000, p.stdout + p.stderr
    print("stability map tool: 1 passed, 0 failed")


if __name__ == "__main__":
    main()
