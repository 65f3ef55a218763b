"""The detector's bank of tests (issue 48, point 2; bgc.diagnosis.detect,
"A bank of tests"): a drift test, a variance test and a frozen-sensor test
beside the windowed mean test, sharing one false-alarm budget.

The statistics and thresholds are derived here from their closed forms
(ramp-weighted sums computed by convolution, the normal quantile of the
union bound, the chi-square law of even degrees of freedom in closed form,
the repeat bound q / (sqrt(2 pi) r)) and compared with what the detector
computes step by step; the slow tests feed it a plant simulated by another
simulator (tests/test_mismatch.py's exact solution of the circuit) with a
sensor that freezes, one whose noise grows five times, and a healthy run.
"""

import math
import pickle

import numpy as np
import pytest
from scipy.stats import norm

import bgc
from bgc.diagnosis import state as states
from bgc.diagnosis.detect import (DRIFT_MEANS, DRIFT_RAMPS, TESTS, VARIANCE_WINDOWS, Detector,
                                  DetectorOptions)

from conftest import bgc_cli

ALL = TESTS


def _ramp_stats(z: np.ndarray, k: int) -> dict:
    """Every drift statistic at step k of one sensor's residuals ``z``, computed directly."""
    out = {}
    for w in DRIFT_RAMPS:
        if w <= k + 1:  # a window is tested from the step it fits in
            weights = np.arange(1, w + 1)
            out[("ramp", w)] = abs(weights @ z[k - w + 1:k + 1]) / math.sqrt(weights @ weights)
    for w in DRIFT_MEANS:
        if w <= k + 1:
            out[("mean", w)] = abs(z[k - w + 1:k + 1].sum()) / math.sqrt(w)
    return out


def _mean_stats(z: np.ndarray, k: int, windows=(1, 8, 32)) -> dict:
    return {w: abs(z[k - w + 1:k + 1].sum()) / math.sqrt(w) for w in windows if w <= k + 1}


def test_a_ramp_is_found_by_the_drift_test_at_its_closed_form_and_dated_at_its_start():
    steps, start, slope = 300, 40, 0.006
    z = np.where(np.arange(steps) >= start, slope * (np.arange(steps) - start + 1), 0.0)
    options = DetectorOptions(0.01, (1, 8, 32), steps, ("mean", "drift"))
    # each family holds half the budget by the union bound over its own tests
    c_mean = norm.isf(0.005 / (2 * steps * 1 * 3))
    c_drift = norm.isf(0.005 / (2 * steps * 1 * (len(DRIFT_RAMPS) + len(DRIFT_MEANS))))
    assert options.threshold(1) == pytest.approx(c_mean, rel=1e-9)
    assert options.drift_threshold(1) == pytest.approx(c_drift, rel=1e-9)
    expected = None
    for k in range(steps):
        mean = max(_mean_stats(z, k).values())
        drift = _ramp_stats(z, k)
        if mean > c_mean or (drift and max(drift.values()) > c_drift):
            expected = (k, mean, drift)
            break
    assert expected is not None
    k, mean, drift = expected
    assert mean <= c_mean  # the ramp is slow enough that the drift test sees it first
    detector = Detector(("y",), options)
    alarm = None
    for i in range(steps):
        alarm = detector.update([z[i]])
        if alarm is not None:
            break
    shape, window = max(drift, key=drift.get)
    assert (alarm.step, alarm.test, alarm.window) == (k, "drift", window)
    assert alarm.statistic == pytest.approx(drift[(shape, window)], rel=1e-9)
    if shape == "ramp":
        # the template of the ramp from its first step fits it exactly: by Cauchy-Schwarz no other start scores as much
        assert alarm.onset_step == start


