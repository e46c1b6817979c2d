#!/usr/bin/python3
"""PETSc peer benchmark: twomem against PETSc's reduced-space VI Newton on the same discrete problem.

What it measures. On the built-in unit disk (coarse mesh from twomem, refined `--levels` times by
red refinement here, in numpy), the script assembles twomem's discrete two-membrane problem
independently (P1 stiffness K, lumped mass D = diag(|ω_a|/3), loads by a degree-5 rule, lifting
of u1 = g on ∂Ω) and poses it as the bound-constrained QP

    min ½ xᵀ H x − bᵀ x   over x = (w, s) = (u1 − u2, u1 + u2) at interior vertices,  w ≥ 0,
    H = ¼ [[(μ1+μ2) K, (μ1−μ2) K], [(μ1−μ2) K, (μ1+μ2) K]],

whose KKT conditions are twomem's equations with multiplier D λ. PETSc solves it with SNES
`vinewtonrsls` (reduced-space active-set Newton), CG + hypre BoomerAMG on each reduced system,
(a) cold on the finest mesh from (w, s) = (g, g) (twomem's (g, 0, 0) guess) and (b) by nested
iteration (solve level 0, interpolate by midpoint averaging, ... finest). In the same run twomem
solves the same case (Newton-min, GMRES with its multigrid block preconditioner, nested
iteration), its own `/performance@solve_seconds` is read, and a markdown table compares
Newton/SNES steps, Krylov iterations and solve seconds (median of `--repeat` runs, interleaved:
twomem, PETSc nested, PETSc cold, twomem, ...). The finest PETSc solution is compared with a
tightly converged twomem solution (newton.tol = gmres.rtol = 1e-12) on the same vertices.

PETSc runs on one process (Debian's hypre has no OpenMP); twomem uses `--threads` OpenMP
threads (a comma list gives one twomem row each; `2:passive` also sets OMP_WAIT_POLICY=passive,
which matters on a loaded machine: libgomp's spinning barriers then cost twomem 20x). Timings on
a shared machine are noisy: read medians, and the spread in the JSON output.

    bench/setup_petsc.sh                              # once: Debian's petsc4py, h5py, scipy
    /usr/bin/python3 bench/petsc_vi.py --levels 2     # coarse_h 0.05, boundary_h 0.01: 48k vertices
    /usr/bin/python3 bench/petsc_vi.py --levels 3 --skip-cold -o results.json

Preconditioners (`--pc`, a comma list, one row pair each): `boomeramg` (the options database's
CG + BoomerAMG on the whole reduced system), `split` (BoomerAMG per field w, s: PETSc's
strongest measured on a single mesh) and `gmg` (PCMG with the red-refinement interpolations
restricted to the inactive set, Galerkin coarse operators: its strongest on the hierarchy); see
the class Precond. `--mesh file.msh` reads a Gmsh MSH 4.1/2.2 ASCII mesh here and solves it as
it is (twomem: mesh.domain=gmsh, mesh.levels=0), PETSc cold only. `--whole` adds twomem's
whole adaptive run (default method, estimators, output; the sum of its phases) as the first
row. `--check` exits 1 when a PETSc solve did not converge or disagrees with twomem (the ctests
bench/petsc_vi_mesh and bench/petsc_vi_gmg).

    /usr/bin/python3 bench/petsc_vi.py --levels 3 --pc gmg,split --whole --threads 2:passive
    /usr/bin/python3 bench/petsc_vi.py --mesh results/meshes/pacman_0.005.msh --pc split,boomeramg

The discrete problem (meshes, P1 assembly, the QP, the KKT check) is bench/petsc_vi_problem.py's;
this script runs the solvers and compares them.

`--petsc-options "-ksp_monitor ..."` is passed to PETSc's options database after the defaults,
so any option below can be overridden from the command line.
"""
from __future__ import annotations

import argparse
import json
import os
import re
import statistics
import subprocess
import sys
import sysconfig
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
# Debian's PETSc for this machine's architecture (x86_64-linux-gnu, aarch64-linux-gnu, ...)
PETSC_DIR = f"/usr/lib/petscdir/petsc3.18/{sysconfig.get_config_var('MULTIARCH') or 'x86_64-linux-gnu'}-real"
PROG = "petsc_vi.py"
# bound by import_numerics() once the arguments are parsed
h5py = np = sp = problem = None


def fail(message: str, code: int = 2) -> None:
    """One-line error on stderr, no traceback."""
    print(f"{PROG}: error: {message}", file=sys.stderr)
    sys.exit(code)


# --------------------------------------------------------------------------------------------
# imports that only the benchmark needs
# --------------------------------------------------------------------------------------------
def import_petsc(extra_options: list[str]):
    """petsc4py initialised with our program name and the user's extra options; PETSc module."""
    os.environ.setdefault("PETSC_DIR", PETSC_DIR)
    # Debian's petsc4py.pth reads PETSC_DIR when the interpreter starts; add the path ourselves
    # so the benchmark also works when the variable was not set beforehand.
    site = Path(os.environ["PETSC_DIR"]) / "lib" / "python3" / "dist-packages"
    if site.is_dir() and str(site) not in sys.path:
        sys.path.append(str(site))
    try:
        import petsc4py
        petsc4py.init([PROG, *extra_options])
        from petsc4py import PETSc
    except ImportError as exc:
        fail(f"petsc4py is not importable under {sys.executable} ({exc}): run bench/setup_petsc.sh", 3)
    return PETSc


