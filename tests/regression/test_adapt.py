"""Adaptive refinement (`&adapt`, docs/method.md §7) through the whole program.

The `radial` case on the unit disk has a closed form: the run's energy error is exact, so the
guaranteed bound η ≥ ‖error‖ is checked at every step, and both converge. The disk's boundary
polygon is made fine (mesh.boundary_h) and stays as it is under refinement, so that its
geometric error, which no estimator of the polygon problem sees, stays below the errors
measured. Every step's mesh in `/adapt/step_NNN` is checked to be conforming and nested in the
next one; the limits end the run with exit code 1 and a result; bad `&adapt` input is refused.
On 2 and 3 MPI ranks (each step's mesh partitioned anew by METIS) the exact method's adaptive
run reproduces the one-rank run: the same meshes at every step, η and the error to round-off.
On the pacman domain's Gmsh mesh (the benchmark's, docs/performance.md) with θ = 0.7 a step's
truncated algebraic coarse level is singular to round-off; the adaptive Newton must still take
a few steps per mesh.
"""
from __future__ import annotations

import os
import re
import subprocess

import h5py
import numpy as np
import pytest

from twomem_testlib import EXE, MPIEXEC, SOURCE, out_file, run, run_on_ranks

DEBUG = os.environ.get("TWOMEM_BUILD_TYPE", "").lower() == "debug"
#: the debug build (-O0) stops earlier
TOL = 4e-3 if DEBUG else 3e-3
RADIAL = ("mesh.levels=0", "mesh.coarse_h=0.25", "mesh.boundary_h=0.01", "problem.exact=radial")
#: the adaptivity benchmark's case (docs/performance.md) on its 96-vertex Gmsh mesh of the pacman domain
PACMAN = ("mesh.domain=gmsh", f"mesh.file={SOURCE / 'tests' / 'data' / 'meshes' / 'pacman_msh41.msh'}",
          "mesh.levels=0", "problem.exact=none", "problem.f1=-1", "problem.f2=0", "problem.g=0.05")


def adapt_steps(path):
    with h5py.File(path, "r") as f:
        a = {k: f["adapt"][k][()] for k in ("vertices", "triangles", "eta", "eta_disc", "eta_lin", "eta_alg",
                                           "energy_error", "wall_time")}
        steps = []
        for k in range(len(a["eta"])):
            g = f[f"adapt/step_{k + 1:03d}"]
            steps.append({n: g[n][()] for n in ("vertices", "triangles", "u1", "u2", "lambda", "eta_disc")})
        summary = dict(f["summary"].attrs)
        final = {"vertices": f["mesh/vertices"][()], "u1": f["solution/u1"][()]}
        status = f.attrs["status"]
    return a, steps, summary, final, status


@pytest.fixture(scope="module")
def radial():
    path = out_file("adapt_radial.h5")
    proc = run(*RADIAL, f"adapt.tol={TOL}", f"output.file={path}")
    return path, proc


def test_radial_bound_holds_and_converges(radial):
    path, proc = radial
    a, steps, summary, final, status = adapt_steps(path)
    n = len(a["eta"])
    assert n >= 4 and summary["adapt_steps"] == n
    assert status.startswith("adapt: eta") and "adapt.tol" in status, status
    assert a["eta"][-1] <= TOL < a["eta"][-2]
    # the guarantee, step by step, against the closed form
    assert np.all(a["eta"] >= a["energy_error"]), (a["eta"], a["energy_error"])
    # effectivity close to one once the mesh resolves the contact zone
    assert np.all(a["eta"][1:] / a["energy_error"][1:] < 1.5)
    # both go down, and by much more than one step's gain
    assert a["eta"][-1] < 0.4 * a["eta"][0] and a["energy_error"][-1] < 0.4 * a["energy_error"][0]
    assert np.all(np.diff(a["vertices"]) > 0)
    # the final result is the last step
    assert len(final["vertices"]) == a["vertices"][-1] == summary["nv"]
    np.testing.assert_array_equal(final["u1"], steps[-1]["u1"])
    assert np.all(a["wall_time"] > 0) and np.all(np.isfinite(a["eta_disc"]))


def edges_of(triangles):
    e = np.sort(np.vstack([triangles[:, [0, 1]], triangles[:, [1, 2]], triangles[:, [2, 0]]]), axis=1)
    uniq, counts = np.unique(e, axis=0, return_counts=True)
    return uniq, counts


def test_step_meshes_conforming_and_nested(radial):
    path, _ = radial
    _, steps, _, _, _ = adapt_steps(path)
    for k, s in enumerate(steps):
        v, t = s["vertices"], s["triangles"]   # (nv, 2) and (nt, 3), zero-based
        area = 0.5 * ((v[t[:, 1], 0] - v[t[:, 0], 0]) * (v[t[:, 2], 1] - v[t[:, 0], 1])
                      - (v[t[:, 2], 0] - v[t[:, 0], 0]) * (v[t[:, 1], 1] - v[t[:, 0], 1]))
        assert np.all(area > 0), f"step {k + 1}: a triangle is not counter-clockwise"
        uniq, counts = edges_of(t)
        assert counts.max() <= 2
        # no hanging vertex: Euler's formula for a disk, V - E + T = 1
        assert len(v) - len(uniq) + len(t) == 1, f"step {k + 1} is not conforming"
        assert len(s["eta_disc"]) == len(t) and len(s["u1"]) == len(v)
        if k + 1 < len(steps):
            w = steps[k + 1]["vertices"]
            # old vertices keep their numbers; the area is the same polygon's
            np.testing.assert_array_equal(w[: len(v)], v)
            # and the new ones are midpoints of its edges (bit for bit: the same sum)
            mid = 0.5 * (v[uniq[:, 0]] + v[uniq[:, 1]])
            known = {tuple(p) for p in mid}
            assert all(tuple(p) in known for p in w[len(v):]), f"step {k + 2} is not nested in step {k + 1}"
            assert abs(area.sum() - np.pi) < 2e-3


