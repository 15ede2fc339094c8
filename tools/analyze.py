#!/usr/bin/python3
"""The first analyses of a polymer run, from its output directory (Debian's python3: MDAnalysis,
numpy, matplotlib; ASE for the extended XYZ).

    /usr/bin/python3 tools/analyze.py RUN_DIR [-o OUT_DIR] [--topology FILE] [--trajectory FILE]
                                      [--atom-style STYLE] [--start T] [--every K] [--middle K]
                                      [--rdf-bins B] [--rdf-rmax R] [--rdf-frames M]

Inputs. The topology is a LAMMPS data file with masses, bonds and molecule ids: RUN_DIR/topology.data
when present, else the one *.data file there (`[output] lammps_data = "final.data"` writes one);
MDAnalysis reads it (atom_style from the `Atoms # style` hint unless --atom-style is given). The
trajectory is the run's extended XYZ (trajectory.xyz, or the one *.xyz / *.xyz.gz), read with ASE for
its times and cell; its positions are unwrapped, as Rg and the MSDs need. An H5MD file
(--trajectory traj.h5md) also works: MDAnalysis reads the wrapped positions, times and box, and the
positions are unwrapped with /particles/<group>/image (which MDAnalysis 2.4.2 ignores). Frames with
t < --start are dropped (equilibration), then every K-th frame is kept.

Chains are the bonded fragments of the topology: `linear` (two ends), `ring` (every bead has two
bonded neighbours) or `branched` (anything else, e.g. stars); single unbonded particles are not chains.

Outputs (OUT_DIR, default RUN_DIR/analysis), each a CSV and a PNG, and a summary on stdout:
  chains.csv            per chain: kind, beads, <Rg^2>, <R^2> (linear: end-to-end; ring: diameter)
  size_vs_time          <Rg^2>(t) and <R^2>(t) over chains
  size_distribution     histograms (probability densities) of Rg and R over chains and frames
  msd                   g1(t) = <|r_i(t0+t) - r_i(t0)|^2> over all particles and time origins t0,
                        g1_middle over the --middle central beads of each linear chain (if given),
                        g3(t) = <|R_cm(t0+t) - R_cm(t0)|^2> over chains (mass-weighted centres)
  ree_autocorrelation   C(t) = <R(t0+t).R(t0)> / <R^2>: linear chains the end-to-end vector, rings the
                        diameter vectors r_{i+N/2} - r_i (every i), branched chains none; <R^2> is over
                        every frame, so C may exceed 1 slightly where few origins remain
  rdf                   g(r) of all pairs (total) and of pairs on different molecules (intermolecular),
                        MDAnalysis InterRDF, periodic boxes only, r up to half the shortest edge or
                        5 mean spacings rho^(-1/3), whichever is shorter (--rdf-rmax to choose), from
                        at most --rdf-frames (10) frames evenly spread
  angles, dihedrals     histograms (degrees) of the bond angle i-j-k (180 = straight) and of the
                        torsion i-j-k-l (180 = trans) over all bonded triples/quadruples (guessed from
                        the bonds, not from the data file's angle list), time-averaged
Definitions. Rg^2 = sum m_i |r_i - R_cm|^2 / sum m_i. For a ring the end-to-end distance is 0, so R^2 is
its squared diameter |r_{i+N/2} - r_i|^2 averaged over i (N even; the nearest-to-opposite bead for N odd),
the thermo column end_to_end's sqrt(R^2) per ring.
Time correlations (msd, ree_autocorrelation) average over every time origin and need equally spaced
frames: a last frame off the grid (the final state of a run whose t_end is not a multiple of the
output interval) is left out of them. No centre-of-mass drift is removed: stiffmd keeps the total
momentum zero.
"""
import argparse
import glob
import os
import sys
import warnings

import numpy as np

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

with warnings.catch_warnings():
    warnings.simplefilter("ignore")
    try:  # imported quietly here, else MDAnalysis's TPR parser prints a DeprecationWarning for it
        import xdrlib  # noqa: F401
    except ImportError:
        pass
    import MDAnalysis as mda
    from MDAnalysis.analysis.rdf import InterRDF
    from MDAnalysis.coordinates.memory import MemoryReader
    from MDAnalysis.lib.distances import calc_angles, calc_dihedrals
