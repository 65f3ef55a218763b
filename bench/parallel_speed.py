"""Parallel speed, side by side in one run:

1. a full RO diagnosis (300 steps, N = 1000: nominal observer, detector,
   symbols, every hypothesis filter from every onset) with its hypothesis
   filters on 2 worker processes against the same filters one after another in
   one process (``DiagnosisOptions.workers`` 2 against 1), timed around
   ``bgc.diagnose`` (simulating the scenario included) and, last column, the
   diagnosis alone (``Diagnosis.seconds``);
2. a campaign (the first ``--runs`` runs of experiments/thesis_tables.yaml)
   on 2 local processes against 1 (``bgc.experiment.campaign.run_campaign(workers=...)``).

    .venv/bin/python bench/parallel_speed.py [--repeats 3] [--runs 40]

Wall-clock seconds (best and median of the repeats); the ratio is the speed-up.
Both sides give the same numbers (checked): only the time differs.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

import bgc  # noqa: E402
from bgc.experiment import campaign
from bgc.experiment import campaign_file
from bgc.diagnosis.options import DiagnosisOptions


def time_diagnosis(workers: int, seed: int, scenario: str) -> tuple[float, object]:
    started = time.perf_counter()
    r = bgc.diagnose(ROOT / "models" / "ro.yaml", scenario=scenario, seed=seed,
                     generated=ROOT / "generated", options=DiagnosisOptions(seed=seed, workers=workers))
    return time.perf_counter() - started, r.diagnosis


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--runs", type=int, default=40)
    args = ap.parse_args()

    print("## 1. One RO diagnosis, 300 steps, N = 1000 (hypothesis filters on 2 processes vs 1)\n")
    print("| scenario | 1 process: best / median s | 2 processes: best / median s | speed-up (median) "
          "| 2 processes, diagnosis alone (no simulation): median s |")
    print("|---|---|---|---|---|")
    for scenario in ("R_pipe:abrupt:31@165", "R_pipe:incipient:0.5@165", "R_memb:abrupt:24@165"):
        time_diagnosis(1, 1, scenario)  # warm-up: compile, import the package
        one, two, alone = [], [], []
        for i in range(args.repeats):
            t1, d1 = time_diagnosis(1, 1 + i, scenario)
            t2, d2 = time_diagnosis(2, 1 + i, scenario)
            assert d1.candidates == d2.candidates and d1.estimate.value == d2.estimate.value
            one.append(t1)
            two.append(t2)
            alone.append(d2.seconds)  # bgc.diagnosis.diagnose.diagnose itself: nominal observer to verdict
        m1, m2 = statistics.median(one), statistics.median(two)
        print(f"| {scenario} | {min(one):.2f} / {m1:.2f} | {min(two):.2f} / {m2:.2f} | {m1 / m2:.2f}x "
              f"| {statistics.median(alone):.2f} |")

    print(f"\n## 2. Campaign: the first {args.runs} runs of experiments/thesis_tables.yaml (2 processes vs 1)\n")
    c = campaign_file.load_campaign(ROOT / "experiments" / "thesis_tables.yaml")
    c = campaign_file.Campaign(c.name, c.description, c.source, c.sha256, c.specs[: args.runs], (), c.groups)
    times: dict[int, list[float]] = {1: [], 2: []}
    rows = {}
    with tempfile.TemporaryDirectory() as folder:
        for i in range(args.repeats):
            for workers in (1, 2):
                started = time.perf_counter()
                r = campaign.run_campaign(c, Path(folder) / f"w{workers}-{i}", workers=workers, progress=False,
                                          outputs=False)
                times[workers].append(time.perf_counter() - started)
                rows[workers] = [{k: v for k, v in row.items() if k != "rt"} for row in r.rows]
    assert rows[1] == rows[2]
    m1, m2 = statistics.median(times[1]), statistics.median(times[2])
    print("| workers | best s | median s | runs per minute (median) |")
    print("|---|---|---|---|")
    for w in (1, 2):
        m = statistics.median(times[w])
        print(f"| {w} | {min(times[w]):.1f} | {m:.1f} | {60 * args.runs / m:.0f} |")
    print(f"\nspeed-up of 2 processes over 1 (median): {m1 / m2:.2f}x")


if __name__ == "__main__":
    main()
