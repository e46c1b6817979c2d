"""The numerical stress suite's cases, methods and checks, shared by test_stress.py (ctest label
`stress`) and table.py (the table of docs/robustness.md).

Every case is a small problem at an extreme of the data or the mesh; every method is
newton.linear in (direct, gmres, adaptive) x newton.cfun in (min, fb). A run must end in one of
two ways:

* exit 0, status `converged`, every field finite, and the solution checked against an
  independent computation: the discrete equations and complementarity recomputed in numpy from
  the result's mesh (tests/regression/p1_numpy.py, nothing of twomem's assembly), and the
  distance to the reference solve (direct Newton-min; for the degenerate case also the closed
  form). `adaptive` stops by design once the linearization and algebraic errors are below the
  discretization error, so its distance to the reference is bounded by its own estimate;
* exit 1, status `not converged: <reason>`, with the result written.

Anything else (another exit code, a crash, a hang past the time limit, NaN called converged, a
check failing) is a failure of the suite.
"""
from __future__ import annotations

import math
import os
import re
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent / "regression"))

import p1_numpy as p1np  # noqa: E402
from twomem_testlib import EXE, SOURCE, TMP, result  # noqa: E402

RUN_SECONDS = 120
METHODS = [(linear, cfun) for linear in ("direct", "gmres", "adaptive") for cfun in ("min", "fb")]
SQUARE = ("mesh.domain=square", "mesh.coarse_h=0.25", "mesh.levels=1")


# --------------------------------------------------------------------------------------------
# meshes written by the suite (MSH 2.2, triangles only): structured grids with chosen node
# coordinates, optionally with cells removed (holes)
# --------------------------------------------------------------------------------------------
def grid_mesh(path: Path, xs: np.ndarray, ys: np.ndarray, removed=lambda i, j: False) -> Path:
    """Cells (i, j) of the tensor grid xs x ys, each cut into two triangles along alternating
    diagonals, except the removed ones; only vertices that some triangle uses are written."""
    nx, ny = len(xs) - 1, len(ys) - 1
    node = lambda i, j: j * (nx + 1) + i  # noqa: E731
    tris = []
    for j in range(ny):
        for i in range(nx):
            if removed(i, j):
                continue
            a, b, c, d = node(i, j), node(i + 1, j), node(i + 1, j + 1), node(i, j + 1)
            if (i + j) % 2 == 0:
                tris += [(a, b, c), (a, c, d)]
            else:
                tris += [(a, b, d), (b, c, d)]
    used = sorted({v for t in tris for v in t})
    number = {v: k + 1 for k, v in enumerate(used)}
    lines = ["$MeshFormat", "2.2 0 8", "$EndMeshFormat", "$Nodes", str(len(used))]
    for v in used:
        lines.append(f"{number[v]} {float(xs[v % (nx + 1)])!r} {float(ys[v // (nx + 1)])!r} 0")
    lines += ["$EndNodes", "$Elements", str(len(tris))]
    for k, (a, b, c) in enumerate(tris, 1):
        lines.append(f"{k} 2 2 1 1 {number[a]} {number[b]} {number[c]}")
    lines.append("$EndElements")
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("\n".join(lines) + "\n")
    return path


def aspect_mesh(path: Path) -> Path:
    """(0,1) x (0,1e-3) in 8 x 8 cells: every triangle has aspect ratio 1e3."""
    return grid_mesh(path, np.linspace(0.0, 1.0, 9), np.linspace(0.0, 1e-3, 9))


def graded_mesh(path: Path) -> Path:
    """(0,1)^2 graded geometrically towards the corner (0,0): cell widths from 1e-3 to 0.4."""
    n = 10
    widths = 1e-3 * (0.4 / 1e-3) ** (np.arange(n) / (n - 1))
    coords = np.concatenate([[0.0], np.cumsum(widths)])
    coords /= coords[-1]
    return grid_mesh(path, coords, coords)


def two_holes_mesh(path: Path) -> Path:
    """(-1,1)^2 in 12 x 12 cells with two 2 x 2 blocks removed: three boundary curves."""
    xs = np.linspace(-1.0, 1.0, 13)
    return grid_mesh(path, xs, xs, lambda i, j: (2 <= i <= 3 and 2 <= j <= 3) or (7 <= i <= 8 and 6 <= j <= 7))


