"""Experiment campaigns: many diagnoses of simulated runs, their metrics and tables.

A campaign file (YAML, ``schemas/campaign.schema.json``, documented in
``docs/experiments.md``) lists groups of runs: a model, scenarios (a grid of
``NAME:KIND:MAGNITUDE@TIME`` and ``none``) or randomised fault draws, times
filters, particle counts, noise levels and seeds. :func:`load_campaign` reads
and checks it (located one-line errors, like a model) and expands it into
:class:`RunSpec` s; :func:`run_one` simulates one scenario, diagnoses it with
:func:`bgc.diagnose` and measures the result (:mod:`bgc.experiment.metrics`);
:func:`run_campaign` runs the specs on local processes or on an existing Dask
distributed cluster, appends each row to ``runs.csv`` as it completes (an
interrupted campaign resumes from it), shows a progress bar and writes the
tables (:mod:`bgc.output.tables`) and plots at the end.

Every run is independent and seeded by its spec, so the same campaign gives
the same rows on one process, on many, or on a cluster (run times aside).

A campaign never runs away: its runs are counted before anything is expanded
(at most :data:`MAX_RUNS` unless the caller raises the limit), it starts no
more local processes than the runs to do, the cores (:data:`WORKERS_PER_CORE`
each) and the memory hold, its workers end when the campaign's process dies,
and a Dask scheduler that refuses the connection fails at once, one that
does not answer after a timeout (:data:`CONNECT_TIMEOUT` by default). It
never loses a row: ``runs.csv`` is read
line by line, every intact row is kept, and a line it cannot read is set
aside in a new ``runs.unread-N.csv`` beside it.
"""

from __future__ import annotations

import os
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable

import numpy as np

from ..errors import (ArgumentTypeError, ArgumentValueError, ExperimentError, printable)
from ..model import DEFAULT_BACKEND

if TYPE_CHECKING:
    pass

from .campaign_file import Campaign
from .runs_csv import set_aside, RUNS, columns, csv_header, csv_row, full_row, read_runs
from .dispatch import (campaign_backend, compile_models, run_locally, run_on_dask, CONNECT_TIMEOUT, check_timeout,
                       check_workers, local_workers)

#: What the end of a campaign writes beside ``runs.csv`` (:func:`write_outputs`).
TABLES, SUMMARY, PLOTS, REPORT = "tables.md", "summary.json", "plots/", "report.html"


@dataclass(frozen=True, slots=True)
class CampaignStart:
    """What :func:`run_campaign` is about to do, once it has read its folder
    (given to its ``on_start`` before the first run starts).

    Attributes
    ----------
    total, todo, reused
        The campaign's runs, those to run now, those whose rows it reuses.
    quarantined, quarantine
        Lines of ``runs.csv`` that could not be read, and the new file that
        holds them as they were (None when there were none).
    workers
        Local processes to start (0: nothing to run); None on a Dask cluster.
    requested
        The ``workers`` asked for (None: the default, one per core).
    limited_by
        Why fewer processes start than asked for or than the default:
        ``"runs"`` (no more than the runs to do) or ``"memory"`` (the
        available memory, :data:`WORKER_MEMORY` each); None otherwise.
    backend
        The backend the runs use (:func:`campaign_backend`; 'auto' on a
        Dask cluster: each worker's choice; None: nothing to run).
    """

    total: int
    todo: int
    reused: int
    quarantined: int
    quarantine: Path | None
    workers: int | None
    requested: int | None
    limited_by: str | None
    backend: str | None = None


@dataclass(frozen=True, slots=True)
class CampaignResult:
    """A finished campaign: its rows in run order and what was done.
    ``quarantined`` lines of ``runs.csv`` could not be read and are kept in
    ``quarantine``; ``workers``: the local processes used (None: Dask)."""

    campaign: Campaign
    rows: tuple[dict[str, Any], ...]
    ran: int
    reused: int
    failed: int
    seconds: float
    folder: Path
    quarantined: int = 0
    quarantine: Path | None = None
    workers: int | None = None

    def __repr__(self) -> str:  # the campaign's runs would flood a notebook
        return (f"<bgc.CampaignResult {self.campaign.name}: {len(self.rows)} rows ({self.ran} run, {self.reused} "
                f"reused, {self.failed} failed) in {self.folder}>")

    def to_frame(self):
        """The rows as a pandas DataFrame (``pip install 'bgc[data]'``): the
        columns of ``runs.csv`` (docs/experiments.md), numbers as numbers
        (NaN where a metric is not a number, missing where it is not
        defined), ``candidates`` and ``rivals`` as lists of names."""
        from ..api.tables import frame
        from .runs_csv import COLUMNS, NUMBERS, SEPARATOR

        lists = ("candidates", "rivals")
        rows = [{k: (v.split(SEPARATOR) if isinstance(v, str) and v else []) if k in lists else v
                 for k, v in row.items()} for row in self.rows]
        states = [f"mse_{x}" for x in self.campaign.states if any(f"mse_{x}" in row for row in rows)]
        columns = [c for c in COLUMNS if any(c in row for row in rows)]
        at = columns.index("nmse") + 1 if "nmse" in columns else len(columns)
        out = frame(rows, columns[:at] + states + columns[at:])
        numbers = [c for c in out.columns if c in NUMBERS or c in states]
        out[numbers] = out[numbers].astype(float)  # None: NaN, as pandas.read_csv reads runs.csv
        return out


