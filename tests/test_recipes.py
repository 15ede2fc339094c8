#!/usr/bin/python3
"""The README's recipes for MDAnalysis and ASE ("Opening the outputs elsewhere") run as written and agree
with stiffmd's own thermo output: bonds and masses from topology.data, whole molecules, the mean
per-molecule radius of gyration equal to the thermo column rg at the same time. On a small periodic
ring solution (and its end_to_end column: the rings' root-mean-square diameter, as tools/analyze.py
defines it, not a bond) and on the bundled melt, whose chains span more than half the box (run by
ctest on Debian's python3 with MDAnalysis and ASE)."""
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
sys.path.insert(0, os.path.join(ROOT, "tools"))
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


def run(exe, deck, run_dir, t_end, interval):
    """Runs an inputs/ deck with XYZ and H5MD frames every `interval`; the thermo rows by time."""
    sets = [f"run.t_end={t_end}", "output.xyz=\"trajectory.xyz\"", "output.h5md=\"trajectory.h5md\"",
            f"output.xyz_interval={interval}", f"output.h5md_interval={interval}", "output.thermo_interval=0.05"]
    cmd = [exe, "run", os.path.join(ROOT, "inputs", deck), "-o", run_dir, "--no-progress"]
    subprocess.run(cmd + [a for s in sets for a in ("--set", s)], check=True, capture_output=True)
    return {round(float(r["time"]), 9): r for r in csv.DictReader(open(f"{run_dir}/thermo.csv"))}


def recipes(run_dir, count):
    """The README's first `count` recipes run on run_dir: their names (u, w, rg, frames, molecule)."""
    ns = {}
    for b in readme_recipes()[:count]:
        exec(b.replace("out/run", run_dir), ns)
    return ns


def h5md_rg_matches_thermo(w, times, thermo, label):
    """The README's H5MD recipe: per frame, the mean Rg equals thermo's rg and no bond is cut by the box."""
    for t, ts in zip(times, w.trajectory):
        r = sum(m.atoms.radius_of_gyration() for m in w.residues) / len(w.residues)
        ref = float(thermo[round(t, 9)]["rg"])
        check(f"{label}: MDAnalysis H5MD + images rg at t = {t:g}", abs(r - ref) < 1e-6 * ref, f"{r:.9g} vs {ref:.9g}")
        longest = w.bonds.values().max()
        check(f"{label}: H5MD + images longest bond at t = {t:g} < half the box", longest < 0.5 * ts.dimensions[:3].min(),
              f"{longest:.4g} in {ts.dimensions[0]:.4g}")


def ring_solution(exe, d):
    run_dir = os.path.join(d, "rings")
    rows = run(exe, "ring_solution.toml", run_dir, 0.2, 0.05)
    thermo = {t: float(r["rg"]) for t, r in rows.items()}
    check("README has the MDAnalysis (XYZ, H5MD) and ASE recipes", len(readme_recipes()) >= 3,
          str(len(readme_recipes())))
    ns = recipes(run_dir, 3)
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
    # From the H5MD, whole again with the file's images; without them, some rings are cut by the
    # box (the recipe's unwrapping is needed, and this test would see it).
    h5md_rg_matches_thermo(w, times, rows, "rings")
    import MDAnalysis as mda
    raw = mda.Universe(f"{run_dir}/topology.data", f"{run_dir}/trajectory.h5md", topology_format="DATA",
                       atom_style="id resid type x y z", format="H5MD", convert_units=False)
    wrapped_rg = sum(m.atoms.radius_of_gyration() for m in raw.residues) / len(raw.residues)
    check("H5MD positions are wrapped (unwrapping is needed)", wrapped_rg > 1.5 * thermo[0.0],
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

    # end_to_end of rings: the mean over rings of the root-mean-square diameter, computed by
    # tools/analyze.py's chains and size vectors on the XYZ positions (12 significant digits).
    import analyze
    chains = analyze.find_chains(u)
    check("analyze.py sees 30 rings", [c.kind for c in chains] == ["ring"] * 30, str({c.kind for c in chains}))
    for f in frames:
        x = f.get_positions()[None]
        size = np.mean([np.sqrt(np.mean(np.einsum("fma,fma->fm", v, v))) for v in
                        (analyze.size_vectors(x, c) for c in chains)])
        ref = float(rows[round(f.info["time"], 9)]["end_to_end"])
        check(f"rings' end_to_end at t = {f.info['time']:g} is analyze.py's rms diameter", abs(size - ref) < 1e-9 * ref,
              f"{ref:.12g} vs {size:.12g}")
        check(f"rings' end_to_end at t = {f.info['time']:g} is not a bond (unit length)", ref > 3.0, f"{ref:.6g}")


def polymer_melt(exe, d):
    """The bundled melt: chains of 100 beads in a box of 22.7, so chains span more than half the box,
    as MDAnalysis 2.4.2's transformations.unwrap does not handle."""
    run_dir = os.path.join(d, "melt")
    rows = run(exe, "polymer_melt.toml", run_dir, 0.25, 0.25)
    ns = recipes(run_dir, 2)
    u, w = ns["u"], ns["w"]
    times = [ts.time for ts in w.trajectory]  # MDAnalysis's XYZ reader has no times or box
    check("melt frames", times == [0.0, 0.25] and len(u.trajectory) == 2, f"{times}, {len(u.trajectory)} XYZ")
    u.trajectory[-1]
    span = max(np.ptp(m.atoms.positions, axis=0).max() for m in u.residues)
    check("a melt chain spans more than half the box", span > 0.5 * w.dimensions[:3].min(),
          f"{span:.4g} in {w.dimensions[0]:.4g}")
    h5md_rg_matches_thermo(w, times, rows, "melt")
    # Linear chains: end_to_end is the mean end-to-end distance |x_last - x_first| (XYZ positions).
    for t, ts in zip(times, u.trajectory):
        ree = np.mean([np.linalg.norm(m.atoms.positions[-1] - m.atoms.positions[0]) for m in u.residues])
        ref = float(rows[round(t, 9)]["end_to_end"])
        check(f"melt end_to_end at t = {t:g}", abs(ree - ref) < 1e-6 * ref, f"{ree:.9g} vs {ref:.9g}")


def main():
    exe = sys.argv[1]
    with tempfile.TemporaryDirectory() as d:
        ring_solution(exe, d)
        polymer_melt(exe, d)
    print(f"{len(failures)} failures")
    sys.exit(1 if failures else 0)


if __name__ == "__main__":
    main()