def import_numerics() -> None:
    """h5py, numpy, scipy and the discrete problem (bench/petsc_vi_problem.py, whose quadrature rule
    checks itself on import) as the module's globals: after the arguments are parsed, so that
    `--help` needs none of them."""
    global h5py, np, sp, problem
    try:
        import h5py
        import numpy as np
        import scipy.sparse as sp
    except ImportError as exc:
        fail(f"{exc.name} is not importable under {sys.executable}: run bench/setup_petsc.sh", 3)
    import petsc_vi_problem as problem


# --------------------------------------------------------------------------------------------
# the case and twomem
# --------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Case:
    coarse_h: float
    boundary_h: float
    levels: int
    mu1: float
    mu2: float
    f1: float
    f2: float
    g: float
    mesh_file: str = ""           # a Gmsh mesh solved as it is (mesh.levels = 0) instead of the disk

    def overrides(self, levels: int | None = None) -> list[str]:
        lv = self.levels if levels is None else levels
        mesh = ([f"mesh.domain=gmsh", f"mesh.file={self.mesh_file}", "mesh.levels=0"] if self.mesh_file else
                [f"mesh.domain=disk", f"mesh.coarse_h={self.coarse_h}", f"mesh.boundary_h={self.boundary_h}",
                 f"mesh.levels={lv}"])
        return [*mesh, f"problem.mu1={self.mu1}", f"problem.mu2={self.mu2}",
                f"problem.f1={self.f1}", f"problem.f2={self.f2}", f"problem.g={self.g}",
                "problem.exact=none", "newton.cfun=min"]


# the timed twomem run: Newton-min, GMRES to a fixed 1e-10 with the default (multigrid) preconditioner,
# nested iteration (default); the reference run converges both tolerances to 1e-12
TWOMEM_TIMED = ["newton.linear=gmres", "gmres.forcing=fixed", "newton.tol=1e-10", "gmres.rtol=1e-10",
                "newton.initial=nested"]
TWOMEM_REFERENCE = ["newton.linear=gmres", "gmres.forcing=fixed", "newton.tol=1e-12", "gmres.rtol=1e-12",
                    "newton.initial=nested"]
TWOMEM_QUIET = ["estimate.enabled=.false.", "output.history=.false.", "output.xdmf=.false.",
                "output.estimators=.false."]
NESTED_LINE = re.compile(r"nested: level\s+(\d+):\s+(\d+) Newton steps,\s+(\d+) GMRES iterations \(([^)]*)\), ([0-9.]+) s")


@dataclass(frozen=True)
class Omp:
    """OpenMP set-up of a twomem run: thread count and optional OMP_WAIT_POLICY."""
    threads: int
    wait: str = ""

    @classmethod
    def parse(cls, text: str) -> "Omp":
        n, _, wait = text.partition(":")
        if not n.isdigit() or int(n) < 1 or wait not in ("", "active", "passive"):
            raise ValueError(text)
        return cls(int(n), wait)

    def env(self) -> dict:
        env = dict(os.environ, OMP_NUM_THREADS=str(self.threads))
        env.pop("OMP_WAIT_POLICY", None)
        env.pop("OPENBLAS_NUM_THREADS", None)
        if self.wait:
            env["OMP_WAIT_POLICY"] = self.wait
        return env

    def label(self) -> str:
        s = f"{self.threads} thread{'s' if self.threads > 1 else ''}"
        return s + (f", OMP_WAIT_POLICY={self.wait}" if self.wait else "")


def run_twomem(exe: Path, case: Case, out: Path, extra: list[str], omp: Omp, levels: int | None = None,
               quiet: bool = True) -> dict:
    """Run twomem, return its result (mesh, solution, summary, performance) and the nested lines.
    quiet: no estimators, history or XDMF (the timed solves); else the run as a user starts it,
    with its estimators, history and result fields (XDMF off)."""
    cmd = [str(exe), "run", str(ROOT / "input" / "default.nml"), *case.overrides(levels),
           *(TWOMEM_QUIET if quiet else ["output.xdmf=.false."]), *extra, f"output.file={out}"]
    env = omp.env()
    proc = subprocess.run(cmd, capture_output=True, text=True, env=env)
    if proc.returncode != 0:
        last = (proc.stderr.strip() or proc.stdout.strip() or "no output").splitlines()[-1]
        fail(f"twomem exited with {proc.returncode} ({' '.join(cmd[3:])}): {last}", 3)
    res = read_result(out)
    res["nested"] = [dict(level=int(m[0]), newton=int(m[1]), krylov=int(m[2]), status=m[3], seconds=float(m[4]))
                     for m in NESTED_LINE.findall(proc.stdout)]
    return res


def read_result(path: Path) -> dict:
    with h5py.File(path, "r") as f:
        if not str(f.attrs["status"]).startswith("converged"):
            fail(f"{path}: twomem did not converge: {f.attrs['status']}", 1)
        return dict(vertices=f["mesh/vertices"][...], triangles=f["mesh/triangles"][...].astype(np.int64),
                    u1=f["solution/u1"][...], u2=f["solution/u2"][...], lam=f["solution/lambda"][...],
                    summary={k: v.item() for k, v in f["summary"].attrs.items()},
                    performance={k: float(v) for k, v in f["performance"].attrs.items()})


# --------------------------------------------------------------------------------------------
# PETSc
# --------------------------------------------------------------------------------------------
@dataclass
class Tolerances:
    newton_tol: float             # SNES atol = newton_tol · ‖b‖ (twomem: ‖R_lin‖ ≤ tol ‖[F; 0]‖)
    ksp_rtol: float               # CG relative tolerance on the true (unpreconditioned) residual
    snes_max_it: int = 200
    ksp_max_it: int = 2000


