#!/usr/bin/env bash
# A longer fuzz run than CI's, outside ctest (whose timeout is sized for 2000 inputs): every
# parser target of tests/fuzz in turn, through the fuzz driver of a build made by
# scripts/bootstrap.sh (or cmake --build --preset ...). See docs/robustness.md.
#
#   scripts/fuzz.sh [COUNT [SEED [BUILD_DIR]]]    # defaults: 100000 inputs, seed 2, build/debug
#
# Exits non-zero as soon as a target reports a contract violation, crashes, or runs longer
# than TWOMEM_FUZZ_INPUT_SECONDS on one input.
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."
root=$(pwd)
count=${1:-100000}
seed=${2:-2}
build=${3:-build/debug}
driver="$build/tests/fuzz/twomem_fuzz"
if [ ! -x "$driver" ]; then
  echo "fuzz.sh: $driver not found: build first (scripts/bootstrap.sh test)" >&2
  exit 2
fi
tmp="$root/$build/tests/fuzz/tmp"
mkdir -p "$tmp"
export TWOMEM_TEST_DATA="$root/tests/data" TWOMEM_SOURCE_DIR="$root" TWOMEM_TEST_TMP="$tmp"
export TWOMEM_FUZZ_COUNT="$count" TWOMEM_FUZZ_SEED="$seed"
# what the sanitize test preset sets (CMakePresets.json); without sanitizers they do nothing
export ASAN_OPTIONS="${ASAN_OPTIONS:-detect_leaks=1:allocator_may_return_null=1}"
export UBSAN_OPTIONS="${UBSAN_OPTIONS:-halt_on_error=1:print_stacktrace=1}"
export LSAN_OPTIONS="${LSAN_OPTIONS:-suppressions=$root/tests/lsan.supp}"
for target in gmsh namelist override; do
  start=$(date +%s)
  "$driver" "$target"
  echo "$target: $(( $(date +%s) - start )) s"
done
