"""A glitch of one reading on a plant that stays healthy (issue 48: "a
reading off once on a healthy plant names a fault"): the alarm it raises
is found a glitch and the verdict is "no fault" (`Diagnoser._false_alarm`,
`bgc.events.Glitch`); the test of the model's fit is not failed by one
reading (`bgc.filters.residuals`: the variance without its farthest
reading).

The plant is the circuit's exact discretisation (tests/test_episodes.py's,
not bgc's simulator); the variance test's reference is drawn here, and the
expected largest square against a Monte Carlo mean."""

from __future__ import annotations

import json
import math
from statistics import NormalDist

import numpy as np
import pytest

import bgc
from bgc import events as ev
from bgc.filters import residuals
from bgc.output.events import sentence

from conftest import FAST, ROOT, bgc_cli, fast_backend, fast_session
from test_episodes import plant
from test_later_onset import _reading_off

CIRCUIT = ROOT / "models" / "circuit.yaml"


@pytest.mark.slow
def test_one_reading_off_on_a_healthy_plant_is_a_glitch_not_a_fault(tmp_path):
    # f6 reads 0.8 A low at t = 6 alone (about 7 of its residual's stds: the detector's one-sample window
    # alarms); the plant stays healthy to the end (t = 20). Before, the verdict named whichever fault model
    # explained that reading best (an offset of f6 from t = 6, or a part changed by a few per cent).
    data = tmp_path / "run.csv"
    data.write_text(_reading_off(plant(400, [], seed=4), 6.0, 1, -0.8), encoding="utf-8")
    d = bgc.diagnose(fast_session("circuit"), data).diagnosis
    assert (d.verdict, d.candidates, d.detection) == ("no fault", (), None)
    (glitch,) = [e for e in d.events if isinstance(e, ev.Glitch)]
    assert d.time_of(glitch.step) == pytest.approx(6.0) and glitch.sensor == "f6"
    assert glitch.statistic < -4.6 or glitch.statistic > 4.6  # past the one-sample threshold
    assert d.time_of(glitch.until) == pytest.approx(20.0)
    assert sentence(glitch, d.time_of) == (  # as docs/diagnosis.md section 6.2 prints it
        f"the alarm at t = 6 was one reading of f6, {abs(glitch.statistic):.3g} of its stds from the model's "
        "prediction, and the model's residuals stay within its noise after it to the data's end (t = 6.05 to "
        "t = 20): a glitch of that reading, not a fault that persists or comes back; the diagnosis "
        "was made again without it")
    assert not any(isinstance(e, ev.FalseAlarm) for e in d.events)


@pytest.mark.slow
@pytest.mark.parametrize("seed", [3, 133])
def test_a_parts_step_whose_spike_alone_alarms_is_not_a_glitch(tmp_path, seed):
    # R3 10 % low from t = 6, the record ending at t = 8.5: the nominal observer takes most of the step into its
    # states, its residuals a spike at the step (e11, past the one-sample threshold) and a shift after it too
    # small for the detector or the test of the model's fit over 50 samples (a review found these seeds named
    # "no fault", a glitch). R3's own model explains the samples after the spike better than no fault with the
    # spike's reading left out by far more than the verdict's Bayes factor: the first diagnosis stands
    data = tmp_path / "run.csv"
    data.write_text(plant(170, [(6.0, {"R3": 0.9})], seed=seed), encoding="utf-8")
    d = bgc.diagnose(fast_session("circuit"), data).diagnosis
    assert d.detection is not None and d.detection.window == 1 and d.time_of(d.detection.step) == pytest.approx(6.0)
    assert not any(isinstance(e, ev.Glitch) for e in d.events)
    assert (d.verdict, d.candidates) == ("isolated", ("R3_abrupt",))


@pytest.mark.slow
def test_two_readings_off_are_not_one_glitch(tmp_path):
    # the same reading and the next one off: the detector armed anew after the first alarm alarms again at
    # once; no quiet stretch follows the alarm, and nothing is called a glitch
    data = tmp_path / "run.csv"
    text = _reading_off(_reading_off(plant(400, [], seed=4), 6.0, 1, -0.8), 6.05, 1, -0.8)
    data.write_text(text, encoding="utf-8")
    d = bgc.diagnose(fast_session("circuit"), data).diagnosis
    assert d.detection is not None and d.time_of(d.detection.step) == pytest.approx(6.0)
    assert not any(isinstance(e, (ev.Glitch, ev.FalseAlarm)) for e in d.events)