def petsc_options(tol: Tolerances) -> dict:
    """Defaults put in the options database before the user's `--petsc-options` (which win).

    snes_vi_zero_tolerance: PETSc's default 1e-8 treats w ≤ 1e-8 with ∂J/∂w > 0 as active and
    freezes it there; measured on the cold 191k-vertex solve, one vertex stayed at w ≈ 1e-8 with
    λ > 0 (λ off by 2.6e-4 relative). With 0 only vertices projected onto w = 0 are active.
    """
    return {"snes_type": "vinewtonrsls", "snes_rtol": 0.0, "snes_stol": 0.0, "snes_vi_zero_tolerance": 0.0,
            "snes_max_it": tol.snes_max_it, "ksp_type": "cg", "ksp_norm_type": "unpreconditioned",
            "ksp_rtol": tol.ksp_rtol, "ksp_atol": 0.0, "ksp_max_it": tol.ksp_max_it,
            "pc_type": "hypre", "pc_hypre_type": "boomeramg",
            # the inner PCs of Precond (--pc split, gmg)
            "inner_pc_mg_galerkin": "both", "inner_pc_fieldsplit_type": "additive",
            "inner_fieldsplit_w_ksp_type": "preonly", "inner_fieldsplit_w_pc_type": "hypre",
            "inner_fieldsplit_s_ksp_type": "preonly", "inner_fieldsplit_s_pc_type": "hypre"}


def set_default_options(PETSc, defaults: dict) -> None:
    """Put the defaults where the user's command-line options did not already set the key."""
    opts = PETSc.Options()
    for key, value in defaults.items():
        if not opts.hasName(key):
            opts.setValue(key, value)


@dataclass
class SolveStats:
    level: int
    nv: int
    snes_it: int
    ksp_it: int
    reason: str
    setup_s: float                # PETSc matrix, vectors, SNES/KSP objects
    solve_s: float                # SNESSolve (includes BoomerAMG set-up on every reduced system)
    pc_setup_s: float             # of which PCSetUp (BoomerAMG hierarchies)
    solve_cpu_s: float            # CPU seconds of SNESSolve (less sensitive to other users' load)
    active: int = 0               # interior vertices with w = 0


def _pc_setup_time(PETSc) -> float:
    return PETSc.Log.Event("PCSetUp").getPerfInfo()["time"]


def snes_solve(PETSc, vi: problem.VI, x0: np.ndarray, tol: Tolerances, level: int, nv: int,
               precond: "Precond | None" = None) -> tuple[np.ndarray, SolveStats]:
    """One SNES vinewtonrsls solve of ∇J(x) = H x − b ⊥ w ≥ 0 from x0; `precond` replaces the
    options database's PC (BoomerAMG by default) by one built on the reduced systems."""
    t0 = time.perf_counter()
    comm = PETSc.COMM_SELF
    H = vi.H
    A = PETSc.Mat().createAIJ(size=H.shape, csr=(H.indptr.astype(PETSc.IntType),
                                                 H.indices.astype(PETSc.IntType), H.data), comm=comm)
    A.assemble()
    rhs = PETSc.Vec().createWithArray(vi.b.copy(), comm=comm)
    x = PETSc.Vec().createWithArray(x0.copy(), comm=comm)
    f = x.duplicate()
    lower = x.duplicate()
    upper = x.duplicate()
    lower.array[: vi.n] = 0.0
    lower.array[vi.n:] = PETSc.NINFINITY
    upper.set(PETSc.INFINITY)

    def residual(snes, xv, fv):
        A.mult(xv, fv)
        fv.axpy(-1.0, rhs)

    def jacobian(snes, xv, J, P):
        pass                                                  # H is constant

    snes = PETSc.SNES().create(comm=comm)
    snes.setFunction(residual, f)
    snes.setJacobian(jacobian, A, A)
    snes.setVariableBounds(lower, upper)
    snes.setFromOptions()
    if precond is not None:
        precond.install(PETSc, snes, level)
    if not PETSc.Options().hasName("snes_atol"):
        snes.setTolerances(atol=tol.newton_tol * float(np.linalg.norm(vi.b)))
    snes.setSolution(x)                                       # SNESSetUp_VI sizes its work vectors on it
    snes.setUp()
    t1 = time.perf_counter()
    pc0 = _pc_setup_time(PETSc)
    c1 = time.process_time()
    snes.solve(None, x)
    t2 = time.perf_counter()
    c2 = time.process_time()
    xs = x.array.copy()
    stats = SolveStats(level=level, nv=nv, snes_it=snes.getIterationNumber(),
                       ksp_it=snes.getLinearSolveIterations(), reason=snes_reason(PETSc, snes),
                       setup_s=t1 - t0, solve_s=t2 - t1, pc_setup_s=_pc_setup_time(PETSc) - pc0, solve_cpu_s=c2 - c1,
                       active=int(np.count_nonzero(xs[: vi.n] <= 0.0)))
    for obj in (snes, A, rhs, x, f, lower, upper):
        obj.destroy()
    return xs, stats


