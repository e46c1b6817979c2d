"""twomem's solutions solve the discrete problem, checked by an independent numpy assembly.

What is checked, for runs on Gmsh meshes (non-convex L-shape, a square with a hole, a disk; each
as read and once red-refined, one case with unequal tensions) and on the built-in square and
disk, all with `newton.linear = 'direct'` and data that produce both contact and non-contact:

* the first two block rows of the discrete problem (docs/method.md §1) at every interior vertex a:
      r1(a) = μ1 (S u1)(a) − |ω_a|/3 λ(a) − f1 |ω_a|/3,
      r2(a) = μ2 (S u2)(a) + |ω_a|/3 λ(a) − f2 |ω_a|/3,
  with S applied to the full nodal vectors (boundary values included: the lifting of g), are
  round-off;
* complementarity min(u1 − u2, λ) = 0 at interior vertices (u1 − u2 ≥ 0, λ ≥ 0, one of them
  zero), with a non-empty contact set and a non-empty non-contact set;
* the boundary conditions u1 = g, u2 = 0, λ = 0, exactly, on the boundary;
* for a `radial` run, the per-element energy error `/error/energy` and its total, recomputed
  from the closed-form solution.

Why it is independent of twomem: only the result file's mesh (/mesh/vertices, /mesh/triangles)
and its `input` attribute (μ, f, g) are used. The P1 stiffness, the lumped mass |ω_a|/3, the
loads F_α(a) = f_α |ω_a|/3 (exact for constant f), the boundary vertices (vertices of edges
that belong to exactly one triangle: twomem's own boundary flags are not read), the radial
closed form (contact radius by bisection) and the quadrature (Dunavant's 12-point degree-6 rule,
on red subtriangles where the kink of the exact gradient needs it; twomem uses a 16-point
degree-8 rule) are all rebuilt in numpy in p1_numpy.py.
"""
from __future__ import annotations

import functools

import numpy as np
import pytest

import p1_numpy as p1np
from twomem_testlib import SOURCE, out_file, result, run

# Data that produce contact on every domain used here: u1 is pushed down, u2 up, and
# D = f2/μ2 − f1/μ1 = 2 is far above the no-contact threshold (≈ 4g on a disk of radius 1).
CONTACT = ("problem.f1=-1", "problem.f2=1", "problem.g=0.05")

# name -> (overrides, number of boundary curves of the domain)
CASES = {
    "lshape_l0": ((*CONTACT, "mesh.domain=gmsh", "mesh.file={meshes}/lshape.msh", "mesh.levels=0"), 1),
    "lshape_l1": ((*CONTACT, "mesh.domain=gmsh", "mesh.file={meshes}/lshape.msh", "mesh.levels=1"), 1),
    "square_hole_l0": ((*CONTACT, "mesh.domain=gmsh", "mesh.file={meshes}/square_hole.msh",
                        "mesh.levels=0"), 2),
    "square_hole_l1": ((*CONTACT, "mesh.domain=gmsh", "mesh.file={meshes}/square_hole.msh",
                        "mesh.levels=1"), 2),
    "disk_gmsh_l0": ((*CONTACT, "mesh.domain=gmsh", "mesh.file={meshes}/disk_gmsh.msh", "mesh.levels=0"), 1),
    "disk_gmsh_l1": ((*CONTACT, "mesh.domain=gmsh", "mesh.file={meshes}/disk_gmsh.msh", "mesh.levels=1"), 1),
    # unequal tensions: D = 0.5/0.5 + 0.6/2 = 1.3
    "lshape_l1_mu": (("problem.mu1=2", "problem.mu2=0.5", "problem.f1=-0.6", "problem.f2=0.5",
                      "problem.g=0.05", "mesh.domain=gmsh", "mesh.file={meshes}/lshape.msh",
                      "mesh.levels=1"), 1),
    # built-in meshes, default loads f1 = −0.25, f2 = 0.25, g = 0.05
    "square_builtin": (("mesh.domain=square", "mesh.coarse_h=0.1", "mesh.levels=1"), 1),
    "disk_builtin": (("mesh.domain=disk", "mesh.levels=2"), 1),
}

