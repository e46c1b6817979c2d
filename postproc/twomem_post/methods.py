"""The solution methods a study compares, as twomem command-line overrides.

The names are the paper's (§8, criteria (84), (85) and (63)), so that a study's rows line up
with the published ones (paper.py):

``exact``     Newton-min with GMRES solved to 2e-12 in every step: the paper's "exact" method.
``inexact``   GMRES stopped once the algebraic residual is below the linearization residual.
``adaptive``  the estimator-based stopping of both GMRES and Newton (the paper's method,
              estimators evaluated at every check).
``direct``    Newton-min with UMFPACK: no algebraic error, a reference for the others.

The paper's three use ILU(0), its preconditioner (Jacobi and no preconditioner stagnate on the
full Newton matrix beyond small meshes). ``exact_mg``, ``inexact_mg`` and ``adaptive_mg`` are
the same methods with twomem's default multigrid block-elimination preconditioner, and
``adaptive_mg`` with twomem's default schedule of evaluations (estimate.checks = 'predicted':
none where the Newton test is predicted to fail).
"""
from __future__ import annotations

METHODS: dict[str, tuple[str, ...]] = {
    "exact": ("newton.linear=gmres", "gmres.forcing=fixed", "gmres.rtol=2e-12",
              "gmres.precond=ilu0"),
    "inexact": ("newton.linear=gmres", "gmres.forcing=paper", "gmres.precond=ilu0"),
    "adaptive": ("newton.linear=adaptive", "gmres.precond=ilu0", "estimate.checks=all"),
    "direct": ("newton.linear=direct",),
    "exact_mg": ("newton.linear=gmres", "gmres.forcing=fixed", "gmres.rtol=2e-12", "gmres.precond=mg"),
    "inexact_mg": ("newton.linear=gmres", "gmres.forcing=paper", "gmres.precond=mg"),
    "adaptive_mg": ("newton.linear=adaptive", "gmres.precond=mg"),
}

#: the paper's three methods, in its order
PAPER_METHODS = ("exact", "inexact", "adaptive")

#: a fixed colour and marker per method, the same on every study figure
STYLE = {
    "exact": ("tab:blue", "o"),
    "inexact": ("tab:orange", "s"),
    "adaptive": ("tab:green", "D"),
    "direct": ("tab:gray", "^"),
    "exact_mg": ("tab:purple", "v"),
    "inexact_mg": ("tab:brown", "P"),
    "adaptive_mg": ("tab:olive", "X"),
}


def parse(text: str) -> list[str]:
    """Method names from 'a,b,c'; ValueError naming the unknown ones."""
    names = [m.strip() for m in text.split(",") if m.strip()]
    unknown = [m for m in names if m not in METHODS]
    if unknown or not names:
        raise ValueError(f"unknown method{'s' if len(unknown) > 1 else ''} "
                         f"{', '.join(map(repr, unknown)) or '(none given)'} "
                         f"(valid: {', '.join(METHODS)})")
    if len(set(names)) != len(names):
        raise ValueError(f"a method is listed twice in {text!r}")
    return names
