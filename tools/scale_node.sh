#!/bin/bash
# ranks × threads on a many-core machine without our packages (docs/parallel.md, "Measured"): the
# 256 000-bead melts of tools/scaling.py (stiff data.chain ×8 at ε = 1e-3 under fixman, rattle,
# velocity Verlet and the impulse method; in.chain ×8 under velocity Verlet), each on the layouts L,
# LAMMPS's in.chain ×8 on the ranks LMP_RANKS, and the same 50 steps on 1 and 16 ranks compared bit
# for bit. Prepare here, in the repository root (devrun/ ignored; the tree that travels ≤ 64 MiB):
#   echo /devrun/ >> .git/info/exclude; mkdir -p devrun
#   bash ../shared/tools/bundle.sh build/stiffmd devrun/b /usr/bin/lmp   # both builds with their libraries
#   strip --strip-unneeded devrun/b/lib/*.so* devrun/b/stiffmd; (cd devrun && tar cJf b.txz b && rm -r b)
#   /usr/bin/python3 tools/scaling.py --systems stiff-32k --methods fixman --layouts 1x1 --repeats 1 --steps 2
#   gzip -c sweeps/scaling/work/stiff32k_eps0.001.data > devrun/stiff32k.data.gz
#   gzip -c /usr/share/lammps/examples/COUPLE/multiple/data.chain > devrun/data.chain.gz
#   cp tools/scale_node.sh devrun/scale.sh; cp /usr/share/lammps/examples/COUPLE/multiple/in.chain devrun/
# and run there `bash devrun/scale.sh` (carry devrun). Its Open MPI (4.1) runs our build with the
# bundle's libraries but MPI's and glibc's own; python3 there needs numpy and h5py. BUDGET (seconds)
# skips what would start after it, so that one call ends inside the device's limit;
# SYSTEMS picks among "lammps kg fixman rattle vv impulse bits"; DETAIL=1 adds each phase's mean
# and max over the ranks and the time inside MPI; STEPS scales the runs' lengths (default 60).

set -u
D=$(cd "$(dirname "$0")" && pwd); W=/tmp/w; mkdir -p $W; cd $W
T0=$(date +%s); BUDGET=${BUDGET:-100000}
late() { [ $(( $(date +%s) - T0 )) -gt $BUDGET ] && { echo "skipped (budget): $*"; return 0; }; return 1; }
[ -d $D/b ] || tar xJf $D/b.txz -C $D
echo "host: $(nproc) cores; $(mpirun --version 2>&1 | head -1)"
mkdir -p $D/lib2; for f in $D/b/lib/*; do case $(basename $f) in libmpi.so*|libopen-*|libc.so*|libm.so*|ld-linux*|libresolv*) ;; *) ln -sf $f $D/lib2/;; esac; done
export LD_LIBRARY_PATH=$D/lib2:${LD_LIBRARY_PATH:-}
EXE=$D/b/stiffmd
gunzip -c $D/stiff32k.data.gz > s32k.data; gunzip -c $D/data.chain.gz > data.chain
python3 -c "
import sys; sys.path.insert(0, '$D/../tools')
from chain_melt import tile_data
tile_data('s32k.data', 's256k.data'); tile_data('data.chain', 'kg256k.data')"
ls -la *.data | awk '{print $5, $9}'
python3 -c "
import sys; sys.path.insert(0, '$D/../tools')
from chain_melt import write_deck
write_deck('stiff.toml', 's256k.data', 1e-3, 'tools/scale_node.sh', 'fixman', 0.02, 1, 1.2, 1.2)"
# Langevin kT = 1, damp = 1 (tools/scaling.py's stiff melts); no checkpoints.
THERMOSTAT=(--set 'thermostat={ style = "langevin", temperature = 1.0, damp = 1.0, seed = 3 }' --set output.checkpoint_interval=0)
run() {  # name ranks threads deck sets...
  late "$1 $2x$3" && return
  local name=$1 r=$2 t=$3 deck=$4; shift 4
  local bind="--bind-to none"; [ $t = 1 ] && bind="--bind-to core"
  local o=$W/out_${name}_${r}x${t}; rm -rf $o
  if [ -n "${STEPS:-}" ]; then  # run.steps instead of the run's t_end
    local a=() prev=""; for x in "$@"; do case "$x" in run.t_end=*) unset 'a[${#a[@]}-1]';; *) a+=("$x");; esac; done
    set -- "${a[@]}" --set run.steps=$STEPS
  fi
  local s0=$(date +%s.%N)
  OMP_NUM_THREADS=$t OMP_PROC_BIND=false timeout 300 mpirun --allow-run-as-root --oversubscribe $bind -np $r -x LD_LIBRARY_PATH -x OMP_NUM_THREADS $EXE run $deck -o $o -q --no-progress "$@" > $o.log 2>&1
  local rc=$?; local s1=$(date +%s.%N)
  local j=$o/summary.json
  if [ $rc != 0 ] || [ ! -f $j ]; then echo "$name ${r}x$t FAILED rc=$rc: $(tail -2 $o.log | tr '\n' ' ')"; return; fi
  python3 - "$name" $r $t $j "$s0" "$s1" <<P
import json, os, sys
name, r, t, j, s0, s1 = sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), sys.argv[4], float(sys.argv[5]), float(sys.argv[6])
s = json.load(open(j)); d = s.get('domains', {})
ms = 1000 * s['loop_seconds'] / s['steps']
tm = s.get('timing', {}); tot = sum(tm.values()) or 1
top = ' '.join(f"{k}={100*v/tot:.0f}%" for k, v in tm.items() if v/tot > 0.04)
print(f"{name:18s} {r:2d}x{t:<2d} {ms:9.2f} ms/step  ghosts/owned={d.get('ghosts_per_owned', 0):.3f} haloMB={d.get('halo_bytes_per_step', 0)/1e6:.2f} msgs={d.get('halo_messages_per_step', 0):.0f} redis={d.get('redistributions', 0)} migr={d.get('migrated_molecules', 0)} imb={(d.get('rank_loop_seconds_max', 1) / d.get('rank_loop_seconds_mean', 1)):.3f} grid={d.get('grid')} wall={s1-s0:.1f}s | {top}", flush=True)
if os.environ.get("DETAIL") and d:
    per = lambda v: 1000 * v / s['steps']
    mean, mx = d.get('timing_mean', {}), d.get('timing_max', {})
    print("    ms/step by phase, mean/max over ranks: " + ' '.join(f"{k}={per(mean[k]):.2f}/{per(mx[k]):.2f}" for k in mean if mx.get(k, 0) > 0.01 * s['loop_seconds']), flush=True)
    print(f"    in MPI exchanges {per(d.get('exchange_seconds_mean', 0)):.2f}/{per(d.get('exchange_seconds_max', 0)):.2f}, reductions {per(d.get('reduction_seconds_mean', 0)):.2f}/{per(d.get('reduction_seconds_max', 0)):.2f} ms/step (mean/max); rebuilds {d.get('neighbor_rebuilds_max')}; setup {d.get('setup_seconds_max', 0):.1f} s; peak RSS max {d.get('peak_rss_mib_max', 0):.0f} MiB", flush=True)
P
}
L=${L:-"1x1 1x2 1x16 2x1 4x1 8x1 16x1 4x4 2x8"}; SYSTEMS=${SYSTEMS:-"lammps kg fixman impulse bits"}
LMP_RANKS=${LMP_RANKS:-"1 16"}
has() { case " $SYSTEMS " in *" $1 "*) return 0;; esac; return 1; }
IMPULSE=(--set integrator.method=impulse --set integrator.h=0.005 --set integrator.micro_steps=50 --set thermostat.splitting=baoab --set run.t_end=0.3 --set output.thermo_interval=0.3)
# LAMMPS's own in.chain on the same 256 000 beads (the tiled file): 100 steps, its "Loop time".
if has lammps && [ -x $D/b/lmp ]; then
  sed 's/^read_data.*/read_data	kg256k.data/; s/^run.*/run		100/' $D/in.chain > in.chain256k
  for r in $LMP_RANKS; do
    late "lammps $r" && continue
    OMP_NUM_THREADS=1 timeout 300 mpirun --allow-run-as-root --oversubscribe --bind-to core -np $r -x LD_LIBRARY_PATH -x OMP_NUM_THREADS $D/b/lmp -in in.chain256k -var t 1.0 -log lmp_$r.log -screen none > lmp_$r.out 2>&1
    loop=$(awk '/^Loop time/ {print $4}' lmp_$r.log); echo "lammps in.chain x8  ${r}x1   $(python3 -c "print('%9.2f' % (1000 * $loop / 100))" 2>/dev/null || echo FAILED) ms/step  (Loop time $loop s / 100 steps)"
  done
