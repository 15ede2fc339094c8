#!/usr/bin/python3
"""Scaling on paper, from measured per-rank costs: stiffmd's decomposition (docs/parallel.md: whole
molecules integrated by their owners, each bead's pair forces on the rank of its own domain over a
thin halo — "thin"), the earlier whole-molecule ghosts (every bead within r_c + margin of an owned
bead — "whole") and atom decomposition with a halo per micro step ("atoms"), for 10⁶ and 10⁷ beads
on 8–512 ranks (strong and weak), and the beads per rank above which whole-molecule ghosts win over
atoms.

    /usr/bin/python3 tools/scale_model.py                 # the tables of docs/parallel.md
    /usr/bin/python3 tools/scale_model.py --micro 20 --latency 5e-6 --bandwidth 5e9

The model, per macro step and rank holding n beads (a cubic domain of side a = (n/ρ)^(1/3)):

    T = c·n·(1 + β·γ) + h·(λ·m + 24·γ·n/B) + S·n·(1 + γ)/k

  c   compute per owned bead and step, one thread (µs), measured: the 256k melts at 1 rank × 1 thread
      on the 16-core machine (tools/scale_node.sh): KG velocity Verlet 0.296, impulse (50 micro
      steps) 0.885, fixman 0.672
  γ   ghosts per owned bead: (1 + 2w/a)³ − 1. Whole molecules: w = 5.35 σ (chains of 100 at ρ = 0.85:
      the beads within the cutoff plus the halo's margin of an owned bead, which reach past the
      domain with the chains; fitted to the measured 1.30 ghosts per owned bead at 32 000 beads per
      rank on a 2 × 2 × 2 grid (fixman, tools/scale_node.sh); it gives 1.76 for the 2 × 2 × 4 grid at
      16 000, measured 1.75). The formula is for domains cut on every axis: slabs hold fewer
      (1 × 1 × 2 at 128 000: 0.38 measured, 0.73 by the formula). Atoms: w = r_c + skin = 1.42 σ.
  β   the ghosts' share of the work (their list build and the owned–ghost pairs): 0.43, fitted to the
      measured 8 and 16 rank runs (0.40 fixman, 0.46 KG)
  h   halos per macro step: 1 for whole molecules (pairs are slow; no halo in the micro steps);
      for atom decomposition n_micro + 1 for the impulse family (the stiff bonds cross ranks: LAMMPS's
      r-RESPA communicates at every level's step), and 1 + 2 × 8 for the constrained methods (a
      halo per SHAKE and per RATTLE iteration across ranks, as LAMMPS's fix ilves; 8 iterations
      assumed) — atom decomposition of a velocity-Verlet melt without constraints is the plain
      case, 1 halo
  λ, B  message latency and bandwidth (between nodes: 2 µs, 10 GB/s, an InfiniBand HDR-class network;
      assumptions, not measurements); m = 26 neighbours (a 3-D grid)
  S/k  selecting the ghosts again: S = 0.5 µs per extended bead, every k = 15 steps (measured:
      tools/scale_node.sh, the "domain" phase). Atom decomposition pays its own list rebuilds too;
      left out for it, which favours it.
  thin  the ghosts are the halo of a domain, w = r_c + 1.5 skin = 1.72 σ (in.chain ×8 on 16 ranks,
      16 000 beads per rank on a 4 × 2 × 2 grid: 0.46 measured, 0.44 by the formula); two exchanges
      per macro step (positions out, forces back: 2 m messages) carrying 24 γ n bytes of halo
      positions and 72 μ n bytes for the beads whose home is not their owner (position and force
      out, force back), μ = 0.2 at 16 000 beads per rank (from the measured 6.6 MB per step of
      in.chain ×8 on 16 ranks) and growing as the domain's surface per volume, 1/a; a selection is
      the list rebuild one process makes anyway (its extra pass and exchange left out).

The tables print the time per macro step, the speed-up over the fewest ranks (strong) and the
efficiency (weak); the crossover line is the smallest n at which T_whole ≤ T_atom.
"""
import argparse

RHO = 0.85
COMPUTE_US = {"kg-velocity-verlet": 0.296, "impulse": 0.885, "fixman": 0.672}
HALOS_ATOMS = {"kg-velocity-verlet": lambda a: 1, "impulse": lambda a: a.micro + 1,
               "fixman": lambda a: 1 + 2 * a.iterations}


def ghosts(n, width):
    a = (n / RHO) ** (1.0 / 3.0)
    return (1.0 + 2.0 * width / a) ** 3 - 1.0


