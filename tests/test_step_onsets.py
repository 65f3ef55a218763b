"""A step's onsets reach the alarm (issue 48, point 4): the detector's change
point may fall a few samples before a step's true onset (the noise before it
leans the same way), and a step tried only from the change point -4 to +2
then misses its onset: the right fault model fails its fit test and the
verdict is "unexplained". The sweep (docs/results.md section 11) had two such
runs, the two tanks' R12 step at t = 78.5; the Kalman filters that weigh a
step now try every sample from the change point - 4 up to the alarm.
"""

import pytest

from bgc.diagnosis.loop import onsets_tried
from bgc.diagnosis.options import DiagnosisOptions
from bgc.diagnosis.values import Detection


def test_a_steps_kalman_onsets_run_from_the_change_point_to_the_alarm():
    o = DiagnosisOptions()
    _, near, _, onsets, kalman = onsets_tried(o, Detection(50, "y", 8, 5.0, 4.6, 40), 300)
    assert sorted(near) == list(range(36, 43))  # the particle filters': the change point -4 to +2
    assert onsets[False] == list(range(36, 43))
    assert kalman[False] == list(range(36, 51))  # the Kalman filters': up to the alarm's sample
    # an alarm at its change point: nothing more
    assert onsets_tried(o, Detection(40, "y", 1, 5.0, 4.6, 40), 300)[4][False] == list(range(36, 42))


@pytest.mark.slow
@pytest.mark.long
def test_the_sweeps_unexplained_r12_steps_are_isolated_and_sized():
    """The sweep's two runs (GPF and APF at the model's noise), replayed from
    the campaign file: isolated as R12's step, the interval holding the truth.
    (On the FAST backend, conftest.fast_backend: the campaign's model is the
    shipped two tanks, and a run's row does not depend on the backend; the
    slow tier only.)"""
    from conftest import ROOT, fast_backend

    from bgc.experiment.campaign_file import load_campaign
    from bgc.experiment.one_run import run_one

    campaign = load_campaign(ROOT / "experiments" / "sweep.yaml")
    specs = [s for s in campaign.specs if s.group == "two_tank" and s.noise == "model"
             and s.scenario.startswith("R12:abrupt:0.821637@78.5")]
    assert [s.filter for s in specs] == ["gpf", "apf"]
    assert {s.model_text for s in specs} == {(ROOT / "models" / "two_tank.yaml").read_text(encoding="utf-8")}
    _, backend = fast_backend("two_tank")
    for spec in specs:
        r = run_one(spec, backend)
        assert (r["verdict"], r["candidates"]) == ("isolated", "R12_abrupt"), r
        assert r["low"] <= 0.821637 <= r["high"]
