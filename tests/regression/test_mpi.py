"""Distributed runs reproduce the one-rank run: 1, 2, 3 and 4 MPI ranks (oversubscribed on a
small machine) on the built-in disk and on a Gmsh mesh, for the exact (direct), GMRES
(multigrid-preconditioned) and adaptive methods, with the a posteriori estimators on.

What is compared with the one-rank run of the same case:
- the mesh and the Newton path: identical (every rank count takes the same decisions, so the
  same steps, GMRES iterations and active sets);
- the solution u1, u2, λ: within 1e-8 of the field's largest value;
- every global estimator value (the summary, each history row, the totals of /estimators)
  and every per-triangle value of /estimators and of the energy error: within
  1e-10 max(|x_ref|, scale). The scale is the bound η of the same evaluation for a global
  value, and for a triangle's value the root mean square of η_K over the mesh. It matters only
  for values that are themselves round-off: η_alg after an exact solve (1e-17 against
  η ≈ 1e-2), or η_alg of a GMRES iterate whose algebraic residual is 1e-9 of the load, which
  inherits the relative round-off of the iterate (1e-15) amplified by that ratio.
- with `estimate.bound = 'sharp'` too (the `*_sharp` cases), whose contact multiplier reads
  whether each ghost triangle is in contact from the triangle's owner;
- η_lin (global and per triangle, and η_K, which contains it) gets √ε η more: it contains
  √η_nonc,3 with η_nonc,3 = 2 C ‖λ⁺‖ η_nonc,1, and η_nonc,1 = |||s_h − u_h||| is exactly zero
  where u1 ≥ u2 but round-off wherever u1 − u2 is round-off (on the contact set), where the
  sign of a vertex's u1 − u2, hence s_h, depends on the order of the sums. The square root
  turns that round-off into √ε-sized values (seen: 3e-10 in η_lin = 0.39 of a Newton
  iterate), which no rank count, thread count or compiler can reproduce better.

The ranks split the coarse mesh with METIS, so with 2 to 4 ranks many vertex patches straddle
a partition boundary. The Gmsh case is not refined (mesh.levels=0): there the ghost layer is
one triangle deep and the ghost triangles have vertices outside the rank's unknowns, the case
in which the estimators must take ∇u_h and the residual lifting from the triangles' owners.
The disk case (two refinements, the default three meshes of the algebraic flux) exercises
the multilevel algebraic flux, whose coarse Riesz problem lives on the partitioned coarse mesh.
"""
from __future__ import annotations

import h5py
import numpy as np
import pytest

from twomem_testlib import out_file, run_on_ranks

SQRT_EPS = float(np.sqrt(np.finfo(float).eps))
RANKS = (1, 2, 3, 4)
SOLUTION_RTOL = 1e-8
ESTIMATOR_RTOL = 1e-10

DISK = ("mesh.coarse_h=0.5", "mesh.boundary_h=0.1", "mesh.levels=2")
GMSH = ("mesh.domain=gmsh", "mesh.file=input/meshes/lshape.msh", "mesh.levels=0", "problem.exact=none")
METHODS = {
    "direct": ("newton.linear=direct",),
    "gmres": ("newton.linear=gmres", "gmres.precond=mg"),
    "adaptive": ("newton.linear=adaptive", "gmres.precond=mg"),
}
CASES = {f"{mesh}_{method}": (*mesh_args, *METHODS[method], "estimate.enabled=.true.", "output.history=.true.",
                              "output.estimators=.true.")
         for mesh, mesh_args in (("disk", DISK), ("gmsh", GMSH)) for method in METHODS}
# estimate.bound = 'sharp' moves part of the contact multiplier inside the patches of the free
# boundary's vertices, by whether each patch triangle is in contact: a ghost triangle's answer
# comes from its owner (the direct method, so that a difference could only be the estimators')
CASES.update({f"{mesh}_sharp": (*mesh_args, *METHODS["direct"], "estimate.bound=sharp", "estimate.enabled=.true.",
                                "output.history=.true.", "output.estimators=.true.")
              for mesh, mesh_args in (("disk", DISK), ("gmsh", GMSH))})
HISTORY_ETA = ("eta_total", "eta_disc", "eta_lin", "eta_alg")
HISTORY_EXACT = ("newton_it", "inner", "gmres_it", "active", "active_changed")


def mpi_run(case: str, ranks: int) -> str:
    """Run case on `ranks` ranks; the result file's path."""
    path = out_file(f"mpi_{case}_{ranks}.h5")
    proc = run_on_ranks(ranks, *CASES[case], f"output.file={path}", timeout=300)
    assert f"{ranks} MPI ranks" in proc.stdout
    return str(path)


