"""A change the observer follows, found while watching before the record
that shows it is forgotten (bgc.diagnosis.diagnoser.Diagnoser._changed_while_watching).

A monitor keeps, while watching, the last ``keep`` of its record and forgets
the older half once it holds twice that. A fault whose residuals the
nominal observer follows raises no alarm of the detector's windows; before
this test, the record kept at the stream's end held only the faulty plant,
and the verdict was "mismatch: calibrate the model". The plant here is the
supply of docs/examples/switched_rc.yaml (a contactor S charging C
through R_s, R_load draining it), its contactor closed 5 s and open 10 s
over and over (the data's mode column), solved by solve_ivp piece by piece
on its equations derived by hand:

    closed:  C dv/dt = (V - v)/R_s - v/R_load,   i_s = (V - v)/R_s
    open:    C dv/dt = -v/R_load,                 i_s = 0

with the sensors' noise the model declares.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from bgc.diagnosis.diagnoser import WATCH_SHARE, watch_level
from bgc.diagnosis.fit import LEVEL

from conftest import FAST, ROOT, bgc_cli
from conftest import session as open_once

MODEL = ROOT / "docs" / "examples" / "switched_rc.yaml"
V, R_S, C, R_LOAD, DT = 10.0, 1.0, 1.0, 4.0, 0.05
NOISE = {"v_C": 0.16, "i_s": 0.2}  # the model's noise: 0.02 of each reading's scale (tests/test_uncommanded.py)
CLOSED, OPEN = 5.0, 10.0


def closed_at(t: float) -> bool:
    return (t + 1e-9) % (CLOSED + OPEN) < CLOSED


def supply(steps: int, onset: float | None, size: float, seed: int) -> str:
    """The run file: R_load ``size`` ohm higher from ``onset`` (None: healthy)."""
    times = DT * np.arange(1, steps + 1)
    end = float(times[-1]) + DT
    edges = {k * (CLOSED + OPEN) + d for k in range(int(end // (CLOSED + OPEN)) + 1) for d in (0.0, CLOSED)}
    if onset is not None:
        edges.add(onset)
    cuts = sorted(e for e in edges if e < end) + [end]
    v, x = np.empty(steps), 0.0
    for a, b in zip(cuts[:-1], cuts[1:]):
        on = closed_at(a)
        r = R_LOAD + (size if onset is not None and a >= onset - 1e-12 else 0.0)
        inside = (times >= a - 1e-9) & (times < b - 1e-9)
        sol = solve_ivp(lambda _, y, on=on, r=r: [((V - y[0]) / R_S if on else 0.0) / C - y[0] / (r * C)], (a, b),
                        [x], dense_output=True, rtol=1e-11, atol=1e-13)
        v[inside] = sol.sol(times[inside])[0]
        x = float(sol.sol(b)[0])
    i_s = np.array([(V - x) / R_S if closed_at(t) else 0.0 for t, x in zip(times, v)])
    rng = np.random.default_rng(seed)
    lines = ["time,mode,u:V,y:v_C,y:i_s"]
    for t, a, b in zip(times, v + NOISE["v_C"] * rng.standard_normal(steps),
                       i_s + NOISE["i_s"] * rng.standard_normal(steps)):
        lines.append(f"{t:.10g},{1 if closed_at(t) else 2},{V},{float(a)!r},{float(b)!r}")
    return "\n".join(lines) + "\n"


def test_the_supply_made_here_is_its_closed_form():
    """The run file's noise-free readings against the exponentials by hand
    (closed: tau = C R_s R_load / (R_s + R_load) toward V R_load / (R_s +
    R_load); open: tau = R_load C toward 0), the load's step at 45 s."""
    times = DT * np.arange(1, 1201)
    cuts = sorted({k * 15.0 + d for k in range(5) for d in (0.0, 5.0)} | {45.0})
    value, start, expected = 0.0, 0.0, []
    for t in times:
        while any(start < c <= t + 1e-9 for c in cuts):
            c = min(c for c in cuts if start < c <= t + 1e-9)
            value = _piece(value, start, c)
            start = c
        expected.append(_piece(value, start, t))
    noise_free = supply(1200, 45.0, 3.0, 0).splitlines()[1:]
    rng = np.random.default_rng(0)
    drawn = NOISE["v_C"] * rng.standard_normal(1200)
    read = np.array([float(line.split(",")[3]) for line in noise_free]) - drawn
    assert np.max(np.abs(read - np.array(expected))) < 1e-8