# --------------------------------------------------------------------------------------------
# cases
# --------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Case:
    name: str
    what: str
    overrides: tuple[str, ...]
    mesh: object = None            # function writing a Gmsh file, or None
    closed_form: bool = False      # u1 − u2 = g and λ = 0 exactly (degenerate case)
    extra: tuple[str, ...] = field(default_factory=tuple)


CASES = [
    Case("mu_1e-6", "μ1/μ2 = 1e-6 (μ1 = 1e-6, μ2 = 1)", (*SQUARE, "problem.mu1=1e-6", "problem.mu2=1")),
    Case("mu_1e6", "μ1/μ2 = 1e6 (μ1 = 1e6, μ2 = 1, f2 = 1)",
         (*SQUARE, "problem.mu1=1e6", "problem.mu2=1", "problem.f2=1")),
    Case("g_1e-10", "g = 1e-10 (default loads: contact almost everywhere)", (*SQUARE, "problem.g=1e-10")),
    Case("g_10", "g = 10 (no contact)", (*SQUARE, "problem.g=10")),
    Case("load_1e8", "f1 = −1e8, f2 = 1e8", (*SQUARE, "problem.f1=-1e8", "problem.f2=1e8")),
    Case("no_contact", "f1 = 1, f2 = −1 (membranes pulled apart)", (*SQUARE, "problem.f1=1", "problem.f2=-1")),
    Case("contact_everywhere", "f1 = −100, f2 = 100, g = 1e-3",
         (*SQUARE, "problem.f1=-100", "problem.f2=100", "problem.g=1e-3")),
    Case("degenerate", "f1 = f2 = 1, μ1 = μ2, g = 1e-10: u1 − u2 = g, λ = 0 everywhere",
         (*SQUARE, "problem.f1=1", "problem.f2=1", "problem.g=1e-10"), closed_form=True),
    Case("aspect_1e3", "(0,1)×(0,1e-3), aspect ratio 1e3, f2 = 1e6", ("mesh.levels=1", "problem.f1=-1e6",
                                                                      "problem.f2=1e6"), mesh=aspect_mesh),
    Case("graded", "(0,1)², cells from 1e-3 to 0.4", ("mesh.levels=1", "problem.f1=-1", "problem.f2=1"),
         mesh=graded_mesh),
    Case("hole", "square with a hole (input/meshes/square_hole.msh)",
         ("mesh.levels=1", "problem.f1=-1", "problem.f2=1",
          f"mesh.file={SOURCE / 'input' / 'meshes' / 'square_hole.msh'}")),
    Case("two_holes", "square with two holes, three boundary curves", ("mesh.levels=1", "problem.f1=-1",
                                                                      "problem.f2=1"), mesh=two_holes_mesh),
]
BY_NAME = {c.name: c for c in CASES}


@dataclass
class Outcome:
    case: str
    linear: str
    cfun: str
    code: int | None = None         # exit code; None: killed at the time limit
    status: str = ""
    newton: int = 0
    gmres: int = 0
    seconds: float = 0.0
    error: float = math.nan         # relative distance to the reference solution
    bound: float = math.nan         # what `error` must not exceed
    residual: float = math.nan      # numpy residual of the discrete problem (relative)
    finite: bool = True
    stderr: str = ""
    data: dict | None = None

    @property
    def converged(self) -> bool:
        return self.code == 0 and self.status == "converged"


def out_dir() -> Path:
    d = TMP / "stress"
    d.mkdir(parents=True, exist_ok=True)
    return d


def case_args(case: Case) -> list[str]:
    args = ["problem.exact=none", *case.overrides, *case.extra]
    if case.mesh is not None:
        path = case.mesh(out_dir() / "meshes" / f"{case.name}.msh")
        args += ["mesh.domain=gmsh", f"mesh.file={path}"]
    elif any(a.startswith("mesh.file=") for a in args):
        args.append("mesh.domain=gmsh")
    return args


