#!/usr/bin/env bash
# Installs what stiffmd needs from Debian packages, only what is missing (--bench: and LAMMPS).
# Non-interactive, works as root on a machine where `apt-get update` never ran, and takes
# well under a second when everything is present.
set -euo pipefail

packages=(
  g++ cmake make pkg-config
  libeigen3-dev libhdf5-dev libtomlplusplus-dev libmuparser-dev libcli11-dev
  libgtest-dev libgmock-dev libbenchmark-dev liblapack-dev
  zlib1g-dev lammps-examples
  python3-numpy python3-scipy python3-matplotlib python3-h5py python3-mdanalysis python3-ase
  pybind11-dev python3-dev
  openmpi-bin libopenmpi-dev libhdf5-openmpi-dev
  libfftw3-dev libfftw3-mpi-dev
)
# `setup.sh --bench`: also LAMMPS, the peer tools/bench_lammps.py and tools/work_precision_melt.py
# measure against (never a dependency of the engine or of the tests).
[[ "${1:-}" == "--bench" ]] && packages+=(lammps)

missing=()
for p in "${packages[@]}"; do
  status=$(dpkg-query -W -f='${Status}' "$p" 2>/dev/null || true)
  [[ "$status" == "install ok installed" ]] || missing+=("$p")
done
[[ ${#missing[@]} -eq 0 ]] && exit 0

echo "setup: installing ${missing[*]}" >&2
sudo=""
if [[ $(id -u) -ne 0 ]]; then
  command -v sudo >/dev/null || { echo "setup: need root (or sudo) to install: ${missing[*]}" >&2; exit 1; }
  sudo="sudo"
fi
export DEBIAN_FRONTEND=noninteractive
install() { $sudo apt-get install -y -q --no-install-recommends "${missing[@]}" >&2; }
# Package lists may be absent (fresh image) or stale: update once and retry on failure.
if ! compgen -G "/var/lib/apt/lists/*_Packages*" >/dev/null || ! install; then
  $sudo apt-get update -q >&2
  install
fi
