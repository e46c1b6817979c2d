"""Independent P1 finite elements in numpy (no scipy), for checking twomem's results.

Everything here is rebuilt from the mesh in a result file (vertices, 0-based triangles) and
the problem data in its `input` attribute; nothing is taken from twomem's own assembly, boundary
flags or quadrature. All loops over triangles are vectorized.
"""
from __future__ import annotations

import re
from dataclasses import dataclass

import numpy as np


# --------------------------------------------------------------------------------------------
# namelist text
# --------------------------------------------------------------------------------------------
_NUMBER = re.compile(r"^\s*([A-Za-z_][A-Za-z0-9_]*)\s*=\s*([-+]?[0-9.]+(?:[eEdD][-+]?[0-9]+)?)\s*,?\s*$")
_STRING = re.compile(r"^\s*([A-Za-z_][A-Za-z0-9_]*)\s*=\s*'([^']*)'\s*,?\s*$")


def parse_namelist(text: str) -> dict[str, dict[str, object]]:
    """Resolved namelist text (one `key = value` per line, as twomem echoes it) -> {group: {key: value}}.

    Numbers become floats (Fortran `d` exponents accepted), quoted strings stay strings, logicals
    and anything else are kept as raw text. Only what the tests need; not a general parser.
    """
    if isinstance(text, bytes):
        text = text.decode()
    groups: dict[str, dict[str, object]] = {}
    current = None
    for line in text.splitlines():
        line = line.split("!", 1)[0].rstrip() if "'" not in line else line.rstrip()
        if not line.strip():
            continue
        if line.lstrip().startswith("&"):
            current = line.strip()[1:].lower()
            groups[current] = {}
            continue
        if line.strip() == "/":
            current = None
            continue
        if current is None:
            continue
        m = _NUMBER.match(line)
        if m:
            groups[current][m.group(1).lower()] = float(m.group(2).replace("d", "e").replace("D", "e"))
            continue
        m = _STRING.match(line)
        if m:
            groups[current][m.group(1).lower()] = m.group(2)
            continue
        key, _, val = line.partition("=")
        groups[current][key.strip().lower()] = val.strip()
    return groups


