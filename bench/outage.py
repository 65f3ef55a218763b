"""A logger's outage bridged by a watching monitor, over seeds: how often the
verdict after the gap is right, with the observer started as
bgc.diagnosis.bridge starts it and, side by side on the same data, started
where it was before the gap (no run on: ``SETTLE = 0``), the control
(docs/results.md section 77).

    .venv/bin/python bench/outage.py [--seeds 10]

The plants are the test suite's own simulators, not bgc's: the circuit by the
exact solution of its equations (tests/test_bridge.py: 400 rows, three hours
with no row, 400 rows after), the two tanks by solve_ivp (tests/
two_tank_reference.py: 400 rows, 20,000 s with no row, 600 rows after).
Across the gap the input moves (the circuit's source from 10 to 7, 10 or 13
V, the tanks' inflow from 1 to 0.7, 1 or 1.3, by the seed), and the plant is
healthy, or a fault starts after the gap (the circuit's R1 or R2 at 1.5
times, the tanks' R12 or R20 up by 0.6, by the seed). A run is right when
a healthy plant gets "no fault" with no alarm, and a faulty one gets its
fault isolated at its size within 10 %.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from collections import Counter
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "tests"))

import bgc  # noqa: E402
from bgc.diagnosis import bridge  # noqa: E402
import two_tank_reference as tanks  # noqa: E402
from test_bridge import circuit_rows  # noqa: E402

SETTLE = bridge.SETTLE


def circuit_case(seed: int, faulty: bool):
    v = (7.0, 10.0, 13.0)[seed % 3]
    fault = ("R1", "R2")[seed % 2]
    rows = circuit_rows(seed, v, fault_after=(10.0, fault, 1.5) if faulty else None, after=400)
    truth = None if not faulty else (f"{fault}_abrupt", 0.5 * {"R1": 1.0, "R2": 2.0}[fault])
    return ROOT / "models" / "circuit.yaml", iter(rows), truth


def tank_case(seed: int, faulty: bool, folder: Path):
    inflow = (0.7, 1.0, 1.3)[seed % 3]
    fault = ("R12", "R20")[seed % 2]
    t1 = 200.0 + 20000.0
    rows = tanks.run(100 + seed, steps=400) + tanks.run(
        200 + seed, (fault, 0.6, t1 + 50.0) if faulty else None, steps=600, inflow=inflow,
        start=tanks.P0 * inflow, t0=t1 - 0.5)
    path = tanks.write(folder / f"tanks_{seed}_{faulty}.csv", rows, [1.0] * 400 + [inflow] * 600)
    return ROOT / "models" / "two_tank.yaml", path, None if not faulty else (f"{fault}_abrupt", 0.6)


def right(report, truth) -> bool:
    d = report.diagnosis
    if truth is None:
        return d.verdict == "no fault" and d.detection is None
    name, size = truth
    return (d.verdict == "isolated" and d.candidates[0] == name and d.estimate is not None
            and abs(d.estimate.value - size) <= 0.1 * size)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=10, help="seeds per plant and case (from 0)")
    args = ap.parse_args()
    counts = {k: Counter() for k in ("bridged", "started where it was")}
    seconds = Counter()
    with tempfile.TemporaryDirectory() as tmp:
        for plant in ("circuit", "two_tank"):
            for faulty in (False, True):
                for seed in range(args.seeds):
                    for variant, settle in (("bridged", SETTLE), ("started where it was", 0.0)):
                        bridge.SETTLE = settle
                        model, data, truth = (circuit_case(seed, faulty) if plant == "circuit"
                                              else tank_case(seed, faulty, Path(tmp)))
                        started = time.process_time()
                        report = bgc.monitor(model, data, seed=3, particles=500)
                        seconds[variant] += time.process_time() - started
                        ok = right(report, truth)
                        case = f"{plant} {'faulty' if faulty else 'healthy'}"
                        counts[variant][case, ok] += 1
                        if not ok:
                            d = report.diagnosis
                            print(f"  {variant}: {case} seed {seed}: {d.verdict} {', '.join(d.candidates)}"
                                  f"{'' if d.detection is None else ' (alarm)'}", flush=True)
    bridge.SETTLE = SETTLE
    print(f"\n{'case':<18} {'bridged':>10} {'started where it was':>22}")
    for plant in ("circuit", "two_tank"):
        for faulty in ("healthy", "faulty"):
            case = f"{plant} {faulty}"
            cells = [f"{counts[v][case, True]}/{counts[v][case, True] + counts[v][case, False]}" for v in counts]
            print(f"{case:<18} {cells[0]:>10} {cells[1]:>22}")
    print(f"CPU seconds: bridged {seconds['bridged']:.0f}, started where it was {seconds['started where it was']:.0f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
