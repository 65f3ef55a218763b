"""A monitor that goes on after a verdict (issue 47, point 2): ``bgc monitor
--episodes`` closes a fault episode at the checkpoint that isolates it,
accommodates the fault in the model it watches with from then on, names the
next fault against the plant as it now is, takes a repaired fault out again
on the stream's word, and re-arms after ``--rearm`` when an episode is not
decided.

The plant is the circuit of models/circuit.yaml simulated by the exact
solution of its equations (tests/test_mismatch.py: the matrix exponential
over each sample period), its parameters changed at the times a test says;
the expectations are those changes, the simulator's truth. The monitors of
the slow tests run on the FAST backend (conftest.fast_backend: numba when
installed; the diagnosis does not depend on it, tests/test_backend.py).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from bgc import events as ev
from bgc.service.episodes import repair_of

from conftest import ROOT, bgc_cli, fast_backend
from test_monitor_state import _no_seconds
from test_mismatch import DT, NOMINAL, START, V, circuit, readings

CIRCUIT = ROOT / "models" / "circuit.yaml"
OPTIONS = ("--particles", "300", "--seed", "3", "--checkpoint", "1", "--episodes")


def plant(steps: int, changes, seed: int = 2, bias: tuple = (), repaired_at: float | None = None) -> str:
    """The circuit's run as a logger's CSV: from each ``(time, {parameter:
    factor of its value in the model file})`` of ``changes`` on, those
    parameters at those values; ``bias`` (time, sensor index, value): that
    sensor reads high from then; a ``# repaired`` line before the row of
    time ``repaired_at``."""
    rng = np.random.default_rng(seed)
    x, lines, cache = np.array(START), ["time,u:V,y:f2,y:f6,y:e11"], {}
    for k in range(1, steps + 1):
        p = dict(NOMINAL)
        for t0, change in changes:
            if k * DT >= t0 - 1e-9:
                p.update({name: factor * NOMINAL[name] for name, factor in change.items()})
        key = tuple(sorted(p.items()))
        e, process, sensor = cache.setdefault(key, circuit(p, 1.0))
        x = e[:3, :3] @ x + e[:3, 3] * V + process * rng.standard_normal(3)
        y = readings(p, x, V) + sensor * rng.standard_normal(3)
        if bias and k * DT >= bias[0] - 1e-9:
            y[bias[1]] += bias[2]
        if repaired_at is not None and abs(k * DT - repaired_at) < DT / 2:
            lines.append("# repaired")
        lines.append(",".join(f"{v:.6g}" for v in (k * DT, V, *y)))
    return "\n".join(lines) + "\n"


def run(tmp_path: Path, text: str, *more):
    p = bgc_cli("monitor", CIRCUIT, "--data", "-", *OPTIONS, *fast_backend("circuit"), *more, "-o", tmp_path / "out",
                input=text)
    assert p.returncode == 0, p.stderr
    report = json.loads((tmp_path / "out" / "report.json").read_text(encoding="utf-8"))
    log = [e for e in report["events"] if e["event"] in ("EpisodeClosed", "Repaired")]
    return p, report, log


#: Two faults one after the other: R2 at 1.6 times its value from t = 6, R1 at 1.5 times from t = 18.
TWO = [(6.0, {"R2": 1.6}), (18.0, {"R1": 1.5})]


@pytest.fixture(scope="module")
def two(tmp_path_factory):
    """The monitor's run of the two faults, uninterrupted."""
    return run(tmp_path_factory.mktemp("two"), plant(600, TWO))


#: R2 at 1.6 times its value from t = 6, back to its value at t = 15, a "# repaired" line there.
REPAIRED = [(6.0, {"R2": 1.6}), (15.0, {"R2": 1.0})]


@pytest.fixture(scope="module")
def said(tmp_path_factory):
    """The plant of REPAIRED, 400 rows, the repair said; and the monitor's run of it, uninterrupted."""
    text = plant(400, REPAIRED, repaired_at=15.0)
    return text, run(tmp_path_factory.mktemp("repaired"), text)


