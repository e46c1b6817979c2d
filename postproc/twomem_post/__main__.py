"""Command line: python -m twomem_post {compare,plot} ...

  compare A.h5 B.h5 [--rtol R --atol A]   differences between two result files
  plot RESULT.h5 -o DIR [--format png|pdf] figures of one result file

Exit status: what the subcommand returns (compare: 1 when the files differ); 2 for a usage
error or a file that is unreadable or not a twomem result (one line on stderr:
``twomem_post: error: <file>: <why>``); 3 for other I/O errors.
"""
from __future__ import annotations

import argparse
import sys

from . import compare, plot


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m twomem_post",
                                     description="Post-processing of twomem result files")
    sub = parser.add_subparsers(dest="command", required=True)
    compare.add_parser(sub)
    plot.add_parser(sub)
    args = parser.parse_args(argv)
    try:
        return args.func(args)
    except plot.ResultError as exc:
        print(f"twomem_post: error: {exc.path}: {exc.why}", file=sys.stderr)
        return 2
    except (OSError, KeyError) as exc:
        print(f"twomem_post: error: {exc}", file=sys.stderr)
        return 3


if __name__ == "__main__":
    sys.exit(main())
