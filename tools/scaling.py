#!/usr/bin/python3
"""Speed-up with threads and ranks: systems × methods × layouts (ranks × threads) → ms per step,
speed-up, efficiency, serial share and, on several ranks, the halo's cost and the load imbalance.

    /usr/bin/python3 tools/scaling.py                                  # the 256 000-bead melts, 1 and 2 threads
    /usr/bin/python3 tools/scaling.py --systems stiff-32k,kg-32k --threads 1,2,4,8,16 --repeats 2
    /usr/bin/python3 tools/scaling.py --systems kg-32k --layouts 1x2,2x1 --repeats 3 --steps 30
    /usr/bin/python3 tools/scaling.py --systems kg-256k --layouts 1x1,2x1,4x1,8x1,16x1,1x16 --mpiexec /usr/bin/mpiexec
    /usr/bin/python3 tools/scaling.py --systems stiff-256k --methods fixman,rattle --steps 30 --repeats 7
    /usr/bin/python3 tools/scaling.py --deck inputs/polymer_melt.toml --methods rattle,fixman --h 0.01
    /usr/bin/python3 tools/scaling.py --work --layouts 1x1,2x1,1x2,16x1,1x16    # instructions, kg-32k and stiff-32k
    /usr/bin/python3 tools/scaling.py --layouts 1x1 --steps 40 --repeats 3 --stiffmd /tmp/before build/stiffmd   # two builds

Systems (--systems; or --deck PATH: that deck with each method as integrator.method, at --h):
  kg-32k, kg-256k      LAMMPS's in.chain as inputs/kremer_grest.toml (FENE + LJ, velocity Verlet with
                       LAMMPS's Langevin, h = 0.012); 256k: data.chain replicated 2 × 2 × 2
                       (tools/chain_melt.py tile_data). Method: velocity-verlet only.
  stiff-32k, stiff-256k  inputs/lammps_chain.toml prepared at --eps (projected, thermal; tools/chain_melt.py),
                       stiff bonds + WCA under Langevin kT = 1, damp = 1; 256k: the prepared state
                       replicated 2 × 2 × 2. Methods and their steps (METHODS below): velocity-verlet at
                       0.9 ε, impulse at 0.005 with 50 micro steps, rattle and fixman at 0.02 (BAOAB;
                       rattle-obabo, fixman-obabo with OBABO), effective at 0.02.

Layouts: --layouts R1xT1,R2xT2,... runs each deck on R ranks (`MPIEXEC -n R stiffmd run ...`, the
plain command when R = 1) of T threads (OMP_NUM_THREADS = T), in the order given; --threads T1,T2,...
(default 1,2; not with --layouts) is the layouts 1xT, fewest threads first. The deck is the same for
every layout (the engine chooses the domains). For R > 1 the tool sets, unless already set, Open
MPI's OMPI_ALLOW_RUN_AS_ROOT(_CONFIRM)=1 (runs as root), OMPI_MCA_rmaps_base_oversubscribe=1 (more
ranks than cores) and OMPI_MCA_hwloc_base_binding_policy=none (Open MPI would bind each of 2 ranks to
one core, all its threads with it; R = 1 runs unbound too); MPICH ignores them.

Every run is --steps steps, no checkpoints, one thermo sample at the end (the step loop is what is
timed). Runs are interleaved: each repeat runs every system, method and layout in turn (layouts in
alternating order from one repeat to the next), so a drift of the machine's speed hits all alike.
Per (system, method, layout): the median over repeats of summary.json's wall_seconds / steps
(ms/step; on several ranks the slowest rank's step loop); the speed-up over the row's first layout is
the median over repeats of the ratio of the two runs of the same repeat; efficiency = speed-up × the
first layout's cores / the layout's cores (cores = R × T). The serial share is the median of
summary.json's "serial_share" where the engine writes it (the share of the step loop's wall time
outside parallel loops), '—' otherwise. On R > 1 ranks, medians over repeats of summary.json's
"domains": ghosts per owned bead, halo kB (1000 bytes) and messages per step, and the load imbalance
rank_loop_seconds_max / rank_loop_seconds_mean (1 = balanced); '—' on one rank. "pairs/1 rank": the
pairs computed per bead relative to one process's, summary.json's neighbor_pairs (the pairs in the
ranks' neighbour lists summed over ranks, a pair counted once by each rank that lists it; at the top
level or under "domains") ÷ that of the row's first one-rank layout (1×T: the threads share one
list); "n/a" where the engine writes no neighbor_pairs or no layout runs on one rank.

--work: the cost of parallelism without the cores. Each layout runs once, --steps steps (default 10),
every rank under `valgrind --tool=callgrind` (`MPIEXEC -n R valgrind --tool=callgrind
--callgrind-out-file=DIR/cg.%p --dump-before='stiffmd::Run::step_to*' --dump-before='stiffmd::Run::finish*'
stiffmd run ...`): engine/run/run.cpp's run_simulation calls Run::step_to (every macro step) and then
Run::finish, so each process's second dump is exactly its step loop, set-up excluded (its first dump);
a dump holds all the process's threads (callgrind's --toggle-collect would count the calling thread
alone: its switch is per thread, and OpenMP's workers never enter step_to — 1×2 would show half the
work). The step loop's instructions (Ir, the dump's "summary:" line) are summed over ranks, less what
ran inside MPI (the inclusive cost of the calls from outside Open MPI's or MPICH's objects into them:
a rank waiting for another polls inside MPI_Waitall, and that polling depends on the scheduling). Work
= Ir per step ÷ that of the first layout: the instructions the parallel run spends on the same steps,
whatever the cores (16 ranks or 16 threads measure the same on 2 cores, only slower). Idle OpenMP
threads are made to sleep (OMP_WAIT_POLICY=passive: a spinning wait would count) and idle Open MPI
ranks to yield. The table adds the set-up's instructions (all ranks: each prepares the whole scene)
and the seconds each run took under valgrind; work.md and work.csv in --out. The default systems are
kg-32k and stiff-32k (16 ranks of kg-32k: about 5 minutes on 2 cores): every rank prepares the whole
scene, so 16 ranks of a 256 000-bead melt would take about half an hour under valgrind (see
docs/parallel.md, "Before the thin halo").

Builds side by side: --stiffmd B1 B2 ... runs every (system, method, layout) with each binary in turn
(the binaries in alternating order from one repeat to the next; the decks are prepared by B1) and adds
a table "before ÷ after": per row each binary's median ms/step of wall time and of CPU time (summary.json
cpu_seconds / steps, the process's own: less sensitive to other processes on a shared machine than the
wall time) and B1's time ÷ Bk's, the median of the ratios of the runs of one repeat (wall and CPU).
Not with --work.

A shared machine: "others" is the median number of cores other processes kept busy during a row's
runs (/proc/stat's busy time less the run's own CPU time, over its wall time; the run's own is
RUSAGE_CHILDREN, which holds mpiexec's ranks too: mpiexec waits for them before it exits); with two
threads on two cores any of it slows the run. --wait-idle S waits before each repeat's runs (at most
S seconds) until other processes use less than 0.2 cores over a second.

Outputs in --out (default sweeps/scaling): scaling.md (the table, also printed), runs.csv (every run),
work/ (states, decks, runs; work/work/ the --work runs and their callgrind files); with --work,
work.md and work.csv instead of scaling.md and runs.csv.
"""
import argparse
import csv
import os
import re
import resource
import shutil
import statistics
import sys
import time

