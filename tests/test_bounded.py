"""A monitor that runs for months keeps a bounded record (issue 47, point 1).

While watching, a diagnoser with ``DiagnosisOptions(keep=...)`` keeps the
last ``keep`` steps of its record (up to twice that between two cuts); the
models of the record kept start from the nominal observer's estimate at its
first step. The plant is the circuit of models/circuit.yaml simulated by
the exact solution of its equations (tests/test_mismatch.py: the matrix
exponential over each sample period), healthy or with its R2 stepping to
1.6 times its value; the truth the diagnoses are held to is the simulated
fault, and the whole record's diagnosis of the same rows is the reference
a bounded one must meet. The slow tests run on the FAST backend
(conftest.fast_session, fast_backend: numba when installed; the diagnosis
does not depend on it, tests/test_backend.py), the others on NumPy.
"""

from __future__ import annotations

import math
import re

import numpy as np
import pytest

import bgc
from bgc import events as ev
from bgc.diagnosis.state import DiagnoserState
from bgc.model.package import STARTED_FROM, forget_started

from conftest import ROOT, bgc_cli, fast_backend, fast_session, session
from test_mismatch import DT, NOMINAL, START, V, circuit, readings
from test_monitor_state import report, saved_rows

CIRCUIT = ROOT / "models" / "circuit.yaml"
STEPS = 1500
#: The record kept while watching, in steps (the least bgc takes with the default options is 256 + 32).
KEEP = 300
#: R2's step: 1.6 times its value from ONSET (after three cuts of the record), the bias 0.6 the fault model sizes.
ONSET, FACTOR = 1250, 1.6


def plant(seed: int = 1, onset: int | None = ONSET, steps: int = STEPS, missing: tuple = ()) -> list[tuple]:
    """The circuit's rows (t, V, f2, f6, e11) at the model's noise, R2 times
    FACTOR from step ``onset`` (None: healthy); the steps in ``missing`` have
    no row."""
    rng = np.random.default_rng(seed)
    faulty_p = dict(NOMINAL, R2=FACTOR * NOMINAL["R2"])
    healthy, faulty = circuit(NOMINAL, 1.0), circuit(faulty_p, 1.0)
    x, rows = np.array(START), []
    for k in range(1, steps + 1):
        p, (e, process, sensor) = (faulty_p, faulty) if onset is not None and k >= onset else (NOMINAL, healthy)
        x = e[:3, :3] @ x + e[:3, 3] * V + process * rng.standard_normal(3)
        y = readings(p, x, V) + sensor * rng.standard_normal(3)
        if k not in missing:
            rows.append((k * DT, V, *y))
    return rows


def options(keep: int | None, **more) -> bgc.DiagnosisOptions:
    return bgc.DiagnosisOptions(particles=300, seed=2, workers=1, horizon=STEPS * DT,
                                keep=None if keep is None else keep * DT, **more)


def feed(d, rows, watch=None) -> list:
    """Every row into diagnoser ``d``; the events with their times as told
    when they happened; ``watch(d)`` after each row."""
    told = []
    for t, v, *y in rows:
        b = d.step(t, {"V": v}, dict(zip(("f2", "f6", "e11"), y)))
        told += [(e, None if getattr(e, "step", None) is None else d.time_of(e.step)) for e in b.events]
        if watch is not None:
            watch(d)
    return told


def diagnoser(keep: int | None, fast: bool = True, **more):
    """A diagnoser of the circuit's stream, on the FAST backend (else NumPy: the fast tier's)."""
    opened = fast_session("circuit") if fast else session("circuit")
    return opened.diagnoser(options(keep, **more), inputs=["V"], sensors=["f2", "f6", "e11"])


@pytest.fixture(scope="module")
def faulty():
    """The diagnoses of the faulty plant's rows with the record bounded and whole."""
    rows = plant()
    bounded, whole = diagnoser(KEEP), diagnoser(None)
    lengths = []
    told = feed(bounded, rows, lambda d: lengths.append(len(d.loop.samples)))
    feed(whole, rows)
    return dict(bounded=bounded, whole=whole, told=told, lengths=lengths, diagnosis=bounded.finish(),
                reference=whole.finish())