# --------------------------------------------------------------------------------------------
# mesh and P1 assembly
# --------------------------------------------------------------------------------------------
@dataclass
class P1:
    """P1 data of a triangulation: element stiffness matrices in COO form, areas, lumped mass."""
    vertices: np.ndarray       # (nv, 2)
    triangles: np.ndarray      # (nt, 3) 0-based
    area: np.ndarray           # (nt,) |K| > 0
    grad: np.ndarray           # (nt, 3, 2) gradients of the barycentric coordinates
    rows: np.ndarray           # (9 nt,) COO row of each element-matrix entry (duplicates summed)
    cols: np.ndarray           # (9 nt,)
    vals: np.ndarray           # (9 nt,)
    mass: np.ndarray           # (nv,) |ω_a|/3
    boundary: np.ndarray       # (nv,) bool, on an edge of exactly one triangle
    edges: np.ndarray          # (n_edges, 2) unique edges, sorted vertex pairs
    n_boundary_edges: int

    @property
    def n_edges(self) -> int:
        return self.edges.shape[0]

    @property
    def nv(self) -> int:
        return self.vertices.shape[0]

    @property
    def nt(self) -> int:
        return self.triangles.shape[0]

    def apply(self, x: np.ndarray) -> np.ndarray:
        """S x for a full nodal vector x (all vertices, boundary values included)."""
        return np.bincount(self.rows, weights=self.vals * x[self.cols], minlength=self.nv)

    def apply_abs(self, x: np.ndarray) -> np.ndarray:
        """Σ over element entries of |S_K,ab| |x_b|: the magnitude of the sums forming (S x)(a).

        This bounds the round-off of (S x)(a) in any summation order (entries are summed
        elementwise, so cancellation inside the assembled entry does not hide anything).
        """
        return np.bincount(self.rows, weights=np.abs(self.vals) * np.abs(x[self.cols]), minlength=self.nv)

    def row_abs_sum(self) -> np.ndarray:
        """Σ_b |S_ab| of the assembled matrix (duplicates summed first), for ‖S‖_∞."""
        key = self.rows.astype(np.int64) * self.nv + self.cols
        uniq, inv = np.unique(key, return_inverse=True)
        entries = np.bincount(inv, weights=self.vals, minlength=uniq.size)
        return np.bincount(uniq // self.nv, weights=np.abs(entries), minlength=self.nv)

    def boundary_components(self) -> int:
        """Number of boundary curves: for a connected triangulated surface with b boundary
        curves, Euler: V − E + T = 2 − b (a disk has one curve, a square with a hole two)."""
        return 2 - (self.nv - self.n_edges + self.nt)


def assemble(vertices: np.ndarray, triangles: np.ndarray) -> P1:
    v = np.asarray(vertices, dtype=float)[:, :2]
    t = np.asarray(triangles, dtype=np.int64)
    p0, p1, p2 = v[t[:, 0]], v[t[:, 1]], v[t[:, 2]]
    e1, e2 = p1 - p0, p2 - p0
    det = e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]          # 2 |K|, signed
    area = 0.5 * np.abs(det)
    # ∇λ_i = rot(edge opposite i) / det, rot(x, y) = (−y, x) applied to p_{i+2} − p_{i+1}
    opp = np.stack([p2 - p1, p0 - p2, p1 - p0], axis=1)       # (nt, 3, 2)
    grad = np.stack([-opp[:, :, 1], opp[:, :, 0]], axis=2) / det[:, None, None]
    kloc = area[:, None, None] * np.einsum("kid,kjd->kij", grad, grad)   # (nt, 3, 3)
    rows = np.repeat(t, 3, axis=1).ravel()                    # (k, i, j) -> t[k, i]
    cols = np.tile(t, (1, 3)).ravel()                         # (k, i, j) -> t[k, j]
    nv = v.shape[0]
    mass = np.zeros(nv)
    np.add.at(mass, t.ravel(), np.repeat(area / 3.0, 3))
    # edges: sorted vertex pairs; a boundary edge belongs to exactly one triangle
    edges = np.sort(np.concatenate([t[:, [0, 1]], t[:, [1, 2]], t[:, [2, 0]]]), axis=1)
    uniq, counts = np.unique(edges, axis=0, return_counts=True)
    if np.any(counts > 2):
        raise ValueError("non-manifold mesh: an edge shared by more than two triangles")
    bedges = uniq[counts == 1]
    boundary = np.zeros(nv, dtype=bool)
    boundary[bedges.ravel()] = True
    return P1(vertices=v, triangles=t, area=area, grad=grad, rows=rows, cols=cols,
              vals=kloc.ravel(), mass=mass, boundary=boundary, edges=uniq,
              n_boundary_edges=int(bedges.shape[0]))


# --------------------------------------------------------------------------------------------
# quadrature: Dunavant's 12-point degree-6 rule (barycentric coordinates, weights sum to 1)
# --------------------------------------------------------------------------------------------
def _rule12() -> tuple[np.ndarray, np.ndarray]:
    bary, w = [], []
    for (a, b), wt in (((0.501426509658179, 0.249286745170910), 0.116786275726379),
                       ((0.873821971016996, 0.063089014491502), 0.050844906370207)):
        for p in ((a, b, b), (b, a, b), (b, b, a)):
            bary.append(p)
            w.append(wt)
    a, b, c = 0.053145049844817, 0.310352451033784, 0.636502499121399
    for p in ((a, b, c), (a, c, b), (b, a, c), (b, c, a), (c, a, b), (c, b, a)):
        bary.append(p)
        w.append(0.082851075618374)
    return np.array(bary), np.array(w)


RULE12_BARY, RULE12_WEIGHTS = _rule12()


def red_subdivision(levels: int) -> np.ndarray:
    """Barycentric corners (n_sub, 3, 3) of the 4**levels similar subtriangles of the reference
    triangle (red refinement), each of area 4**-levels of the parent."""
    tris = np.eye(3)[None, :, :]                              # corners as rows
    for _ in range(levels):
        a, b, c = tris[:, 0], tris[:, 1], tris[:, 2]
        ab, bc, ca = (a + b) / 2, (b + c) / 2, (c + a) / 2
        tris = np.concatenate([np.stack(s, axis=1) for s in
                               ((a, ab, ca), (ab, b, bc), (ca, bc, c), (ab, bc, ca))])
    return tris