from chain_melt import engine_method, fmt, prepare_state, tile_data, write_deck  # tools/ is the script's directory
from engines import RunFailed, check_exit, read_summary, run_measured

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
DATA_CHAIN = "/usr/share/lammps/examples/COUPLE/multiple/data.chain"
KG_DECK = os.path.join(ROOT, "inputs", "kremer_grest.toml")

# Stiff melt: method → (h as a function of ε, micro steps). The settings at ε = 1e-3.
METHODS = {
    "velocity-verlet": (lambda eps: 0.9 * eps, 1),
    "impulse": (lambda eps: 0.005, 50),
    "mollified-impulse": (lambda eps: 0.005, 50),
    "rattle": (lambda eps: 0.02, 1),
    "fixman": (lambda eps: 0.02, 1),
    "rattle-obabo": (lambda eps: 0.02, 1),
    "fixman-obabo": (lambda eps: 0.02, 1),
    "effective": (lambda eps: 0.02, 1),
}
SYSTEMS = ("kg-32k", "kg-256k", "stiff-32k", "stiff-256k")
# Open MPI's settings for R > 1 ranks (docstring); MPICH ignores them.
OPEN_MPI_ENV = {"OMPI_ALLOW_RUN_AS_ROOT": "1", "OMPI_ALLOW_RUN_AS_ROOT_CONFIRM": "1",
                "OMPI_MCA_rmaps_base_oversubscribe": "1", "OMPI_MCA_hwloc_base_binding_policy": "none"}
LANGEVIN = ['thermostat.style="langevin"', "thermostat.temperature=1.0", "thermostat.damp=1.0", "thermostat.seed=3"]


