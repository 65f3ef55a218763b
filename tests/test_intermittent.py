"""Intermittent faults (issue 47, point 3): a fault that appears and goes
away by itself, again and again.

``bgc simulate`` injects one (``NAME:KIND:MAGNITUDE@ON-OFF,ON-OFF,ON``: present
over each span); ``bgc monitor --episodes`` names each appearance as the
fault it is, accommodates it, names its going away as the same fault model
sized back to the value in the model file (the step back is a candidate of
every diagnoser watching a fault accommodated: its signature the opposite
direction's, its prior reaching back), and calls it intermittent from then
on, with the spans it was present over.

The monitored plant is the circuit of models/circuit.yaml simulated by the
exact solution of its equations (tests/test_mismatch.py), R2 switched at
the times a test says; the expectations are those times and values.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

import bgc
from bgc import events as ev
from bgc.diagnosis.isolate import with_returns
from bgc.model.package import accommodated, started_package
from bgc.output.render import distinguishability_text
from bgc.service.episodes import Episodes

from conftest import ROOT, bgc_cli, session
from test_episodes import plant, run
from test_mismatch import DT, NOMINAL

CIRCUIT = ROOT / "models" / "circuit.yaml"


# ------------------------------------------------------------------ the simulator
def test_an_intermittent_fault_is_present_over_its_spans_and_nominal_between_them():
    s = bgc.simulate(CIRCUIT, "R2:abrupt:1.2@5-10,15", seed=1, steps=400)
    present = (s.time >= 5 - 1e-9) & (s.time < 10 - 1e-9) | (s.time >= 15 - 1e-9)
    np.testing.assert_array_equal(s.parameters["R2"], np.where(present, NOMINAL["R2"] + 1.2, NOMINAL["R2"]))
    assert s.truth["onset"] == 5.0 and s.truth["magnitude"] == 1.2
    # between the spans the plant is the healthy one: its currents go back towards the healthy steady
    # state (R1 + R2 + R3 = 4 ohm from 10 V: 2.5 A through R2), with the present span's lower current
    f6 = s.measurements["f6"]
    assert f6[(s.time > 8) & (s.time < 10)].mean() < 2.3 and f6[(s.time > 13) & (s.time < 15)].mean() > 2.4


def test_a_sensors_intermittent_bias_is_on_its_reading_over_its_spans_only():
    steady = bgc.simulate(CIRCUIT, "none", seed=1, steps=200)
    s = bgc.simulate(CIRCUIT, "f2:bias:0.5@2-4,6-8", seed=1, steps=200)
    on = ((s.time >= 2 - 1e-9) & (s.time < 4 - 1e-9)) | ((s.time >= 6 - 1e-9) & (s.time < 8 - 1e-9))
    np.testing.assert_allclose(s.measurements["f2"] - steady.measurements["f2"], np.where(on, 0.5, 0.0), atol=1e-12)
    np.testing.assert_array_equal(s.measurements["f6"], steady.measurements["f6"])


@pytest.mark.parametrize("scenario, said", [
    ("R2:incipient:0.1@5-10", "an incipient fault does not come and go"),
    ("R2:abrupt:1@10-5", "must increase"),
    ("R2:abrupt:1@5-10,12-11", "must increase"),
])
def test_an_intermittent_fault_the_simulator_cannot_make_is_refused_in_one_line(scenario, said):
    p = bgc_cli("simulate", CIRCUIT, "--steps", "300", "--fault", scenario, "-o", "-")
    assert p.returncode != 0 and said in p.stderr and "Traceback" not in p.stderr
    assert len(p.stderr.strip().splitlines()) == 1


def test_the_run_files_header_says_when_the_fault_was_present(tmp_path):
    out = tmp_path / "run.csv"
    p = bgc_cli("simulate", CIRCUIT, "--steps", "400", "--fault", "R2:abrupt:1.2@5-10,15", "--seed", "1", "-o", out)
    assert p.returncode == 0, p.stderr
    assert "intermittent, present t = 5 to 10, from t = 15" in out.read_text(encoding="utf-8")


# ------------------------------------------------------- the way back, a candidate
def test_a_fault_accommodated_gets_the_step_back_as_a_candidate_its_signature_and_its_prior(tmp_path):
    s = session("circuit")
    package = started_package(s.package, theta={"R2": 3.2})
    assert accommodated(package) == ("R2",) and accommodated(s.package) == ()
    # the prior of R2's step reaches back to 2 ohm with half that way beyond (3.2 - 1.2 - 0.6 = 1.4 ohm)
    # and keeps its own upper bound (+100 % of 2 ohm); its drift's prior is its own
    assert package.MODELS["R2_abrupt"].FAULT_PRIOR == pytest.approx((-1.8, 2.0))
    assert package.MODELS["R2_incipient"].FAULT_PRIOR == s.package.MODELS["R2_incipient"].FAULT_PRIOR
    assert package.MODELS["R1_abrupt"].FAULT_PRIOR == s.package.MODELS["R1_abrupt"].FAULT_PRIOR
    signatures = s.view.signatures
    back = with_returns(signatures, accommodated(package))
    added = [x for x in back.signatures if x not in signatures.signatures]
    assert [x.name for x in added] == ["R2-:abrupt"]
    # the compiler's own TRANSCEND signature of R2 falling, from the model with both directions listed
    both = tmp_path / "circuit.yaml"
    both.write_text(CIRCUIT.read_text(encoding="utf-8").replace(
        "R2: {kinds: [abrupt, incipient], direction: increase}", "R2: {kinds: [abrupt, incipient], direction: both}"),
        encoding="utf-8")
    assert added[0] == bgc.open(both).view.signatures.get("R2-:abrupt")
    # a parameter whose model lists both directions already gets nothing more
    assert with_returns(signatures, ("R1",)).signatures == signatures.signatures


def test_the_fault_log_of_an_intermittent_fault_survives_its_state():
    s = session("circuit")
    log = Episodes(s.package)
    log.spells = {"R2": [[6.0, 14.0, 3.19], [22.0, None, 3.24]]}
    log.theta, log.by = {"R2": 3.24}, {"R2": 3}
    log.log = [ev.EpisodeClosed(3, 22.0, "f6", 24.6, "isolated", ("R2_abrupt",), 22.0, "", "accommodated", "R2",
                                3.24, None, 2, ((6.0, 14.0), (22.0, None)))]
    again = Episodes(s.package)
    again.restore(json.loads(json.dumps(log.plain())))
    assert again.log == log.log and again.spells == log.spells
    assert again.present("R2") == ((6.0, 14.0), (22.0, None)) and again.theta == {"R2": 3.24}


# ----------------------------------------------------------------- the monitor
#: R2 at 1.6 times its value from t = 6 to 14, and again from t = 22.
ON_OFF = [(6.0, {"R2": 1.6}), (14.0, {"R2": 1.0}), (22.0, {"R2": 1.6})]


@pytest.mark.slow
def test_a_fault_that_comes_and_goes_is_named_each_time_and_called_intermittent(tmp_path):
    p, report, log = run(tmp_path, plant(600, ON_OFF))
    assert [(e["candidates"], e["action"], e["parameter"], e["appearance"]) for e in log] == [
        (["R2_abrupt"], "accommodated", "R2", 1), (["R2_abrupt"], "ended", "R2", 1),
        (["R2_abrupt"], "accommodated", "R2", 2)]
    first, gone, back = log
    # each change is dated as a permanent fault of its size is: within the first one's detection
    # delay (its alarm less the truth's onset), and a sample
    delay = first["alarm"] - 6.0
    for e, truth in zip(log, (6.0, 14.0, 22.0)):
        assert abs(e["began"] - truth) <= delay + DT + 1e-9, (e["began"], truth, delay)
    # sized: 3.2 ohm while present, back at the model file's 2 ohm in between
    assert first["value"] == pytest.approx(3.2, rel=0.05) and back["value"] == pytest.approx(3.2, rel=0.05)
    assert gone["value"] == 2.0
    spans = back["present"]
    assert len(spans) == 2 and spans[1][1] is None
    assert [spans[0][0], spans[0][1], spans[1][0]] == pytest.approx([6.0, 14.0, 22.0], abs=delay + DT + 1e-9)
    assert "went away without a repair (intermittent: present t = 6" in p.stdout
    assert "the intermittent fault of R2 is back (appearance 2" in p.stdout
    # the last diagnoser watches with R2 at its faulty value again: no alarm after the third episode
    assert report["verdict"] == "no fault"


@pytest.mark.slow
def test_a_fault_that_stays_is_never_said_gone(tmp_path):
    """The step back is a candidate, not a verdict the data must refute: a
    second fault of another part after the first one (R1 from t = 18) is
    named as itself with R2 still present."""
    p, report, log = run(tmp_path, plant(480, [(6.0, {"R2": 1.6}), (18.0, {"R1": 1.5})], seed=5))
    assert [(e["candidates"], e["action"], e["parameter"]) for e in log] == [
        (["R2_abrupt"], "accommodated", "R2"), (["R1_abrupt"], "accommodated", "R1")]
    assert "went away" not in p.stdout


def actuator_plant(steps: int, spans, offset: float, seed: int = 2) -> str:
    """The circuit's run (the exact solution of its equations) with its source
    driving ``offset`` volts above the 10 V the logger records over ``spans``
    ((on, off), ...): an actuator's intermittent fault."""
    from test_mismatch import START, V, circuit, readings

    rng = np.random.default_rng(seed)
    e, process, sensor = circuit(dict(NOMINAL), 1.0)
    x, lines = np.array(START), ["time,u:V,y:f2,y:f6,y:e11"]
    for k in range(1, steps + 1):
        t = k * DT
        v = V + (offset if any(a - 1e-9 <= t < b - 1e-9 for a, b in spans) else 0.0)
        x = e[:3, :3] @ x + e[:3, 3] * v + process * rng.standard_normal(3)
        y = readings(NOMINAL, x, v) + sensor * rng.standard_normal(3)
        lines.append(",".join(f"{w:.6g}" for w in (t, V, *y)))
    return "\n".join(lines) + "\n"


