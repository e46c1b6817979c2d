"""The discrete problem of the PETSc peer benchmark (bench/petsc_vi.py), built independently of
twomem: meshes (red refinement as twomem does it, a Gmsh MSH 4.1/2.2 ASCII reader), P1 assembly
(stiffness, lumped mass, loads by Dunavant's degree-5 rule, checked exact on import), the
bound-constrained QP in (w, s) = (u1 − u2, u1 + u2) that PETSc's VI solver takes, and the check of
a solution's KKT conditions. A bad mesh raises ProblemError with a one-line message, which the
benchmark reports. scipy is imported where sparse matrices are built, so that `--help` and the
mesh functions need numpy alone.

    python3 bench/petsc_vi_problem.py --help     # this text
"""
from __future__ import annotations

import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np


class ProblemError(Exception):
    """A mesh or a quadrature rule the benchmark cannot use: the message is one line."""

# --------------------------------------------------------------------------------------------
# meshes: red refinement, as twomem does it (edge numbering may differ)
# --------------------------------------------------------------------------------------------
@dataclass
class Mesh:
    vertices: np.ndarray          # (nv, 2)
    triangles: np.ndarray         # (nt, 3) int64, counter-clockwise
    edges: np.ndarray             # (ne, 2) unique vertex pairs, i < j
    edge_of: np.ndarray           # (nt, 3) edge index of the sides (0,1), (1,2), (2,0)
    boundary: np.ndarray          # (nv,) bool: on an edge of exactly one triangle

    @property
    def nv(self) -> int:
        return self.vertices.shape[0]