def split(text):
    return [w for w in text.replace(",", " ").split() if w]


def parse_layouts(layouts, threads):
    """[(ranks, threads)] of --layouts (in the order given) or --threads (1×T, fewest threads first);
    None when a count is not an integer >= 1."""
    try:
        if layouts is not None:
            pairs = [tuple(int(n) for n in w.lower().split("x")) for w in split(layouts)]
        else:
            pairs = sorted({(1, int(t)) for t in split(threads)})
    except ValueError:
        return None
    if not pairs or any(len(p) != 2 or min(p) < 1 for p in pairs):
        return None
    return list(dict.fromkeys(pairs))  # repeated layouts once, in order


def layout_name(layout):
    return f"{layout[0]}×{layout[1]}"


def system_runs(system, methods, args, work):
    """[(system, method, deck, --set overrides)] of one named system."""
    if system.startswith("kg-"):
        data = DATA_CHAIN
        if system == "kg-256k":
            data = os.path.join(work, "kg256k.data")
            if not os.path.exists(data):
                tile_data(DATA_CHAIN, data)
        bad = [m for m in methods if m != "velocity-verlet"]
        if bad:
            raise RunFailed(f"{system} runs velocity-verlet only (no stiff bonds for {', '.join(bad)})")
        t_end = 0.012 * args.steps
        sets = [f'import.lammps_data="{data}"', f"run.t_end={fmt(t_end)}", f"output.thermo_interval={fmt(t_end)}",
                f"output.screen_interval={fmt(t_end)}"]
        return [(system, "velocity-verlet", KG_DECK, sets)]
    state = os.path.join(work, f"stiff32k_eps{args.eps:g}.data")
    if not os.path.exists(state):
        prepare_state(args.stiffmd[0], args.eps, state)
    if system == "stiff-256k":
        tiled = os.path.join(work, f"stiff256k_eps{args.eps:g}.data")
        if not os.path.exists(tiled):
            tile_data(state, tiled)
        state = tiled
    runs = []
    for m in methods:
        if m not in METHODS:
            raise RunFailed(f"unknown method {m!r} for {system}: one of {', '.join(METHODS)}")
        h = METHODS[m][0](args.eps)
        micro = METHODS[m][1]
        t_end = h * args.steps
        deck = os.path.join(work, f"{system}_{m}.toml")
        write_deck(deck, state, args.eps, "tools/scaling.py", engine_method(m)[0], h, micro, t_end, t_end)
        runs.append((system, m, deck, LANGEVIN + engine_method(m)[1]))
    return runs


def deck_runs(deck, methods, args):
    """A deck of the user's, each method as integrator.method, --steps steps of --h, one thermo sample."""
    t_end = fmt(args.h * args.steps)
    runs = []
    for m in methods:
        name, sets = engine_method(m)
        runs.append((os.path.basename(deck), m, os.path.abspath(deck),
                     [f'integrator.method="{name}"', f"integrator.h={fmt(args.h)}", f"run.t_end={t_end}",
                      f"output.thermo_interval={t_end}", f"output.screen_interval={t_end}"] + sets))
    return runs


def busy_seconds():
    """CPU seconds the whole machine has been busy (all cores; /proc/stat), or None off Linux."""
    try:
        with open("/proc/stat") as f:
            ticks = [int(w) for w in f.readline().split()[1:9]]
    except (OSError, ValueError):
        return None
    return (sum(ticks) - ticks[3] - ticks[4]) / os.sysconf("SC_CLK_TCK")  # less idle and iowait


def wait_idle(limit):
    """Waits until other processes use < 0.2 cores over a second, at most `limit` seconds."""
    start = time.monotonic()
    while time.monotonic() - start < limit:
        before = busy_seconds()
        if before is None:
            return
        time.sleep(1.0)
        if busy_seconds() - before < 0.2:
            return


# A run's measures (run_once), each a column of runs.csv and, as the median over repeats, of the table.
MEASURES = ("ms_per_step", "cpu_ms_per_step", "serial_share", "ghosts_per_owned", "halo_kb_per_step", "halo_messages_per_step",
            "imbalance", "others", "neighbor_pairs")


def neighbor_pairs(s):
    """summary.json's neighbor_pairs (the pairs in the ranks' neighbour lists, summed over ranks: a pair
    counted once per rank that lists it), at the top level or under "domains"; None where the engine
    does not write it."""
    v = s.get("neighbor_pairs")
    if v is None:
        v = (s.get("domains") or {}).get("neighbor_pairs")
    return v


