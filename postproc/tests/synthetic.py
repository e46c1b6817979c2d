"""Small twomem-like result files written with h5py, so the figures and the study can be tested
without the Fortran side, including data it does not produce yet (estimators), and a stand-in
executable that writes them (``fake_twomem``) so the study's process handling is tested too."""
from __future__ import annotations

import os
import stat
import sys
from pathlib import Path

import h5py
import numpy as np

HERE = Path(__file__).resolve().parent
ESTIMATOR_NAMES = ("eta_total", "eta_disc", "eta_lin", "eta_alg", "eta_F", "eta_osc", "eta_C",
                   "eta_nonc1", "eta_nonc2", "eta_nonc3")


def square_mesh(n: int = 4):
    """[-1, 1]^2 cut into n x n squares, two counter-clockwise triangles each."""
    s = np.linspace(-1.0, 1.0, n + 1)
    x, y = np.meshgrid(s, s)
    xy = np.column_stack([x.ravel(), y.ravel()])
    tri = []
    for j in range(n):
        for i in range(n):
            a = j * (n + 1) + i
            b, c, d = a + 1, a + n + 1, a + n + 2
            tri += [[a, b, d], [a, d, c]]
    return xy, np.array(tri, dtype=np.int32)


def history_rows(gmres: bool, eta: bool, steps: int = 3):
    """Newton rows (inner 0) and, with gmres, one inner row inside every step."""
    rows = [(0, 0, 0)]
    for k in range(1, steps + 1):
        if gmres:
            rows += [(k, 10 * k + 3 * (k - 1), 1), (k, 13 * k, 0)]
        else:
            rows.append((k, 0, 0))
    n = len(rows)
    decay = 10.0 ** (-3.0 * np.arange(n) / max(1, n - 1) * steps)
    h = {
        "newton_it": np.array([r[0] for r in rows], dtype=np.int32),
        "gmres_it": np.array([r[1] for r in rows], dtype=np.int32),
        "inner": np.array([r[2] for r in rows], dtype=np.int32),
        "lin_residual": 0.3 * decay,
        "alg_residual": np.where(np.arange(n) == 0, np.nan, 1e-2 * decay),
        "energy_error": 1e-2 + 1e-2 * decay,
        "active": np.full(n, 5, dtype=np.int32),
        "active_changed": np.zeros(n, dtype=np.int32),
        "step": np.ones(n),
        "wall_time": np.linspace(0.0, 1.0, n),
    }
    e = h["energy_error"]
    etas = {"eta_disc": np.full(n, 1.04e-2), "eta_lin": 0.9 * e * decay + 1e-6,
            "eta_alg": 1e-2 * e * decay + 1e-9}
    etas["eta_total"] = etas["eta_disc"] + etas["eta_lin"] + etas["eta_alg"]
    for name, values in etas.items():
        h[name] = values if eta else np.full(n, np.nan)
    return h


def _fields(xy):
    r2 = (xy ** 2).sum(axis=1)
    bump = 0.2 * np.maximum(r2 - 0.3, 0.0)
    fields = {"u1": 0.1 + bump, "u2": 0.1 - bump, "lambda": np.where(r2 < 0.3, 1.0 - r2, 0.0)}
    fields["u2"][r2 < 0.3] -= 1e-14  # GMRES-like round-off in the gap of contact vertices
    return fields


def _write_per_element(f, name, values):
    f[name] = values
    f[name].attrs["total"] = np.sqrt(np.nansum(values ** 2))


