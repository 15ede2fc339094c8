#!/usr/bin/python3
"""Smoke test: tools/pair_ratio.py on the bundled trimer deck (two pairs of 20-step runs).

    /usr/bin/python3 tests/test_pair_ratio_tool.py build/stiffmd

Checks the printed line (positive medians, the ratio within the pairs' range), that the two sides
ran with their own overrides (a bad override on one side fails the tool with exit 2 and names the
run), and that bad arguments are refused with exit 2."""
import os
import re
import subprocess
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
TOOL = os.path.join(ROOT, "tools", "pair_ratio.py")
DECK = os.path.join(ROOT, "inputs", "nvt_trimers.toml")


def tool(exe, *extra):
    return subprocess.run(["/usr/bin/python3", TOOL, DECK, "--a-stiffmd", exe, "--b-stiffmd", exe, "--h", "0.01",
                           "--steps", "20", "--pairs", "2", *extra], capture_output=True, text=True)


def main():
    exe = os.path.abspath(sys.argv[1]) if len(sys.argv) > 1 else os.path.join(ROOT, "build", "stiffmd")
    p = tool(exe, "--both", 'thermostat.splitting="obabo"', "--a", 'integrator.method="rattle"', "--b",
             'integrator.method="fixman"')
    assert p.returncode == 0, p.stdout + p.stderr
    m = re.search(r"A ([0-9.]+) ms/step, B ([0-9.]+) ms/step .*B/A = ([0-9.]+) .*range ([0-9.]+) … ([0-9.]+)", p.stdout)
    assert m, p.stdout
    a, b, r, lo, hi = (float(g) for g in m.groups())
    assert a > 0 and b > 0 and lo <= r <= hi, p.stdout
    p = tool(exe, "--b", "integrator.method=\"no-such-method\"")
    assert p.returncode == 2 and "no-such-method" in p.stderr, p.stdout + p.stderr
    p = tool(exe, "--pairs", "0")
    assert p.returncode == 2, p.stdout + p.stderr
    print("3 passed, 0 failed")


if __name__ == "__main__":
    main()