@pytest.mark.slow
def test_an_actuators_fault_that_comes_and_goes_is_named_each_time(tmp_path):
    """The source drives 1.5 V high over t = 6 to 14 and from t = 22 (the
    logged input stays 10 V): its offset is accommodated, named gone, and
    back, each change dated as a permanent one's, sized 1.5 V while on."""
    _, report, log = run(tmp_path, actuator_plant(600, [(6.0, 14.0), (22.0, np.inf)], 1.5))
    assert [(e["candidates"], e["action"], e["parameter"], e["appearance"]) for e in log] == [
        (["V_offset_bias"], "accommodated", "V_offset", 1), (["V_offset_bias"], "ended", "V_offset", 1),
        (["V_offset_bias"], "accommodated", "V_offset", 2)]
    delay = log[0]["alarm"] - 6.0
    for e, truth in zip(log, (6.0, 14.0, 22.0)):
        assert abs(e["began"] - truth) <= delay + DT + 1e-9, (e["began"], truth, delay)
    assert log[0]["value"] == pytest.approx(1.5, rel=0.1) and log[2]["value"] == pytest.approx(1.5, rel=0.1)
    assert log[1]["value"] == 0.0  # the model file's offset
    assert report["verdict"] == "no fault"


def test_distinguish_tells_apart_an_intermittent_faults_first_appearance_as_the_step_it_is():
    """Until it first goes away an intermittent fault is the permanent one:
    the prediction over the samples before t = 14 (279 of 0.05 s) is that
    of R2's step from t = 6 over those samples."""
    intermittent = bgc.distinguishability(CIRCUIT, "R2:abrupt:1.2@6-14,22", steps=600)
    permanent = bgc.distinguishability(CIRCUIT, "R2:abrupt:1.2@6", steps=279)
    assert intermittent.steps == 279
    assert intermittent.distinctions == permanent.distinctions
    assert "its first appearance is told apart, over the 279 samples" in distinguishability_text(intermittent)


