"""Calibration without the mode column (bgc.analysis.calibrate.calibrate_hidden):
the level plant of docs/examples/level.yaml (a pump switched by its tank's
pressure: autonomous transitions) simulated by solve_ivp on its hand-derived
equations (tests/hybrid_reference.py), its R_out ``--r-out`` where the model
file says 1.5, ``--steps`` samples, logged with and without the mode column;
R_out calibrated on each. Per seed: the two estimates and intervals, the
switches of the run and those read, the largest distance of a switch read
from solve_ivp's crossing (in samples), the rounds, and the seconds.

    .venv/bin/python bench/hidden_mode_calibration.py [--seeds 3 4 5] [--steps 240] [--r-out 1.65]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests"))

import bgc  # noqa: E402
from hybrid_reference import LEVEL_DT, level_csv, level_run  # noqa: E402


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--seeds", type=int, nargs="+", default=[3, 4, 5])
    p.add_argument("--steps", type=int, default=240)
    p.add_argument("--r-out", type=float, default=1.65)
    args = p.parse_args(argv)
    session = bgc.open(ROOT / "docs" / "examples" / "level.yaml", backend="numpy")
    print(f"bench/hidden_mode_calibration.py --seeds {' '.join(map(str, args.seeds))} --steps {args.steps} "
          f"--r-out {args.r_out}: R_out calibrated with the mode column and without it\n")
    print("| seed | with the mode: R_out [95 %] | without: R_out [95 %] | switches (read) | farthest switch read "
          "(samples) | rounds | seconds (with / without) |")
    print("|---|---|---|---|---|---|---|")
    with tempfile.TemporaryDirectory() as tmp:
        for seed in args.seeds:
            times, modes, y_p, y_q, switches = level_run(seed, fault=(0.0, "R_out", args.r_out), steps=args.steps)
            cells, seconds, read = [], [], None
            for with_mode in (True, False):
                path = level_csv(Path(tmp) / f"run{seed}{with_mode}.csv", times, modes, y_p, y_q, with_mode)
                start = time.perf_counter()
                report = session.calibrate(str(path), "R_out")
                seconds.append(time.perf_counter() - start)
                e = report.calibration.estimate("R_out")
                cells.append(f"{e.value:.4f} [{e.low:.4f}, {e.high:.4f}]")
                read = report.modes_read[0] if report.modes_read else read
            far = max(min(abs(t - s) for s in switches) for t, _, _ in read.switches) / LEVEL_DT
            print(f"| {seed} | {cells[0]} | {cells[1]} | {len(switches)} ({len(read.switches)}) | {far:.2f} | "
                  f"{read.rounds} | {seconds[0]:.1f} / {seconds[1]:.1f} |", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
