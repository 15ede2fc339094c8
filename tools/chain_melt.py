"""The LAMMPS chain melt shared by tools/bench_lammps.py and tools/work_precision_melt.py.

inputs/lammps_chain.toml at a given ε, prepared once by stiffmd (`check --write-data`: projected
onto the bonds, T = 1 velocities, thermal bond vibrations) and written as a LAMMPS data file; the
stiffmd deck and the LAMMPS input that run that same state with the same potentials: stiff harmonic
bonds ℓ = 0.97, α = 1 (stiffmd ½(α/ε)²(r − ℓ)², LAMMPS `harmonic` K(r − r0)² with K = α²/(2ε²)) and
WCA between non-bonded pairs (`special_bonds lj 0 1 1`, skin 0.3).

Also the readers and the block average the melt tools share (tools/kremer_grest_lammps.py,
tools/stiff_melt_nvt.py): the bonds of a LAMMPS data file, the frames of an extended XYZ file.
"""
import math
import os
import shlex
import subprocess

from engines import RunFailed  # tools/ is the script's directory

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SOURCE_DECK = os.path.join(ROOT, "inputs", "lammps_chain.toml")
BOND_LENGTH = 0.97  # ℓ and α of inputs/lammps_chain.toml
ALPHA = 1.0
WCA_CUTOFF = 2.0 ** (1.0 / 6.0)


def read_bonds(path):
    """The Bonds section of a LAMMPS data file as 0-based (i, j) pairs (a list)."""
    bonds, section = [], None
    with open(path) as f:
        for line in f:
            s = line.split("#")[0].strip()
            if not s:
                continue
            if s.split()[0] in ("Atoms", "Velocities", "Bonds", "Masses", "Angles", "Dihedrals", "Impropers"):
                section = s.split()[0]
                continue
            if section == "Bonds" and len(s.split()) == 4:
                w = s.split()
                bonds.append((int(w[2]) - 1, int(w[3]) - 1))
    return bonds


def xyz_frames(path):
    """(time, positions N × 3 as a numpy array) of every frame of an extended XYZ file."""
    import numpy as np
    with open(path) as f:
        while True:
            head = f.readline()
            if not head:
                return
            n = int(head)
            comment = f.readline()
            t = float(comment.split("time=")[1].split()[0])
            yield t, np.loadtxt([f.readline() for _ in range(n)], usecols=(1, 2, 3), ndmin=2)


def block_mean(series, nblocks):
    """Mean and its standard error from nblocks block averages (series: samples along axis 0)."""
    import numpy as np
    series = np.asarray(series, dtype=float)
    per = len(series) // nblocks
    means = series[: per * nblocks].reshape(nblocks, per, *series.shape[1:]).mean(axis=1)
    return means.mean(axis=0), means.std(axis=0, ddof=1) / math.sqrt(nblocks)


def fmt(x):
    """A float as the shortest text that reads back exactly (for decks, --set and LAMMPS inputs)."""
    return repr(float(x))


def prepare_state(stiffmd, eps, data, env=None, deck=SOURCE_DECK):
    """Writes the prepared t = 0 state at this ε to the LAMMPS data file `data`; returns its path.
    `deck`: a deck with a `variables.eps` whose [prepare] makes the state (default the data.chain melt)."""
    os.makedirs(os.path.dirname(os.path.abspath(data)), exist_ok=True)
    cmd = [stiffmd, "check", deck, "--set", f"variables.eps={eps}", "--write-data", data]
    p = subprocess.run(cmd, capture_output=True, text=True, env=env)
    if p.returncode != 0:
        raise RunFailed(f"state preparation failed (exit {p.returncode}): {shlex.join(cmd)}\n"
                        f"--- output tail ---\n{(p.stdout + p.stderr)[-3000:]}")
    return data