warnings.filterwarnings("ignore")  # MDAnalysis and ASE chatter about formats and deprecations


class UsageError(Exception):
    """Bad arguments or input files: one line, exit 2."""


# ---------------------------------------------------------------- finding and reading the inputs

def find_topology(run_dir):
    preferred = os.path.join(run_dir, "topology.data")
    if os.path.isfile(preferred):
        return preferred
    found = sorted(glob.glob(os.path.join(run_dir, "*.data")))
    if len(found) == 1:
        return found[0]
    if not found:
        raise UsageError(f"{run_dir}: no topology (*.data) file; run with [output] lammps_data = \"final.data\" "
                         "or pass --topology")
    raise UsageError(f"{run_dir}: several *.data files ({', '.join(map(os.path.basename, found))}); pass --topology")


def find_trajectory(run_dir):
    for name in ("trajectory.xyz", "trajectory.xyz.gz"):
        if os.path.isfile(os.path.join(run_dir, name)):
            return os.path.join(run_dir, name)
    for patterns in (("*.xyz", "*.xyz.gz"), ("*.h5md", "*.h5")):
        found = sorted(f for p in patterns for f in glob.glob(os.path.join(run_dir, p)))
        if len(found) == 1:
            return found[0]
        if len(found) > 1:
            raise UsageError(f"{run_dir}: several trajectories ({', '.join(map(os.path.basename, found))}); "
                             "pass --trajectory")
    raise UsageError(f"{run_dir}: no trajectory (*.xyz, *.xyz.gz, *.h5md); pass --trajectory")


# LAMMPS atom styles (the `Atoms # style` hint) as MDAnalysis column lists.
ATOM_STYLES = {"atomic": "id type x y z", "bond": "id resid type x y z", "angle": "id resid type x y z",
               "molecular": "id resid type x y z", "full": "id resid type charge x y z",
               "charge": "id type charge x y z"}


def atom_style_hint(path):
    with open(path) as f:
        for line in f:
            words = line.split()
            if words[:1] == ["Atoms"]:
                return words[2] if len(words) > 2 and words[1] == "#" else None
    return None


def load_topology(path, atom_style):
    if atom_style is None:
        hint = atom_style_hint(path)
        atom_style = ATOM_STYLES.get(hint) if hint else None
    elif atom_style in ATOM_STYLES:
        atom_style = ATOM_STYLES[atom_style]
    kwargs = {"atom_style": atom_style} if atom_style else {}
    try:
        return mda.Universe(path, topology_format="DATA", **kwargs)
    except Exception as e:  # MDAnalysis raises many kinds; name the file
        raise UsageError(f"{path}: MDAnalysis cannot read it as a LAMMPS data file: {e}") from None


def read_xyz(path, n_atoms):
    """Unwrapped positions [F][N][3], times [F], box edge lengths [F][3] or None (ASE's extxyz)."""
    import ase.io
    try:
        frames = ase.io.read(path, index=":")
    except Exception as e:
        raise UsageError(f"{path}: ASE cannot read it as extended XYZ: {e}") from None
    if any(len(a) != n_atoms for a in frames):
        raise UsageError(f"{path}: frames do not have the topology's {n_atoms} atoms")
    x = np.array([a.get_positions() for a in frames])
    if not all("time" in a.info for a in frames):
        print(f"warning: {path}: no time= in the comment lines; using the frame index as time", file=sys.stderr)
        t = np.arange(len(frames), dtype=float)
    else:
        t = np.array([float(a.info["time"]) for a in frames])
    periodic = all(a.pbc.all() for a in frames)
    box = np.array([a.cell.lengths() for a in frames]) if periodic else None
    if periodic and not all(np.allclose(a.cell.angles(), 90) for a in frames):
        raise UsageError(f"{path}: only orthorhombic boxes are supported")
    return x, t, box