@pytest.mark.slow
def test_two_faults_in_sequence_are_named_in_order_each_sized_against_the_plant_as_it_then_was(two):
    p, report, log = two
    first, second = log
    assert (first["number"], first["candidates"], first["action"], first["parameter"]) == \
        (1, ["R2_abrupt"], "accommodated", "R2")
    assert first["value"] == pytest.approx(1.6 * NOMINAL["R2"], rel=0.03)  # the parameter's value accommodated
    assert 6.0 <= first["alarm"] <= 6.5 and first["began"] == pytest.approx(6.0, abs=2 * DT)
    assert (second["number"], second["candidates"], second["parameter"]) == (2, ["R1_abrupt"], "R1")
    assert second["value"] == pytest.approx(1.5 * NOMINAL["R1"], rel=0.03)
    assert 18.0 <= second["alarm"] <= 19.0 and second["began"] == pytest.approx(18.0, abs=3 * DT)
    assert report["verdict"] == "no fault"  # the plant with both faults accommodated: no third alarm
    lines = p.stdout.splitlines()
    assert any(line.startswith("episode 1 closed") and "R2 = 3.1" in line for line in lines)


@pytest.mark.slow
def test_a_repair_said_in_the_stream_takes_the_fault_out_and_without_it_the_fault_went_away(tmp_path, said):
    _, (_, report, log) = said  # repaired at t = 15
    closed, repaired = log
    assert closed["action"] == "accommodated" and closed["parameter"] == "R2"
    assert (repaired["time"], repaired["episodes"], repaired["parameters"]) == (15.0, [1], ["R2"])
    assert report["verdict"] == "no fault"
    assert not [e for e in report["events"] if e["event"] == "Alarmed"]  # the last diagnoser's: none after it
    # unsaid, the model with R2 accommodated meets a plant whose R2 went back: an alarm, and the fault
    # gone by itself (an intermittent fault's going away: tests/test_intermittent.py)
    _, report, log = run(tmp_path / "unsaid", plant(400, REPAIRED))
    assert [(e["event"], e["action"], e["parameter"]) for e in log] == [
        ("EpisodeClosed", "accommodated", "R2"), ("EpisodeClosed", "ended", "R2")]
    assert 15.0 <= log[1]["alarm"] <= 15.5 and abs(log[1]["began"] - 15.0) <= 0.25


@pytest.mark.slow
@pytest.mark.long
def test_an_episode_not_decided_is_closed_after_rearm_and_the_monitor_watches_again(tmp_path):
    # R2 falls: outside the prior of every fault model (R2_abrupt rises), never isolated. 240 rows (t = 12):
    # the first episode (alarm from t = 6, closed by alarm + 4.05) and the watch after it fit in with room
    # to spare; the monitor is causal, and what it does later (more episodes) is not what is checked here.
    _, report, log = run(tmp_path, plant(240, [(6.0, {"R2": 0.6})]), "--rearm", "3")
    first = log[0]
    assert first["action"] == "re-armed" and first["verdict"] != "isolated" and first["parameter"] is None
    assert 3.0 <= first["time"] - first["alarm"] <= 3.0 + 1.0 + DT  # at the first checkpoint past --rearm
    assert report["events"][0]["event"] == "EpisodeClosed"
    # watching again on the model as it was, while the plant's R2 stays low: the next alarm comes after it
    assert any(e["event"] == "Alarmed" and e["time"] > first["time"] for e in report["events"]), report["events"]


@pytest.mark.slow
@pytest.mark.long
def test_a_sensor_bias_is_accommodated_as_its_offset_or_the_sensor_taken_out(tmp_path):
    text = plant(420, [(16.0, {"R2": 1.6})], bias=(6.0, 0, 0.5))  # f2 reads 0.5 high from t = 6
    _, _, log = run(tmp_path / "kept", text)
    first, second = log[:2]
    assert (first["candidates"], first["parameter"]) == (["f2_offset_bias"], "f2_offset")
    assert first["value"] == pytest.approx(0.5, abs=0.05)
    assert second["candidates"] == ["R2_abrupt"] and second["value"] == pytest.approx(1.6 * NOMINAL["R2"], rel=0.05)
    _, report, log = run(tmp_path / "out", text, "--exclude-faulty-sensor")
    assert (log[0]["action"], log[0]["parameter"]) == ("sensor out", "f2")
    assert log[1]["candidates"] == ["R2_abrupt"]
    assert not [e for e in report["events"] if e["event"] == "SensorMissing"]  # taken out, not missing


@pytest.mark.slow
@pytest.mark.long
def test_a_restart_in_the_second_episode_goes_on_with_the_first_accommodated(tmp_path, two):
    text = plant(600, TWO)
    lines = text.splitlines(keepends=True)
    first = bgc_cli("monitor", CIRCUIT, "--data", "-", *OPTIONS, *fast_backend("circuit"), "--state",
                    tmp_path / "state", "-o", tmp_path / "first",
                    input="".join(lines[:391]))  # stopped at t = 19.5: episode 2's alarm is in
    assert first.returncode == 0, first.stderr
    assert "episode 1 closed" in first.stdout and "episode 2" not in first.stdout
    p, report, log = run(tmp_path, text, "--state", tmp_path / "state")
    assert "resumed from" in p.stdout and "episode 1 closed" not in p.stdout  # said before the restart
    _, whole, whole_log = two
    assert log == whole_log
    assert _no_seconds(report) == _no_seconds(whole)


