#!/usr/bin/python3
"""Smoke test: tools/bench_lammps.py with tiny settings (2 macro steps of 2 micro steps, one repeat).

    /usr/bin/python3 tests/test_bench_tool.py build/stiffmd

Checks the table has the five rows (four when LAMMPS is not installed) with positive times and
memory, finite drifts, that LAMMPS and stiffmd start from the same energy, and that bench.csv holds
every run. Exits 77 (ctest SKIP_RETURN_CODE) when LAMMPS's data.chain is not installed."""
import csv
import math
import os
import shutil
import subprocess
import sys
import tempfile

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
DATA_CHAIN = "/usr/share/lammps/examples/COUPLE/multiple/data.chain"  # inputs/lammps_chain.toml imports it
STIFFMD_ROWS = ["stiffmd impulse", "stiffmd projected-impulse", "stiffmd mollified-impulse", "stiffmd velocity-verlet"]


def table_rows(markdown):
    """{first cell: [cells]} of the markdown table's body rows."""
    rows = {}
    for line in markdown.splitlines():
        if line.startswith("| ") and not line.startswith("| code/method"):
            cells = [c.strip() for c in line.strip("|").split(" | ")]
            rows[cells[0]] = cells
    return rows


def main():
    exe = os.path.abspath(sys.argv[1]) if len(sys.argv) > 1 else os.path.join(ROOT, "build", "stiffmd")
    if not os.path.exists(DATA_CHAIN):
        print(f"bench tool: skipped, {DATA_CHAIN} not installed (Debian package lammps-examples)")
        sys.exit(77)
    have_lammps = shutil.which("lmp") is not None
    with tempfile.TemporaryDirectory() as d:
        p = subprocess.run(["/usr/bin/python3", os.path.join(ROOT, "tools", "bench_lammps.py"), "--stiffmd", exe,
                            "--steps", "2", "--repeats", "1", "--eps", "0.01", "--threads", "1", "--micro-steps", "2",
                            "--out", d], capture_output=True, text=True, timeout=120)
        assert p.returncode == 0, p.stdout + p.stderr
        assert p.stdout.startswith("command: "), p.stdout
        assert "machine: " in p.stdout, p.stdout
        with open(os.path.join(d, "bench_eps0.01.md")) as f:
            markdown = f.read()
        assert markdown.split("\n\n", 1)[1] in p.stdout  # the file: the command and machine, then the table
        rows = table_rows(markdown)
        expected = (["lammps-respa"] if have_lammps else []) + STIFFMD_ROWS
        assert list(rows) == expected, (list(rows), markdown)
        for name, cells in rows.items():
            # code/method, threads, h, n, ms, ÷ LAMMPS, ÷ impulse, CPU use, RSS, drift end, drift max, relative max
            threads, h, n, ms, vs_lammps, vs_impulse, cpu, rss, d_end, d_max, d_rel = cells[1:]
            assert threads == "1" and n == ("1" if "verlet" in name else "2"), cells
            assert float(h) == (0.0025 if "verlet" in name else 0.005), cells
            assert 0 < float(ms) < 10000 and 1 < float(rss) < 10000 and 0 < float(cpu.rstrip("%")) < 10000, cells
            for ratio in ([vs_lammps] if have_lammps else []) + [vs_impulse]:
                assert 0 < float(ratio) < 1000, cells
            if not have_lammps:
                assert vs_lammps == "n/a", cells
            for drift in (d_end, d_max, d_rel):
                assert math.isfinite(float(drift)) and 0 <= float(drift) < 0.1, cells
            assert float(d_end) <= float(d_max), cells
        assert rows["stiffmd impulse"][6] == "1.00", rows
        if have_lammps:
            assert "largest relative difference" in markdown and "MORE THAN" not in markdown, markdown
        with open(os.path.join(d, "bench.csv")) as f:
            raw = list(csv.DictReader(f))
        assert len(raw) == len(expected), raw
        assert all(int(r["natoms"]) == 32000 and float(r["loop_seconds"]) > 0 for r in raw), raw
    print("bench tool: 1 passed, 0 failed")


if __name__ == "__main__":
    main()