def tile_data(src, dst, reps=(2, 2, 2)):
    """Writes the LAMMPS data file `src` (atom_style bond: Atoms `id mol type x y z [ix iy iz]`,
    Velocities, Bonds; no angles) replicated reps[0] × reps[1] × reps[2] times into a box that many
    times larger, as LAMMPS's `replicate`: copy k of atom id is id + k·N in molecule mol + k·M, at
    its unwrapped position shifted by the copy's offset, written wrapped into the new box with its
    image flags. Returns dst."""
    with open(src) as f:
        lines = f.read().splitlines()
    counts, lo, length, sections, current = {}, [0.0] * 3, [0.0] * 3, {}, None
    for line in lines:
        s = line.split("#")[0].strip()
        w = s.split()
        if not w:
            continue
        if w[0] in ("Masses", "Atoms", "Velocities", "Bonds", "Angles", "Dihedrals", "Impropers"):
            current = w[0]
            sections[current] = []
        elif current is None and len(w) == 2 and w[1] in ("atoms", "bonds", "angles", "dihedrals", "impropers"):
            counts[w[1]] = int(w[0])
        elif current is None and len(w) == 3 and w[1] == "atom" and w[2] == "types":
            counts["atom types"] = int(w[0])
        elif current is None and len(w) == 3 and w[1] == "bond" and w[2] == "types":
            counts["bond types"] = int(w[0])
        elif current is None and len(w) == 4 and w[2] in ("xlo", "ylo", "zlo"):
            a = "xyz".index(w[2][0])
            lo[a], length[a] = float(w[0]), float(w[1]) - float(w[0])
        elif current is not None:
            sections[current].append(w)
    if any(counts.get(k, 0) for k in ("angles", "dihedrals", "impropers")):
        raise RunFailed(f"{src}: tile_data handles atoms and bonds only")
    n, nb = counts["atoms"], counts.get("bonds", 0)
    atoms, bonds = sections["Atoms"], sections.get("Bonds", [])
    if len(atoms) != n or len(bonds) != nb:
        raise RunFailed(f"{src}: {len(atoms)} atoms and {len(bonds)} bonds listed, the header says {n} and {nb}")
    velocities = {w[0]: w[1:4] for w in sections.get("Velocities", [])}
    nmol = max(int(w[1]) for w in atoms)
    new_length = [length[a] * reps[a] for a in range(3)]
    copies = [(i, j, k) for k in range(reps[2]) for j in range(reps[1]) for i in range(reps[0])]
    out = [f"LAMMPS data file: {src} replicated {reps[0]} x {reps[1]} x {reps[2]} (tools/chain_melt.py tile_data)", "",
           f"{n * len(copies)} atoms", f"{nb * len(copies)} bonds", f"{counts.get('atom types', 1)} atom types",
           f"{counts.get('bond types', 1)} bond types", ""]
    out += [f"{fmt(lo[a])} {fmt(lo[a] + new_length[a])} {c}lo {c}hi" for a, c in enumerate("xyz")]
    out += ["", "Masses", ""] + [" ".join(w) for w in sections.get("Masses", [])] + ["", "Atoms # bond", ""]
    for u, shift in enumerate(copies):
        for w in atoms:
            image = [int(v) for v in w[6:9]] if len(w) >= 9 else [0, 0, 0]
            pos, flags = [], []
            for a in range(3):
                unwrapped = float(w[3 + a]) + image[a] * length[a] + shift[a] * length[a]
                whole = math.floor((unwrapped - lo[a]) / new_length[a])
                pos.append(fmt(unwrapped - whole * new_length[a]))
                flags.append(str(whole))
            out.append(f"{int(w[0]) + u * n} {int(w[1]) + u * nmol} {w[2]} {' '.join(pos)} {' '.join(flags)}")
    if velocities:
        out += ["", "Velocities", ""]
        for u in range(len(copies)):
            out += [f"{int(w[0]) + u * n} {' '.join(velocities[w[0]])}" for w in atoms]
    if bonds:
        out += ["", "Bonds", ""]
        for u in range(len(copies)):
            out += [f"{int(w[0]) + u * nb} {w[1]} {int(w[2]) + u * n} {int(w[3]) + u * n}" for w in bonds]
    with open(dst, "w") as f:
        f.write("\n".join(out) + "\n")
    return dst