def make_mesh(vertices: np.ndarray, triangles: np.ndarray) -> Mesh:
    """Edges (by a 1-D key i·nv + j, faster than unique over rows) and boundary vertices."""
    nv = vertices.shape[0]
    t = triangles
    sides = np.stack([t[:, [0, 1]], t[:, [1, 2]], t[:, [2, 0]]], axis=1).reshape(-1, 2)
    sides.sort(axis=1)
    keys, edge_of, counts = np.unique(sides[:, 0] * nv + sides[:, 1], return_inverse=True, return_counts=True)
    edges = np.stack([keys // nv, keys % nv], axis=1)
    if np.any(counts > 2):
        raise ProblemError("non-manifold mesh: an edge is shared by more than two triangles")
    boundary = np.zeros(nv, dtype=bool)
    boundary[edges[counts == 1].ravel()] = True
    return Mesh(vertices=vertices, triangles=t, edges=edges, edge_of=edge_of.reshape(-1, 3), boundary=boundary)


def red_refine(mesh: Mesh) -> Mesh:
    """Coarse vertices first, then one midpoint per edge (boundary midpoints stay on the chords);
    four children per triangle, all with the parent's orientation."""
    v, t = mesh.vertices, mesh.triangles
    mid = 0.5 * (v[mesh.edges[:, 0]] + v[mesh.edges[:, 1]])
    m = mesh.edge_of + mesh.nv                                # midpoints of (a,b), (b,c), (c,a)
    a, b, c = t[:, 0], t[:, 1], t[:, 2]
    ab, bc, ca = m[:, 0], m[:, 1], m[:, 2]
    children = np.concatenate([np.stack(k, axis=1) for k in ((a, ab, ca), (ab, b, bc), (ca, bc, c), (ab, bc, ca))])
    return make_mesh(np.concatenate([v, mid]), children)


def read_gmsh(path: Path) -> Mesh:
    """The triangles of a Gmsh MSH 4.1 or 2.2 ASCII file as they are (read here, not by twomem):
    nodes no triangle uses dropped (twomem drops them too), clockwise triangles turned. A file
    whose numbers or counts do not parse raises ProblemError naming it (twomem's own reader
    says more about where)."""
    try:
        lines = path.read_text().splitlines()
    except (OSError, UnicodeDecodeError) as exc:
        raise ProblemError(f"{path}: cannot read the mesh ({exc}; binary MSH files are not read here)")
    try:
        return _parse_gmsh(path, lines)
    except (ValueError, IndexError) as exc:
        raise ProblemError(f"{path}: not a well-formed MSH file ({exc})")


def _parse_gmsh(path: Path, lines: list[str]) -> Mesh:
    def section(name: str) -> int:
        try:
            return lines.index(f"${name}") + 1
        except ValueError:
            raise ProblemError(f"{path}: no ${name} section")
    version = lines[section("MeshFormat")].split()
    if version[1] != "0":
        raise ProblemError(f"{path}: binary MSH files are not read here: save it as ASCII")
    tags, coords, tris = [], [], []
    i = section("Nodes")
    if version[0].startswith("4"):
        nblocks = int(lines[i].split()[0])
        i += 1
        for _ in range(nblocks):
            dim, _, parametric, count = (int(x) for x in lines[i].split())
            tags.append(np.array(lines[i + 1:i + 1 + count], dtype=np.int64))
            xyz = np.array(" ".join(lines[i + 1 + count:i + 1 + 2 * count]).split(), dtype=float)
            coords.append(xyz.reshape(count, -1)[:, :2] if count else np.zeros((0, 2)))
            i += 1 + 2 * count
        i = section("Elements")
        nblocks = int(lines[i].split()[0])
        i += 1
        for _ in range(nblocks):
            dim, _, etype, count = (int(x) for x in lines[i].split())
            if etype == 2:
                tris.append(np.array(" ".join(lines[i + 1:i + 1 + count]).split(), dtype=np.int64).reshape(count, 4)[:, 1:])
            elif dim == 2:
                raise ProblemError(f"{path}: element type {etype} in a surface: only 3-node triangles are read")
            i += 1 + count
    elif version[0].startswith("2"):
        count = int(lines[i])
        data = np.array(" ".join(lines[i + 1:i + 1 + count]).split(), dtype=float).reshape(count, 4)
        tags.append(data[:, 0].astype(np.int64))
        coords.append(data[:, 1:3])
        i = section("Elements")
        for line in lines[i + 1:i + 1 + int(lines[i])]:
            f = line.split()
            if f[1] == "2":
                tris.append(np.array([f[-3:]], dtype=np.int64))
    else:
        raise ProblemError(f"{path}: MSH version {version[0]}: only 4.1 and 2.2 are read")
    if not tris:
        raise ProblemError(f"{path}: no triangles")
    tags, coords, tri_tags = np.concatenate(tags), np.concatenate(coords), np.concatenate(tris)
    index = np.full(int(tags.max()) + 1, -1, dtype=np.int64)
    index[tags] = np.arange(tags.size)
    if tri_tags.max() >= index.size or np.any((t := index[tri_tags]) < 0):
        raise ProblemError(f"{path}: a triangle names a node that is not in $Nodes")
    used, t = np.unique(t, return_inverse=True)               # drop nodes no triangle uses
    t = t.reshape(-1, 3)
    v = coords[used]
    p0, p1, p2 = v[t[:, 0]], v[t[:, 1]], v[t[:, 2]]
    det = (p1[:, 0] - p0[:, 0]) * (p2[:, 1] - p0[:, 1]) - (p1[:, 1] - p0[:, 1]) * (p2[:, 0] - p0[:, 0])
    t[det < 0] = t[det < 0][:, [0, 2, 1]]
    return make_mesh(v, t)


def prolong(coarse: Mesh, x: np.ndarray) -> np.ndarray:
    """P1 interpolation of a nodal field from `coarse` to its red refinement: midpoint averages."""
    return np.concatenate([x, 0.5 * (x[coarse.edges[:, 0]] + x[coarse.edges[:, 1]])])


def match_vertices(mine: np.ndarray, theirs: np.ndarray) -> tuple[np.ndarray, float]:
    """Permutation p with theirs[p] ≈ mine (same vertex set), and the largest coordinate gap.

    Vertices are ordered by coordinates rounded to 1e-9 (far below the smallest edge) so that a
    last-bit difference cannot reorder them; the gap is then measured on the raw coordinates.
    """
    if mine.shape != theirs.shape:
        raise ProblemError(f"finest mesh differs from twomem's: {mine.shape[0]} vertices here, {theirs.shape[0]} in twomem")
    def order(v):
        k = np.round(v * 1e9).astype(np.int64)
        return np.lexsort((k[:, 1], k[:, 0]))
    om, ot = order(mine), order(theirs)
    perm = np.empty_like(om)
    perm[om] = ot
    gap = float(np.max(np.abs(theirs[perm] - mine)))
    if gap > 1e-12:
        raise ProblemError(f"finest mesh differs from twomem's: vertex coordinates differ by up to {gap:.3e}")
    return perm, gap


# --------------------------------------------------------------------------------------------
# P1 assembly (independent of twomem): stiffness, lumped mass, degree-5 loads
# --------------------------------------------------------------------------------------------
def _dunavant5() -> tuple[np.ndarray, np.ndarray]:
    """Dunavant's 7-point rule, exact for degree 5: barycentric points (7, 3), weights (sum 1)."""
    pts, wts = [(1 / 3, 1 / 3, 1 / 3)], [0.225]
    for a, b, w in ((0.059715871789770, 0.470142064105115, 0.132394152788506),
                    (0.797426985353087, 0.101286507323456, 0.125939180544827)):
        pts += [(a, b, b), (b, a, b), (b, b, a)]
        wts += [w] * 3
    return np.array(pts), np.array(wts)


def _check_rule5() -> None:
    """∫ x^i y^j over the reference triangle is i! j! / (i + j + 2)!: exact for i + j ≤ 5."""
    from math import factorial
    x, y = RULE5_BARY[:, 1], RULE5_BARY[:, 2]
    for i in range(6):
        for j in range(6 - i):
            exact = factorial(i) * factorial(j) / factorial(i + j + 2)
            if abs(0.5 * RULE5_WEIGHTS @ (x ** i * y ** j) - exact) > 1e-14:
                raise ProblemError(f"degree-5 rule is not exact for x^{i} y^{j}")


@dataclass
class Level:
    mesh: Mesh
    K: sparse.csr_matrix          # (nv, nv) P1 stiffness, all vertices
    mass: np.ndarray              # (nv,) |ω_a|/3
    load1: np.ndarray             # (nv,) (f1, ψ_a) by the degree-5 rule
    load2: np.ndarray
    interior: np.ndarray          # indices of interior vertices
    seconds: float = 0.0          # assembly time


def assemble(mesh: Mesh, case: petsc_vi.Case) -> Level:
    """P1 stiffness, lumped mass and the two loads of `case` (μ1, μ2, f1, f2, g) on `mesh`."""
    from scipy import sparse
    t0 = time.perf_counter()
    v, t = mesh.vertices, mesh.triangles
    p0, p1, p2 = v[t[:, 0]], v[t[:, 1]], v[t[:, 2]]
    det = (p1[:, 0] - p0[:, 0]) * (p2[:, 1] - p0[:, 1]) - (p1[:, 1] - p0[:, 1]) * (p2[:, 0] - p0[:, 0])
    if np.any(det <= 0):
        raise ProblemError("mesh has a triangle that is not counter-clockwise or is degenerate")
    area = 0.5 * det
    opp = np.stack([p2 - p1, p0 - p2, p1 - p0], axis=1)       # side opposite each corner
    grad = np.stack([-opp[:, :, 1], opp[:, :, 0]], axis=2) / det[:, None, None]
    kloc = area[:, None, None] * np.einsum("kid,kjd->kij", grad, grad)
    rows = np.repeat(t, 3, axis=1).ravel()
    cols = np.tile(t, (1, 3)).ravel()
    K = sparse.csr_matrix((kloc.ravel(), (rows, cols)), shape=(mesh.nv, mesh.nv))   # duplicates summed
    mass = np.bincount(t.ravel(), weights=np.repeat(area / 3.0, 3), minlength=mesh.nv)
    load1 = load_vector(mesh, area, lambda x: np.full(x.shape[:-1], case.f1))
    load2 = load_vector(mesh, area, lambda x: np.full(x.shape[:-1], case.f2))
    lv = Level(mesh=mesh, K=K, mass=mass, load1=load1, load2=load2, interior=np.flatnonzero(~mesh.boundary))
    lv.seconds = time.perf_counter() - t0
    return lv


def load_vector(mesh: Mesh, area: np.ndarray, f) -> np.ndarray:
    """(f, ψ_a) = Σ_K |K| Σ_q w_q f(x_q) ψ_a(x_q) with the degree-5 rule; f takes points (..., 2)."""
    t = mesh.triangles
    xq = np.einsum("qi,kid->kqd", RULE5_BARY, mesh.vertices[t])          # (nt, 7, 2)
    fw = f(xq) * RULE5_WEIGHTS[None, :] * area[:, None]                  # (nt, 7)
    local = fw @ RULE5_BARY                                              # (nt, 3): ψ_i(x_q) = bary_i
    return np.bincount(t.ravel(), weights=local.ravel(), minlength=mesh.nv)


# --------------------------------------------------------------------------------------------
# the VI in (w, s) = (u1 − u2, u1 + u2)
# --------------------------------------------------------------------------------------------
@dataclass
class VI:
    H: sparse.csr_matrix          # (2n, 2n) Hessian of the QP at the interior unknowns [w; s]
    b: np.ndarray                 # (2n,) so that ∇J(x) = H x − b (lifting of w = s = g included)
    n: int


def vi_system(lv: Level, case: petsc_vi.Case) -> VI:
    """J(u1, u2) = ½μ1 u1ᵀK u1 + ½μ2 u2ᵀK u2 − (f1, u1) − (f2, u2) with u1 = (s + w)/2,
    u2 = (s − w)/2 gives ∂²J/∂w² = ∂²J/∂s² = (μ1+μ2)/4 K and ∂²J/∂w∂s = (μ1−μ2)/4 K; the linear
    part is ½[(f1 − f2, ψ); (f1 + f2, ψ)] minus the boundary columns applied to w = s = g."""
    from scipy import sparse
    a, c = (case.mu1 + case.mu2) / 4.0, (case.mu1 - case.mu2) / 4.0
    I = lv.interior
    B = np.flatnonzero(lv.mesh.boundary)
    KI = lv.K[I]
    KII, KIB = KI[:, I], KI[:, B]
    H = sparse.bmat([[a * KII, c * KII], [c * KII, a * KII]], format="csr")
    lift = KIB @ np.full(B.size, case.g)                      # K_IB g, for both w and s
    b_w = 0.5 * (lv.load1[I] - lv.load2[I]) - (a + c) * lift
    b_s = 0.5 * (lv.load1[I] + lv.load2[I]) - (c + a) * lift
    H.sort_indices()
    return VI(H=H, b=np.concatenate([b_w, b_s]), n=I.size)


def to_nodal(lv: Level, x: np.ndarray, g: float) -> tuple[np.ndarray, np.ndarray]:
    """Interior [w; s] → nodal w, s with the boundary values w = s = g."""
    n = lv.interior.size
    w, s = np.full(lv.mesh.nv, g), np.full(lv.mesh.nv, g)
    w[lv.interior], s[lv.interior] = x[:n], x[n:]
    return w, s


def fields(lv: Level, case: petsc_vi.Case, w: np.ndarray, s: np.ndarray) -> dict:
    """u1, u2 and λ = (μ1 K u1 − F1)/D at interior vertices (0 on ∂Ω), from the first equation."""
    u1, u2 = 0.5 * (s + w), 0.5 * (s - w)
    lam = np.zeros(lv.mesh.nv)
    I = lv.interior
    lam[I] = (case.mu1 * (lv.K @ u1)[I] - lv.load1[I]) / lv.mass[I]
    return dict(u1=u1, u2=u2, lam=lam)


def kkt_check(lv: Level, case: petsc_vi.Case, fld: dict) -> dict:
    """The second equation μ2 K u2 + D λ = F2 (the first defines λ) and complementarity of a
    solution, relative to the size of their terms: an assembly-independent self-check."""
    I = lv.interior
    u1, u2, lam = fld["u1"], fld["u2"], fld["lam"]
    ku2 = case.mu2 * (lv.K @ u2)[I]
    r2 = ku2 + lv.mass[I] * lam[I] - lv.load2[I]
    scale = max(np.max(np.abs(ku2)), np.max(np.abs(lv.mass[I] * lam[I])), np.max(np.abs(lv.load2[I])))
    w = (u1 - u2)[I]
    return dict(eq2_rel=float(np.max(np.abs(r2)) / scale),
                min_gap=float(np.min(w)), min_lambda=float(np.min(lam[I])),
                compl_rel=float(np.max(np.abs(np.minimum(w / np.max(np.abs(w)), lam[I] / np.max(np.abs(lam[I])))))))


RULE5_BARY, RULE5_WEIGHTS = _dunavant5()
_check_rule5()

if __name__ == "__main__":
    print(__doc__)
    sys.exit(0 if sys.argv[1:] in ([], ["--help"], ["-h"]) else 2)