def interior_prolongation(coarse: problem.Level, fine: problem.Level) -> sp.csr_matrix:
    """P1 interpolation from `coarse` to its red refinement `fine` (coarse vertices first, then
    the edge midpoints: red_refine's numbering) between interior vertices, for both fields
    [w; s]: the corrections vanish on ∂Ω, where w = s = g are fixed."""
    nc, e = coarse.mesh.nv, coarse.mesh.edges
    ne = e.shape[0]
    rows = np.concatenate([np.arange(nc), nc + np.arange(ne), nc + np.arange(ne)])
    cols = np.concatenate([np.arange(nc), e[:, 0], e[:, 1]])
    vals = np.concatenate([np.ones(nc), np.full(2 * ne, 0.5)])
    P = sp.csr_matrix((vals, (rows, cols)), shape=(nc + ne, nc))[fine.interior][:, coarse.interior]
    return sp.block_diag((P, P), format="csr")


def petsc_aij(PETSc, M: sp.csr_matrix):
    M = M.tocsr()
    M.sort_indices()
    A = PETSc.Mat().createAIJ(size=M.shape, csr=(M.indptr.astype(PETSc.IntType), M.indices.astype(PETSc.IntType),
                                                  M.data), comm=PETSc.COMM_SELF)
    A.assemble()
    return A


class Precond:
    """A preconditioner of the reduced systems that needs to know the inactive set: a PETSc
    'python' PC whose set-up (once per SNES step, when the reduced matrix changes) reads the
    inactive set from SNESVIGetInactiveSet (ascending indices of [w; s], so the reduced matrix's
    rows are the inactive w first, then every s) and builds an inner PC on it, options prefix
    `inner_`.

    kind 'gmg': PCMG with the red-refinement interpolations of the hierarchy: the finest one
    restricted to the inactive rows, coarse columns that no remaining row reaches dropped (they
    would give zero rows in the Galerkin product), and the same, level by level, further down;
    Galerkin coarse operators (PCMG's MatPtAP), LU on the coarsest level.
    kind 'split': PCFIELDSPLIT of the reduced system into its w and s blocks, each by BoomerAMG:
    the coupled system H = M ⊗ K, scalar to BoomerAMG, has positive off-diagonals c·k_ii between
    w_i and s_i that its coarsening does not expect."""

    def __init__(self, kind: str, n: int, prolongations: list | None = None):
        self.kind, self.n, self.P = kind, n, prolongations or []
        self.snes = self.inner = None
        self.level = 0

    def install(self, PETSc, snes, level: int) -> None:
        self.PETSc, self.snes, self.level = PETSc, snes, level
        ksp = snes.getKSP()
        # vinewtonrsls resets its KSP from the options database whenever the inactive set
        # changes (SNESVIResetPCandKSP), which would bring back -pc_type hypre; under a prefix
        # nothing sets, the reset keeps CG, its tolerances and this PC
        ksp.setOptionsPrefix("reduced_")
        pc = ksp.getPC()
        pc.setType("python")
        pc.setPythonContext(self)

    def setUp(self, pc) -> None:
        PETSc = self.PETSc
        A, _ = pc.getOperators()
        idx = self.snes.getVIInactiveSet().getIndices()
        if idx.size != A.getSize()[0]:
            fail(f"inactive set ({idx.size}) and reduced matrix ({A.getSize()[0]}) differ in size")
        if self.inner is not None:
            self.inner.destroy()
        inner = PETSc.PC().create(comm=PETSc.COMM_SELF)
        inner.setOptionsPrefix("inner_")
        inner.setOperators(A, A)
        if self.kind == "gmg" and self.level == 0:
            inner.setType("lu")                               # the coarsest mesh: no hierarchy below
        elif self.kind == "gmg":
            mats, rows = [], idx
            for P in reversed(self.P[:self.level]):
                R = P[rows]
                keep = np.flatnonzero(np.diff(R.tocsc().indptr) > 0)
                mats.append(R[:, keep])
                rows = keep
            inner.setType("mg")
            inner.setMGLevels(len(mats) + 1)
            for l, R in enumerate(reversed(mats), start=1):
                inner.setMGInterpolation(l, petsc_aij(PETSc, R))
        else:
            nw = int(np.count_nonzero(idx < self.n))
            inner.setType("fieldsplit")
            inner.setFieldSplitIS(("w", PETSc.IS().createStride(nw, 0, 1, comm=PETSc.COMM_SELF)),
                                  ("s", PETSc.IS().createStride(idx.size - nw, nw, 1, comm=PETSc.COMM_SELF)))
        inner.setFromOptions()
        inner.setUp()
        self.inner = inner

    def apply(self, pc, x, y) -> None:
        self.inner.apply(x, y)


def snes_reason(PETSc, snes) -> str:
    r = snes.getConvergedReason()
    names = {v: k for k, v in vars(PETSc.SNES.ConvergedReason).items() if not k.startswith("_") and isinstance(v, int)}
    return names.get(r, str(r))


def make_precond(kind: str, levels: list[problem.Level], prolongations: list) -> "Precond | None":
    """None for the options database's PC (BoomerAMG on the whole reduced system)."""
    if kind == "boomeramg":
        return None
    return Precond(kind, levels[-1].interior.size, prolongations)


