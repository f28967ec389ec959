"""The ``drivetrain`` command line.

Each subcommand lives in its own module and is imported lazily, so that ``drivetrain --help`` stays fast
and a missing optional piece does not break the others.
"""
from __future__ import annotations

import argparse
import sys


def _cmd_build_fmus(args: argparse.Namespace) -> int:
    from drivetrain.fmubuild import build_all

    paths = build_all(args.out, only=args.only)
    for p in paths:
        print(p)
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="drivetrain", description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True)

    p = sub.add_parser("build-fmus", help="build every FMU of the project into fmus/ (or --out DIR)")
    p.add_argument("--out", default="fmus", help="output directory (default: fmus)")
    p.add_argument("--only", nargs="*", default=None, help="build only these FMUs (model names)")
    p.set_defaults(func=_cmd_build_fmus)

    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except KeyboardInterrupt:
        return 130


if __name__ == "__main__":
    sys.exit(main())
