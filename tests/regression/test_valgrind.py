"""valgrind memcheck on a small case of each method: no invalid read or write, no invalid free,
no definite leak (docs/robustness.md, "In CI, and under valgrind").

Runs under the release build when valgrind is installed; skipped otherwise, under the debug
build (-O0 code under valgrind: minutes per case) and under AddressSanitizer (the two cannot
share a process). Uninitialised-value errors are off (--undef-value-errors=no): gfortran's
code for assignment to an unallocated allocatable reads the array descriptor's bounds, which
are never set, next to its null data pointer, and valgrind reports every such assignment
(seen in discrete_init and fill_record); uninitialised reals are caught instead by the debug
build, which fills them with signalling NaNs and traps invalid operations.
By hand: valgrind --error-exitcode=99 --leak-check=full --errors-for-leak-kinds=definite
--undef-value-errors=no build/release/twomem run input/default.nml mesh.domain=square
mesh.coarse_h=0.5 mesh.levels=1
"""
from __future__ import annotations

import os
import shutil
import subprocess

import pytest

from twomem_testlib import DEFAULT_CASE, EXE, out_file

VALGRIND = shutil.which("valgrind")
pytestmark = [pytest.mark.skipif(VALGRIND is None, reason="valgrind is not installed"),
              pytest.mark.skipif("ASAN_OPTIONS" in os.environ, reason="valgrind does not run ASan builds"),
              pytest.mark.skipif(os.environ.get("TWOMEM_BUILD_TYPE", "Release") != "Release",
                                 reason="valgrind runs the release build (the debug build is too slow under it)")]

SMALL = ["mesh.domain=square", "mesh.coarse_h=0.5", "mesh.levels=1", "problem.exact=none"]


@pytest.mark.parametrize("linear,cfun", [("direct", "min"), ("gmres", "fb"), ("adaptive", "min")])
def test_memcheck_clean(linear, cfun):
    out = out_file(f"valgrind/{linear}_{cfun}.h5")
    out.parent.mkdir(parents=True, exist_ok=True)
    proc = subprocess.run([VALGRIND, "--error-exitcode=99", "--leak-check=full", "--errors-for-leak-kinds=definite",
                           "--show-leak-kinds=definite", "--undef-value-errors=no", "--quiet", EXE, "run", str(DEFAULT_CASE),
                           *SMALL, f"newton.linear={linear}", f"newton.cfun={cfun}", f"output.file={out}"],
                          capture_output=True, text=True, timeout=900, env={**os.environ, "OMP_NUM_THREADS": "1"})
    assert proc.returncode == 0, f"exit {proc.returncode}\n{proc.stderr[-6000:]}"
    assert "== ERROR SUMMARY" not in proc.stderr or "ERROR SUMMARY: 0 errors" in proc.stderr, proc.stderr[-6000:]
    assert out.exists()
