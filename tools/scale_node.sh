#!/bin/bash
# ranks × threads on a many-core machine without our packages (docs/parallel.md, "Measured"): the
# 256 000-bead melts of tools/scaling.py (stiff data.chain ×8 at ε = 1e-3 under fixman and the
# impulse method; in.chain ×8 under velocity Verlet), each on the layouts L, and the same 50 steps
# on 1 and 16 ranks compared bit for bit. Prepare here, in the repository root (devrun/ ignored):
#   echo /devrun/ >> .git/info/exclude; mkdir -p devrun
#   bash ../shared/tools/bundle.sh build/stiffmd devrun/b        # the MPI build with its libraries
#   /usr/bin/python3 tools/scaling.py --systems stiff-32k --methods fixman --layouts 1x1 --repeats 1 --steps 2
#   gzip -c sweeps/scaling/work/stiff32k_eps0.001.data > devrun/stiff32k.data.gz
#   gzip -c /usr/share/lammps/examples/COUPLE/multiple/data.chain > devrun/data.chain.gz
#   cp tools/scale_node.sh devrun/scale.sh
# and run there `bash devrun/scale.sh` (carry devrun). Its Open MPI (4.1) runs our build with the
# bundle's libraries but MPI's and glibc's own; python3 there needs numpy and h5py.

set -u
D=$(cd "$(dirname "$0")" && pwd); W=/tmp/w; mkdir -p $W; cd $W
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
  local name=$1 r=$2 t=$3 deck=$4; shift 4
  local bind="--bind-to none"; [ $t = 1 ] && bind="--bind-to core"
  local o=$W/out_${name}_${r}x${t}; rm -rf $o
  local s0=$(date +%s.%N)
  OMP_NUM_THREADS=$t OMP_PROC_BIND=false timeout 300 mpirun --allow-run-as-root --oversubscribe $bind -np $r -x LD_LIBRARY_PATH -x OMP_NUM_THREADS $EXE run $deck -o $o -q --no-progress "$@" > $o.log 2>&1
  local rc=$?; local s1=$(date +%s.%N)
  local j=$o/summary.json
  if [ $rc != 0 ] || [ ! -f $j ]; then echo "$name ${r}x$t FAILED rc=$rc: $(tail -2 $o.log | tr '\n' ' ')"; return; fi
  python3 - "$name" $r $t $j "$s0" "$s1" <<P
import json, sys
name, r, t, j, s0, s1 = sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), sys.argv[4], float(sys.argv[5]), float(sys.argv[6])
s = json.load(open(j)); d = s.get('domains', {})
ms = 1000 * s['loop_seconds'] / s['steps']
tm = s.get('timing', {}); tot = sum(tm.values()) or 1
top = ' '.join(f"{k}={100*v/tot:.0f}%" for k, v in tm.items() if v/tot > 0.04)
print(f"{name:18s} {r:2d}x{t:<2d} {ms:9.2f} ms/step  ghosts/owned={d.get('ghosts_per_owned', 0):.3f} haloMB={d.get('halo_bytes_per_step', 0)/1e6:.2f} msgs={d.get('halo_messages_per_step', 0):.0f} redis={d.get('redistributions', 0)} migr={d.get('migrated_molecules', 0)} imb={(d.get('rank_loop_seconds_max', 1) / d.get('rank_loop_seconds_mean', 1)):.3f} grid={d.get('grid')} wall={s1-s0:.1f}s | {top}", flush=True)
P
}
L=${L:-"1x1 1x2 1x16 2x1 4x1 8x1 16x1 4x4 2x8"}; ONLY=${ONLY:-}; SKIPFX=${SKIPFX:-}
[ -n "${SKIPFX:-}" ] || for lay in $L; do r=${lay%x*}; t=${lay#*x}; run fixman $r $t stiff.toml "${THERMOSTAT[@]}"; done
[ -n "$ONLY$SKIPFX" ] || for lay in $L; do r=${lay%x*}; t=${lay#*x}; run impulse $r $t stiff.toml "${THERMOSTAT[@]}" --set integrator.method=impulse --set integrator.h=0.005 --set integrator.micro_steps=50 --set thermostat.splitting=baoab --set run.t_end=0.3 --set output.thermo_interval=0.3; done
[ -n "$ONLY" ] || for lay in $L; do r=${lay%x*}; t=${lay#*x}; run kg-vv $r $t $D/../inputs/kremer_grest.toml --set import.lammps_data=\"$W/kg256k.data\" --set run.t_end=0.72 --set output.thermo_interval=0.72 --set output.screen_interval=0.72 --set output.checkpoint_interval=0; done
# The same trajectory on 1 and 16 ranks (one thread each): positions and velocities bit for bit.
[ -n "${SKIPFX:-}" ] || for r in 1 16; do o=$W/bits_$r; rm -rf $o; OMP_NUM_THREADS=1 mpirun --allow-run-as-root --oversubscribe --bind-to none -np $r -x LD_LIBRARY_PATH -x OMP_NUM_THREADS $EXE run stiff.toml -o $o -q --no-progress "${THERMOSTAT[@]}" --set run.t_end=1.0 --set output.h5md=\"t.h5md\" --set output.h5md_interval=1.0 --set output.h5md_velocity=true > $o.log 2>&1 || tail -3 $o.log; done
[ -n "${SKIPFX:-}" ] || python3 -c "
import h5py, numpy as np
a, b = h5py.File('bits_1/t.h5md'), h5py.File('bits_16/t.h5md')
for k in ('position', 'velocity'):
    x, y = a['particles/all/%s/value' % k][-1], b['particles/all/%s/value' % k][-1]
    print('256k fixman 50 steps, 1 vs 16 ranks:', k, 'bit for bit' if np.array_equal(x, y) else 'max diff %g' % np.abs(x - y).max())
"
