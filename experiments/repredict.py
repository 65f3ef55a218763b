"""Recompute the prediction columns of a finished campaign's ``runs.csv``
with the code of this checkout, and leave every other column as the
campaign wrote it.

    .venv/bin/python experiments/repredict.py CONFIG.yaml DIR
    .venv/bin/bgc experiment CONFIG.yaml -o DIR      # rewrites the tables: every run is reused
    .venv/bin/python experiments/repredict.py CONFIG.yaml DIR --check 4   # afterwards: rerun 4 changed rows

``--check N`` (once the predictions are recomputed) runs N of the rows whose
predictions changed again from scratch with this checkout (the changed
models' first, one per model in turn) and compares them with the file's, every
column but the run time and the model file's displayed path: the evidence that
the recomputed file is the one a campaign at this checkout would write.

The prediction columns (``separable``, ``rivals``, ``separation``,
``detectability``) are what ``bgc distinguish`` predicts of a run's scenario
(:func:`bgc.experiment.one_run._separation`). They depend on the model, the scenario,
the noise levels and the run's length only; the diagnosis never reads them.
When a fix to ``bgc distinguish`` leaves the diagnosis unchanged (commit
21e3e08: a sensor's or an actuator's drift as a rival had been taken for no
fault), this gives the rows a campaign run at this checkout would give,
without running the diagnoses again.

The old file is kept beside the new one as ``runs.csv.before-repredict``
(a new file: the script refuses if it exists). The script only rewrites the
``runs.csv`` of a folder ``bgc experiment`` wrote (its ``manifest.json``).
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

from tqdm import tqdm

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))


from bgc.experiment import campaign_file, one_run, runs_csv
from bgc.output import artifacts  # noqa: E402

COLUMNS = ("separable", "rivals", "separation", "detectability")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("config", type=Path)
    ap.add_argument("folder", type=Path)
    ap.add_argument("--check", type=int, metavar="N", help="rerun N changed rows and compare (after recomputing)")
    args = ap.parse_args()
    runs = args.folder / "runs.csv"
    kept = args.folder / "runs.csv.before-repredict"
    if args.check is not None:
        return check(args.config, runs, kept, args.check)
    m = artifacts.read_manifest(args.folder)
    if m is None or artifacts.manifest_command(m) != "experiment" or "runs.csv" not in m.get("files", {}):
        print(f"{runs}: not a runs.csv bgc experiment wrote (no campaign's manifest.json beside it): left alone",
              file=sys.stderr)
        return 1
    if kept.exists():
        print(f"{kept} exists: move it away first (this script never overwrites it)", file=sys.stderr)
        return 1
    c = campaign_file.load_campaign(args.config)
    specs = {s.id: s for s in c.specs}
    rows = runs_csv.read_rows(runs)
    changed = 0
    todo = [(row, specs[row["id"]]) for row in rows if row["id"] in specs and specs[row["id"]].fault is not None]
    # by model and noise levels: each is compiled, and its families prepared, once (as in a campaign's worker)
    todo.sort(key=lambda rs: (rs[1].model_name, rs[1].noise))
    for row, spec in tqdm(todo, desc="predictions", unit="run"):
        one_run._session(spec, spec.process_noise, spec.measurement_noise)  # its compiled model, for the prediction
        new = dict.fromkeys(COLUMNS) | one_run._separation(spec)
        if any(new[k] != row[k] for k in COLUMNS):
            changed += 1
        row.update(new)
    data = runs_csv.csv_header(c) + "".join(runs_csv.csv_row(r, runs_csv.columns(c.states)) for r in rows)
    os.link(runs, kept)  # the old rows stay under the new name
    tmp = runs.with_name("runs.csv.repredict-tmp")
    tmp.write_text(data, encoding="utf-8")
    os.replace(tmp, runs)
    print(f"{runs}: {len(rows)} rows, the predictions of {changed} changed; the old file is {kept}")
    return 0


def check(config: Path, runs: Path, kept: Path, count: int) -> int:
    """Rerun ``count`` rows whose predictions changed and compare them with ``runs``."""
    c = campaign_file.load_campaign(config)
    specs = {s.id: s for s in c.specs}
    new = {r["id"]: r for r in runs_csv.read_rows(runs)}
    old = {r["id"]: r for r in runs_csv.read_rows(kept)}
    changed = [i for i in new if i in old and i in specs and any(new[i][k] != old[i][k] for k in COLUMNS)]
    by_model: dict[str, list[str]] = {}
    for i in changed:
        by_model.setdefault(specs[i].model_name, []).append(i)
    order = [ids[j] for j in range(max(map(len, by_model.values()), default=0)) for ids in by_model.values()
             if j < len(ids)]
    differing = 0
    for i in order[:count]:
        row = one_run.run_one(specs[i])
        diff = {k: (row[k], new[i][k]) for k in row if k not in ("rt", "model")
                and runs_csv.format_cell(k, row[k]) != runs_csv.format_cell(k, new[i][k])}
        differing += bool(diff)
        print(f"{specs[i].scenario} {specs[i].filter} {specs[i].noise} seed {specs[i].seed}: "
              + (f"differs: {diff}" if diff else "the same in every column but rt"))
    print(f"{min(count, len(order))} of {len(changed)} changed rows rerun; {differing} differ")
    return 1 if differing else 0


if __name__ == "__main__":
    raise SystemExit(main())
