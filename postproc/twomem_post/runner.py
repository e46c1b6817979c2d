"""Running twomem: finding the executable and running many cases side by side.

Each run is one ``twomem run CASE OVERRIDES... output.file=RESULT`` process in the caller's
working directory (relative paths in a case, like ``mesh.file``, mean what they mean for a
single run), with its standard output and error in one log beside the result. Runs are
independent processes, so a study uses the cores by running several at once; each then gets one
OpenMP thread (OMP_NUM_THREADS=1), since threads of concurrent runs would only compete.
A run that fails is recorded with its exit code and error line, never raised: a study reports
it and goes on.
"""
from __future__ import annotations

import math
import os
import re
import shutil
import subprocess
import time
from concurrent.futures import ThreadPoolExecutor, as_completed
from dataclasses import dataclass
from pathlib import Path

from .errors import EnvironmentFailure
from .result import one_line

#: where a build with the CMake preset 'release' puts the executable, from the repository root
RELEASE_BINARY = Path("build") / "release" / "twomem"


@dataclass
class Run:
    """One twomem run of a study and, once finished, how it went."""
    tag: str
    method: str
    params: dict[str, str]
    overrides: tuple[str, ...]
    result: Path
    log: Path
    exit_code: int | None = None
    seconds: float = math.nan
    error: str = ""

    @property
    def failed(self) -> bool:
        return self.exit_code != 0


def find_twomem(explicit: str | None = None) -> Path:
    """The executable: `explicit` (--twomem), else $TWOMEM_EXE, else the repository's release
    build; EnvironmentFailure saying where it looked when there is none."""
    repo = Path(__file__).resolve().parents[2]
    for where, candidate in (("--twomem", explicit), ("TWOMEM_EXE", os.environ.get("TWOMEM_EXE"))):
        if candidate:
            found = candidate if os.sep in candidate else shutil.which(candidate)
            if found and os.path.isfile(found) and os.access(found, os.X_OK):
                return Path(found).resolve()
            raise EnvironmentFailure(candidate, f"no twomem executable there (from {where})")
    default = repo / RELEASE_BINARY
    if default.is_file() and os.access(default, os.X_OK):
        return default
    raise EnvironmentFailure(default, "no twomem executable: build it (cmake --preset release "
                                      "&& cmake --build --preset release) or give --twomem PATH "
                                      "or TWOMEM_EXE")


def command(exe: Path, case: Path, run: Run) -> list[str]:
    return [str(exe), "run", str(case), *run.overrides, f"output.file={run.result}"]


def _error_line(log_text: str) -> str:
    """twomem's one-line error message, or the log's last line when there is none."""
    lines = [ln for ln in log_text.splitlines() if ln.strip()]
    errors = [ln for ln in lines if ln.startswith("twomem: error:")]
    return (errors or lines or ["(no output)"])[-1].strip()


def execute(exe: Path, case: Path, run: Run, env: dict[str, str]) -> Run:
    """Run one case to completion, filling in exit code, time and error line."""
    cmd = command(exe, case, run)
    run.result.unlink(missing_ok=True)  # a stale result must not pass for this run's
    start = time.perf_counter()
    with open(run.log, "w") as log:
        print("$ " + " ".join(cmd), file=log, flush=True)
        try:
            run.exit_code = subprocess.run(cmd, stdout=log, stderr=subprocess.STDOUT,
                                           env=env).returncode
        except OSError as exc:
            run.error = f"cannot start {exe}: {one_line(exc)}"
            print(run.error, file=log)
    run.seconds = time.perf_counter() - start
    if run.exit_code is not None:
        with open(run.log, "a") as log:
            print(f"# exit {run.exit_code} after {run.seconds:.3f} s", file=log)
    if run.failed and not run.error:
        run.error = _error_line(run.log.read_text(errors="replace"))
    return run


_EXIT_LINE = re.compile(r"^# exit (-?\d+) after ([0-9.]+) s$", re.MULTILINE)


def recorded(run: Run) -> Run:
    """A run executed earlier, maybe by another process (a job array task): its exit code,
    time and error line from the last line `execute` wrote to its log; a run without a log or
    whose log has no such line (still running, or killed) is recorded as failed."""
    try:
        text = run.log.read_text(errors="replace")
    except OSError:
        run.error = f"not run: no log {run.log}"
        return run
    ends = _EXIT_LINE.findall(text)
    if not ends:
        run.error = f"did not finish: {run.log} has no exit line"
        return run
    run.exit_code, run.seconds = int(ends[-1][0]), float(ends[-1][1])
    if run.failed:
        run.error = _error_line("\n".join(ln for ln in text.splitlines() if not ln.startswith("# exit ")))
    return run


def execute_all(exe: Path, case: Path, runs: list[Run], jobs: int, on_done) -> None:
    """Run all, `jobs` at a time in the given order; call on_done(run) as each finishes."""
    env = dict(os.environ)
    if jobs > 1:
        env["OMP_NUM_THREADS"] = "1"
    for run in runs:
        run.log.parent.mkdir(parents=True, exist_ok=True)
    with ThreadPoolExecutor(max_workers=max(1, jobs)) as pool:
        futures = [pool.submit(execute, exe, case, run, env) for run in runs]
        for future in as_completed(futures):
            on_done(future.result())
