"""A hypothesis's filters stepped together (FilterBank) against the same
filters stepped one by one, side by side in one run.

Run: .venv/bin/python bench/filter_bank.py [--rounds 3]

What a drift hypothesis does in a diagnosis: F filters of one fault model
(the RO plant's R_pipe drift), each with its own seed, step through the same
150 samples of a simulated run (the thesis's R_pipe drift, seed 1, from
t = 150). Two ways, taking turns in rounds:

  one by one  the integrator in one call for all the filters' particles (what
              diagnoses did before the bank), then each filter's own
              ``step(y, u, predicted=True)`` and its Liu and West move of
              the magnitude: bgc's path before the bank
  bank        ``FilterBank.step`` and the Liu and West move on the bank's rows
              (``bgc.diagnosis.hypothesis._shrink_together``): bgc's path now

for F = 1, 4, 16 filters, N = 200, 500, 1000 particles, GPF and APF. The table
gives, per pass over the 150 steps, the best round's CPU seconds of each
(time.process_time, one process, BLAS on one thread; a round times
max(1, 8000 // (F N)) passes, each from fresh filters) and their ratio. With
F = 1 both ways run the same code (the bank steps a lone filter by its own
step): that row's ratio shows the timing's own scatter. Both ways must end with the same
particles, bit for bit: the benchmark checks it (and says so) for every cell.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("MKL_NUM_THREADS", "1")

import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

import bgc  # noqa: E402
from bgc.model import package as packages  # noqa: E402
from bgc.analysis import track
from bgc.diagnosis.hypothesis import _shrink_together  # noqa: E402
from bgc.diagnosis.hypothesis import kernel_shrinkage as _kernel_shrinkage  # noqa: E402

SHRINKAGE = 0.98
FIRST, STEPS = 150, 150


def filters(cls, model, count: int, n: int) -> list:
    return [cls(model, n, np.random.default_rng([7, f])) for f in range(count)]


def one_by_one(package, model, pfs, ys, us, row: int) -> None:  # package: the signature banked() needs
    """The integrator over every filter's particles in one call, then each
    filter's own step and kernel move."""
    for k in range(len(ys)):
        x = np.concatenate([pf.x for pf in pfs], axis=1)
        model.predict(x, us[k], pfs[0].theta, model.DT, out=x)
        at = 0
        for pf in pfs:
            pf.x = x[:, at:at + pf.n].copy()
            at += pf.n
        for pf in pfs:
            r = pf.step(ys[k], us[k], predicted=True)
            _kernel_shrinkage(pf.x[row][None], pf.logw[None], SHRINKAGE, [pf.rng], np.array([r.resampled]))


def banked(package, model, pfs, ys, us, row: int) -> None:
    bank = package.filters.FilterBank(model)
    for k in range(len(ys)):
        results = bank.step(pfs, ys[k], us[k])
        _shrink_together(bank, pfs, row, SHRINKAGE, [r.resampled for r in results])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rounds", type=int, default=3)
    args = ap.parse_args()
    package = packages.load_package(ROOT / "generated", "ro", "models/ro.yaml")
    name = "R_pipe_incipient"
    model = package.MODELS[name]
    row = len(model.STATES) - 1
    report = bgc.diagnose(ROOT / "models" / "ro.yaml", scenario="R_pipe:incipient:0.5@150", seed=1,
                          generated=ROOT / "generated")
    ys, us = track.run_arrays(report.run, package, name)
    ys, us = ys[FIRST:FIRST + STEPS], us[FIRST:FIRST + STEPS]
    classes = {"GPF": package.filters.GenericParticleFilter, "APF": package.filters.AuxiliaryParticleFilter}
    print(f"## {name}: F filters x N particles, {STEPS} steps (CPU s, best of {args.rounds} rounds)\n")
    print("| filter | F | N | one by one s | bank s | one by one / bank | same particles |")
    print("|---|---|---|---|---|---|---|")
    for method, cls in classes.items():
        for count in (1, 4, 16):
            for n in (200, 500, 1000):
                best = {"one by one": np.inf, "bank": np.inf}
                ends = {}
                reps = max(1, 8000 // (count * n))  # passes per timing: small cells are timed over several
                for _ in range(args.rounds):
                    for way, fn in (("one by one", one_by_one), ("bank", banked)):
                        seconds = 0.0
                        for _ in range(reps):
                            pfs = filters(cls, model, count, n)
                            with np.errstate(all="ignore"):
                                started = time.process_time()
                                fn(package, model, pfs, ys, us, row)
                                seconds += time.process_time() - started
                        best[way] = min(best[way], seconds / reps)
                        ends[way] = [pf.x.copy() for pf in pfs]
                same = all(np.array_equal(a, b) for a, b in zip(ends["one by one"], ends["bank"]))
                print(f"| {method} | {count} | {n} | {best['one by one']:.3f} | {best['bank']:.3f} | "
                      f"{best['one by one'] / best['bank']:.2f}x | {'yes' if same else 'NO'} |", flush=True)


if __name__ == "__main__":
    main()
