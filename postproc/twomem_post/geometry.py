"""Mesh geometry and the contact set, as the maps draw them.

Contact set: a vertex is in contact when u1 − u2 <= max(λ, tol), tol = 1e-12·max(|u1|, |u2|),
i.e. it is in the active set of the min C-function (the set the run's log counts as "contact"),
or the membranes touch there to round-off with λ = 0. A fixed gap tolerance alone is not
enough: after a GMRES solve to 1e-10 the gap at contact vertices reaches 5e-11·max|u|
(input/paper_p1.nml with newton.linear=gmres: 26 of 504 contact vertices have gaps above
1e-12·max|u|, while the smallest gap off the contact set is 2e-6).
The contact set drawn is the union of the triangles whose three vertices are in contact.
"""
from __future__ import annotations

import numpy as np

#: relative gap tolerance of the contact set (times max |u|)
CONTACT_RTOL = 1e-12


def triangle_areas(xy: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    p0, p1, p2 = (xy[triangles[:, i]] for i in range(3))
    d1, d2 = p1 - p0, p2 - p0
    return 0.5 * np.abs(d1[:, 0] * d2[:, 1] - d1[:, 1] * d2[:, 0])


def contact_vertices(u1: np.ndarray, u2: np.ndarray, lam: np.ndarray | None) -> np.ndarray:
    """Vertices in contact: u1 − u2 <= max(λ, tol), tol = 1e-12·max|u| (see the module doc)."""
    scale = max(float(np.nanmax(np.abs(u1), initial=0.0)), float(np.nanmax(np.abs(u2), initial=0.0)))
    bound = np.full(u1.shape, CONTACT_RTOL * scale)
    if lam is not None:
        bound = np.fmax(bound, lam)
    with np.errstate(invalid="ignore"):
        return (u1 - u2) <= bound


def contact_triangles(triangles: np.ndarray, vertex_in_contact: np.ndarray) -> np.ndarray:
    return vertex_in_contact[triangles].all(axis=1)


def region_outline(triangles: np.ndarray, selected: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """Segments (n, 2, 2) bounding the union of the selected triangles (edges used once)."""
    t = triangles[selected]
    if len(t) == 0:
        return np.zeros((0, 2, 2))
    edges = np.sort(np.concatenate([t[:, [0, 1]], t[:, [1, 2]], t[:, [2, 0]]]), axis=1)
    uniq, count = np.unique(edges, axis=0, return_counts=True)
    boundary = uniq[count == 1]
    return xy[boundary]
