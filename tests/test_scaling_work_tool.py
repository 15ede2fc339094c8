#!/usr/bin/python3
"""tools/scaling.py --work (the step loop's instructions under callgrind) and the pair count.

    /usr/bin/python3 tests/test_scaling_work_tool.py build/stiffmd [MPIEXEC]

Without valgrind or a binary: the callgrind reader on files written here (the trigger, Ir from
"summary:" or "totals:", MPI's share as the inclusive cost of the calls into MPI's objects from
outside them, name compression), the sum over a run's processes of their step-loop dumps, and the
pair count read from summary.json (top level, under "domains", absent: "n/a"), and that a missing
valgrind exits 2 naming it. With valgrind
installed (skipped otherwise): --work on a small deck, 1×1 and, given MPIEXEC, 2×1 — every rank's
dumps found, the work column 1.000 on 1×1, and the step loop's count doubling (within a first
step's extra) when the steps double, where the set-up (50 relaxation steps, over 5 times the 8
steps' loop) would keep it near 1 had it leaked in."""
import os
import re
import shutil
import subprocess
import sys
import tempfile

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
TOOL = os.path.join(ROOT, "tools", "scaling.py")
DECK = os.path.join(ROOT, "tests", "decks", "small_melt.toml")
sys.path.insert(0, os.path.join(ROOT, "tools"))
import scaling  # noqa: E402
from engines import RunFailed  # noqa: E402

# A dump as callgrind writes one (abridged): the engine (ob 1) calls libc's memcpy (ob 2: not MPI)
# and MPI_Allreduce in libmpi (ob 3), which calls into an Open MPI plugin (ob 4, inside MPI: not
# counted again); libevent (MPI's, ob 5) calls back into libopen-pal (ob 6): inside MPI too. A
# thread's start in libc (ob 2) calls libopen-pal's progress thread (ob 6): MPI's.
STEP_DUMP = """# callgrind format
version: 1
creator: callgrind-3.19.0
pid: 4242
cmd:  stiffmd run deck.toml
part: 2

desc: I1 cache:
desc: Timerange: Basic block 10 - 20
desc: Trigger: --dump-before=stiffmd::Run::finish()

positions: instr line
events: Ir Dr
summary: 1000 77

ob=(1) /work/build/stiffmd
fl=(1) run.cpp
fn=(1) stiffmd::Run::step_to(long)
0x10 12 500 7
+4 * 20
cob=(2) /usr/lib/x86_64-linux-gnu/libc.so.6
cfi=(2) ???
cfn=(2) memcpy
calls=3 0x99 0
0x20 13 40 2
cob=(3) /usr/lib/x86_64-linux-gnu/libmpi.so.40.30.4
cfi=(3) ???
cfn=(3) PMPI_Allreduce
calls=1 0x77 0
0x24 14 300 60
cfn=(4) stiffmd::Run::observe(bool)
calls=1 0x30 0
0x28 15 25

ob=(3)
fl=(3)
fn=(3)
0x77 0 100
cob=(4) /usr/lib/x86_64-linux-gnu/openmpi/lib/openmpi3/mca_coll_tuned.so
cfn=(5) ompi_coll_tuned_allreduce
calls=1 0x55 0
0x78 0 200

ob=(5) /usr/lib/x86_64-linux-gnu/libevent_core-2.1.so.7.0.1
fl=(4) ???
fn=(6) event_base_loop
0x5 0 10
cob=(6) /usr/lib/x86_64-linux-gnu/libopen-pal.so.40.30.2
cfn=(7) opal_progress
calls=2 0x6 0
0x6 0 90

ob=(2)
fl=(2)
fn=(8) start_thread
cob=(6)
cfn=(9) progress_engine
calls=1 0x9 0
0x7 0 100
"""
SETUP_DUMP = """events: Ir
desc: Trigger: --dump-before=stiffmd::Run::step_to(long)
ob=(1) /work/build/stiffmd
fn=(1) main
5 40
totals: 40
"""


