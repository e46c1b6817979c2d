"""The numerical stress suite (ctest label `stress`): every case of stress_lib.CASES by every
method, judged by stress_lib.judge (converged and checked against an independent computation,
or exit 1 with a precise reason; never a crash, a hang or NaN called converged).

TWOMEM_STRESS_CASES (comma-separated names) restricts the run to some cases: ctest runs one
case per test so that `ctest -j` spreads them.
"""
from __future__ import annotations

import functools
import os

import pytest

import stress_lib as sl

SELECTED = [c for c in sl.CASES if c.name in os.environ.get("TWOMEM_STRESS_CASES", c.name).split(",")]


@functools.lru_cache(maxsize=None)
def outcomes(name: str) -> tuple[dict, sl.Outcome | None]:
    """Every method's run of the case and the reference (stress_lib.run_all)."""
    return sl.run_all(sl.BY_NAME[name])


@pytest.mark.parametrize("linear,cfun", sl.METHODS, ids=[f"{lin}-{c}" for lin, c in sl.METHODS])
@pytest.mark.parametrize("name", [c.name for c in SELECTED])
def test_case_by_method(name, linear, cfun):
    runs, ref = outcomes(name)
    o = runs[(linear, cfun)]
    problems = sl.judge(o, ref)
    print(f"{name} {linear}/{cfun}: exit {o.code}, {o.status}, {o.newton} Newton, {o.gmres} GMRES, "
          f"error {o.error:.2e} (bound {o.bound:.2e}), residual {o.residual:.2e}, {o.seconds:.1f} s")
    assert not problems, "; ".join(problems)
