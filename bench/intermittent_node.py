"""A fault that comes and goes as one fault node (bgc/diagnosis/intermittent.py;
issue 47, point 3), diagnosed in one batch, over 20 seeds on two plants, by
the simulators of ``bench/intermittent.py`` (the suite's own, not ``bgc
simulate``: the circuit by the exact solution of its equations, the two
tanks by their exact step map).

Per seed a fault appears three times and goes away twice, its spans drawn at
random (bench/intermittent.py's ``spans``): on even seeds a part of the plant
(R2 or R12, 1.4 to 1.8 times its value), on odd seeds a sensor's offset (f2 by
0.6 to 0.9 A, F12 by 0.05 to 0.08). ``bgc.diagnose`` (the default filter)
reads the whole record. The same seed with the fault present from its
first onset on (a persistent fault) is the control, and its time the cost
beside which the intermittent diagnosis's is given.

Per plant the claims: the fault named (the verdict isolated, the right
fault model) and called intermittent in at least 90 % of the runs; each
appearance and going away dated within one sample of the truth in at
least 90 % of those of the runs named right; the 95 % interval of the
magnitude while present holding the truth in at least 85 % of them; and no
persistent fault of the control called intermittent. Run::

    .venv/bin/python bench/intermittent_node.py [circuit] [two_tank]
"""

from __future__ import annotations

import sys
import tempfile
import time
from pathlib import Path

import _claims  # noqa: F401  (the suite's set-up, before NumPy loads)
import numpy as np

from bgc import events as ev
from intermittent import SEEDS, circuit_rows, tank_rows

MODELS = {"circuit": circuit_rows, "two_tank": tank_rows}
#: Where each plant's model file is, from the checkout.
ROOT = Path(__file__).resolve().parents[1]


def diagnosed(model: str, text: str):
    """``bgc.diagnose`` of the rows ``text`` and its seconds."""
    import bgc

    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "run.csv"
        path.write_text(text, encoding="utf-8")
        started = time.perf_counter()
        report = bgc.diagnose(ROOT / "models" / f"{model}.yaml", path)
        return report.diagnosis, time.perf_counter() - started


def model_name(parameter: str, model: str) -> str:
    """The fault model of the truth's parameter: a part's step, a sensor's bias."""
    return f"{parameter}_bias" if parameter.endswith("_offset") else f"{parameter}_abrupt"


def claim(model: str):
    rows_of = MODELS[model]
    rows, named, dated, changes, covered, control, seconds = [], 0, 0, 0, 0, 0, ([], [])
    right_fault, tried = 0, 0
    for seed in SEEDS:
        text, truth = rows_of(seed, False)
        d, took = diagnosed(model, text)
        p, took_p = diagnosed(model, rows_of(seed, True)[0])
        seconds[0].append(took)
        seconds[1].append(took_p)
        want = model_name(truth["parameter"], model)
        by = {h.name: h for h in d.hypotheses}
        h = by.get(want)
        right = d.verdict == "isolated" and d.candidates == (want,) and h is not None and h.intermittent is not None
        control += any(x.intermittent is not None for x in p.hypotheses)
        tried += any(isinstance(e, ev.IntermittentTried) for e in p.events)
        right_fault += d.verdict == "isolated" and d.candidates == (want,)
        times = [t for a, b in truth["spans"] for t in (a, b) if np.isfinite(t)]  # on, off, on, off, on
        said = "-"
        if right:
            named += 1
            i = h.intermittent
            got = [d.time_of(k) for s in i.spans for k in (s.on, s.off) if k is not None]
            said = ", ".join(f"{t:.2f}" for t in got)
            changes += len(times)
            if len(got) == len(times):
                dated += sum(abs(a - b) <= truth["dt"] + 1e-9 for a, b in zip(got, times))
            # a part's value while present less its nominal 2 (R2 and R12 alike); a sensor's offset itself
            magnitude = truth["value"] - 2.0 if truth["parameter"] in ("R2", "R12") else truth["value"]
            covered += i.low <= magnitude <= i.high
        rows.append(f"  seed {seed:2d} {truth['parameter']:<11} truth on/off {', '.join(f'{t:.2f}' for t in times)};"
                    f" verdict {d.verdict} {', '.join(d.candidates) or '-'}; dated {said}; {took:.1f} s "
                    f"(persistent: {p.verdict} {', '.join(p.candidates) or '-'}, {took_p:.1f} s)")
    n = len(SEEDS)
    rows.append(f"  named the right fault (intermittent or not) in {right_fault} of {n}; the persistent faults tried "
                f"as ones that come and go (their residuals' mean wandered) in {tried} of {n}")
    rows.append(f"  seconds per diagnosis, median: intermittent {np.median(seconds[0]):.2f}, persistent "
                f"{np.median(seconds[1]):.2f}, ratio {np.median(seconds[0]) / np.median(seconds[1]):.2f}")
    checks = [(f"named right and intermittent in {named} of {n} runs >= 90 %", named >= 0.9 * n),
              (f"appearances and goings away dated within a sample: {dated} of {changes} >= 90 %",
               changes > 0 and dated >= 0.9 * changes),
              (f"95 % interval of the magnitude holds the truth in {covered} of {named} >= 85 %",
               named > 0 and covered >= 0.85 * named),
              (f"persistent faults called intermittent: {control} of {n} == 0", control == 0)]
    return rows, checks


CLAIMS = {name: (lambda name=name: claim(name)) for name in MODELS}

if __name__ == "__main__":
    sys.exit(_claims.run(CLAIMS, __doc__))