def check_reader(work):
    path = os.path.join(work, "cg.4242.2")
    with open(path, "w") as f:
        f.write(STEP_DUMP)
    part = scaling.read_callgrind(path)
    # MPI: the call into libmpi from the engine (300) and the thread start's call into libopen-pal
    # (100); not the plugin's call from libmpi (200) nor libevent's back into libopen-pal (90), which
    # are inside them; not memcpy (libc), nor the engine's own call to observe.
    assert part == {"trigger": "--dump-before=stiffmd::Run::finish()", "total": 1000, "mpi": 400}, part
    assert scaling.read_callgrind(path, "Dr") == {"trigger": part["trigger"], "total": 77, "mpi": 60}
    setup = os.path.join(work, "cg.4242.1")
    with open(setup, "w") as f:
        f.write(SETUP_DUMP)
    assert scaling.read_callgrind(setup) == {"trigger": "--dump-before=stiffmd::Run::step_to(long)", "total": 40,
                                             "mpi": 0}
    final = os.path.join(work, "cg.4242")
    with open(final, "w") as f:
        f.write("events: Ir\ndesc: Trigger: Program termination\nsummary: 9\n")
    assert scaling.step_loop_work(work, 1) == (600, 40, 400)
    # Two processes: their step loops and set-ups add up; a missing step-loop dump is refused.
    for name, text in (("cg.4243.2", STEP_DUMP), ("cg.4243.1", SETUP_DUMP)):
        with open(os.path.join(work, name), "w") as f:
            f.write(text)
    assert scaling.step_loop_work(work, 2) == (1200, 80, 800)
    os.remove(os.path.join(work, "cg.4243.2"))
    try:
        scaling.step_loop_work(work, 2)
        raise AssertionError("a process without its step-loop dump was accepted")
    except RunFailed as e:
        assert "1 step-loop and 2 set-up dumps for 2 process(es)" in str(e), e
    with open(os.path.join(work, "junk"), "w") as f:
        f.write("not callgrind\n")
    try:
        scaling.read_callgrind(os.path.join(work, "junk"))
        raise AssertionError("a file without events was accepted")
    except RunFailed as e:
        assert "not a callgrind output file" in str(e), e


def check_pairs():
    assert scaling.neighbor_pairs({"neighbor_pairs": 10}) == 10
    assert scaling.neighbor_pairs({"domains": {"neighbor_pairs": 12}}) == 12
    assert scaling.neighbor_pairs({"domains": {"ghosts_per_owned": 0.5}}) is None
    assert scaling.pairs_ratio(12, 10) == 1.2 and scaling.pairs_ratio(None, 10) is None
    assert scaling.pairs_ratio(12, None) is None
    assert scaling.form_pairs(None) == "n/a" and scaling.form_pairs(1.2) == "1.200"
    by_layout = {(2, 1): [{"neighbor_pairs": 30}], (1, 2): [{"neighbor_pairs": 20}, {"neighbor_pairs": 22}]}
    assert scaling.one_rank_pairs(by_layout, [(2, 1), (1, 2)]) == 21
    assert scaling.one_rank_pairs(by_layout, [(2, 1)]) is None


def tool(exe, out, *extra):
    return subprocess.run(["/usr/bin/python3", TOOL, "--stiffmd", exe, "--out", out, "--work", "--deck", DECK,
                           "--methods", "rattle", "--h", "0.005", "--set", "prepare.relax_steps=50", *extra], capture_output=True, text=True)


def work_rows(stdout):
    """{layout: {column: cell}} of --work's table."""
    lines = stdout.splitlines()
    header = next(l for l in lines if l.startswith("| system |"))
    names = [w.strip() for w in header.strip("|").split("|")]
    rows = {}
    for l in lines:
        if l.startswith("| small_melt.toml |"):
            cells = dict(zip(names, (w.strip() for w in l.strip("|").split("|"))))
            rows[cells["ranks×threads"]] = cells
    return rows