def make_result(path: Path, *, case="synthetic", error=True, estimators=False, gmres=True,
                history=True, solution=("u1", "u2", "lambda"), mesh=True, n=4, steps=3,
                input_text=None, summary=None) -> Path:
    """A result file like twomem's; `estimators` adds every /estimators dataset and the
    estimator history columns (NaN otherwise, as twomem writes them before they exist)."""
    xy, tri = square_mesh(n)
    rng = np.random.default_rng(1)
    h = history_rows(gmres, estimators, steps)
    with h5py.File(path, "w") as f:
        f.attrs["version"] = "0.1.0"
        f.attrs["input"] = input_text or f"! twomem input: case '{case}' from 'input/{case}.nml'\n&mesh\n/\n"
        f.attrs["status"] = "converged"
        if mesh:
            f["mesh/vertices"] = xy
            f["mesh/triangles"] = tri
        fields = _fields(xy)
        for name in solution:
            f[f"solution/{name}"] = fields[name]
        if error:
            e = rng.uniform(1e-4, 1e-2, len(tri))
            e[:3] = 0.0  # exact on a few elements: must not break the log scale
            _write_per_element(f, "error/energy", e)
        if estimators:
            for name in ESTIMATOR_NAMES:
                _write_per_element(f, f"estimators/{name}", rng.uniform(1e-4, 3e-2, len(tri)))
        if history:
            for name, values in h.items():
                f[f"history/{name}"] = values
        s = f.create_group("summary")
        last = np.flatnonzero(h["inner"] == 0)[-1]
        attrs = {"nv": len(xy), "nt": len(tri), "levels": 0, "newton_iterations": steps,
                 "gmres_iterations": int(h["gmres_it"][-1]), "newton_iterations_coarse": 0,
                 "gmres_iterations_coarse": 0, "energy_error": h["energy_error"][last],
                 "eta_total": h["eta_total"][last], "wall_time": 0.1 * len(tri) ** 1.2 / 32,
                 "peak_memory_kib": 1000}
        for name in ("eta_disc", "eta_lin", "eta_alg"):
            attrs[name] = h[name][last]
        attrs["effectivity"] = attrs["eta_total"] / attrs["energy_error"]
        attrs.update(summary or {})
        for k, v in attrs.items():
            s.attrs[k] = v
    return path


FAKE_TWOMEM = """#!{python}
# Stand-in for twomem in the study tests: `run CASE KEY=VALUE...` writes a synthetic result whose
# mesh grows with mesh.levels (or shrinks with mesh.coarse_h); newton.linear=adaptive fails
# like the real program before the estimators exist (exit 2, one line on stderr); fake.broken=1
# writes a file that is not HDF5 and exits 0.
import os, sys
sys.path.insert(0, {here!r})
from synthetic import make_result
args = dict(a.split("=", 1) for a in sys.argv[3:])
print("OMP_NUM_THREADS=" + os.environ.get("OMP_NUM_THREADS", "unset"))
if args.get("newton.linear") == "adaptive" and os.environ.get("FAKE_ADAPTIVE") != "1":
    sys.exit(print("twomem: error: " + sys.argv[2] + ": &newton: linear: 'adaptive' not available",
                   file=sys.stderr) or 2)
if args.get("fake.broken") == "1":
    sys.exit(open(args["output.file"], "w").write("not HDF5") and 0)
n = 2 * 2 ** int(args.get("mesh.levels", "0"))
if "mesh.coarse_h" in args:
    n = max(2, round(0.5 / float(args["mesh.coarse_h"])))
text = "! twomem input: case 'fake' from " + sys.argv[2] + "\\n" + open(sys.argv[2]).read()
gmres = args.get("newton.linear") != "direct"
make_result(args["output.file"], n=n, gmres=gmres, estimators=os.environ.get("FAKE_ETA") == "1",
            steps=2 + n // 4, input_text=text)
print("result: " + args["output.file"])
"""


def fake_twomem(directory: Path) -> Path:
    """An executable stand-in for twomem (see FAKE_TWOMEM) in directory."""
    exe = Path(directory) / "fake_twomem"
    exe.write_text(FAKE_TWOMEM.format(python=sys.executable, here=str(HERE)))
    exe.chmod(exe.stat().st_mode | stat.S_IXUSR)
    return exe


def env_with_package() -> dict[str, str]:
    """The environment for `python -m twomem_post` in a subprocess, with or without the
    editable install."""
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(HERE.parent), env.get("PYTHONPATH", "")]).rstrip(os.pathsep)
    return env
