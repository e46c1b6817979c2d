"""Command line: python -m twomem_post compare A.h5 B.h5 [--rtol R --atol A]."""
from __future__ import annotations

import argparse
import sys

from . import compare


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m twomem_post",
                                     description="Post-processing of twomem result files")
    sub = parser.add_subparsers(dest="command", required=True)
    compare.add_parser(sub)
    args = parser.parse_args(argv)
    try:
        return args.func(args)
    except (OSError, KeyError) as exc:
        print(f"twomem_post: error: {exc}", file=sys.stderr)
        return 3


if __name__ == "__main__":
    sys.exit(main())
