"""Energy-error convergence against the closed-form solutions (docs/method.md §4).

P1 elements converge at rate 1 in the energy norm. Two studies per case, four meshes each:
- *deeper*: one fixed coarse disk (its boundary spacing fixed too, so the polygon is the
  same on every level) refined 0..3 times: the hierarchy's own levels;
- *halving*: coarse_h halved three times, no refinement (uniform meshes, boundary resolved
  like the interior).
The error is read from the result file (`/summary` energy_error); test_discrete.py checks that
measurement independently. Every successive rate must lie in 1 ± 0.1.
"""
from __future__ import annotations

import math

import pytest

from twomem_testlib import out_file, result, run

STUDIES = {
    # coarse_h 0.125 with the boundary spacing the automatic rule picks for 3 levels
    "deeper": [dict(coarse_h=0.125, boundary_h=0.025, levels=l) for l in range(4)],
    "halving": [dict(coarse_h=0.1 / 2**k, boundary_h=0, levels=0) for k in range(4)],
}


def energy_errors(case: str, study: str) -> list[tuple[int, float]]:
    rows = []
    for i, mesh in enumerate(STUDIES[study]):
        path = out_file(f"convergence/{case}_{study}_{i}.h5")
        run(f"problem.exact={case}", "newton.linear=direct",
            *(f"mesh.{k}={v}" for k, v in mesh.items()), f"output.file={path}")
        r = result(path)
        rows.append((int(r["summary"]["nt"]), float(r["summary"]["energy_error"])))
    return rows


@pytest.mark.parametrize("study", sorted(STUDIES))
@pytest.mark.parametrize("case", ["radial", "bbbv"])
def test_energy_error_rate_is_one(case, study):
    rows = energy_errors(case, study)
    rates = [math.log2(e0 / e1) for (_, e0), (_, e1) in zip(rows, rows[1:])]
    table = "\n".join(f"  {nt:8d} triangles  error {e:.5e}" for nt, e in rows)
    print(f"{case} {study}:\n{table}\n  rates {', '.join(f'{r:.3f}' for r in rates)}")
    assert all(0.9 <= r <= 1.1 for r in rates), f"{case} {study}: rates {rates}\n{table}"
