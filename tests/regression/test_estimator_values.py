"""Every estimator value against the values of the estimator code as it was before its rewrite
for speed and memory (shape classes, patch signatures): the new evaluation must reproduce the old one
to round-off.

How the references were made: with the release and debug builds of commit 30774a0 (main with
the multigrid and MPI solver, before the rewritten estimators were merged: per-triangle mixed
inverses, dense patch systems), by

    .venv/bin/python tests/regression/test_estimator_values.py --regenerate build/release/twomem
    .venv/bin/python tests/regression/test_estimator_values.py --regenerate build/debug/twomem debug

(the first references, of commit 7c04e15, were replaced because the solver changes merged in
between, such as the stable Fischer–Burmeister back-substitution, moved the iterates of the
adaptive and GMRES cases by up to 1e-3 relative; the estimators themselves were not compared
across that change). They were made again with 30774a0 plus two solver changes, the same as
main's: a full Newton step takes GMRES's iterate itself (x = x_new instead of
x + 1·(x_new − x), which differs by round-off), which moves every iterate after the first by
round-off and the converged η_lin, itself round-off, by more than 1e-12; and the adaptive
method evaluates no estimators at its initial iterate (history row 0 NaN). (The GMRES cases
keep the paper's forcing, gmres.forcing = 'paper', not the default 'finish'; the adaptive cases
evaluate at every check, estimate.checks = 'all', which was the only schedule then.) The four
ILU(0) cases were regenerated, and the two direct ones kept, when the unknowns began to be
numbered for locality (twomem_fem_transfer) instead of in vertex order: ILU(0) still factorizes
in vertex order, but every sparse product now sums its rows in another order, which moves the
GMRES iterates by round-off; in the L-shape GMRES cases the paper's test then meets its tie
(algebraic = linearization residual) on the other side at Newton step 10 (12 steps instead of
10), and the adaptive cases' converged η_lin moved by up to 2e-6 relative. The direct cases,
whose iterates do not depend on GMRES, still reproduce 30774a0's estimator code. The two
L-shape cases were regenerated again when nested iteration began to settle the contact set of
its interpolated start (twomem_newton_settle): their iterates changed (10 Newton steps instead
of 12), not the estimator code. The command runs each case of CASES below with OMP_NUM_THREADS=1 and stores the `/history` and
`/estimators` groups of its result file as tests/regression/reference/estimators_<case>.h5. Regenerate
only where round-off moves a value beyond the tolerance, and say so in the commit.

The cases cover both flux spaces, the multilevel algebraic flux with its three kinds of patch
problems (the first refined level with the coarse Riesz representer, a further refined level,
and a single mesh when alg_levels = 1), boundary vertices of the disk and of a non-convex Gmsh
mesh, contact (bbbv) and the nonconformity terms of Fischer–Burmeister iterates. The direct
solves give iterates that do not depend on the estimators; in the adaptive and GMRES runs
the iterates carry a real algebraic residual, so σ_alg is far from zero.

Tolerance: each value x (per history row: η, η_disc, η_lin, η_alg; per triangle: every field
of `/estimators` and its total) must satisfy |x − x_ref| ≤ 1e-12 max(|x_ref|, scale), with
scale the bound η of the same evaluation for the global values, and for a triangle's values
the larger of its own η_K and the root mean square of η_K over the mesh. The scale matters
only for values that are themselves round-off, such as η_alg after an exact solve (1e-17
against η ≈ 1e-3), η_C,K = 0 where there is no contact, or η_F,K ≈ 1e-18 on triangles where
the discrete solution is exactly linear (there the old and new code differ by 1e-19, a 10%
"relative" change of a value that is zero to round-off).
"""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import h5py
import numpy as np
import pytest

HERE = Path(__file__).resolve().parent
REFERENCES = HERE / "reference"
RTOL = 1e-12

DISK = ("mesh.coarse_h=0.5", "mesh.boundary_h=0.1", "newton.initial=paper")
LSHAPE = ("mesh.domain=gmsh", "mesh.file=input/meshes/lshape.msh", "problem.exact=none")
CASES = {
    "radial_rt1_direct": (*DISK, "mesh.levels=2", "problem.exact=radial", "newton.linear=direct"),
    "bbbv_rt0_direct": (*DISK, "mesh.levels=2", "problem.exact=bbbv", "newton.linear=direct",
                        "estimate.flux=rt0"),
    "bbbv_rt1_adaptive_fb": (*DISK, "mesh.levels=2", "problem.exact=bbbv", "newton.linear=adaptive",
                             "newton.cfun=fb", "gmres.precond=ilu0", "estimate.checks=all"),
    "bbbv_rt0_adaptive_alg2": (*DISK, "mesh.levels=2", "problem.exact=bbbv", "newton.linear=adaptive",
                               "estimate.flux=rt0", "estimate.alg_levels=2", "gmres.precond=ilu0",
                               "estimate.checks=all"),
    "lshape_rt1_gmres_alg1": (*LSHAPE, "mesh.levels=1", "newton.linear=gmres", "gmres.forcing=paper",
                              "estimate.alg_levels=1", "gmres.precond=ilu0"),
    "lshape_rt1_gmres": (*LSHAPE, "mesh.levels=1", "newton.linear=gmres", "gmres.forcing=paper",
                         "gmres.precond=ilu0"),
}
HISTORY = ("eta_total", "eta_disc", "eta_lin", "eta_alg")


