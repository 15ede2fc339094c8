#!/usr/bin/env python3
"""A staged protocol restarted from a checkpoint written in any stage ends in the uninterrupted
protocol's state, bit for bit (docs/decks.md "[[stage]]", engine/run/stages.hpp).

    test_stages.py STIFFMD N [MPIEXEC NUMPROC_FLAG] [--deck DECK]

inputs/staged_chains.toml (relax: FIRE only; equilibrate: RATTLE under Langevin; produce: Fixman
under Langevin, H5MD), its equilibrate stage shortened to 60 steps, run on N processes (N > 1 under
MPIEXEC NUMPROC_FLAG N). Against one process's uninterrupted run, every stage's final positions and
velocities (its checkpoint's) bit for bit, of:
  - the uninterrupted protocol on N processes;
  - SIGTERM inside stage 2 (STIFFMD_SIGNAL_AT_STEP, engine/run/signals.hpp), then --restart from
    OUT/2_equilibrate/checkpoint.bin on N processes (and, with N > 1, on one);
  - SIGTERM inside stage 3, then --restart from OUT/3_produce/checkpoint.bin;
  - stage 1's final checkpoint (stage 2 and 3 removed), which starts stage 2 from its state;
  - with N = 1, SIGKILL inside stage 2 after a periodic checkpoint (checkpoint_interval), the
    restart continuing from that checkpoint.
--deck: another protocol of the same three stage names (tests/decks/staged_npt.toml: a barostat in
stage 2, whose box the checkpoints carry). Each restarted protocol's thermo files are the uninterrupted N-process run's byte for byte
(on N > 1, ecouple and econserve to round-off: HEAT_COLUMNS), and a
restart says where it continued.

Open MPI as root and with more processes than cores wants permission: given by its environment
variables (which MPICH's launcher ignores)."""
import os
import shutil
import struct
import subprocess
import sys
import tempfile

ROOT = os.path.normpath(os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))
DECK = os.path.join(ROOT, "inputs", "staged_chains.toml")
STAGES = ["1_relax", "2_equilibrate", "3_produce"]
ONE_RANK = True
# Stage 2 of 60 steps (h = 0.02), stage 3 of 100: a signal at step 30 lands in stage 2, at 80 in
# stage 3 (the hook fires in the first stage that reaches the step). A checkpoint every 0.4 = 20
# steps in stage 2, for the SIGKILL case.
SETS = ["--set", "stage.1.steps=60", "--set", "stage.1.output.checkpoint_interval=0.4"]


def environment(signal_at=None):
    env = dict(os.environ, OMP_NUM_THREADS="1", OMPI_ALLOW_RUN_AS_ROOT="1", OMPI_ALLOW_RUN_AS_ROOT_CONFIRM="1",
               OMPI_MCA_rmaps_base_oversubscribe="1")
    env.pop("STIFFMD_SIGNAL_AT_STEP", None)
    if signal_at:
        env["STIFFMD_SIGNAL_AT_STEP"] = signal_at
    return env


def run(launch, stiffmd, out, extra=(), signal_at=None, expect=0):
    cmd = launch + [stiffmd, "run", DECK, "-o", out, "-q", "--no-progress"] + SETS + list(extra)
    print("$ " + ("STIFFMD_SIGNAL_AT_STEP=" + signal_at + " " if signal_at else "") + " ".join(cmd), flush=True)
    r = subprocess.run(cmd, capture_output=True, text=True, timeout=300, env=environment(signal_at))
    code = 128 - r.returncode if r.returncode < 0 else r.returncode  # killed: -signal
    if code != expect:
        sys.stderr.write(r.stdout[-3000:] + r.stderr[-3000:])
        raise SystemExit(f"FAIL: exit {code}, expected {expect}")
    return r


def checkpoint_state(path):
    """(stage number, stage name, step, t, x bytes, v bytes) of a version-6, 7 or 8 checkpoint
    (engine/run/checkpoint.hpp: one layout, 7 and 8 other fingerprints; the 40-byte header, then the particle count, step, t, h, method,
    stage number and name, x, v, ...)."""
    with open(path, "rb") as f:
        b = f.read()
    if struct.unpack_from("<I", b, 12)[0] not in (6, 7, 8):
        raise SystemExit(f"FAIL: {path} is not of format version 6, 7 or 8")
    pos = 40
    _, step = struct.unpack_from("<qq", b, pos)
    t, _ = struct.unpack_from("<dd", b, pos + 16)
    pos += 32
    length = struct.unpack_from("<Q", b, pos)[0]
    pos += 8 + length
    number = struct.unpack_from("<q", b, pos)[0]
    length = struct.unpack_from("<Q", b, pos + 8)[0]
    name = b[pos + 16:pos + 16 + length].decode()
    pos += 16 + length
    blocks = []
    for _ in range(2):
        count = struct.unpack_from("<Q", b, pos)[0]
        blocks.append(b[pos + 8:pos + 8 + 8 * count])
        pos += 8 + 8 * count
    return number, name, step, t, blocks[0], blocks[1]


