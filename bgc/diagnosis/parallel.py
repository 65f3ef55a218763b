"""The diagnosis's work on worker processes, outside the algorithm: one
parallel map (:func:`parallel_map`). Every job carries its own seeds, so the
results do not depend on the number of workers nor on the order they finish in."""

from __future__ import annotations

import multiprocessing
from concurrent.futures import ProcessPoolExecutor

from .options import processes


def parallel_map(fn, jobs: list, workers: int | None) -> list:
    """``[fn(job) for job in jobs]``, on ``workers`` forked processes when
    there are more than one of each (in this process otherwise, or where the
    platform cannot fork); ``workers`` None: the environment's
    ``BGC_WORKERS``, else 2 (:func:`bgc.diagnosis.options.processes`)."""
    workers = processes(workers)
    if workers <= 1 or len(jobs) <= 1 or "fork" not in multiprocessing.get_all_start_methods():
        return [fn(j) for j in jobs]
    with ProcessPoolExecutor(max_workers=min(workers, len(jobs)),
                             mp_context=multiprocessing.get_context("fork")) as pool:
        return list(pool.map(fn, jobs))