def _piece(value: float, start: float, t: float) -> float:
    on = closed_at(start)
    r = R_LOAD + (3.0 if start >= 45.0 - 1e-9 else 0.0)
    tau, inf = (C * R_S * r / (R_S + r), V * r / (R_S + r)) if on else (r * C, 0.0)
    return inf + (value - inf) * math.exp(-(t - start) / tau)


def test_the_watching_tests_level_holds_its_share_of_the_budget():
    """Two tests every ``keep`` steps are 2 horizon / keep tests per
    horizon: at a level of share * budget * keep / horizon / 2 each their
    union is at most the share of the budget; never above the fit test's
    own level."""
    assert watch_level(0.01, 1024, 200) == LEVEL  # 0.05 * 0.01 * 1024 / 200 / 2 = 0.00128: the fit test's own
    assert watch_level(0.01, 1024, 300) == pytest.approx(0.05 * 0.01 * 1024 / 300 / 2)
    assert 2 * watch_level(0.01, 1024, 100_000) * 100_000 / 1024 == pytest.approx(WATCH_SHARE * 0.01)


@pytest.mark.slow
@pytest.mark.long
def test_a_load_step_the_observer_follows_is_found_before_its_record_is_forgotten(tmp_path):
    """R_load 3 ohm higher from t = 45 s, monitored keeping 15 s (300
    steps): no test of the detector alarms (the observer follows the
    plant). The record is tested each time it reaches 600 steps, at t = 30,
    45, 60, ...; at t = 60 it holds t = 30.05 to 60, fails the test of the
    model, fits it before the change point and changed there: the alarm is
    raised at the change point, the monitor says it as the data come, and
    the diagnosis names R_load's step, its interval holding the 3 ohm and
    its onset within 0.5 s of 45 s. The input's cell left empty at t = 50
    (between the change point and the test) is said once, as it comes, not
    again when the record is taken from the change point. The stream is
    the run's first 65 s (:data:`STEPPED`: the test at t = 60 and 5 s
    after it). The healthy plant (the same noise) raises no alarm over
    the whole 90 s (1800 steps)."""
    out = tmp_path / "out"
    rows = [",".join(["50", "2", "", *row.split(",")[3:]]) if row.startswith("50,") else row
            for row in first_rows(supply(1800, 45.0, 3.0, 2), STEPPED).splitlines()]
    p = bgc_cli("monitor", MODEL, "--data", "-", "--keep", "15", "--backend", FAST, "-o", out,
                input="\n".join(rows) + "\n")
    assert p.returncode == 0, p.stderr
    assert p.stdout.count("input u:V is empty") == 1, p.stdout
    assert "detected at t = 60 (the change test: the residuals of" in p.stdout, p.stdout
    report = json.loads((out / "report.json").read_text(encoding="utf-8"))
    det = report["detection"]  # dated at the change point, raised when the record was tested
    assert det["test"] == "change" and det["raised"] == pytest.approx(60.0) and 45.0 <= det["time"] <= 46.0, det
    said = [e for e in report["events"] if e["event"] == "ChangeMissed"]
    assert len(said) == 1 and said[0]["watching"] and said[0]["found"], said
    assert report["verdict"] == "isolated" and report["diagnosis"] == ["R_load_abrupt"], report["verdict"]
    (best,) = [h["estimate"] for h in report["hypotheses"] if h["model"] == "R_load_abrupt"]
    assert best["interval"][0] <= 3.0 <= best["interval"][1], best
    assert abs(report["onset"] - 45.0) <= 0.5, report["onset"]
    assert "the record kept while watching fails the test of the model" in p.stdout
    healthy = bgc_cli("monitor", MODEL, "--data", "-", "--keep", "15", "--backend", FAST, "-o", tmp_path / "h",
                      input=supply(1800, None, 0.0, 2))
    assert healthy.returncode == 0, healthy.stderr
    assert "switched_rc: no fault" in healthy.stdout and "change test" not in healthy.stdout, healthy.stdout
    assert "does not fit" not in healthy.stdout, healthy.stdout