def pairs_ratio(pairs, one_rank):
    """pairs computed per bead relative to one process's: neighbor_pairs ÷ that of a one-rank run of the same
    system and method; None when either is missing."""
    return pairs / one_rank if pairs is not None and one_rank else None


def engine_command(args, deck, sets, run_dir, ranks, wrapper=(), binary=None):
    """`stiffmd run` of a deck with its --set overrides (binary: one of --stiffmd, the first by default),
    prefixed by wrapper (valgrind and its options) and, on several ranks, by `MPIEXEC -n RANKS` (every rank
    under the wrapper)."""
    cmd = list(wrapper) + [binary or args.stiffmd[0], "run", deck, "--no-progress", "-o", run_dir, "--set",
                           "output.checkpoint_interval=0"]
    for kv in sets + args.set:
        cmd += ["--set", kv]
    if ranks > 1:
        cmd = [args.mpiexec, "-n", str(ranks)] + cmd
    return cmd


def checked_summary(args, run_dir, ranks):
    """summary.json of a finished run, refused when it ran no steps or on another number of ranks."""
    s = read_summary(run_dir)
    if s["steps"] < 1:
        raise RunFailed(f"{run_dir}: no steps run")
    if s.get("ranks", 1) != ranks:
        raise RunFailed(f"{run_dir}: ran on {s.get('ranks', 1)} rank(s), not {ranks} (is {args.stiffmd[0]} built with "
                        f"the MPI of {args.mpiexec}?)")
    return s


def domain_measures(m, s, ranks):
    """Fills m's pair count and, on several ranks, the domains' ghosts, halo and imbalance from summary s."""
    m["neighbor_pairs"] = neighbor_pairs(s)
    if ranks > 1:
        d = s["domains"]
        m["ghosts_per_owned"] = d["ghosts_per_owned"]
        m["halo_kb_per_step"] = d["halo_bytes_per_step"] / 1e3
        m["halo_messages_per_step"] = d["halo_messages_per_step"]
        if "imbalance" in m:
            m["imbalance"] = d["rank_loop_seconds_max"] / d["rank_loop_seconds_mean"]


def run_once(args, deck, sets, layout, run_dir, binary=None):
    """{measure: value or None} of one run of binary (one of --stiffmd) on layout = (ranks, threads): ms
    per step of the step loop's wall time (the slowest rank's) and of CPU time, serial share, the pair count (None where the engine writes none),
    the domains' halo and imbalance (None on one rank), cores other processes kept busy meanwhile
    (None off Linux)."""
    ranks, threads = layout
    shutil.rmtree(run_dir, ignore_errors=True)
    os.makedirs(run_dir)
    cmd = engine_command(args, deck, sets, run_dir, ranks, binary=binary)
    # RUSAGE_CHILDREN: every process this one has waited for and their waited-for children, so the
    # ranks of mpiexec (which waits for them) count as the run's own CPU time.
    busy0, own0, t0 = busy_seconds(), resource.getrusage(resource.RUSAGE_CHILDREN), time.monotonic()
    code, _, _ = run_measured(cmd, run_dir, threads)
    busy1, own1, t1 = busy_seconds(), resource.getrusage(resource.RUSAGE_CHILDREN), time.monotonic()
    check_exit(code, cmd, run_dir, log="stderr.txt")
    s = checked_summary(args, run_dir, ranks)
    m = dict.fromkeys(MEASURES)
    m["ms_per_step"] = 1e3 * s["wall_seconds"] / s["steps"]
    if s.get("cpu_seconds") is not None:
        m["cpu_ms_per_step"] = 1e3 * s["cpu_seconds"] / s["steps"]
    m["serial_share"] = s.get("serial_share")
    domain_measures(m, s, ranks)
    if busy0 is not None:
        own = (own1.ru_utime + own1.ru_stime) - (own0.ru_utime + own0.ru_stime)
        m["others"] = max(0.0, (busy1 - busy0 - own) / (t1 - t0))
    return m


# --work: callgrind's instruction count of the step loop (docstring). run_simulation (engine/run/run.cpp)
# calls Run::step_to(final step), which takes every macro step, then Run::finish(): a dump on entering
# each splits every process's count into set-up (part 1), the step loop (part 2) and the rest (the
# final dump). A dump holds every thread of the process (callgrind's --toggle-collect would not: its
# switch is per thread, and OpenMP's worker threads never enter step_to). MPI's own instructions (a
# waiting rank polls) are taken out afterwards: the inclusive cost of every call from outside MPI's
# objects into them (MPI_OBJECT).
STEP_LOOP = "stiffmd::Run::step_to*"
AFTER_LOOP = "stiffmd::Run::finish*"
CALLGRIND = ("--tool=callgrind", "-q", f"--dump-before={STEP_LOOP}", f"--dump-before={AFTER_LOOP}")
# Open MPI's and MPICH's libraries and plugins, and the event and topology libraries they run (which call
# back into them: a call from there is inside MPI already).
MPI_OBJECT = re.compile(r"libmpi|libopen-pal|libopen-rte|libpmix|libpmi|libmpich|/openmpi/|/pmix/|mca_|libevent|"
                        r"libhwloc|libucp|libucs|libuct|libfabric|libpsm")