def reference(case: str, build_type: str) -> Path:
    suffix = ".debug" if build_type.lower() == "debug" else ""
    return REFERENCES / f"estimators_{case}{suffix}.h5"


def run_case(exe: str, source: Path, case: str, out: Path) -> None:
    cmd = [exe, "run", str(source / "input" / "default.nml"), *CASES[case], f"output.file={out}",
           "output.fields=.false.", "output.xdmf=.false.", "newton.max_it=200"]
    env = dict(os.environ, OMP_NUM_THREADS="1")
    proc = subprocess.run(cmd, capture_output=True, text=True, cwd=source, env=env, timeout=1800)
    assert proc.returncode == 0, f"{' '.join(cmd)} exited {proc.returncode}\n{proc.stdout[-2000:]}\n{proc.stderr}"


def read(path: Path) -> tuple[dict, dict, dict]:
    with h5py.File(path, "r") as f:
        history = {k: f["history"][k][()] for k in f["history"]}
        fields = {k: f["estimators"][k][()] for k in f["estimators"]}
        totals = {k: float(f["estimators"][k].attrs["total"]) for k in f["estimators"]}
    return history, fields, totals


def close(x, ref, scale) -> np.ndarray:
    """Where |x − ref| ≤ RTOL max(|ref|, scale), NaN matching NaN."""
    x, ref, scale = np.broadcast_arrays(np.asarray(x, float), np.asarray(ref, float), np.asarray(scale, float))
    both_nan = np.isnan(x) & np.isnan(ref)
    with np.errstate(invalid="ignore"):
        ok = np.abs(x - ref) <= RTOL * np.maximum(np.abs(ref), np.abs(scale))
    return ok | both_nan


@pytest.mark.parametrize("case", CASES)
def test_estimators_reproduce_the_previous_evaluation(case):
    from twomem_testlib import EXE, SOURCE, out_file

    path = out_file(f"estimator-values-{case}.h5")
    run_case(EXE, SOURCE, case, path)
    history, fields, totals = read(path)
    ref_history, ref_fields, ref_totals = read(reference(case, os.environ.get("TWOMEM_BUILD_TYPE", "Release")))

    # the same iterates were recorded (same Newton and GMRES counts)
    for key in ("newton_it", "inner", "gmres_it"):
        np.testing.assert_array_equal(history[key], ref_history[key], err_msg=key)
    recorded = np.isfinite(ref_history["eta_total"])
    assert recorded.sum() >= 2
    for key in HISTORY:
        ok = close(history[key], ref_history[key], ref_history["eta_total"])
        assert ok.all(), (f"{key}: rows {np.flatnonzero(~ok)}: {history[key][~ok]} against "
                          f"{ref_history[key][~ok]}")
    assert set(fields) == set(ref_fields)
    eta_k = ref_fields["eta_total"]
    scale = np.maximum(eta_k, np.sqrt(np.mean(eta_k**2)))
    for name in ref_fields:
        ok = close(fields[name], ref_fields[name], scale)
        worst = np.argmax(np.abs(fields[name] - ref_fields[name]))
        assert ok.all(), (f"{name}: {np.count_nonzero(~ok)} triangles differ, worst {worst}: "
                          f"{fields[name][worst]!r} against {ref_fields[name][worst]!r}")
        assert close(totals[name], ref_totals[name], ref_totals["eta_total"]), \
            f"{name} total: {totals[name]!r} against {ref_totals[name]!r}"


def regenerate(exe: str, build_type: str) -> None:
    source = HERE.parents[1]
    for case in CASES:
        out = reference(case, build_type)
        full = out.with_suffix(".full.h5")
        run_case(str(Path(exe).resolve()), source, case, full)
        # only what the test compares: the history and /estimators
        with h5py.File(full, "r") as f, h5py.File(out, "w") as g:
            f.copy("history", g)
            f.copy("estimators", g)
        full.unlink()
        print(f"wrote {out}")


if __name__ == "__main__":
    if len(sys.argv) not in (3, 4) or sys.argv[1] != "--regenerate":
        sys.exit("usage: test_estimator_values.py --regenerate TWOMEM_EXE [debug|release]")
    regenerate(sys.argv[2], sys.argv[3] if len(sys.argv) == 4 else "release")
