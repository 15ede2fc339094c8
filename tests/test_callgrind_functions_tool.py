#!/usr/bin/python3
"""tools/callgrind_functions.py on callgrind dumps written here: a function's self count is its
cost lines (absolute and relative positions, name compression, a file's id numbered apart from
a function's), not the inclusive costs after "calls="; a directory's step-loop dumps alone (the
trigger on entering Run::finish) are summed over processes; --against gives the differences.

    /usr/bin/python3 tests/test_callgrind_functions_tool.py"""
import os
import subprocess
import sys
import tempfile

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
TOOL = os.path.join(ROOT, "tools", "callgrind_functions.py")
sys.path.insert(0, os.path.join(ROOT, "tools"))
import callgrind_functions  # noqa: E402


def dump(trigger, search, forward):
    """A dump in callgrind's format: run() (self 7 + 3) calls search() (self `search`) and
    forward() (self `forward`), which calls memcpy (self 50)."""
    return f"""# callgrind format
version: 1
positions: line
events: Ir
desc: Trigger: --dump-before={trigger}
summary: {10 + search + forward + 50}

ob=(1) /work/build/stiffmd
fl=(1) run.cpp
fn=(1) run()
12 7
+1 3
cfi=(2) neighbor_list.cpp
cfn=(2) search()
calls=1 40
15 {search}
cfn=(3) forward()
calls=1 50
16 {forward + 50}

fl=(2)
fn=(2)
40 {search}

fl=(3) decomposition.cpp
fn=(3)
50 {forward - 5}
* 5
cfn=(4) memcpy
calls=4 0
51 50

fn=(4)
0 50
"""


def main():
    with tempfile.TemporaryDirectory() as d:
        run, old = os.path.join(d, "run"), os.path.join(d, "old")
        os.makedirs(run), os.makedirs(old)
        M = 10**6
        for pid, (search, forward) in {1: (100 * M, 30 * M), 2: (200 * M, 20 * M)}.items():
            with open(os.path.join(run, f"cg.{pid}.1"), "w") as f:  # the set-up: not summed
                f.write(dump("stiffmd::Run::step_to*", 9000, 9000))
            with open(os.path.join(run, f"cg.{pid}.2"), "w") as f:
                f.write(dump("stiffmd::Run::finish()", search, forward))
            with open(os.path.join(old, f"cg.{pid}.2"), "w") as f:
                f.write(dump("stiffmd::Run::finish()", 2 * search, 2 * forward))
        one = callgrind_functions.self_costs(os.path.join(run, "cg.1.2"))
        assert one == {"run()": 10, "search()": 100 * M, "forward()": 30 * M, "memcpy": 50}, one
        total, files = callgrind_functions.run_costs([run])
        assert files == 2, files
        assert total == {"run()": 20, "search()": 300 * M, "forward()": 50 * M, "memcpy": 100}, total
        out = subprocess.run([sys.executable, TOOL, run, "--against", old], capture_output=True, text=True, check=True)
        rows = [line.split() for line in out.stdout.splitlines()[1:]]
        # The largest difference first: search() 600 → 300, forward() 100 → 50; the sum last.
        assert rows[0] == ["600.0", "300.0", "-300.0", "search()"], out.stdout
        assert rows[1] == ["100.0", "50.0", "-50.0", "forward()"], out.stdout
        assert rows[-1][:3] == ["700.0", "350.0", "-350.0"] and rows[-1][3] == "(all", out.stdout
        empty = os.path.join(d, "empty")
        os.makedirs(empty)
        r = subprocess.run([sys.executable, TOOL, empty], capture_output=True, text=True)
        assert r.returncode != 0 and "no step-loop dump" in r.stderr, r
    print("callgrind_functions: ok")


if __name__ == "__main__":
    main()
