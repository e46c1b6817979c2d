"""Meshes given without coarser meshes: multigrid on algebraic coarse levels and nested
iteration on coarsened meshes.

A 9267-vertex built-in disk solved as it is (mesh.levels=0) is larger than the direct solve
of a coarsest level allows (2000 unknowns), so multigrid runs on smoothed-aggregation levels
below it, and nested iteration starts on meshes coarsened from it. Both change the path, not
the discrete problem: multigrid GMRES must reach exact Newton-min's solution (UMFPACK on the
whole mesh) to 1e-8 with both C-functions, on one rank and on two (where the algebraic levels
are aggregated rank by rank), with at most 20 GMRES iterations per Newton step; the coarsened
start (the mesh gathered on every rank of a distributed run) must leave the finest mesh at most
8 Newton steps, where the paper's cold start takes
one step per layer of vertices between its first contact front and the free boundary. A
refinement hierarchy whose coarse mesh has more than 10^4 triangles gets the same algebraic
levels below its coarsest mesh. A mesh file of more than 10^4 triangles is solved in a
numbering along the domain (the mesher's numbering scatters every row over memory) and written
back in the file's numbering: the same disk as a Gmsh file with its nodes and triangles
shuffled must give the direct solution, node for node, through the coarsened start, the
algebraic levels and the estimators.
"""
from __future__ import annotations

import h5py
import numpy as np
import pytest

from twomem_testlib import MPIEXEC, out_file, result, run, run_on_ranks

MEMBRANES = ("problem.exact=none", "problem.mu1=2", "problem.mu2=0.5", "problem.f1=-2", "problem.f2=1")
FINE = ("mesh.coarse_h=0.02", "mesh.boundary_h=0.02", "mesh.levels=0", *MEMBRANES)
LARGE_COARSE = ("mesh.coarse_h=0.02", "mesh.boundary_h=0.02", "mesh.levels=1", *MEMBRANES)
TIGHT = ("newton.tol=1e-12", "gmres.rtol=1e-13", "estimate.enabled=.false.")


def solve(name: str, *args: str, last: tuple[str, ...] = ()) -> dict:
    """The run's result; `last` overrides come after TIGHT's."""
    path = out_file(f"any_mesh/{name}.h5")
    proc = run(*args, *TIGHT, *last, f"output.file={path}")
    got = result(path)
    got["stdout"] = proc.stdout
    got["path"] = path
    return got


def assert_same_solution(got: dict, ref: dict, where: str) -> None:
    assert ref["status"] == got["status"] == "converged", where
    for field in ("u1", "u2", "lambda"):
        diff = np.max(np.abs(got[field] - ref[field]))
        print(f"{where} {field}: max diff {diff:.2e}")
        assert diff <= 1e-8, f"{where}: {field} differs by {diff:.3e}"


@pytest.fixture(scope="module")
def direct_fine() -> dict:
    return solve("fine_direct", *FINE, "newton.linear=direct")


@pytest.mark.parametrize("cfun", ["min", "fb"])
def test_multigrid_on_algebraic_levels_reaches_the_direct_solution(direct_fine, cfun):
    got = solve(f"fine_{cfun}", *FINE, f"newton.cfun={cfun}", "newton.linear=gmres", "gmres.precond=mg")
    assert_same_solution(got, direct_fine, f"fine mesh, {cfun}")
    s = got["summary"]
    per_step = s["gmres_iterations"]/max(1, s["newton_iterations"])
    print(f"{cfun}: {s['newton_iterations']} finest Newton steps, {per_step:.1f} GMRES iterations per step")
    assert per_step <= 20
    assert s["newton_iterations"] <= 8


def test_coarsened_start_replaces_the_cold_start(direct_fine):
    """The same finest problem from the paper's initial guess crawls; from the coarsened
    meshes it does not."""
    assert "nested: coarsened mesh" in direct_fine["stdout"]
    assert direct_fine["summary"]["newton_iterations"] <= 8
    cold = solve("fine_direct_cold", *FINE, "newton.linear=direct", "newton.initial=paper")
    assert_same_solution(cold, direct_fine, "fine mesh, cold start")
    print(f"Newton steps: cold {cold['summary']['newton_iterations']}, "
          f"coarsened start {direct_fine['summary']['newton_iterations']}")
    assert cold["summary"]["newton_iterations"] >= 3*direct_fine["summary"]["newton_iterations"]


def test_hierarchy_with_a_large_coarse_mesh():
    ref = solve("large_coarse_direct", *LARGE_COARSE, "newton.linear=direct")
    got = solve("large_coarse_gmres", *LARGE_COARSE, "newton.linear=gmres", "gmres.precond=mg")
    assert_same_solution(got, ref, "coarse mesh of 18218 triangles")
    s = got["summary"]
    assert s["gmres_iterations"]/max(1, s["newton_iterations"]) <= 20
    # every rank coarsens the gathered mesh alike: the nested start holds on two ranks too
    assert s["newton_iterations"] <= 8