@pytest.mark.slow
@pytest.mark.long
def test_a_verdict_made_again_with_every_fault_model_keeps_the_watching_alarm(monkeypatch):
    """When the verdict at the end is made again with every fault model (an
    unexplained verdict with fault models the symbols ruled out:
    Diagnoser._retry), the alarm the record's test raised at a change point
    while watching is raised again in the record made anew (Loop.forced):
    its detector does not alarm either, so without it the replay would see
    no fault. The load step of the test above (its first 65 s, the same
    rows), the retry asked for once here: the diagnosis made again alarms
    at the same change point and names R_load's step."""
    from bgc.diagnosis.diagnoser import Diagnoser
    from bgc.diagnosis.options import DiagnosisOptions

    asked = []
    retry = Diagnoser._retry

    def once(self, d, loop=None):
        if not asked and (self.loop if loop is None else loop).forced is not None:
            asked.append(d.detection)
            return True
        return retry(self, d, loop)

    monkeypatch.setattr(Diagnoser, "_retry", once)
    d = open_once(MODEL, backend=FAST).diagnoser(DiagnosisOptions(keep=15.0, workers=1))
    for row in first_rows(supply(1800, 45.0, 3.0, 2), STEPPED).splitlines()[1:]:
        t, mode, v, v_c, i_s = (float(x) for x in row.split(","))
        d.step(t, {"V": v, "mode": mode}, {"v_C": v_c, "i_s": i_s})
    final = d.finish()
    assert asked and asked[0].test == "change", asked
    assert final.detection.test == "change" and final.detection.step == asked[0].step, final.detection
    assert final.verdict == "isolated" and final.candidates[0] == "R_load_abrupt", (final.verdict, final.candidates)


