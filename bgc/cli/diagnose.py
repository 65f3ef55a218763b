"""``bgc diagnose``: a recorded run or a simulated scenario diagnosed, and its report."""

from __future__ import annotations

import argparse
from pathlib import Path

from ..errors import BgcError
from .common import (Progress, add_backend_option, add_data_options, add_prior_option, add_workers_option, backend_note,
    check_times, parse_noise, refuse_input_in_output, rows_of, seed, workers, write_report)


def add_parser(sub) -> None:
    p = sub.add_parser("diagnose", help="detect, isolate and identify a fault in a run (report and plots)")
    p.add_argument("model", metavar="MODEL")
    p.add_argument("--data", metavar="RUN.csv",
                   help="a recorded run (a CSV as bgc simulate writes), or a folder or a glob pattern of a logger's "
                        "files, read in time order as one run")
    p.add_argument("--scenario", metavar="NAME:KIND:MAGNITUDE@TIME",
                   help="simulate this fault (or 'none'), then diagnose, e.g. R_pipe:incipient:0.5@165; MAGNITUDE "
                        "is an abrupt fault's bias (in the parameter's units) or an incipient fault's slope (per "
                        "unit of time)")
    p.add_argument("--filter", choices=["gpf", "apf", "opf", "ckf"], default="gpf",
                   help="gpf (the thesis's generic filter), apf (auxiliary), opf (the locally optimal proposal) or "
                        "ckf (cubature Kalman filters alone, no particles: exact on plants linear in their states, "
                        "for sensors sharp against the process noise, where particle filters degenerate)")
    p.add_argument("--decompose", action="store_true",
                   help="diagnose on the model's submodels (as bgc compile --decompose splits it): each fault "
                        "weighed on the submodels it touches, by cubature Kalman filters (ckf, in place of the "
                        "default gpf; apf and opf are refused); the cost grows with what a fault touches, not with "
                        "the plant")
    p.add_argument("--particles", type=int, default=1000)
    p.add_argument("--seed", type=seed, default=0, help="random seed, an integer >= 0")
    p.add_argument("--noise", metavar="process=Q,measurement=R",
                   help="relative noise levels of the data (and of a simulated scenario); default: the model's. "
                        "measurement=R replaces every sensor's own level; process=Q scales the states' levels")
    p.add_argument("--steps", type=int, default=None, help="with --scenario: samples to simulate")
    p.add_argument("--generated", metavar="DIR",
                   help="use the package bgc compile wrote there (default: generate one for this run)")
    p.add_argument("--identify", choices=["kalman", "filter"], default="kalman",
                   help="kalman (default): weigh the hypotheses and size the fault with the magnitude held static, "
                        "by cubature Kalman filters on a grid of onsets and magnitudes; filter: by the particle "
                        "filters' own magnitude state (the thesis's method)")
    p.add_argument("--rank", action="store_true",
                   help="with --identify filter: weigh the surviving hypotheses by particle filters with the fault "
                        "magnitude held static, on a grid")
    p.add_argument("--refine", action="store_true",
                   help="estimate the fault magnitude by the particle filters' marginal likelihood on a grid "
                        "(slower; a check of the estimate for strongly nonlinear plants)")
    add_data_options(p)
    add_prior_option(p)
    p.add_argument("-o", "--output", metavar="DIR", help="report folder (default: MODEL-diagnosis)")
    add_backend_option(p)
    add_workers_option(p)
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from .. import api
    from ..diagnosis.options import DiagnosisOptions

    if (args.data is None) == (args.scenario is None):
        raise BgcError("give --data RUN.csv or --scenario NAME:KIND:MAGNITUDE@TIME", None,
                       "e.g. --scenario R_pipe:incipient:0.5@165, or --scenario none for a fault-free run")
    if args.data is not None and args.steps is not None:
        raise BgcError("--steps applies to --scenario: a recorded run has its own length", None,
                       "drop --steps, or simulate a scenario")
    check_times(args, ("horizon", "gap"))
    refuse_input_in_output(args.data, Path(args.output) if args.output else None)
    process, measurement = parse_noise(args.noise)
    progress = Progress()
    try:
        if args.decompose and args.filter not in ("gpf", "ckf"):  # gpf: the default, replaced
            raise BgcError(f"--decompose with --filter {args.filter}: the submodels are weighed by cubature Kalman "
                           "filters", None, "drop --filter, or give --filter ckf")
        options = DiagnosisOptions(filter="ckf" if args.decompose else args.filter,
                                   particles=args.particles, seed=args.seed,
                                   identify=args.identify, rank=args.rank, refine=args.refine,
                                   horizon=args.horizon, gap=args.gap, recheck=args.recheck, no_fault=args.no_fault,
                                   input_timing=args.input_timing, detectors=args.detect, workers=workers(args))
        steps = args.steps if args.scenario is not None else rows_of(args.data)  # auto's estimate of the work
        session = api.open(args.model, process_noise=process, measurement_noise=measurement,
                           generated=args.generated, prior_scale=args.prior_scale, backend=args.backend,
                           work=(max(args.particles, 1), steps if steps and steps > 0 else None))
        backend_note(session, args)
        if args.columns is not None and args.data is None:
            raise BgcError("--columns applies to --data: a column map is for a logger's file", None,
                           "drop --columns, or give --data")
        r = api.diagnose(session, data=args.data, scenario=args.scenario, seed=args.seed, steps=args.steps,
                         options=options, progress=progress, columns=args.columns, decompose=args.decompose)
    finally:
        progress.close()
    write_report(r, args.output or f"{r.model}-diagnosis", "diagnose")
    return 0