def petsc_nested(PETSc, levels: list[problem.Level], systems: list[problem.VI], case: Case, tol: Tolerances, kind: str,
                 prolongations: list):
    """Level 0 from (g, g), then each level from the midpoint interpolation of the previous one."""
    stats, x = [], None
    t_interp = 0.0
    for l, (lv, vi) in enumerate(zip(levels, systems)):
        if l == 0:
            x0 = np.full(2 * vi.n, case.g)
        else:
            t0 = time.perf_counter()
            w, s = problem.to_nodal(levels[l - 1], x, case.g)
            w, s = problem.prolong(levels[l - 1].mesh, w), problem.prolong(levels[l - 1].mesh, s)
            x0 = np.concatenate([w[lv.interior], s[lv.interior]])
            t_interp += time.perf_counter() - t0
        x, st = snes_solve(PETSc, vi, x0, tol, l, lv.mesh.nv, make_precond(kind, levels[:l + 1], prolongations))
        stats.append(st)
    return x, stats, t_interp


def petsc_cold(PETSc, levels: list[problem.Level], systems: list[problem.VI], case: Case, tol: Tolerances, kind: str,
               prolongations: list):
    vi = systems[-1]
    L = len(levels) - 1
    x, st = snes_solve(PETSc, vi, np.full(2 * vi.n, case.g), tol, L, levels[-1].mesh.nv,
                       make_precond(kind, levels, prolongations))
    return x, [st], 0.0


# --------------------------------------------------------------------------------------------
# comparison and report
# --------------------------------------------------------------------------------------------
def difference(mine: dict, ref: dict, perm: np.ndarray) -> dict:
    """max |mine − ref| and that relative to max |ref| per field, ref mapped onto our vertices."""
    out = {}
    for k in ("u1", "u2", "lam"):
        r = ref[k][perm]
        d = float(np.max(np.abs(mine[k] - r)))
        out[k] = dict(abs=d, rel=d / max(float(np.max(np.abs(r))), 1e-300))
    out["max_rel"] = max(v["rel"] for v in out.values())
    return out


def median(values):
    return statistics.median(values) if values else float("nan")


def summarize_petsc(runs: list[list[SolveStats]], t_interp: list[float]) -> dict:
    """Medians over repeats of the per-level numbers and of the totals (iterations do not vary)."""
    first = runs[0]
    per_level = []
    for i, st in enumerate(first):
        per_level.append(dict(level=st.level, nv=st.nv, snes_it=st.snes_it, ksp_it=st.ksp_it, reason=st.reason,
                              active=st.active,
                              setup_s=median([r[i].setup_s for r in runs]),
                              solve_s=median([r[i].solve_s for r in runs]),
                              pc_setup_s=median([r[i].pc_setup_s for r in runs]),
                              solve_cpu_s=median([r[i].solve_cpu_s for r in runs])))
    totals = [sum(s.solve_s for s in r) + ti for r, ti in zip(runs, t_interp)]
    setups = [sum(s.setup_s for s in r) for r in runs]
    return dict(levels=per_level, solve_s=median(totals), solve_s_all=totals, setup_s=median(setups),
                snes_it_finest=first[-1].snes_it, snes_it_coarse=sum(s.snes_it for s in first[:-1]),
                ksp_it_finest=first[-1].ksp_it, ksp_it_coarse=sum(s.ksp_it for s in first[:-1]),
                converged=all(s.reason.startswith("CONVERGED") for r in runs for s in r))


def fmt_steps(finest: int, coarse: int, nested: bool) -> str:
    return f"{finest} (+{coarse})" if nested else f"{finest}"


def print_tables(nv: int, rows: list[dict], petsc_rows: dict, repeat: int, notes: list[str]) -> None:
    first = next((r for r in rows if r["method"].startswith("twomem")), None)
    ref = first["solve_s"] if first else float("nan")
    print(f"\nSolve seconds: median of {repeat} interleaved runs on a shared machine (noisy); twomem's own "
          "/performance@solve_seconds, PETSc's SNESSolve time summed over levels (assembly excluded from both). "
          "Steps and iterations: finest level (+ coarser levels of nested iteration). "
          f"PETSc/twomem: against the first row ({first['method'] if first else '-'}).\n")
    print("| vertices | method | Newton/SNES steps | Krylov iterations | solve s | PETSc/twomem | "
          "max rel. difference u1, u2, λ vs twomem 1e-12 |")
    print("| --- | --- | --- | --- | --- | --- | --- |")
    for r in rows:
        d = r["difference"]
        diff = f"{d['u1']['rel']:.1e}, {d['u2']['rel']:.1e}, {d['lam']['rel']:.1e}"
        ratio = r["solve_s"] / ref if r["method"].startswith("PETSc") else 1.0
        print(f"| {nv} | {r['method']} | {r['steps']} | {r['krylov']} | {r['solve_s']:.3g} | "
              f"{ratio:.3g} | {diff} |")
    for name, summary in petsc_rows.items():
        print(f"\n{name}, per level (medians of {repeat}; set-up = PETSc objects, solve = SNESSolve "
              "including BoomerAMG set-up on every reduced system):\n")
        print("| level | vertices | SNES steps | CG iterations | active | set-up s | solve s | of which PCSetUp s "
              "| solve CPU s | reason |")
        print("| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |")
        for lv in summary["levels"]:
            print(f"| {lv['level']} | {lv['nv']} | {lv['snes_it']} | {lv['ksp_it']} | {lv['active']} | "
                  f"{lv['setup_s']:.3g} | {lv['solve_s']:.3g} | {lv['pc_setup_s']:.3g} | {lv['solve_cpu_s']:.3g} | "
                  f"{lv['reason']} |")
    for n in notes:
        print(n)