# Relative round-off bounds (see the comments at their use).
EQ_RTOL = 1e-10
COMPL_RTOL = 1e-12


@functools.lru_cache(maxsize=None)
def solve(name: str) -> dict:
    """Run twomem on a case once per session; return the result file and its P1 assembly."""
    overrides, _ = CASES[name]
    meshes = str(SOURCE / "input" / "meshes")
    out = out_file(f"discrete/{name}.h5")
    out.parent.mkdir(parents=True, exist_ok=True)
    out.unlink(missing_ok=True)
    run(*(o.format(meshes=meshes) for o in overrides), "problem.exact=none",
        "newton.linear=direct", f"output.file={out}")
    res = result(out)
    res["p1"] = p1np.assemble(res["vertices"], res["triangles"])
    res["data"] = p1np.parse_namelist(res["input"])["problem"]
    return res


def residuals(res: dict):
    """(r1, r2, scale1, scale2, cw1, cw2) at all vertices (only interior entries are meaningful).

    scale_α is a normwise bound of the size of the terms forming r_α; cw_α is the componentwise
    size Σ_K Σ_b μ|S_K,ab||u_b| + |ω_a|/3 |λ(a)| + |F_α(a)|, used for reporting.
    """
    p, d = res["p1"], res["data"]
    u1, u2, lam = res["u1"], res["u2"], res["lambda"]
    mu1, mu2, f1, f2 = (float(d[k]) for k in ("mu1", "mu2", "f1", "f2"))
    m = p.mass
    r1 = mu1 * p.apply(u1) - m * lam - f1 * m
    r2 = mu2 * p.apply(u2) + m * lam - f2 * m
    # Normwise scale (Rigal–Gaches / Oettli–Prager style): a backward-stable direct solve gives
    # ‖r‖_∞ ≤ c ε (‖A‖_∞‖x‖_∞ + ‖b‖_∞) with c a modest growth factor, so we bound
    # max|r_α| by EQ_RTOL · (μ_α ‖S‖_∞ max|u_α| + max(|ω|/3) max|λ| + max|F_α|). ‖S‖_∞ is O(1)
    # on shape-regular meshes while the mass and load terms are O(h²), so consistency errors
    # show up at O(h²) relative: scaling the lumped mass by 1.01 already gives ~2e-5 on these
    # meshes (a consistent mass, a missing lifting or a wrong sign give far more), five orders
    # above EQ_RTOL = 1e-10, while round-off (observed ~2e-16) is six orders below it.
    snorm = np.max(p.row_abs_sum())
    mmax = np.max(m)
    scale1 = mu1 * snorm * np.max(np.abs(u1)) + mmax * np.max(np.abs(lam)) + abs(f1) * mmax
    scale2 = mu2 * snorm * np.max(np.abs(u2)) + mmax * np.max(np.abs(lam)) + abs(f2) * mmax
    cw1 = mu1 * p.apply_abs(u1) + m * np.abs(lam) + abs(f1) * m
    cw2 = mu2 * p.apply_abs(u2) + m * np.abs(lam) + abs(f2) * m
    return r1, r2, scale1, scale2, cw1, cw2


@pytest.mark.parametrize("name", CASES)
def test_mesh_and_boundary(name):
    """The mesh is a valid triangulation with the expected boundary, and u1 = g, u2 = λ = 0 there."""
    res = solve(name)
    p, d = res["p1"], res["data"]
    _, n_curves = CASES[name]
    assert p.nv == int(res["summary"]["nv"]) and p.nt == int(res["summary"]["nt"])
    assert res["u1"].shape == res["u2"].shape == res["lambda"].shape == (p.nv,)
    assert res["triangles"].min() == 0 and res["triangles"].max() == p.nv - 1
    assert np.all(np.bincount(p.triangles.ravel(), minlength=p.nv) > 0), "unused vertices"
    assert np.all(p.area > 1e-12 * np.max(p.area)), "degenerate triangles"
    assert p.boundary_components() == n_curves
    b = p.boundary
    assert 0 < b.sum() < p.nv
    # boundary values are prescribed, not computed: exact equality
    assert np.all(res["u1"][b] == d["g"]), np.max(np.abs(res["u1"][b] - d["g"]))
    assert np.all(res["u2"][b] == 0.0) and np.all(res["lambda"][b] == 0.0)