def read_h5md(path, n_atoms):
    """Positions unwrapped with the H5MD image element; times and box as MDAnalysis reads them."""
    import h5py
    from MDAnalysis.coordinates.H5MD import H5MDReader
    reader = H5MDReader(path, convert_units=False)
    if reader.n_atoms != n_atoms:
        raise UsageError(f"{path}: {reader.n_atoms} particles, the topology has {n_atoms}")
    x, t, dims = [], [], []
    for ts in reader:
        x.append(ts.positions.astype(float))
        t.append(ts.time)
        dims.append(None if ts.dimensions is None else ts.dimensions.copy())
    x, t = np.array(x), np.array(t)
    with h5py.File(path, "r") as f:
        group = f["particles"][list(f["particles"])[0]]
        boundary = [b.decode() if isinstance(b, bytes) else str(b) for b in group["box"].attrs["boundary"]]
        if "image" in group:
            edges = group["box/edges/value"][:len(x)]
            lengths = np.array([np.diag(e) if e.ndim == 2 else e for e in edges])
            x = x + group["image/value"][:len(x)] * lengths[:, None, :]
    periodic = boundary == ["periodic"] * 3 and all(d is not None for d in dims)
    box = np.array([d[:3] for d in dims]) if periodic else None
    return x, t, box


class Run:
    """The topology (an MDAnalysis Universe whose trajectory is the unwrapped frames in memory),
    positions x [F][N][3], times t [F], box edges [F][3] (None unless periodic on every axis)."""

    def __init__(self, topology, trajectory, atom_style=None, start=0.0, every=1):
        self.topology_path, self.trajectory_path = topology, trajectory
        self.u = load_topology(topology, atom_style)
        n = self.u.atoms.n_atoms
        if trajectory.endswith((".h5md", ".h5")):
            x, t, box = read_h5md(trajectory, n)
        else:
            x, t, box = read_xyz(trajectory, n)
        keep = np.flatnonzero(t >= start - 1e-12)[::every]
        if len(keep) == 0:
            raise UsageError(f"{trajectory}: no frame at t >= {start}")
        self.x, self.t = x[keep], t[keep]
        self.box = None if box is None else box[keep]
        dims = None
        if self.box is not None:
            dims = np.hstack([self.box, np.full((len(keep), 3), 90.0)])
        self.u.load_new(self.x.astype(np.float32), format=MemoryReader, order="fac", dimensions=dims)
        self.masses = self.u.atoms.masses.astype(float)

    def uniform_frames(self):
        """How many leading frames lie on one time grid (what the time correlations use)."""
        if len(self.t) < 2:
            return len(self.t)
        dt = np.diff(self.t)
        on_grid = np.isclose(dt, dt[0], rtol=1e-6, atol=1e-12)
        return len(self.t) if on_grid.all() else int(np.argmin(on_grid)) + 1


# ---------------------------------------------------------------- chains

class Chain:
    def __init__(self, kind, path):
        self.kind, self.path = kind, np.asarray(path)  # path: bead indices in bond order (any order if branched)


def bond_neighbours(u):
    neighbours = [[] for _ in range(u.atoms.n_atoms)]
    for i, j in (u.bonds.indices if hasattr(u, "bonds") else []):
        neighbours[i].append(j)
        neighbours[j].append(i)
    return neighbours


def find_chains(u):
    """Bonded fragments with their kind and, for linear chains and rings, the beads in bond order."""
    neighbours = bond_neighbours(u)
    chains = []
    for frag in u.atoms.fragments:
        ix = frag.indices
        if len(ix) < 2:
            continue
        degree = np.array([len(neighbours[i]) for i in ix])
        ends = ix[degree == 1]
        if len(ends) == 2 and np.all(degree <= 2):
            kind, start = "linear", ends.min()
        elif np.all(degree == 2):
            kind, start = "ring", ix.min()
        else:
            chains.append(Chain("branched", ix))
            continue
        path, previous = [start], -1
        while len(path) < len(ix):
            step = [k for k in neighbours[path[-1]] if k != previous and (len(path) < 2 or k != path[-2])]
            step = min(step)  # a ring's first step: the lower-index neighbour
            previous = path[-1]
            path.append(step)
        chains.append(Chain(kind, path))
    return chains