WORK_MEASURES = ("steps", "ir_steps", "ir_setup", "ir_mpi_steps", "ghosts_per_owned", "neighbor_pairs",
                 "halo_kb_per_step", "halo_messages_per_step", "valgrind_seconds")


def read_callgrind(path, event="Ir"):
    """{"trigger", "total", "mpi"} of one callgrind output file (one dump): the text of its "desc:
    Trigger:" line (None when absent); the event's count from its "summary:" line (or "totals:" where it
    has no summary), in the order of its "events:" line; and of that count, what ran inside MPI: the
    inclusive cost of the calls from objects outside MPI_OBJECT to functions in it (the cost line after
    "calls="; the callee's object is the "cob=" given for that call, else the caller's "ob=")."""
    trigger, events, summary, totals, npos = None, None, None, None, 1
    names, ob, cob, mpi, call = {}, "", None, 0, False

    def name_of(value):  # "(id) name" defines an id, "(id)" refers to it, else the name itself
        value = value.strip()
        if value.startswith("("):
            key, _, rest = value.partition(")")
            if rest.strip():
                names[key] = rest.strip()
            return names.get(key, "")
        return value

    with open(path, errors="replace") as f:
        for line in f:
            if call:  # the call's cost line: positions, then the inclusive counts
                call = False
                w = line.split()
                if cob is not None and MPI_OBJECT.search(cob) and not MPI_OBJECT.search(ob) and events:
                    i = npos + events.index(event) if event in events else len(w)
                    mpi += int(w[i]) if i < len(w) else 0
                cob = None
            elif line.startswith("ob="):
                ob, cob = name_of(line[3:]), None
            elif line.startswith("cob="):
                cob = name_of(line[4:])
            elif line.startswith("calls="):
                call, cob = True, ob if cob is None else cob
            elif line.startswith("desc: Trigger:"):
                trigger = line.split(":", 2)[2].strip()
            elif line.startswith("positions:"):
                npos = len(line.split(":", 1)[1].split())
            elif line.startswith("events:"):
                events = line.split(":", 1)[1].split()
            elif line.startswith("summary:"):
                summary = line.split(":", 1)[1].split()
            elif line.startswith("totals:"):
                totals = line.split(":", 1)[1].split()
    counts = summary if summary is not None else totals
    if events is None or counts is None or event not in events:
        raise RunFailed(f"{path}: not a callgrind output file with an {event} count (no events:/summary:/totals: line)")
    i = events.index(event)
    total = int(counts[i]) if i < len(counts) else 0  # trailing zero counts may be left off
    return {"trigger": trigger, "total": total, "mpi": mpi}


def step_loop_work(cg_dir, ranks):
    """(instructions in the step loop less MPI's, those of the set-up, MPI's in the step loop), each
    summed over the run's processes, from the callgrind files in cg_dir: a process's step loop is its
    dump triggered on entering Run::finish, its set-up the dump on entering Run::step_to."""
    loop, setup = [], []
    for name in sorted(os.listdir(cg_dir)):
        part = read_callgrind(os.path.join(cg_dir, name))
        if part["trigger"] and "Run::finish" in part["trigger"]:
            loop.append(part)
        elif part["trigger"] and "Run::step_to" in part["trigger"]:
            setup.append(part)
    if len(loop) != ranks or len(setup) != ranks:
        raise RunFailed(f"{cg_dir}: {len(loop)} step-loop and {len(setup)} set-up dumps for {ranks} process(es): the "
                        f"step loop is no longer {STEP_LOOP} followed by {AFTER_LOOP} (engine/run/run.cpp)?")
    mpi = sum(p["mpi"] for p in loop)
    return sum(p["total"] for p in loop) - mpi, sum(p["total"] - p["mpi"] for p in setup), mpi


