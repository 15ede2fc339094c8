#!/usr/bin/python3
"""Smoke test: tools/headline_ratio.py with tiny settings (ε = 1e-2, 3 steps, one repeat).

    /usr/bin/python3 tests/test_headline_ratio_tool.py build/stiffmd

Checks the table row (positive costs, the ratio their quotient), that velocity Verlet ran at 0.9 ε
and the thermal stiff limit with the OBABO splitting at h = 0.02. Exits 77 (ctest
SKIP_RETURN_CODE) when LAMMPS's data.chain is not installed."""
import json
import math
import os
import subprocess
import sys
import tempfile

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
DATA_CHAIN = "/usr/share/lammps/examples/COUPLE/multiple/data.chain"  # inputs/lammps_chain.toml imports it


def main():
    exe = os.path.abspath(sys.argv[1]) if len(sys.argv) > 1 else os.path.join(ROOT, "build", "stiffmd")
    if not os.path.exists(DATA_CHAIN):
        print(f"headline ratio tool: skipped, {DATA_CHAIN} not installed (Debian package lammps-examples)")
        sys.exit(77)
    with tempfile.TemporaryDirectory() as d:
        p = subprocess.run(["/usr/bin/python3", os.path.join(ROOT, "tools", "headline_ratio.py"), "--stiffmd", exe,
                            "--eps", "1e-2", "--steps", "3", "--repeats", "1", "--out", d],
                           capture_output=True, text=True)
        assert p.returncode == 0, p.stdout[-2000:] + p.stderr[-2000:]
        row = next(line for line in p.stdout.splitlines() if line.startswith("| 0.01 |"))
        vv, m, ratio = (float(c) for c in row.strip("|").split("|")[1:4])
        assert vv > 0 and m > 0 and math.isclose(ratio, vv / m, rel_tol=0.06), row
        runs = os.path.join(d, "headline")
        with open(os.path.join(runs, "eps0.01_velocity-verlet_r0", "summary.json")) as f:
            s = json.load(f)
        assert s["method"] == "velocity-verlet" and math.isclose(s["h"], 0.009, rel_tol=1e-9), s
        with open(os.path.join(runs, "eps0.01_fixman-obabo_r0", "summary.json")) as f:
            s = json.load(f)
        assert s["method"] == "fixman" and math.isclose(s["h"], 0.02, rel_tol=1e-9), s
        with open(os.path.join(runs, "eps0.01_fixman-obabo_r0", "command.txt")) as f:
            assert 'thermostat.splitting="obabo"' in f.read()
    print("1 passed, 0 failed")


if __name__ == "__main__":
    main()
