"""The drifts' detection delay in a campaign's runs, beside the least delay
any detector could have (issue 48's delay target).

Reads one or more ``runs.csv`` (``bgc experiment``; the columns ``delay``
and ``ideal_delay``, docs/experiments.md) and prints, per model and
detector (the ``detectors`` column; a second file's rows labelled with its
name), over the drift runs (kinds ``incipient`` and ``drift``) whose data
show the fault (the ideal detector held at 1 % per run detects it with
probability at least 0.95, the campaign tables' "detected where the data
show it"):

- the median delay from the onset to the alarm, a run not detected at or
  after its onset counted as never (so the median is over every such run,
  as the bound's is);
- the median of ``ideal_delay``, the least delay by which any detector
  holding 1 % false alarms per run alarms in half of such runs (Neyman and
  Pearson), over the same runs;
- their ratio; and the detected runs' own median, the figure earlier
  sections of docs/results.md gave.

    .venv/bin/python bench/drift_delay.py out/sweep_bank/runs.csv
    .venv/bin/python bench/drift_delay.py out/sweep_bank/runs.csv out/sweep_before/runs.csv
"""

from __future__ import annotations

import math
import statistics
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from bgc.analysis.distinguish import FALSE_ALARM, LEVEL, ideal_power  # noqa: E402
from bgc.experiment.runs_csv import read_rows  # noqa: E402

DRIFTS = ("incipient", "drift")


def median(values: list[float]) -> float:
    return statistics.median(values) if values else math.nan


def text(value: float) -> str:
    return "never" if math.isinf(value) else ("–" if math.isnan(value) else f"{value:.3g}")


def main(paths: list[str]) -> int:
    rows = []
    for i, path in enumerate(paths):
        for r in read_rows(Path(path)):
            r = dict(r)
            r["label"] = (r.get("detectors") or "mean") + ("" if i == 0 else f" ({Path(path).parent.name})")
            rows.append(r)
    shown = [r for r in rows if r.get("status") == "ok" and r.get("kind") in DRIFTS
             and ideal_power(r.get("detectability") or 0.0, FALSE_ALARM) >= LEVEL]
    print("| model | detector | drift runs | detected | median delay (never counted) | median bound | "
          "delay / bound | median delay of the detected |")
    print("|---|---|---|---|---|---|---|---|")
    for model in dict.fromkeys(r["model"] for r in shown):
        for label in dict.fromkeys(r["label"] for r in shown):
            mine = [r for r in shown if r["model"] == model and r["label"] == label]
            if not mine:
                continue
            delays = [r["delay"] if r.get("delay") is not None else math.inf for r in mine]
            bounds = [r["ideal_delay"] if r.get("ideal_delay") is not None else math.inf for r in mine
                      if not (isinstance(r.get("ideal_delay"), float) and math.isnan(r["ideal_delay"]))]
            detected = [d for d in delays if not math.isinf(d)]
            d, b = median(delays), median(bounds)
            ratio = d / b if b and not (math.isinf(d) or math.isinf(b) or math.isnan(b)) else math.nan
            print(f"| {Path(model).stem} | {label} | {len(mine)} | {len(detected)} | {text(d)} | {text(b)} | "
                  f"{'–' if math.isnan(ratio) else f'{ratio:.2f}'} | {text(median(detected))} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