fi
for lay in $L; do r=${lay%x*}; t=${lay#*x}
  has kg && run kg-vv $r $t $D/../inputs/kremer_grest.toml --set import.lammps_data=\"$W/kg256k.data\" --set run.t_end=0.72 --set output.thermo_interval=0.72 --set output.screen_interval=0.72 --set output.checkpoint_interval=0
  has fixman && run fixman $r $t stiff.toml "${THERMOSTAT[@]}"
  has rattle && run rattle $r $t stiff.toml "${THERMOSTAT[@]}" --set integrator.method=rattle
  has vv && run stiff-vv $r $t stiff.toml "${THERMOSTAT[@]}" --set integrator.method=velocity-verlet --set integrator.h=0.0009 --set run.t_end=0.054 --set output.thermo_interval=0.054
  has impulse && run impulse $r $t stiff.toml "${THERMOSTAT[@]}" "${IMPULSE[@]}"
done
# The same trajectory on 1 and 16 ranks (one thread each): positions and velocities bit for bit.
if has bits && ! late bits; then
  for r in 1 16; do o=$W/bits_$r; rm -rf $o; OMP_NUM_THREADS=1 mpirun --allow-run-as-root --oversubscribe --bind-to none -np $r -x LD_LIBRARY_PATH -x OMP_NUM_THREADS $EXE run stiff.toml -o $o -q --no-progress "${THERMOSTAT[@]}" --set run.t_end=1.0 --set output.h5md=\"t.h5md\" --set output.h5md_interval=1.0 --set output.h5md_velocity=true > $o.log 2>&1 || tail -3 $o.log; done
  python3 -c "
import h5py, numpy as np
a, b = h5py.File('bits_1/t.h5md'), h5py.File('bits_16/t.h5md')
for k in ('position', 'velocity'):
    x, y = a['particles/all/%s/value' % k][-1], b['particles/all/%s/value' % k][-1]
    print('256k fixman 50 steps, 1 vs 16 ranks:', k, 'bit for bit' if np.array_equal(x, y) else 'max diff %g' % np.abs(x - y).max())
"
fi
echo "total $(( $(date +%s) - T0 )) s"
