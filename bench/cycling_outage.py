"""A plant that cycles through its modes, monitored across a logger's outage (issue 47, point 5, on a plant with
modes).

Run: .venv/bin/python bench/cycling_outage.py [--seed 3] [--starts 53000 53013 53031 53047]

The level plant of docs/examples/level.yaml (a pump a level switch turns on under p = 0.4 and off over 0.8; the
data have no mode column) is simulated by an independent simulator (tests/hybrid_reference.py: scipy's solve_ivp
on its equations derived by hand, its switches found by events) for 53,500 samples of 0.05 s, without a break.
The logger's file keeps the first 400 rows and then 300 rows from each ``--starts`` sample on: an outage of about
52,600 steps (44 minutes), more than the diagnosis holds (51,885 steps of this model), at whatever point of its
cycle the plant then is. Each file goes through ``bgc.monitor`` (as ``bgc monitor`` reads it); the table gives, per
start, the pump's true mode before and after the outage, the verdict at the end and the first alarm's time.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests"))

import bgc  # noqa: E402
import hybrid_reference as hybrid  # noqa: E402

MODEL = ROOT / "docs" / "examples" / "level.yaml"
BEFORE, AFTER, STEPS = 400, 300, 53500


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, default=3)
    ap.add_argument("--starts", type=int, nargs="+", default=[53000, 53013, 53031, 53047])
    args = ap.parse_args()
    print(f"command: .venv/bin/python bench/cycling_outage.py --seed {args.seed} --starts "
          + " ".join(map(str, args.starts)))
    t0 = time.perf_counter()
    times, modes, y_p, y_q, _ = hybrid.level_run(args.seed, steps=max(STEPS, max(args.starts) + AFTER))
    print(f"simulated {len(times)} samples in {time.perf_counter() - t0:.0f} s")
    print("\n| rows after the outage from | mode before | mode after | verdict | first alarm | s |")
    print("|---|---|---|---|---|---|")
    for start in args.starts:
        keep = np.r_[0:BEFORE, start:start + AFTER]
        lines = ["time,u:E,y:p,y:q_out"] + [f"{times[k]:.10g},{hybrid.LEVEL_E},{float(y_p[k])!r},{float(y_q[k])!r}"
                                            for k in keep]
        t0 = time.perf_counter()
        d = bgc.monitor(str(MODEL), iter(lines)).diagnosis
        alarm = "-" if d.detection is None else f"t = {float(d.time[d.detection.step]):.6g}"
        said = d.verdict + (f": {', '.join(d.candidates)}" if d.candidates else "")
        mode_names = ("filling", "draining")
        print(f"| t = {times[start]:.6g} | {mode_names[modes[BEFORE - 1] - 1]} | {mode_names[modes[start] - 1]} | "
              f"{said} | {alarm} | {time.perf_counter() - t0:.1f} |", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
