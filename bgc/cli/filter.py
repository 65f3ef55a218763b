"""``bgc filter``: one generated filter over a recorded run."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from ..errors import printable
from .common import add_backend_option, add_columns_option, fault_model, seed, status


class _Renamed(argparse.Action):
    """``--filter``, and its old name ``--method`` with a warning on stderr (the filter has one name)."""

    def __call__(self, parser, namespace, values, option_string=None):
        if option_string == "--method":
            print("bgc filter: --method is deprecated, its name is --filter", file=sys.stderr)
        setattr(namespace, self.dest, values)


def add_parser(sub) -> None:
    p = sub.add_parser("filter", help="run a generated particle filter (GPF/APF) over a recorded run")
    p.add_argument("model", metavar="MODEL")
    p.add_argument("run_csv", metavar="RUN.csv", help="a CSV written by bgc simulate")
    p.add_argument("--fault", metavar="PARAM:KIND", help="track with this fault model (default: nominal)")
    p.add_argument("--filter", "--method", dest="method", choices=["gpf", "apf", "opf", "both"], default="both",
                   action=_Renamed, help="gpf, apf, opf (the locally optimal proposal) or both (gpf and apf); "
                                         "--method is its old name, as bgc diagnose's --filter")
    p.add_argument("--particles", type=int, default=200)
    p.add_argument("--seed", type=seed, default=0, help="random seed, an integer >= 0")
    p.add_argument("--start", type=float, metavar="T",
                   help="with --fault: track the nominal model until T, then the fault model (its fault from the "
                        "sample at T)")
    p.add_argument("--generated", default="generated", metavar="DIR",
                   help="where bgc compile wrote the package (its -o DIR; default: generated)")
    p.add_argument("--plot", metavar="FILE.png")
    p.add_argument("--hidden-mode", action="store_true",
                   help="a model with modes: follow its guards and timed transitions as if the run had no mode "
                        "column, and say how often the most probable mode is the run's")
    add_columns_option(p)
    add_backend_option(p)
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    import numpy as np

    from ..api import cache
    from ..api.session import choose_backend, reading_of
    from ..ir import NUMBA_PACKAGE
    from ..output import artifacts
    from ..data.clock import Clock
    from ..data import runs
    from ..analysis import track
    from ..model import package as packages
    from ..model import warmup

    c = cache.open_model(args.model).view
    run = runs.read_run(args.run_csv, reading_of(c, args.columns))
    track.check_run_of(run, c.model.name, args.run_csv)
    numba = Path(args.generated) / c.model.name / NUMBA_PACKAGE
    methods = 2 if args.method == "both" else 1
    backend, why = choose_backend(args.backend, numba, max(args.particles, 1) * len(run.time) * methods)
    status(args, f"backend {backend} ({why})")
    package = packages.load_package(args.generated, c.model.name, args.model, backend=backend)
    name = fault_model(c, args.fault) if args.fault else "nominal"
    seconds, compiled, loaded = warmup.warm_up(package, steps=(name,))  # the filtered model's whole step
    if backend == "numba":
        cache.mark_warm(numba, compiled + loaded)
    if compiled:
        status(args, f"numba backend: {compiled} kernels compiled in {seconds:.1f} s (kept in numba's disk cache)")
    elif loaded:
        status(args, f"numba backend: {loaded} kernels loaded from numba's disk cache in {seconds:.1f} s")
    track.check_request(run, package, name, args.particles, args.start)
    results = []
    for method in (["gpf", "apf"] if args.method == "both" else [args.method]):
        r = track.track(run, package, name, method, args.particles, args.seed, args.start, args.hidden_mode)
        results.append(r)
        rmse = ", ".join(f"{x} {v:.4g}" for x, v in r.rmse(run).items())
        print(f"{method.upper()} on {name}, N = {args.particles}: {len(r.time)} steps in {r.seconds:.3f} s, "
              f"mean ESS {float(np.mean(r.ess)):.0f}, resampled {int(r.resampled.sum())} times, "
              f"recoveries {r.recoveries}")
        print("  RMSE vs truth: " + (rmse or "no truth in the run"))
        modes = getattr(package.MODELS[name], "MODES", ())
        last = ", ".join(f"mode {round(m)} ({modes[round(m) - 1]})" if x == "mode" and modes else
                         f"{x} {m:.4g} +- {s:.2g}" for x, m, s in zip(r.state_names, r.mean[-1], r.std[-1]))
        print(f"  final estimate: {last}")
        agreement = r.mode_agreement(run) if args.hidden_mode else None
        if agreement is not None:
            right = int(round(agreement * len(r.time)))
            print(f"  mode: the most probable mode is the run's at {right} of {len(r.time)} samples "
                  f"({100 * agreement:.2f} %)")
        est = track.fault_estimate(r, package, run, c.labels.per_time)
        if est is not None:
            true_text = ""
            if est.truth is not None:
                true_text = f" (true {est.truth:.4g}, error {100 * est.relative_error:.1f} %)"
            when = Clock.of(run.time, c.labels.time_unit).text(est.time)
            print(f"  estimate of {est.what} at t = {when}: {est.value:.4g} +- {est.std:.2g}{true_text}")
    if args.plot:
        from ..output import plots

        artifacts.write_file(Path(args.plot), plots.tracking_figure(run, results, "png", c.labels))
        print(f"wrote {printable(args.plot)}")
    return 0