def check_refusal(exe, work):
    p = tool(exe, os.path.join(work, "bad"), "--valgrind", "/no/such/valgrind", "--layouts", "1x1")
    assert p.returncode == 2 and "/no/such/valgrind" in p.stderr and "Traceback" not in p.stderr, p.stderr


def check_work(exe, work, mpiexec):
    layouts = "1x1,2x1" if mpiexec else "1x1"
    extra = ["--mpiexec", mpiexec] if mpiexec else []
    runs = {}
    for steps in (4, 8):
        out = os.path.join(work, f"work{steps}")
        p = tool(exe, out, "--layouts", layouts if steps == 4 else "1x1", "--steps", str(steps), *extra)
        assert p.returncode == 0, p.stdout + p.stderr
        rows = work_rows(p.stdout)
        with open(os.path.join(out, "work.md")) as f:
            assert f.read().strip() in p.stdout
        assert list(rows) == (["1×1", "2×1"] if steps == 4 and mpiexec else ["1×1"]), p.stdout
        one = rows["1×1"]
        assert one["work ÷ 1×1"] == "1.000" and one["steps"] == str(steps), p.stdout
        assert one["ghosts/owned"] == "—" and one["halo msgs/step"] == "—", p.stdout
        with open(os.path.join(out, "work.csv")) as f:
            head, *lines = f.read().splitlines()
        assert "ir_steps" in head and len(lines) == len(rows), (head, lines)
        # The counts themselves (work.csv), not the table's three decimals of 10⁹: the small deck's
        # step loop is ≈ 0.0015 × 10⁹ instructions, where the rounding alone moves the ratio from 1.5 to 3.
        columns = head.split(",")
        solo = [dict(zip(columns, l.split(","))) for l in lines]
        solo = [r for r in solo if r["ranks"] == "1" and r["threads"] == "1"]
        assert len(solo) == 1, lines
        runs[steps] = float(solo[0]["ir_steps"])
        setup = float(solo[0]["ir_setup"])
        if steps == 4 and mpiexec:
            two = rows["2×1"]
            assert float(two["ghosts/owned"]) > 0 and float(two["halo msgs/step"]) > 0, p.stdout
            assert 0.5 < float(two["work ÷ 1×1"]) < 2.0, p.stdout  # 192 beads: ghosts and halo dominate
            files = os.listdir(os.path.join(out, "work", "work", "small_melt.toml_rattle_r2t1", "callgrind"))
            assert len([n for n in files if re.fullmatch(r"cg\.\d+\.2", n)]) == 2, files  # both ranks' loops
    # The count is the steps': twice the steps, about twice the count (the first step builds the lists).
    ratio = runs[8] / runs[4]
    assert 1.25 < ratio < 2.3, (runs, setup)  # a leaked set-up (over 5 times the loop) would give < 1.1
    assert setup > 5 * runs[8], (runs, setup)
    return ratio


def main():
    exe = os.path.abspath(sys.argv[1]) if len(sys.argv) > 1 else os.path.join(ROOT, "build", "stiffmd")
    mpiexec = sys.argv[2] if len(sys.argv) > 2 else None  # tests/CMakeLists.txt: when CMake found MPI
    with tempfile.TemporaryDirectory() as work:
        os.makedirs(os.path.join(work, "cg"))
        check_reader(os.path.join(work, "cg"))
        check_pairs()
        check_refusal(exe, work)
        if shutil.which("valgrind") is None:
            print("work: skipped (no valgrind)")
            print("3 passed, 0 failed, 1 skipped")
            return
        ratio = check_work(exe, work, mpiexec)
        print(f"work: 8 steps / 4 steps = {ratio:.2f}{'' if mpiexec else ' (1x1 only: no MPIEXEC)'}")
    print("4 passed, 0 failed")


if __name__ == "__main__":
    main()