def work_once(args, deck, sets, layout, run_dir):
    """{work measure: value or None} of one run under callgrind on layout = (ranks, threads): the step
    loop's and the set-up's instructions (all ranks and threads), the pair count, the domains' ghosts and
    halo (None on one rank), and the run's wall seconds under valgrind."""
    ranks, threads = layout
    shutil.rmtree(run_dir, ignore_errors=True)
    cg_dir = os.path.join(run_dir, "callgrind")
    os.makedirs(cg_dir)
    wrapper = [args.valgrind, *CALLGRIND, f"--callgrind-out-file={os.path.join(cg_dir, 'cg.%p')}"]
    cmd = engine_command(args, deck, sets, run_dir, ranks, wrapper)
    code, seconds, _ = run_measured(cmd, run_dir, threads)
    check_exit(code, cmd, run_dir, log="stderr.txt")
    s = checked_summary(args, run_dir, ranks)
    m = dict.fromkeys(WORK_MEASURES)
    m["steps"] = s["steps"]
    m["ir_steps"], m["ir_setup"], m["ir_mpi_steps"] = step_loop_work(cg_dir, ranks)
    m["valgrind_seconds"] = seconds
    domain_measures(m, s, ranks)
    return m


def work_table(rows, layouts):
    """The markdown table of --work: one run per (system, method, layout)."""
    first = layouts[0]

    def cell(v, form):
        return "—" if v is None else form(v)

    lines = [f"| system | method | ranks×threads | steps | step-loop Ir ×10⁹ (all ranks) | work ÷ {layout_name(first)} | "
             "set-up Ir ×10⁹ (all ranks) | ghosts/owned | pairs/1 rank | halo kB/step | halo msgs/step | valgrind s |",
             "|---|---|--:|--:|--:|--:|--:|--:|--:|--:|--:|--:|"]
    for (system, method), by_layout in rows.items():
        base = by_layout[first][0]["ir_steps"] / by_layout[first][0]["steps"]
        one_rank = one_rank_pairs(by_layout, layouts)
        for layout in layouts:
            m = by_layout[layout][0]
            work = m["ir_steps"] / m["steps"] / base if base > 0 else None
            lines.append(f"| {system} | {method} | {layout_name(layout)} | {m['steps']} | {m['ir_steps'] / 1e9:.3f} | "
                         f"{cell(work, '{:.3f}'.format)} | {m['ir_setup'] / 1e9:.2f} | "
                         f"{cell(m['ghosts_per_owned'], '{:.3f}'.format)} | "
                         f"{form_pairs(pairs_ratio(m['neighbor_pairs'], one_rank))} | "
                         f"{cell(m['halo_kb_per_step'], '{:.1f}'.format)} | "
                         f"{cell(m['halo_messages_per_step'], '{:g}'.format)} | {m['valgrind_seconds']:.0f} |")
    return "\n".join(lines)


def table(rows, layouts):
    """The markdown table of the medians."""
    def median(runs, key, form):
        values = [m[key] for m in runs if m[key] is not None]
        return form(statistics.median(values)) if values else "—"

    first = layouts[0]
    lines = ["| system | method | ranks×threads | ms/step | speed-up | efficiency | serial share | ghosts/owned | "
             "pairs/1 rank | halo kB/step | halo msgs/step | imbalance | others |",
             "|---|---|--:|--:|--:|--:|--:|--:|--:|--:|--:|--:|--:|"]
    for (system, method), by_layout in rows.items():
        base = [m["ms_per_step"] for m in by_layout[first]]
        one_rank = one_rank_pairs(by_layout, layouts)
        for layout in layouts:
            runs = by_layout[layout]
            speedup = statistics.median(b / m["ms_per_step"] for b, m in zip(base, runs))
            efficiency = speedup * (first[0] * first[1]) / (layout[0] * layout[1])
            lines.append(f"| {system} | {method} | {layout_name(layout)} | {median(runs, 'ms_per_step', '{:.2f}'.format)} | "
                         f"{speedup:.2f} | {100 * efficiency:.0f} % | "
                         f"{median(runs, 'serial_share', lambda v: f'{100 * v:.2f} %')} | "
                         f"{median(runs, 'ghosts_per_owned', '{:.3f}'.format)} | "
                         f"{form_pairs(pairs_ratio(median_of(runs, 'neighbor_pairs'), one_rank))} | "
                         f"{median(runs, 'halo_kb_per_step', '{:.1f}'.format)} | "
                         f"{median(runs, 'halo_messages_per_step', '{:g}'.format)} | "
                         f"{median(runs, 'imbalance', '{:.3f}'.format)} | {median(runs, 'others', '{:.2f}'.format)} |")
    return "\n".join(lines)


