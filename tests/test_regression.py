"""Regression corpus: diagnoses recorded with the code of commit 5cca73a, re-recorded with step 6b.

What it is for: a refactor of the diagnosis runtime (bgc/diagnosis/diagnose.py
and what it calls) must not change the diagnoses. Each case of
tests/regression/cases.json is a run file (tests/regression/runs/*.csv, made
by that commit's simulator) of one of the plants (the shipped models as they were before
sensor faults, tests/regression/models/*.yaml, and
tests/data/models/*.yaml), diagnosed with given options through the public
API, ``bgc.api.diagnose(model, data=run, options=...)``; the test diagnoses it
again and checks that the verdict, the candidates, the filter that made the
diagnosis (ckf after the particle observer degenerated), the detection, the
onset, the symbols, the signatures they ruled out and the kinds of note are
the same, and every hypothesis's dropped step, onset, posterior, log evidence
and estimate (value, std, interval, parameter value) the same to a relative
1e-9. The numbers are those of OpenBLAS's Haswell kernels: the root
conftest.py asks OpenBLAS for them on any CPU with AVX2 and FMA (left to
itself OpenBLAS picks kernels by CPU: the corpus was first recorded with
kernels that round as SkylakeX's do, and Haswell's other rounding of a
matrix product moved 5 of the 43 cases, the particle clouds after a
hypothesis dropped a step earlier or later: re-recorded with --only under
Haswell, record.py's docstring); without AVX2 the
cases are skipped with that reason.

The corpus covers the filters gpf, apf, opf and ckf; abrupt faults up and
down, drifts and fault-free runs; noise levels other than the model's;
``identify="filter"``; two workers; and both fallbacks of ``diagnose``: the
particle observer degenerates and the diagnosis switches to ckf (the
drivetrain), and an unexplained verdict with fault models the symbols ruled
out, diagnosed again with every fault model (``every=True``). Verdicts:
isolated, ambiguous, unexplained and no fault.

How it was recorded: ``tests/regression/record.py``, first run with the code
of commit 5cca73a (a pristine worktree of it: ``PYTHONPATH=<checkout> python
tests/regression/record.py``); it simulates the runs and writes cases.json.
Floats are stored as the strings of their repr. A change that is meant to
change diagnoses re-records the corpus with that script (``--keep-runs``:
the same run files) and says why; record.py's docstring lists the
re-recordings (the weighing of the fault models the symbols ruled out, step
6b, changed the hypotheses of 18 cases and the verdicts of two).
"""

from __future__ import annotations

import json
import math
import os
from pathlib import Path

import pytest

from bgc import api
from bgc import events
from bgc.data import runs
from bgc.diagnosis.options import DiagnosisOptions

pytestmark = pytest.mark.slow

ROOT = Path(__file__).resolve().parent.parent
CORPUS = ROOT / "tests" / "regression" / "cases.json"
CASES = json.loads(CORPUS.read_text(encoding="utf-8"))["cases"]


def options_for(case: dict) -> DiagnosisOptions:
    """The diagnosis options of a case (the one place they are built). The
    detector's horizon is the run's length, as it was when the corpus was
    recorded (the false-alarm rate was per file then; it is per horizon now,
    by default the model's declared run length)."""
    o = case["options"]
    t = runs.read_run(ROOT / case["run"]).time
    return DiagnosisOptions(filter=o["method"], particles=o["particles"], seed=o["seed"], workers=o["workers"],
                            identify=o["identify"], switch=o["switch"], rank=o["rank"], refine=o["refine"],
                            horizon=len(t) * float(t[1] - t[0]))


#: The kinds of note the recording code wrote (as record.py classifies them), and the event
#: that says the same now (notes became events).
NOTE_KINDS = {
    "degenerates": events.Degenerate,
    "every": events.AllTried,
    "grid edge": events.Truncated,
    "static alarm": events.Misfit,
    "no sample": events.SensorSilent,
}


def note_kinds(d) -> list[str]:
    """The kinds of note the diagnosis's events stand for, sorted."""
    return sorted(kind for e in d.events for kind, cls in NOTE_KINDS.items()
                  if isinstance(e, cls) and not (isinstance(e, events.AllTried) and e.why != "unexplained"))


