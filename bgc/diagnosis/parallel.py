"""The hypotheses' work on worker processes, outside the algorithm: each
hypothesis's batches of onsets and their follow-up jobs
(:func:`run_batches`), or a list of jobs (:func:`run_all`). The results do
not depend on the number of workers."""

from __future__ import annotations

import multiprocessing
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait


from .hypothesis import run_job


def run_batches(batches: dict[str, list[int]], job, arrived, workers: int, cost, idle=None, done=None,
                 landed=None) -> None:
    """Run each hypothesis's first batch of onsets (``batches``: name ->
    onsets), and each further batch ``arrived(name, onsets, results, trace)``
    asks for once the one before it is back, until none is asked for; then
    the follow-up job ``done(name)`` gives ((function, argument), or None),
    whose result goes to ``landed(name, result)``. ``idle()`` runs here once
    the first batches are out. With ``workers`` > 1 the jobs run on that many
    forked processes, and a hypothesis's next batch starts as soon as its
    own last one is back and a worker is free, before the first batches still
    waiting (it lies on the longest chain of work), while other hypotheses'
    batches still run; the first batches start longest first (``cost(onsets)``:
    a batch's work); a follow-up waits behind every first batch (a first
    batch may lead to a follow-up of its own: the chains of work end
    together). A hypothesis's jobs depend on its own results only, so the
    results do not depend on ``workers``."""
    idle = idle or (lambda: None)
    done = done or (lambda name: None)
    order = sorted(batches, key=lambda name: -cost(batches[name]))
    if workers <= 1 or len(batches) <= 1 or "fork" not in multiprocessing.get_all_start_methods():
        idle()
        queue = [(name, batches[name]) for name in order]
        while queue:
            name, starts = queue.pop(0)
            more = arrived(name, starts, *run_job(job(name, starts)))
            if more:
                queue.append((name, more))
                continue
            follow = done(name)
            if follow is not None:
                landed(name, follow[0](follow[1]))
        return
    waiting = [(name, (run_job, job(name, batches[name])), batches[name]) for name in order]
    with ProcessPoolExecutor(max_workers=workers, mp_context=multiprocessing.get_context("fork")) as pool:
        running: dict = {}
        first = True
        while waiting or running:
            while waiting and len(running) < workers:  # one job per worker: a later job can go first
                name, (fn, arg), starts = waiting.pop(0)
                running[pool.submit(fn, arg)] = (name, starts)
            if first:
                idle()
                first = False
            finished, _ = wait(running, return_when=FIRST_COMPLETED)
            for future in sorted(finished, key=lambda f: running[f][0]):
                name, starts = running.pop(future)
                if starts is None:  # a follow-up
                    landed(name, future.result())
                    continue
                more = arrived(name, starts, *future.result())
                if more:  # on the longest path: before the first batches still waiting
                    waiting.insert(0, (name, (run_job, job(name, more)), more))
                    continue
                follow = done(name)
                if follow is not None:  # after the first batches still waiting: they may lead to follow-ups
                    waiting.append((name, follow, None))


def run_all(jobs: list, workers: int, fn=None) -> list:
    """``fn`` (default: one hypothesis's filters) over the jobs, on ``workers`` forked processes."""
    fn = fn or run_job
    if workers <= 1 or len(jobs) <= 1 or "fork" not in multiprocessing.get_all_start_methods():
        return [fn(j) for j in jobs]
    with ProcessPoolExecutor(max_workers=min(workers, len(jobs)),
                             mp_context=multiprocessing.get_context("fork")) as pool:
        return list(pool.map(fn, jobs))