# --------------------------------------------------------------------------------------------
# driver
# --------------------------------------------------------------------------------------------
def parse_args(argv: list[str]) -> argparse.Namespace:
    ap = argparse.ArgumentParser(prog=PROG, description=__doc__.splitlines()[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter, epilog="\n".join(__doc__.splitlines()[1:]))
    ap.add_argument("--coarse-h", type=float, default=0.05)
    ap.add_argument("--boundary-h", type=float, default=0.01, help="always explicit: level l then equals a run with levels=l")
    ap.add_argument("--levels", type=int, default=2)
    ap.add_argument("--mu1", type=float, default=2.0)
    ap.add_argument("--mu2", type=float, default=0.5)
    ap.add_argument("--f1", type=float, default=-2.0)
    ap.add_argument("--f2", type=float, default=1.0)
    ap.add_argument("--g", type=float, default=0.05)
    ap.add_argument("--twomem", default=str(ROOT / "build" / "release" / "twomem"), help="twomem executable")
    ap.add_argument("--threads", default="2", help="OMP_NUM_THREADS for twomem; a comma list gives one row "
                    "each; N:passive also sets OMP_WAIT_POLICY=passive (e.g. 2,1,2:passive)")
    ap.add_argument("--repeat", type=int, default=3, help="timed runs per method; medians are reported")
    ap.add_argument("--cold-repeat", type=int, default=None, help="timed cold PETSc runs (default: --repeat)")
    ap.add_argument("--skip-cold", action="store_true", help="no cold PETSc solve on the finest mesh (slow when large)")
    ap.add_argument("--skip-nested", action="store_true", help="no nested PETSc solve (always with --mesh)")
    ap.add_argument("--mesh", help="a Gmsh MSH 4.1/2.2 ASCII mesh solved as it is (mesh.levels = 0 in twomem; "
                    "PETSc cold only) instead of the refined disk")
    ap.add_argument("--pc", default="boomeramg",
                    help="PETSc preconditioners of the reduced systems, comma list, one row pair each: boomeramg "
                         "(CG+BoomerAMG on the whole reduced system), split (BoomerAMG per field w, s), gmg "
                         "(PCMG with the hierarchy's interpolations restricted to the inactive set; not with --mesh)")
    ap.add_argument("--whole", action="store_true",
                    help="also time twomem's whole adaptive run (the default method, estimators, output) as the first row")
    ap.add_argument("--newton-tol", type=float, default=1e-10, help="twomem newton.tol; SNES atol = this · ‖∇J(0)‖")
    ap.add_argument("--ksp-rtol", type=float, default=1e-10, help="CG relative tolerance (twomem: gmres.rtol = 1e-10)")
    ap.add_argument("--petsc-options", default="", help="extra PETSc options, e.g. \"-snes_monitor -ksp_converged_reason\"")
    ap.add_argument("--agree", type=float, default=1e-8,
                    help="warn when a PETSc solution differs from twomem's reference by more (relative)")
    ap.add_argument("--check", action="store_true",
                    help="exit 1 when a PETSc solve did not converge or differs from twomem's reference by more "
                         "than --agree (the test of this script: small meshes, --repeat 1)")
    ap.add_argument("-o", "--output", help="write every measurement as JSON here")
    args = ap.parse_args(argv)
    if args.levels < 0 or args.repeat < 1:
        ap.error("--levels must be ≥ 0 and --repeat ≥ 1")
    try:
        args.threads = [Omp.parse(t) for t in args.threads.split(",")]
    except ValueError as exc:
        ap.error(f"--threads: {exc}: expected N or N:passive or N:active, comma separated")
    if args.cold_repeat is None:
        args.cold_repeat = args.repeat
    if args.skip_cold:
        args.cold_repeat = 0
    args.pc = args.pc.split(",")
    if any(pc not in PC_LABELS for pc in args.pc):
        ap.error(f"--pc: one or more of {', '.join(PC_LABELS)}")
    if args.mesh:
        if not Path(args.mesh).is_file():
            ap.error(f"--mesh: {args.mesh}: no such file")
        if "gmg" in args.pc:
            ap.error("--pc gmg needs the refinement hierarchy: not with --mesh")
        args.mesh = str(Path(args.mesh).resolve())
        args.levels, args.skip_nested = 0, True
    if args.skip_nested and args.skip_cold:
        ap.error("--skip-nested and --skip-cold leave no PETSc solve")
    return args


def build_levels(exe: Path, case: Case, work: Path) -> tuple[list[problem.Level], float]:
    """Coarse mesh from twomem (levels=0), refined here, or the Gmsh mesh read here; assembled
    on every level."""
    t0 = time.perf_counter()
    if case.mesh_file:
        meshes = [problem.read_gmsh(Path(case.mesh_file))]
    else:
        coarse = run_twomem(exe, case, work / "coarse.h5", TWOMEM_TIMED, Omp(1), levels=0)
        t0 = time.perf_counter()
        meshes = [problem.make_mesh(coarse["vertices"].astype(float), coarse["triangles"])]
    for _ in range(case.levels):
        meshes.append(problem.red_refine(meshes[-1]))
    t_mesh = time.perf_counter() - t0
    return [problem.assemble(m, case) for m in meshes], t_mesh


PHASES = ("mesh", "assembly", "solve", "estimators", "error", "output")
PC_LABELS = {"boomeramg": "CG+BoomerAMG", "split": "CG+BoomerAMG per field (w, s)",
             "gmg": "CG+GMG on the inactive set (red-refinement interpolation, Galerkin)"}


def twomem_row(runs: list[dict], label: str, diff: dict, whole: bool) -> dict:
    """Solve seconds: the solve phase; for the whole run the sum of all its phases."""
    s = runs[0]["summary"]
    times = [sum(r["performance"].get(f"{p}_seconds", 0.0) for p in PHASES) if whole
             else r["performance"]["solve_seconds"] for r in runs]
    return dict(method=label, steps=fmt_steps(s["newton_iterations"], s["newton_iterations_coarse"], True),
                krylov=fmt_steps(s["gmres_iterations"], s["gmres_iterations_coarse"], True),
                solve_s=median(times), solve_s_all=times,
                assembly_s=median([r["performance"]["assembly_seconds"] for r in runs]),
                nested=runs[0]["nested"], difference=diff)


def petsc_row(summary: dict, label: str, nested: bool, diff: dict) -> dict:
    return dict(method=label, steps=fmt_steps(summary["snes_it_finest"], summary["snes_it_coarse"], nested),
                krylov=fmt_steps(summary["ksp_it_finest"], summary["ksp_it_coarse"], nested),
                solve_s=summary["solve_s"], solve_s_all=summary["solve_s_all"], difference=diff)


@dataclass
class Measurements:
    """Everything the repeats produce: per twomem configuration its runs, per PETSc method
    (preconditioner, start) its per-level statistics and interpolation times, and the last
    finest solution of each."""
    configs: list
    methods: list
    twomem: dict = field(default_factory=dict)
    petsc: dict = field(default_factory=dict)
    interp: dict = field(default_factory=dict)
    x: dict = field(default_factory=dict)


def twomem_configs(threads: list[Omp], whole: bool) -> list[tuple[str, list[str], Omp, bool]]:
    """(label, overrides, OpenMP, whole run): the whole adaptive run first when asked for."""
    configs = [("twomem, whole adaptive run (default method, RT1 estimators, output), nested, "
                f"{threads[0].label()}", [], threads[0], True)] if whole else []
    configs += [(f"twomem, MG-GMRES, tol 1e-10, nested, {t.label()}", TWOMEM_TIMED, t, False) for t in threads]
    configs.append((f"twomem, MG-GMRES, tol 1e-12 (reference), nested, {threads[0].label()}",
                    TWOMEM_REFERENCE, threads[0], False))
    return configs


def run_repeats(PETSc, args, exe: Path, case: Case, levels: list[problem.Level], systems: list[problem.VI],
                tol: Tolerances, work: Path) -> Measurements:
    """Interleaved repeats (twomem rows, PETSc nested, PETSc cold, per preconditioner) so that
    slow phases of the machine's load hit every method alike."""
    starts = ([] if args.skip_nested else ["nested"]) + ([] if args.skip_cold else ["cold"])
    m = Measurements(configs=twomem_configs(args.threads, args.whole),
                     methods=[(pc, start) for pc in args.pc for start in starts])
    m.twomem = {i: [] for i in range(len(m.configs))}
    m.petsc = {k: [] for k in m.methods}
    m.interp = {k: [] for k in m.methods}
    prolongations = [interior_prolongation(c, f) for c, f in zip(levels[:-1], levels[1:])]
    for r in range(max(args.repeat, args.cold_repeat)):
        if r < args.repeat:
            for i, (_, overrides, omp, whole) in enumerate(m.configs):
                run = run_twomem(exe, case, work / "timed.h5", overrides, omp, quiet=not whole)
                del run["vertices"], run["triangles"]                # same mesh as the reference
                m.twomem[i].append(run)
            times = ", ".join(f"{m.twomem[i][-1]['performance']['solve_seconds']:.3g}" for i in m.twomem)
            print(f"run {r + 1}: twomem solve phases (table rows) {times} s", flush=True)
        for pc, start in m.methods:
            if r >= (args.repeat if start == "nested" else args.cold_repeat):
                continue
            solve = petsc_nested if start == "nested" else petsc_cold
            m.x[pc, start], st, ti = solve(PETSc, levels, systems, case, tol, pc, prolongations)
            m.petsc[pc, start].append(st)
            m.interp[pc, start].append(ti)
            print(f"run {r + 1}: PETSc {pc} {start} {sum(x.solve_s for x in st) + ti:.3g} s "
                  f"({st[-1].snes_it} SNES, {st[-1].ksp_it} CG on the finest level)", flush=True)
    return m


def build_rows(m: Measurements, fine: problem.Level, case: Case, ref: dict, perm: np.ndarray, agree: float):
    """Table rows, PETSc per-level summaries and notes (self-checks, warnings)."""
    rows, petsc_tables, notes = [], {}, []
    for i, (label, _, _, whole) in enumerate(m.configs):
        last = m.twomem[i][-1]                                # twomem's vertex order, like ref
        diff = difference({k: last[k][perm] for k in ("u1", "u2", "lam")}, ref, perm)
        rows.append(twomem_row(m.twomem[i], label, diff, whole))
    for pc, start in m.methods:
        label = f"PETSc vinewtonrsls, {PC_LABELS[pc]}, {start}"
        summary = summarize_petsc(m.petsc[pc, start], m.interp[pc, start])
        fld = problem.fields(fine, case, *problem.to_nodal(fine, m.x[pc, start], case.g))
        diff = difference(fld, ref, perm)
        rows.append(petsc_row(summary, label, start == "nested", diff))
        kkt = summary["kkt"] = problem.kkt_check(fine, case, fld)
        petsc_tables[label] = summary
        notes.append(f"{label}: second equation residual {kkt['eq2_rel']:.1e} (relative), min(w) {kkt['min_gap']:.1e}, "
                     f"min(λ) {kkt['min_lambda']:.1e}, max|min(w, λ)| {kkt['compl_rel']:.1e} (each scaled by its max)")
        if not summary["converged"]:
            notes.append(f"warning: {label}: a SNES solve did not converge (see the reason column)")
        if diff["max_rel"] > agree:
            notes.append(f"warning: {label}: differs from twomem's reference by {diff['max_rel']:.1e} (> {agree:g})")
    return rows, petsc_tables, notes


def main(argv: list[str]) -> int:
    args = parse_args(argv)
    # PETSc runs on one core, and its vector operations call the system BLAS: with OpenBLAS's
    # OpenMP build (which scripts/bootstrap.sh selects for UMFPACK) every VecTDot and VecAXPY
    # of 2.5·10^4 entries then took 12 ms on the loaded machine (thread start-up and spinning),
    # most of a solve. One thread for this process, before numpy or PETSc load the BLAS; twomem's
    # runs get their own OMP_NUM_THREADS (Omp.env).
    os.environ["OMP_NUM_THREADS"] = os.environ["OPENBLAS_NUM_THREADS"] = "1"
    import_numerics()
    PETSc = import_petsc(args.petsc_options.split())
    exe = Path(args.twomem)
    if not exe.is_file() or not os.access(exe, os.X_OK):
        fail(f"{exe}: no twomem executable (build it: cmake --preset release && cmake --build --preset release)", 3)
    exe = exe.resolve()
    case = Case(args.coarse_h, args.boundary_h, args.levels, args.mu1, args.mu2, args.f1, args.f2, args.g,
                mesh_file=args.mesh or "")
    tol = Tolerances(newton_tol=args.newton_tol, ksp_rtol=args.ksp_rtol)
    defaults = petsc_options(tol)
    set_default_options(PETSc, defaults)
    PETSc.Log.begin()
    load_before = os.getloadavg()

    with tempfile.TemporaryDirectory(prefix="petsc_vi.") as tmp:
        work = Path(tmp)
        levels, t_mesh = build_levels(exe, case, work)
        fine = levels[-1]
        where = (f"Gmsh mesh {case.mesh_file} as it is" if case.mesh_file else
                 f"disk coarse_h {case.coarse_h} boundary_h {case.boundary_h} levels {case.levels}")
        print(f"case: {where}, "
              f"mu1 {case.mu1} mu2 {case.mu2} f1 {case.f1} f2 {case.f2} g {case.g}; vertices per level "
              + ", ".join(str(lv.mesh.nv) for lv in levels), flush=True)
        systems = [problem.vi_system(lv, case) for lv in levels]
        ref = run_twomem(exe, case, work / "reference.h5", TWOMEM_REFERENCE, args.threads[0])
        if ref["triangles"].shape != fine.mesh.triangles.shape:
            fail("finest mesh differs from twomem's: triangle counts differ")
        perm, gap = problem.match_vertices(fine.mesh.vertices, ref["vertices"])
        print(f"mesh check: finest mesh equals twomem's ({fine.mesh.nv} vertices, "
              f"{fine.mesh.triangles.shape[0]} triangles; coordinates differ by at most {gap:.1e})", flush=True)
        m = run_repeats(PETSc, args, exe, case, levels, systems, tol, work)

    rows, petsc_tables, notes = build_rows(m, fine, case, ref, perm, args.agree)
    if args.skip_cold:
        notes.append("PETSc cold solve skipped (--skip-cold).")
    if args.whole:
        notes.append("The whole adaptive run's time is the sum of its phases (mesh, assembly, solve, estimators, "
                     "output: /performance); the other twomem rows' and PETSc's are their solves alone.")
    load_after = os.getloadavg()
    notes.append(f"\nload average (1, 5, 15 min) at start {load_before[0]:.1f} {load_before[1]:.1f} {load_before[2]:.1f}, "
                 f"at end {load_after[0]:.1f} {load_after[1]:.1f} {load_after[2]:.1f} on {os.cpu_count()} cores")
    print_tables(fine.mesh.nv, rows, petsc_tables, args.repeat, notes)
    if args.output:
        results = dict(case=vars(case), vertices=[lv.mesh.nv for lv in levels], mesh_check_gap=gap,
                       refine_s=t_mesh, assembly_s=[lv.seconds for lv in levels],
                       petsc_options=defaults, petsc_user_options=args.petsc_options,
                       snes_atol=[tol.newton_tol * float(np.linalg.norm(vi.b)) for vi in systems],
                       twomem_timed_overrides=TWOMEM_TIMED, twomem_reference_overrides=TWOMEM_REFERENCE,
                       repeat=args.repeat, cold_repeat=args.cold_repeat, pc=args.pc,
                       load_before=load_before, load_after=load_after, rows=rows, petsc=petsc_tables)
        Path(args.output).write_text(json.dumps(results, indent=1, default=float))
        print(f"\nwritten: {args.output}")
    if args.check and any(n.startswith("warning") for n in notes):
        fail("--check: " + "; ".join(n for n in notes if n.startswith("warning")), 1)
    return 0


if __name__ == "__main__":
    try:
        sys.exit(main(sys.argv[1:]))
    except Exception as exc:                                  # PETSc errors: one line, no traceback
        if type(exc).__module__.startswith("petsc4py"):
            fail(f"PETSc: {str(exc).splitlines()[0] if str(exc) else type(exc).__name__}", 3)
        if problem is not None and isinstance(exc, problem.ProblemError):  # a bad mesh: its one line
            fail(str(exc))
        raise
