#!/usr/bin/env python3
"""Check the layering of src/fortran: a module may use modules of its own subsystem and of the
subsystems on lower levels of LEVELS, nothing else.

    scripts/check_layers.py            # exit 0, or exit 1 with one line per violation
    scripts/check_layers.py --graph    # the subsystem graph: levels and `use` edges with counts
    scripts/check_layers.py --root DIR # check another tree (DIR holds src/fortran)

A module's subsystem is the folder it lives in (src/fortran/<subsystem>/..., base/mpi and
base/serial being base; the program twomem_main belongs to app); every module must be named
twomem_<subsystem>_<thing>, and a folder that LEVELS does not name is an error, so a new
subsystem is placed in the order before anything can use it.
Only `use twomem_...` statements count (intrinsic modules, omp_lib and mpi_f08 are not ours).
Standard library only: it runs before anything is built. docs/architecture.md, "Layers".
"""
from __future__ import annotations

import argparse
import re
import sys
from collections import Counter
from pathlib import Path

# The one statement of the order, lowest level first. A subsystem sees every level below its
# own; two subsystems on one level do not see each other.
LEVELS: list[list[str]] = [
    ["base"],
    ["input", "mesh", "linalg", "hdf5"],
    ["fem", "io"],
    ["newton", "estimate"],
    ["app"],
]
# subsystems whose folder holds variants of one module, built one at a time
VARIANT_DIRS = {"mpi", "serial"}

USE = re.compile(r"^\s*use\s*(?:,\s*non_intrinsic\s*)?(?:::)?\s*(twomem_[a-z0-9_]+)", re.IGNORECASE)
MODULE = re.compile(r"^\s*module\s+(?!procedure\b)(twomem_[a-z0-9_]+)\s*(?:!.*)?$", re.IGNORECASE)

LEVEL_OF = {name: i for i, level in enumerate(LEVELS) for name in level}


def sources(src: Path) -> list[Path]:
    return sorted(p for p in src.rglob("*") if p.is_file() and p.name.endswith((".f90", ".f90.in")))


def scan(root: Path):
    """The subsystem defining each module, every `use twomem_...` as (file, line, user, its
    subsystem, used module), and the problems of placement and naming."""
    src = root / "src" / "fortran"
    owner: dict[str, str] = {}
    uses: list[tuple[Path, int, str, str, str]] = []
    problems: list[str] = []
    for path in sources(src):
        rel = path.relative_to(root)
        parts = path.relative_to(src).parts
        if len(parts) < 2:
            problems.append(f"{rel}: outside any subsystem folder (src/fortran/<subsystem>/)")
            continue
        sub = parts[0]
        if len(parts) > 2 and parts[1] not in VARIANT_DIRS:
            problems.append(f"{rel}: nested folder; only {'/'.join(sorted(VARIANT_DIRS))} hold variants of a module")
        if sub not in LEVEL_OF:
            problems.append(f"{rel}: subsystem '{sub}' is not placed in the order (LEVELS in scripts/check_layers.py)")
        unit = path.name.split(".")[0]
        for number, text in enumerate(path.read_text(encoding="utf-8", errors="replace").splitlines(), start=1):
            m = MODULE.match(text)
            if m:
                unit = m.group(1).lower()
                owner[unit] = sub
                if not unit.startswith(f"twomem_{sub}_"):
                    problems.append(f"{rel}:{number}: module {unit} lives in {sub}/ but is not named twomem_{sub}_<thing>")
            m = USE.match(text)
            if m:
                uses.append((rel, number, unit, sub, m.group(1).lower()))
    return owner, uses, problems


def subsystem_of_module(name: str, owner: dict[str, str]) -> str:
    if name in owner:
        return owner[name]
    # not defined in the tree (a typo the compiler will report, or a generated module): its name
    return name.split("_")[1] if name.count("_") >= 2 else "?"


def check(root: Path) -> list[str]:
    owner, uses, problems = scan(root)
    for rel, number, user, mine, used in uses:
        theirs = subsystem_of_module(used, owner)
        if mine == theirs or mine not in LEVEL_OF:
            continue
        if theirs not in LEVEL_OF:
            problems.append(f"{rel}:{number}: {user} uses {used}, of subsystem '{theirs}' that is not in the order")
        elif LEVEL_OF[theirs] >= LEVEL_OF[mine]:
            where = "above" if LEVEL_OF[theirs] > LEVEL_OF[mine] else "beside"
            problems.append(f"{rel}:{number}: {user} uses {used}: {mine} (level {LEVEL_OF[mine]}) may not use "
                            f"{theirs} (level {LEVEL_OF[theirs]}, {where} it)")
    return problems


def graph(root: Path) -> str:
    owner, uses, _ = scan(root)
    edges: Counter[tuple[str, str]] = Counter()
    for _, _, _, mine, used in uses:
        theirs = subsystem_of_module(used, owner)
        if mine != theirs:
            edges[(mine, theirs)] += 1
    out = ["levels, highest first (a subsystem uses its own modules and lower levels only):"]
    for i in reversed(range(len(LEVELS))):
        out.append(f"  {i}  " + "  ".join(LEVELS[i]))
    out.append("edges (user -> used, number of `use` statements):")
    known = [s for level in reversed(LEVELS) for s in level]
    for a in known + sorted({a for a, _ in edges} - set(known)):
        row = sorted(((b, n) for (x, b), n in edges.items() if x == a), key=lambda e: (-LEVEL_OF.get(e[0], 99), e[0]))
        if row:
            out.append(f"  {a:<8} -> " + ", ".join(f"{b} {n}" for b, n in row))
    return "\n".join(out)


def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--root", type=Path, default=Path(__file__).resolve().parents[1],
                    help="source tree holding src/fortran (default: this checkout)")
    ap.add_argument("--graph", action="store_true", help="print the subsystem graph instead of checking")
    args = ap.parse_args(argv)
    src = args.root / "src" / "fortran"
    if not src.is_dir():
        print(f"check_layers: {src}: no such directory", file=sys.stderr)
        return 2
    if args.graph:
        print(graph(args.root))
        return 0
    problems = check(args.root)
    for p in problems:
        print(f"layering: {p}")
    if problems:
        return 1
    n = len(sources(src))
    print(f"layering: {n} files, every use goes to a lower level or within a subsystem")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
