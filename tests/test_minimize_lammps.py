#!/usr/bin/python3
"""stiffmd's [minimize] against LAMMPS's `minimize` on inputs/minimize_chain.toml (four beads, harmonic
bonds and angles, LJ between the ends: one minimum up to a rigid motion and the mirror image).

    /usr/bin/python3 tests/test_minimize_lammps.py build/stiffmd

1. `stiffmd check` on the deck without its [minimize] table, `--write-data`: the start as a LAMMPS data
   file with the deck's types and coefficients (bond harmonic, angle harmonic, lj/cut).
2. LAMMPS: the same styles (pair_modify shift yes, special_bonds lj 0 0 1, shrink-wrapped open box),
   `min_style cg` and `minimize 0 1e-10 100000 1000000`; the energy from thermo (norm no, %.17g).
3. stiffmd runs the deck with style cg (its own), fire and sd: summary.json's minimize.
Same start energy to 1e-12, same minimum to 1e-6 relative (measured: 1e-13 or better), each stiffmd run
stopped by ftol. Exits 77 (ctest SKIP_RETURN_CODE) when LAMMPS (/usr/bin/lmp) is not installed."""
import os
import re
import sys
import tempfile

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.join(ROOT, "tools"))
import engines  # noqa: E402

LMP = "/usr/bin/lmp"
DECK = os.path.join(ROOT, "inputs", "minimize_chain.toml")

LAMMPS_INPUT = """units lj
atom_style angle
boundary s s s
pair_style lj/cut 2.5
pair_modify shift yes
bond_style harmonic
angle_style harmonic
read_data start.data
special_bonds lj 0.0 0.0 1.0
thermo_style custom step pe fnorm
thermo_modify norm no format float %.17g
thermo 0
min_style cg
minimize 0 1e-10 100000 1000000
"""


def without_table(text, name):
    """The deck's text with the table [name] (its header and keys up to the next table) left out."""
    out, skipping = [], False
    for line in text.splitlines(keepends=True):
        if line.startswith("["):
            skipping = line.strip() == f"[{name}]"
        if not skipping:
            out.append(line)
    return "".join(out)


def lammps_minimum(log_text):
    """(first energy, last energy, iterations, evaluations, stopping criterion) of a LAMMPS minimize log."""
    block = log_text.split("Step PotEng Fnorm", 1)[1].split("Loop time", 1)[0]
    rows = [line.split() for line in block.strip().splitlines()]
    assert len(rows) == 2 and all(len(r) == 3 for r in rows), log_text[-3000:]
    counts = re.search(r"Iterations, force evaluations = (\d+) (\d+)", log_text)
    criterion = re.search(r"Stopping criterion = (.+)", log_text)
    assert counts and criterion, log_text[-3000:]
    return float(rows[0][1]), float(rows[-1][1]), int(counts[1]), int(counts[2]), criterion[1].strip()


def main():
    exe = os.path.abspath(sys.argv[1]) if len(sys.argv) > 1 else os.path.join(ROOT, "build", "stiffmd")
    if not os.path.exists(LMP):
        print(f"minimize_lammps: skipped, {LMP} not installed (tools/setup.sh --bench)")
        sys.exit(77)
    with tempfile.TemporaryDirectory() as d:
        with open(DECK) as f:
            start_deck = without_table(f.read(), "minimize")
        assert "\n[minimize]" not in start_deck and "\n[forces.ends]" in start_deck
        with open(os.path.join(d, "start.toml"), "w") as f:
            f.write(start_deck)
        check = engines.run_engine([exe, "check", os.path.join(d, "start.toml"), "--write-data",
                                    os.path.join(d, "start.data")])
        assert check.code == 0, engines.failure(check, "stiffmd check")
        with open(os.path.join(d, "in.minimize"), "w") as f:
            f.write(LAMMPS_INPUT)
        run = engines.run_lammps(LMP, "in.minimize", os.path.join(d, "log.lammps"), cwd=d, timeout=60)
        with open(os.path.join(d, "log.lammps")) as f:
            log_text = f.read()
        assert run.code == 0, engines.failure(run, "LAMMPS") + engines.tail(os.path.join(d, "log.lammps"))
        e0_lammps, e_lammps, iters, evals, criterion = lammps_minimum(log_text)
        print(f"LAMMPS min_style cg: E0 {e0_lammps!r} -> E {e_lammps!r}, {iters} iterations, {evals} force "
              f"evaluations, stopped by {criterion}")
        assert criterion == "force tolerance", criterion

        for style in ("cg", "fire", "sd"):
            out = os.path.join(d, style)
            engines.run_stiffmd(exe, DECK, out, sets=[f"minimize.style={style}"], timeout=120)
            m = engines.read_summary(out)["minimize"]
            rel = abs(m["energy"] - e_lammps) / abs(e_lammps)
            print(f"stiffmd {style}: E0 {m['initial_energy']!r} -> E {m['energy']!r}, {m['iterations']} iterations, "
                  f"{m['evaluations']} force evaluations, stopped by {m['stopped_by']}, |f|2 {m['fnorm']:.3g}; "
                  f"relative difference from LAMMPS {rel:.2e}")
            assert m["style"] == style and m["stopped_by"] == "ftol", m
            assert abs(m["initial_energy"] - e0_lammps) <= 1e-12 * abs(e0_lammps), (m, e0_lammps)
            assert rel <= 1e-6, (style, m["energy"], e_lammps)
            assert m["energy"] < m["initial_energy"] - 10, m  # it went somewhere: E0 = 12.8, E = -0.17
    print("minimize_lammps: ok")


if __name__ == "__main__":
    main()
