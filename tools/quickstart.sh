#!/usr/bin/env bash
# The main job: installs what is missing, builds, and runs the seed paper's stiff spring
# double pendulum (inputs/double_pendulum.toml). Extra arguments go to `stiffmd run`,
# e.g.  bash tools/quickstart.sh --set variables.eps=1e-4 --set integrator.h=1e-6
set -euo pipefail
cd "$(dirname "$0")/.."
bash tools/build.sh
exec build/stiffmd run inputs/double_pendulum.toml "$@"
