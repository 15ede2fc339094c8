#!/usr/bin/python3
"""The README's recipes for MDAnalysis and ASE ("Opening the outputs elsewhere") run as written on a
small periodic ring solution and agree with stiffmd's own thermo output: bonds and masses from
topology.data, whole molecules, the mean per-molecule radius of gyration equal to the thermo column
rg at the same time (run by ctest on Debian's python3 with MDAnalysis and ASE)."""
import csv
import os
import re
import subprocess
import sys
import tempfile
import warnings

import numpy as np

warnings.filterwarnings("ignore")  # MDAnalysis's deprecation noise on this python
ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
failures = []


def check(name, ok, detail=""):
    print(f"{'ok  ' if ok else 'FAIL'} {name} {detail}")
    if not ok:
        failures.append(name)


def readme_recipes():
    """The indented code blocks of README's "Opening the outputs elsewhere", in order."""
    text = open(os.path.join(ROOT, "README.md"), encoding="utf-8").read()
    section = text[text.index("### Opening the outputs elsewhere"):]
    section = section[:section.index("\n## ")]
    blocks, current = [], []
    for line in section.split("\n"):
        if line.startswith("      "):
            current.append(line[6:])
        elif current and line.strip() == "":
            current.append("")
        elif current:
            blocks.append("\n".join(current).strip() + "\n")
            current = []
    if current:
        blocks.append("\n".join(current).strip() + "\n")
    return blocks


def mean_rg(positions, masses, molecule):
    out = []
    for m in np.unique(molecule):
        sel = molecule == m
        x, w = positions[sel], masses[sel]
        com = (w[:, None] * x).sum(axis=0) / w.sum()
        out.append(np.sqrt((w * ((x - com) ** 2).sum(axis=1)).sum() / w.sum()))
    return np.mean(out)


def main():
    exe = sys.argv[1]
    with tempfile.TemporaryDirectory() as d:
        run_dir = os.path.join(d, "run")
        sets = ["run.t_end=0.2", "output.xyz=\"trajectory.xyz\"", "output.h5md=\"trajectory.h5md\"",
                "output.xyz_interval=0.05", "output.h5md_interval=0.05", "output.thermo_interval=0.05"]
        cmd = [exe, "run", os.path.join(ROOT, "inputs", "ring_solution.toml"), "-o", run_dir, "--no-progress"]
        subprocess.run(cmd + [a for s in sets for a in ("--set", s)], check=True, capture_output=True)
        thermo = {round(float(r["time"]), 9): float(r["rg"]) for r in csv.DictReader(open(f"{run_dir}/thermo.csv"))}

        blocks = readme_recipes()
        check("README has the MDAnalysis (XYZ, H5MD) and ASE recipes", len(blocks) >= 3, str(len(blocks)))
        ns = {}
        for b in blocks[:3]:
            exec(b.replace("out/run", run_dir), ns)
        u, w, rg, frames, molecule = ns["u"], ns["w"], ns["rg"], ns["frames"], ns["molecule"]

        # Topology: 30 rings of 24 beads: 720 bonds, unit masses, 30 molecules.
        check("MDAnalysis bonds", len(u.bonds) == 720, str(len(u.bonds)))
        check("MDAnalysis masses", np.all(u.atoms.masses == 1.0), str(u.atoms.masses[:3]))
        check("MDAnalysis molecules", len(u.residues) == 30, str(len(u.residues)))
        times = [f.info["time"] for f in frames]
        check("frames", len(times) == len(rg) and len(times) >= 5, f"{len(times)} ASE, {len(rg)} MDAnalysis")
        # The README's per-chain Rg from the XYZ: equal to thermo rg (12 significant digits written,
        # single precision in MDAnalysis).
        for t, r in zip(times, rg):
            ref = thermo[round(t, 9)]
            check(f"MDAnalysis XYZ rg at t = {t:g}", abs(r - ref) < 1e-6 * ref, f"{r:.9g} vs thermo {ref:.9g}")
        # From the H5MD, whole again through MDAnalysis's unwrap along the bonds; without it, some
        # rings are cut by the box (the recipe's unwrap is needed, and this test would see it).
        wrapped_rg = []
        for t, ts in zip(times, w.trajectory):
            r = sum(m.atoms.radius_of_gyration() for m in w.residues) / len(w.residues)
            ref = thermo[round(t, 9)]
            check(f"MDAnalysis H5MD + unwrap rg at t = {t:g}", abs(r - ref) < 1e-6 * ref, f"{r:.9g} vs {ref:.9g}")
        import MDAnalysis as mda
        raw = mda.Universe(f"{run_dir}/topology.data", f"{run_dir}/trajectory.h5md", topology_format="DATA",
                           atom_style="id resid type x y z", format="H5MD", convert_units=False)
        wrapped_rg = sum(m.atoms.radius_of_gyration() for m in raw.residues) / len(raw.residues)
        check("H5MD positions are wrapped (unwrap is needed)", wrapped_rg > 1.5 * thermo[0.0],
              f"{wrapped_rg:.4g} vs {thermo[0.0]:.4g}")
        # ASE: masses from the XYZ's masses column (not nitrogen's 14.007), positions whole, and
        # with the topology's molecules the same per-chain Rg.
        for f in frames:
            ref = thermo[round(f.info["time"], 9)]
            check(f"ASE masses at t = {f.info['time']:g}", np.all(f.get_masses() == 1.0), str(f.get_masses()[:3]))
            r = mean_rg(f.get_positions(), f.get_masses(), np.asarray(molecule))
            check(f"ASE rg at t = {f.info['time']:g}", abs(r - ref) < 1e-9 * ref, f"{r:.12g} vs {ref:.12g}")
        x0 = frames[0].get_positions()
        top = mda.Universe(f"{run_dir}/topology.data", atom_style="id resid type x y z")
        # topology.data holds wrapped positions with image flags, which MDAnalysis ignores: equal up to
        # whole box lengths.
        L = frames[0].cell.lengths()
        d = x0 - top.atoms.positions
        d -= L * np.round(d / L)
        check("ASE positions at t = 0 equal topology.data's (mod the box)", np.abs(d).max() < 1e-5,
              f"{np.abs(d).max():.3g}")
    print(f"{len(failures)} failures")
    sys.exit(1 if failures else 0)


if __name__ == "__main__":
    main()
