#!/usr/bin/env bash
# Set-up for the PETSc peer benchmark (bench/petsc_vi.py) ONLY: installs Debian's petsc4py
# (PETSc 3.18 with hypre), h5py and scipy for the system interpreter /usr/bin/python3, then checks
# that petsc4py imports and that hypre's BoomerAMG can be selected. None of this is a twomem
# dependency; twomem itself never links PETSc.
#
#   bench/setup_petsc.sh        # idempotent: installs only what is missing, then checks
#   bench/setup_petsc.sh --help # this text; nothing installed
set -euo pipefail

# the comment block above, as the help text (bash alone: the ctest of --help runs without PATH)
usage() {
  local line
  {
    read -r line
    while read -r line && [[ $line == "#"* ]]; do
      line=${line#"#"}
      printf '%s\n' "${line# }"
    done
  } <"${BASH_SOURCE[0]}"
}
say() { printf '[setup_petsc] %s\n' "$*"; }
die() { printf '[setup_petsc] error: %s\n' "$*" >&2; exit 1; }

# arguments first: anything but --help is refused before a package is touched
case "${1:-}" in
  "") ;;
  -h|--help) usage; exit 0 ;;
  *) usage >&2; exit 2 ;;
esac

py=/usr/bin/python3
[ -x "$py" ] || die "$py not found (Debian's petsc4py runs under the system interpreter)"
# Debian's PETSc lives under the architecture's triplet (x86_64-linux-gnu, aarch64-linux-gnu, ...)
export PETSC_DIR=${PETSC_DIR:-/usr/lib/petscdir/petsc3.18/$("$py" -c 'import sysconfig; print(sysconfig.get_config_var("MULTIARCH"))')-real}

packages=(python3-petsc4py python3-h5py python3-scipy python3-numpy)
# shellcheck source=scripts/debian_packages.sh
source "$(dirname "${BASH_SOURCE[0]}")/../scripts/debian_packages.sh"
install_missing_packages setup_petsc "${packages[@]}"

[ -d "$PETSC_DIR" ] || die "PETSC_DIR=$PETSC_DIR does not exist"

# petsc4py imports, and a 1x1 KSP accepts -pc_type hypre -pc_hypre_type boomeramg
"$py" - <<'EOF' || die "petsc4py or hypre BoomerAMG check failed (see above)"
import sys
import petsc4py
petsc4py.init(sys.argv[:1])
from petsc4py import PETSc
A = PETSc.Mat().createAIJ([2, 2], nnz=2)
A.setValues([0, 1], [0, 1], [2.0, -1.0, -1.0, 2.0])
A.assemble()
ksp = PETSc.KSP().create()
ksp.setOperators(A)
ksp.setType("cg")
pc = ksp.getPC()
pc.setType("hypre")
pc.setHYPREType("boomeramg")
ksp.setFromOptions()
b = A.createVecLeft()
b.set(1.0)
x = A.createVecRight()
ksp.solve(b, x)
if pc.getType() != "hypre" or ksp.getConvergedReason() <= 0:
    sys.exit("BoomerAMG solve did not converge")
v = PETSc.Sys.getVersion()
print(f"[setup_petsc] petsc4py {petsc4py.__version__}, PETSc {v[0]}.{v[1]}.{v[2]}: "
      f"CG + hypre BoomerAMG ok")
import h5py, scipy  # noqa: F401  (the benchmark reads twomem's HDF5 and assembles with scipy)
print(f"[setup_petsc] h5py {h5py.__version__}, scipy {scipy.__version__}")
EOF
say "ready: PETSC_DIR=$PETSC_DIR /usr/bin/python3 bench/petsc_vi.py --help"
