"""``bgc check``: every compiler stage of each model, and a summary of it."""

from __future__ import annotations

import argparse
import sys

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
            c = pipeline.check_model(path)
        except BgcError as exc:
            print_errors(exc)
            status = 1
            continue
        if isinstance(c, pipeline.Hybrid):
            print(render.hybrid_summary(c.model, c.modes))
            continue
        print(render.check_summary(c.equations, c.numerics))
        if c.numerics.faults:
            for line in unseen_warnings(path, c):
                print(f"warning: {line}", file=sys.stderr)
    return status


def unseen_warnings(path: str, compiled) -> list[str]:
    """What ``bgc check`` warns of the faults bgc's detector would most often
    miss at the declared noise and inputs (:func:`bgc.api.detection.unseen`
    of the model file ``path``'s compilation), with what would help."""
    from ..api.detection import unseen
    from ..errors import printable

    missed = unseen(compiled)
    if not missed:
        return []
    where = printable(path)
    threshold = missed[0].threshold
    bursts = [u.name for u in missed if u.burst]
    still = [u.name for u in missed if u.still]
    weak = [f"{u.name} (size {u.size:.3g}: {u.reach:.2g})" for u in missed if not u.still and not u.burst]
    out = []
    if bursts:
        out.append(f"{where}: {', '.join(bursts)} {'moves' if len(bursts) == 1 else 'move'} no reading's mean: "
                   "the detector's default mean test sees a burst of noise late or by chance; its variance test "
                   "sees it within a few samples (bgc diagnose or monitor --detect variance, or all)")
    if still:
        out.append(f"{where}: with the model's inputs the plant settles and {', '.join(still)} "
                   f"{'changes' if len(still) == 1 else 'change'} nothing the sensors read: bgc's detector will not "
                   f"see {'it' if len(still) == 1 else 'them'} (a storage element's parameter at steady state, for "
                   "one); an input test that moves the plant shows it (bgc distinguish MODEL --scenario ... --input "
                   "NAME='{signal: prbs, ...}'), or a sensor on what is stored")
    if weak:
        out.append(f"{where}: at the declared noise, bgc's detector will miss {', '.join(weak)} in about half "
                   f"the runs or more: at the size its prior expects, the windowed statistic's mean stays under the "
                   f"threshold {threshold:.2f} (closed form, the fault from mid-run); calibrated noise (bgc calibrate "
                   "--estimate noise), a sensor nearer it or an input test would help; bgc distinguish --scenario "
                   "measures it")
    return out
