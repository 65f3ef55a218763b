"""Diagnosis through mode changes with the mode from the data (the run file's
``mode`` column): the relay circuit (tests/data/hybrid/relay_rl.yaml)
simulated by an independent simulator (solve_ivp with events on its
hand-derived equations: tests/hybrid_reference.py), its relay cycling by
itself and its supply tripped and closed again."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import bgc
from bgc.data import runs
from bgc.diagnosis.isolate import ModeSignatures
from bgc.diagnosis.values import Symbol
from bgc.errors import BgcError
from bgc.output import plots

from conftest import bgc_cli, session
from hybrid_reference import R_aux, V, sampled

ROOT = Path(__file__).resolve().parent.parent
RELAY = ROOT / "tests" / "data" / "hybrid" / "relay_rl.yaml"
#: The relay's sensors' noise stds as its generated model has them (1 % of the signals' size: i_L, v_C).
NOISE = (0.10825763, 0.07757651)


def relay():
    """The relay's session on NumPy, opened once per test process for the
    tests that diagnose with it or read its modes and are not about opening
    it: ``bgc.diagnose(relay(), ...)`` gives what ``bgc.diagnose(RELAY, ...,
    backend="numpy")`` gives (conftest.session)."""
    return session(RELAY, backend="numpy")


def exact_run(seed: int, fault: tuple[float, float] | None = None, end: float = 30.0) -> runs.Run:
    """The exact relay, sampled every 0.01 s with the model's measurement
    noise (seeded), its mode column, as a plant's logger would record it."""
    times, states, modes, _ = sampled(end, fault=fault)
    y = states + np.array(NOISE) * np.random.default_rng(seed).standard_normal(states.shape)
    return runs.Run(times, {"V": np.full(len(times), V)}, {"i_L": y[:, 0], "v_C": y[:, 1]}, {}, {},
                    ("exact relay (solve_ivp)",), f"exact relay, seed {seed}", modes.astype(float))


@pytest.mark.slow
def test_a_relay_cycling_without_a_fault_raises_no_alarm():
    """One fault-free run (seed 1; a second seed ran the same path): the rate over 100 runs is
    bench/hybrid_false_alarms.py's (the RO)."""
    run = exact_run(1)
    assert int(np.sum(np.diff(run.modes) != 0)) >= 25  # many switches, each one the model explains
    report = bgc.diagnose(relay(), data=run)
    assert report.diagnosis.verdict == "no fault", report.diagnosis.candidates


@pytest.mark.slow
@pytest.mark.long
def test_a_fault_only_the_closed_relay_shows_is_isolated_and_sized():
    """R_aux carries current only with the relay closed: its fault is seen there, and the
    symbols read over a stretch in that mode keep it while an open relay's signatures would not."""
    truth = 0.4
    report = bgc.diagnose(relay(), data=exact_run(5, fault=(21.0, R_aux + truth)))
    d = report.diagnosis
    assert d.verdict == "isolated" and d.candidates[0] == "R_aux_abrupt", (d.verdict, d.candidates)
    best = next(h for h in d.hypotheses if h.name == "R_aux_abrupt")
    e = best.estimate
    assert e.low <= truth <= e.high and abs(e.value - truth) / truth < 0.1
    assert abs(d.detection.onset_step * 0.01 - 21.0) < 0.5
    # the report's measurements figure has the mode timeline under the sensors, its ticks the modes' names
    fig = plots.diagnosis_measurements(report)
    assert len(fig.axes) == 3 and [t.get_text() for t in fig.axes[-1].get_yticklabels()] == \
        ["open", "closed", "unpowered"]


@pytest.mark.slow
@pytest.mark.long
def test_stepping_the_diagnoser_through_the_switches_gives_the_batch_diagnosis():
    """Online (a sample at a time, the mode among the inputs as a stream's column) and batch
    give the same diagnosis of the relay through its switches."""
    from bgc.diagnosis.options import DiagnosisOptions
    from bgc.model.protocol import nominal_model

    run = exact_run(6, fault=(5.0, R_aux + 0.4), end=8.0)
    options = DiagnosisOptions(particles=300, seed=1, workers=1)
    batch = bgc.diagnose(relay(), data=run, options=options).diagnosis
    d = relay().diagnoser(options)
    outputs = nominal_model(relay().package).OUTPUTS
    for i, t in enumerate(run.time):
        d.step(float(t), {"V": run.inputs["V"][i], "mode": run.modes[i]}, [run.measurements[y][i] for y in outputs])
    online = d.finish(run)
    assert (online.verdict, online.candidates, online.onset) == (batch.verdict, batch.candidates, batch.onset)
    assert online.candidates[0] == "R_aux_abrupt"
    for h, g in zip(online.hypotheses, batch.hypotheses):
        assert (h.name, h.dropped_step) == (g.name, g.dropped_step)
        assert h.estimate.value == pytest.approx(g.estimate.value, rel=1e-9)