def same(actual: float, recorded: str | None) -> bool:
    """``actual`` equals the recorded repr to a relative 1e-9 (nan equals nan,
    an infinity itself only)."""
    if recorded is None:
        return actual is None
    want = float(recorded)
    actual = float(actual)
    if math.isnan(want) or math.isnan(actual):
        return math.isnan(want) and math.isnan(actual)
    if math.isinf(want) or math.isinf(actual):
        return want == actual
    return math.isclose(actual, want, rel_tol=1e-9, abs_tol=1e-12)


def test_the_corpus_is_as_the_brief_says():
    """At least 32 cases, each with its own run file, every filter several
    times, both fallbacks and every verdict present."""
    assert len(CASES) >= 32 and len({c["name"] for c in CASES}) == len(CASES)
    assert all((ROOT / c["run"]).is_file() for c in CASES)
    methods = [c["options"]["method"] for c in CASES]
    assert all(methods.count(m) >= 3 for m in ("gpf", "apf", "opf", "ckf"))
    verdicts = {c["expected"]["verdict"] for c in CASES}
    assert verdicts == {"isolated", "ambiguous", "unexplained", "mismatch", "no fault"}
    kinds = [set(c["expected"]["note_kinds"]) for c in CASES]
    assert any("degenerates" in k and c["expected"]["method"] == "ckf" != c["options"]["method"]
               for k, c in zip(kinds, CASES))
    assert any("every" in k for k in kinds)
    assert any(c["options"]["identify"] == "filter" for c in CASES)
    assert any(c["options"]["workers"] > 1 for c in CASES)


#: The OpenBLAS kernels the corpus was recorded with (the root conftest.py asks for them where the CPU
#: can run them): with others a matrix product rounds differently, and a particle filter's cloud differs.
RECORDED_CORETYPE = "Haswell"


@pytest.mark.skipif(os.environ.get("OPENBLAS_CORETYPE", "").lower() != RECORDED_CORETYPE.lower(),
                    reason=f"the corpus's numbers are those of OpenBLAS's {RECORDED_CORETYPE} kernels, which this "
                           "CPU cannot run (no AVX2) or OPENBLAS_CORETYPE sets others: another rounding")
@pytest.mark.parametrize("case", CASES, ids=[c["name"] for c in CASES])
def test_a_refactor_does_not_change_the_diagnosis(case):
    sim = case["simulation"]
    d = api.diagnose(ROOT / case["model"], data=ROOT / case["run"], options=options_for(case),
                     process_noise=sim["process_noise"], measurement_noise=sim["measurement_noise"]).diagnosis
    e = case["expected"]
    assert d.verdict == e["verdict"]
    assert list(d.candidates) == e["candidates"]
    assert d.options.filter == e["method"], "the filter that made the diagnosis (ckf after a switch)"
    if e["detection"] is None:
        assert d.detection is None
    else:
        det, want = d.detection, e["detection"]
        assert det is not None
        assert (det.step, det.sensor, det.window, det.onset_step) == (want["step"], want["sensor"], want["window"],
                                                                 want["change_point"])
        assert same(det.statistic, want["statistic"]), (det.statistic, want["statistic"])
    assert d.onset_step == e["onset"]
    assert [f"{s.sensor}/{s.sign}/{s.slope}" for s in d.symbols] == e["symbols"]
    assert [signature for signature, _ in d.refuted] == e["refuted"]
    assert note_kinds(d) == sorted(e["note_kinds"]), d.events
    assert [h.name for h in d.hypotheses] == [h["name"] for h in e["hypotheses"]]
    wrong = []
    for h, want in zip(d.hypotheses, e["hypotheses"]):
        if (h.dropped_step, h.start_step, h.onset_step, h.estimate.magnitude) != (want["dropped"], want["start"], want["onset"],
                                                                   want["estimate"]["magnitude"]):
            wrong.append(f"{h.name}: dropped/start/onset/magnitude {(h.dropped_step, h.start_step, h.onset_step, h.estimate.magnitude)}"
                         f" != {(want['dropped'], want['start'], want['onset'], want['estimate']['magnitude'])}")
        numbers = {"posterior": h.posterior, "log_evidence": h.log_evidence,
                   **{k: getattr(h.estimate, k) for k in ("value", "std", "low", "high", "parameter_value")}}
        recorded = {"posterior": want["posterior"], "log_evidence": want["log_evidence"], **{
            k: want["estimate"][k] for k in ("value", "std", "low", "high", "parameter_value")}}
        wrong += [f"{h.name}: {k} {numbers[k]!r} != recorded {recorded[k]}" for k in numbers
                  if not same(numbers[k], recorded[k])]
    assert not wrong, "\n".join(wrong)
