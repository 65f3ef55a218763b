"""``bgc check``: every compiler stage of each model, and a summary of it."""

from __future__ import annotations

import argparse

from ..errors import BgcError
from .common import print_errors


def add_parser(sub) -> None:
    p = sub.add_parser("check", help="check models through every compiler stage and print a summary")
    p.add_argument("models", nargs="+", metavar="MODEL", help="model files (YAML)")
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from .. import pipeline
    from ..output import render

    status = 0
    for path in args.models:
        try:
            c = pipeline.compile_model(path)
        except BgcError as exc:
            print_errors(exc)
            status = 1
            continue
        print(render.check_summary(c.equations, c.numerics))
    return status
