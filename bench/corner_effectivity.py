#!/usr/bin/python3
"""Effectivity of the guaranteed bound at a re-entrant corner, against an independent reference.

    bench/setup_petsc.sh                                   # once: Debian's petsc4py, h5py, scipy
    .venv/bin/python bench/single_mesh.py --write-mesh 0.1 results/meshes/pacman_0.1.msh
    /usr/bin/python3 bench/corner_effectivity.py --mesh results/meshes/pacman_0.1.msh \
        --levels 0,1,2 --ref-levels 5 [--bounds paper,sharp --fluxes rt1,rt0]

The pacman domain (the unit disk without its first quadrant: a 270° corner at the origin) has
no closed-form solution. The reference is the same Gmsh mesh refined `--ref-levels` times by red
refinement here (numpy, bench/petsc_vi_problem.py: its own P1 assembly, not twomem's), solved
by PETSc's reduced-space VI Newton (CG + multigrid on the inactive set, nested iteration) to
1e-11. twomem solves the mesh refined k times for each k of `--levels` (exact Newton-min,
each `estimate.flux` and `estimate.bound` asked); its solution, interpolated onto the reference
mesh (the meshes are nested: red refinement keeps the polygon), gives
e_k = |||u_ref − u_k||| = (Σ_α μ_α ‖∇(u_ref,α − u_k,α)‖²)^½ exactly.

The reference has its own error δ = |||u − u_ref|||, which twomem's guaranteed η on the
reference mesh bounds (twomem runs on the reference mesh itself, multigrid GMRES and Newton to
1e-12, one per variant: the smallest η is δ's bound; the script prints how far their solutions
are from PETSc's). The true error
|||u − u_k||| then lies in [e_k − δ, e_k + δ] by the triangle inequality, and η_k over those
limits brackets the true effectivity: `eff low`/`eff high` with δ ≤ η_ref. For a linear
problem Galerkin orthogonality would give |||u − u_k|||² = e_k² + δ² exactly; `eff (orth.)`
uses that with δ = η_ref (an overestimate of δ, so it leans low). Problem data as the mesh
adaptivity issue's corner case: μ1 = μ2 = 1, f1 = −1, f2 = 0, g = 0.05 (change with --set).
"""
from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import petsc_vi  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
# the measured solves: exact Newton-min (UMFPACK), the discrete solution to round-off
EXACT = ["newton.linear=direct"]


def twomem(exe: Path, mesh: Path, levels: int, out: Path, extra: list[str], method: list[str]) -> dict:
    """twomem's solve of `mesh` refined `levels` times with `method` and its estimators."""
    case = ["mesh.domain=gmsh", f"mesh.file={mesh}", f"mesh.levels={levels}", "problem.exact=none",
            "problem.mu1=1", "problem.mu2=1", "problem.f1=-1", "problem.f2=0", "problem.g=0.05",
            *method, "output.xdmf=.false.", "output.estimators=.false."]
    cmd = [str(exe), "run", str(ROOT / "input" / "default.nml"), *case, *extra, f"output.file={out}"]
    proc = subprocess.run(cmd, capture_output=True, text=True)
    if proc.returncode != 0:
        petsc_vi.fail(f"twomem exited with {proc.returncode} ({' '.join(cmd[3:])}): "
                      f"{(proc.stderr or proc.stdout).strip().splitlines()[-1]}", 3)
    return petsc_vi.read_result(out)