def solve_on_ranks(name: str, ranks: int, *args: str) -> dict:
    path = out_file(f"any_mesh/{name}.h5")
    proc = run_on_ranks(ranks, *args, *TIGHT, f"output.file={path}")
    got = result(path)
    got["stdout"] = proc.stdout
    assert got["summary"]["mpi_ranks"] == ranks
    return got


@pytest.mark.skipif(not MPIEXEC, reason="no MPI launcher")
@pytest.mark.parametrize("cfun", ["min", "fb"])
def test_two_ranks_reach_the_direct_solution(direct_fine, cfun):
    got = solve_on_ranks(f"fine_{cfun}_2ranks", 2, *FINE, f"newton.cfun={cfun}", "newton.linear=gmres",
                         "gmres.precond=mg")
    assert_same_solution(got, direct_fine, f"fine mesh, {cfun}, 2 ranks")
    s = got["summary"]
    assert s["gmres_iterations"]/max(1, s["newton_iterations"]) <= 20
    # every rank coarsens the gathered mesh alike: the nested start holds on two ranks too
    assert s["newton_iterations"] <= 8


def write_shuffled_msh(path, vertices: np.ndarray, triangles: np.ndarray,
                       seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The mesh as an MSH 2.2 file whose nodes and triangles come in random order; returns the
    file's node order (node k is vertex order[k]), its triangle order (element k is triangle
    tri_order[k]) and its triangles in file numbering (0-based)."""
    rng = np.random.default_rng(seed)
    order = rng.permutation(len(vertices))
    number = np.empty(len(vertices), dtype=np.int64)
    number[order] = np.arange(len(vertices))
    tri_order = rng.permutation(len(triangles))
    shuffled = number[triangles[tri_order]]
    with open(path, "w") as f:
        f.write(f"$MeshFormat\n2.2 0 8\n$EndMeshFormat\n$Nodes\n{len(order)}\n")
        for k, v in enumerate(order):
            f.write(f"{k + 1} {float(vertices[v, 0])!r} {float(vertices[v, 1])!r} 0\n")
        f.write(f"$EndNodes\n$Elements\n{len(shuffled)}\n")
        for k, t in enumerate(shuffled):
            f.write(f"{k + 1} 2 2 1 1 {t[0] + 1} {t[1] + 1} {t[2] + 1}\n")
        f.write("$EndElements\n")
    return order, tri_order, shuffled


@pytest.mark.parametrize("ranks", [1, 2])
def test_a_mesh_file_keeps_its_numbering(direct_fine, ranks):
    if ranks > 1 and not MPIEXEC:
        pytest.skip("no MPI launcher")
    path = out_file(f"any_mesh/shuffled_disk_{ranks}.msh")
    order, tri_order, shuffled = write_shuffled_msh(path, direct_fine["vertices"], direct_fine["triangles"], seed=7)
    assert len(shuffled) > 10**4
    args = ("mesh.domain=gmsh", f"mesh.file={path}", "mesh.levels=0", *MEMBRANES, "newton.linear=gmres",
            "gmres.precond=mg")
    if ranks == 1:
        got = solve("shuffled_gmres", *args, last=("estimate.enabled=.true.",))
        # the estimators too, triangle by triangle in the file's order: those of the same disk
        # built in (the same discrete solution to 1e-12, so the same η_disc,K to round-off)
        ref = solve("fine_gmres_estimated", *FINE, "newton.linear=gmres", "gmres.precond=mg",
                    last=("estimate.enabled=.true.",))
        with h5py.File(got["path"]) as f, h5py.File(ref["path"]) as g:
            mine, theirs = f["estimators/eta_disc"][()], g["estimators/eta_disc"][()][tri_order]
        scale = np.sqrt(np.mean(theirs**2))
        print(f"eta_disc,K: max difference {np.max(np.abs(mine - theirs))/scale:.2e} of their rms")
        np.testing.assert_allclose(mine, theirs, rtol=1e-8, atol=1e-10*scale)
    else:
        got = solve_on_ranks(f"shuffled_gmres_{ranks}ranks", ranks, *args)
    assert "nested: coarsened mesh" in got["stdout"]
    np.testing.assert_array_equal(got["vertices"], direct_fine["vertices"][order])
    np.testing.assert_array_equal(got["triangles"], shuffled)
    ref = dict(direct_fine)
    for field in ("u1", "u2", "lambda"):
        ref[field] = direct_fine[field][order]
    assert_same_solution(got, ref, "shuffled mesh file")
    assert got["summary"]["newton_iterations"] <= 8
