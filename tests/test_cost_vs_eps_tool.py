#!/usr/bin/python3
"""End to end: tools/cost_vs_eps.py --quick (8 chains of 20 beads, ε = 1e-2 and 3e-3, ≈ 10 s).

Usage: test_cost_vs_eps_tool.py [STIFFMD]   (default build/stiffmd)

Checks that the ladder, the cost table, the markdown table and the figure are written, that every
method's ladder climbs (steps increasing, velocity Verlet's first step the reference at 0.2 ε, the
micro-step methods' n = ceil(h / (ε/10))) and stops at its first failing step, that the pass/fail of
every run is the criterion the tool states (|Δ| < 3 σ_combined recomputed here from the CSV's means
and block errors; Rg's paired z within 3), and that each (ε, method) was timed at its largest passing
step, or at its first step when none passed. The LAMMPS rows are checked when `lmp` is on PATH.
"""
import csv
import math
import os
import shutil
import subprocess
import sys
import tempfile

from checklist import finish, test

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
TOOL = os.path.join(ROOT, "tools", "cost_vs_eps.py")
EPS = [0.01, 0.003]
METHODS = ["velocity-verlet", "impulse", "projected-impulse", "mollified-impulse", "rattle", "fixman"]
MICRO = {"impulse", "projected-impulse", "mollified-impulse", "lammps-respa"}
if shutil.which("lmp"):
    METHODS.append("lammps-respa")

exe = sys.argv[1] if len(sys.argv) > 1 else os.path.join(ROOT, "build", "stiffmd")
tmp = tempfile.TemporaryDirectory()
out, fig = os.path.join(tmp.name, "out"), os.path.join(tmp.name, "fig", "cost.png")
run = subprocess.run(["/usr/bin/python3", TOOL, "--quick", "--stiffmd", exe, "--out", out, "--figure", fig,
                      "--jobs", "1"], capture_output=True, text=True)


def rows(name):
    with open(os.path.join(out, name)) as f:
        return list(csv.DictReader(f))


def ladders():
    table = {}
    for r in rows("ladder.csv"):
        table.setdefault((float(r["eps"]), r["method"]), []).append(r)
    return table


@test
def tool_succeeds_and_writes_its_outputs():
    assert run.returncode == 0, f"exit {run.returncode}\n{run.stdout[-3000:]}\n{run.stderr[-3000:]}"
    for name in ("ladder.csv", "cost.csv", "cost_vs_eps.md"):
        assert os.path.getsize(os.path.join(out, name)) > 0, name
    assert os.path.getsize(fig) > 10000, "figure too small"


@test
def every_method_climbs_its_ladder_and_stops_at_the_first_failure():
    table = ladders()
    assert sorted(table) == sorted((e, m) for e in EPS for m in METHODS), sorted(table)
    for (eps, method), rs in table.items():
        hs = [float(r["h"]) for r in rs]
        assert all(b > a for a, b in zip(hs, hs[1:])), (eps, method, hs)
        if method == "velocity-verlet":
            assert math.isclose(hs[0], 0.2 * eps), hs
            assert rs[0]["passed"] == "True"  # the reference
        for r in rs:
            n_expected = math.ceil(float(r["h"]) / (eps / 10) * (1 - 1e-9)) if method in MICRO else 1
            assert int(r["n"]) == n_expected, r
        passed = [r["passed"] == "True" for r in rs]
        assert all(passed[:-1]), (eps, method, passed)  # only the last step may fail: the climb stops there


@test
def pass_is_three_sigma_combined_against_the_reference():
    table = ladders()
    for (eps, method), rs in table.items():
        ref = table[(eps, "velocity-verlet")][0]
        for r in rs:
            if r is ref:
                continue
            if r["status"] != "ok":
                assert r["passed"] == "False", r
                continue
            z = {}
            for q in ("cos", "cos2", "pressure"):
                z[q] = (float(r[q]) - float(ref[q])) / math.hypot(float(r[q + "_err"]), float(ref[q + "_err"]))
                assert math.isclose(z[q], float(r[q + "_z"]), rel_tol=1e-6, abs_tol=1e-9), (q, z[q], r)
            z["rg"] = float(r["rg_z"])
            assert math.isfinite(z["rg"]), r
            assert (r["passed"] == "True") == all(abs(v) < 3.0 for v in z.values()), (z, r)


@test
def each_method_is_timed_at_its_largest_passing_step():
    table = ladders()
    cost = rows("cost.csv")
    assert len(cost) == len(table), (len(cost), len(table))
    for c in cost:
        rs = table[(float(c["eps"]), c["method"])]
        ok = [r for r in rs if r["passed"] == "True"]
        expected = ok[-1] if ok else rs[0]
        assert math.isclose(float(c["h"]), float(expected["h"])) and int(c["n"]) == int(expected["n"]), (c, expected)
        for k in ("cpu_per_time", "wall_per_time"):
            assert math.isfinite(float(c[k])) and float(c[k]) > 0, c


@test
def markdown_has_a_row_per_eps_and_method():
    with open(os.path.join(out, "cost_vs_eps.md")) as f:
        text = f.read()
    for eps in EPS:
        for m in METHODS:
            assert f"| {eps:g} | {m} |" in text, (eps, m)


finish()