def run(case: Case, linear: str, cfun: str) -> Outcome:
    """One run of `case` by one method; the result file is read when the run wrote one."""
    out = out_dir() / f"{case.name}_{linear}_{cfun}.h5"
    out.unlink(missing_ok=True)
    args = [EXE, "run", str(SOURCE / "input" / "default.nml"), *case_args(case), f"newton.linear={linear}",
            f"newton.cfun={cfun}", "newton.tol=1e-12", "gmres.rtol=1e-13", "newton.max_it=200", "newton.initial=paper",
            f"estimate.enabled={'.true.' if linear == 'adaptive' else '.false.'}", f"output.file={out}"]
    o = Outcome(case.name, linear, cfun)
    start = time.monotonic()
    try:
        proc = subprocess.run(args, capture_output=True, text=True, timeout=RUN_SECONDS,
                              env={**os.environ, "OMP_NUM_THREADS": "1"})
    except subprocess.TimeoutExpired:
        o.seconds = time.monotonic() - start
        o.status = f"killed after {RUN_SECONDS} s"
        return o
    o.seconds = time.monotonic() - start
    o.code, o.stderr = proc.returncode, proc.stderr
    if proc.returncode in (0, 1) and out.exists():
        r = result(out)
        o.status = str(r["status"])
        o.newton = int(r["summary"]["newton_iterations"])
        o.gmres = int(r["summary"]["gmres_iterations"])
        o.finite = all(np.all(np.isfinite(r[k])) for k in ("u1", "u2", "lambda"))
        r["eta_total"] = float(r["summary"].get("eta_total", math.nan))
        r["p1"] = p1np.assemble(r["vertices"], r["triangles"])
        r["data"] = p1np.parse_namelist(r["input"])["problem"]
        o.data = r
        if o.finite:
            o.residual = discrete_residual(r)
    return o


def discrete_residual(r: dict) -> float:
    """max over interior vertices of the residuals of the discrete problem, relative:
    r_α = μ_α S u_α ∓ |ω_a|/3 λ − f_α |ω_a|/3 against the size of its terms (as
    tests/regression/test_discrete.py), and min(u1 − u2, λ) against max(|u1|, |u2|) and max|λ|."""
    p, d = r["p1"], r["data"]
    u1, u2, lam = r["u1"], r["u2"], r["lambda"]
    mu1, mu2, f1, f2 = (float(d[k]) for k in ("mu1", "mu2", "f1", "f2"))
    m, inner = p.mass, ~p.boundary
    r1 = mu1 * p.apply(u1) - m * lam - f1 * m
    r2 = mu2 * p.apply(u2) + m * lam - f2 * m
    c1 = mu1 * p.apply_abs(u1) + m * np.abs(lam) + abs(f1) * m
    c2 = mu2 * p.apply_abs(u2) + m * np.abs(lam) + abs(f2) * m
    eq = max(np.max(np.abs(r1[inner])) / np.max(c1[inner]), np.max(np.abs(r2[inner])) / np.max(c2[inner]))
    w = u1 - u2
    wscale = max(np.max(np.abs(u1)), np.max(np.abs(u2)), 1e-300)
    lscale = max(np.max(np.abs(lam)), (abs(f1) + abs(f2)) * 1e-300, 1e-300)
    compl = np.max(np.abs(np.minimum(w[inner] / wscale, lam[inner] / lscale)))
    return float(max(eq, compl))


def distance(got: dict, ref: dict) -> float:
    """Relative max-norm distance of (u1, u2) and of λ, the larger of the two."""
    uscale = max(np.max(np.abs(ref["u1"])), np.max(np.abs(ref["u2"])), 1e-300)
    du = max(np.max(np.abs(got["u1"] - ref["u1"])), np.max(np.abs(got["u2"] - ref["u2"]))) / uscale
    d = ref["data"]
    lscale = max(np.max(np.abs(ref["lambda"])), abs(float(d["f1"])) + abs(float(d["f2"])))
    dl = np.max(np.abs(got["lambda"] - ref["lambda"])) / lscale
    return float(max(du, dl))


def energy_distance(got: dict, ref: dict) -> float:
    """(μ1 |u1 − u1_ref|²_1 + μ2 |u2 − u2_ref|²_1)^{1/2}, the energy norm of the estimators."""
    p, d = ref["p1"], ref["data"]
    e1, e2 = got["u1"] - ref["u1"], got["u2"] - ref["u2"]
    return float(math.sqrt(max(0.0, float(d["mu1"]) * e1 @ p.apply(e1) + float(d["mu2"]) * e2 @ p.apply(e2))))


