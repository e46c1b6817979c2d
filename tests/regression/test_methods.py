"""Every Newton variant reaches the same discrete solution, and nested iteration keeps the
Newton count on the finest level bounded.

The reference is exact Newton-min (UMFPACK). Fischer–Burmeister and GMRES (with the
multigrid block-elimination preconditioner or ILU(0), the default forcing 'finish') change the path,
not the discrete problem: their solutions must agree with it to 1e-8. All runs use
newton.tol = 1e-12: a residual of 1e-10 in a multiplier row is divided by the lumped mass
|ω_a|/3 ~ h², which leaves λ only ~1e-8 accurate at the default. With multigrid, GMRES needs at
most 20 iterations per Newton step, on every mesh.
"""
from __future__ import annotations

import numpy as np
import pytest

from twomem_testlib import SOURCE, out_file, result, run

CASES = {
    "radial": (SOURCE / "input" / "default.nml", ["mesh.levels=2"]),
    "bbbv": (SOURCE / "input" / "paper_p1.nml", []),
    "gmsh_lshape": (SOURCE / "input" / "default.nml",
                    ["problem.exact=none", "mesh.domain=gmsh", "mesh.levels=1",
                     f"mesh.file={SOURCE / 'input' / 'meshes' / 'lshape.msh'}",
                     "problem.f1=-1", "problem.f2=1"]),
    "gmsh_hole": (SOURCE / "input" / "default.nml",
                  ["problem.exact=none", "mesh.domain=gmsh", "mesh.levels=2",
                   f"mesh.file={SOURCE / 'input' / 'meshes' / 'square_hole.msh'}",
                   "problem.mu1=3", "problem.mu2=0.5", "problem.f1=-2", "problem.f2=1"]),
}
METHODS = [("min", "gmres", "mg"), ("min", "gmres", "ilu0"), ("fb", "direct", "mg"), ("fb", "gmres", "mg"),
           ("fb", "gmres", "ilu0")]


def solve(case: str, cfun: str, linear: str, precond: str = "mg", *extra: str) -> dict:
    nml, args = CASES[case]
    path = out_file(f"methods/{case}_{cfun}_{linear}_{precond}.h5")
    run(*args, f"newton.cfun={cfun}", f"newton.linear={linear}", f"gmres.precond={precond}", "newton.tol=1e-12",
        "gmres.rtol=1e-13", *extra, f"output.file={path}", case=nml)
    return result(path)


@pytest.mark.parametrize("cfun,linear,precond", METHODS)
@pytest.mark.parametrize("case", sorted(CASES))
def test_method_reaches_the_direct_newton_min_solution(case, cfun, linear, precond):
    ref = solve(case, "min", "direct")
    got = solve(case, cfun, linear, precond)
    assert ref["status"] == got["status"] == "converged"
    for field in ("u1", "u2", "lambda"):
        diff = np.max(np.abs(got[field] - ref[field]))
        print(f"{case} {cfun}/{linear}/{precond} {field}: max diff {diff:.2e}")
        assert diff <= 1e-8, f"{field} differs by {diff:.3e}"
    if linear == "gmres" and precond == "mg":
        per_step = got["summary"]["gmres_iterations"] / max(1, got["summary"]["newton_iterations"])
        print(f"{case} {cfun}: {per_step:.1f} GMRES iterations per Newton step")
        assert per_step <= 20


@pytest.mark.parametrize("cfun", ["min", "fb"])
def test_multigrid_iterations_do_not_grow_with_the_mesh(cfun):
    """GMRES to 1e-10 with the multigrid preconditioner: the same handful of iterations per
    Newton step from 12k to 190k vertices, and nested iteration leaves few Newton steps for
    the finest level (measured: min 3, 2, 1; Fischer–Burmeister 4, 3, 2 with its active-set
    step, 7 at 12k vertices without it)."""
    per_step = []
    for levels in range(1, 4):
        path = out_file(f"methods/mg_growth_{cfun}_{levels}.h5")
        run(f"mesh.levels={levels}", "mesh.coarse_h=0.05", "mesh.boundary_h=0.01", "problem.exact=none",
            "problem.mu1=2", "problem.mu2=0.5", "problem.f1=-2", "problem.f2=1", f"newton.cfun={cfun}",
            "newton.linear=gmres", "gmres.forcing=fixed", "estimate.enabled=.false.", "output.history=.false.",
            f"output.file={path}")
        s = result(path)["summary"]
        assert s["newton_iterations"] <= (6 if cfun == "min" else 5), s
        per_step.append(s["gmres_iterations"] / max(1, s["newton_iterations"]))
    print(f"{cfun}: GMRES iterations per Newton step on levels 1..3: {per_step}")
    assert max(per_step) <= 12, per_step
    assert per_step[-1] <= per_step[0] + 3, per_step


