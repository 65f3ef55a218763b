"""Run again some runs of a finished campaign, with the code of this checkout,
and print each one's verdict as the campaign recorded it beside the verdict
now: the runs a change was made for, and the runs it must leave alone.

    .venv/bin/python bench/replay_runs.py CAMPAIGN.yaml RUNS.csv [--where COLUMN=VALUE ...] [ID ...]

``RUNS.csv`` is the campaign's ``runs.csv`` (``bgc experiment CAMPAIGN.yaml -o
DIR``); the runs replayed are those whose id is given, or, with ``--where``
(repeatable, all must hold), those whose columns hold those values
(``--where verdict=isolated --where right=false``: the wrong isolations;
``--where kind=noise``). Each run is the campaign's own (its spec: the same
seed, data, filter and detectors), diagnosed in this process. Prints one
line per run and the counts of verdicts then and now.
"""

from __future__ import annotations

import argparse
import sys
from collections import Counter
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from bgc.experiment import one_run  # noqa: E402
from bgc.experiment.campaign_file import load_campaign  # noqa: E402
from compare_runs import rows  # noqa: E402  (this folder: the same reading of a runs.csv)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("campaign", help="the campaign file the runs were made by")
    parser.add_argument("runs", help="its runs.csv")
    parser.add_argument("ids", nargs="*", help="run ids (the runs.csv's id column)")
    parser.add_argument("--where", action="append", default=[], metavar="COLUMN=VALUE",
                        help="replay the rows whose COLUMN holds VALUE (repeatable: all must hold)")
    a = parser.parse_args(argv)
    conditions = []
    for w in a.where:
        column, sep, value = w.partition("=")
        if not sep:
            parser.error(f"--where {w!r}: write COLUMN=VALUE")
        conditions.append((column, value))
    by_id = rows(a.runs)
    chosen = {key: r for key, r in by_id.items()
              if (key in a.ids or (conditions and not a.ids)) and all(r.get(c) == v for c, v in conditions)}
    unknown = sorted(set(a.ids) - set(by_id))
    if unknown:
        parser.error(f"run ids not in {a.runs}: {', '.join(unknown[:5])}")
    if not chosen:
        parser.error("no run of the runs file matches")
    specs = {s.id: s for s in load_campaign(a.campaign).specs if s.id in chosen}
    missing = sorted(set(chosen) - set(specs))
    if missing:
        parser.error(f"runs not in {a.campaign} (another campaign's?): {', '.join(missing[:5])}")
    then, now = Counter(), Counter()
    print("| run | scenario | noise | filter | detectors | then | now |")
    print("|---|---|---|---|---|---|---|")
    for key, r in chosen.items():
        row = one_run.run_one(specs[key])
        was = f"{r.get('verdict')} {r.get('diagnosed') or ''}".strip()
        is_ = f"{row.get('verdict')} {row.get('diagnosed') or ''}".strip()
        then[r.get("verdict")] += 1
        now[row.get("verdict")] += 1
        print(f"| {key} | {r.get('scenario')} | {r.get('noise')} | {r.get('filter')} | {r.get('detectors')} | {was} "
              f"| {is_} |",
              flush=True)
    print(f"\n{len(chosen)} runs; verdicts then: {dict(then)}; now: {dict(now)}")


if __name__ == "__main__":
    main()
