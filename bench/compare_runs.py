"""Compare two campaigns' runs.csv row by row (by run id): every column but
the run times (``rt``, ``ct``). A change that must not alter the diagnoses
(a refactor) shows "different: 0". Then, per detector set (the ``detectors``
column), the verdicts before and after: runs isolated (right, wrong), runs
"unexplained", and runs whose diagnosis is right (the ``right`` column).

    .venv/bin/python bench/compare_runs.py BEFORE/runs.csv AFTER/runs.csv
"""

from __future__ import annotations

import csv
import sys

#: The columns that time a run: they differ from run to run of the same code.
TIMES = {"rt", "ct"}


def rows(path: str) -> dict[str, dict[str, str]]:
    with open(path, newline="") as f:
        return {r["id"]: r for r in csv.DictReader(line for line in f if not line.startswith("#"))}


def main(before_path: str, after_path: str) -> None:
    before, after = rows(before_path), rows(after_path)
    same, different, columns = 0, 0, {}
    for key, a in before.items():
        if key not in after:
            continue
        changed = [c for c in a if c not in TIMES and a[c] != after[key].get(c)]
        if not changed:
            same += 1
            continue
        different += 1
        for c in changed:
            columns[c] = columns.get(c, 0) + 1
        if different <= 5:
            print(key, a["group"], a["scenario"], a["filter"], [(c, a[c], after[key][c]) for c in changed][:4])
    print(f"rows in both: {same + different}; equal but {', '.join(sorted(TIMES))}: {same}; different: {different}; "
          f"only before: {len(set(before) - set(after))}; only after: {len(set(after) - set(before))}")
    print("differing columns:", columns)
    print()
    print("| detectors | isolated (right, wrong) before | after | unexplained before | after | right before | after |")
    print("|---|---|---|---|---|---|---|")
    for detectors in sorted({r.get("detectors") or "" for r in (*before.values(), *after.values())}):
        counts = [verdicts([r for r in side.values() if (r.get("detectors") or "") == detectors])
                  for side in (before, after)]
        (i0, w0, u0, r0), (i1, w1, u1, r1) = counts
        print(f"| {detectors or '-'} | {i0} ({i0 - w0}, {w0}) | {i1} ({i1 - w1}, {w1}) | {u0} | {u1} | {r0} | {r1} |")


def verdicts(rows: list[dict[str, str]]) -> tuple[int, int, int, int]:
    """(runs isolated, of them wrong, runs unexplained, runs right) of ``rows``."""
    isolated = [r for r in rows if r.get("verdict") == "isolated"]
    right = [str(r.get("right") or "").lower() == "true" for r in rows]
    return (len(isolated), sum(str(r.get("right") or "").lower() != "true" for r in isolated),
            sum(r.get("verdict") == "unexplained" for r in rows), sum(right))


if __name__ == "__main__":
    main(*sys.argv[1:3])