@pytest.mark.parametrize("levels,most", [(2, 5), (3, 4)])
def test_fischer_burmeister_finishes_like_newton_min(levels, most):
    """bench/scaling.py's `membranes` case with the paper's forcing. Fischer–Burmeister alone
    took 7 finest-level Newton steps at both sizes (18k and 72k vertices): after the contact
    set settles, its quadratic convergence has a constant ~1/|(u1 − u2, λ)| of the solution,
    which is ~h² on the first free layer beside the contact zone, and the tail took 4–5 steps.
    Active-set steps once an FB step moves at most 1% of the contact set finish as Newton-min
    does: 5 and 4 steps, measured with 1 and 2 threads, debug and release builds (6 and 4 when
    they waited for an FB step that moved no vertex)."""
    path = out_file(f"methods/fb_finish_{levels}.h5")
    run("mesh.coarse_h=0.1", "mesh.boundary_h=0.02", f"mesh.levels={levels}", "problem.exact=none",
        "problem.mu1=2", "problem.mu2=0.5", "problem.f1=-2", "problem.f2=1", "problem.g=0.05", "newton.cfun=fb",
        "newton.linear=gmres", "estimate.enabled=.false.", "output.history=.false.", "output.fields=.false.",
        f"output.file={path}")
    s = result(path)["summary"]
    assert s["newton_iterations"] <= most, s


def test_forcing_finish_ends_the_last_linear_solve():
    """gmres.forcing = 'finish' (the default) against the paper's test, Newton-min with
    multigrid GMRES checked after every iteration on the membranes case at 72k vertices: once
    the GMRES iterate takes the Newton step's contact set, 'paper' stops at the first check (the
    algebraic and linearization residuals are then the same vector) and leaves the rest of the
    solve to further Newton steps; 'finish' goes on to newton.tol. Measured: 3 finest-level
    Newton steps against 8, and the same solution."""
    common = ("mesh.coarse_h=0.1", "mesh.boundary_h=0.02", "mesh.levels=3", "problem.exact=none", "problem.mu1=2",
              "problem.mu2=0.5", "problem.f1=-2", "problem.f2=1", "problem.g=0.05", "newton.linear=gmres",
              "estimate.enabled=.false.", "output.history=.false.")
    got = {}
    for forcing in ("paper", "finish"):
        path = out_file(f"methods/forcing_{forcing}.h5")
        run(*common, f"gmres.forcing={forcing}", f"output.file={path}")
        got[forcing] = result(path)
        assert got[forcing]["status"] == "converged"
    steps = {k: int(v["summary"]["newton_iterations"]) for k, v in got.items()}
    assert steps["finish"] <= steps["paper"] - 2, steps
    for name in ("u1", "u2"):
        assert np.allclose(got["finish"][name], got["paper"][name], rtol=0, atol=1e-9), name