def test_the_mean_test_alone_is_unchanged_and_the_bank_shares_its_budget():
    steps, sensors = 400, 3
    alone = DetectorOptions(0.01, (1, 8, 32), steps)
    assert alone.threshold(sensors) == pytest.approx(norm.isf(0.01 / (2 * steps * sensors * 3)), rel=1e-9)
    bank = DetectorOptions(0.01, (1, 8, 32), steps, ALL)
    assert bank.threshold(sensors) == pytest.approx(norm.isf(0.0025 / (2 * steps * sensors * 3)), rel=1e-9)
    assert bank.variance_level(sensors) == pytest.approx(0.0025 / (2 * steps * sensors * len(VARIANCE_WINDOWS)))
    assert bank.frozen_level(sensors) == pytest.approx(0.0025 / (steps * sensors))


def _chi2_even_sf(x: float, df: int) -> float:
    """P(chi2_df > x) for even df: exp(-x/2) sum_{i < df/2} (x/2)^i / i!."""
    half = x / 2.0
    return math.exp(-half) * sum(half ** i / math.factorial(i) for i in range(df // 2))


def test_the_variance_bounds_are_the_chi_square_quantiles_at_the_level():
    options = DetectorOptions(0.01, (1, 8, 32), 300, ALL)
    detector = Detector(("a", "b"), options, noise=[0.1, 0.1])
    level = options.variance_level(2)
    for df in (2, 4, 6, 16, 30):
        low, high = detector.more.bounds(df)
        assert _chi2_even_sf(high, df) == pytest.approx(level, rel=1e-6)
        assert 1.0 - _chi2_even_sf(low, df) == pytest.approx(level, rel=1e-6)


def test_a_swinging_and_a_flat_residual_alarm_the_variance_test_with_its_ratio():
    rng = np.random.default_rng(3)
    steps = 300
    for way in ("rose", "fell"):
        z = rng.standard_normal(steps)
        if way == "rose":  # swings of 2.5 either way: no window's mean reaches the mean test's threshold
            z[150:] = 2.5 * (-1.0) ** np.arange(steps - 150)
        else:  # a residual that no longer moves: off by a constant, its variance nothing
            z[150:] = 0.4
        options = DetectorOptions(0.01, (1, 8, 32), steps, ("mean", "variance"))
        detector = Detector(("y",), options)
        alarm = next(a for a in (detector.update([v]) for v in z) if a is not None)
        assert alarm.step >= 150 and alarm.test == "variance"
        w = alarm.window
        window = z[alarm.step - w + 1:alarm.step + 1]
        q = float(((window - window.mean()) ** 2).sum())
        assert alarm.statistic == pytest.approx(q / (w - 1), rel=1e-6, abs=1e-12)
        low, high = detector.more.bounds(w - 1)
        assert (q > high) if way == "rose" else (q < low)
        assert abs(alarm.onset_step - 150) <= 3


def _quantised(rng, n: int, step: float, r: float) -> list[float]:
    """Readings around 2 (one decimal exponent: one resolution), noise r, written to ``step``."""
    values = np.round((2.0 + r * rng.standard_normal(n)) / step) * step
    values[1] = values[0] + step  # one change of exactly the resolution
    return values.tolist()


def _longest_run(values: list[float]) -> int:
    """The longest run of readings equal to the one before."""
    longest = run = 0
    for a, b in zip(values, values[1:]):
        run = run + 1 if a == b else 0
        longest = max(longest, run)
    return longest


@pytest.mark.parametrize("resolution", [1e-3, 1e-6])
def test_a_frozen_reading_alarms_after_the_repeats_its_resolution_allows(resolution):
    rng = np.random.default_rng(5)
    r, steps = 0.02, 300
    readings = _quantised(rng, 100, resolution, r)
    assert len(set(readings[-5:])) == 5  # the plant's readings move
    frozen = readings + [readings[-1]] * 50
    options = DetectorOptions(0.01, (1, 8, 32), steps, ("mean", "frozen"))
    detector = Detector(("y",), options, noise=[r])
    smallest = min(abs(a - b) for a, b in zip(readings, readings[1:]) if a != b)
    assert smallest == pytest.approx(resolution, rel=1e-6)
    chance = smallest / (math.sqrt(2 * math.pi) * r)
    # beyond chance, and longer than twice the longest run of repeats before (a logger's habit)
    needed = max(math.ceil(math.log(options.frozen_level(1)) / math.log(chance)), 2 * _longest_run(readings) + 1)
    alarm = None
    for i, v in enumerate(frozen):
        alarm = detector.update([0.0], None, [v])
        if alarm is not None:
            break
    assert (alarm.step, alarm.test, alarm.onset_step) == (99 + needed, "frozen", 100)
    assert (alarm.statistic, alarm.threshold) == (needed, needed)


def test_readings_coarser_than_their_noise_never_alarm_the_frozen_or_the_variance_test():
    """Most readings repeat when the resolution is 5 times the noise: a
    repeat says nothing, and a residual that moves in steps of 0.1 has no
    variance to speak of in units of a noise of 0.02 (the lower tail is
    left to readings at most a quarter of their noise apart)."""
    rng = np.random.default_rng(6)
    readings = _quantised(rng, 300, 0.1, 0.02)
    detector = Detector(("y",), DetectorOptions(0.01, (1, 8, 32), 300, ("mean", "variance", "frozen")),
                        noise=[0.02])
    assert all(detector.update([0.0], None, [v]) is None for v in readings)


def test_readings_that_a_logger_writes_twice_need_a_longer_run_to_be_frozen():
    """A logger that writes each reading twice (a multi-rate export) repeats
    by habit: a run alarms once it is longer than twice the longest before."""
    rng = np.random.default_rng(11)
    once = _quantised(rng, 100, 1e-6, 0.02)
    twice = [v for v in once for _ in (0, 1)] + [once[-1]] * 10
    detector = Detector(("y",), DetectorOptions(0.01, (1, 8, 32), 300, ("mean", "frozen")), noise=[0.02])
    alarm = next(a for a in (detector.update([0.0], None, [v]) for v in twice) if a is not None)
    assert (alarm.test, alarm.statistic, alarm.onset_step) == ("frozen", 3.0, 199)  # runs of 1 before: 3 repeats


def test_white_residuals_alarm_each_family_at_most_at_its_share():
    """300-step runs (every window of every family tested) of white
    residuals, readings written to 5 decimals (a repeat now and then):
    each family alarms at most at its share of the budget, alpha / 4, by
    the union bound (3 standard errors of slack over 200 runs)."""
    rng = np.random.default_rng(7)
    runs, steps, alpha = 200, 300, 0.4
    options = DetectorOptions(alpha, (1, 8, 32), steps, ALL)
    first = dict.fromkeys(ALL, 0)  # runs in which each family alarmed first
    for _ in range(runs):
        detector = Detector(("a", "b"), options, noise=[0.05, 0.05])
        z = rng.standard_normal((steps, 2))
        y = np.round(1.0 + 0.05 * z, 5)
        for k in range(steps):
            alarm = detector.update(z[k], None, y[k])
            if alarm is not None:
                first[alarm.test] += 1
                break
    share = alpha / len(ALL)
    for test, count in first.items():
        assert count <= share * runs + 3 * math.sqrt(runs * share * (1 - share)), first


def test_the_banks_state_round_trips_and_the_run_goes_on_as_if_never_stopped():
    rng = np.random.default_rng(8)
    steps = 400
    z = rng.standard_normal((steps, 2))
    z[300:, 0] += 0.01 * np.arange(100)  # a drift late in the run
    y = np.round(1.0 + 0.05 * z, 4)
    spread = 1.0 + 0.5 * rng.random((steps, 2))
    options = DetectorOptions(0.01, (1, 8, 32), steps, ALL)

    def run(detector, rows):
        for k in rows:
            alarm = detector.update(z[k], None, y[k], spread[k])
            if alarm is not None:
                return alarm
        return None

    whole = Detector(("a", "b"), options, noise=[0.05, 0.05])
    expected = run(whole, range(steps))
    half = Detector(("a", "b"), options, noise=[0.05, 0.05])
    assert run(half, range(290)) is None  # past the longest ring (258 rows)
    saved = pickle.loads(pickle.dumps(states.detector_state(half)))
    again = Detector(("a", "b"), options, noise=[0.05, 0.05])
    states.restore_detector(again, saved)
    assert run(again, range(290, steps)) == expected
    assert expected is not None and expected.step >= 300


def test_the_options_refuse_a_bank_without_the_mean_test_or_an_unknown_family():
    with pytest.raises(bgc.ArgumentValueError, match="mean"):
        bgc.diagnose("models/circuit.yaml", scenario="none", steps=20,
                     options=bgc.DiagnosisOptions(detectors=("drift",)))
    out = bgc_cli("diagnose", "models/circuit.yaml", "--scenario", "none", "--detect", "slope")
    assert out.returncode == 2 and "'slope': give some of mean, drift, variance, frozen" in out.stderr
    assert "Traceback" not in out.stderr


def _circuit_with(path, seed: int, change: str) -> float:
    """A healthy run of the circuit by another simulator (tests/test_mismatch.py's
    exact solution, the model's own numbers), its sensor f6 changed from
    step 150 on: ``frozen`` (the logger repeats its reading of step 149),
    ``burst`` (its noise five times the model's), or ``none``; returns f6's
    noise std."""
    from test_mismatch import circuit, plant_csv

    p = plant_csv(path, seed, 0.0, 1.0)
    _, _, r = circuit(p, 1.0)
    lines = path.read_text(encoding="utf-8").splitlines()
    column = lines[0].split(",").index("y:f6")
    rows = [line.split(",") for line in lines[1:]]
    rng = np.random.default_rng(seed + 100)
    for row in rows[150:]:
        if change == "frozen":
            row[column] = rows[149][column]
        elif change == "burst":  # the reading's noise r becomes 5 r: add sqrt(24) r more
            row[column] = f"{float(row[column]) + math.sqrt(24.0) * r * rng.standard_normal():.6g}"
    path.write_text("\n".join([lines[0]] + [",".join(row) for row in rows]) + "\n", encoding="utf-8")
    return r


@pytest.mark.slow
@pytest.mark.parametrize("change", ["frozen", "burst"])
def test_a_frozen_sensor_and_a_burst_of_noise_are_alarmed_within_ten_samples(tmp_path, change):
    from conftest import fast_session

    for seed in (0, 1):
        _circuit_with(tmp_path / "run.csv", seed, change)
        d = bgc.diagnose(fast_session("circuit"), tmp_path / "run.csv",
                         options=bgc.DiagnosisOptions(detectors=ALL)).diagnosis
        alarm = d.detection
        assert alarm is not None and 150 <= alarm.step <= 159, (seed, alarm)
        if change == "frozen":  # at 6 significant digits two repeats are already beyond chance
            assert (alarm.sensor, alarm.test, alarm.onset_step) == ("f6", "frozen", 150)
            # no fault of the plant holds a reading still, and the circuit declares no stuck sensor
            said = [e for e in d.events if type(e).__name__ == "ReadingFrozen"]
            assert d.verdict == "unexplained" and not d.hypotheses and len(said) == 1 and said[0].kept == ()


@pytest.mark.slow
def test_a_frozen_sensor_the_model_declares_stuck_is_isolated_and_sized(tmp_path):
    from conftest import ROOT, session

    _circuit_with(tmp_path / "run.csv", 0, "frozen")
    held = float((tmp_path / "run.csv").read_text(encoding="utf-8").splitlines()[150].split(",")[3])
    d = bgc.diagnose(session(ROOT / "experiments" / "models" / "circuit_all_kinds.yaml"), tmp_path / "run.csv",
                     options=bgc.DiagnosisOptions(detectors=ALL)).diagnosis
    assert d.verdict == "isolated" and d.candidates == ("f6_stuck_stuck",)
    assert d.best.estimate.low <= held <= d.best.estimate.high
    assert d.onset_step == 150  # the first reading that repeats: the stuck fault is tried from there


def test_the_example_file_is_the_frozen_run_of_the_circuit(tmp_path):
    from conftest import ROOT

    _circuit_with(tmp_path / "run.csv", 0, "frozen")
    shipped = (ROOT / "docs" / "examples" / "circuit_frozen.csv").read_text(encoding="utf-8").splitlines()
    assert [line for line in shipped if not line.startswith("#")] == \
        (tmp_path / "run.csv").read_text(encoding="utf-8").splitlines()


@pytest.mark.slow
def test_the_bank_raises_no_alarm_on_another_simulators_healthy_runs(tmp_path):
    from conftest import fast_session

    for seed in range(3):
        _circuit_with(tmp_path / "run.csv", seed, "none")
        d = bgc.diagnose(fast_session("circuit"), tmp_path / "run.csv",
                         options=bgc.DiagnosisOptions(detectors=ALL)).diagnosis
        assert d.verdict == "no fault" and d.detection is None, (seed, d.verdict, d.detection)


@pytest.mark.slow
def test_the_report_says_which_test_fired(tmp_path):
    from conftest import fast_backend

    _circuit_with(tmp_path / "run.csv", 0, "frozen")
    out = bgc_cli("diagnose", "models/circuit.yaml", "--data", tmp_path / "run.csv", "--detect", "frozen,variance",
                  "--output", tmp_path / "out", *fast_backend("circuit"))
    assert out.returncode == 0, out.stderr
    report = (tmp_path / "out" / "report.md").read_text(encoding="utf-8")
    assert "alarm on f6: its reading repeated" in report and "a frozen sensor" in report


@pytest.mark.slow
@pytest.mark.parametrize("how", ["--episodes", "--exclude-faulty-sensor"])
def test_the_monitor_takes_a_frozen_sensor_out_and_watches_on(tmp_path, how):
    """A frozen reading the model cannot size (no stuck fault of f6 in the
    circuit) is off all the same: the monitor takes the sensor out at the
    checkpoint that says so and watches the rest of the stream with the
    other two, which raise no alarm (the plant is healthy)."""
    import json

    from conftest import fast_backend

    _circuit_with(tmp_path / "run.csv", 0, "frozen")
    out = bgc_cli("monitor", "models/circuit.yaml", "--data", tmp_path / "run.csv", "--detect", "all", how,
                  "--checkpoint", "1", "-o", tmp_path / "out", *fast_backend("circuit"))
    assert out.returncode == 0, out.stderr
    events = json.loads((tmp_path / "out" / "report.json").read_text(encoding="utf-8"))["events"]
    if how == "--episodes":
        closed = [e for e in events if e["event"] == "EpisodeClosed"]
        assert [(e["verdict"], e["action"], e["parameter"]) for e in closed] == [("unexplained", "sensor out", "f6")]
    else:
        assert [e["sensor"] for e in events if e["event"] == "SensorExcluded"] == ["f6"]
    assert "circuit: no fault" in out.stdout


def test_a_forgotten_record_shifts_the_alarm_and_its_onset_by_the_steps_forgotten():
    """The diagnoser forgets the first steps of a long record while watching
    (Loop.forget trims the detector's statistics); the tests' own sums run
    on, and their alarm is dated in the steps kept."""
    rng = np.random.default_rng(9)
    steps = 500
    z = rng.standard_normal((steps, 1))
    z[400:, 0] = 0.3  # a residual that stops moving: the variance test's lower tail
    options = DetectorOptions(0.01, (1, 8, 32), steps, ("mean", "variance"))
    whole, cut = Detector(("y",), options), Detector(("y",), options)
    expected = next(a for a in (whole.update(z[k]) for k in range(steps)) if a is not None)
    alarm = None
    for k in range(steps):
        if k == 300:
            cut.statistics = cut.statistics[120:]  # 120 steps forgotten
        alarm = cut.update(z[k])
        if alarm is not None:
            break
    assert expected.test == "variance" and expected.step >= 400
    assert (alarm.step, alarm.onset_step) == (expected.step - 120, expected.onset_step - 120)


def test_a_prediction_unsure_of_itself_does_not_pass_for_a_frozen_sensor():
    """The lower tail takes the residual in units of the sensor's own noise:
    residuals whose predicted std is 20 times the noise (a filter's wide
    first steps) have a tiny variance in those units of their std, and none
    below the noise's in units of the noise; the same sensor frozen (its
    residual no longer carrying the noise) alarms."""
    rng = np.random.default_rng(10)
    steps, ratio = 300, 20.0
    noise = rng.standard_normal(steps)  # the innovations: the sensor's noise, of std r
    options = DetectorOptions(0.01, (1, 8, 32), steps, ("mean", "variance"))
    unsure = Detector(("y",), options)
    assert all(unsure.update([v / ratio], None, None, [ratio]) is None for v in noise)
    frozen = Detector(("y",), options)
    residual = np.where(np.arange(steps) < 150, noise, 0.05 * rng.standard_normal(steps))
    alarm = next(a for a in (frozen.update([v / ratio], None, None, [ratio]) for v in residual) if a is not None)
    assert alarm.test == "variance" and alarm.statistic < alarm.threshold and 150 <= alarm.step < 160


def test_only_a_reading_repeated_beyond_chance_rules_out_the_plant():
    from bgc.diagnosis.loop import frozen_sensor
    from bgc.diagnosis.values import Detection

    assert frozen_sensor(Detection(160, "f6", 3, 2.0, 2.0, 158, "frozen")) == "f6"
    # a variance fallen below the noise's: a coarse logger or a quieter sensor do that too
    assert frozen_sensor(Detection(160, "f6", 32, 0.01, 0.2, 150, "variance")) is None
    assert frozen_sensor(Detection(160, "f6", 1, 9.0, 4.6, 160)) is None


@pytest.mark.slow
def test_readings_rounded_coarser_than_their_noise_raise_no_alarm(tmp_path):
    """The healthy circuit by another simulator, its readings written to 0.1
    (twice the sensors' noise and more): no alarm with the whole bank."""
    from conftest import fast_session

    for seed in (1, 2):
        _circuit_with(tmp_path / "run.csv", seed, "none")
        lines = (tmp_path / "run.csv").read_text(encoding="utf-8").splitlines()
        rounded = [lines[0]] + [",".join([row.split(",")[0], row.split(",")[1]]
                                         + [f"{round(float(v), 1):g}" for v in row.split(",")[2:]])
                                for row in lines[1:]]
        (tmp_path / "run.csv").write_text("\n".join(rounded) + "\n", encoding="utf-8")
        d = bgc.diagnose(fast_session("circuit"), tmp_path / "run.csv",
                         options=bgc.DiagnosisOptions(detectors=ALL)).diagnosis
        assert d.detection is None, (seed, d.detection)


def test_distinguish_measures_the_detector_with_the_tests_asked_for():
    report = bgc.distinguishability("models/circuit.yaml", "R2:abrupt:1.2@7.5", detector_runs=2, detectors=ALL)
    assert report.detector.detectors == ALL and report.detector.runs == 2
    with pytest.raises(bgc.ArgumentValueError, match="mean"):
        bgc.distinguishability("models/circuit.yaml", "R2:abrupt:1.2@7.5", detector_runs=2, detectors=("frozen",))