def test_the_expected_largest_square_against_draws():
    rng = np.random.default_rng(11)
    for n in (2, 10, 300):
        draws = (rng.standard_normal((20000, n)) ** 2).max(axis=1)
        error = draws.std() / math.sqrt(len(draws))
        assert abs(residuals.largest_square(n) - draws.mean()) < 4 * error
    assert residuals.largest_square(1) == pytest.approx(1.0, abs=1e-6)  # one draw: its mean square
    n = 10 ** 6
    assert abs(residuals.largest_square(n) - (2 * math.log(n) - math.log(math.log(n)))) < 1.5


def _fails(z: np.ndarray) -> bool:
    return bool(residuals.failures(residuals.summary([z[:, None]], ["y"]), 0.001, correlation=False,
                                   narrower=False))


def _plain(z: np.ndarray) -> bool:
    """The variance and mean tests without the reading left out (the variance by its exact tail, as
    ``failures``' first half): what the glitch rule adds its second half to."""
    n, cut = len(z), NormalDist().inv_cdf(1 - 0.001 / 2 / 2)  # failures' quantile: level 0.001 over two tests
    return bool(abs(z.mean()) * math.sqrt(n) > cut or residuals.variance_z(z.var() * n / (n - 1), n - 1) > cut)


def test_one_far_reading_does_not_make_the_noise_too_small_and_a_wider_noise_still_does():
    rng = np.random.default_rng(3)
    glitched = wide = before = 0
    for _ in range(400):
        z = rng.standard_normal(60)
        z[30] = 7.0 * rng.choice([-1.0, 1.0])  # one reading seven stds off
        glitched += _fails(z)
        before += _plain(z)
        wide += _fails(1.6 * rng.standard_normal(60))  # a plant 1.6 times noisier than its model
    assert before > 0.5 * 400  # the plain variance test calls most of them a noise too small
    assert glitched <= 0.02 * 400  # the mean test moved by the reading, at its level
    assert wide >= 0.9 * 400


def test_the_test_fails_only_where_the_plain_one_does():
    # requiring the variance without the farthest reading too: the test's size is at most the plain one's
    rng = np.random.default_rng(8)
    for scale in (1.0, 1.2, 1.4):
        for _ in range(300):
            z = scale * rng.standard_normal(int(rng.integers(10, 200)))
            assert not _fails(z) or _plain(z)


@pytest.mark.slow
@pytest.mark.long
def test_a_monitor_closes_a_glitchs_episode_and_watches_on(tmp_path):
    # the same glitch streamed through bgc monitor --episodes: the checkpoint after it says no fault, and
    # the episode is closed as a glitch, the model watched as it was (nothing accommodated)
    text = _reading_off(plant(400, [], seed=4), 6.0, 1, -0.8)
    p = bgc_cli("monitor", CIRCUIT, "--data", "-", "--episodes", "--checkpoint", "5", *fast_backend("circuit"),
                "-o", tmp_path / "out",
                input=text)
    assert p.returncode == 0, p.stderr
    report = json.loads((tmp_path / "out" / "report.json").read_text(encoding="utf-8"))
    (closed,) = [e for e in report["events"] if e["event"] == "EpisodeClosed"]
    assert (closed["verdict"], closed["action"], closed["reason"], closed["alarm"]) == \
        ("no fault", "re-armed", "glitch", 6.0)
    assert ("episode 1 closed at t = 12.6 (alarm at t = 6 on f6): no fault; the alarm was one reading off, the "
            "data within the model's noise after it (a glitch of that reading): watching again on the "
            "model as it was") in p.stdout
    assert report["verdict"] == "no fault"


@pytest.mark.slow
@pytest.mark.long
def test_a_glitch_on_a_plant_whose_mode_the_data_do_not_give(tmp_path):
    # docs/examples/level.yaml's tank, its pump switched by the tank's pressure and no mode column (the modes
    # decoded from the data): a healthy run by solve_ivp on its hand-derived equations, one reading of p seven
    # noise stds high at t = 10.05. Was "unexplained: p_offset_bias"; the glitch's "no fault" is not read again
    # mode by mode (a fault's would be)
    from hybrid_reference import LEVEL_NOISE, level_csv, level_run

    times, modes, y_p, y_q, _ = level_run(7, steps=400)
    y_p = np.array(y_p, dtype=float)
    y_p[200] += 7 * LEVEL_NOISE
    data = level_csv(tmp_path / "run.csv", times, modes, y_p, y_q, with_mode=False)
    d = bgc.diagnose(ROOT / "docs" / "examples" / "level.yaml", data, backend=FAST).diagnosis  # (conftest.FAST)
    assert (d.verdict, d.candidates, d.detection) == ("no fault", (), None)
    (glitch,) = [e for e in d.events if isinstance(e, ev.Glitch)]
    assert d.time_of(glitch.step) == pytest.approx(10.05) and glitch.sensor == "p"


