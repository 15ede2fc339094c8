#!/usr/bin/python3
"""The headline ratio: velocity Verlet at its stability-limited step (0.9 ε) against the thermal
stiff limit, timed side by side on data.chain (docs/design.md §6).

    /usr/bin/python3 tools/headline_ratio.py                      # ε = 1e-3, 1e-4, 3e-3; 3 repeats (≈ 3 min)
    /usr/bin/python3 tools/headline_ratio.py --eps 1e-3 --repeats 5

tools/cost_vs_eps.py times every method at the largest step its ladder passed; when a false alarm
of the ladder's criterion stops velocity Verlet early (as once at ε = 1e-4), its row there
is not the reference the headline means. This times velocity Verlet at --vv-step × ε (0.9: it is
stable up to h = ε, ω_max = 2α/ε, and kept every observable there in the cost study) and --method at
--h, interleaved, --repeats times per ε, with the cost study's timed runs (`timed_measure`: Langevin
kT = 1, damp = 1, --steps steps of the step loop, one thread, CPU seconds per unit simulated time;
the prepared states of the study, OUT/work/datachain_eps*.data, made here if missing). Prints the
medians and the ratio per ε.
"""
import argparse
import os
import statistics
import sys

import cost_vs_eps  # tools/ is the script's directory
from chain_melt import prepare_state
from engines import RunFailed


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--eps", default="1e-3,1e-4,3e-3")
    ap.add_argument("--method", default="fixman-obabo", choices=[m for m in cost_vs_eps.METHODS
                                                                 if m not in cost_vs_eps.MICRO])
    ap.add_argument("--h", type=float, default=0.02, help="the method's step")
    ap.add_argument("--vv-step", type=float, default=0.9, help="velocity Verlet's step / ε")
    ap.add_argument("--steps", type=int, default=150)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--stiffmd", default=os.path.join(cost_vs_eps.ROOT, "build", "stiffmd"))
    ap.add_argument("--out", default=os.path.join(cost_vs_eps.ROOT, "sweeps", "cost_vs_eps"))
    args = ap.parse_args()
    args.stiffmd, args.out = os.path.abspath(args.stiffmd), os.path.abspath(args.out)
    eps_list = cost_vs_eps.split_floats(args.eps)
    work = os.path.join(args.out, "work")
    runs = os.path.join(args.out, "headline")
    cost = {}
    try:
        states = {e: os.path.join(work, f"datachain_eps{e:g}.data") for e in eps_list}
        for e, path in states.items():
            if not os.path.exists(path):
                prepare_state(args.stiffmd, e, path)
        for r in range(args.repeats):  # interleaved: slow drifts of the machine hit both alike
            for e in eps_list:
                for method, h in (("velocity-verlet", args.vv_step * e), (args.method, args.h)):
                    run_dir = os.path.join(runs, f"eps{e:g}_{method}_r{r}")
                    os.makedirs(run_dir, exist_ok=True)
                    row = cost_vs_eps.timed_measure(args, e, method, h, 1, args.steps, states[e], run_dir, r)
                    if row["status"] != "ok":
                        raise RunFailed(f"{method} at eps {e:g}, h {h:g}: {row['status']} ({run_dir})")
                    cost.setdefault((e, method), []).append(row["cpu_per_time"])
    except RunFailed as err:
        print(f"headline_ratio: {err}", file=sys.stderr)
        return 2
    print(f"CPU s per unit time on data.chain, one thread, median of {args.repeats} interleaved repeats of "
          f"{args.steps} steps\n")
    print(f"| ε | velocity Verlet (h = {args.vv_step:g} ε) | {args.method} (h = {args.h:g}) | ratio |")
    print("|---|--:|--:|--:|")
    for e in eps_list:
        vv, m = statistics.median(cost[(e, "velocity-verlet")]), statistics.median(cost[(e, args.method)])
        print(f"| {e:g} | {vv:.3g} | {m:.3g} | {vv / m:.3g} |")  # 3 digits: a ratio below 1 too
    return 0


if __name__ == "__main__":
    sys.exit(main())
