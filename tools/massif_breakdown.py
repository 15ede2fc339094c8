#!/usr/bin/env python3
"""Where a process's heap goes at its peak, by what holds it: a massif file's peak snapshot, each
allocation's stack matched against the rules below (first match wins), the bytes summed per rule.

Usage: tools/massif_breakdown.py MASSIF_OUT [--snapshot N] [--show-other BYTES]

Run massif with a low threshold so that few allocations are lumped together below it, e.g. one
process, and rank 1 of 8 (an MPMD launch: rank 1 alone under valgrind):

    OMP_NUM_THREADS=1 valgrind --tool=massif --threshold=0.2 --massif-out-file=/tmp/ms1.out \\
        build/stiffmd run DECK -o /tmp/m1 -q --no-progress
    OMP_NUM_THREADS=1 mpiexec --allow-run-as-root --oversubscribe -n 1 build/stiffmd run DECK -o /tmp/m8 -q \\
        --no-progress : -n 1 valgrind --tool=massif --threshold=0.2 --massif-out-file=/tmp/ms8.out \\
        build/stiffmd run DECK -o /tmp/m8 -q --no-progress : -n 6 build/stiffmd run DECK -o /tmp/m8 -q --no-progress

docs/parallel.md ("What a rank holds") has the tables this prints.
"""
import argparse
import collections
import re
import sys

# (what holds the memory, a regular expression on the allocation's stack, innermost frame first)
RULES = [
    ("the part: its force terms, integrator and thermo", r"DomainIntegrator::build_part|DomainIntegrator::start"),
    ("the part: pair set and halo", r"Decomposition::select_pair_set|Decomposition::forward|Decomposition::reverse|"
                                    r"GhostedPairs|Decomposition::distribute"),
    ("the part: its neighbour list (the thermo row's sums)", r"DomainIntegrator::sample_sums"),
    ("checkpoint (blocks, words)", r"write_checkpoint|save_state|state_block|Run::snapshot|BlockExchange"),
    ("the state gathered to rank 0", r"gather_columns|MpiCommunicator::gather"),
    ("MPI library", r"opal_|ompi_|mca_|pmix|hwloc|MPI_Init|orte_|PMPI"),
    ("the whole system's neighbour list and pair buffers", r"Thermo::sample|Thermo::sums"),
    ("the whole system's integrator (its kick forces)", r"make_integrator|MultipleTimeStepping::MultipleTimeStepping|"
                                                        r"Rattle::Rattle"),
    ("whole-system maps (Decomposition, SpecialPartners)", r"DomainIntegrator::DomainIntegrator|SpecialPartners|"
                                                           r"Decomposition::Decomposition"),
    ("the whole scene: particles and topology (builder)", r"build_linear_chains|build_rings|build_stars|"
                                                           r"read_builders|append_particles"),
    ("the whole scene: particles and topology (import)", r"read_lammps_data|read_import|import_"),
    ("the whole scene: velocities", r"maxwell_boltzmann|read_velocities"),
    ("the whole scene: force terms (bonds, special pairs)", r"read_forces|ForceField|load_scene"),
    ("outputs (RunOutputs)", r"RunOutputs"),
]


def snapshots(lines):
    """(number, total heap bytes, tree kind, first line of its tree) per snapshot."""
    out, cur = [], None
    for i, line in enumerate(lines):
        if line.startswith("snapshot="):
            cur = {"n": int(line.split("=")[1]), "heap": 0, "tree": "empty", "at": None}
            out.append(cur)
        elif cur is not None and line.startswith("mem_heap_B="):
            cur["heap"] = int(line.split("=")[1])
        elif cur is not None and line.startswith("heap_tree="):
            cur["tree"], cur["at"] = line.split("=")[1], i + 1
    return out


def leaves(lines, start):
    """Each leaf of the tree from line `start`: (bytes, its stack from the allocation outwards)."""
    stack = []
    for line in lines[start:]:
        if line.startswith("snapshot="):
            break
        m = re.match(r"^( *)n(\d+): (\d+) (.*)$", line)
        if not m:
            continue
        depth, children, size = len(m.group(1)), int(m.group(2)), int(m.group(3))
        stack = stack[:depth] + [m.group(4)]
        if children == 0 and depth > 0:
            yield size, " <- ".join(stack[1:])


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("massif_out")
    ap.add_argument("--snapshot", type=int, help="a detailed snapshot's number (default: the peak)")
    ap.add_argument("--show-other", type=int, default=0, metavar="BYTES",
                    help="print the stacks of unmatched allocations of at least BYTES")
    a = ap.parse_args()
    with open(a.massif_out) as f:
        lines = f.read().split("\n")
    snaps = [s for s in snapshots(lines) if s["at"] is not None]
    chosen = [s for s in snaps if (s["n"] == a.snapshot if a.snapshot is not None else s["tree"] == "peak")]
    if not chosen:
        sys.exit(f"{a.massif_out}: no such detailed snapshot")
    snap = chosen[0]
    total = collections.Counter()
    for size, stack in leaves(lines, snap["at"]):
        what = next((name for name, pattern in RULES if re.search(pattern, stack)), "other")
        total[what] += size
        if what == "other" and a.show_other and size >= a.show_other:
            print(f"other {size / 1e6:.2f} MB: {stack[:300]}")
    print(f"snapshot {snap['n']}: heap {snap['heap'] / 1e6:.2f} MB")
    print("| held by | MB | share |")
    print("|---|--:|--:|")
    for what, size in total.most_common():
        print(f"| {what} | {size / 1e6:.2f} | {100.0 * size / snap['heap']:.0f} % |")


if __name__ == "__main__":
    main()