def centres_of_mass(x, masses, chains):
    """[F][chains][3] mass-weighted centres."""
    return np.stack([np.einsum("fia,i->fa", x[:, c.path], masses[c.path]) / masses[c.path].sum() for c in chains],
                    axis=1)


def radius_of_gyration_sq(x, masses, chains):
    """[F][chains] Rg^2 = sum m |r - R_cm|^2 / M."""
    com = centres_of_mass(x, masses, chains)
    out = np.empty((x.shape[0], len(chains)))
    for k, c in enumerate(chains):
        d = x[:, c.path] - com[:, k, None, :]
        out[:, k] = np.einsum("fia,fia,i->f", d, d, masses[c.path]) / masses[c.path].sum()
    return out


def size_vectors(x, chain):
    """[F][m][3]: the end-to-end vector (linear, m = 1) or the N diameter vectors (ring)."""
    p = chain.path
    if chain.kind == "linear":
        return (x[:, p[-1]] - x[:, p[0]])[:, None, :]
    if chain.kind == "ring":
        return x[:, np.roll(p, -(len(p) // 2))] - x[:, p]
    return None


# ---------------------------------------------------------------- time correlations

def mean_square_displacement(r):
    """r [F][M][3] -> [F]: <|r(t0 + k dt) - r(t0)|^2> over the M objects and every origin t0."""
    f = r.shape[0]
    out = np.zeros(f)
    for k in range(1, f):
        d = r[k:] - r[:-k]
        out[k] = np.mean(np.einsum("fma,fma->fm", d, d))
    return out


def vector_autocorrelation(v):
    """v [F][M][3] -> [F]: <v(t0 + k dt).v(t0)> / <|v|^2> over the M vectors and every origin t0."""
    f = v.shape[0]
    norm = np.mean(np.einsum("fma,fma->fm", v, v))
    return np.array([np.mean(np.einsum("fma,fma->fm", v[k:], v[:f - k])) for k in range(f)]) / norm


# ---------------------------------------------------------------- output helpers

def write_csv(path, header, columns):
    np.savetxt(path, np.column_stack(columns), delimiter=",", header=",".join(header), comments="", fmt="%.10g")


def plot(path, x, curves, xlabel, ylabel, loglog=False, title=None):
    fig, ax = plt.subplots(figsize=(5.5, 4))
    for label, y in curves:
        if loglog:
            ok = (x > 0) & (y > 0)
            ax.loglog(x[ok], y[ok], "o-", ms=3, label=label)
        else:
            ax.plot(x, y, "-", label=label)
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    if title:
        ax.set_title(title, fontsize=9)
    if len(curves) > 1 or curves[0][0]:
        ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def histogram(values, bins, value_range):
    density, edges = np.histogram(values, bins=bins, range=value_range, density=True)
    return 0.5 * (edges[1:] + edges[:-1]), density


# ---------------------------------------------------------------- the analyses

def chain_sizes(run, chains, out, summary):
    rg2 = radius_of_gyration_sq(run.x, run.masses, chains)
    r2 = np.full_like(rg2, np.nan)
    for k, c in enumerate(chains):
        v = size_vectors(run.x, c)
        if v is not None:
            r2[:, k] = np.mean(np.einsum("fma,fma->fm", v, v), axis=1)
    kinds = [c.kind for c in chains]
    with open(os.path.join(out, "chains.csv"), "w") as f:
        f.write("chain,kind,beads,first_bead,rg2_mean,r2_mean\n")
        for k, c in enumerate(chains):
            f.write(f"{k},{c.kind},{len(c.path)},{c.path.min()},{rg2[:, k].mean():.10g},"
                    f"{'' if np.isnan(r2[0, k]) else format(r2[:, k].mean(), '.10g')}\n")
    has_r = ~np.isnan(r2[0])
    r2_t = np.nanmean(r2[:, has_r], axis=1) if has_r.any() else np.full(len(run.t), np.nan)
    write_csv(os.path.join(out, "size_vs_time.csv"), ["time", "rg2_mean", "r2_mean"], [run.t, rg2.mean(axis=1), r2_t])
    curves = [("<Rg²>", rg2.mean(axis=1))] + ([("<R²>", r2_t)] if has_r.any() else [])
    plot(os.path.join(out, "size_vs_time.png"), run.t, curves, "t", "squared size")

    rg = np.sqrt(rg2).ravel()
    r = np.sqrt(r2[:, has_r]).ravel()
    top = max(rg.max(), r.max() if r.size else 0) * 1.05
    centres, p_rg = histogram(rg, 60, (0, top))
    _, p_r = histogram(r, 60, (0, top)) if r.size else (None, np.full(60, np.nan))
    write_csv(os.path.join(out, "size_distribution.csv"), ["r", "p_rg", "p_r"], [centres, p_rg, p_r])
    plot(os.path.join(out, "size_distribution.png"), centres,
         [("P(Rg)", p_rg)] + ([("P(R) (rings: diameter)" if "ring" in kinds else "P(R)", p_r)] if r.size else []), "r", "probability density")

    for kind in ("linear", "ring", "branched"):
        sel = np.array([k == kind for k in kinds])
        if not sel.any():
            continue
        beads = sorted({len(c.path) for c, s in zip(chains, sel) if s})
        samples = rg2[:, sel]
        line = (f"{kind} chains: {sel.sum()} of {'/'.join(map(str, beads))} beads; "
                f"<Rg^2> = {samples.mean():.6g} ± {stderr(samples):.2g}")
        summary[f"{kind}_rg2"] = samples.mean()
        if kind != "branched":
            name = "R_ee" if kind == "linear" else "diameter"
            rs = r2[:, sel]
            line += (f", <{name}^2> = {rs.mean():.6g} ± {stderr(rs):.2g}, "
                     f"<{name}^2>/<Rg^2> = {rs.mean() / samples.mean():.4g}")
            summary[f"{kind}_r2"] = rs.mean()
        print(line)


def stderr(samples):
    """Standard error of the mean, chains taken as independent (frames of one chain are not)."""
    per_chain = samples.mean(axis=0)
    return per_chain.std(ddof=1) / np.sqrt(len(per_chain)) if len(per_chain) > 1 else float("nan")


def time_correlations(run, chains, out, middle, summary):
    nf = run.uniform_frames()
    if nf < len(run.t):
        print(f"time correlations: the last {len(run.t) - nf} frame(s) are off the time grid and left out")
    if nf < 2:
        print("time correlations: fewer than 2 equally spaced frames, skipped")
        return
    x, lag = run.x[:nf], run.t[:nf] - run.t[0]
    g1 = mean_square_displacement(x)
    header, columns, curves = ["time", "g1"], [lag, g1], [("g1", g1)]
    linear = [c for c in chains if c.kind == "linear"]
    if middle > 0 and linear:
        mid = np.concatenate([c.path[(len(c.path) - middle) // 2:][:middle] for c in linear])
        g1m = mean_square_displacement(x[:, mid])
        header.append("g1_middle")
        columns.append(g1m)
        curves.append((f"g1 (middle {middle})", g1m))
    if chains:
        g3 = mean_square_displacement(centres_of_mass(x, run.masses, chains))
        header.append("g3")
        columns.append(g3)
        curves.append(("g3", g3))
    write_csv(os.path.join(out, "msd.csv"), header, columns)
    plot(os.path.join(out, "msd.png"), lag, curves, "t", "mean-square displacement", loglog=True)
    summary["g1_last"] = g1[-1]
    print(f"msd: {nf} frames, t up to {lag[-1]:.6g}: g1 = {g1[-1]:.6g}"
          + (f", g3 = {columns[header.index('g3')][-1]:.6g}" if chains else ""))

    sized = [c for c in chains if c.kind in ("linear", "ring")]
    if sized:
        v = np.concatenate([size_vectors(x, c) for c in sized], axis=1)
        c_t = vector_autocorrelation(v)
        write_csv(os.path.join(out, "ree_autocorrelation.csv"), ["time", "c"], [lag, c_t])
        plot(os.path.join(out, "ree_autocorrelation.png"), lag, [("", c_t)], "t", "<R(t)·R(0)> / <R²>")
        summary["ree_autocorrelation"] = c_t
        print(f"end-to-end autocorrelation: C({lag[-1]:.6g}) = {c_t[-1]:.4g}"
              + (" (rings: diameter vectors)" if any(c.kind == "ring" for c in sized) else ""))


def pair_distribution(run, chains, out, bins, rmax, max_frames):
    if run.box is None:
        print("rdf: skipped (needs a box periodic on every axis)")
        return
    if not rmax:  # half the shortest edge, at most 5 mean spacings rho^(-1/3) (pair counts stay small)
        rho = run.u.atoms.n_atoms / np.prod(run.box[0])
        rmax = min(0.5 * run.box.min() * (1 - 1e-9), 5 * rho ** (-1 / 3))
    u = run.u
    step = -(-len(run.t) // max_frames)  # every step-th frame: at most max_frames of them
    total = InterRDF(u.atoms, u.atoms, nbins=bins, range=(0.0, rmax), exclusion_block=(1, 1)).run(step=step)
    columns, header = [total.results.bins, total.results.rdf], ["r", "g_total"]
    curves = [("total", total.results.rdf)]
    # Intermolecular: InterRDF excludes diagonal blocks of equal size, so it needs every molecule
    # (chains and single particles alike) to be one contiguous block of the same number of beads.
    sizes = {len(c.path) for c in chains}
    contiguous = all(np.ptp(c.path) == len(c.path) - 1 for c in chains)
    in_chains = sum(len(c.path) for c in chains)
    if not chains:
        sizes, contiguous = {1}, True
    if len(sizes) == 1 and contiguous and (in_chains == u.atoms.n_atoms or not chains):
        n = sizes.pop()
        inter = InterRDF(u.atoms, u.atoms, nbins=bins, range=(0.0, rmax), exclusion_block=(n, n)).run(step=step)
        columns.append(inter.results.rdf)
        header.append("g_inter")
        curves.append(("intermolecular", inter.results.rdf))
    else:
        print("rdf: intermolecular g(r) skipped (needs molecules of one size, each a contiguous index block)")
    write_csv(os.path.join(out, "rdf.csv"), header, columns)
    plot(os.path.join(out, "rdf.png"), total.results.bins, curves, "r", "g(r)")
    tail = total.results.bins > 0.5 * rmax
    print(f"rdf: r up to {rmax:.4g}, {len(range(0, len(run.t), step))} frames; mean g_total over r > {0.5 * rmax:.3g}: "
          f"{total.results.rdf[tail].mean():.4f}")


def bonded_tuples(u):
    """Every bonded triple i-j-k and quadruple i-j-k-l (each once), from the bonds alone."""
    neighbours = bond_neighbours(u)
    angles = [(i, j, k) for j, nb in enumerate(neighbours) for a, i in enumerate(nb) for k in nb[a + 1:]]
    dihedrals = [(i, j, k, l) for j, k in u.bonds.indices for i in neighbours[j] if i != k
                 for l in neighbours[k] if l not in (j, i)]
    return np.array(angles, dtype=int).reshape(-1, 3), np.array(dihedrals, dtype=int).reshape(-1, 4)


def bonded_geometry(run, out, summary, max_frames=200):
    u = run.u
    if not hasattr(u, "bonds") or len(u.bonds) < 2:
        print("angles: skipped (fewer than two bonds)")
        return
    ang_idx, dih_idx = bonded_tuples(u)
    frames = np.unique(np.linspace(0, len(run.t) - 1, min(max_frames, len(run.t))).astype(int))
    theta, phi = [], []
    for f in frames:
        x = run.x[f]
        if len(ang_idx):
            theta.append(calc_angles(*(x[ang_idx[:, k]] for k in range(3))))
        if len(dih_idx):
            phi.append(calc_dihedrals(*(x[dih_idx[:, k]] for k in range(4))))
    for name, values, lo in (("angles", theta, 0.0), ("dihedrals", phi, -180.0)):
        if not values:
            print(f"{name}: none in the topology")
            continue
        deg = np.degrees(np.concatenate(values))
        centres, p = histogram(deg, 180, (lo, 180.0))
        write_csv(os.path.join(out, f"{name}.csv"), ["degrees", "p"], [centres, p])
        label = "bond angle i-j-k (180 = straight)" if name == "angles" else "torsion i-j-k-l (180 = trans)"
        plot(os.path.join(out, f"{name}.png"), centres, [("", p)], label + ", degrees", "probability density")
        summary[f"{name}_peak"] = centres[np.argmax(p)]
        print(f"{name}: {len(deg) // len(frames)} per frame, mean {deg.mean():.2f} deg, "
              f"histogram peak at {centres[np.argmax(p)]:.1f} deg")


def analyze(run, out, middle=0, rdf_bins=100, rdf_rmax=None, rdf_frames=10):
    """Runs every analysis; returns the summary numbers (a dict) for tests."""
    os.makedirs(out, exist_ok=True)
    chains = find_chains(run.u)
    summary = {"chains": chains}
    kinds = {k: sum(c.kind == k for c in chains) for k in ("linear", "ring", "branched")}
    print(f"{run.u.atoms.n_atoms} particles, {len(chains)} chains ({', '.join(f'{v} {k}' for k, v in kinds.items() if v)}), "
          f"{len(run.t)} frames t = {run.t[0]:.6g}..{run.t[-1]:.6g}; "
          f"topology {run.topology_path}, trajectory {run.trajectory_path}")
    if chains:
        chain_sizes(run, chains, out, summary)
    time_correlations(run, chains, out, middle, summary)
    pair_distribution(run, chains, out, rdf_bins, rdf_rmax, rdf_frames)
    bonded_geometry(run, out, summary)
    print(f"wrote {out}/")
    return summary


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("run_dir", help="the run's output directory")
    ap.add_argument("-o", "--output", help="output folder (default RUN_DIR/analysis)")
    ap.add_argument("--topology", help="LAMMPS data file (default: RUN_DIR/topology.data, else the one *.data)")
    ap.add_argument("--trajectory", help="extended XYZ or H5MD (default: RUN_DIR/trajectory.xyz, else the one *.xyz)")
    ap.add_argument("--atom-style", help="LAMMPS atom style of the data file (atomic, bond, angle, molecular, full) "
                    "or MDAnalysis columns such as 'id resid type x y z'; default from the file's hint")
    ap.add_argument("--start", type=float, default=0.0, help="drop frames with t < START (equilibration)")
    ap.add_argument("--every", type=int, default=1, help="keep every K-th frame")
    ap.add_argument("--middle", type=int, default=0, help="also g1 over the K central beads of each linear chain")
    ap.add_argument("--rdf-bins", type=int, default=100)
    ap.add_argument("--rdf-frames", type=int, default=10, help="g(r) from at most this many frames, evenly spread")
    ap.add_argument("--rdf-rmax", type=float, help="default: half the shortest box edge, at most 5 rho^(-1/3)")
    args = ap.parse_args(argv)
    try:
        if not os.path.isdir(args.run_dir):
            raise UsageError(f"{args.run_dir}: not a directory")
        if args.every < 1 or args.middle < 0 or args.rdf_bins < 1 or args.rdf_frames < 1:
            raise UsageError("--every, --rdf-bins and --rdf-frames must be >= 1, --middle >= 0")
        topology = args.topology or find_topology(args.run_dir)
        trajectory = args.trajectory or find_trajectory(args.run_dir)
        for p in (topology, trajectory):
            if not os.path.isfile(p):
                raise UsageError(f"{p}: no such file")
        run = Run(topology, trajectory, args.atom_style, args.start, args.every)
        analyze(run, args.output or os.path.join(args.run_dir, "analysis"), args.middle, args.rdf_bins,
                args.rdf_rmax, args.rdf_frames)
    except UsageError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