def test_refinement_is_red():
    """levels=1 is one red refinement of the Gmsh mesh: 4× the triangles, same boundary curves,
    every new vertex a midpoint of a coarse edge."""
    for mesh in ("lshape", "square_hole", "disk_gmsh"):
        c, f = solve(f"{mesh}_l0"), solve(f"{mesh}_l1")
        pc, pf = c["p1"], f["p1"]
        assert pf.nt == 4 * pc.nt
        assert pf.nv == pc.nv + pc.n_edges
        assert pf.n_boundary_edges == 2 * pc.n_boundary_edges
        expected = np.concatenate([pc.vertices, pc.vertices[pc.edges].mean(axis=1)])
        key = lambda v: np.unique(np.round(v / 1e-11).astype(np.int64), axis=0)  # noqa: E731
        assert np.array_equal(key(pf.vertices), key(expected))
        # the total area is unchanged (boundary vertices stay where they are)
        assert np.isclose(pf.area.sum(), pc.area.sum(), rtol=1e-13)


@pytest.mark.parametrize("name", CASES)
def test_equations(name):
    """μ1 S u1 − D λ = F1 and μ2 S u2 + D λ = F2 at interior vertices, to round-off."""
    res = solve(name)
    inner = ~res["p1"].boundary
    r1, r2, s1, s2, cw1, cw2 = residuals(res)
    e1, e2 = np.max(np.abs(r1[inner])), np.max(np.abs(r2[inner]))
    print(f"{name}: max|r1|/scale = {e1 / s1:.2e}, max|r2|/scale = {e2 / s2:.2e}, "
          f"componentwise {np.max(np.abs(r1[inner]) / cw1[inner]):.2e}, "
          f"{np.max(np.abs(r2[inner]) / cw2[inner]):.2e}")
    assert e1 <= EQ_RTOL * s1, (e1, s1)
    assert e2 <= EQ_RTOL * s2, (e2, s2)
    # the check is not vacuous: the contact force and the lifting of g are each far above the bound
    m, lam = res["p1"].mass, res["lambda"]
    assert np.max(m[inner] * np.abs(lam[inner])) > 1e4 * EQ_RTOL * max(s1, s2)
    u1_no_lift = np.where(res["p1"].boundary, 0.0, res["u1"])
    r1_no_lift = float(res["data"]["mu1"]) * res["p1"].apply(u1_no_lift) - m * lam \
        - float(res["data"]["f1"]) * m
    assert np.max(np.abs(r1_no_lift[inner])) > 1e4 * EQ_RTOL * s1


@pytest.mark.parametrize("name", CASES)
def test_complementarity(name):
    """min(u1 − u2, λ) = 0 at interior vertices; both contact and non-contact occur."""
    res = solve(name)
    inner = ~res["p1"].boundary
    a = (res["u1"] - res["u2"])[inner]
    lam = res["lambda"][inner]
    # Each side is relative to its own size: in the active (contact) rows twomem solves
    # u1 − u2 = 0 and in the inactive rows λ = 0, so the exact zeros are round-off of a
    # backward-stable solve of quantities of size max|u| and max|λ|: 1e-12 leaves room for the
    # growth factor and stays far below any real discretization quantity.
    tol_a = COMPL_RTOL * max(np.max(np.abs(res["u1"])), np.max(np.abs(res["u2"])))
    tol_l = COMPL_RTOL * np.max(np.abs(lam))
    c = np.minimum(a / tol_a, lam / tol_l)  # in units of the tolerances
    contact = a <= tol_a
    print(f"{name}: min(u1-u2) = {a.min():.2e} (tol {tol_a:.1e}), min λ = {lam.min():.2e} "
          f"(tol {tol_l:.1e}), max|min(a,λ)|/tol = {np.max(np.abs(c)):.2e}, "
          f"contact {contact.sum()} of {inner.sum()}")
    assert a.min() >= -tol_a
    assert lam.min() >= -tol_l
    assert np.max(np.abs(c)) <= 1.0
    assert contact.sum() > 0, "no contact"
    assert (~contact).sum() > 0, "contact everywhere"
    assert np.max(lam) > 0.0


