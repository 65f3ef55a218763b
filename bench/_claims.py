"""What bench/seeded_statistics.py and bench/full_cases.py share: the test
suite's set-up (imported before NumPy loads: OpenBLAS's kernels, the kept
caches, the NumPy backend, the tests' helpers on the path), and the runner
of named claims (:func:`run`), each a function returning its rows and its
(text, passed) checks."""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
#: The suite's set-up, before NumPy loads (the root conftest.py): OpenBLAS's kernels and the kept caches.
os.environ.setdefault("OPENBLAS_CORETYPE", "Haswell")
_KEPT = Path(os.environ.get("BGC_TEST_CACHE")
             or Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "bgc-tests")
os.environ.setdefault("NUMBA_CACHE_DIR", str(_KEPT / "numba"))
os.environ.setdefault("BGC_CACHE_DIR", str(_KEPT / "bgc"))
os.environ.setdefault("BGC_BACKEND", "numpy")
os.environ.setdefault("MPLBACKEND", "Agg")
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests"))


def run(claims: dict, doc: str, argv=None) -> int:
    """Run the claims named on the command line (default: all), print each
    one's rows and checks and a summary; 0 when every one holds, else 1."""
    parser = argparse.ArgumentParser(description=doc.split("\n\n")[0])
    parser.add_argument("claims", nargs="*", metavar="CLAIM", help=f"of {', '.join(claims)} (default: all)")
    args = parser.parse_args(argv)
    unknown = [name for name in args.claims if name not in claims]
    if unknown:
        parser.error(f"no claim {', '.join(unknown)} (the claims: {', '.join(claims)})")
    summary = []
    for name in args.claims or list(claims):
        start = time.perf_counter()
        rows, checks = claims[name]()
        seconds = time.perf_counter() - start
        ok = all(passed for _, passed in checks)
        print(f"{name} ({seconds:.0f} s): {'holds' if ok else 'FAILS'}")
        print("\n".join(rows))
        for text, passed in checks:
            print(f"  {'ok  ' if passed else 'FAIL'} {text}")
        print(flush=True)
        summary.append((name, ok, seconds))
    print(f"{'claim':<20} {'result':<7} {'s':>5}")
    for name, ok, seconds in summary:
        print(f"{name:<20} {'holds' if ok else 'FAILS':<7} {seconds:5.0f}")
    return 0 if all(ok for _, ok, _ in summary) else 1