@pytest.mark.slow
@pytest.mark.long
def test_a_stream_that_ends_as_an_episode_closes_reports_it_and_a_restart_takes_no_repair_twice(tmp_path, said):
    text, (_, _, log) = said
    lines = text.splitlines(keepends=True)
    closing = next(i for i, line in enumerate(lines) if line.startswith(f"{log[0]['time']:g},"))
    p, report, cut = run(tmp_path / "cut", "".join(lines[:closing + 1]))  # the last row is the one it closes on
    assert [e["event"] for e in cut] == ["EpisodeClosed"] and report["verdict"] == "isolated"
    first = bgc_cli("monitor", CIRCUIT, "--data", "-", *OPTIONS, *fast_backend("circuit"), "--state",
                    tmp_path / "state", "-o", tmp_path / "first",
                    input="".join(lines[:330]))  # stopped after the repair (t = 15, row 301)
    assert first.returncode == 0 and "repaired at t = 15" in first.stdout, first.stderr
    p, report, again = run(tmp_path, "".join(lines), "--state", tmp_path / "state")
    assert "repaired" not in p.stdout and again == log  # the repair taken once, before the restart


def test_a_repair_line_names_what_was_repaired():
    assert repair_of("repaired") == ()
    assert repair_of("repaired: R2, C1") == ("R2", "C1")
    assert repair_of("Repaired:R2") == ("R2",)
    assert repair_of("repaired by the night shift") is None
    assert repair_of("model circuit: ...") is None


@pytest.mark.parametrize("args, message", [
    (("--episodes",), "--episodes are closed at checkpoints"),
    (("--rearm", "3"), "--rearm applies to --episodes"),
])
def test_episodes_refuse_what_they_cannot_do_in_one_line(tmp_path, args, message):
    p = bgc_cli("monitor", CIRCUIT, "--data", "-", *args, "-o", tmp_path / "out", input=plant(20, []))
    assert p.returncode != 0 and message in p.stderr and "Traceback" not in p.stderr
    assert len(p.stderr.strip().splitlines()) <= 2


def test_the_fault_log_is_in_words():
    from bgc.output.events import sentence

    e = ev.EpisodeClosed(2, 18.05, "f6", 19.05, "isolated", ("R1_abrupt",), 18.0, "parameter R1 rose by 0.5 ohm",
                         "accommodated", "R1", 1.5)
    assert sentence(e, None) == ("episode 2 closed at t = 19.05 (alarm at t = 18.05 on f6, onset t = 18): isolated: "
                                 "R1_abrupt (parameter R1 rose by 0.5 ohm); accommodated: the model watched from now "
                                 "on has R1 = 1.5")
    assert sentence(ev.Repaired(15.0, (1,), ("R2",)), None) == \
        "repaired at t = 15: episode(s) 1 taken out of the model (R2); watching on the model as it was"


def test_the_docs_example_is_this_plants_run():
    text = (ROOT / "docs" / "examples" / "circuit_two_faults.csv").read_text(encoding="utf-8")
    assert "\n".join(line for line in text.splitlines() if not line.startswith("#")) + "\n" == plant(600, TWO)


def test_a_checkpoints_no_fault_after_an_alarm_closes_the_episode_as_a_false_alarm():
    """A checkpoint's verdict "no fault" while an alarm is open (no fault
    weighed beside the faults, bgc.diagnosis.weigh.no_fault) closes the
    episode: the monitor re-arms on the model as it was, the reason said;
    "ambiguous" does not (it waits for --rearm)."""
    from types import SimpleNamespace

    from bgc.output.events import sentence
    from bgc.service.episodes import Episodes

    log = Episodes(base=None)
    log.alarm = (12.5, "f6")
    assert log.due(SimpleNamespace(verdict="no fault"), 13.0)
    assert not log.due(SimpleNamespace(verdict="ambiguous"), 13.0)
    e = ev.EpisodeClosed(1, 12.5, "f6", 13.0, "no fault", (), None, "", "re-armed", reason="false alarm")
    assert sentence(e, None) == ("episode 1 closed at t = 13 (alarm at t = 12.5 on f6): no fault; no fault explains "
                                 "the data better than chance (a false alarm the detector's budget allows): "
                                 "watching again on the model as it was")
