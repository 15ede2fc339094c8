#!/usr/bin/python3
"""The CPU-time ratio of two runs of one deck, from back-to-back pairs: B ÷ A.

    /usr/bin/python3 tools/pair_ratio.py DECK --a 'integrator.method="rattle"' --b 'integrator.method="fixman"'
    /usr/bin/python3 tools/pair_ratio.py DECK --a-stiffmd /tmp/old/stiffmd --h 0.02 --steps 100 --pairs 21

On a machine whose speed drifts by tens of per cent within minutes (a shared VM), medians of
separately timed runs compare phases as much as code. Here A and B run back to back, in alternating
order (A B, B A, A B, …), and the result is the median over the pairs of B's CPU seconds per step ÷
A's: each ratio is taken within one phase. Each side is a stiffmd binary (--a-stiffmd, --b-stiffmd;
default build/stiffmd) and a list of `--set` overrides (--both, then --a or --b: KEY=VALUE separated by ';'), run
with OMP_NUM_THREADS=--threads for --steps steps of --h (run.t_end = steps × h, no checkpoints, the
deck's outputs otherwise). CPU seconds are the step loop's (summary.json's cpu_seconds).

Used for the fixman ÷ rattle ratio and for before/after comparisons of a change (docs/performance.md).
Prints one line: both medians in ms per step, the median of the pair ratios and their range.
"""
import argparse
import os
import shutil
import statistics
import sys
import tempfile

from engines import RunFailed, check_exit, read_summary, run_measured  # tools/ is the script's directory

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def overrides(text):
    return [kv for kv in (text or "").split(";") if kv.strip()]


def run(stiffmd, deck, sets, args, work):
    """CPU ms per step of one run."""
    out = os.path.join(work, "run")
    shutil.rmtree(out, ignore_errors=True)
    os.makedirs(out)
    cmd = [stiffmd, "run", deck, "--no-progress", "-o", out, "--set", "output.checkpoint_interval=0",
           "--set", f"integrator.h={args.h!r}", "--set", f"run.t_end={args.h * args.steps!r}"]
    for kv in sets:
        cmd += ["--set", kv]
    code, _, _ = run_measured(cmd, out, args.threads)
    check_exit(code, cmd, out, log="stderr.txt")
    s = read_summary(out)
    return 1e3 * s["cpu_seconds"] / s["steps"]


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("deck")
    ap.add_argument("--a", default="", help="A's --set overrides, KEY=VALUE;KEY=VALUE")
    ap.add_argument("--b", default="", help="B's --set overrides")
    ap.add_argument("--both", default="", help="--set overrides for both sides, before their own")
    default_exe = os.path.join(ROOT, "build", "stiffmd")
    ap.add_argument("--a-stiffmd", default=default_exe)
    ap.add_argument("--b-stiffmd", default=default_exe)
    ap.add_argument("--h", type=float, default=0.005)
    ap.add_argument("--steps", type=int, default=200)
    ap.add_argument("--pairs", type=int, default=11)
    ap.add_argument("--threads", type=int, default=1)
    args = ap.parse_args()
    if args.pairs < 1 or args.steps < 1 or not args.h > 0:
        print("pair_ratio: --pairs and --steps must be >= 1 and --h > 0", file=sys.stderr)
        return 2
    deck = os.path.abspath(args.deck)
    common = overrides(args.both)
    sides = [(os.path.abspath(args.a_stiffmd), common + overrides(args.a)),
             (os.path.abspath(args.b_stiffmd), common + overrides(args.b))]
    a_ms, b_ms, ratios = [], [], []
    with tempfile.TemporaryDirectory() as work:
        try:
            for k in range(args.pairs):
                order = (0, 1) if k % 2 == 0 else (1, 0)
                got = {i: run(sides[i][0], deck, sides[i][1], args, work) for i in order}
                a_ms.append(got[0])
                b_ms.append(got[1])
                ratios.append(got[1] / got[0])
        except RunFailed as e:
            print(f"pair_ratio: {e}", file=sys.stderr)
            return 2
    print(f"A {statistics.median(a_ms):.3f} ms/step, B {statistics.median(b_ms):.3f} ms/step (medians); "
          f"B/A = {statistics.median(ratios):.3f} (median of {args.pairs} pair ratios, "
          f"range {min(ratios):.3f} … {max(ratios):.3f})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