def count_atoms(data):
    with open(data) as f:
        for line in f:
            if line.strip().endswith(" atoms"):
                return int(line.split()[0])
    raise RunFailed(f"{data}: no 'N atoms' line")


# Names the tools give an engine method run with another Langevin splitting: (integrator.method,
# the --set overrides that choose the splitting).
SPLITTINGS = {"rattle-obabo": ("rattle", ['thermostat.splitting="obabo"']),
              "fixman-obabo": ("fixman", ['thermostat.splitting="obabo"'])}


def engine_method(name):
    """(stiffmd's integrator.method, extra --set overrides) of a tool's method name."""
    return SPLITTINGS.get(name, (name, []))


def write_deck(path, data, eps, writer, method, h, micro_steps, t_end, thermo_interval):
    """A stiffmd deck running the prepared state (with its velocities; no [velocities], no [prepare],
    no trajectory or histogram output)."""
    # The styles come before read_data: the data file holds stiffmd's force field as Coeffs sections,
    # which LAMMPS reads only for styles already defined.
    with open(path, "w") as f:
        f.write(f"""# Written by {writer}: the prepared state of inputs/lammps_chain.toml at eps = {eps}.
[types.bead]
mass = 1.0

[import]
lammps_data = "{data}"
atom_types = {{ "1" = "bead" }}
bond_types = {{ "1" = "backbone" }}
velocities = true

[forces.bonds]
style = "stiff-harmonic"
level = "fast"
epsilon = {fmt(eps)}
bond_types.backbone = {{ length = {fmt(BOND_LENGTH)}, alpha = {fmt(ALPHA)} }}

[forces.excluded_volume]
style = "wca"
level = "slow"
epsilon = 1.0
sigma = 1.0
special_bonds = [0.0, 1.0]
skin = 0.3

[integrator]
method = "{method}"
h = {fmt(h)}
micro_steps = {micro_steps}

[run]
t_end = {fmt(t_end)}

[output]
xyz = ""
thermo_interval = {fmt(thermo_interval)}

[observables]
histograms = false
""")


def write_lammps_input(path, data, eps, h, n, steps, thermo_every, writer, langevin=None, dump=None):
    """The same state, potentials, h and n in LAMMPS: r-RESPA with the bonds inner, WCA outer.
    langevin = (kT, damp, seed) adds `fix langevin` (applied at the outer level) and the pressure to
    the thermo; dump = (every, file) writes id, mol and unwrapped positions, sorted by id."""
    extra_fix = "" if langevin is None else \
        f"fix             2 all langevin {fmt(langevin[0])} {fmt(langevin[0])} {fmt(langevin[1])} {int(langevin[2])}\n"
    extra_dump = "" if dump is None else \
        f"dump            1 all custom {int(dump[0])} {dump[1]} id mol xu yu zu\ndump_modify     1 sort id format float %.10g\n"
    columns = "step temp pe ke etotal" + ("" if langevin is None else " press")
    k_lammps = ALPHA ** 2 / (2.0 * float(eps) ** 2)  # LAMMPS harmonic: K (r - r0)^2, stiffmd ½ k (r - ℓ)^2
    # The styles come before read_data: the data file holds stiffmd's force field as Coeffs sections,
    # which LAMMPS reads only for styles already defined.
    with open(path, "w") as f:
        f.write(f"""# Written by {writer}: the prepared state of inputs/lammps_chain.toml at eps = {eps}, h = {h}, n = {n}.
units           lj
atom_style      bond
boundary        p p p
special_bonds   lj 0.0 1.0 1.0
bond_style      harmonic
pair_style      lj/cut {WCA_CUTOFF:.17g}
pair_modify     shift yes
read_data       {data}

bond_coeff      1 {k_lammps:.17g} {fmt(BOND_LENGTH)}
pair_coeff      1 1 1.0 1.0 {WCA_CUTOFF:.17g}

neighbor        0.3 bin
neigh_modify    every 1 delay 0 check yes

timestep        {fmt(h)}
run_style       respa 2 {n} bond 1 pair 2
fix             1 all nve
{extra_fix}{extra_dump}
thermo          {thermo_every}
thermo_style    custom {columns}
thermo_modify   norm no format float %.15g
run             {steps}
""")


