"""Real faults that a glitch could be taken for (issue 48; docs/results.md
§45): short records of the circuit by the suite's exact plant
(tests/test_episodes.py's ``plant``, not ``bgc simulate``), a part stepping
and the record ending soon after, diagnosed by ``bgc.diagnose``. A part's
step that the nominal observer absorbs into its states leaves a spike at
its onset and a small shift after it: the one-sample alarm and quiet
residuals a glitch has.

Two screens:

- ``r3``: R3 10 % low from t = 6, the record ending at t = 8.5 (170 rows),
  seeds 0 to 59 (a review found seeds 3, 13, 31 and 133 called a glitch
  before ``Diagnoser._explained_after``);
- ``parts``: 120 records, each of R1, R2, R3, C1, C2 and L in turn stepping
  to 0.8, 0.9, 1.1 or 1.25 times its value at a time drawn in 3 to 8 s, the
  record ending 32 to 80 samples after it (the draws seeded).

The claim, per screen: no run whose alarm falls at or after the fault's
onset ends with a glitch (a ``Glitch`` event); a glitch before the onset is
a chance excursion, the fault after it undetected. The rows: the verdicts
counted, the runs that alarmed, the glitches and when. Run::

    .venv/bin/python bench/glitch_screen.py [r3] [parts]
"""

from __future__ import annotations

import sys
import tempfile
from collections import Counter
from pathlib import Path

import _claims  # noqa: F401  (the suite's set-up, before NumPy loads)
import numpy as np

DT = 0.05


def _runs(name: str):
    """(part, factor, onset, rows, seed) of screen ``name``."""
    if name == "r3":
        return [("R3", 0.9, 6.0, 170, seed) for seed in range(60)]
    rng = np.random.default_rng(75)
    out = []
    for run in range(120):
        part = ("R1", "R2", "R3", "C1", "C2", "L")[run % 6]
        factor = float(rng.choice([0.8, 0.9, 1.1, 1.25]))
        onset = float(np.round(rng.uniform(3, 8) / DT) * DT)
        out.append((part, factor, onset, int(round(onset / DT)) + int(rng.integers(32, 80)), int(rng.integers(0, 10000))))
    return out


def screen(name: str):
    import bgc
    from bgc import events as ev
    from conftest import ROOT
    from test_episodes import plant

    verdicts, alarmed, rows, wrong = Counter(), 0, [], 0
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "run.csv"
        for part, factor, onset, steps, seed in _runs(name):
            path.write_text(plant(steps, [(onset, {part: factor})], seed=seed), encoding="utf-8")
            d = bgc.diagnose(ROOT / "models" / "circuit.yaml", path).diagnosis
            verdicts[d.verdict] += 1
            glitch = [e for e in d.events if isinstance(e, ev.Glitch)]
            alarmed += d.detection is not None or bool(glitch)
            for g in glitch:
                when = d.time_of(g.step)
                late = when >= onset - 1e-9
                wrong += late
                rows.append(f"  {part} x{factor:g} from t = {onset:g}, {steps} rows, seed {seed}: a glitch at "
                            f"t = {when:g} ({'at or after the onset' if late else 'before the onset'})")
    rows.insert(0, f"  {sum(verdicts.values())} runs, {alarmed} alarmed; verdicts: "
                + ", ".join(f"{v} {n}" for v, n in verdicts.most_common()))
    return rows, [(f"glitches at or after the fault's onset: {wrong} == 0", wrong == 0)]


CLAIMS = {"r3": lambda: screen("r3"), "parts": lambda: screen("parts")}

if __name__ == "__main__":
    sys.exit(_claims.run(CLAIMS, __doc__))