# ----------------------------------------------------------------------------------------------
# energy error of the radial case, recomputed
# ----------------------------------------------------------------------------------------------
def _min_radius(corners: np.ndarray) -> np.ndarray:
    """Distance from the origin to each triangle (nt, 3, 2) (0 if the origin is inside)."""
    dmin = np.full(corners.shape[0], np.inf)
    side = []
    for i in range(3):  # three edges, vectorized over triangles
        p, q = corners[:, i], corners[:, (i + 1) % 3]
        e = q - p
        s = np.clip(-np.sum(p * e, axis=1) / np.sum(e * e, axis=1), 0.0, 1.0)
        dmin = np.minimum(dmin, np.linalg.norm(p + s[:, None] * e, axis=1))
        side.append(np.sign(e[:, 0] * (-p[:, 1]) - e[:, 1] * (-p[:, 0])))  # origin left of edge?
    inside = (side[0] == side[1]) & (side[1] == side[2])
    return np.where(inside, 0.0, dmin)


def test_quadrature_rule_exact_to_degree_6():
    """The 12-point rule (and its composite) integrates monomials x^i y^j, i + j ≤ 6, exactly on
    the reference triangle: ∫ x^i y^j = i! j! / (i + j + 2)!."""
    from math import factorial
    for bary, w in ((p1np.RULE12_BARY, p1np.RULE12_WEIGHTS), p1np.composite_rule(2)):
        x, y = bary[:, 1], bary[:, 2]
        for i in range(7):
            for j in range(7 - i):
                exact = factorial(i) * factorial(j) / factorial(i + j + 2)
                assert np.isclose(0.5 * np.sum(w * x**i * y**j), exact, rtol=1e-13, atol=0)


# Tolerances of the energy-error comparison.
# * Elements not crossed by the free boundary |x| = ρ: the exact gradient is smooth (rational)
#   there, so twomem's degree-8 rule and our degree-6 rule agree to quadrature accuracy,
#   observed ≈ 2e-10 relative per element at levels = 2.
ENERGY_RTOL_SMOOTH = 1e-8
# * The total. Across |x| = ρ the exact ∇w = (D/2)(1 − ρ²/r²) x has a kink, so the integrand
#   on the ~135 crossed elements is only C⁰ there and no fixed-point rule integrates it to better
#   than a few percent per element. Our reference integrates those elements with the 12-point
#   rule on 4⁵ red subtriangles (converged to ~4e-7 relative on the total). twomem splits an
#   element while its degree-8 and degree-5 rules disagree (relative 1e-8), which brings its
#   total to within ~5e-6 of ours (a single 16-point rule was off by 1.4e-4); the bounds
#   below would catch anything larger (wrong exact solution, wrong ρ, missing μ weights are
#   O(1e-2..1) effects).
ENERGY_RTOL_TOTAL = 2e-5
ENERGY_RTOL_CROSSED = 2e-3

RADIAL_CASES = {
    "default": ("mesh.levels=2",),
    # unequal tensions and f1 + f2 ≠ 0 (∇S ≠ 0): D = 0.5/0.5 + 0.6/2 = 1.3 > 4g
    "mu": ("mesh.levels=2", "problem.mu1=2", "problem.mu2=0.5", "problem.f1=-0.6", "problem.f2=0.5"),
}


