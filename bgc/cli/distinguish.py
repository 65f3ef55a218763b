"""``bgc distinguish``: which faults the data of a scenario can tell apart, before any data."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from ..errors import BgcError, printable
from .common import (Progress, above_zero, add_signal_option, at_least, detectors, parse_noise, positive, seed,
                     signals_of)

nonnegative = at_least(0, "{value} is negative: give 0 or more runs")


def add_parser(sub) -> None:
    p = sub.add_parser("distinguish", help="predict which faults the data of a scenario can tell apart (before "
                       "any data: noise, size, onset and kind of the fault)")
    p.add_argument("model", metavar="MODEL")
    p.add_argument("--scenario", metavar="NAME:KIND:MAGNITUDE@TIME",
                   help="one fault, e.g. R_pipe:incipient:0.5@165 (default: every candidate, kind and direction)")
    p.add_argument("--change", type=above_zero, default=0.3,
                   help="without --scenario: the relative change of each parameter (a drift reaches it at the end "
                        "of the run; default 0.3)")
    p.add_argument("--at", type=above_zero, default=0.5,
                   help="without --scenario: the onset, as a fraction of the run (default 0.5)")
    p.add_argument("--noise", metavar="process=Q,measurement=R", help="relative noise levels (default: the model's)")
    p.add_argument("--steps", type=positive, default=None, help="samples of the run (default: the model's; at most "
                   "what the prediction's memory allows, 2 GB: bgc says how many)")
    p.add_argument("--detector-runs", type=nonnegative, default=None, metavar="N",
                   help="with --scenario: also simulate N runs and count how often bgc's own detector alarms on the "
                        "fault (default 50; 0: skip)")
    p.add_argument("--seed", type=seed, default=0, help="the first seed of those runs, an integer >= 0")
    p.add_argument("--detect", type=detectors, default=("mean",), metavar="TESTS",
                   help="the tests of bgc's detector on those runs, as bgc diagnose --detect (default: mean)")
    add_signal_option(p)
    p.add_argument("--modes", metavar="MODE@TIME,...",
                   help="a model with modes: the controlled changes of mode over the run, e.g. closed@0.5,open@3 "
                        "(default: the modes its guards and timed transitions reach; the detector's runs are not "
                        "built for such a model and are skipped)")
    p.add_argument("--format", choices=["text", "json"], default="text")
    p.add_argument("-o", "--output", metavar="FILE", help="write to FILE instead of printing")
    p.add_argument("--plot", metavar="FILE.png", help="also draw the probabilities as a heat map")
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from .. import api
    from ..api.detection import RUNS
    from ..output import artifacts, plots, render

    process, measurement = parse_noise(args.noise)
    for path, what in ((args.output, "the report"), (args.plot, "the plot")):  # refused before the work, not after
        if path:
            artifacts.check_writable(Path(path), what)
    progress = Progress("distinguish")
    try:
        from ..compiler.load import declares_modes

        hybrid = declares_modes(args.model)
        runs = args.detector_runs if args.detector_runs is not None else (RUNS if args.scenario and not hybrid else 0)
        if runs and not args.scenario:
            raise BgcError("--detector-runs applies to --scenario: one fault's runs are simulated", None,
                           "give --scenario NAME:KIND:MAGNITUDE@TIME, or drop --detector-runs")
        r = api.distinguishability(args.model, args.scenario, change=args.change, at=args.at,
                                   process_noise=process, measurement_noise=measurement, steps=args.steps,
                                   progress=progress, detector_runs=runs, seed=args.seed,
                                   inputs=dict(_signals(args)) or None, modes=args.modes, detectors=args.detect)
    finally:
        progress.close()
    text = render.to_json(render.distinguishability_json(r)) if args.format == "json" else \
        render.distinguishability_text(r)
    if args.output:
        artifacts.write_file(Path(args.output), artifacts.mark_text(text, args.format, r.source))
        print(f"wrote {printable(args.output)}")
    else:
        sys.stdout.write(text)
        sys.stdout.flush()
    if args.plot:
        artifacts.write_file(Path(args.plot), plots.distinguishability_figure(r, "png"))
        print(f"wrote {printable(args.plot)}")
    return 0


def _signals(args: argparse.Namespace) -> tuple:
    """The ``--input`` options, checked against the model's inputs."""
    if not args.signals:
        return ()
    from ..api import cache

    return signals_of(args.signals, tuple(u.name for u in cache.open_model(args.model).view.model.inputs))
