"""Drift isolation on the sweep's runs, with diagnosis options of your choice
beside the sweep's own result.

    .venv/bin/python bench/drift_isolation.py [--runs out/sweep/runs.csv] [--groups circuit,two_tank,ro]
                                              [--kind incipient] [--filter gpf] [--rank] [--search 64]
                                              [--history 256] [--workers 2]

Reads a finished sweep (``bgc experiment experiments/sweep.yaml -o
out/sweep``), takes its runs of the given groups, fault kind and filter that
bgc detected, and diagnoses each again (the same seeds: the same data, the
same particle count) with the options given here (``--rank``: weigh the
survivors by their static evidence; ``--search``, ``--history``: the drift's
onset grid). Prints per group: the runs, how many the sweep named right (its
``right`` column), how many this run names right, how many it isolates (one
survivor), and its mean seconds per diagnosis. An option's effect is the
difference between two runs of this script, or between one run and the
sweep's column when the sweep ran with the same code.
"""

from __future__ import annotations

import argparse
import sys
import time
from collections import defaultdict
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

from tqdm import tqdm

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))


from bgc.experiment import campaign_file, one_run, runs_csv
from bgc.diagnosis import diagnose as dg  # noqa: E402



def _run(job):
    spec, options = job
    original = dg.DiagnosisOptions
    dg.DiagnosisOptions = lambda **kw: original(**{**kw, **options})  # run_one builds its options here
    try:
        started = time.perf_counter()
        row = one_run.run_one(spec)
        return spec.group, row, time.perf_counter() - started
    finally:
        dg.DiagnosisOptions = original


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--runs", default=str(ROOT / "out" / "sweep" / "runs.csv"))
    ap.add_argument("--config", default=str(ROOT / "experiments" / "sweep.yaml"))
    ap.add_argument("--groups", default="circuit,two_tank,ro")
    ap.add_argument("--kind", default="incipient")
    ap.add_argument("--filter", default="gpf")
    ap.add_argument("--rank", action="store_true")
    ap.add_argument("--search", type=int, default=None)
    ap.add_argument("--history", type=int, default=None)
    ap.add_argument("--workers", type=int, default=2)
    a = ap.parse_args()
    if not Path(a.runs).is_file():
        sys.exit(f"{a.runs}: no finished sweep; run: bgc experiment experiments/sweep.yaml -o out/sweep")
    rows = {r["id"]: r for r in runs_csv.read_rows(Path(a.runs))}
    options = {"rank": a.rank}
    options.update({k: v for k, v in (("search", a.search), ("history", a.history)) if v is not None})
    groups = a.groups.split(",")
    c = campaign_file.load_campaign(a.config)
    specs = [s for s in c.specs if s.group in groups and s.kind == a.kind and s.filter == a.filter
             and rows.get(s.id, {}).get("detected") is True]
    print(f"{len(specs)} detected {a.kind} runs ({a.filter}) of {', '.join(groups)}; options {options}")
    tally = defaultdict(lambda: [0, 0, 0, 0, 0.0])
    with ProcessPoolExecutor(a.workers) as pool:
        for group, row, seconds in tqdm(pool.map(_run, [(s, options) for s in specs]), total=len(specs)):
            t = tally[group]
            t[0] += 1
            t[1] += bool(rows[row["id"]]["right"])
            t[2] += bool(row["right"])
            t[3] += row["verdict"] == "isolated"
            t[4] += seconds
    print("| group | runs | sweep right | right here | isolated here | s per run |")
    print("|---|---|---|---|---|---|")
    for g in groups:
        n, old, new, iso, sec = tally[g]
        if n:
            print(f"| {g} | {n} | {old} ({100 * old / n:.0f} %) | {new} ({100 * new / n:.0f} %) | {iso} | {sec / n:.1f} |")


if __name__ == "__main__":
    main()
