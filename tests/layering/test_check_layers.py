#!/usr/bin/env python3
"""The layering check must fail when the layering is broken: on a copy of src/fortran it passes,
and each planted violation (a module using a subsystem above it or beside it, a folder the order
does not name, a module named for another subsystem) makes it exit 1 with a line naming the
file, the line and what is wrong. Without this, a checker that matched no `use` statement at all
would pass every tree. Standard library only, like the check.

    python3 tests/layering/test_check_layers.py      # exit 0 when every case behaves
"""
from __future__ import annotations

import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
CHECKER = ROOT / "scripts" / "check_layers.py"


def run(root: Path) -> tuple[int, str]:
    proc = subprocess.run([sys.executable, str(CHECKER), "--root", str(root)], capture_output=True, text=True)
    return proc.returncode, proc.stdout + proc.stderr


def insert_after_module_line(path: Path, statement: str) -> int:
    """Put `statement` right after the `module ...` line of `path`; its line number."""
    lines = path.read_text(encoding="utf-8").splitlines(keepends=True)
    at = next(i for i, text in enumerate(lines) if text.lstrip().lower().startswith("module "))
    lines.insert(at + 1, statement + "\n")
    path.write_text("".join(lines), encoding="utf-8")
    return at + 2


def fresh_copy(tmp: Path, name: str) -> Path:
    root = tmp / name
    shutil.copytree(ROOT / "src" / "fortran", root / "src" / "fortran")
    return root


def main() -> int:
    failures = []

    def expect(name: str, root: Path, code: int, *fragments: str) -> None:
        got, out = run(root)
        missing = [f for f in fragments if f not in out]
        # a planted case reports its violation and nothing else
        lines = out.strip().splitlines()
        alone = code == 0 or len(lines) == 1
        status = "ok" if got == code and not missing and alone else "FAILED"
        print(f"{status}: {name}: exit {got} (expected {code})")
        for line in lines:
            print(f"    {line}")
        if status != "ok":
            failures.append(name + (f" (output lacks {missing})" if missing else "")
                            + ("" if alone else f" ({len(lines)} lines where one was planted)"))

    with tempfile.TemporaryDirectory(prefix="check_layers.") as t:
        tmp = Path(t)
        expect("the unchanged tree passes", fresh_copy(tmp, "clean"), 0, "every use goes to a lower level")

        root = fresh_copy(tmp, "base_uses_newton")
        line = insert_after_module_line(root / "src/fortran/base/twomem_base_kinds.f90",
                                        "   use twomem_newton_history, only: history_t")
        expect("base uses newton", root, 1,
               f"src/fortran/base/twomem_base_kinds.f90:{line}: twomem_base_kinds uses twomem_newton_history: "
               "base (level 0) may not use newton (level 3, above it)")

        root = fresh_copy(tmp, "io_uses_newton")
        line = insert_after_module_line(root / "src/fortran/io/twomem_io_result.f90",
                                        "   USE :: twomem_newton_history, only: history_t")
        expect("io uses newton (upper case, `::`)", root, 1,
               f"src/fortran/io/twomem_io_result.f90:{line}: twomem_io_result uses twomem_newton_history: "
               "io (level 2) may not use newton")

        root = fresh_copy(tmp, "estimate_uses_newton")
        line = insert_after_module_line(root / "src/fortran/estimate/twomem_estimate_estimates.f90",
                                        "   use twomem_newton_cfun, only: cfun_kind")
        expect("estimate uses newton, its neighbour on the same level", root, 1,
               f"src/fortran/estimate/twomem_estimate_estimates.f90:{line}: twomem_estimate_estimates uses "
               "twomem_newton_cfun: estimate (level 3) may not use newton (level 3, beside it)")

        root = fresh_copy(tmp, "undeclared_subsystem")
        extra = root / "src/fortran/extra/twomem_extra_thing.f90"
        extra.parent.mkdir()
        extra.write_text("module twomem_extra_thing\n   use twomem_base_kinds, only: dp\nend module twomem_extra_thing\n")
        expect("a folder the order does not name", root, 1,
               "src/fortran/extra/twomem_extra_thing.f90: subsystem 'extra' is not placed in the order")

        root = fresh_copy(tmp, "misnamed_module")
        misnamed = root / "src/fortran/mesh/twomem_linalg_stray.f90"
        misnamed.write_text("module twomem_linalg_stray\nend module twomem_linalg_stray\n")
        expect("a module named for another subsystem", root, 1,
               "src/fortran/mesh/twomem_linalg_stray.f90:1: module twomem_linalg_stray lives in mesh/")

    if failures:
        print(f"test_check_layers: {len(failures)} case(s) failed: " + "; ".join(failures))
        return 1
    print("test_check_layers: every planted violation was caught")
    return 0


if __name__ == "__main__":
    sys.exit(main())
