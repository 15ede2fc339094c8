#!/usr/bin/env bash
# Fuzzing (libFuzzer, clang-14): builds the fuzz targets in build-fuzz (cmake/Fuzz.cmake) and
# runs each for SECONDS (default 120) under ASan + UBSan, with bounded memory and time per input:
#   bash tools/fuzz.sh [SECONDS] [TARGET...]      targets: fuzz_deck fuzz_lammps_data (default both)
# The corpus of each target grows in build-fuzz/corpus/TARGET (seeded from inputs/, the decks and
# data files under tests/ and the kept regressions); a crashing, leaking, slow or memory-hungry
# input is written to build-fuzz/findings/TARGET/ and the script fails. Keep each one, once fixed,
# in tests/fuzz/regressions/{deck,lammps_data}/ (replayed by ctest) and note it in
# tests/fuzz/FINDINGS.md.
set -euo pipefail
cd "$(dirname "$0")/.."
seconds="${1:-120}"
[ $# -gt 0 ] && shift
targets=("$@")
[ ${#targets[@]} -eq 0 ] && targets=(fuzz_deck fuzz_lammps_data)

cmake -S . -B build-fuzz -DCMAKE_BUILD_TYPE=RelWithDebInfo -DCMAKE_C_COMPILER=clang-14 \
  -DCMAKE_CXX_COMPILER=clang++-14 -DSTIFFMD_FUZZ=ON -DSTIFFMD_TESTS=OFF -DSTIFFMD_BENCHMARKS=OFF > /dev/null
cmake --build build-fuzz -j"${JOBS:-2}" --target "${targets[@]}"

status=0
for t in "${targets[@]}"; do
  corpus="build-fuzz/corpus/$t"
  findings="build-fuzz/findings/$t"
  mkdir -p "$corpus" "$findings"
  case "$t" in
    fuzz_deck)
      seeds=(inputs/*.toml tests/decks/*.toml tests/bad_decks/*.toml tests/fuzz/seeds/deck/* tests/fuzz/regressions/deck/*)
      dict=tests/fuzz/deck.dict ;;
    fuzz_lammps_data)
      seeds=(tests/data/* tests/fuzz/regressions/lammps_data/*)
      dict=tests/fuzz/lammps_data.dict ;;
    *) echo "unknown fuzz target $t" >&2; exit 2 ;;
  esac
  for s in "${seeds[@]}"; do
    # The deck is fuzzed from the temporary directory: seeds name data files by absolute path.
    [ -f "$s" ] && sed -e "s|@TESTS_DATA@|$PWD/tests/data|g" -e "s|\"\.\./data/|\"$PWD/tests/data/|g" "$s" \
      > "$corpus/seed_$(basename "$s")"
  done
  echo "== $t: ${seconds} s"
  if ! "build-fuzz/$t" "$corpus" -dict="$dict" -max_total_time="$seconds" -timeout=10 -rss_limit_mb=2048 \
    -malloc_limit_mb=2048 -artifact_prefix="$findings/" -print_final_stats=1; then
    echo "== $t: FINDING, see $findings/" >&2
    status=1
  fi
done
exit $status
