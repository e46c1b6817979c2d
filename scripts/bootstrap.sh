#!/usr/bin/env bash
# One entry point for a fresh Debian 12 machine (and for every later run: each step is skipped
# when already done). Installs the missing Debian packages and the Python venv of postproc,
# builds, then either runs the default case or runs the whole test suite.
#
#   scripts/bootstrap.sh run    # install + build + run input/default.nml, print the result path
#   scripts/bootstrap.sh test   # install + build + ctest (every label: unit, fuzz, regression,
#                               # postproc, stress), then the fast tests under the sanitizers
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."
root=$(pwd)
mode=${1:-}
case "$mode" in
  run|test) ;;
  *) echo "usage: scripts/bootstrap.sh run|test" >&2; exit 2 ;;
esac

say() { printf '[bootstrap] %s\n' "$*"; }

# --- Debian packages ---------------------------------------------------------------------
# libopenblas0-openmp: UMFPACK's factorizations are dense products of frontal matrices, and
# Debian's default reference BLAS makes them about half as fast (docs/performance.md,
# "Measuring"). Installing it makes OpenBLAS the system's libblas.so.3
# (a Debian alternative); its OpenMP build follows OMP_NUM_THREADS like twomem's own loops.
packages=(gfortran gcc g++ cmake ninja-build pkg-config libsuitesparse-dev libmetis-dev
          libopenblas0-openmp libhdf5-dev libopenmpi-dev openmpi-bin python3 python3-venv python3-pip)
# shellcheck source=scripts/debian_packages.sh
source "$root/scripts/debian_packages.sh"
install_missing_packages bootstrap "${packages[@]}"

# --- Python venv for postproc (h5py, numpy, matplotlib; pytest for the tests) --------------
venv="$root/.venv"
req="$root/postproc/requirements.txt"
stamp="$venv/.requirements.sha256"
want=$(sha256sum "$req" | cut -d' ' -f1)
if [ ! -x "$venv/bin/python" ] || [ "$(cat "$stamp" 2>/dev/null)" != "$want" ]; then
  say "setting up the Python venv in .venv"
  # Debian's own interpreter: the venv must work on a machine that has nothing else
  py=/usr/bin/python3
  [ -x "$py" ] || py=$(command -v python3)
  "$py" -m venv "$venv"
  "$venv/bin/pip" install -q --upgrade pip >/dev/null
  "$venv/bin/pip" install -q -r "$req"
  "$venv/bin/pip" install -q -e "$root/postproc" >/dev/null
  echo "$want" >"$stamp"
fi

# --- build ---------------------------------------------------------------------------------
build() {
  local preset=$1
  # configuring again is cheap and keeps the test interpreter pointing at the venv
  say "configuring ($preset)"
  cmake --preset "$preset" -DTWOMEM_PYTHON="$venv/bin/python" >/dev/null
  say "building ($preset)"
  cmake --build --preset "$preset" | grep -E "error|warning|FAILED" || true
  # grep hides ninja's chatter; the build's own status decides
  cmake --build --preset "$preset" >/dev/null
}

build release
case "$mode" in
  run)
    say "running input/default.nml"
    status=0
    build/release/twomem run input/default.nml || status=$?
    if [ $status -le 1 ] && [ -f results/default.h5 ]; then
      say "result: $root/results/default.h5 (ParaView: results/default.xdmf)"
      say "figures of the default case"
      .venv/bin/python -m twomem_post plot results/default.h5 -o results/figures || status=$?
      [ $status -le 1 ] && say "figures: $root/results/figures"
    fi
    exit $status
    ;;
  test)
    # strict debug build (-fcheck=all, FPE traps, warnings as errors) for everything but the
    # convergence studies, which need the release build's speed; then all under release
    build debug
    say "tests under the debug build (convergence studies excluded)"
    ctest --preset debug -E convergence -j 2
    say "all tests under the release build"
    ctest --preset release -j 2
    # AddressSanitizer + UBSan on the C glue and the Fortran (MPI off: Open MPI's own
    # allocations drown the reports); the fast tests only, the solver is 3-10x slower there
    build sanitize
    say "fast tests under the sanitizers (unit, fuzz, CLI and resources)"
    ctest --preset sanitize -L "unit|fuzz" -j 2
    ctest --preset sanitize -R "regression/(cli|resources)" -j 2
    ;;
esac
