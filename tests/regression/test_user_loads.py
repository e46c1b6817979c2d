"""Users' own data: loads as formulas and from HDF5 files, exact solutions on a Gmsh disk, Gmsh
files as Gmsh writes them.

- The paper's `bbbv` loads written as formulas reproduce the built-in case to round-off:
  solution and every estimator (the data oscillation integrates the formula).
- Nodal loads from a file: a linear load is its own P1 interpolant, so the file run (values on
  the coarse or on the finest mesh) must agree with the formula run to round-off.
- Bad formulas, bad files and non-disk meshes with `exact` are bad input (exit 2, nothing
  written), with the column, the point or the vertex in the message.
- A Gmsh mesh whose coarse level has no interior vertex (two triangles, as users start from):
  nested iteration and multigrid begin on the first level with unknowns, and every method
  reaches the direct solution.
"""
from __future__ import annotations

import math

import h5py
import numpy as np
import pytest

from twomem_testlib import SOURCE, out_file, result, run

PAPER = SOURCE / "input" / "paper_p1.nml"
DISK_GMSH = SOURCE / "input" / "meshes" / "disk_gmsh.msh"
LSHAPE = SOURCE / "input" / "meshes" / "lshape.msh"
UNUSED = SOURCE / "tests" / "data" / "meshes" / "unused_nodes.msh"

# the bbbv data (docs/method.md §4): mu = 1, g = 0.05, r0 = 1/sqrt(2),
# c = g sqrt(2)/(sqrt(2) - 1); f1 = -10g inside r0, -8g outside; f2 = -6g inside,
# -c(1 + 8r - 18r^2)/r outside
R0 = "1/sqrt(2)"
C = "0.05*sqrt(2)/(sqrt(2) - 1)"
BBBV_F1 = f"(r <= {R0})*(-10*0.05) + (r > {R0})*(-8*0.05)"
BBBV_F2 = f"(r <= {R0})*(-6*0.05) + (r > {R0})*(-{C}*(1 + 8*r - 18*r^2)/r)"


def fields(path):
    with h5py.File(path, "r") as f:
        out = {k: f[f"solution/{k}"][()] for k in ("u1", "u2", "lambda")}
        for name in f["estimators"]:
            out[f"estimators/{name}"] = f[f"estimators/{name}"][()]
        out["eta_total"] = f["summary"].attrs["eta_total"]
    return out


def assert_same(a, b, rtol, what):
    for key in a:
        x, y = np.asarray(a[key]), np.asarray(b[key])
        scale = max(float(np.max(np.abs(x))), 1e-300)
        assert np.max(np.abs(x - y)) <= rtol * scale, f"{what}: {key} differs by {np.max(np.abs(x - y)):.3e}"


def test_bbbv_as_formulas_reproduces_builtin():
    builtin, formula = out_file("bbbv_builtin.h5"), out_file("bbbv_formula.h5")
    common = ("mesh.levels=1", "newton.initial=nested", "estimate.every=0")
    run(*common, f"output.file={builtin}", case=PAPER)
    proc = run(*common, f"output.file={formula}", "problem.exact=none", "problem.mu1=1", "problem.mu2=1",
               "problem.g=0.05", f"problem.f1={BBBV_F1}", f"problem.f2={BBBV_F2}", case=PAPER)
    assert "problem: user" in proc.stdout
    a, b = fields(builtin), fields(formula)
    # the built-in case computes r with norm2, the formula with sqrt(x^2 + y^2): round-off
    assert_same(a, b, 1e-11, "bbbv as formulas")
    # and the estimators include a data oscillation that the formula must reproduce: nonzero
    assert np.max(a["estimators/eta_osc"]) > 1e-6


def test_formula_parse_error_names_column():
    target = out_file("never.h5")
    proc = run("problem.exact=none", "problem.f1=2*x + sin(y", f"output.file={target}", check_rc=2)
    assert "f1 formula '2*x + sin(y': column" in proc.stderr
    assert "expected ')'" in proc.stderr
    assert not target.exists()


