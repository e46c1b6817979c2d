"""A small case's complete result against a stored reference (tests/regression/reference).

The reference was produced by twomem itself and scrutinized before it was stored: its
discrete equations and energy error are checked independently by test_discrete.py and its
convergence rate by test_convergence.py. This test guards against unintended changes of any
number in the result file. Tolerances: rtol 1e-9 and atol 1e-12 — the solution comes from a
direct solve, so differences beyond round-off mean a change of the discretization or solver.
Regenerate (after checking why it changed) with:
    twomem run input/default.nml mesh.levels=1 output.file=tests/regression/reference/radial_small.h5
"""
from __future__ import annotations

from twomem_testlib import SOURCE, out_file, run
from twomem_post.compare import compare

REFERENCE = SOURCE / "tests" / "regression" / "reference" / "radial_small.h5"


def test_small_radial_matches_reference():
    path = out_file("reference/radial_small.h5")
    run("mesh.levels=1", f"output.file={path}")
    assert compare(str(path), str(REFERENCE), rtol=1e-9, atol=1e-12) == 0