@pytest.mark.slow
def test_while_watching_the_record_stays_within_twice_what_is_kept(faulty):
    d, lengths = faulty["bounded"], faulty["lengths"]
    alarm = next(e for e, _ in faulty["told"] if isinstance(e, ev.Alarmed))
    watching = lengths[:next(i for i, (t, *_) in enumerate(plant()) if t >= faulty["whole"].time_of(alarm.step))]
    assert max(watching) <= 2 * KEEP
    assert d.offset > 0 and d.offset + len(d.loop.samples) == STEPS  # every step taken, the first ones forgotten
    assert d.offset % KEEP == 0 and d.offset >= 3 * KEEP  # cut whenever the record reached twice KEEP


@pytest.mark.slow
def test_a_fault_after_the_record_was_cut_is_isolated_as_with_the_whole_record(faulty):
    bounded, whole = faulty["diagnosis"], faulty["reference"]
    assert bounded.verdict == whole.verdict == "isolated"
    assert bounded.candidates == whole.candidates == ("R2_abrupt",)
    truth = (FACTOR - 1.0) * NOMINAL["R2"]  # the bias of R2 in ohm
    assert bounded.estimate.low <= truth <= bounded.estimate.high
    assert abs(bounded.onset - ONSET * DT) <= 3 * DT and bounded.onset == pytest.approx(whole.onset)
    assert bounded.estimate.value == pytest.approx(whole.estimate.value, rel=1e-3)
    assert bounded.time[0] == pytest.approx(faulty["bounded"].offset * DT + DT)  # the report's record is the kept one


@pytest.mark.slow
def test_the_alarm_is_told_at_the_time_of_the_data(faulty):
    (alarm, at), = [(e, t) for e, t in faulty["told"] if isinstance(e, ev.Alarmed)]
    (whole, _), = [(e, None) for e in faulty["reference"].events if isinstance(e, ev.Alarmed)]
    assert at == pytest.approx(faulty["whole"].time_of(whole.step))
    assert ONSET * DT <= at <= (ONSET + 40) * DT


@pytest.mark.slow
def test_a_healthy_stream_many_times_longer_than_the_record_raises_no_alarm():
    d = diagnoser(KEEP)
    told = feed(d, plant(seed=5, onset=None, steps=4 * STEPS))
    assert not [e for e, _ in told if isinstance(e, ev.Alarmed)]
    assert len(d.loop.samples) <= 2 * KEEP
    assert d.finish().verdict == "no fault"


def test_a_gap_is_told_at_its_time_and_one_before_the_record_kept_is_forgotten():
    before, after = range(400, 420), range(1300, 1320)
    d = diagnoser(KEEP, fast=False)
    told = feed(d, plant(onset=None, missing=tuple(before) + tuple(after)))
    gaps = [(e, t) for e, t in told if isinstance(e, ev.Gap)]
    assert [t for _, t in gaps] == pytest.approx([before[0] * DT, after[0] * DT])
    diagnosis = d.finish()
    kept = [e for e in diagnosis.events if isinstance(e, ev.Gap)]
    assert len(kept) == 1 and diagnosis.time[kept[0].step] == pytest.approx(after[0] * DT)


def test_the_forgotten_started_packages_are_freed_every_few_cuts(monkeypatch):
    """Each cut starts the record's models from a package of their own and
    forgets the last one: cycles only the cyclic collector frees. With its
    automatic passes off, the diagnoser's own full collection, after every
    COLLECT_EVERY (here 2) packages forgotten, frees them: the three cuts of
    1500 steps kept 300 forget the model's own package (kept: it is the
    session's), then two started ones; the first one's functions are all
    freed at the second's forgetting, the second's wait for the fourth
    (with no collection of its own, neither would be freed)."""
    import gc
    import sys
    import types
    import weakref

    from bgc.diagnosis import diagnoser as module

    forgotten = []

    def forget(package):  # the package's functions: a module's functions and its globals are the cycles
        if getattr(package, STARTED_FROM, None) is not None:
            modules = [m for name, m in sys.modules.items() if name.startswith(package.__name__)]
            forgotten.append([weakref.ref(f) for m in modules for f in vars(m).values()
                              if isinstance(f, types.FunctionType) and f.__module__ == m.__name__])
        forget_started(package)

    monkeypatch.setattr(module, "forget_started", forget)
    monkeypatch.setattr(module, "COLLECT_EVERY", 2)
    monkeypatch.setattr(module, "_forgotten", 0)
    d = diagnoser(KEEP, fast=False)
    was = gc.isenabled()
    gc.disable()
    try:
        feed(d, plant(onset=None))
        freed = [[ref() is None for ref in refs] for refs in forgotten]
    finally:
        if was:
            gc.enable()
    assert len(freed) == 2 and all(freed[0]) and not any(freed[1]) and all(forgotten), freed


