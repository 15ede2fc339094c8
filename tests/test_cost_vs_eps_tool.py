#!/usr/bin/python3
"""End to end: tools/cost_vs_eps.py --quick (8 chains of 20 beads, ε = 1e-2 and 3e-3, 3 seeds per
setting and 3 for the reference, ≈ 5 s).

Usage: test_cost_vs_eps_tool.py [STIFFMD]   (default build/stiffmd)

Checks that the ladder, the cost table, the markdown table and the figure are written, that every
method's ladder climbs (steps increasing, velocity Verlet's first step the reference at 0.2 ε, the
micro-step methods' n = ceil(h / (ε/10))) and stops at its first failing step, that every setting ran
its seeds (distinct thermostat seeds within LAMMPS's 9e8, one value per seed and observable, the mean
the mean over them), that the pass/fail of every run is the criterion the tool states, recomputed here
from the CSV's per-seed values alone (pooled seed standard error s_p √(1/K + 1/K_ref), |z| within the
Student-t quantile of 3σ's two-sided 0.0027 with K + K_ref − 2 degrees of freedom), and that each
(ε, method) was timed at its largest passing step, or at its first step when none passed. The LAMMPS
rows are checked when `lmp` is on PATH. A rerun of the ladders reuses every seed's cached run.
"""
import csv
import glob
import json
import math
import os
import shutil
import subprocess
import sys
import tempfile
import time

from checklist import finish, test

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
TOOL = os.path.join(ROOT, "tools", "cost_vs_eps.py")
EPS = [0.01, 0.003]
METHODS = ["velocity-verlet", "impulse", "projected-impulse", "mollified-impulse", "rattle", "fixman", "rattle-obabo",
           "fixman-obabo"]
MICRO = {"impulse", "projected-impulse", "mollified-impulse", "lammps-respa"}
if shutil.which("lmp"):
    METHODS.append("lammps-respa")
SEEDS, REF_SEEDS = 3, 3  # --quick's
REPEATS = 1  # --quick: one timed run per (ε, method)
# The limit on |z|: Student's t with SEEDS + REF_SEEDS − 2 = 4 degrees of freedom at the two-sided
# tail probability of a 3σ normal test, erfc(3/√2) = 0.0026998 (scipy.stats.t.isf(0.0013499, 4)).
LIMIT = 6.620205978448

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


def per_seed(r, q):
    return [float(v) for v in r[q + "_seeds"].split(";")] if r[q + "_seeds"] else []


def mean(v):
    return sum(v) / len(v)


def pooled(a, b):
    """(z, se) of mean(a) − mean(b) with the pooled variance, computed here from scratch."""
    ma, mb = mean(a), mean(b)
    sp2 = (sum((x - ma) ** 2 for x in a) + sum((x - mb) ** 2 for x in b)) / (len(a) + len(b) - 2)
    se = math.sqrt(sp2 * (1 / len(a) + 1 / len(b)))
    return (ma - mb) / se, se


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
        if passed[-1]:  # and it stops only there: a ladder without a failure is climbed to its top
            assert len(rs) == 2, (eps, method, hs)  # --quick's ladders: two steps (velocity Verlet: ref, 0.4 ε)


@test
def every_setting_ran_its_seeds():
    table = ladders()
    seen = set()
    for (eps, method), rs in table.items():
        for k, r in enumerate(rs):
            reference = method == "velocity-verlet" and k == 0
            want = REF_SEEDS if reference else SEEDS
            seeds = [int(v) for v in r["thermostat_seeds"].split(";")]
            assert all(1 <= v <= 900000000 for v in seeds), seeds  # LAMMPS's limit
            assert not seen & set(seeds), (eps, method, r["h"], seeds)  # every run its own noise
            seen |= set(seeds)
            if r["status"] != "ok":
                continue
            assert int(r["seeds"]) == want == len(seeds), (eps, method, r["h"], r["seeds"], seeds)
            for q in ("cos", "cos2", "rg", "pressure"):
                v = per_seed(r, q)
                assert len(v) == want and len(set(v)) == want, (eps, method, q, v)  # the seeds differ
                assert math.isclose(float(r[q]), mean(v), rel_tol=1e-12, abs_tol=1e-12), (q, r[q], v)


