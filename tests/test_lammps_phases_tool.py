#!/usr/bin/python3
"""Smoke test: tools/lammps_phases.py on in.chain with tiny settings (20 steps, one repeat).

    /usr/bin/python3 tests/test_lammps_phases_tool.py build/stiffmd

Checks that the printed table has every common row (pair, bond, neighbour, integrate/thermostat,
kspace, other, total, CPU) with each engine's seconds, that the times in.chain exercises (pair, bond,
neighbour, integrate/thermostat and the loop) are positive in both engines and none negative, that
every ratio printed is the quotient of its row's times, that the machine line names the load
before and after, and that --decks hands each binary its own deck (one per binary). Exits 77 (ctest SKIP_RETURN_CODE) when LAMMPS (`lmp`) or data.chain is not installed."""
import json
import math
import os
import shutil
import subprocess
import sys
import tempfile

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.join(ROOT, "tools"))
from kremer_grest_lammps import CHAIN_DATA  # noqa: E402  (tools/ on the path)

ROWS = ["pair", "bond", "neighbour", "integrate/thermostat", "kspace", "other", "total (loop)", "CPU (loop)"]
EXERCISED = ["pair", "bond", "neighbour", "integrate/thermostat", "total (loop)", "CPU (loop)"]


def main():
    exe = os.path.abspath(sys.argv[1]) if len(sys.argv) > 1 else os.path.join(ROOT, "build", "stiffmd")
    if shutil.which("lmp") is None or not os.path.exists(CHAIN_DATA):
        print("lammps phases tool: skipped, LAMMPS (lmp) or data.chain (Debian lammps-examples) not installed")
        sys.exit(77)
    with tempfile.TemporaryDirectory() as d:
        out = os.path.join(d, "phases.json")
        p = subprocess.run(["/usr/bin/python3", os.path.join(ROOT, "tools", "lammps_phases.py"), "--stiffmd", exe,
                            "--case", "chain", "--steps", "20", "--repeats", "1", "--json", out],
                           capture_output=True, text=True)
        assert p.returncode == 0, p.stdout[-2000:] + p.stderr[-2000:]
        lines = p.stdout.splitlines()
        assert any(line.startswith("machine: ") and " before " in line and ", after " in line for line in lines), p.stdout
        table = {}
        for line in lines:
            cells = [c.strip() for c in line.strip().strip("|").split("|")]
            if line.startswith("| ") and cells[0] in ROWS:
                table[cells[0]] = cells
        assert sorted(table) == sorted(ROWS), p.stdout
        with open(out) as f:
            result = json.load(f)
        assert result["steps"] == 20 and result["repeats"] == 1, result
        medians = result["medians"]
        for row, cells in table.items():
            s, lmp, ratio = medians["stiffmd"][row], medians["LAMMPS"][row], cells[3]
            assert math.isclose(float(cells[1]), s, abs_tol=6e-5) and math.isclose(float(cells[2]), lmp, abs_tol=6e-5), (
                row, cells, s, lmp)
            assert s >= 0 and lmp >= 0, (row, cells)
            if row in EXERCISED:
                assert s > 0 and lmp > 0, (row, cells)
            if lmp > 0:
                assert math.isclose(float(ratio), s / lmp, abs_tol=0.006), (row, cells, s, lmp)
            else:
                assert ratio == "—", (row, cells)
        for engine in ("stiffmd", "LAMMPS"):
            assert all(result["repeats_seconds"][engine][row] == [medians[engine][row]] for row in ROWS), result
        # Two binaries (a build before and after a change): a column each, both run in the repeat.
        p = subprocess.run(["/usr/bin/python3", os.path.join(ROOT, "tools", "lammps_phases.py"), "--stiffmd", exe, exe,
                            "--case", "chain", "--steps", "10", "--repeats", "1", "--json", out],
                           capture_output=True, text=True)
        assert p.returncode == 0, p.stdout[-2000:] + p.stderr[-2000:]
        header = next(line for line in p.stdout.splitlines() if line.startswith("| phase |"))
        for name in ("stiffmd 1", "stiffmd 2"):
            assert f"| {name} (s) |" in header and f"| {name} / LAMMPS |" in header, header
            assert f"{name}: {exe}" in p.stdout, p.stdout
        with open(out) as f:
            result = json.load(f)
        assert len(result["medians"]) == 3 and all(result["medians"][e]["pair"] > 0 for e in result["medians"]), result
        # --decks: one deck per binary (each run reads its own), refused when the counts differ.
        deck = os.path.join(ROOT, "inputs", "kremer_grest.toml")
        p = subprocess.run(["/usr/bin/python3", os.path.join(ROOT, "tools", "lammps_phases.py"), "--stiffmd", exe, exe,
                            "--decks", deck, os.path.join(d, "missing.toml"), "--case", "chain", "--steps", "10",
                            "--repeats", "1"], capture_output=True, text=True)
        assert p.returncode != 0 and "missing.toml" in p.stdout + p.stderr, p.stdout[-2000:] + p.stderr[-2000:]
        p = subprocess.run(["/usr/bin/python3", os.path.join(ROOT, "tools", "lammps_phases.py"), "--stiffmd", exe,
                            "--decks", deck, deck, "--case", "chain"], capture_output=True, text=True)
        assert p.returncode == 2 and "one deck per --stiffmd binary" in p.stderr, p.stderr
    print("1 passed, 0 failed")


if __name__ == "__main__":
    main()