def compare_table(rows, layouts, binaries):
    """The markdown table of several binaries: per (system, method, layout) each binary's median wall and
    CPU ms/step and the first binary's ÷ each other's (median of the per-repeat ratios)."""
    lines = ["| system | method | ranks×threads | binary | ms/step (wall) | ms/step (CPU) | B1 ÷ this (wall) | "
             "B1 ÷ this (CPU) |", "|---|---|--:|---|--:|--:|--:|--:|"]

    def ratio(first, runs, key):
        r = [a[key] / b[key] for a, b in zip(first, runs) if a.get(key) and b.get(key)]
        return f"{statistics.median(r):.2f}" if r else "—"

    for (system, method), by_layout in rows.items():
        for layout in layouts:
            first = by_layout[layout][0]
            for k, binary in enumerate(binaries):
                runs = by_layout[layout][k]
                wall, cpu = median_of(runs, "ms_per_step"), median_of(runs, "cpu_ms_per_step")
                lines.append(f"| {system} | {method} | {layout_name(layout)} | B{k + 1} {binary} | {wall:.2f} | "
                             f"{'—' if cpu is None else f'{cpu:.2f}'} | {ratio(first, runs, 'ms_per_step')} | "
                             f"{ratio(first, runs, 'cpu_ms_per_step')} |")
    return "\n".join(lines)


def median_of(runs, key):
    values = [m[key] for m in runs if m.get(key) is not None]
    return statistics.median(values) if values else None


def one_rank_pairs(by_layout, layouts):
    """The reference of "pairs/1 rank": the median neighbor_pairs of the first one-rank layout (1×T: the
    threads share one list), or None when no layout runs on one rank or the engine writes no pair count."""
    for layout in layouts:
        if layout[0] == 1:
            return median_of(by_layout[layout], "neighbor_pairs")
    return None


