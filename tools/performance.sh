#!/usr/bin/env bash
# Regenerates the performance tables (docs/performance.md §4; README "Performance summary" quotes them): the stiffmd vs LAMMPS table (tools/bench_lammps.py)
# and the work–precision / step-size resonance figures on the melt (tools/work_precision_melt.py).
#
#   bash tools/performance.sh          # table (≈ 5 min) + figures at ε = 0.01 (≈ 10 min) on 2 cores
#   bash tools/performance.sh --full   # + ε = 0.003 and energy drift to t = 10 (≈ 1–1.5 h)
#
# Run it on a quiet machine: the timings are medians of interleaved repeats, but a busy core
# slows the 2-thread runs most (OpenMP threads wait for each other).
set -euo pipefail
cd "$(dirname "$0")/.."
bash tools/setup.sh --bench
bash tools/build.sh
/usr/bin/python3 tools/bench_lammps.py --threads "1 2"
if [[ "${1:-}" == "--full" ]]; then
  /usr/bin/python3 tools/work_precision_melt.py
else
  /usr/bin/python3 tools/work_precision_melt.py --eps 0.01 --t-long 2
fi