@pytest.mark.parametrize("case", RADIAL_CASES)
def test_energy_error_radial(case):
    """/error/energy of a radial run (levels = 2) against an independent recomputation."""
    out = out_file(f"discrete/radial_{case}.h5")
    out.parent.mkdir(parents=True, exist_ok=True)
    out.unlink(missing_ok=True)
    run(*RADIAL_CASES[case], "newton.linear=direct", f"output.file={out}")
    res = result(out)
    d = p1np.parse_namelist(res["input"])["problem"]
    assert d["exact"] == "radial"
    mu1, mu2, f1, f2, g = (float(d[k]) for k in ("mu1", "mu2", "f1", "f2", "g"))
    p = p1np.assemble(res["vertices"], res["triangles"])

    def grad_exact(x):
        g1, g2, _ = p1np.radial_gradients(x, mu1, mu2, f1, f2, g)
        return g1, g2

    _, _, rho = p1np.radial_gradients(np.zeros((1, 2)), mu1, mu2, f1, f2, g)
    D = f2 / mu2 - f1 / mu1
    assert 0.0 < rho < 1.0
    assert np.isclose((D / 4) * (1 - rho**2 + 2 * rho**2 * np.log(rho)), g, rtol=1e-14)

    corners = p.vertices[p.triangles]
    rmax = np.max(np.linalg.norm(corners, axis=2), axis=1)  # |x| is convex: max at a vertex
    crossed = (_min_radius(corners) < rho) & (rmax > rho)
    assert 0 < crossed.sum() < p.nt // 10

    theirs = res["energy"]
    assert theirs.shape == (p.nt,) and np.all(theirs >= 0)
    total_theirs = float(res["summary"]["energy_error"])
    # /error/energy holds |||u − u_h|||_K (square roots); the total is the l2 sum of them
    assert np.isclose(total_theirs, np.sqrt(np.sum(theirs**2)), rtol=1e-12)

    # plain 12-point rule where the exact gradient is smooth: elementwise comparison
    mine = np.sqrt(p1np.energy_error_sq(p, res["u1"], res["u2"], grad_exact, p1np.RULE12_BARY,
                                        p1np.RULE12_WEIGHTS, mu1, mu2))
    # 12 points on 4⁵ red subtriangles on the crossed elements
    bary, w = p1np.composite_rule(5)
    kx = np.flatnonzero(crossed)
    mine[kx] = np.sqrt(p1np.energy_error_sq(p, res["u1"], res["u2"], grad_exact, bary, w, mu1, mu2,
                                            elements=kx))
    total_mine = np.sqrt(np.sum(mine**2))

    smooth = ~crossed
    diff = np.abs(mine - theirs)
    # elements with zero error (u exactly linear there) carry only round-off, and a square
    # root turns the round-off ε|∇u|²|K| of the squared error into ~1e-8|∇u||K|^½: measure
    # them against a floor of 1e-5 of the largest element error
    floor = 1e-5 * theirs.max()
    rel_smooth = np.max(diff[smooth] / np.maximum(theirs[smooth], floor))
    rel_crossed = np.max(diff[crossed] / theirs[crossed])
    share = np.sqrt(np.sum(mine[crossed] ** 2)) / total_mine
    print(f"radial[{case}]: rho = {rho:.15f}, {crossed.sum()} of {p.nt} elements crossed "
          f"(their share of the error {share:.2f}); elementwise rel. diff: smooth {rel_smooth:.2e}, "
          f"crossed {rel_crossed:.2e}; total mine {total_mine:.12e} twomem {total_theirs:.12e} "
          f"rel {total_theirs / total_mine - 1:.2e}; smooth part rel "
          f"{np.sqrt(np.sum(theirs[smooth]**2) / np.sum(mine[smooth]**2)) - 1:.2e}")
    assert rel_smooth <= ENERGY_RTOL_SMOOTH
    assert rel_crossed <= ENERGY_RTOL_CROSSED
    assert abs(total_theirs / total_mine - 1) <= ENERGY_RTOL_TOTAL
