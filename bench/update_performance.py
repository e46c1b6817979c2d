#!/usr/bin/env python3
"""Regenerate the tables of docs/performance.md by running the commands written above them.

    .venv/bin/python bench/update_performance.py [ID ...] [--list] [--dry-run] [--file docs/performance.md]

Every measured table of docs/performance.md sits in a block

    <!-- bench ID -->            (or <!-- bench ID all -->)
    ```sh
    COMMAND                      one or more shell commands, run from the repository's root
    ```
    *Measured at ...*            everything from here to the end marker is regenerated
    | table |
    <!-- /bench -->

For each block named (all blocks without an ID), the script runs its commands in order with
bash and replaces the block's measured part with a line naming the commit, the date and the
machine, and the markdown table the commands printed: the first table of each command's
output, the rows of later commands appended to the first one's (so that a table of several
commands, such as the scaling series of both C-functions, stays one table). A block marked
`all` takes a command's whole report instead (from its first table or bold heading on), for
the scripts that print several tables with their headings (bench/mpi_scaling.py). The
benchmarks' own progress goes to stderr, which passes through. Commit first: the line names
the commit that was measured, and says so when the work tree had uncommitted changes.
"""
from __future__ import annotations

import argparse
import datetime
import os
import re
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
BLOCK = re.compile(r"(<!-- bench (?P<id>[\w-]+)(?P<all> all)? -->\n```sh\n(?P<cmds>.*?)\n```\n)(?P<body>.*?)(<!-- /bench -->)",
                   re.S)


def commands(text: str) -> list[str]:
    """The block's commands, a trailing backslash joining a line to the next."""
    return [c.strip() for c in re.sub(r"\\\n\s*", " ", text).splitlines() if c.strip()]


def first_table(output: str) -> list[str]:
    lines, table = output.splitlines(), []
    for line in lines:
        if line.startswith("|"):
            table.append(line)
        elif table:
            break
    return table


def whole_report(output: str) -> list[str]:
    lines = output.splitlines()
    start = next((i for i, line in enumerate(lines) if line.startswith(("|", "**"))), len(lines))
    return [line.rstrip() for line in lines[start:]]


def machine() -> str:
    info = Path("/proc/cpuinfo").read_text() if Path("/proc/cpuinfo").exists() else ""
    model = re.search(r"^model name\s*:\s*(.*)$", info, re.M)
    virtual = " virtual machine" if re.search(r"^flags\s*:.*\bhypervisor\b", info, re.M) else ""
    return f"a {os.cpu_count()}-core {model.group(1).strip() if model else 'machine'}{virtual}"


def provenance(doc: Path) -> str:
    git = ["git", "-C", str(ROOT)]
    commit = subprocess.run([*git, "rev-parse", "--short", "HEAD"], capture_output=True, text=True).stdout.strip()
    own = str(doc.relative_to(ROOT)) if doc.is_relative_to(ROOT) else None
    changes = [line for line in subprocess.run([*git, "status", "--porcelain"], capture_output=True,
                                               text=True).stdout.splitlines()
               if line[3:] != own]
    dirty = " with uncommitted changes" if changes else ""
    return (f"*Measured at {commit or 'an unknown commit'}{dirty} ({datetime.date.today().isoformat()}) "
            f"on {machine()}, release build.*")


def measure(block: re.Match, doc: Path) -> str:
    body: list[str] = []
    for i, cmd in enumerate(commands(block["cmds"])):
        print(f"update_performance: {block['id']}: {cmd}", file=sys.stderr, flush=True)
        proc = subprocess.run(["bash", "-c", cmd], cwd=ROOT, stdout=subprocess.PIPE, text=True)
        if proc.returncode != 0:
            sys.exit(f"update_performance: {block['id']}: `{cmd}` exited {proc.returncode}")
        if block["all"]:
            part = whole_report(proc.stdout)
            body += ([""] if body else []) + part
        else:
            part = first_table(proc.stdout)
            body += part if i == 0 else part[2:]
        if not part:
            sys.exit(f"update_performance: {block['id']}: `{cmd}` printed no table")
    return "\n" + provenance(doc) + "\n\n" + "\n".join(body) + "\n"


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("ids", nargs="*", help="the blocks to regenerate (default: all)")
    ap.add_argument("--file", default=str(ROOT / "docs" / "performance.md"))
    ap.add_argument("--list", action="store_true", help="list the blocks and their commands, run nothing")
    ap.add_argument("--dry-run", action="store_true", help="say what would run, change nothing")
    args = ap.parse_args()
    doc = Path(args.file).resolve()
    text = doc.read_text()
    blocks = {m["id"]: m for m in BLOCK.finditer(text)}
    unknown = [i for i in args.ids if i not in blocks]
    if unknown:
        sys.exit(f"update_performance: no block {', '.join(unknown)} in {doc} (--list shows them)")
    chosen = args.ids or list(blocks)
    if args.list or args.dry_run:
        for name in chosen:
            print(f"{name}:" + "".join(f"\n    {c}" for c in commands(blocks[name]["cmds"])))
        return 0
    for name in chosen:
        # measured one at a time, and the file rewritten after each, so that an interrupted
        # series keeps the tables already measured
        text = doc.read_text()
        block = next(m for m in BLOCK.finditer(text) if m["id"] == name)
        text = text[:block.start("body")] + measure(block, doc) + text[block.end("body"):]
        doc.write_text(text)
        print(f"update_performance: {name}: table written to {doc}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