@pytest.mark.slow
def test_a_gap_across_the_moment_the_record_is_cut_keeps_its_time():
    missing = tuple(range(2 * KEEP - 10, 2 * KEEP + 10))  # the row after the gap brings the steps past the cut
    d = diagnoser(KEEP)
    told = feed(d, plant(onset=None, steps=2 * KEEP + 40, missing=missing))
    (gap, at), = [(e, t) for e, t in told if isinstance(e, ev.Gap)]
    assert at == pytest.approx(missing[0] * DT) and d.offset > 0
    kept = [e for e in d.finish().events if isinstance(e, ev.Gap)]
    assert len(kept) == 1 and d.time_of(kept[0].step) == pytest.approx(missing[0] * DT)


@pytest.mark.slow
@pytest.mark.parametrize("method", ["gpf", "ckf"])
def test_a_state_taken_after_cuts_goes_on_as_if_it_never_stopped(method):
    rows = plant(seed=3)
    whole = diagnoser(KEEP, filter=method)
    feed(whole, rows)
    expected = whole.finish()
    first = diagnoser(KEEP, filter=method)
    feed(first, rows[:1000])
    assert first.offset > 0 and getattr(first.config.package, STARTED_FROM, None) is not None
    data = first.to_state().to_bytes()
    forget_started(first.config.package)  # as in a new process: the started package is made again from the state
    again = type(first).from_state(diagnoser(KEEP, filter=method).config, DiagnoserState.from_bytes(data))
    assert again.offset == first.offset
    feed(again, rows[1000:])
    got = again.finish()
    assert (got.verdict, got.candidates, got.onset) == (expected.verdict, expected.candidates, expected.onset)
    assert got.estimate.value == expected.estimate.value
    assert math.isclose(got.estimate.value, (FACTOR - 1.0) * NOMINAL["R2"], abs_tol=0.1)


@pytest.mark.slow
def test_bgc_monitor_keeps_a_bounded_record_and_state(tmp_path):
    lines = ["time,u:V,y:f2,y:f6,y:e11\n"] + [",".join(f"{v:.6g}" for v in row) + "\n" for row in plant(seed=4)]
    p = bgc_cli("monitor", CIRCUIT, "--data", "-", "--particles", "300", "--seed", "2", "--keep", f"{KEEP * DT:g}",
                *fast_backend("circuit"), "--state", tmp_path / "state", "-o", tmp_path / "out", input="".join(lines))
    assert p.returncode == 0, p.stderr
    assert saved_rows(tmp_path / "state") <= 2 * KEEP  # the rows the state holds are the record's
    alarm = next(line for line in p.stdout.splitlines() if "fault detected" in line.lower() or "alarm" in line.lower())
    at = float(alarm.split("t = ")[1].split(":")[0])
    assert ONSET * DT <= at <= (ONSET + 40) * DT
    r = report(tmp_path / "out")
    assert r["verdict"] == "isolated" and r["diagnosis"] == ["R2_abrupt"]
    assert r["data"]["t_first"] == pytest.approx(3 * KEEP * DT + DT)  # the record kept: from the third cut on


def test_the_docs_and_the_help_say_the_monitors_default_record():
    from bgc.cli.main import build_parser
    from bgc.service.monitor import KEEP_STEPS

    text = " ".join((ROOT / "docs" / "commands.md").read_text(encoding="utf-8").split())
    said = re.findall(r"by default (\d+) steps of the model's grid", text)
    monitor = next(a for a in build_parser()._subparsers._group_actions[0].choices.values() if a.prog.endswith("monitor"))
    text = " ".join(monitor.format_help().split())
    helped = re.findall(r"^--keep TIME [^-]*?default: (\d+) steps", text[text.rfind("--keep TIME"):])  # its help
    assert said and helped and {int(n) for n in said + helped} == {KEEP_STEPS}