# ------------------------------------------------------------- found in review
def test_the_spans_in_words_take_an_onset_not_known():
    from bgc.output.events import spans_text

    assert spans_text(((6.0, 14.0), (22.0, None))) == "t = 6 to 14 and from t = 22"
    assert spans_text(((None, 14.0),)) == "at an onset not known"


def test_a_repair_starts_an_intermittent_faults_story_again():
    """The report's ``intermittent``, as the monitor's episodes keep it: a
    fault of R2 after R2's repair is a new one (a permanent fault then is
    not intermittent); one that went away after the repair is."""
    from bgc.api.reports import DiagnosisReport

    def closed(action, began, value, appearance, present):
        return ev.EpisodeClosed(0, began, "f6", began + 1, "isolated", ("R2_abrupt",), began, "", action, "R2",
                                value, None, appearance, present)

    before = [closed("accommodated", 6.0, 3.2, 1, ((6.0, None),)), closed("ended", 14.0, 2.0, 1, ((6.0, 14.0),)),
              closed("accommodated", 22.0, 3.2, 2, ((6.0, 14.0), (22.0, None))),
              ev.Repaired(30.0, (3,), ("R2",))]

    class Log:
        def __init__(self, log):
            self.fault_log = tuple(log)

    after = [closed("accommodated", 40.0, 3.5, 1, ((40.0, None),))]
    assert DiagnosisReport.intermittent.fget(Log(before + after)) == {}
    again = after + [closed("ended", 50.0, 2.0, 1, ((40.0, 50.0),))]
    assert DiagnosisReport.intermittent.fget(Log(before + again)) == {
        "R2": {"spans": ((40.0, 50.0),), "values": [3.5], "mean": 3.5}}


def test_an_injection_made_in_python_keeps_its_spans_in_its_text():
    import math

    from bgc.analysis.simulate import FaultInjection

    f = FaultInjection("R2", "abrupt", 1.2, 6.0, "parameter", "R2", None, ((6.0, 14.0), (22.0, math.inf)))
    assert f.text == "R2:abrupt:1.2@6.0-14.0,22.0"


def test_distinguish_cuts_to_the_first_appearance_only_when_it_ends_inside_the_run():
    assert not bgc.distinguishability(CIRCUIT, "R2:abrupt:1.2@6-100", steps=300).first_appearance
    cut = bgc.distinguishability(CIRCUIT, "R2:abrupt:1.2@6-10,12", steps=300)
    assert cut.first_appearance and cut.steps < 300


def test_the_csv_text_given_as_a_path_is_refused_in_one_line():
    from bgc.errors import ArgumentTypeError

    with pytest.raises(ArgumentTypeError, match="splitlines"):
        bgc.monitor(CIRCUIT, "time,u:V,y:f2,y:f6,y:e11\n0.05,10,1,2,3\n")
