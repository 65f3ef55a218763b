"""A change the nominal observer follows, in a record bounded while watching:
found before the record that shows it is forgotten
(bgc.diagnosis.diagnoser.Diagnoser._changed_while_watching), measured
against the diagnosis of the whole record on the same data.

    .venv/bin/python bench/watched_change.py [--runs 20] [--sizes 2,3] [--keep 15] [--steps 1800] [--onset 45]

The plant is docs/examples/switched_rc.yaml's supply, its contactor closed 5 s
and open 10 s over and over (the data's mode column), solved by solve_ivp
piece by piece on its equations derived by hand (tests/test_watched_change.py,
which checks the solution against the exponentials by hand), with the
sensors' noise the model declares (seeds 1 to ``--runs``). Each seed gives a
healthy stream and, per size, a stream whose R_load is that many ohm higher
from t = ``--onset`` s. Each stream is diagnosed twice, side by side: as a monitor
would (``keep``: the last ``--keep`` seconds of the record while watching)
and with the whole record kept (``bgc diagnose``: the reference, whose end
tests the whole record). The table prints, per size (0: healthy) and way,
the runs, the verdicts (isolated R_load_abrupt, other verdicts), the runs
whose alarm is the change test's (for the monitor, raised while watching),
the intervals that hold the true size and the median onset error.
``BGC_WORKERS=1`` keeps the hypotheses in the bench's process.
"""

from __future__ import annotations

import argparse
import collections
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests"))


def main() -> int:
    import bgc
    from test_watched_change import MODEL, supply

    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--runs", type=int, default=20)
    p.add_argument("--sizes", default="2,3")
    p.add_argument("--keep", type=float, default=15.0)
    p.add_argument("--steps", type=int, default=1800)
    p.add_argument("--onset", type=float, default=45.0)
    a = p.parse_args()
    print(f"bench/watched_change.py --runs {a.runs} --sizes {a.sizes} --keep {a.keep:g} --steps {a.steps} "
          f"--onset {a.onset:g}")
    session = bgc.open(MODEL, backend="numpy")
    sizes = [0.0] + [float(s) for s in a.sizes.split(",")]
    rows = collections.defaultdict(list)
    with tempfile.TemporaryDirectory() as folder:
        for seed in range(1, a.runs + 1):
            for size in sizes:
                path = Path(folder) / f"s{seed}_{size:g}.csv"
                path.write_text(supply(a.steps, a.onset if size else None, size, seed), encoding="utf-8")
                for way, keep in (("watching", a.keep), ("whole", None)):
                    d = bgc.diagnose(session, path, options=bgc.DiagnosisOptions(keep=keep, workers=1)).diagnosis
                    h = next((h for h in d.hypotheses if h.name == "R_load_abrupt"), None)
                    named = d.verdict == "isolated" and d.candidates == ("R_load_abrupt",)
                    covers = named and h is not None and h.estimate.low <= size <= h.estimate.high
                    change = d.detection is not None and d.detection.test == "change"
                    error = abs(d.onset - a.onset) if named and d.onset is not None else None
                    rows[(size, way)].append((d.verdict, named, change, covers, error))
                    print(f"  seed {seed:3d} size {size:g} {way:8s}: {d.verdict}"
                          + (f": {', '.join(d.candidates)}" if d.candidates else "")
                          + (" (change test)" if change else "")
                          + (f", onset {d.onset:.2f}" if d.onset is not None else ""), flush=True)
    print(f"{'size':>5} {'way':9s} {'runs':>5} {'R_load':>7} {'other':>24} {'change':>7} {'covers':>7} "
          f"{'onset err (median)':>19}")
    for (size, way), r in sorted(rows.items()):
        others = collections.Counter(v for v, named, *_ in r if not named)
        errors = [e for *_, e in r if e is not None]
        print(f"{size:5g} {way:9s} {len(r):5d} {sum(x[1] for x in r):7d} "
              f"{', '.join(f'{k} {n}' for k, n in sorted(others.items())) or '-':>24} "
              f"{sum(x[2] for x in r):7d} {sum(x[3] for x in r):7d} "
              f"{(f'{np.median(errors):.2f} s' if errors else '-'):>19}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