def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--mesh", required=True, help="a Gmsh mesh of the domain (MSH 4.1 or 2.2 ASCII)")
    ap.add_argument("--levels", default="0,1,2", help="twomem's refinement levels to measure (comma list)")
    ap.add_argument("--ref-levels", type=int, default=5, help="refinements of the reference mesh")
    ap.add_argument("--bounds", default="paper,sharp", help="estimate.bound of twomem's runs (comma list)")
    ap.add_argument("--fluxes", default="rt1,rt0", help="estimate.flux of twomem's runs (comma list)")
    ap.add_argument("--set", action="append", default=[], help="a further twomem override (repeatable)")
    ap.add_argument("--twomem", default=str(ROOT / "build" / "release" / "twomem"))
    ap.add_argument("--check", action="store_true",
                    help="exit 1 if twomem's solution on the reference mesh differs from PETSc's by more than 1e-8, "
                         "or a bound falls below the error by more than the reference's own error")
    args = ap.parse_args(argv)
    levels = [int(k) for k in args.levels.split(",")]
    if max(levels) >= args.ref_levels:
        petsc_vi.fail("--ref-levels must exceed every level of --levels", 2)
    os.environ["OMP_NUM_THREADS"] = os.environ["OPENBLAS_NUM_THREADS"] = "1"
    petsc_vi.import_numerics()
    np, problem = petsc_vi.np, petsc_vi.problem
    PETSc = petsc_vi.import_petsc([])
    exe = Path(args.twomem).resolve()
    mesh = Path(args.mesh).resolve()
    variants = [(flux, bound) for flux in args.fluxes.split(",") for bound in args.bounds.split(",")]
    case = petsc_vi.Case(0.0, 0.0, args.ref_levels, 1.0, 1.0, -1.0, 0.0, 0.05, mesh_file=str(mesh))

    meshes = [problem.read_gmsh(mesh)]
    for _ in range(args.ref_levels):
        meshes.append(problem.red_refine(meshes[-1]))
    lvs = [problem.assemble(m, case) for m in meshes]
    systems = [problem.vi_system(lv, case) for lv in lvs]
    tol = petsc_vi.Tolerances(newton_tol=1e-11, ksp_rtol=1e-12)
    petsc_vi.set_default_options(PETSc, petsc_vi.petsc_options(tol))
    PETSc.Log.begin()
    prolongations = [petsc_vi.interior_prolongation(lvs[l - 1], lvs[l]) for l in range(1, len(lvs))]
    x, stats, _ = petsc_vi.petsc_nested(PETSc, lvs, systems, case, tol, "gmg", prolongations)
    if stats[-1].reason is not None and "CONVERGED" not in str(stats[-1].reason):
        petsc_vi.fail(f"PETSc's reference solve did not converge: {stats[-1].reason}", 1)
    fine = lvs[-1]
    ref = problem.fields(fine, case, *problem.to_nodal(fine, x, case.g))
    print(f"reference: {mesh.name} refined {args.ref_levels} times, {fine.mesh.nv} vertices, PETSc VI "
          f"(vinewtonrsls, CG + GMG, nested) to 1e-11", flush=True)

    with tempfile.TemporaryDirectory(prefix="corner.") as tmp:
        # every bound is guaranteed: the smallest one on the reference mesh bounds δ
        delta, gap = float("inf"), 0.0
        for flux, bound in variants:
            top = twomem(exe, mesh, args.ref_levels, Path(tmp) / "ref.h5",
                         [f"estimate.bound={bound}", f"estimate.flux={flux}", *args.set], petsc_vi.TWOMEM_REFERENCE)
            perm, _ = problem.match_vertices(fine.mesh.vertices, top["vertices"])
            gap = max(gap, float(np.max(np.abs(top["u1"][perm] - ref["u1"]))),
                      float(np.max(np.abs(top["u2"][perm] - ref["u2"]))))
            delta = min(delta, float(top["summary"]["eta_total"]))
        print(f"twomem on the reference mesh: its solution within {gap:.1e} of PETSc's, smallest η = {delta:.4e} "
              f"(bounds the reference's own error δ)\n", flush=True)
        failures = []
        if gap > 1e-8:
            failures.append(f"twomem and PETSc differ by {gap:.1e} on the reference mesh")
        print("| flux | bound | level | vertices | η | e = \\|\\|\\|u_ref − u_h\\|\\|\\| | δ/e | eff low | eff (orth.) "
              "| eff high |")
        print("| --- | --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |")
        for flux, bound in variants:
            for k in levels:
                res = twomem(exe, mesh, k, Path(tmp) / f"l{k}.h5",
                             [f"estimate.bound={bound}", f"estimate.flux={flux}", *args.set], EXACT)
                perm_k, _ = problem.match_vertices(meshes[k].vertices, res["vertices"])
                u = [res["u1"][perm_k], res["u2"][perm_k]]
                for j in range(k, args.ref_levels):
                    u = [problem.prolong(meshes[j], v) for v in u]
                d = [ref["u1"] - u[0], ref["u2"] - u[1]]
                e = float(np.sqrt(case.mu1 * d[0] @ (fine.K @ d[0]) + case.mu2 * d[1] @ (fine.K @ d[1])))
                eta = float(res["summary"]["eta_total"])
                high = f"{eta / (e - delta):.3f}" if e > delta else "∞"
                if e > delta and eta < e - delta:
                    failures.append(f"{flux} {bound} level {k}: η = {eta:.4e} below e − δ = {e - delta:.4e}")
                print(f"| {flux} | {bound} | {k} | {meshes[k].nv} | {eta:.4e} | {e:.4e} | {delta / e:.3f} | "
                      f"{eta / (e + delta):.3f} | {eta / np.hypot(e, delta):.3f} | {high} |", flush=True)
    if args.check and failures:
        petsc_vi.fail("--check: " + "; ".join(failures), 1)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