def _check_arguments(c: Any, out: Any, scheduler: Any, progress: Any, outputs: Any, on_start: Any,
                     backend: Any) -> None:
    if not isinstance(c, Campaign):
        raise ArgumentTypeError(f"the campaign must be a Campaign, not {type(c).__name__}", None,
                                "read it with bgc.experiment.campaign_file.load_campaign(path)")
    if not isinstance(out, (str, os.PathLike)) or not str(out):
        raise ArgumentTypeError(f"out must be a folder path, not {type(out).__name__}", None,
                                "give a str or pathlib.Path")
    if scheduler is not None and (not isinstance(scheduler, str) or not scheduler.strip()):
        raise ArgumentTypeError(f"scheduler must be an address (str) or None, not {type(scheduler).__name__}",
                                None, "e.g. scheduler='tcp://10.0.0.5:8786'")
    if progress is not None and not isinstance(progress, (bool, np.bool_)):
        raise ArgumentTypeError(f"progress must be True, False or None, not {type(progress).__name__}", None,
                                "None: a progress bar when stderr is a terminal")
    if not isinstance(outputs, (bool, np.bool_)):
        raise ArgumentTypeError(f"outputs must be True or False, not {type(outputs).__name__}", None,
                                "True: write the tables and plots at the end")
    if on_start is not None and not callable(on_start):
        raise ArgumentTypeError(f"on_start must be callable or None, not {type(on_start).__name__}", None,
                                "give a function of one CampaignStart")
    if backend is not None and not isinstance(backend, str):
        raise ArgumentTypeError(f"backend must be a str, not {type(backend).__name__}", None,
                                "give 'auto' (the default), 'numpy' or 'numba'")
    if backend not in (None, "auto", "numpy", "numba"):
        raise ArgumentValueError(f"backend {printable(repr(backend))[:40]} is not one of 'auto', 'numpy', 'numba'",
                                 None, f"the default is {DEFAULT_BACKEND!r}: numba when it is installed and worth it")