@pytest.mark.slow
@pytest.mark.long
def test_a_plant_off_its_model_from_the_start_is_said_so_at_the_first_test_of_the_record(tmp_path):
    """R_load 6 ohm where the model says 4, from the first sample: the
    observer follows the plant (no alarm), and a larger load drains the
    capacitor less, so v_C reads above the model's prediction: its
    residuals' mean is positive throughout, with no change in the record.
    Kept 15 s (300 steps), the record is first tested when it holds 600
    samples, at t = 30: the monitor says then that the model does not fit,
    naming v_C, a positive offset and R_load among what to calibrate, not
    only at the stream's end; once (one test per diagnoser: the record
    tested again at t = 45, 60, 75 says nothing more), also through a state
    saved and taken up on the next row; its sentence, read at the stream's
    end, still names the record it tested. With --checkpoint 20 the
    checkpoint's test says it first, at t = 20 (400 samples), and the
    watching test does not say it again. The 6 ohm stream is the run's
    first 76 s (:data:`OFF`: its record's tests at t = 30, 45, 60 and 75
    all made, the end's verdict at t = 76). With the load 5 ohm, nothing is
    said while watching over the whole 90 s, and the end's test passes
    too."""
    import bgc
    from bgc.diagnosis.diagnoser import Diagnoser
    from bgc.diagnosis.options import DiagnosisOptions
    from bgc.diagnosis.state import DiagnoserState
    from bgc.output.events import sentence

    text = first_rows(supply(1800, 0.0, 2.0, 2), OFF)
    end = float(f"{OFF * DT:.10g}")  # the last row's time (76): the end's verdict
    p = bgc_cli("monitor", MODEL, "--data", "-", "--keep", "15", "--backend", FAST, "-o", tmp_path / "out",
                input=text)
    assert p.returncode == 0, p.stderr
    said = [line for line in p.stdout.splitlines() if "the model does not fit this plant" in line]
    assert said[0].startswith("t = 30: the model does not fit this plant: over the whole record (t = 0.05 to 30, "
                              "600 samples) sensor v_C's residuals average +"), p.stdout
    assert said[0].endswith("--estimate noise,R_load)"), said[0]
    assert len(said) == 2 and said[1].startswith(f"t = {end:g}: "), said  # the second: the end's verdict
    assert "switched_rc: mismatch" in p.stdout and "detected at" not in p.stdout, p.stdout
    # the report keeps what was said at t = 30, on data its record (the last 15 s) forgot since, and the end's
    kept = _misfits(tmp_path / "out")
    assert [(e["time"], e["span"]) for e in kept] == [(30.0, [0.05, 30.0, 600]), (end, None)], kept
    assert kept[0]["text"] == said[0][len("t = 30: "):] and kept[0]["step"] is None and kept[0]["last"] is None
    assert f"- {said[0]}" in (tmp_path / "out" / "report.md").read_text(encoding="utf-8")
    # and so does the report of a monitor restarted from its state after it was said: the state holds it
    head = "\n".join(text.splitlines()[:700]) + "\n"
    first = bgc_cli("monitor", MODEL, "--data", "-", "--keep", "15", "--backend", FAST, "--state",
                    tmp_path / "state", "-o", tmp_path / "first", input=head)
    assert first.returncode == 0 and said[0] in first.stdout, first.stdout
    again = bgc_cli("monitor", MODEL, "--data", "-", "--keep", "15", "--backend", FAST, "--state",
                    tmp_path / "state", "-o", tmp_path / "again", input=text)
    assert again.returncode == 0 and said[0] not in again.stdout, again.stdout  # said before the restart
    assert [(e["time"], e["span"]) for e in _misfits(tmp_path / "again")] == [(30.0, [0.05, 30.0, 600]),
                                                                              (end, None)]
    checked = bgc_cli("monitor", MODEL, "--data", "-", "--keep", "15", "--checkpoint", "20", "--backend", FAST,
                      "-o", tmp_path / "checked", input=text)  # the checkpoint's test says it first, at t = 20
    said = [line for line in checked.stdout.splitlines() if "the model does not fit this plant" in line]
    assert checked.returncode == 0 and len(said) == 2, checked.stdout  # not again at t = 30; the end's
    assert said[0].startswith("t = 20: ") and said[1].startswith(f"t = {end:g}: "), said
    assert [(e["time"], e["span"]) for e in _misfits(tmp_path / "checked")] == [(20.0, [0.05, 20.0, 400]),
                                                                                (end, None)]
    nearer = bgc_cli("monitor", MODEL, "--data", "-", "--keep", "15", "--backend", FAST, "-o", tmp_path / "near",
                     input=supply(1800, 0.0, 1.0, 2))  # 5 ohm: within what the watching level lets pass
    assert nearer.returncode == 0 and "does not fit" not in nearer.stdout, nearer.stdout
    assert "switched_rc: no fault" in nearer.stdout, nearer.stdout
    session = open_once(MODEL, backend=FAST)
    rows = [line.split(",") for line in text.splitlines()[1:]]
    d = session.diagnoser(DiagnosisOptions(keep=15.0, workers=1))
    events, kept = [], []
    for k, row in enumerate(rows):
        if k == 601:  # a restart on the row after the one that said it: the record halved, not tested again
            d = Diagnoser.from_state(d.config, DiagnoserState.from_bytes(d.to_state().to_bytes()))
        belief = d.step(float(row[0]), {"V": float(row[2]), "mode": float(row[1])},
                        {"v_C": float(row[3]), "i_s": float(row[4])})
        events += [(k, type(e).__name__) for e in belief.events]
        kept += [e for e in belief.events if type(e).__name__ == "Mismatched"]
    # tested as the 601st row comes (the record holds 600 samples), said in that row's belief
    assert [e for e in events if e[1] in ("Mismatched", "Alarmed", "ChangeMissed")] == [(600, "Mismatched")], events
    # its sentence read at the end, the record halved many times since, still names the record it tested
    assert "over the whole record (t = 0.05 to 30, 600 samples)" in sentence(kept[0], d.time_of)
    # a batch diagnosis keeping 15 s says it too, dated, among the final diagnosis's events
    (tmp_path / "run.csv").write_text(text, encoding="utf-8")
    batch = bgc.diagnose(session, tmp_path / "run.csv", options=DiagnosisOptions(keep=15.0, workers=1)).diagnosis
    said = [e for e in batch.events if type(e).__name__ == "Mismatched" and e.said is not None]
    assert [(e.said, e.span) for e in said] == [(30.0, (0.05, 30.0, 600))], batch.events


def _misfits(folder: Path) -> list[dict]:
    """The misfits a monitor's report.json holds, in its order."""
    report = json.loads((folder / "report.json").read_text(encoding="utf-8"))
    return [e for e in report["events"] if e["event"] == "Mismatched"]


def _kolmogorov_tail(x: float) -> float:
    """P(sup |B| > x) for a Brownian bridge B: 2 sum_j (-1)^(j-1) exp(-2 j^2 x^2)."""
    return 2.0 * sum((-1) ** (j - 1) * math.exp(-2.0 * j * j * x * x) for j in range(1, 101))