def closed_form_distance(r: dict) -> float:
    """Degenerate case: u1 − u2 = g at every vertex and λ = 0, relative to max |u| and to the
    load (u1 − u2 is a difference of numbers of size max |u|: its round-off is relative to that)."""
    d = r["data"]
    uscale = max(np.max(np.abs(r["u1"])), np.max(np.abs(r["u2"])))
    return float(max(np.max(np.abs(r["u1"] - r["u2"] - float(d["g"]))) / uscale,
                     np.max(np.abs(r["lambda"])) / (abs(float(d["f1"])) + abs(float(d["f2"])))))


# Bounds, and why. Exact methods stop at ‖R_lin‖/‖[F;0]‖ ≤ 1e-12; the distance of two such
# solutions is that times the condition of the Newton matrix in the max norm, which grows like
# h^-2 and with μ1/μ2 and the aspect ratio: 1e-6 holds for every case here with a margin.
# The numpy residual of an exact solve is round-off times the growth of the solve: 1e-8.
EXACT_BOUND = 1e-6
# The numpy residual of the reference (a direct solve) is round-off times the growth of the
# solve: 1e-8. The other exact methods meet newton.tol in their own norm (relative to ‖F‖, not
# to the size of each row's terms): the same 1e-6 as the distance.
RESIDUAL_BOUND = 1e-8
# the closed form of the degenerate case, relative to max |u|: 1e-12 keeps the error far below
# g/max|u| = 3e-10, so u1 − u2 = g > 0 is really resolved
CLOSED_FORM_BOUND = 1e-12
# adaptive: ‖u − u_h‖ ≤ η for its own iterate and for the reference (the guaranteed bound of the
# estimators; the reference's η is at most the adaptive run's η_disc ≤ η): the energy distance of
# the two is at most 2η
ADAPTIVE_FACTOR = 2.0


EXACT_METHODS = [("direct", "min"), ("direct", "fb"), ("gmres", "min"), ("gmres", "fb")]


def run_all(case: Case) -> tuple[dict, Outcome | None]:
    """Every method on `case`, and the reference: the first exact method (direct Newton-min
    first) that converged."""
    outcomes = {(lin, cfun): run(case, lin, cfun) for lin, cfun in METHODS}
    ref = next((outcomes[m] for m in EXACT_METHODS if outcomes[m].converged), None)
    return outcomes, ref


def judge(o: Outcome, ref: Outcome | None) -> list[str]:
    """What is wrong with an outcome (empty: it is acceptable); fills o.error and o.bound."""
    problems = []
    if o.code is None:
        return [o.status]
    if o.code not in (0, 1):
        return [f"exit {o.code}: {o.stderr.strip()[-300:]}"]
    if o.data is None:
        return [f"exit {o.code} without a result file"]
    if o.code == 1:
        if not re.match(r"not converged: \S", o.status):
            problems.append(f"exit 1 with status {o.status!r}")
        return problems
    if o.status != "converged":
        return [f"exit 0 with status {o.status!r}"]
    if not o.finite:
        return ["NaN or Inf in a result marked converged"]
    case = BY_NAME[o.case]
    if o.linear == "adaptive":
        if ref is None or not ref.converged:
            return ["no converged reference to compare with"]
        o.error = energy_distance(o.data, ref.data)
        o.bound = ADAPTIVE_FACTOR * o.data["eta_total"]
    elif case.closed_form:
        o.error = closed_form_distance(o.data)
        o.bound = CLOSED_FORM_BOUND
    elif ref is o:
        # the reference itself: checked by the numpy residual
        o.error = o.residual
        o.bound = RESIDUAL_BOUND
    else:
        if ref is None or not ref.converged:
            return ["no converged reference to compare with"]
        o.error = distance(o.data, ref.data)
        o.bound = EXACT_BOUND
    if not o.error <= o.bound:
        problems.append(f"distance to the reference {o.error:.2e} > {o.bound:.2e}")
    bound = RESIDUAL_BOUND if ref is o else EXACT_BOUND
    if o.linear != "adaptive" and not o.residual <= bound:
        problems.append(f"numpy residual of the discrete problem {o.residual:.2e} > {bound:.0e}")
    return problems