def test_symbols_are_matched_in_the_modes_the_plant_was_in():
    """By hand: R_aux enters the capacitor's equation only with the relay closed (C dv/dt = i -
    v/R_load - v/R_aux), so its rise makes v_C rise in mode closed (signature v_C: 0+, a slope)
    and moves nothing in modes open and unpowered (00 at both sensors). A v_C that rises is
    then explained by R_aux in closed, not in open; over a window of both modes, by closed."""
    view = relay().view
    names = tuple(m.name for m in view.modes)
    assert names == ("open", "closed", "unpowered")
    sigs = ModeSignatures(tuple(m.signatures for m in view.modes), names)
    # each sensor's symbols at derivative orders 0 and 1 (i_L, v_C)
    by_mode = {m.name: tuple("".join(order[:2]) for order in m.signatures.get("R_aux+:abrupt").symbols)
               for m in view.modes}
    assert by_mode["open"] == by_mode["unpowered"] == ("00", "00")
    assert by_mode["closed"] == ("00", "0+")
    rising = (Symbol("v_C", "+", "+", 10),)
    kept = lambda modes: {s.name for s in sigs.hypotheses(rising, modes)[0]}  # noqa: E731
    assert "R_aux+:abrupt" not in kept([1, 1, 1])
    assert "R_aux+:abrupt" in kept([2, 2]) and "R_aux+:abrupt" in kept([1, 2, 1])
    assert "R_aux+:abrupt" in kept([np.nan, 1])  # a sample whose mode the data do not say: any mode
    _, dropped = sigs.hypotheses(rising, [1, 3])
    why = dict((s.name, w) for s, w in dropped)["R_aux+:abrupt"]
    assert why.startswith("in mode open: v_C deviated (+) but R_aux+:abrupt does not move it; in mode unpowered:")


def test_candidates_alike_in_the_modes_seen_are_named_with_the_mode_that_would_separate_them():
    """By hand: with the relay closed, R_load and R_aux are two loads in parallel across C
    (C dv/dt = i - v/R_load - v/R_aux), so a rise of either shows alike; with it open R_aux
    carries no current (its fault shows nothing) and R_load's still does, as it does unpowered
    (C dv/dt = -v/R_load). An ambiguity of the two read while closed may end at the next switch."""
    from types import SimpleNamespace

    from bgc.output.report import mode_split_lines

    view = relay().view
    sigs = ModeSignatures(tuple(m.signatures for m in view.modes), tuple(m.name for m in view.modes))
    pair = ("R_load_abrupt", "R_aux_abrupt")
    split = sigs.split(pair, [2, 2, 2])
    assert split is not None and split.seen == ("closed",)
    assert split.pairs == (("R_load_abrupt", "R_aux_abrupt", ("open", "unpowered")),)
    assert sigs.split(pair, [2, 1, 2]) is None  # open was seen: its signatures separate them already
    assert sigs.split(pair, [2, np.nan]) is None  # a sample of unknown mode: the modes seen are not known
    assert sigs.split(("R_load_abrupt", "v_C_offset_bias"), [2]) is None  # an offset of v_C shows otherwise
    (line,) = mode_split_lines(SimpleNamespace(mode_split=split))
    assert line == ("R_load_abrupt and R_aux_abrupt show the same signature in mode closed, where the plant was "
                    "from the onset on; they differ in open and unpowered: data that reach a switch to one of "
                    "them may separate them")


def test_a_scenario_of_a_model_with_modes_takes_its_switches_and_refuses_them_in_one_line_where_they_do_not_fit():
    with pytest.raises(BgcError, match="'shut' is no mode of the model"):
        bgc.diagnose(RELAY, scenario="R_aux:abrupt:0.4@5", modes="shut@1", backend="numpy")
    with pytest.raises(BgcError, match="modes= with data"):
        bgc.diagnose(RELAY, data=exact_run(1, end=1.0), modes="closed@0.5", backend="numpy")
    with pytest.raises(BgcError, match="the model has no modes"):
        bgc.diagnose(ROOT / "models" / "circuit.yaml", scenario="R2:abrupt:0.6@5", modes="on@1", backend="numpy")
    report = bgc.diagnose(RELAY, scenario="none", modes="unpowered@0.5", steps=100, backend="numpy", particles=100)
    assert report.diagnosis.verdict == "no fault" and set(report.run.modes[50:]) == {3.0}  # tripped from 0.5 s


@pytest.mark.slow
def test_bgc_monitor_reads_the_mode_column_of_a_stream(tmp_path):
    """A run file with its mode column on bgc monitor's standard input (the command in this process,
    conftest.bgc_cli; a real pipe into a real process: tests/test_online.py): the switches raise no alarm."""
    text = runs.run_csv(exact_run(4, end=14.0))  # through the trip at 12 s
    done = bgc_cli("monitor", RELAY, "--data", "-", "-o", tmp_path / "mon", input=text, env={"BGC_BACKEND": "numpy"})
    assert done.returncode == 0, done.stderr
    assert "no fault" in done.stdout and "alarm" not in done.stdout, done.stdout
    assert "input u:mode: from the data" in (tmp_path / "mon" / "report.md").read_text(encoding="utf-8")
