#!/usr/bin/python3
"""The state of inputs/half_melt.toml: a Kremer–Grest melt filling half of a periodic box.

    /usr/bin/python3 tools/half_melt.py build/stiffmd inputs/half_melt.data [CHAINS]

40 chains × 50 beads are built by the engine at density 0.85 in a periodic cube (side 13.3 σ) and
thermalised there (FENE bonds, WCA; 200 FIRE iterations with the force capped at 100 ε/σ push the
builder's beads at 0.8 σ apart, then Langevin at kT = 1, 2 000 steps of 0.005 τ); the final state (`[output] lammps_data`) is then put in a box twice
as long along x, each bead at its unwrapped position wrapped into the new box: the melt fills
0 ≤ x < 13.3 σ (its chains reach a little past both faces), vacuum the rest. CHAINS (40) makes a
larger melt the same way (docs/parallel.md, "Load balance", times steps on 200 chains: 10 000 beads,
by phase).
"""
import os
import subprocess
import sys
import tempfile

BUILD = """
[types.bead]
mass = 1.0

[[build]]
style = "linear-chains"
chains = {chains}
beads = 50
bond_length = 0.97
bond_type = "fene"
density = 0.85
min_distance = 0.8
seed = 41

[velocities]
temperature = 1.0
seed = 42

[forces.fene]
style = "fene"
bond_types.fene = { K = 30.0, R0 = 1.5, epsilon = 1.0, sigma = 1.0 }

[forces.lj]
style = "lj"
epsilon = 1.0
sigma = 1.0
cutoff = 1.12
special_bonds = [0.0, 1.0]
skin = 0.4

[minimize]
style = "fire"
maxiter = 200
max_force = 100.0

[thermostat]
style = "langevin"
temperature = 1.0
damp = 1.0
seed = 43

[integrator]
method = "velocity-verlet"
h = 0.005

[run]
steps = 2000

[output]
xyz = ""
lammps_data = "melt.data"
"""


def stretch_x(text):
    """The data file with its box twice as long along x and every atom at its unwrapped position
    wrapped into the new box (image flags recomputed)."""
    lines = text.splitlines()
    out, section, lo, length = [], None, None, None
    for line in lines:
        words = line.split()
        if line.rstrip().endswith("xlo xhi"):
            lo, hi = float(words[0]), float(words[1])
            length = hi - lo
            out.append(f"{lo!r} {lo + 2 * length!r} xlo xhi")
            continue
        if words and words[0] in ("Atoms", "Velocities", "Bonds", "Masses", "Angles"):
            section = words[0]
            out.append(line)
            continue
        if section == "Atoms" and len(words) >= 9:
            # atom_style molecular or bond: id mol type x y z ix iy iz (image flags last)
            x, ix = float(words[-6]), int(words[-3])
            unwrapped = x + ix * length
            image = (unwrapped - lo) // (2 * length)
            words[-6] = repr(unwrapped - image * 2 * length)
            words[-3] = str(int(image))
            out.append(" ".join(words))
            continue
        out.append(line)
    return "\n".join(out) + "\n"


def main(argv):
    if len(argv) not in (3, 4):
        raise SystemExit(__doc__)
    stiffmd, target = argv[1], argv[2]
    chains = int(argv[3]) if len(argv) == 4 else 40
    with tempfile.TemporaryDirectory() as tmp:
        deck = os.path.join(tmp, "build.toml")
        with open(deck, "w") as f:
            f.write(BUILD.replace("{chains}", str(chains)))
        subprocess.run([stiffmd, "run", deck, "-o", os.path.join(tmp, "out"), "-q", "--no-progress"], check=True,
                       env=dict(os.environ, OMP_NUM_THREADS="1"))
        with open(os.path.join(tmp, "out", "melt.data")) as f:
            text = f.read()
    with open(target, "w") as f:
        f.write(stretch_x(text))


if __name__ == "__main__":
    sys.exit(main(sys.argv))
