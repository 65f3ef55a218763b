"""The memory a bounded record's cuts leave behind: each cut of a watching
diagnoser's record (``DiagnosisOptions.keep``) imports the generated
package again with the record's new start
(:func:`bgc.model.package.started_package`) and drops the previous one
(:func:`~bgc.model.package.forget_started`); a module's functions and its
globals are a reference cycle, which only Python's cyclic collector frees.

    .venv/bin/python bench/started_packages.py [--model models/ro.yaml] [--cuts 600] [--backend numpy]

Two runs of ``--cuts`` cuts side by side, each in a fresh process: one
leaving the dropped packages to the collector's own passes, one collecting
at each cut as the diagnoser does (``gc.collect()`` in
``Diagnoser._forget``). It prints the resident set (VmRSS, MB) before the
first cut and after every quarter of them, and the milliseconds a
collection takes. Exit status 1 when the run that collects grows by more
than 10 % of its start.
"""

from __future__ import annotations

import argparse
import gc
import json
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))


def _rss() -> float:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024.0
    return float("nan")


def child(model: str, cuts: int, backend: str, collect: bool) -> dict:
    import bgc
    from bgc.model.package import forget_started, started_package

    session = bgc.open(model, backend=backend)
    n = len(session.package.MODELS["nominal"].STATES)
    old, marks, spent = session.package, [_rss()], 0.0
    for i in range(1, cuts + 1):
        new = started_package(session.package, np.full(n, float(i)), np.ones(n))
        if old is not session.package:
            forget_started(old)
        old = new
        if collect:
            started = time.perf_counter()
            gc.collect()
            spent += time.perf_counter() - started
        if i % max(cuts // 4, 1) == 0:
            marks.append(_rss())
    return {"marks": marks, "collect_ms": spent / cuts * 1e3 if collect else None}


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--model", default=str(ROOT / "models" / "ro.yaml"))
    p.add_argument("--cuts", type=int, default=600)
    p.add_argument("--backend", default="numpy")
    p.add_argument("--child", choices=["collect", "leave"], help=argparse.SUPPRESS)
    args = p.parse_args()
    if args.child:
        print(json.dumps(child(args.model, args.cuts, args.backend, args.child == "collect")))
        return 0
    print(f"{'collection':>26} " + " ".join(f"{f'{q}/4':>8}" for q in range(5)) + "   (VmRSS MB after that share of "
          f"{args.cuts} cuts)   ms per collection")
    ok = True
    for mode, label in (("leave", "the collector's own passes"), ("collect", "gc.collect() at each cut")):
        out = subprocess.run([sys.executable, __file__, "--model", args.model, "--cuts", str(args.cuts), "--backend",
                              args.backend, "--child", mode], capture_output=True, text=True, check=True)
        r = json.loads(out.stdout.strip().splitlines()[-1])
        marks = r["marks"]
        print(f"{label:>26} " + " ".join(f"{m:>8.1f}" for m in marks)
              + ("" if r["collect_ms"] is None else f"   {r['collect_ms']:.1f}"))
        if mode == "collect":
            ok = marks[-1] <= 1.10 * marks[0]
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