def read(path: str) -> dict:
    out = {}
    with h5py.File(path, "r") as f:
        out["summary"] = dict(f["summary"].attrs)
        for group in ("mesh", "solution", "history", "estimators", "error"):
            if group in f:
                for name, item in f[group].items():
                    out[f"{group}/{name}"] = item[()]
                    if "total" in item.attrs:
                        out[f"{group}/{name}:total"] = float(item.attrs["total"])
    return out


def close(value, reference, scale, rtol, extra=0.0):
    """Whether |value − reference| ≤ rtol max(|reference|, scale) everywhere (NaN where the
    reference has NaN, e.g. the estimators of a history row that has none), and the worst
    ratio of the difference to that bound."""
    value, reference = np.asarray(value, float), np.asarray(reference, float)
    assert value.shape == reference.shape
    nan = np.isnan(reference)
    if not np.array_equal(np.isnan(value), nan):
        return False, float("inf")
    bound = (rtol*np.maximum(np.abs(reference), scale) + extra)[~nan]
    diff = np.abs(value - reference)[~nan]
    return bool(np.all(diff <= bound)), float(np.max(diff/np.maximum(bound, 1e-300), initial=0))


@pytest.mark.parametrize("case", sorted(CASES))
def test_ranks_reproduce_one_rank(case):
    ref = read(mpi_run(case, 1))
    assert ref["summary"]["mpi_ranks"] == 1
    eta = ref["summary"]["eta_total"]
    assert np.isfinite(eta) and eta > 0
    rms_eta_k = float(np.sqrt(np.mean(ref["estimators/eta_total"]**2)))
    for ranks in RANKS[1:]:
        got = read(mpi_run(case, ranks))
        where = f"{case}, {ranks} ranks"
        assert got["summary"]["mpi_ranks"] == ranks
        np.testing.assert_array_equal(got["mesh/vertices"], ref["mesh/vertices"], err_msg=where)
        np.testing.assert_array_equal(got["mesh/triangles"], ref["mesh/triangles"], err_msg=where)
        for key in ("newton_iterations", "gmres_iterations", "estimator_evaluations"):
            assert got["summary"][key] == ref["summary"][key], f"{where}: {key}"
        for name in ("u1", "u2", "lambda"):
            scale = np.max(np.abs(ref[f"solution/{name}"]))
            ok, worst = close(got[f"solution/{name}"], ref[f"solution/{name}"], scale, SOLUTION_RTOL)
            assert ok, f"{where}: {name} off by {worst:.2f} x the tolerance"
        for key in ("eta_total", "eta_disc", "eta_lin", "eta_alg"):
            ok, worst = close(got["summary"][key], ref["summary"][key], eta, ESTIMATOR_RTOL,
                              SQRT_EPS*eta if key == "eta_lin" else 0.0)
            assert ok, f"{where}: summary {key} off by {worst:.2f} x the tolerance"
        # the history: the same rows (the same decisions), estimators row by row
        for key in HISTORY_EXACT:
            np.testing.assert_array_equal(got[f"history/{key}"], ref[f"history/{key}"], err_msg=f"{where}: {key}")
        # a check the adaptive method did not evaluate (estimate.checks = 'predicted') has η_lin
        # alone, which is then its own scale
        row_eta = np.where(np.isnan(ref["history/eta_total"]), ref["history/eta_lin"], ref["history/eta_total"])
        for key in HISTORY_ETA:
            ok, worst = close(got[f"history/{key}"], ref[f"history/{key}"], row_eta, ESTIMATOR_RTOL,
                              SQRT_EPS*row_eta if key == "eta_lin" else 0.0)
            assert ok, f"{where}: history {key} off by {worst:.2f} x the tolerance"
        fields = [key for key in ref if key.startswith("estimators/") and not key.endswith(":total")]
        assert len(fields) == 10
        for key in fields:
            extra = SQRT_EPS*eta if key in ("estimators/eta_lin", "estimators/eta_total") else 0.0
            ok, worst = close(got[key], ref[key], rms_eta_k, ESTIMATOR_RTOL, extra)
            assert ok, f"{where}: {key} off by {worst:.2f} x the tolerance"
            ok, worst = close(got[f"{key}:total"], ref[f"{key}:total"], eta, ESTIMATOR_RTOL,
                              extra if key == "estimators/eta_lin" else 0.0)
            assert ok, f"{where}: {key} total off by {worst:.2f} x the tolerance"
        if "error/energy" in ref:
            ok, worst = close(got["error/energy"], ref["error/energy"],
                              float(np.sqrt(np.mean(ref["error/energy"]**2))), ESTIMATOR_RTOL)
            assert ok, f"{where}: energy error per triangle off by {worst:.2f} x the tolerance"
            ok, worst = close(got["summary"]["energy_error"], ref["summary"]["energy_error"], 0, ESTIMATOR_RTOL)
            assert ok, f"{where}: energy error off by {worst:.2f} x the tolerance"