def run_campaign(c: Campaign, out: str | Path, scheduler: str | None = None, workers: int | None = None,
                 progress: bool | None = None, outputs: bool = True, connect_timeout: float = CONNECT_TIMEOUT,
                 on_start: Callable[[CampaignStart], None] | None = None,
                 backend: str = DEFAULT_BACKEND) -> CampaignResult:
    """Run the campaign's runs not yet in ``out/runs.csv`` (a failed one is run
    again), append each row as it completes, then write the tables and plots.

    Parameters
    ----------
    c
        The campaign (:func:`load_campaign`).
    out
        Its folder: empty, or one this campaign wrote before (it resumes).
        The lines of its ``runs.csv`` that cannot be read are kept in a new
        ``runs.unread-N.csv`` (:func:`read_runs`).
    scheduler
        A Dask distributed scheduler's address; None: local processes.
    workers
        Local processes (None: one per core), at most :func:`worker_limit`;
        no more start than the runs to do or the memory holds
        (:func:`local_workers`). Not used with ``scheduler``.
    progress
        A progress bar on stderr (None: when stderr is a terminal).
    outputs
        Write ``tables.md``, ``report.html``, ``summary.json`` and the plots at the end.
    connect_timeout
        Seconds to wait for the scheduler (:func:`check_scheduler`, then
        Dask's handshake).
    backend
        The generated package the runs' filters use: 'numpy', 'numba', or
        'auto' (the default, as ``bgc experiment``'s): with local workers
        chosen here once by what is installed and the campaign's work
        (:func:`campaign_backend`), on a Dask cluster by each worker
        (numba where it is installed). The rows do not depend on it but for
        the run time. With numba and local workers, the models' kernels are
        compiled here first, once.
    on_start
        Called with a :class:`CampaignStart` once the folder is read, before
        the first run.

    Raises
    ------
    ArgumentTypeError, ArgumentValueError
        An argument of the wrong type or out of range.
    ExperimentError, OutputError
        The folder holds another campaign or files bgc did not write; the
        scheduler cannot be reached.
    TrackingError
        numba asked for (``backend`` or ``BGC_BACKEND``) and not installed.
    """
    from ..output import artifacts

    _check_arguments(c, out, scheduler, progress, outputs, on_start, backend)
    workers = check_workers(workers)
    connect_timeout = check_timeout(connect_timeout)
    started = time.perf_counter()
    folder = Path(out)
    previous = artifacts.read_manifest(folder) if folder.is_dir() else None
    if previous is not None and previous.get("campaign") != c.name:
        what = (f"campaign '{printable(str(previous.get('campaign')))}'" if previous.get("campaign")
                else "another bgc output (not a campaign)")
        raise ExperimentError(f"{printable(str(folder))} holds {what}", None, "choose another -o folder")
    # what the end writes is checked now, before any run (a tables.md the user edited, a link in plots/)
    outputs_now = {RUNS, TABLES, REPORT, SUMMARY} | {p for p in (previous or {}).get("files", {})
                                             if isinstance(p, str) and p.startswith(PLOTS)}
    artifacts.check_folder(folder, outputs_now, "experiment", adopt=(RUNS,))
    done, quarantine, unread = _finished(c, folder) if previous is not None else ({}, None, 0)
    todo = [s for s in c.specs if s.id not in done]
    backend = campaign_backend(c.specs, backend or DEFAULT_BACKEND, scheduler)[0] if todo else None
    cols = columns(c.states)
    rows_text = csv_header(c) + "".join(csv_row(r, cols) for r in sorted(done.values(), key=lambda r: r["index"]))
    artifacts.write_folder(folder, {RUNS: rows_text, artifacts.MANIFEST: artifacts.manifest(
        {RUNS: rows_text}, "experiment", growing=(RUNS,), campaign=c.name, source=c.source)},
        adopt=(RUNS,) if previous is not None else ())
    n_workers, why = (None, None) if scheduler else local_workers(workers, len(todo))
    if on_start is not None:
        on_start(CampaignStart(len(c.specs), len(todo), len(done), unread, quarantine, n_workers, workers, why,
                               backend))
    by_id = {s.id: s for s in c.specs}
    # where it sits now, its model's path now; every row with the same cells, reused or run now
    rows = {k: full_row({**v, **by_id[k].identity()}, cols) for k, v in done.items()}
    failed = 0
    if todo:
        show = sys.stderr.isatty() if progress is None else bool(progress)
        bar = _bar(len(c.specs), len(done), c.name, show)
        if backend == "numba" and not scheduler:
            compile_models(todo)
        source = (run_on_dask(todo, scheduler, connect_timeout, backend) if scheduler
                  else run_locally(todo, n_workers, backend))
        try:
            with artifacts.GrowingFile(folder / RUNS) as runs_file:
                for spec, row in source:
                    rows[spec.id] = full_row(row, cols)
                    runs_file.append(csv_row(row, cols))
                    failed += row["status"] != "ok"
                    bar.update(1)
                    bar.set_postfix(failed=failed, refresh=False)
        finally:
            bar.close()
    ordered = tuple(sorted(rows.values(), key=lambda r: r["index"]))
    result = CampaignResult(c, ordered, len(todo), len(done), failed, time.perf_counter() - started, folder,
                            unread, quarantine, n_workers)
    if outputs:
        write_outputs(result)
    return result


def _finished(c: Campaign, folder: Path) -> tuple[dict[str, dict[str, Any]], Path | None, int]:
    """The rows of the campaign's runs that finished in its folder before, by
    run id (the first of each), and the lines of its ``runs.csv`` that cannot
    be read: set aside in a new file (its path and their count) before the
    file is written again."""
    runs_path = folder / RUNS
    if runs_path.exists() and (runs_path.is_symlink() or not runs_path.is_file()):
        raise ExperimentError(f"{printable(str(runs_path))} is not a regular file bgc wrote", None,
                              "move it away, or choose another -o folder")
    found = read_runs(runs_path)
    quarantine = set_aside(folder, found.unread) if found.unread_lines else None
    ids = {s.id for s in c.specs}
    done: dict[str, dict[str, Any]] = {}
    for row in found.rows:
        if row["status"] == "ok" and row["id"] in ids and row["id"] not in done:
            done[row["id"]] = row
    return done, quarantine, found.unread_lines


def _bar(total: int, initial: int, name: str, show: bool):
    from tqdm import tqdm

    tqdm.monitor_interval = 0  # no monitor thread in a process that forks workers
    return tqdm(total=total, initial=initial, desc=name, unit="run", disable=not show, dynamic_ncols=True,
                smoothing=0.1)


def write_outputs(result: CampaignResult) -> list[Path]:
    """``runs.csv`` (in run order), ``tables.md``, ``report.html`` (the tables and the plots in one
    self-contained page), ``summary.json`` and the plots."""
    from ..output import artifacts, plots, tables

    c = result.campaign
    cols = columns(c.states)
    files: dict[str, str | bytes] = {RUNS: csv_header(c) + "".join(csv_row(r, cols) for r in result.rows)}
    files[TABLES] = tables.campaign_markdown(c, result.rows)
    files[SUMMARY] = tables.campaign_json(c, result.rows)
    figures = plots.campaign_figures(result.rows)
    files[REPORT] = tables.campaign_html(c, result.rows, figures)
    for name, data in figures.items():
        files[PLOTS + name] = data
    files[artifacts.MANIFEST] = artifacts.manifest(files, "experiment", campaign=c.name, source=c.source)
    return artifacts.write_folder(result.folder, files)


__all__ = ["CampaignResult", "CampaignStart", "run_campaign", "write_outputs"]