def test_nonfinite_formula_names_point():
    target = out_file("never.h5")
    proc = run("problem.exact=none", "mesh.domain=square", "mesh.levels=0", "mesh.coarse_h=0.5",
               "mesh.boundary_h=0", "problem.f2=log(x + 0.5)", f"output.file={target}", check_rc=2)
    line = proc.stderr.strip()
    assert line.startswith("twomem: error: problem.f2: not finite at the quadrature point (x, y) = ("), line
    assert line.endswith("formula 'log(x + 0.5)': log of a number <= 0"), line
    x = float(line.split("= (")[1].split(",")[0])
    assert x <= -0.5
    assert not target.exists()


def write_loads(path, xy, values, with_coordinates=True):
    with h5py.File(path, "w") as f:
        f["loads/f1"] = values
        if with_coordinates:
            f["mesh/vertices"] = xy


@pytest.mark.parametrize("where", ["coarse", "finest"])
def test_file_loads_match_formula(where):
    # a linear load: the P1 interpolant is the load itself
    formula = "-0.5 + 0.3*x - 0.2*y"
    # a fixed boundary spacing: the automatic one depends on mesh.levels, and the coarse mesh
    # of the levels=0 run must be that of the levels=1 runs
    base = ("problem.exact=none", "mesh.levels=1", "mesh.boundary_h=0.25", "estimate.enabled=.false.")
    ref = out_file(f"file_ref_{where}.h5")
    run(*base, f"problem.f1={formula}", f"output.file={ref}")
    mesh_run = out_file(f"file_mesh_{where}.h5")
    levels = "mesh.levels=0" if where == "coarse" else "mesh.levels=1"
    run("problem.exact=none", levels, "mesh.boundary_h=0.25", "estimate.enabled=.false.", f"output.file={mesh_run}")
    xy = result(mesh_run)["vertices"]
    loads = out_file(f"loads_{where}.h5")
    write_loads(loads, xy, -0.5 + 0.3 * xy[:, 0] - 0.2 * xy[:, 1])
    got = out_file(f"file_got_{where}.h5")
    run(*base, f"problem.f1_file={loads}:/loads/f1", f"output.file={got}")
    a, b = result(ref), result(got)
    for key in ("u1", "u2", "lambda"):
        assert np.max(np.abs(a[key] - b[key])) <= 1e-12 * np.max(np.abs(a[key])), key


def test_file_loads_checked():
    mesh_run = out_file("file_mesh_check.h5")
    run("problem.exact=none", "mesh.levels=0", "mesh.boundary_h=0.25", "estimate.enabled=.false.",
        f"output.file={mesh_run}")
    xy = result(mesh_run)["vertices"]
    target = out_file("never.h5")
    base = ("problem.exact=none", "mesh.levels=1", "mesh.boundary_h=0.25", f"output.file={target}")

    short = out_file("loads_short.h5")
    write_loads(short, xy[:-1], np.zeros(len(xy) - 1), with_coordinates=False)
    proc = run(*base, f"problem.f1_file={short}:/loads/f1", check_rc=2)
    assert f"{len(xy) - 1} values, but the coarse mesh has {len(xy)} vertices and the finest" in proc.stderr

    moved = out_file("loads_moved.h5")
    shifted = xy.copy()
    shifted[3] += 0.01
    write_loads(moved, shifted, np.zeros(len(xy)))
    proc = run(*base, f"problem.f2_file={moved}:/loads/f1", check_rc=2)
    assert "problem.f2_file" in proc.stderr and "vertex 3 (0-based) lies at" in proc.stderr

    proc = run(*base, f"problem.f1_file={moved}:/loads/nothing", check_rc=2)
    assert "no dataset '/loads/nothing'" in proc.stderr

    bad = out_file("loads_nan.h5")
    values = np.zeros(len(xy))
    values[5] = np.nan
    write_loads(bad, xy, values)
    proc = run(*base, f"problem.f1_file={bad}:/loads/f1", check_rc=2)
    assert "value 5 (0-based) is not finite" in proc.stderr
    assert not target.exists()


