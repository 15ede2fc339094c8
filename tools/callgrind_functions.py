#!/usr/bin/python3
"""Where a --work run's instructions go: each function's own instructions (callgrind's self Ir, the
calls it makes left out) in the step loop, summed over the run's processes; with --against, beside
another run's and the difference.

    /usr/bin/python3 tools/callgrind_functions.py RUN/callgrind
    /usr/bin/python3 tools/callgrind_functions.py NEW/callgrind --against OLD/callgrind --top 20

A directory is a --work run's callgrind directory (tools/scaling.py --work: OUT/work/work/<system>_<method>_
r<R>t<T>/callgrind): its step-loop dumps are the files whose trigger is entering Run::finish (the
dump that closes the step loop, as tools/scaling.py reads them); a file is taken as given. Rows in
10⁶ instructions, the largest (with --against: the largest differences) first; the last row is the
sum over every function. MPI's own functions are rows like any other (tools/scaling.py takes their
inclusive cost out of its work figure).
"""
import argparse
import collections
import os
import re
import sys

STEP_LOOP_END = "Run::finish"
NAME = re.compile(r"\((\d+)\)(?: (.*))?$")


def self_costs(path, event="Ir"):
    """{function: self count of `event`} of one callgrind output file: the cost lines under each
    "fn=", less the inclusive cost line that follows each "calls=" (a call's cost is the callee's)."""
    costs = collections.Counter()
    names, fn, events, npos, skip_next = {}, None, None, 1, False

    def name_of(value):  # "(id) name" defines an id, "(id)" refers to it, else the name itself
        m = NAME.match(value.strip())
        if not m:
            return value.strip()
        if m.group(2):
            names[m.group(1)] = m.group(2)
        return names.get(m.group(1), m.group(1))

    with open(path, errors="replace") as f:
        for line in f:
            if line.startswith("fn="):
                fn = name_of(line[3:])
            elif line.startswith("cfn="):
                name_of(line[4:])  # may define an id used later (files, "fl=", "cfi=", number their own)
            elif line.startswith("calls="):
                skip_next = True
            elif line.startswith("events:"):
                events = line.split(":", 1)[1].split()
            elif line.startswith("positions:"):
                npos = len(line.split(":", 1)[1].split())
            elif line[:1].isdigit() or line[:1] in "+-*":
                if skip_next:
                    skip_next = False
                    continue
                w = line.split()
                i = npos + (events.index(event) if events and event in events else 0)
                if fn is not None and i < len(w):
                    costs[fn] += int(w[i])
    return costs


def is_step_loop(path):
    with open(path, errors="replace") as f:
        for line in f:
            if line.startswith("desc: Trigger:"):
                return STEP_LOOP_END in line
            if line.startswith("fn="):
                return False
    return False


def run_costs(where):
    """Summed self costs of a directory's step-loop dumps, or of the files given."""
    files = []
    for w in where:
        if os.path.isdir(w):
            files += [os.path.join(w, n) for n in sorted(os.listdir(w)) if is_step_loop(os.path.join(w, n))]
        else:
            files.append(w)
    if not files:
        sys.exit(f"callgrind_functions: no step-loop dump in {', '.join(where)}")
    total = collections.Counter()
    for path in files:
        total.update(self_costs(path))
    return total, len(files)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("run", nargs="+", help="a --work run's callgrind directory, or callgrind files")
    ap.add_argument("--against", nargs="+", help="the run to compare with (directory or files)")
    ap.add_argument("--top", type=int, default=25, help="rows (default 25)")
    ap.add_argument("--width", type=int, default=100, help="characters of a function's name shown")
    args = ap.parse_args()
    new, n_new = run_costs(args.run)
    if not args.against:
        print(f"self Ir ×10⁶, {n_new} step-loop dump(s)")
        for fn, c in new.most_common(args.top):
            print(f"{c / 1e6:10.1f}  {fn[:args.width]}")
        print(f"{sum(new.values()) / 1e6:10.1f}  (all functions)")
        return
    old, n_old = run_costs(args.against)
    print(f"self Ir ×10⁶: --against ({n_old} dumps), run ({n_new} dumps), difference")
    rows = sorted(set(old) | set(new), key=lambda k: -abs(new[k] - old[k]))
    for fn in rows[:args.top]:
        print(f"{old[fn] / 1e6:10.1f} {new[fn] / 1e6:10.1f} {(new[fn] - old[fn]) / 1e6:+10.1f}  {fn[:args.width]}")
    a, b = sum(old.values()), sum(new.values())
    print(f"{a / 1e6:10.1f} {b / 1e6:10.1f} {(b - a) / 1e6:+10.1f}  (all functions)")


if __name__ == "__main__":
    main()