def step_seconds(n, c_us, halos, width, args):
    g = ghosts(n, width)
    compute = c_us * 1e-6 * n * (1.0 + args.beta * g)
    comm = halos * (args.latency * args.neighbours + 24.0 * g * n / args.bandwidth)
    select = args.select_us * 1e-6 * n * (1.0 + g) / args.select_every
    return compute + comm + select


def whole(n, method, args):
    return step_seconds(n, COMPUTE_US[method], 1, args.whole_width, args)


def moved(n, args):
    a0 = (16000 / RHO) ** (1.0 / 3.0)
    return min(1.0, args.moved * a0 / (n / RHO) ** (1.0 / 3.0))


def thin(n, method, args):
    g = ghosts(n, args.thin_width)
    compute = COMPUTE_US[method] * 1e-6 * n * (1.0 + args.beta * g)
    comm = 2 * args.latency * args.neighbours + (24.0 * g * n + 72.0 * moved(n, args) * n) / args.bandwidth
    return compute + comm


def atoms(n, method, args):
    return step_seconds(n, COMPUTE_US[method], HALOS_ATOMS[method](args), args.atom_width, args) - (
        args.select_us * 1e-6 * n * (1.0 + ghosts(n, args.atom_width)) / args.select_every)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--beta", type=float, default=0.43)
    ap.add_argument("--whole-width", type=float, default=5.35)
    ap.add_argument("--atom-width", type=float, default=1.42)
    ap.add_argument("--thin-width", type=float, default=1.72)
    ap.add_argument("--moved", type=float, default=0.2, help="beads away from their owner's domain at 16 000 per rank")
    ap.add_argument("--latency", type=float, default=2e-6)
    ap.add_argument("--bandwidth", type=float, default=10e9)
    ap.add_argument("--neighbours", type=int, default=26)
    ap.add_argument("--select-us", type=float, default=0.5)
    ap.add_argument("--select-every", type=float, default=15.0)
    ap.add_argument("--micro", type=int, default=50, help="micro steps of the impulse family")
    ap.add_argument("--iterations", type=int, default=8, help="SHAKE/RATTLE iterations across ranks (atoms)")
    args = ap.parse_args()
    ranks = [8, 16, 32, 64, 128, 256, 512]
    for method in COMPUTE_US:
        print(f"\n### {method}\n")
        print("| beads | ranks | beads/rank | thin: ghosts/bead | thin: ms/step | speed-up | whole: ghosts/owned "
              "| whole: ms/step | atoms: ms/step |")
        print("|--:|--:|--:|--:|--:|--:|--:|--:|--:|")
        for total in (1e6, 1e7):
            t0 = thin(total / ranks[0], method, args)
            for p in ranks:
                n = total / p
                t = thin(n, method, args)
                print(f"| {total:.0e} | {p} | {n:,.0f} | {ghosts(n, args.thin_width):.2f} | {1e3 * t:.2f} | "
                      f"{ranks[0] * t0 / t:.0f} | {ghosts(n, args.whole_width):.2f} | "
                      f"{1e3 * whole(n, method, args):.2f} | {1e3 * atoms(n, method, args):.2f} |")
        print("\nweak scaling (the time per step does not depend on the rank count in this model, only on beads"
              " per rank; thin halo, and whole-molecule ghosts):")
        for n in (1e4, 3e4, 1e5, 3e5, 1e6):
            ideal = COMPUTE_US[method] * 1e-6 * n
            print(f"  {n:>9,.0f} beads/rank: thin {1e3 * thin(n, method, args):8.2f} ms/step, efficiency "
                  f"{100 * ideal / thin(n, method, args):3.0f} %; whole {100 * ideal / whole(n, method, args):3.0f} %"
                  " of one rank without ghosts")
        # The crossover, for the measured β and for ghosts that cost less (a leaner extended-set
        # evaluation: the list built on the owned particles' cells only, say).
        measured = args.beta
        for beta in (measured, 0.1, 0.03, 0.01):
            args.beta = beta
            lo, hi = 100.0, 1e8
            if whole(hi, method, args) > atoms(hi, method, args):
                print(f"  β = {beta:g}: whole molecules do not win below 10⁸ beads per rank "
                      f"({HALOS_ATOMS[method](args)} halos per macro step for atoms)")
                continue
            for _ in range(100):
                mid = (lo * hi) ** 0.5
                lo, hi = (lo, mid) if whole(mid, method, args) <= atoms(mid, method, args) else (mid, hi)
            print(f"  β = {beta:g}: whole molecules win from {hi:,.0f} beads per rank "
                  f"({HALOS_ATOMS[method](args)} halos per macro step for atoms)")
        args.beta = measured

if __name__ == "__main__":
    main()