def test_radial_on_gmsh_disk_reports_error_and_effectivity():
    target = out_file("radial_gmsh.h5")
    proc = run("mesh.domain=gmsh", f"mesh.file={DISK_GMSH}", "mesh.levels=0", f"output.file={target}")
    assert "energy error:" in proc.stdout and "effectivity:" in proc.stdout
    r = result(target)
    # the boundary of this mesh lies on the circle, so the exact solution's trace is exact there
    radius = np.hypot(r["vertices"][:, 0], r["vertices"][:, 1])
    assert np.max(radius) <= 1 + 1e-12
    energy = r["summary"]["energy_error"]
    assert math.isclose(energy, float(np.sqrt(np.sum(r["energy"] ** 2))), rel_tol=1e-12)
    # P1 on h ≈ 0.06: a few 1e-3, as on the built-in disk of that size
    assert 1e-3 < energy < 1e-2
    eff = r["summary"]["effectivity"]
    assert 0.95 < eff < 1.3, eff
    printed = float(proc.stdout.split("effectivity:")[1].split()[0])
    assert math.isclose(printed, eff, rel_tol=1e-3)


def test_exact_refused_off_the_disk():
    target = out_file("never.h5")
    proc = run("mesh.domain=gmsh", f"mesh.file={LSHAPE}", "mesh.levels=0", "problem.exact=bbbv",
               f"output.file={target}", check_rc=2)
    assert "problem.exact='bbbv' needs a mesh of the unit disk" in proc.stderr
    assert "is not on the unit circle" in proc.stderr
    assert not target.exists()


def test_gmsh_unused_nodes_dropped_with_a_note():
    target = out_file("unused_nodes.h5")
    proc = run("mesh.domain=gmsh", f"mesh.file={UNUSED}", "mesh.levels=2", "problem.exact=none",
               "newton.initial=paper", "estimate.enabled=.false.", f"output.file={target}")
    assert proc.stdout.count("note: 2 nodes used by no triangle dropped") == 1
    assert result(target)["summary"]["nv"] == 25


def test_coarse_mesh_without_interior_vertex():
    # unused_nodes.msh: a square of two triangles; level 0 has no unknown, level 1 one
    common = ("mesh.domain=gmsh", f"mesh.file={UNUSED}", "mesh.levels=3", "problem.exact=none",
              "newton.tol=1e-12", "gmres.rtol=1e-13")
    reference = out_file("coarse_empty_direct.h5")
    run(*common, "newton.linear=direct", "newton.initial=paper", f"output.file={reference}")
    ref = result(reference)
    for linear in ("gmres", "adaptive"):
        target = out_file(f"coarse_empty_{linear}.h5")
        proc = run(*common, f"newton.linear={linear}", "gmres.precond=mg", "newton.initial=nested",
                   f"output.file={target}")
        assert "nested: levels 0..0 have no interior vertex" in proc.stdout
        got = result(target)
        scale = np.max(np.abs(ref["u1"]))
        tol = 1e-8 if linear == "gmres" else 1e-4  # adaptive stops at the discretization error
        for key in ("u1", "u2"):
            assert np.max(np.abs(got[key] - ref[key])) <= tol * scale, f"{linear}: {key}"


def test_formula_example_runs():
    target = out_file("formula_gmsh.h5")
    proc = run("mesh.levels=0", f"output.file={target}", case=SOURCE / "input" / "formula_gmsh.nml",
               cwd=SOURCE)
    assert "status: converged" in proc.stdout
    r = result(target)
    assert np.any(r["lambda"] > 0), "the example's loads bring the membranes into contact"