def test_steps_xdmf_names_every_step(radial):
    path, _ = radial
    text = path.with_suffix(".steps.xdmf").read_text()
    n = len(adapt_steps(path)[0]["eta"])
    assert 'CollectionType="Temporal"' in text
    assert len(re.findall(r"<Time Value=", text)) == n
    assert f"/adapt/step_{n:03d}/eta_disc" in text


@pytest.mark.parametrize("limit,word", [("adapt.max_steps=2", "max_steps"), ("adapt.max_vertices=300", "max_vertices")])
def test_limits_exit_1_with_result(limit, word):
    path = out_file(f"adapt_{word}.h5")
    proc = run("mesh.levels=0", "mesh.coarse_h=0.25", "adapt.tol=1e-6", limit, f"output.file={path}",
               check_rc=1)
    a, _, _, _, status = adapt_steps(path)
    assert f"adapt.{word}" in status and f"adapt.{word}" in proc.stdout, status
    if word == "max_steps":
        assert len(a["eta"]) == 2
    else:
        assert a["vertices"][-1] <= 300


def test_singular_coarse_level_keeps_newton_short():
    """Step 5 of this run (2366 vertices) makes the w-block's coarsest algebraic level singular to
    round-off: its solve returned corrections of 10^20 and more, and the adaptive Newton took 26
    steps there (GMRES broke down or stalled). Bounded by the coarsest level's diagonal shift, every
    step takes the two or three Newton steps of an interpolated start."""
    path = out_file("adapt_pacman.h5")
    run(*PACMAN, "adapt.tol=1e-6", "adapt.theta=0.7", "adapt.max_steps=6", f"output.file={path}", check_rc=1)
    with h5py.File(path, "r") as f:
        newton = f["adapt/newton_iterations"][()]
        vertices = f["adapt/vertices"][()]
    assert len(newton) == 6 and vertices[4] > 2000, vertices
    assert newton.max() <= 4, newton


def test_first_check_goes_by_the_previous_eta_disc():
    """A refinement step's first estimator check is told the previous mesh's η_disc scaled to the
    new mesh: while η_lin is far above γ_lin times it, the check computes η_lin alone instead of
    the discretization flux (which a check with nothing to go by computes), and the steps end as
    before, each with one whole evaluation."""
    path = out_file("adapt_hint.h5")
    proc = run(*PACMAN, "adapt.tol=1e-6", "adapt.max_steps=8", f"output.file={path}", check_rc=1)
    steps = proc.stdout.split("adapt: step ")
    first_checks = [next(line for line in step.splitlines() if line.startswith("newton    1")) for step in steps[1:-1]]
    assert len(first_checks) == 7
    assert all("(no evaluation)" in line for line in first_checks), first_checks
    with h5py.File(path, "r") as f:
        newton = f["adapt/newton_iterations"][()]
    assert newton[1:].max() <= 3, newton


def test_tol_zero_writes_no_adapt_group():
    path = out_file("adapt_off.h5")
    run("mesh.levels=1", f"output.file={path}")
    with h5py.File(path, "r") as f:
        assert "adapt" not in f and "adapt_steps" not in f["summary"].attrs
        assert "&adapt" in f.attrs["input"]


def test_nodal_load_files_are_refused(tmp_path):
    case = tmp_path / "case.nml"
    case.write_text("&mesh levels = 0 /\n&problem f1_file = 'loads.h5:/f1' /\n&adapt tol = 1e-3 /\n")
    proc = subprocess.run([EXE, "run", str(case), f"output.file={tmp_path / 'out' / 'a.h5'}"], capture_output=True,
                          text=True)
    assert proc.returncode == 2, proc.stderr
    lines = proc.stderr.splitlines()
    assert len(lines) == 1 and "&adapt" in lines[0] and "f1_file" in lines[0], lines
    assert not (tmp_path / "out").exists()


@pytest.mark.skipif(not MPIEXEC, reason="no MPI launcher in this build")
def test_ranks_reproduce_one_rank():
    runs = {}
    for ranks in (1, 2, 3):
        path = out_file(f"adapt_mpi_{ranks}.h5")
        run_on_ranks(ranks, "mesh.levels=0", "mesh.coarse_h=0.25", "mesh.boundary_h=0.02", "newton.linear=direct",
                     "adapt.tol=6e-3", f"output.file={path}", timeout=300)
        runs[ranks] = adapt_steps(path)
    ref, ref_steps = runs[1][0], runs[1][1]
    assert len(ref["eta"]) >= 3
    for ranks in (2, 3):
        a, steps, summary, _, _ = runs[ranks]
        assert summary["mpi_ranks"] == ranks
        np.testing.assert_array_equal(a["vertices"], ref["vertices"])
        for s, r in zip(steps, ref_steps):
            np.testing.assert_array_equal(s["triangles"], r["triangles"])
            np.testing.assert_array_equal(s["vertices"], r["vertices"])
            np.testing.assert_allclose(s["u1"], r["u1"], rtol=0, atol=1e-12)
        np.testing.assert_allclose(a["eta"], ref["eta"], rtol=1e-10)
        np.testing.assert_allclose(a["energy_error"], ref["energy_error"], rtol=1e-10)
