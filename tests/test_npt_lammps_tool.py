#!/usr/bin/python3
"""The plumbing of tools/npt_lammps.py: its --quick comparison (200 chains of 5 beads, t = 10, both
engines) and its --quick --cost mode, not the physics targets (docs/performance.md has the runs).

Usage: test_npt_lammps_tool.py [STIFFMD]   (default build/stiffmd)

Checks that both engines ran every step from the one data file stiffmd wrote, that every reported
number parses and is finite (density, κ_T and their errors, pressures, temperatures, τ_int), that the
printed verdicts are the tool's, and that --cost times every setting and writes cost.json. Exits 77
(ctest SKIP_RETURN_CODE) when /usr/bin/lmp is absent."""
import json
import math
import os
import subprocess
import sys
import tempfile

from checklist import finish, test

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
TOOL = os.path.join(ROOT, "tools", "npt_lammps.py")
LMP = "/usr/bin/lmp"
sys.path.insert(0, os.path.join(ROOT, "tools"))

exe = os.path.abspath(sys.argv[1]) if len(sys.argv) > 1 else os.path.join(ROOT, "build", "stiffmd")
if not os.path.exists(LMP):
    print(f"npt_lammps tool: skipped, {LMP} not installed (bash tools/setup.sh --bench)")
    sys.exit(77)
tmp = tempfile.TemporaryDirectory()
out, cost_out = os.path.join(tmp.name, "cmp"), os.path.join(tmp.name, "cost")
run = subprocess.run(["/usr/bin/python3", TOOL, "--quick", "--stiffmd", exe, "--lmp", LMP, "--out", out],
                     capture_output=True, text=True, timeout=300)
cost = subprocess.run(["/usr/bin/python3", TOOL, "--quick", "--cost", "--stiffmd", exe, "--out", cost_out],
                      capture_output=True, text=True, timeout=300)


def comparison():
    with open(os.path.join(out, "comparison.json")) as f:
        return json.load(f)


def finite_pair(v, name):
    assert len(v) == 2 and all(isinstance(x, float) and math.isfinite(x) for x in v), (name, v)
    assert v[1] >= 0.0, (name, v)


@test
def quick_comparison_succeeds():
    assert run.returncode == 0, f"exit {run.returncode}\n{run.stdout[-3000:]}\n{run.stderr[-3000:]}"
    assert "Traceback" not in run.stderr


@test
def both_engines_ran_every_step_from_the_same_data():
    r = comparison()
    data = os.path.join(out, "start", "start.data")
    assert r["data"] == data and os.path.getsize(data) > 0
    assert r["steps"] == {"stiffmd": 2000, "LAMMPS": 2000}, r["steps"]
    with open(os.path.join(out, "stiffmd", "deck.toml")) as f:
        assert f'lammps_data = "{data}"' in f.read()
    with open(os.path.join(out, "lammps", "in.npt")) as f:
        text = f.read()
    assert f"read_data       {data}" in text and "fix             npt all npt temp 1.0 1.0" in text
    with open(os.path.join(out, "lammps", "log.lammps")) as f:
        assert "Loop time of" in f.read()


@test
def every_number_parses_and_is_finite():
    r = comparison()
    for engine in ("stiffmd", "LAMMPS"):
        st = r["stats"][engine]
        for q in ("density", "kappa", "volume", "pressure", "temperature"):
            finite_pair(st[q], f"{engine} {q}")
        assert 0.5 < st["density"][0] < 1.2, (engine, st["density"])
        assert st["kappa"][0] > 0.0 and st["tau_int_volume"] > 0.0, (engine, st)
        assert 2.0 < st["pressure"][0] < 8.0 and 0.8 < st["temperature"][0] < 1.2, (engine, st)
        assert st["samples"] >= st["batches"] == 4, st
    finite_pair(r["stats"]["stiffmd"]["molecular_pressure"], "stiffmd molecular_pressure")
    for d in ("density_difference", "kappa_difference"):
        finite_pair(r[d]["relative"], d)
        assert r[d]["verdict"].split()[0] in ("met", "missed"), r[d]


@test
def the_printed_table_is_the_json():
    r = comparison()
    assert f"density: stiffmd/LAMMPS - 1 = {100 * r['density_difference']['relative'][0]:+.3f} %" in run.stdout
    assert f"kappa_T: stiffmd/LAMMPS - 1 = {100 * r['kappa_difference']['relative'][0]:+.2f} %" in run.stdout


@test
def lammps_log_rows_are_every_thermo_row():
    from npt_lammps import lammps_log
    th, loop, cpu, _ = lammps_log(os.path.join(out, "lammps", "log.lammps"))
    assert loop[1] == 2000 and cpu > 0, (loop, cpu)
    assert len(th["Step"]) == 2000 // 20 + 1 and th["Step"][-1] == 2000, th["Step"][-3:]
    assert set(th) >= {"Time", "Volume", "Density", "Press", "Temp"}


@test
def cost_mode_times_every_setting():
    assert cost.returncode == 0, f"exit {cost.returncode}\n{cost.stdout[-3000:]}\n{cost.stderr[-3000:]}"
    with open(os.path.join(cost_out, "cost.json")) as f:
        c = json.load(f)
    assert list(c["settings"]) == ["none", "interval 10", "interval 25", "interval 50", "interval 100"], list(c["settings"])
    for name, row in c["settings"].items():
        assert row["ms_per_step"] > 0 and math.isfinite(row["overhead_percent"]), (name, row)
    # A move every 10 steps over 50 steps: 4 fresh force evaluations (the last move ends the run).
    assert math.isclose(c["settings"]["interval 10"]["extra_evaluations_per_step"], 4 / 50), c["settings"]["interval 10"]
    assert c["settings"]["interval 100"]["extra_evaluations_per_step"] == 0.0


finish()