@pytest.mark.slow
@pytest.mark.long
def test_a_reading_off_then_a_pump_turned_on_by_itself_on_a_plant_whose_mode_the_data_do_not_give(tmp_path):
    # docs/examples/level.yaml's tank with its pump's contactor declared to stick ON or turn ON without a
    # command, no mode column: a run by solve_ivp on its hand-derived equations (tests/hybrid_reference.py),
    # one reading of p seven noise stds high at t = 3.6 while the tank drains, and the pump turned on by
    # itself at t = 4.9, 26 samples later, never released (the tank then stays over the level that would
    # ask for the pump). The alarm on the reading is a false one (one reading, the residuals quiet after it
    # until the fault's alarm, more than the detector's middle window), and the fault is dated from its own
    # onset, where the two kinds are the same plant until a mode asks for the pump: ambiguous (so on seeds
    # 4 to 6 as well, measured). Was "unexplained: p_offset_bias" from t = 3.55: with the mode from the
    # data's readings, an alarm was not taken for a false one unless it was a glitch to the data's end, and
    # the quiet stretch had to be the detector's longest window (32 samples); every fault model was fitted
    # from the reading, where the pump still ran as the modes said.
    from hybrid_reference import LEVEL_NOISE, level_csv, level_run

    text = (ROOT / "docs" / "examples" / "level.yaml").read_text(encoding="utf-8")
    model = tmp_path / "level.yaml"
    model.write_text(text.replace("  p: [bias]\n", "  p: [bias]\n  P: {kinds: [stuck_on, uncommanded_on], prior: 0.02}\n"),
                     encoding="utf-8")
    times, modes, y_p, y_q, switches = level_run(3, fault=(4.9, "P", 1.0), steps=200)
    assert modes[times >= 4.9].tolist() == [2] * int(np.sum(times >= 4.9))  # never released: draining on
    y_p = np.array(y_p, dtype=float)
    glitch = int(np.flatnonzero(np.isclose(times, 3.6))[0])
    assert modes[glitch] == 2 and times[glitch] > max(s for s in switches if s < 3.6)  # in the draining stretch
    y_p[glitch] += 7 * LEVEL_NOISE
    data = level_csv(tmp_path / "run.csv", times, modes, y_p, y_q, with_mode=False)
    d = bgc.diagnose(model, data, backend="numpy").diagnosis
    (false,) = [e for e in d.events if isinstance(e, ev.FalseAlarm)]
    assert d.time_of(false.step) == pytest.approx(3.6)
    assert (d.verdict, set(d.candidates)) == ("ambiguous", {"P_stuck_on", "P_uncommanded_on"})
    assert abs(d.time_of(d.onset_step) - 4.9) <= 2 * 0.05


def test_the_quiet_stretch_that_makes_an_alarm_false_is_the_next_window_only_between_a_reading_and_an_alarm():
    # Diagnoser._false_alarm's rule: the detector's longest window of quiet residuals, but between an alarm on
    # one reading (the mean test's one-sample window) and the detector's next alarm its next window; windows
    # read as a set (a window given twice is one window)
    from types import SimpleNamespace

    from bgc.diagnosis.diagnoser import quiet_enough

    one, wide = SimpleNamespace(test="mean", window=1), SimpleNamespace(test="mean", window=8)
    assert quiet_enough(one, (1, 8, 32), again=True) == 8
    assert quiet_enough(one, (32, 1, 8), again=True) == 8  # in any order
    assert quiet_enough(one, (1, 8, 32), again=False) == 32  # quiet to the data's end: a glitch's stretch
    assert quiet_enough(wide, (1, 8, 32), again=True) == 32  # an alarm over a window of readings
    assert quiet_enough(SimpleNamespace(test="drift", window=1), (1, 8, 32), again=True) == 32
    assert quiet_enough(one, (1, 1, 32), again=True) == 32  # (1, 1, 32): the next window is 32
    assert quiet_enough(one, (1,), again=True) == 1  # one window: it is also the longest
    assert quiet_enough(wide, (8, 16), again=True) == 16  # no one-sample window
