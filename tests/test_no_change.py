"""An unexplained alarm that saw no change is a model that does not fit
(issue 48: a plant off its model is "mismatch" or "no fault", never a fault
and never "unexplained" for its own misfit). A fault is a change: when the
whole record fails the test of the model and no sensor's residuals differ
after the alarm's change point from before it beyond chance
(bgc.diagnosis.fit.changed), the stretch before the change point was only
too short to show the misfit (bgc.diagnosis.finish.unchanged_misfit). A
fault outside the model changes the residuals at its onset, and stays
"unexplained"."""

import math
from statistics import NormalDist

import numpy as np
import pytest

import bgc
from bgc.diagnosis.detect import TESTS
from bgc.diagnosis.fit import CHANGE_LEVEL, changed

from conftest import fast_session
from test_mismatch import plant_csv


def cut(sensors: int) -> float:
    return NormalDist().inv_cdf(1 - CHANGE_LEVEL / (2 * 2 * sensors))


def exact(n: int, mean: float, variance: float, seed: int) -> np.ndarray:
    """``n`` draws whose sample mean and variance (ddof 1) are exactly ``mean`` and ``variance``."""
    x = np.random.default_rng(seed).standard_normal(n)
    return mean + (x - x.mean()) / x.std(ddof=1) * math.sqrt(variance)


@pytest.mark.parametrize("n1,n2", [(20, 280), (60, 240)])
def test_the_change_tests_against_their_closed_forms(n1, n2):
    c = cut(2)
    se_log = math.sqrt(2 / (n1 - 1) + 2 / (n2 - 1))
    quiet = exact(n2, 0.0, 1.0, 1)
    for factor, expected in ((0.98, ()), (1.02, ("y",))):  # the variance's log ratio just within, just beyond
        before = exact(n1, 0.0, math.exp(-factor * c * se_log), 2)
        z = np.column_stack([np.concatenate([before, quiet]), np.zeros(n1 + n2)])
        z[:, 1] = exact(n1 + n2, 0.0, 1.0, 3)  # a second sensor, the same throughout
        assert changed(z, n1, ("y", "other")) == expected, factor
    for factor, expected in ((0.98, ()), (1.02, ("y",))):  # the mean, against Welch's standard error
        shift = factor * c * math.sqrt(1 / n1 + 1 / n2)
        z = np.column_stack([np.concatenate([exact(n1, shift, 1.0, 4), exact(n2, 0.0, 1.0, 5)]),
                             exact(n1 + n2, 0.0, 1.0, 6)])
        assert changed(z, n1, ("y", "other")) == expected, factor


def test_a_sensor_not_read_on_one_side_counts_as_changed_and_one_never_read_does_not():
    z = np.column_stack([exact(100, 0.0, 1.0, 7), np.r_[np.full(98, np.nan), 0.1, -0.2], np.full(100, np.nan)])
    assert changed(z, 50, ("a", "b", "c")) == ("b",)


@pytest.mark.slow
def test_a_noisier_plants_pooled_alarm_with_no_change_is_a_mismatch(tmp_path):
    """Seed 37's second recording (3 % off, noise 1.5 times the model's),
    the detector's bank: its pooled test alarmed at the 17th sample, no
    fault model explains the data, and the 16 samples before it passed the
    test of the model; the whole record fails it (variances about 2.5) and
    the residuals are the same before and after: mismatch (it was
    "unexplained: R1_incipient")."""
    plant_csv(tmp_path / "run.csv", 37, 0.03, 1.5, noise_seed=1)
    d = bgc.diagnose(fast_session("circuit"), tmp_path / "run.csv",
                     options=bgc.DiagnosisOptions(detectors=TESTS)).diagnosis
    assert d.detection is not None and d.detection.test == "pooled" and d.detection.onset_step < 20
    assert (d.verdict, d.candidates) == ("mismatch", ()), (d.verdict, d.candidates)
    assert d.fit.end == len(d.time) and d.fit.findings[-1].startswith("no sensor's residuals changed")
    assert any("variance" in f for f in d.fit.findings)


@pytest.mark.slow
def test_a_fault_outside_the_model_changes_the_residuals_and_stays_unexplained(tmp_path):
    """The circuit with the model's own numbers, f6's noise five times
    larger from t = 7.5 (the circuit declares no noise fault): the whole
    record fails the test of the model, but f6's residuals changed at the
    change point, so the verdict stays "unexplained", never mismatch."""
    path = tmp_path / "run.csv"
    plant_csv(path, 2, 0.0, 1.0)
    lines = path.read_text(encoding="utf-8").splitlines()
    head, rows = lines[0].split(","), [line.split(",") for line in lines[1:]]
    j = head.index("y:f6")
    nominal = fast_session("circuit").package.MODELS["nominal"]
    sigma = float(nominal.MEASUREMENT_STD[list(nominal.OUTPUTS).index("f6")])
    rng = np.random.default_rng(8)
    for row in rows:
        if float(row[0]) >= 7.5 - 1e-9:
            row[j] = f"{float(row[j]) + math.sqrt(24) * sigma * rng.standard_normal():.6g}"
    path.write_text("\n".join([lines[0]] + [",".join(r) for r in rows]) + "\n", encoding="utf-8")
    d = bgc.diagnose(fast_session("circuit"), path, options=bgc.DiagnosisOptions(detectors=TESTS)).diagnosis
    assert d.detection is not None and d.detection.sensor == "f6" and d.detection.onset_step >= 140
    assert d.verdict == "unexplained", (d.verdict, d.candidates, d.fit.findings)
