#!/bin/bash
# How much of a many-core machine's cores one process's work gets when every core is busy
# (docs/parallel.md, "Sixteen cores"): K independent copies of one single-core run, each pinned to
# its own core, against one copy alone — for stiffmd (in.chain, 32 000 beads, inputs/kremer_grest.toml)
# and for LAMMPS (its in.chain). The ratio of the copies' mean ms/step to the lone copy's is what
# frequency, shared caches, memory bandwidth and shared physical cores cost a core at that load: it
# bounds any parallel speed-up on that machine from above by K / ratio. Prepared as
# tools/scale_node.sh's header says (devrun/ with b.txz, data.chain.gz, in.chain), run there as
# `bash devrun/throughput.sh` (carry devrun); COPIES (default "1 8 16") and STEPS (300).
set -u
D=$(cd "$(dirname "$0")" && pwd); W=/tmp/t; mkdir -p $W; cd $W
[ -d $D/b ] || tar xJf $D/b.txz -C $D
mkdir -p $D/lib2; for f in $D/b/lib/*; do case $(basename $f) in libmpi.so*|libopen-*|libc.so*|libm.so*|ld-linux*|libresolv*) ;; *) ln -sf $f $D/lib2/;; esac; done
export LD_LIBRARY_PATH=$D/lib2:${LD_LIBRARY_PATH:-} OMP_NUM_THREADS=1
gunzip -c $D/data.chain.gz > data.chain
STEPS=${STEPS:-300}
sed "s/^run.*/run\t\t$STEPS/" $D/in.chain > in.chain32k
stiff() { taskset -c $1 $D/b/stiffmd run $D/../inputs/kremer_grest.toml -o $W/s$1 -q --no-progress \
  --set "import.lammps_data=\"$W/data.chain\"" --set run.steps=$STEPS --set output.checkpoint_interval=0 > $W/s$1.log 2>&1; }
lammps() { taskset -c $1 $D/b/lmp -in in.chain32k -var t 1.0 -log $W/l$1.log -screen none > $W/l$1.out 2>&1; }
for code in stiff lammps; do
  for k in ${COPIES:-1 8 16}; do
    rm -rf $W/s* $W/l*.log
    for ((c = 0; c < k; ++c)); do $code $c & done; wait
    python3 - $code $k $STEPS $W <<'P'
import json, re, statistics, sys
code, k, steps, w = sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), sys.argv[4]
ms = []
for c in range(k):
    if code == "stiff":
        s = json.load(open(f"{w}/s{c}/summary.json")); ms.append(1000 * s["loop_seconds"] / s["steps"])
    else:
        t = re.search(r"^Loop time of (\S+)", open(f"{w}/l{c}.log").read(), re.M); ms.append(1000 * float(t.group(1)) / steps)
print(f"{code:7s} {k:2d} copies on cores 0-{k - 1}: ms/step mean {statistics.mean(ms):.3f} (min {min(ms):.3f}, max {max(ms):.3f})", flush=True)
P
  done
done