def same_states(ref, out, what):
    for k, stage in enumerate(STAGES):
        a = checkpoint_state(os.path.join(ref, stage, "checkpoint.bin"))
        b = checkpoint_state(os.path.join(out, stage, "checkpoint.bin"))
        if a[:2] != (k + 1, stage.split("_", 1)[1]) or a[:4] != b[:4]:
            raise SystemExit(f"FAIL: {what}: {stage}'s checkpoint is of {b[:4]}, expected {a[:4]}")
        if a[4] != b[4] or a[5] != b[5]:
            raise SystemExit(f"FAIL: {what}: {stage}'s final positions or velocities differ from the reference's")
    print(f"{what}: every stage's final state bit for bit")


# The thermostat's heat is each rank's running sum, and a restart on several ranks hands the sum so
# far to rank 0 (DomainIntegrator::start): the columns made of it, ecouple and econserve, are then the
# same sum added in another order, equal to round-off (a relative 1e-12 of their scale) rather than
# byte for byte. Every other column, and everything on one rank, byte for byte.
HEAT_COLUMNS = ("ecouple", "econserve")


def same_thermo(ref, out, what):
    for stage in STAGES:
        with open(os.path.join(ref, stage, "thermo.csv")) as fa, open(os.path.join(out, stage, "thermo.csv")) as fb:
            a, b = fa.read(), fb.read()
        if a == b:
            continue
        rows_a, rows_b = [r.split(",") for r in a.splitlines()], [r.split(",") for r in b.splitlines()]
        header = rows_a[0]
        heat = [header.index(c) for c in HEAT_COLUMNS if c in header]
        ok = len(rows_a) == len(rows_b) and rows_a[0] == rows_b[0] and ONE_RANK is False
        for ra, rb in zip(rows_a[1:], rows_b[1:]):
            if not ok:
                break
            for k, (x, y) in enumerate(zip(ra, rb)):
                if x == y:
                    continue
                scale = max(abs(float(r[k])) for r in rows_a[1:]) or 1.0
                ok = k in heat and abs(float(x) - float(y)) <= 1e-12 * scale
                if not ok:
                    break
        if not ok:
            raise SystemExit(f"FAIL: {what}: {stage}/thermo.csv differs from the uninterrupted run's")


def main(argv):
    global DECK
    if "--deck" in argv:
        k = argv.index("--deck")
        DECK = os.path.abspath(argv[k + 1])
        argv = argv[:k] + argv[k + 2:]
    if len(argv) not in (3, 5):
        raise SystemExit(__doc__)
    global ONE_RANK
    stiffmd, n = argv[1], int(argv[2])
    ONE_RANK = n == 1
    launch = [argv[3], argv[4], str(n)] if n > 1 else []
    one = []
    tmp = tempfile.mkdtemp(prefix="stiffmd_stages_")
    try:
        ref = os.path.join(tmp, "ref")
        run(one, stiffmd, ref)
        whole = ref
        if n > 1:
            whole = os.path.join(tmp, f"whole_{n}")
            run(launch, stiffmd, whole)
            same_states(ref, whole, f"uninterrupted on {n} ranks")

        cases = [("stage 2", "30:15", "2_equilibrate", "at step 30 "), ("stage 3", "80:15", "3_produce", "at step 80 ")]
        if n == 1:  # killed at step 50: the periodic checkpoint of step 40 continues
            cases.append(("stage 2, killed", "50:9", "2_equilibrate", "at step 40 "))
        for what, signal_at, stage, said in cases:
            out = os.path.join(tmp, f"{stage}_{signal_at.replace(':', '_')}")
            run(launch, stiffmd, out, signal_at=signal_at, expect=128 + int(signal_at.split(":")[1]))
            if os.path.exists(os.path.join(out, "protocol.json")):
                raise SystemExit(f"FAIL: {what}: an interrupted protocol wrote protocol.json")
            checkpoint = os.path.join(out, stage, "checkpoint.bin")
            if n > 1 and stage == "2_equilibrate":  # the same checkpoint continued on one process too
                copy = out + "_on_1"
                shutil.copytree(out, copy)
                run(one, stiffmd, copy, ["--restart", os.path.join(copy, stage, "checkpoint.bin")])
                same_states(ref, copy, f"interrupted in {what} on {n} ranks, restarted on 1")
            r = run(launch, stiffmd, out, ["--restart", checkpoint])
            if said not in r.stderr:
                raise SystemExit(f"FAIL: {what}: the restart did not say it continued {said}:\n{r.stderr}")
            same_states(ref, out, f"interrupted in {what} on {n} ranks, restarted")
            same_thermo(whole, out, f"interrupted in {what}")

        # Stage 1's final checkpoint: stage 2 starts from its state.
        out = os.path.join(tmp, "from_stage_1")
        shutil.copytree(whole, out)
        for stage in STAGES[1:]:
            shutil.rmtree(os.path.join(out, stage))
        r = run(launch, stiffmd, out, ["--restart", os.path.join(out, STAGES[0], "checkpoint.bin")])
        if "stage 2 (equilibrate) starts from its state" not in r.stderr:
            raise SystemExit(f"FAIL: the restart from stage 1's end did not say so:\n{r.stderr}")
        same_states(ref, out, f"restarted from stage 1's end on {n} ranks")
        same_thermo(whole, out, "restarted from stage 1's end")
    except BaseException:
        print(f"(outputs kept in {tmp})")
        raise
    shutil.rmtree(tmp)
    print("OK")


if __name__ == "__main__":
    main(sys.argv)