def lammps_dump_frames(path):
    """(timestep, positions N × 3 sorted by atom id) of every frame of a LAMMPS `dump custom` file
    with columns id x y z (any order of the rows)."""
    import numpy as np
    with open(path) as f:
        while True:
            line = f.readline()
            if not line:
                return
            if not line.startswith("ITEM: TIMESTEP"):
                continue
            step = int(f.readline())
            f.readline()  # ITEM: NUMBER OF ATOMS
            n = int(f.readline())
            for _ in range(4):  # ITEM: BOX BOUNDS and its three lines
                f.readline()
            columns = f.readline().split()[2:]
            rows = np.loadtxt([f.readline() for _ in range(n)], ndmin=2)
            ids = rows[:, columns.index("id")].astype(int)
            x = np.empty((n, 3))
            x[ids - 1] = rows[:, [columns.index(c) for c in ("x", "y", "z")]]
            yield step, x


def read_box(path):
    """The edge lengths (xhi − xlo, ...) of a LAMMPS data file's box."""
    lengths = {}
    with open(path) as f:
        for line in f:
            w = line.split()
            if len(w) == 4 and w[2] in ("xlo", "ylo", "zlo"):
                lengths[w[2][0]] = float(w[1]) - float(w[0])
            if len(lengths) == 3:
                break
    return [lengths["x"], lengths["y"], lengths["z"]]


def linear_chains(bonds, n):
    """The linear chains of a bond list (0-based pairs) as lists of atom indices from one end to the
    other (atoms without bonds are left out)."""
    neighbours = [[] for _ in range(n)]
    for i, j in bonds:
        neighbours[i].append(j)
        neighbours[j].append(i)
    seen, chains = [False] * n, []
    for start in range(n):
        if seen[start] or len(neighbours[start]) != 1:
            continue
        chain, prev, cur = [start], -1, start
        seen[start] = True
        while True:
            nxt = [k for k in neighbours[cur] if k != prev]
            if not nxt:
                break
            prev, cur = cur, nxt[0]
            seen[cur] = True
            chain.append(cur)
        chains.append(chain)
    return chains


def chain_shapes(x, chains, box):
    """Mean bond length, mean Rg² and mean end-to-end R² over the chains of one frame, each chain
    made whole by minimum-image bond vectors (wrapped or unwrapped positions alike)."""
    import numpy as np
    box = np.asarray(box)
    idx = np.array(chains)  # equal-length chains: (chains, beads)
    d = x[idx[:, 1:]] - x[idx[:, :-1]]
    d -= box * np.round(d / box)
    whole = np.concatenate([np.zeros((len(chains), 1, 3)), np.cumsum(d, axis=1)], axis=1)
    centred = whole - whole.mean(axis=1, keepdims=True)
    rg2 = (centred ** 2).sum(axis=2).mean(axis=1)
    r2 = (whole[:, -1] ** 2).sum(axis=1)
    return float(np.linalg.norm(d, axis=2).mean()), float(rg2.mean()), float(r2.mean())


def autocorrelation_time(series):
    """Integrated autocorrelation time in samples (Sokal's window: the sum stops at the first lag
    M ≥ 5 τ(M)); 0.5 for uncorrelated samples."""
    import numpy as np
    y = np.asarray(series, dtype=float) - np.mean(series)
    n = len(y)
    var = y.var()
    if n < 4 or var == 0.0:
        return 0.5
    tau = 0.5
    for lag in range(1, n // 2):
        tau += np.dot(y[:-lag], y[lag:]) / ((n - lag) * var)
        if lag >= 5 * tau:
            break
    return float(tau)
