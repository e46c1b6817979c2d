"""Command line: python -m twomem_post {compare,plot,study} ...

  compare A.h5 B.h5 [--rtol R --atol A]        differences between two result files
  plot RESULT.h5 -o DIR [--format png|pdf]     figures of one result file
  study CASE.nml -o DIR [sweep] [--methods ...] runs over meshes and methods, CSV and figures

Exit status: what the subcommand returns (compare: 1 when the files differ; study: 1 when a run
failed or did not converge); 2 for a usage error or a file that is unreadable or not a twomem
result (one line on stderr: ``twomem_post: error: <file or option>: <why>``); 3 for a missing
executable and other I/O errors.
"""
from __future__ import annotations

import argparse
import sys

from . import compare, plot, study
from .errors import PostError


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m twomem_post",
                                     description="Post-processing of twomem result files")
    sub = parser.add_subparsers(dest="command", required=True)
    compare.add_parser(sub)
    plot.add_parser(sub)
    study.add_parser(sub)
    args = parser.parse_args(argv)
    try:
        return args.func(args)
    except PostError as exc:
        print(f"twomem_post: error: {exc.where}: {exc.why}", file=sys.stderr)
        return exc.status
    except (OSError, KeyError) as exc:
        print(f"twomem_post: error: {exc}", file=sys.stderr)
        return 3


if __name__ == "__main__":
    sys.exit(main())
