#!/usr/bin/python3
"""Convert an H5MD trajectory written by stiffmd to extended XYZ (read by ASE, OVITO, VMD).

    /usr/bin/python3 tools/h5md_to_xyz.py traj.h5 traj.xyz [--wrapped]

Each frame's comment line carries Properties= (species, pos, and velo/forces when the file has
them), time=, step=, pbc= and, when an axis is periodic, Lattice= (rows: the box edge vectors)
and Origin=. Positions are unwrapped (position + image·edges) unless --wrapped is given, which
writes them as stored: wrapped into the box on periodic axes. Species symbols come from the
element table in the `elements` attribute of particles/all/species.

Frames are counted by the shortest time series in the file, so a file whose writer was killed
in the middle of a frame converts up to its last complete frame.
"""
import argparse
import sys

import h5py
import numpy as np

GROUP = "particles/all"


def read_elements(particles):
    """Symbol of each particle: species indices mapped through the `elements` table."""
    species = particles["species"][()]
    table = [e.decode() if isinstance(e, bytes) else str(e) for e in particles["species"].attrs["elements"]]
    return [table[s] for s in species]


def frame_count(particles):
    """Frames present in every time series this converter reads (all share one time grid)."""
    names = ["position/value", "position/step", "position/time", "image/value", "velocity/value", "force/value",
             "box/edges/value"]
    return min(particles[n].shape[0] for n in names if n in particles)


def box_info(particles):
    """(pbc flags, edges dataset or None, origin)."""
    box = particles["box"]
    boundary = [b.decode() if isinstance(b, bytes) else str(b) for b in box.attrs["boundary"]]
    pbc = [b == "periodic" for b in boundary]
    edges = box["edges/value"] if "edges" in box else None
    origin = box["offset"][()] if "offset" in box else np.zeros(3)
    return pbc, edges, origin


def edge_matrix(edges, frame):
    """The box edge vectors (rows) of one frame; a stored vector means a cuboid box."""
    e = np.asarray(edges[frame], dtype=float)
    return np.diag(e) if e.ndim == 1 else e


def fmt(values):
    return " ".join("%.17g" % v for v in values)


def convert(path, out, wrapped=False):
    """Writes every complete frame of `path` to the open text stream `out`; returns the count."""
    with h5py.File(path, "r") as f:
        particles = f[GROUP]
        symbols = read_elements(particles)
        pbc, edges, origin = box_info(particles)
        has_v, has_f = "velocity" in particles, "force" in particles
        props = "species:S:1:pos:R:3" + (":velo:R:3" if has_v else "") + (":forces:R:3" if has_f else "")
        n = frame_count(particles)
        pbc_text = " ".join("T" if p else "F" for p in pbc)
        for k in range(n):
            x = particles["position/value"][k].astype(float)
            header = f'Properties={props} time={float(particles["position/time"][k])!r} ' \
                     f'step={int(particles["position/step"][k])} pbc="{pbc_text}"'
            if edges is not None:
                cell = edge_matrix(edges, k)
                if not wrapped and "image" in particles:
                    x = x + particles["image/value"][k].astype(float) @ cell
                header += f' Lattice="{fmt(cell.ravel())}" Origin="{fmt(origin)}"'
            columns = [x]
            if has_v:
                columns.append(particles["velocity/value"][k])
            if has_f:
                columns.append(particles["force/value"][k])
            rows = np.hstack(columns)
            out.write(f"{len(symbols)}\n{header}\n")
            out.writelines(f"{s} {fmt(r)}\n" for s, r in zip(symbols, rows))
    return n


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("input", help="H5MD file written by stiffmd")
    p.add_argument("output", help="extended XYZ file to write")
    p.add_argument("--wrapped", action="store_true",
                   help="write positions wrapped into the box (as stored) instead of unwrapped")
    a = p.parse_args(argv)
    try:
        with open(a.output, "w") as out:
            n = convert(a.input, out, a.wrapped)
    except (OSError, KeyError) as e:
        sys.exit(f"{a.input}: cannot convert: {e}")
    print(f"{a.output}: {n} frames")


if __name__ == "__main__":
    main()
