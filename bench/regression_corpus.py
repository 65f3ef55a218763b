"""The whole regression corpus replayed: every case of
tests/regression/cases.json diagnosed again and compared with what was
recorded, as tests/test_regression.py compares the representative subset it
runs (``REPRESENTATIVE``, 15 of the 42 cases; this script runs the rest
too, about 90 s more of diagnoses than the test).

    .venv/bin/python bench/regression_corpus.py [--only TEXT]

Each case is diagnosed through the public API with its options and noise
levels (tests/test_regression.py's ``differences``: the verdict, the
candidates, the filter that made the diagnosis, the detection, the onset,
the symbols, the signatures ruled out, the kinds of note, and every
hypothesis's numbers to a relative 1e-9). The numbers are those of
OpenBLAS's Haswell kernels: set here before NumPy loads, as the root
conftest.py does (a CPU without AVX2 rounds otherwise: the script says so
and stops).

Prints one row per case: its plant, filter, verdict, whether the test runs
it, the seconds of its diagnosis and "same" or what differs; then the count.
Exits 1 when any case differs.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_CORETYPE", "Haswell")  # before NumPy loads (the root conftest.py's choice)

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests"))


def main(argv=None) -> int:
    import test_regression as corpus

    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--only", metavar="TEXT", help="only the cases whose name holds TEXT")
    args = parser.parse_args(argv)
    if os.environ["OPENBLAS_CORETYPE"].lower() != corpus.RECORDED_CORETYPE.lower():
        print(f"OPENBLAS_CORETYPE={os.environ['OPENBLAS_CORETYPE']}: the corpus's numbers are those of "
              f"{corpus.RECORDED_CORETYPE}'s kernels", file=sys.stderr)
        return 2
    cases = [c for c in corpus.CASES if args.only is None or args.only in c["name"]]
    if not cases:
        print(f"no case of the corpus has {args.only!r} in its name", file=sys.stderr)
        return 2
    print(f"{'case':<52} {'plant':<24} {'filter':<6} {'verdict':<12} {'test':<5} {'s':>6}  result")
    differ, total = [], 0.0
    for case in cases:
        start = time.perf_counter()
        wrong = corpus.differences(case)
        seconds = time.perf_counter() - start
        total += seconds
        plant = Path(case["model"]).stem
        in_test = "yes" if case["name"] in corpus.REPRESENTATIVE else "-"
        result = "same" if not wrong else f"DIFFERS: {wrong[0]}" + (f" (+{len(wrong) - 1} more)" if wrong[1:] else "")
        print(f"{case['name']:<52} {plant:<24} {case['options']['method']:<6} {case['expected']['verdict']:<12} "
              f"{in_test:<5} {seconds:6.1f}  {result}", flush=True)
        if wrong:
            differ.append((case["name"], wrong))
    print(f"\n{len(cases) - len(differ)} of {len(cases)} cases the same as recorded ({total:.0f} s of diagnoses; "
          f"{sum(c['name'] in corpus.REPRESENTATIVE for c in cases)} of them run by tests/test_regression.py)")
    for name, wrong in differ:
        print(f"\n{name}:\n  " + "\n  ".join(wrong))
    return 1 if differ else 0


if __name__ == "__main__":
    sys.exit(main())