@test
def pass_is_the_pooled_seed_criterion_against_the_reference():
    from scipy.stats import t  # python3-scipy, tools/setup.sh
    assert math.isclose(t.isf(math.erfc(3 / math.sqrt(2)) / 2, SEEDS + REF_SEEDS - 2), LIMIT, rel_tol=1e-8)
    table = ladders()
    for (eps, method), rs in table.items():
        ref = table[(eps, "velocity-verlet")][0]
        for r in rs:
            if r is ref:
                continue
            if r["status"] != "ok":
                assert r["passed"] == "False", r
                continue
            assert math.isclose(float(r["limit"]), LIMIT, rel_tol=1e-8), r["limit"]  # scipy's isf: ≈ 2e-9
            verdict = True
            for q in ("cos", "cos2", "rg", "pressure"):
                z, se = pooled(per_seed(r, q), per_seed(ref, q))
                assert math.isclose(z, float(r[q + "_z"]), rel_tol=1e-6, abs_tol=1e-9), (q, z, r)
                assert math.isclose(se, float(r[q + "_err"]), rel_tol=1e-6), (q, se, r)
                verdict = verdict and abs(z) <= LIMIT
            assert (r["passed"] == "True") == verdict, (eps, method, r["h"], r["passed"], verdict)


@test
def each_method_is_timed_at_its_largest_passing_step():
    """Timed at the largest passing step that also ran on the timing system: the steps tried before it
    (largest first) each failed there with exit 3 and are recorded as such."""
    table = ladders()
    cost = rows("cost.csv")
    timed = {}
    for c in cost:
        timed.setdefault((float(c["eps"]), c["method"]), []).append(c)
    assert set(timed) == set(table), (sorted(timed), sorted(table))
    for key, rs in table.items():
        passing = []
        for r in rs:
            if r["passed"] != "True":
                break
            passing.append(r)
        candidates = [(float(r["h"]), int(r["n"])) for r in passing[::-1]] or [(float(rs[0]["h"]), int(rs[0]["n"]))]
        ok = [c for c in timed[key] if c["status"] == "ok"]
        failed = {float(c["h"]) for c in timed[key] if c["status"] != "ok"}
        assert all(c["status"] == "failed (exit 3)" for c in timed[key] if c["status"] != "ok"), timed[key]
        expected = next(hn for hn in candidates if hn[0] not in failed)
        assert len(ok) == REPEATS and all(math.isclose(float(c["h"]), expected[0]) and int(c["n"]) == expected[1]
                                          for c in ok), (key, ok, expected)
        assert all(f > expected[0] for f in failed), (key, failed, expected)
        for c in ok:
            for k in ("cpu_per_time", "wall_per_time"):
                assert math.isfinite(float(c[k])) and float(c[k]) > 0, c


@test
def a_rerun_reuses_every_seeds_run():
    before = rows("ladder.csv")
    runs = os.path.join(out, "work", "runs")
    kept = [os.path.join(runs, d, s, "row.json") for d in os.listdir(runs) for s in os.listdir(os.path.join(runs, d))]
    assert len(kept) >= len(before) * SEEDS, (len(kept), len(before))
    stamps = {k: os.stat(k).st_mtime_ns for k in kept}
    time.sleep(0.05)
    p = subprocess.run(["/usr/bin/python3", TOOL, "--quick", "--stiffmd", exe, "--out", out, "--figure", fig,
                        "--jobs", "1", "--no-timing"], capture_output=True, text=True)
    assert p.returncode == 0, p.stderr[-2000:]
    assert rows("ladder.csv") == before
    rerun = [k for k in kept if os.stat(k).st_mtime_ns != stamps[k]]
    assert not rerun, f"cached seeds ran again: {rerun[:3]}"


@test
def the_obabo_rows_run_their_method_with_the_obabo_splitting():
    """Every run of rattle-obabo and fixman-obabo (ladder seeds, stability and timed runs) runs the
    engine's rattle or fixman with thermostat.splitting = "obabo"; no other row does."""
    commands = glob.glob(os.path.join(out, "work", "*", "*", "command.txt")) + \
        glob.glob(os.path.join(out, "work", "runs", "*", "*", "command.txt"))
    seen = set()
    for path in commands:
        with open(path) as f:
            cmd = f.read()
        tag = os.path.relpath(path, os.path.join(out, "work")).split(os.sep)[1]
        method = next((m for m in ("rattle-obabo", "fixman-obabo") if f"_{m}_" in tag), None)
        with open(os.path.join(os.path.dirname(path), "run.toml")) as f:
            deck = f.read()
        if method:
            seen.add((os.path.relpath(path, out).split(os.sep)[1], method))
            assert 'thermostat.splitting="obabo"' in cmd, (path, cmd)
            assert f'method = "{method.split("-")[0]}"' in deck, path
        else:
            assert "obabo" not in cmd, (path, cmd)
    for where in ("runs", "timed"):
        for m in ("rattle-obabo", "fixman-obabo"):
            assert (where, m) in seen, (where, m, sorted(seen))


