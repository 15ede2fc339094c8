#!/usr/bin/env bash
# The seed paper's experiment (Lubich & Weiss §2, Figs. 1–5) plus every method's work–precision,
# in one command: the stiff spring double pendulum at ε = 1e-4, t ∈ [0, 10], h = 1/4 … 1/1024,
# micro step ε/100 (ε/1000 for the plain impulse method), errors against the effective dynamics
# (RATTLE on U + W with step h/16 at h = 1/1024). Figures go to docs/figures/ (a few minutes).
set -euo pipefail
cd "$(dirname "$0")/.."
bash tools/build.sh
/usr/bin/python3 tools/sweep.py inputs/double_pendulum.toml -o sweeps/paper --eps 1e-4 --h 1/4:1/1024 \
  --methods impulse,mollified-impulse,projected-impulse,rattle,effective,velocity-verlet --vv-steps 16:1024 "$@"
/usr/bin/python3 tools/plot_sweep.py sweeps/paper --out docs/figures --actions-h 0.015625