def test_fischer_burmeister_checks_every_gmres_iteration():
    """With the active-set finish (the default), Fischer–Burmeister's inexact GMRES checks its
    stopping test after every iteration, as Newton-min's does: bench/scaling.py's bbbv case at
    7.2e4 vertices takes 4 finest-level Newton steps with 8 GMRES iterations, against 14 with a
    check every third iteration (estimate.every = 3), and reaches the same solution. Pure FB
    (newton.fb_finish = 'none') keeps ν = 3: with ν = 1 its inexact steps wander between contact
    sets (5 finest-level Newton steps on the membranes case at 7.2e4 vertices instead of 2)."""
    common = ("mesh.coarse_h=0.1", "mesh.boundary_h=0.02", "mesh.levels=3", "newton.cfun=fb",
              "newton.linear=gmres", "estimate.enabled=.false.", "output.history=.false.", "output.xdmf=.false.")
    got = {}
    for every in (0, 3):
        path = out_file(f"methods/fb_every_{every}.h5")
        run(*common, "problem.exact=bbbv", f"estimate.every={every}", f"output.file={path}")
        got[every] = result(path)
        assert got[every]["status"] == "converged"
    counts = {k: (int(v["summary"]["newton_iterations"]), int(v["summary"]["gmres_iterations"]))
              for k, v in got.items()}
    assert counts[0][0] <= 5 and counts[0][1] <= 10, counts
    assert counts[3][1] >= counts[0][1] + 4, counts
    for name in ("u1", "u2"):
        assert np.allclose(got[0][name], got[3][name], rtol=0, atol=1e-9), name
    path = out_file("methods/fb_every_pure.h5")
    run(*common, "problem.exact=none", "problem.mu1=2", "problem.mu2=0.5", "problem.f1=-2", "problem.f2=1",
        "problem.g=0.05", "newton.fb_finish=none", f"output.file={path}")
    assert int(result(path)["summary"]["newton_iterations"]) <= 3


def test_fb_finish_none_is_fischer_burmeister_throughout():
    """newton.fb_finish = 'none' keeps the paper's method: FB at every step, so the tail after
    the contact set settles is back (7 finest-level steps on the membranes case at 18k
    vertices, against at most 6 with the active-set steps), and both reach the same solution."""
    common = ("mesh.coarse_h=0.1", "mesh.boundary_h=0.02", "mesh.levels=2", "problem.exact=none", "problem.mu1=2",
              "problem.mu2=0.5", "problem.f1=-2", "problem.f2=1", "problem.g=0.05", "newton.cfun=fb",
              "newton.linear=gmres", "estimate.enabled=.false.", "output.history=.false.")
    fields = {}
    for finish in ("active_set", "none"):
        path = out_file(f"methods/fb_finish_word_{finish}.h5")
        run(*common, f"newton.fb_finish={finish}", f"output.file={path}")
        fields[finish] = result(path)
    steps = {k: int(v["summary"]["newton_iterations"]) for k, v in fields.items()}
    assert steps["none"] >= steps["active_set"] + 1, steps
    for name in ("u1", "u2"):
        assert np.allclose(fields["none"][name], fields["active_set"][name], rtol=0, atol=1e-9), name


def test_nested_iteration_bounds_newton_on_the_finest_level():
    counts = []
    for levels in range(1, 5):
        path = out_file(f"methods/nested_{levels}.h5")
        run(f"mesh.levels={levels}", "mesh.coarse_h=0.5", "problem.exact=bbbv", "newton.initial=nested",
            "newton.linear=direct", "output.history=.false.", f"output.file={path}")
        counts.append(int(result(path)["summary"]["newton_iterations"]))
    print(f"Newton steps on the finest level, levels 1..4: {counts}")
    assert max(counts) <= 4, counts


@pytest.mark.parametrize("data", [["problem.f1=-5", "problem.f2=5"],
                                  ["problem.mu1=100", "problem.mu2=0.01", "problem.f1=-1", "problem.f2=1"]])
def test_line_search_does_not_slow_fischer_burmeister(data):
    """The globalization must not cost convergence where full steps work. A line search on
    the weak (h²-scaled) residual once took 30 steps instead of 10, or stalled: from (g, 0, 0)
    the weak residual is tiny and every useful step looks like an increase."""
    steps = {}
    for ls in ("on", "off"):
        path = out_file(f"methods/fb_ls_{ls}.h5")
        run("mesh.levels=2", "newton.initial=paper", "newton.cfun=fb", f"newton.line_search={ls}",
            "newton.linear=direct", *data, "output.history=.false.", f"output.file={path}")
        steps[ls] = int(result(path)["summary"]["newton_iterations"])
    print(f"{data}: Newton steps with line search {steps['on']}, without {steps['off']}")
    assert steps["on"] <= steps["off"] + 2, steps