@test
def markdown_has_a_row_per_eps_and_method():
    with open(os.path.join(out, "cost_vs_eps.md")) as f:
        text = f.read()
    for eps in EPS:
        for m in METHODS:
            assert f"| {eps:g} | {m} |" in text, (eps, m)


def blow_up_at_the_larger_step(where, status):
    """A stiffmd that exits 3 in fixman's runs under WHERE/ (timed/ or stable/) at its larger --quick
    step (as fixman at 0.028 did on data.chain): the tool records it as STATUS, times the next smaller
    passing step, and says so in its table."""
    ladder = [r for r in rows("ladder.csv") if r["method"] == "fixman" and float(r["eps"]) == EPS[0]]
    passing = []
    for r in ladder:
        if r["passed"] != "True":
            break
        passing.append(float(r["h"]))
    if len(passing) < 2:
        print("  (skipped: fixman passed fewer than two steps at this ε)")
        return
    limit = 0.5 * (passing[-1] + passing[-2])
    wrapper = os.path.join(tmp.name, f"stiffmd_exits_3_{where}")
    with open(wrapper, "w") as f:
        f.write(f"""#!/bin/bash
# fixman's runs under {where}/ at h above {limit} fail as a blow-up would
deck="$2"
if [[ "$*" == */{where}/* ]] && grep -q 'method = "fixman"' "$deck"; then
  h=$(awk -F' = ' '$1 == "h" {{print $2}}' "$deck")
  if awk -v h="$h" 'BEGIN {{exit !(h > {limit})}}'; then echo "error: numerical failure (test)" >&2; exit 3; fi
fi
exec "{os.path.abspath(exe)}" "$@"
""")
    os.chmod(wrapper, 0o755)
    out2 = os.path.join(tmp.name, f"out_exit3_{where}")
    p = subprocess.run(["/usr/bin/python3", TOOL, "--quick", "--stiffmd", wrapper, "--out", out2, "--figure",
                        os.path.join(tmp.name, f"fig_{where}.png"), "--jobs", "1", "--eps", f"{EPS[0]:g}",
                        "--methods", "fixman"], capture_output=True, text=True)
    assert p.returncode == 0, p.stderr[-2000:]
    with open(os.path.join(out2, "cost.csv")) as f:
        cost = [c for c in csv.DictReader(f) if c["method"] == "fixman"]
    failed = [c for c in cost if c["status"] != "ok"]
    timed = [c for c in cost if c["status"] == "ok"]
    assert [c["status"] for c in failed] == [status], cost
    assert math.isclose(float(failed[0]["h"]), passing[-1]), (failed, passing)
    assert len(timed) == REPEATS and all(math.isclose(float(c["h"]), passing[-2]) for c in timed), (timed, passing)
    with open(os.path.join(out2, "cost_vs_eps.md")) as f:
        row = next(line for line in f if line.startswith(f"| {EPS[0]:g} | fixman |"))
    assert f"{passing[-2]:.4g}" in row and "exit 3 on the timing system" in row, row
    return out2, passing


@test
def a_step_that_blows_up_on_the_timing_system_is_recorded_and_the_next_timed():
    blow_up_at_the_larger_step("timed", "failed (exit 3)")


@test
def a_step_that_fails_its_stability_run_is_not_timed():
    """The stability run comes first: its failure alone stops the step (no timed run of it), and it
    is max(--timed-steps, min(--stable-time / h, --stable-steps)) steps long."""
    done = blow_up_at_the_larger_step("stable", "failed (exit 3 in the stability run)")
    if done is None:
        return
    out2, passing = done
    runs = glob.glob(os.path.join(out2, "work", "stable", "*", "stable.json"))
    assert runs, "no stability run recorded"
    for path in runs:
        with open(path) as f:
            kept = json.load(f)
        h = kept["key"]["h"]
        assert kept["row"]["steps"] == max(20, min(math.ceil(0.5 / h - 1e-9), 2000)), kept
        assert kept["row"]["stable"] == (not math.isclose(h, passing[-1])), kept


finish()
