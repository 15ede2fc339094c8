#!/usr/bin/python3
"""How much of the particle array each part of the parallel pair loop touches, from a LAMMPS data file.

    /usr/bin/python3 tools/pair_bands.py /usr/share/lammps/examples/COUPLE/multiple/data.chain --reach 1.52
    /usr/bin/python3 tools/pair_bands.py sweeps/scaling/kg256k.data --reach 1.52 --parts 2,4,16

The pair loop (forcefields/pair_loop.hpp, accumulate_pair_rows_parallel) splits the half list's rows
(every pair i < j within --reach = cutoff + skin of each other, minimum image, bonded pairs left out as
special_bonds = [0, 1] does) into `parts` blocks of about equal pairs. Part u writes f_i of its rows
and f_j of their neighbours j > i. Printed per part count, over the parts u ≥ 1 (those with a buffer
of their own), as fractions of N: the band [first row, largest j] that a min/max range would clear
and add, and the touched set (the rows and their neighbours) that the loop clears and adds; and the
sums over those parts, against parts − 1 for whole arrays. The list is built from the file's
positions, as the engine's first build is.
"""
import argparse
import sys

import numpy as np
from scipy.spatial import cKDTree


def read_data(path):
    """Positions (index order = atom id order), box origin and lengths, bonds as index pairs."""
    lo, length, section, atoms, bonds = [0.0] * 3, [0.0] * 3, None, [], []
    with open(path) as f:
        for line in f:
            w = line.split("#")[0].split()
            if not w:
                continue
            if w[0] in ("Masses", "Atoms", "Velocities", "Bonds", "Angles", "Dihedrals", "Impropers"):
                section = w[0]
            elif section is None and len(w) == 4 and w[2] in ("xlo", "ylo", "zlo"):
                a = "xyz".index(w[2][0])
                lo[a], length[a] = float(w[0]), float(w[1]) - float(w[0])
            elif section == "Atoms":
                atoms.append((int(w[0]), float(w[3]), float(w[4]), float(w[5])))
            elif section == "Bonds":
                bonds.append((int(w[2]), int(w[3])))
    atoms.sort()
    index = {a[0]: k for k, a in enumerate(atoms)}
    x = np.array([a[1:] for a in atoms])
    b = np.array([(index[i], index[j]) for i, j in bonds], dtype=np.int64).reshape(-1, 2)
    return x, np.array(lo), np.array(length), b


def half_list(x, lo, length, bonds, reach):
    """offsets, neighbours of the half list (rows i, j > i ascending)."""
    n = len(x)
    xw = np.mod(x - lo, length)
    xw[xw >= length] = 0.0
    p = cKDTree(xw, boxsize=length).query_pairs(reach, output_type="ndarray")
    i, j = p.min(axis=1), p.max(axis=1)
    key = i * n + j
    bonded = np.sort(bonds, axis=1)
    keep = ~np.isin(key, bonded[:, 0] * n + bonded[:, 1])
    i, j = i[keep], j[keep]
    order = np.lexsort((j, i))
    offsets = np.concatenate([[0], np.cumsum(np.bincount(i, minlength=n))])
    return offsets, j[order]


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("data", nargs="+")
    ap.add_argument("--reach", type=float, default=1.52, help="cutoff + skin (in.chain: 1.12 + 0.4)")
    ap.add_argument("--parts", default="2,4,16")
    args = ap.parse_args()
    part_counts = [int(w) for w in args.parts.split(",")]
    for path in args.data:
        x, lo, length, bonds = read_data(path)
        n = len(x)
        offsets, nbr = half_list(x, lo, length, bonds, args.reach)
        pairs = int(offsets[-1])
        print(f"{path}: N = {n}, {pairs} listed pairs ({pairs / n:.2f} per particle), reach {args.reach:g}")
        print("| parts | band / N, mean (max) | touched / N, mean (max) | Σ band / N | Σ touched / N | whole arrays |")
        print("|--:|--:|--:|--:|--:|--:|")
        for parts in part_counts:
            first = [0] + [int(np.searchsorted(offsets, pairs * u // parts)) for u in range(1, parts)] + [n]
            band, touched = [], []
            for u in range(1, parts):
                r0, r1 = first[u], max(first[u], first[u + 1])
                js = nbr[offsets[r0]:offsets[r1]]
                if r1 == r0:
                    band.append(0.0)
                    touched.append(0.0)
                    continue
                band.append((max(r1 - 1, int(js.max()) if len(js) else r1 - 1) - r0 + 1) / n)
                touched.append(len(np.union1d(np.arange(r0, r1), js)) / n)
            print(f"| {parts} | {np.mean(band):.3f} ({np.max(band):.3f}) | {np.mean(touched):.3f} ({np.max(touched):.3f}) "
                  f"| {np.sum(band):.2f} | {np.sum(touched):.2f} | {parts - 1} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
