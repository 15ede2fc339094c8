#!/usr/bin/env bash
# The whole test suite: installs what is missing, builds, runs ctest.
set -euo pipefail
cd "$(dirname "$0")/.."
bash tools/build.sh
cd build
# ctest runs tests in parallel and the engine's OpenMP loops use every core: waiting threads
# should sleep, not spin, or an oversubscribed machine crawls.
export OMP_WAIT_POLICY="${OMP_WAIT_POLICY:-passive}"
ctest --output-on-failure -j"$(nproc)" "$@"
