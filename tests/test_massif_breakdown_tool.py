#!/usr/bin/python3
"""tools/massif_breakdown.py on a small massif file written here: the peak snapshot's leaves summed
by what holds them (the first rule whose pattern the stack matches), an earlier snapshot by number,
and the unmatched bytes as "other".

    /usr/bin/python3 tests/test_massif_breakdown_tool.py"""
import os
import subprocess
import sys
import tempfile

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
TOOL = os.path.join(ROOT, "tools", "massif_breakdown.py")

# Two detailed snapshots; the second is the peak. Leaves: a whole-system list built for a thermo row
# (matched before the force field frame below it), the part's force terms, a scene's bonds read with
# the deck, and an allocation no rule names.
MASSIF = """desc: --threshold=0.2
cmd: stiffmd run deck.toml
time_unit: i
#-----------
snapshot=0
#-----------
time=0
mem_heap_B=1000000
mem_heap_extra_B=0
mem_stacks_B=0
heap_tree=detailed
n1: 1000000 (heap allocation functions) malloc/new/new[], --alloc-fns, etc.
 n1: 1000000 0x1: stiffmd::BondTerm<stiffmd::Fene>::BondTerm(...) (in stiffmd)
  n1: 1000000 0x2: stiffmd::(anonymous namespace)::read_forces(...) (in stiffmd)
   n0: 1000000 0x3: stiffmd::load_scene(...) (in stiffmd)
#-----------
snapshot=1
#-----------
time=10
mem_heap_B=10000000
mem_heap_extra_B=0
mem_stacks_B=0
heap_tree=peak
n4: 10000000 (heap allocation functions) malloc/new/new[], --alloc-fns, etc.
 n1: 6000000 0x4: stiffmd::NeighborList::bin(...) (in stiffmd)
  n1: 6000000 0x5: stiffmd::ForceField::energies_and_virial(...) (in stiffmd)
   n0: 6000000 0x6: stiffmd::Thermo::sums(...) (in stiffmd)
 n1: 2000000 0x7: stiffmd::ForceField::on_subset(...) (in stiffmd)
  n0: 2000000 0x8: stiffmd::DomainIntegrator::build_part(...) (in stiffmd)
 n1: 1500000 0x1: stiffmd::BondTerm<stiffmd::Fene>::BondTerm(...) (in stiffmd)
  n0: 1500000 0x3: stiffmd::load_scene(...) (in stiffmd)
 n0: 500000 in 12 places, all below massif's threshold (0.20%)
"""


def rows(text):
    """{held by: MB} of the tool's table."""
    out = {}
    for line in text.splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if len(cells) == 3 and cells[1] not in ("MB", "--:"):
            out[cells[0]] = float(cells[1])
    return out


def main():
    with tempfile.TemporaryDirectory() as tmp:
        path = os.path.join(tmp, "massif.out")
        with open(path, "w") as f:
            f.write(MASSIF)
        peak = subprocess.run([sys.executable, TOOL, path], capture_output=True, text=True, check=True).stdout
        first = subprocess.run([sys.executable, TOOL, path, "--snapshot", "0"], capture_output=True, text=True,
                               check=True).stdout
    expected = {"the whole system's neighbour list and pair buffers": 6.0,
                "the part: its force terms, integrator and thermo": 2.0,
                "the whole scene: force terms (bonds, special pairs)": 1.5, "other": 0.5}
    got = rows(peak)
    if "snapshot 1: heap 10.00 MB" not in peak or got != expected:
        raise SystemExit(f"FAIL: the peak's breakdown\n{peak}\nexpected {expected}")
    if rows(first) != {"the whole scene: force terms (bonds, special pairs)": 1.0}:
        raise SystemExit(f"FAIL: snapshot 0's breakdown\n{first}")
    print("massif_breakdown: the peak's leaves by what holds them, and snapshot 0's")


if __name__ == "__main__":
    main()