def composite_rule(levels: int) -> tuple[np.ndarray, np.ndarray]:
    """12-point rule on each of the 4**levels red subtriangles: (bary (nq, 3), weights (nq,))."""
    sub = red_subdivision(levels)                             # (ns, 3 corners, 3 bary)
    bary = np.einsum("qc,scb->sqb", RULE12_BARY, sub).reshape(-1, 3)
    w = np.tile(RULE12_WEIGHTS, sub.shape[0]) / sub.shape[0]
    return bary, w


# --------------------------------------------------------------------------------------------
# the `radial` closed form (docs/method.md §4), gradients only
# --------------------------------------------------------------------------------------------
def radial_contact_radius(D: float, g: float) -> float:
    """ρ in (0, 1) with (D/4)(1 − ρ² + 2ρ² ln ρ) = g, by bisection; 0 if D ≤ 4g (no contact).

    φ(ρ) = 1 − ρ² + 2ρ² ln ρ decreases from 1 (ρ → 0) to 0 (ρ = 1): φ'(ρ) = 4ρ ln ρ < 0.
    """
    if D <= 4.0 * g:
        return 0.0
    target = 4.0 * g / D
    lo, hi = 1e-300, 1.0                                     # φ(lo) ≈ 1 > target > 0 = φ(hi)
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        phi = 1.0 - mid * mid + 2.0 * mid * mid * np.log(mid)
        if phi > target:
            lo = mid
        else:
            hi = mid
        if hi - lo <= 4e-16 * hi:
            break
    return 0.5 * (lo + hi)


def radial_gradients(x: np.ndarray, mu1: float, mu2: float, f1: float, f2: float, g: float):
    """Exact ∇u1, ∇u2 at points x (..., 2) for the `radial` case.

    S = μ1 u1 + μ2 u2 = μ1 g + (f1 + f2)(1 − r²)/4  ⇒ ∇S = −(f1 + f2) x / 2;
    w = u1 − u2: contact (ρ > 0): w = 0 (r ≤ ρ), (D/4)(r² − ρ²) − (Dρ²/2) ln(r/ρ) (r > ρ)
    ⇒ ∇w = (D/2)(1 − ρ²/r²) x for r > ρ, else 0; no contact: w = g + D(r² − 1)/4 ⇒ ∇w = D x / 2.
    u1 = (S + μ2 w)/(μ1 + μ2), u2 = (S − μ1 w)/(μ1 + μ2).
    """
    D = f2 / mu2 - f1 / mu1
    rho = radial_contact_radius(D, g)
    r2 = np.sum(x * x, axis=-1)
    grad_s = -(f1 + f2) / 2.0 * x
    if rho > 0.0:
        with np.errstate(divide="ignore", invalid="ignore"):
            factor = np.where(r2 > rho * rho, (D / 2.0) * (1.0 - rho * rho / r2), 0.0)
    else:
        factor = np.full(r2.shape, D / 2.0)
    grad_w = factor[..., None] * x
    g1 = (grad_s + mu2 * grad_w) / (mu1 + mu2)
    g2 = (grad_s - mu1 * grad_w) / (mu1 + mu2)
    return g1, g2, rho


def energy_error_sq(p1: P1, u1: np.ndarray, u2: np.ndarray, grad_exact, bary: np.ndarray,
                    weights: np.ndarray, mu1: float, mu2: float,
                    elements: np.ndarray | None = None) -> np.ndarray:
    """Per element Σ_α μ_α ∫_K |∇u_α − ∇u_αh|² by the rule (bary, weights) mapped to each K
    (all elements, or the given element indices)."""
    k = np.arange(p1.nt) if elements is None else np.asarray(elements)
    t = p1.triangles[k]
    gh1 = np.einsum("kid,ki->kd", p1.grad[k], u1[t])          # (n, 2) constant P1 gradients
    gh2 = np.einsum("kid,ki->kd", p1.grad[k], u2[t])
    corners = p1.vertices[t]                                  # (n, 3, 2)
    xq = np.einsum("qi,kid->kqd", bary, corners)              # (n, nq, 2)
    ge1, ge2 = grad_exact(xq)
    integrand = (mu1 * np.sum((ge1 - gh1[:, None, :]) ** 2, axis=-1)
                 + mu2 * np.sum((ge2 - gh2[:, None, :]) ** 2, axis=-1))
    return p1.area[k] * (integrand @ weights)
