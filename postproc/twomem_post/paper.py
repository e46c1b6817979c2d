"""The paper's published numbers, which the study figures and table put beside ours.

Source: J. Dabaghi, V. Martin, M. Vohralík, "Adaptive inexact semismooth Newton methods for
the contact problem between two membranes", J. Sci. Comput. 84:28 (2020), §8.1: p = 1, the
test case 'bbbv', Newton-min with ILU(0)-preconditioned GMRES(30), estimators every ν = 10
GMRES iterations, γ_alg = γ_lin = 0.3, initial guess (g, 0, 0). Iteration counts from Fig. 6,
estimators at convergence from Fig. 3, effectivity indices from Fig. 7, read off the
figures. Keys are our own names: the /summary attributes and the
study's method names (methods.py), so a value is looked up the way ours is.
"""
from __future__ import annotations

import math
import re

#: mesh sizes of Figs. 3, 6 and 7 (number of triangles)
TRIANGLES = (2048, 4064, 7840, 16832, 20928, 27328, 34592)

#: quantity -> method -> one value per entry of TRIANGLES
AT_CONVERGENCE = {
    "newton_iterations": {            # Fig. 6, left
        "exact": (8, 12, 15, 19, 22, 25, 28),
        "inexact": (16, 27, 46, 76, 86, 174, 166),
        "adaptive": (7, 11, 14, 18, 21, 23, 27),
    },
    "gmres_iterations": {             # Fig. 6, right (cumulated over the Newton steps)
        "exact": (330, 585, 930, 1485, 1920, 2460, 2985),
        "inexact": (160, 270, 460, 760, 860, 1740, 1660),
        "adaptive": (80, 120, 180, 340, 410, 490, 670),
    },
    "eta_disc": {"exact": (0.0261, 0.01889, 0.01301, 0.00877, 0.0080, 0.00697, 0.00605)},
    "eta_total": {"adaptive": (0.02719, 0.02057, 0.0161, 0.01128, 0.00976, 0.00907, 0.0077)},
    "eta_lin": {"adaptive": (1.03e-3, 1.17e-3, 4.3e-4, 4.0e-4, 2.3e-4, 1.6e-4, 3.5e-4)},
    "eta_alg": {"adaptive": (6.2e-4, 5.1e-4, 2.68e-3, 2.49e-3, 1.54e-3, 1.95e-3, 1.3e-3)},
    "effectivity": {                  # Fig. 7, right
        "exact": (1.038, 1.036, 1.035, 1.034, 1.035, 1.034, 1.034),
        "adaptive": (1.071, 1.085, 1.053, 1.029, 1.049, 1.043, 1.066),
    },
}

#: Fig. 6, middle: GMRES iterations of each Newton step on this mesh
PER_STEP_TRIANGLES = 7840
GMRES_PER_STEP = {
    "exact": (255, 30, 30, 30, 30, 45, 45) + (60,) * 7 + (45,),
    # 10 per step: the total 460 over 46 steps of Fig. 6, and the text of §8.1
    "inexact": (10,) * 46,
    "adaptive": (10,) * 10 + (30, 10, 30, 10),
}

#: our mesh matches a paper mesh when the triangle counts differ by at most this fraction
#: (our meshes of input/paper_p1.nml: 2032, 7424, 34592 against 2048, 7840, 34592)
MATCH_RTOL = 0.1


def is_paper_case(input_text: str) -> bool:
    """Whether a run's resolved input (the / attribute `input`) is the paper's test case."""
    return re.search(r"\bexact\s*=\s*'bbbv'", input_text or "") is not None


def mesh_index(nt: float) -> int | None:
    """The paper mesh our mesh of nt triangles stands for, or None when none is close."""
    if not nt or not math.isfinite(nt):
        return None
    i = min(range(len(TRIANGLES)), key=lambda j: abs(math.log(TRIANGLES[j] / nt)))
    return i if abs(TRIANGLES[i] - nt) <= MATCH_RTOL * TRIANGLES[i] else None


def value(quantity: str, method: str, nt: float) -> float | None:
    """The paper's value of a quantity for a method on the mesh matching ours, if published."""
    i = mesh_index(nt)
    values = AT_CONVERGENCE.get(quantity, {}).get(method)
    return None if i is None or values is None else values[i]


def curve(quantity: str, method: str) -> tuple[tuple[int, ...], tuple[float, ...]] | None:
    """(triangles, values) of a quantity for a method over all the paper's meshes, if published."""
    values = AT_CONVERGENCE.get(quantity, {}).get(method)
    return None if values is None else (TRIANGLES, values)