def test_the_cusum_test_of_a_shift_against_its_closed_form():
    """shifted's statistic by hand (the largest partial sum about the mean,
    over sqrt(n) times the standard deviation), its tail Kolmogorov's
    series, each sensor at the level over the sensors read: a column just
    past the Bonferroni cut is shifted, one just short of it is not, a
    column read too rarely is not tested."""
    from bgc.diagnosis.fit import LEAST, shifted

    level, n = 0.01, 400
    cut = next(x / 1000 for x in range(1000, 3000) if _kolmogorov_tail(x / 1000) < level / 2)  # two sensors read

    def scaled(target: float) -> np.ndarray:
        # a step at the middle and an alternating wiggle: the wiggle's size sets the statistic (closed form below)
        step = np.r_[np.ones(n // 2), -np.ones(n // 2)]
        wiggle = (-1.0) ** np.arange(n)

        def statistic(c: float) -> float:
            a = step + c * wiggle
            return float(np.max(np.abs(np.cumsum(a - a.mean())))) / (math.sqrt(n) * a.std(ddof=1))

        lo, hi = 0.0, 100.0  # the statistic falls as the wiggle grows: bisect to the target
        for _ in range(200):
            mid = (lo + hi) / 2
            lo, hi = (mid, hi) if statistic(mid) > target else (lo, mid)
        return step + lo * wiggle

    rare = np.full(n, np.nan)
    rare[: 2 * LEAST - 1] = 5.0 * (-1.0) ** np.arange(2 * LEAST - 1)
    z = np.column_stack([scaled(cut * 1.01), scaled(cut * 0.99), rare])
    assert shifted(z, level) == (0,)


def test_the_cusum_tests_level_on_white_residuals():
    """On white N(0, 1) residuals (n = 1000, 4000 series) the test rejects
    at about its level (the bridge's law is the limit: a little under it)."""
    from bgc.diagnosis.fit import shifted

    rng = np.random.default_rng(7)
    z = rng.standard_normal((1000, 4000))
    rejected = sum(bool(shifted(z[:, [j]], 0.05)) for j in range(4000)) / 4000
    assert 0.035 <= rejected <= 0.055, rejected


def test_a_misfit_said_before_keeps_its_own_time_and_leaves_the_ends_timing_advice():
    """A misfit said while watching, dated (said at t = 102.4 over t = 0.05
    to 102.4, 2048 samples, its steps those of a record forgotten since),
    leading a report's events: report.json gives it its own time and span,
    no steps; report.md's line its own time, whatever the record's steps
    now mean; its sentence the record it was said on. The end's own misfit,
    which names the other input timing, still gives the report's advice
    (the first misfit of the events names none)."""
    from types import SimpleNamespace

    from bgc import events as ev
    from bgc.output import events as words
    from bgc.output import report

    said = ev.Mismatched(1023, 1023, ("sensor e11's residuals average +0.12 stds",), False, 10, (), ("noise",),
                         said=102.4, span=(0.05, 102.4, 2048))
    end = ev.Mismatched(60, 60, (), False, 10, (), ("noise",), timing="start", timing_fits=True, timing_ratio=9.0)

    def time_of(k):  # the record kept: from t = 51.25, 200 steps
        return 51.25 + 0.05 * k if 0 <= k < 200 else float("nan")

    plain = words.record(said, time_of)
    assert (plain["time"], plain["said"], plain["span"], plain["step"], plain["last"]) == \
        (102.4, 102.4, [0.05, 102.4, 2048], None, None), plain
    assert "over the whole record (t = 0.05 to 102.4, 2048 samples)" in plain["text"]
    d = SimpleNamespace(events=(said, end), time_of=time_of)
    assert report._when(d, said) == "t = 102.4: " and report._timing(d) == "start"


#: The rows of the load step's run (R_load 3 ohm higher from t = 45) the two tests of it stream: t = 0.05
#: to 65, the record's test at t = 60 (as the 1201st row comes) and 5 s of the faulty plant after it: the
#: rows of the 90 s run after those only lengthened the hypotheses' tracking after the alarm.
STEPPED = 1300
#: The rows of the run of R_load 6 ohm from the start the misfit test streams: t = 0.05 to 76, each of
#: its record's tests (as the rows of t = 30.05, 45.05, 60.05 and 75.05 come) made, as over the 90 s run
#: (whose next, at t = 90.05, never came), and the end's own test.
OFF = 1520


def first_rows(text: str, steps: int) -> str:
    """A run file's header and its first ``steps`` rows (the same readings: the rows after cut off)."""
    lines = text.splitlines()
    return "\n".join(lines[: 1 + steps]) + "\n"
