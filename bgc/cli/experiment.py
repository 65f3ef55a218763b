"""``bgc experiment``: a campaign of diagnoses, and its tables."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from ..errors import printable
from .common import above_zero, add_backend_option, positive, status


def add_parser(sub) -> None:
    p = sub.add_parser("experiment", help="run a campaign of diagnoses (grid or randomised) and write its tables")
    p.add_argument("config", metavar="CONFIG.yaml")
    p.add_argument("-o", "--output", metavar="DIR", help="results folder (default: out/CAMPAIGN); an interrupted "
                   "campaign resumes from it")
    p.add_argument("--scheduler", metavar="ADDRESS", help="run on this Dask distributed scheduler "
                   "(e.g. tcp://10.0.0.5:8786) instead of local processes")
    p.add_argument("--workers", type=positive, default=None,
                   help="local processes (default: one per core; at most 4 per core, and never more than the runs "
                        "to do)")
    p.add_argument("--max-runs", type=positive, default=100_000, metavar="N",
                   help="refuse a campaign of more than N runs (default 100000), counted before any is expanded")
    p.add_argument("--connect-timeout", type=above_zero, default=10.0, metavar="SECONDS",
                   help="with --scheduler: seconds to wait for the scheduler to answer (default 10; a refused "
                        "connection fails at once)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    add_backend_option(p)
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from ..experiment import campaign
    from ..experiment import campaign_file, dispatch, runs_csv
    from ..output import tables
    from ..model import package as packages

    # a backend asked for by name and not installed is refused before the models compile
    if args.scheduler is None and packages.chosen_by_name(args.backend):
        packages.resolve_backend(args.backend)

    # what can be refused without the models: before they compile
    dispatch.check_workers(args.workers, "--workers")
    if args.scheduler:
        dispatch.check_scheduler(args.scheduler, args.connect_timeout)
        if args.workers is not None:
            print("warning: --workers is for local processes: the Dask cluster's own workers run the campaign",
                  file=sys.stderr)
    c = campaign_file.load_campaign(args.config, max_runs=args.max_runs)
    # local workers get a name (numba compiled once, before they start), as run_campaign would give them;
    # a Dask cluster's workers choose by what they have installed
    backend, why = dispatch.campaign_backend(c.specs, args.backend, args.scheduler)
    if why is not None:
        status(args, f"backend {backend} ({why}, over the campaign's {len(c.specs)} runs)")
    out = Path(args.output or Path("out") / c.name)
    folder = printable(str(out))

    def started(s: campaign.CampaignStart) -> None:
        if s.quarantined:  # warnings: what was set aside, what the machine's memory allows
            print(f"warning: {s.quarantined} line{'s' if s.quarantined > 1 else ''} of {folder}/{runs_csv.RUNS} "
                  f"could not be read: kept as they were in {printable(str(s.quarantine))} (a run among them runs "
                  "again)", file=sys.stderr)
        if s.workers is not None and s.limited_by == "memory":
            print(f"warning: starting {s.workers} local processes: the available memory holds no more at "
                  f"{dispatch.WORKER_MEMORY // 2**20} MiB each", file=sys.stderr)
        elif s.workers is not None and s.limited_by == "runs" and s.requested is not None:
            status(args, f"--workers {s.requested}: starting {s.workers} local "
                         f"process{'es' if s.workers > 1 else ''}, one per run to do")
        where = (f"the Dask cluster at {printable(args.scheduler)}" if s.workers is None else
                 f"{s.workers} local process{'es' if s.workers != 1 else ''}")
        plan = f"{s.total} runs" if not s.reused else f"{s.total} runs ({s.reused} done before, {s.todo} to run)"
        if s.todo:
            status(args, f"campaign {c.name}: {plan} on {where}, results in {folder}/")
        else:
            status(args, f"campaign {c.name}: {plan}: every run done before, results in {folder}/")

    try:
        r = campaign.run_campaign(c, out, scheduler=args.scheduler, workers=args.workers,
                                  progress=None if not args.no_progress else False,
                                  connect_timeout=args.connect_timeout, on_start=started,
                                  backend=backend)
    except KeyboardInterrupt:
        print(f"bgc: interrupted; finished runs are in {folder}/{runs_csv.RUNS}: run the same command "
              "to resume", file=sys.stderr)
        return 130
    print(tables.summary_markdown(list(r.rows)), end="")
    kept = (f"; {r.quarantined} unreadable line{'s' if r.quarantined > 1 else ''} of {runs_csv.RUNS} kept in "
            f"{printable(str(r.quarantine))}" if r.quarantined else "")
    print(f"{c.name}: {r.ran} runs done, {r.reused} reused from an earlier run, {r.failed} failed "
          f"({r.seconds:.1f} s); tables in {folder}/tables.md, the page with tables and plots in "
          f"{folder}/report.html, plots in {folder}/plots/{kept}")
    return 1 if r.failed and r.failed == r.ran and r.ran else 0
