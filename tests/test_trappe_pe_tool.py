#!/usr/bin/python3
"""End to end: tools/trappe_pe.py compare on the bundled TraPPE-UA state, runs of 0.3 ps (≈ 10 s).

Usage: test_trappe_pe_tool.py [STIFFMD]   (default build/stiffmd)

The reference is stiffmd's velocity Verlet at 1 fs (so no LAMMPS is needed); the LAMMPS respa row
is added when `lmp` is on PATH. Checks that every setting ran once per seed with its own seed (the
per-seed values differ, the cached results carry the seeds), that a setting's mean and error are the
mean over seeds and s/√K of the per-seed values, that "keeps" is the criterion the tool states
(every |Δ| ≤ 3 s_p √(1/K + 1/K_ref), s_p the pooled seed spread) recomputed here, that the table has a
row per setting and the figure is written, and that too few seeds are refused.
"""
import json
import math
import os
import shutil
import subprocess
import sys
import tempfile

from checklist import finish, test

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
TOOL = os.path.join(ROOT, "tools", "trappe_pe.py")
DATA = os.path.join(ROOT, "inputs", "trappe_pe.data")
OBSERVABLES = ("energy", "pressure", "trans", "r2", "rg2")
SEEDS, REF_SEEDS = 2, 3

exe = sys.argv[1] if len(sys.argv) > 1 else os.path.join(ROOT, "build", "stiffmd")
tmp = tempfile.TemporaryDirectory()
out, fig = os.path.join(tmp.name, "out"), os.path.join(tmp.name, "pe.png")
lammps = ["--lammps", "2"] if shutil.which("lmp") else ["--lammps", ""]
cmd = ["/usr/bin/python3", TOOL, "compare", DATA, out, "--ps", "0.3", "--skip-ps", "0.05", "--frame-fs", "50",
       "--seeds", str(SEEDS), "--reference-seeds", str(REF_SEEDS), "--reference", "stiffmd", "--stiffmd-binary", exe,
       "--stiffmd", "impulse=2,4", "--stiffmd", "rattle=2", "--figure", fig] + lammps
run = subprocess.run(cmd, capture_output=True, text=True)


def results():
    with open(os.path.join(out, "results.json")) as f:
        return json.load(f)


@test
def tool_succeeds_and_writes_its_outputs():
    assert run.returncode == 0, f"exit {run.returncode}\n{run.stdout[-3000:]}\n{run.stderr[-3000:]}"
    assert os.path.getsize(os.path.join(out, "table.md")) > 0
    assert os.path.getsize(fig) > 10000, "figure too small"


@test
def every_setting_ran_once_per_seed_with_its_own_seed():
    r = results()
    settings = [(r["reference"], REF_SEEDS, "stiffmd_verlet_1fs")] + [
        (run_["result"], SEEDS, run_["method"].replace(" ", "_") + f"_{run_['h']:g}fs") for run_ in r["runs"]]
    assert len(r["runs"]) == 3 + (1 if shutil.which("lmp") else 0), [x["method"] for x in r["runs"]]
    for res, k, name in settings:
        assert res is not None, name
        assert res["seeds"] == k, (name, res["seeds"])
        for o in OBSERVABLES:
            assert len(res["per_seed"][o]) == k, (name, o)
        # Different thermostat seeds make different trajectories: the energy averages differ.
        assert len(set(res["per_seed"]["energy"])) == k, (name, res["per_seed"]["energy"])
        seeds = []
        for j in range(k):
            with open(os.path.join(out, name, f"seed{j}", "result.json")) as f:
                seeds.append(json.load(f)["key"]["seed"])
        assert seeds == [r["settings"]["first_seed"] + j for j in range(k)], (name, seeds)


@test
def mean_and_error_are_the_mean_over_seeds_and_s_over_root_k():
    r = results()
    for res in [r["reference"]] + [x["result"] for x in r["runs"]]:
        for o in OBSERVABLES:
            v = res["per_seed"][o]
            k = len(v)
            mean = sum(v) / k
            s = math.sqrt(sum((a - mean) ** 2 for a in v) / (k - 1))
            assert math.isclose(res[o][0], mean, rel_tol=1e-12, abs_tol=1e-12), (o, res[o], mean)
            assert math.isclose(res[o][1], s / math.sqrt(k), rel_tol=1e-9, abs_tol=1e-15), (o, res[o], s)


@test
def keeps_is_the_pooled_three_sigma_criterion():
    r = results()
    ref = r["reference"]["per_seed"]
    for x in r["runs"]:
        verdict = True
        for o in OBSERVABLES:
            a, b = x["result"]["per_seed"][o], ref[o]
            ka, kb = len(a), len(b)
            ma, mb = sum(a) / ka, sum(b) / kb
            sp2 = (sum((v - ma) ** 2 for v in a) + sum((v - mb) ** 2 for v in b)) / (ka + kb - 2)
            z = (ma - mb) / math.sqrt(sp2 * (1 / ka + 1 / kb))
            assert math.isclose(z, x["z"][o], rel_tol=1e-9, abs_tol=1e-9), (x["method"], x["h"], o, z, x["z"][o])
            verdict = verdict and abs(z) <= 3.0
        assert x["keeps"] == verdict, (x["method"], x["h"], x["z"])


@test
def table_has_a_row_per_setting():
    with open(os.path.join(out, "table.md")) as f:
        text = f.read()
    assert "| stiffmd | velocity verlet (reference) | 1 |" in text
    for m, h in (("impulse", 2), ("impulse", 4), ("rattle", 2)):
        assert f"| stiffmd | {m} | {h} |" in text, (m, h)
    assert "Largest outer step" in text


@test
def too_few_seeds_are_refused():
    p = subprocess.run(["/usr/bin/python3", TOOL, "compare", DATA, os.path.join(tmp.name, "bad"), "--seeds", "1",
                        "--reference", "stiffmd", "--lammps", "", "--stiffmd-binary", exe],
                       capture_output=True, text=True)
    assert p.returncode != 0 and "at least 2" in p.stderr, (p.returncode, p.stderr[-500:])
    assert "Traceback" not in p.stderr


finish()