def form_pairs(ratio):
    return "n/a" if ratio is None else f"{ratio:.3f}"


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--systems", help=f"comma-separated, of {', '.join(SYSTEMS)} (default kg-256k,stiff-256k; "
                    "kg-32k,stiff-32k with --work)")
    ap.add_argument("--deck", help="a deck to run instead of the named systems")
    ap.add_argument("--methods", default="velocity-verlet,impulse,rattle,fixman",
                    help="for the stiff systems and --deck (kg-* run velocity-verlet)")
    ap.add_argument("--threads", help="thread counts on one rank: the layouts 1xT (default 1,2)")
    ap.add_argument("--layouts", help="RANKSxTHREADS,... e.g. 1x2,2x1 (not with --threads)")
    ap.add_argument("--mpiexec", default="mpiexec", help="runs the layouts of more than one rank")
    ap.add_argument("--eps", type=float, default=1e-3, help="the stiff systems' ε")
    ap.add_argument("--h", type=float, default=0.005, help="--deck's step")
    ap.add_argument("--steps", type=int, help="steps per run (default 50; 10 with --work)")
    ap.add_argument("--repeats", type=int, default=5, help="interleaved repeats (--work: one run each)")
    ap.add_argument("--work", action="store_true",
                    help="instructions of the step loop under valgrind's callgrind (all ranks and threads), "
                         "not wall time")
    ap.add_argument("--valgrind", default="valgrind", help="--work's valgrind")
    ap.add_argument("--set", action="append", default=[], help="KEY=VALUE for every run (repeatable)")
    ap.add_argument("--wait-idle", type=float, default=0.0, metavar="S",
                    help="before each repeat's runs, wait up to S seconds for other processes to go quiet")
    ap.add_argument("--stiffmd", nargs="+", default=[os.path.join(ROOT, "build", "stiffmd")],
                    help="the binary, or several to compare (each run with each, interleaved)")
    ap.add_argument("--out", default=os.path.join(ROOT, "sweeps", "scaling"))
    args = ap.parse_args()
    if args.systems is None:
        args.systems = "kg-32k,stiff-32k" if args.work else "kg-256k,stiff-256k"
    if args.steps is None:
        args.steps = 10 if args.work else 50
    if args.work:
        args.repeats = 1
    if args.threads is not None and args.layouts is not None:
        print("scaling: --threads and --layouts both given: --threads T means --layouts 1xT; give one", file=sys.stderr)
        return 2
    layouts = parse_layouts(args.layouts, "1,2" if args.threads is None else args.threads)
    if not layouts or args.steps < 1 or args.repeats < 1 or not args.eps > 0 or not args.h > 0:
        print("scaling: --threads must be integers >= 1 (--layouts RANKSxTHREADS,... of integers >= 1), --steps and "
              "--repeats >= 1, --eps and --h > 0", file=sys.stderr)
        return 2
    if any(r > 1 for r, _ in layouts):
        if shutil.which(args.mpiexec) is None:
            print(f"scaling: no mpiexec {args.mpiexec!r} (--mpiexec) for the layouts of several ranks", file=sys.stderr)
            return 2
        for key, value in OPEN_MPI_ENV.items():
            os.environ.setdefault(key, value)
    if args.work:
        if shutil.which(args.valgrind) is None:
            print(f"scaling: no valgrind {args.valgrind!r} (--valgrind) for --work", file=sys.stderr)
            return 2
        # A spinning wait would count as work: idle OpenMP threads sleep (whatever the caller set), and
        # Open MPI's idle ranks yield their core (their polling inside MPI is not collected anyway).
        os.environ["OMP_WAIT_POLICY"] = "passive"
        os.environ.setdefault("OMPI_MCA_mpi_yield_when_idle", "1")
    if args.work and len(args.stiffmd) > 1:
        print("scaling: --work takes one --stiffmd", file=sys.stderr)
        return 2
    args.stiffmd, args.out = [os.path.abspath(b) for b in args.stiffmd], os.path.abspath(args.out)
    binaries = list(range(len(args.stiffmd)))
    work = os.path.join(args.out, "work")
    os.makedirs(work, exist_ok=True)
    methods = split(args.methods)
    try:
        if args.deck:
            if not os.path.isfile(args.deck):
                raise RunFailed(f"no deck {args.deck}")
            runs = deck_runs(args.deck, methods, args)
        else:
            runs = []
            for system in split(args.systems):
                if system not in SYSTEMS:
                    raise RunFailed(f"unknown system {system!r}: one of {', '.join(SYSTEMS)}")
                sys_methods = ["velocity-verlet"] if system.startswith("kg-") else methods
                runs += system_runs(system, sys_methods, args, work)
        rows, records = {}, []
        by_binary = {}  # (system, method) -> layout -> [runs of binary k] for k in binaries
        for r in range(args.repeats):
            order = layouts if r % 2 == 0 else layouts[::-1]
            for system, method, deck, sets in runs:
                by_layout = rows.setdefault((system, method), {})
                if args.wait_idle > 0:
                    wait_idle(args.wait_idle)
                for layout in order:
                    kind = "work" if args.work else "runs"
                    for k in (binaries if r % 2 == 0 else binaries[::-1]):
                        suffix = f"_b{k + 1}" if len(binaries) > 1 else ""
                        run_dir = os.path.join(work, kind, f"{system}_{method}_r{layout[0]}t{layout[1]}{suffix}")
                        if args.work:
                            m = work_once(args, deck, sets, layout, run_dir)
                        else:
                            m = run_once(args, deck, sets, layout, run_dir, args.stiffmd[k])
                        if k == 0:
                            by_layout.setdefault(layout, []).append(m)
                        by_binary.setdefault((system, method), {}).setdefault(
                            layout, [[] for _ in binaries])[k].append(m)
                        records.append({"system": system, "method": method, "ranks": layout[0], "threads": layout[1],
                                        "repeat": r, "binary": args.stiffmd[k],
                                        **{key: "" if v is None else v for key, v in m.items()}})
    except RunFailed as e:
        print(f"scaling: {e}", file=sys.stderr)
        return 2
    if args.work:
        head = (f"Instructions (callgrind's Ir) of the step loop, {args.steps} steps, all ranks and threads, MPI's own "
                f"excluded; work = Ir per step ÷ that of {layout_name(layouts[0])} (ranks×threads)")
        text, names = head + "\n\n" + work_table(rows, layouts) + "\n", ("work.md", "work.csv")
    else:
        head = (f"Wall ms per step of the step loop, {args.steps} steps, median of {args.repeats} interleaved repeats; "
                f"speed-up over {layout_name(layouts[0])} (ranks×threads; median of the ratios within a repeat)")
        text, names = head + "\n\n" + table(rows, layouts) + "\n", ("scaling.md", "runs.csv")
        if len(binaries) > 1:
            text = (f"Builds side by side (B1 = {args.stiffmd[0]}; the table above is B1's), median of {args.repeats} "
                    f"interleaved repeats; B1 ÷ this: the median of the ratios within a repeat\n\n"
                    + compare_table(by_binary, layouts, args.stiffmd) + "\n\n" + text)
    with open(os.path.join(args.out, names[0]), "w") as f:
        f.write(text)
    with open(os.path.join(args.out, names[1]), "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(records[0]))
        w.writeheader()
        w.writerows(records)
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
