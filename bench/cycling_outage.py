"""A plant that cycles through its modes, monitored across a logger's outage (issue 47, point 5, on a plant with
modes).

Run: .venv/bin/python bench/cycling_outage.py [--seed 3] [--starts 53000 53013 53031 53047] [--valve]
     [--stitched FIRST LAST]

The level plant of docs/examples/level.yaml (a pump a level switch turns on under p = 0.4 and off over 0.8; the
data have no mode column) is simulated by an independent simulator (tests/hybrid_reference.py: scipy's solve_ivp
on its equations derived by hand, its switches found by events) for 53,500 samples of 0.05 s, without a break.
The logger's file keeps the first 400 rows and then 300 rows from each ``--starts`` sample on: an outage of about
52,600 steps (44 minutes), more than the diagnosis holds (51,885 steps of this model), at whatever point of its
cycle the plant then is. Each file goes through ``bgc.monitor`` (as ``bgc monitor`` reads it); the table gives, per
start, the pump's true mode before and after the outage, the verdict at the end and the first alarm's time.

``--valve``: models/ro_hybrid_valve.yaml instead, its valve setting in the data (the Makefile demo's schedule: two
cycles in 300 s), by bgc's own simulator (``bgc.simulate``, seeds 4 and 5: no other simulator of RO ships): the
rows of the first run to a point of its cycle, the clock 2 * 10^5 s ahead, then the rows of the second from another
point of its cycle.

``--stitched FIRST LAST``: tests/test_bridge.py's three stitched outages (the level plant and the thermostat by
solve_ivp, the switched supply of docs/examples/switched_rc.yaml by the exact solution of its equations, its mode
in the data), each for the seeds FIRST to LAST (the tests use 1 and 2): per plant, the runs that say "no fault".
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests"))

import bgc  # noqa: E402
import hybrid_reference as hybrid  # noqa: E402
import test_bridge as tb  # noqa: E402  (the tests' logger files of the stitched outages)

MODEL = ROOT / "docs" / "examples" / "level.yaml"
BEFORE, AFTER, STEPS = 400, 300, 53500


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, default=3)
    ap.add_argument("--starts", type=int, nargs="+", default=[53000, 53013, 53031, 53047])
    ap.add_argument("--valve", action="store_true", help="the RO plant whose valve setting the data give")
    ap.add_argument("--stitched", type=int, nargs=2, metavar=("FIRST", "LAST"),
                    help="tests/test_bridge.py's stitched outages for these seeds")
    args = ap.parse_args()
    if args.valve:
        return valve()
    if args.stitched:
        return stitched(*args.stitched)
    print(f"command: .venv/bin/python bench/cycling_outage.py --seed {args.seed} --starts "
          + " ".join(map(str, args.starts)))
    t0 = time.perf_counter()
    times, modes, y_p, y_q, _ = hybrid.level_run(args.seed, steps=max(STEPS, max(args.starts) + AFTER))
    print(f"simulated {len(times)} samples in {time.perf_counter() - t0:.0f} s")
    print("\n| rows after the outage from | mode before | mode after | verdict | first alarm | s |")
    print("|---|---|---|---|---|---|")
    for start in args.starts:
        keep = np.r_[0:BEFORE, start:start + AFTER]
        lines = tb._level_lines(times[keep], y_p[keep], y_q[keep])
        t0 = time.perf_counter()
        d = bgc.monitor(str(MODEL), iter(lines)).diagnosis
        alarm = "-" if d.detection is None else f"t = {float(d.time[d.detection.step]):.6g}"
        said = d.verdict + (f": {', '.join(d.candidates)}" if d.candidates else "")
        mode_names = ("filling", "draining")
        print(f"| t = {times[start]:.6g} | {mode_names[modes[BEFORE - 1] - 1]} | {mode_names[modes[start] - 1]} | "
              f"{said} | {alarm} | {time.perf_counter() - t0:.1f} |", flush=True)
    return 0


#: models/ro_hybrid_valve.yaml's valve schedule (the Makefile's demo), and the cuts: (rows of the first run, the row
#: of the second the file goes on from).
SCHEDULE = "secondary@60,purge@100,primary@120,secondary@180,purge@220,primary@240"
CUTS = ((90, 190), (150, 105), (230, 70))


def valve() -> int:
    print("command: .venv/bin/python bench/cycling_outage.py --valve")
    model = ROOT / "models" / "ro_hybrid_valve.yaml"
    names = ("primary", "secondary", "purge")
    runs = []
    with tempfile.TemporaryDirectory() as tmp:
        for seed in (4, 5):
            path = Path(tmp) / f"run{seed}.csv"
            bgc.simulate(str(model), steps=300, modes=SCHEDULE, seed=seed).write(path)
            lines = [line.strip().split(",") for line in path.read_text().splitlines() if not line.startswith("#")]
            runs.append((lines[0], lines[1:]))
    header = runs[0][0]
    keep = [i for i, c in enumerate(header) if c in ("time", "mode") or c[:2] in ("u:", "y:")]
    mode = header.index("mode")
    print("\n| first run's rows | valve then | second run from | valve then | verdict | first alarm | s |")
    print("|---|---|---|---|---|---|---|")
    for end, start in CUTS:
        lines = [",".join(header[i] for i in keep)] + [",".join(r[i] for i in keep) for r in runs[0][1][:end]]
        lines += [",".join([repr(float(r[0]) + 2e5)] + [r[i] for i in keep[1:]]) for r in runs[1][1][start:]]
        t0 = time.perf_counter()
        d = bgc.monitor(str(model), iter(lines)).diagnosis
        alarm = "-" if d.detection is None else f"t = {float(d.time[d.detection.step]):.6g}"
        said = d.verdict + (f": {', '.join(d.candidates)}" if d.candidates else "")
        before, after = int(float(runs[0][1][end - 1][mode])), int(float(runs[1][1][start][mode]))
        print(f"| 0 to {end - 1} | {names[before - 1]} | {start} | {names[after - 1]} | {said} | {alarm} | "
              f"{time.perf_counter() - t0:.1f} |", flush=True)
    return 0


def stitched(first: int, last: int) -> int:
    print(f"command: .venv/bin/python bench/cycling_outage.py --stitched {first} {last}")
    supply = ROOT / "docs" / "examples" / "switched_rc.yaml"
    plants = {"level (mode hidden)": (MODEL, tb._cycling_lines),
              "thermostat (mode hidden)": (hybrid.THERMO_MODEL, tb._thermostat_lines),
              "switched supply (mode in the data)": (supply, tb._supply_lines)}
    print("\n| plant | seeds | no fault | other verdicts |")
    print("|---|---|---|---|")
    for name, (model, lines) in plants.items():
        said = [(seed, bgc.monitor(str(model), iter(lines(seed)), seed=3).diagnosis.verdict)
                for seed in range(first, last + 1)]
        other = ", ".join(f"seed {s}: {v}" for s, v in said if v != "no fault") or "-"
        print(f"| {name} | {first} to {last} | {sum(v == 'no fault' for _, v in said)} of {len(said)} | {other} |",
              flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
