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
from bgc.diagnosis.diagnoser import Diagnoser
from bgc.filters.cubature import CubatureKalmanFilter
from bgc.diagnosis.detect import (DRIFT_MEANS, DRIFT_RAMPS, POOLED_WINDOWS, TESTS, VARIANCE_WINDOWS, Detector,
                                  DetectorOptions, Families)

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


def test_the_drift_family_tests_an_exact_observers_residuals_with_no_allowance():
    """Given ``exact`` (a Kalman observer's residuals beside a particle
    one), the drift family's statistics are those of ``exact`` with no Monte
    Carlo allowance however large the particle filter's shares, and the
    other families still take ``z`` and its shares: the same ramp fed as
    ``z`` with shares of 0.3 alarms later than the ramp fed as ``exact``, or not at all."""
    steps, start, slope = 300, 40, 0.006
    ramp = np.where(np.arange(steps) >= start, slope * (np.arange(steps) - start + 1), 0.0)
    noise = np.random.default_rng(5).standard_normal(steps) * 0.1
    options = DetectorOptions(0.01, (1, 8, 32), steps, ("mean", "drift"))
    c_drift = options.drift_threshold(1)
    expected = next(k for k in range(steps) if max(_ramp_stats(ramp, k).values(), default=0.0) > c_drift)
    given, shared = Detector(("y",), options), Detector(("y",), options)
    alarms = {}
    for i in range(steps):
        for name, d, z, exact in (("given", given, noise[i], ramp[i]), ("shared", shared, ramp[i], None)):
            if name not in alarms:
                alarm = d.update([z], [0.3], exact=None if exact is None else [exact])
                if alarm is not None:
                    alarms[name] = alarm
    alarm = alarms["given"]
    stats = _ramp_stats(ramp, expected)
    assert (alarm.step, alarm.test) == (expected, "drift")
    assert alarm.statistic == pytest.approx(max(stats.values()), rel=1e-9)
    assert alarm.onset_step == start
    # with the shares' allowance, fully correlated over the window, the same ramp alarms later or not at all
    assert "shared" not in alarms or alarms["shared"].step > expected


def _rows(session, scenario: str) -> list:
    """The (time, inputs, measurements) rows of ``scenario`` simulated on ``session`` (seed 3), as
    :meth:`Diagnoser.step` takes them."""
    sim = bgc.simulate(session, scenario, seed=3)
    return [(float(t), {n: v[k] for n, v in sim.inputs.items()}, {n: v[k] for n, v in sim.measurements.items()})
            for k, t in enumerate(sim.time)]


def _spy_on_exact(monkeypatch) -> list:
    """The residuals every detector is given as ``exact`` from now on (a list filled as they come)."""
    given = []
    original = Detector.update

    def spy(self, z, mc=None, y=None, spread=None, corr=None, exact=None, whitened=None):
        given.append(np.array(exact, dtype=float))
        return original(self, z, mc, y, spread, corr, exact, whitened)

    monkeypatch.setattr(Detector, "update", spy)
    return given


def test_a_particle_observer_runs_the_drift_familys_kalman_observer_beside_it(monkeypatch):
    """Beside a particle observer (and only with the drift family), the loop
    runs the nominal model's cubature Kalman filter, whose residuals the
    drift family takes; its state goes with the diagnoser's (the round trip
    of tests/test_state.py) and a state without it is refused."""
    from conftest import fast_session

    session = fast_session("two_tank")
    rows = _rows(session, "R12:abrupt:0.8@60")
    options = bgc.DiagnosisOptions(workers=1, particles=100, seed=4, detectors=("mean", "drift"))
    original = Detector.update
    given = _spy_on_exact(monkeypatch)
    whole = session.diagnoser(options)
    assert whole.loop.companion is not None
    assert session.diagnoser(bgc.DiagnosisOptions(workers=1, particles=100)).loop.companion is None
    assert session.diagnoser(bgc.DiagnosisOptions(workers=1, filter="ckf", detectors=("mean", "drift"))
                             ).loop.companion is None  # the observer is a Kalman filter already
    cut = 50
    for row in rows[:cut]:
        whole.step(*row)
    kf = CubatureKalmanFilter(session.package.MODELS["nominal"])
    expected = []
    for t, u, y in rows[:cut]:  # the companion is the nominal Kalman filter from the model's prior
        y = np.array([y[n] for n in whole.nominal.OUTPUTS])
        r = kf.step(y, np.array([u[n] for n in whole.nominal.INPUTS]))
        expected.append((y - r.y_mean) / r.y_std)
    np.testing.assert_allclose(whole.loop.companion.mean, kf.mean, rtol=1e-12, atol=1e-12)
    # and the detector took its residuals as the drift family's, a detector told they are exact
    np.testing.assert_allclose(np.array(given), np.array(expected), rtol=1e-9, atol=1e-12)
    assert whole.loop.detector.exact and whole.loop.detector.more.exact
    state = states.DiagnoserState.from_bytes(whole.to_state().to_bytes())
    resumed = Diagnoser.from_state(whole.config, state)
    np.testing.assert_array_equal(resumed.loop.companion.cov, whole.loop.companion.cov)
    monkeypatch.setattr(Detector, "update", original)
    later = [(whole.step(*row).alarm, resumed.step(*row).alarm) for row in rows[cut:]]
    assert all(a == b for a, b in later) and any(a is not None for a, _ in later)
    import dataclasses

    loop = dataclasses.replace(state.loop, companion=None)
    with pytest.raises(bgc.Error, match="drift family's Kalman observer missing"):
        Diagnoser.from_state(whole.config, dataclasses.replace(state, loop=loop))


def test_a_kalman_observer_that_loses_its_estimate_starts_again_from_the_particle_cloud_and_says_so(monkeypatch):
    """The drift family's Kalman observer whose estimate is no longer finite
    (forced here at one step) starts again from the particle observer's
    cloud after that step (its weighted mean and covariance), the step's residuals go
    to the drift test as not read, an event says so, and the drift test goes
    on with the restarted observer's residuals."""
    from conftest import fast_session

    session = fast_session("two_tank")
    rows = _rows(session, "none")
    # the optimal-proposal filter resamples only when its weights grow uneven: the cloud's moments are weighted
    d = session.diagnoser(bgc.DiagnosisOptions(workers=1, particles=100, seed=4, detectors=("mean", "drift"),
                                               filter="opf"))
    given = _spy_on_exact(monkeypatch)
    broken, at = [], 30
    for k, row in enumerate(rows[:60]):
        if k == at:  # the observer loses its estimate on this step
            companion = d.loop.companion
            step = companion.step

            def lost(y, u, dt=None, step=step, companion=companion):
                r = step(y, u, dt)
                companion.mean = companion.mean * np.nan
                return r

            companion.step = lost
            broken.append(companion)
        d.step(*row)
        if k == at:
            x, w = d.loop.pf.x[d.loop.companion.kf.physical], np.exp(d.loop.pf.logw - d.loop.pf.logw.max())
            w /= w.sum()
            assert w.max() > 3 * w.min()  # uneven: the plain mean and covariance would not do
            mean = x @ w
            cov = sum(wi * np.outer(xi - mean, xi - mean) for wi, xi in zip(w, x.T)) / (1 - w @ w)
            np.testing.assert_allclose(d.loop.companion.mean, mean, rtol=1e-10)
            np.testing.assert_allclose(d.loop.companion.cov, cov, rtol=1e-10)
    assert d.loop.companion is not broken[0]
    said = [e for e in d.loop.events if isinstance(e, bgc.events.ObserverRestarted)]
    assert said == [bgc.events.ObserverRestarted(at, 1)]
    assert np.isnan(given[at]).all()
    assert np.isfinite(given[at - 1]).all() and np.isfinite(given[at + 1:]).all()
    from bgc.output.events import sentence

    assert "starts again there from the particle observer's cloud" in sentence(said[0], lambda k: k * 0.5)
    from bgc.output.events import notes

    again = [said[0], bgc.events.ObserverRestarted(40, 2), bgc.events.ObserverRestarted(41, 3)]
    lines = [line for line in notes(again, lambda k: k * 0.5) if "Kalman observer" in line]
    assert lines == ["the Kalman observer whose residuals the drift test reads lost its estimate 3 times, from "
                     "t = 15 to t = 20.5, and started again each time from the particle observer's cloud (the "
                     "report lists each)"]


def test_the_mean_test_alone_is_unchanged_and_the_bank_shares_its_budget():
    steps, sensors = 400, 3
    alone = DetectorOptions(0.01, (1, 8, 32), steps)
    assert alone.threshold(sensors) == pytest.approx(norm.isf(0.01 / (2 * steps * sensors * 3)), rel=1e-9)
    bank = DetectorOptions(0.01, (1, 8, 32), steps, ALL)
    assert len(ALL) == 6  # the mean test and five families: a sixth of 1 % each
    share = 0.01 / 6
    assert bank.threshold(sensors) == pytest.approx(norm.isf(share / (2 * steps * sensors * 3)), rel=1e-9)
    assert bank.variance_level(sensors) == pytest.approx(share / (2 * steps * sensors * len(VARIANCE_WINDOWS)))
    assert bank.frozen_level(sensors) == pytest.approx(share / (steps * sensors))
    assert bank.pooled_level() == pytest.approx(share / (steps * len(POOLED_WINDOWS)))


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


def _change_point(z: np.ndarray, longest: int, mean_term: bool = True) -> int:
    """The GLR change point of a residual's mean and variance by brute force:
    the start of the span of ``m`` last samples (2 <= m <= ``longest``) that
    maximises S2 - m - m log v (``v`` the span's mean square about its mean,
    ``S2`` its sum of squares); without ``mean_term``, m (v' - 1 - log v')
    with ``v'`` the centred variance (the form that ignores the mean)."""
    best, at = -np.inf, None
    for m in range(2, longest + 1):
        span = z[-m:]
        if mean_term:
            v = float(np.mean((span - span.mean()) ** 2))
            score = float(span @ span) - m - m * np.log(v)
        else:
            v = float(np.sum((span - span.mean()) ** 2)) / (m - 1)
            score = m * (v - 1.0 - np.log(v))
        if score > best:
            best, at = score, len(z) - m
    return at


def test_the_variance_tests_onset_is_where_the_mean_or_the_variance_changed():
    # a bias or a stuck sensor can reach the variance test first (a step raises the variance of the windows that
    # straddle it); its onset is then where the mean stepped, not the start of the longest straddling window
    steps, at, longest = 160, 150, max(VARIANCE_WINDOWS)
    options = DetectorOptions(0.01, (1, 8, 32), 300, ("mean", "variance"))
    near, near_centred = 0, 0
    for seed in range(100):
        rng = np.random.default_rng(seed)
        z = rng.standard_normal(steps)
        z[at:] += 3.0 if seed % 2 else -3.0
        detector = Detector(("y",), options)
        for v in z:
            detector.update([v])
        more = detector.more
        onset = more._variance_onset(more._c, more._sq)
        assert onset == _change_point(z, longest)
        near += abs(onset - at) <= 2
        near_centred += abs(_change_point(z, longest, mean_term=False) - at) <= 2
    assert near >= 90
    assert near_centred <= 20  # the variance alone puts the change a window early
    # a sensor stuck at a constant: no variance after the step, and the onset is the step
    z = np.random.default_rng(7).standard_normal(steps)
    z[at:] = 1.7
    detector = Detector(("y",), options)
    for v in z:
        detector.update([v])
    assert detector.more._variance_onset(detector.more._c, detector.more._sq) == at


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


@pytest.mark.slow
@pytest.mark.long
def test_white_residuals_alarm_each_family_at_most_at_its_share():
    """300-step runs (every window of every family tested) of white
    residuals, readings written to 5 decimals (a repeat now and then), their
    correlation (none) given: each family alarms at most at its share of
    the budget, alpha / 5, by the union bound (3 standard errors of slack
    over 200 runs)."""
    rng = np.random.default_rng(7)
    runs, steps, alpha = 200, 300, 0.4
    options = DetectorOptions(alpha, (1, 8, 32), steps, ALL)
    first = dict.fromkeys(ALL, 0)  # runs in which each family alarmed first
    for _ in range(runs):
        detector = Detector(("a", "b"), options, noise=[0.05, 0.05])
        z = rng.standard_normal((steps, 2))
        y = np.round(1.0 + 0.05 * z, 5)
        for k in range(steps):
            alarm = detector.update(z[k], None, y[k], None, np.eye(2))
            if alarm is not None:
                first[alarm.test] += 1
                break
    share = alpha / len(ALL)
    for test, count in first.items():
        assert count <= share * runs + 3 * math.sqrt(runs * share * (1 - share)), first


def _crossing(c: float, rho: float) -> float:
    """P(X > c, X' <= c) for a standard normal pair of correlation rho, by quadrature (not Owen's T)."""
    from scipy import integrate

    s = math.sqrt(1.0 - rho * rho)
    return integrate.quad(lambda x: norm.pdf(x) * norm.cdf((c - rho * x) / s), c, c + 15.0,
                          epsabs=0.0, epsrel=1e-11, limit=200)[0]


def test_the_chain_bound_is_met_at_its_threshold_and_below_the_union_bound():
    """The drift family's threshold on an exact observer's residuals: the
    Hunter-Worsley bound summed over sensors and windows (on 0.9 of the
    share; the windows with a gap hold 0.1 by the union bound), each window's
    lag-one correlation from its weights (the dot product of the weights
    and themselves shifted by one step), the crossing probability by
    quadrature, equals the family's share at it; it is below the union
    bound's threshold."""
    from bgc.diagnosis.detect import chain_threshold, lag_one

    for steps, sensors in ((300, 3), (400, 4), (120, 1)):
        options = DetectorOptions(0.01, (1, 8, 32), steps, ALL)
        c = options.drift_threshold(sensors, exact=True)
        rhos = []
        for w in DRIFT_RAMPS:
            weights = np.arange(1, w + 2, dtype=float)  # a window and the one a step after, over w + 1 samples
            now, before = np.r_[0.0, weights[:-1]], np.r_[weights[:-1], 0.0]
            rhos.append(now @ before / (now @ now))
            assert lag_one(w, True) == pytest.approx(rhos[-1], rel=1e-12)
        for w in DRIFT_MEANS:
            rhos.append((w - 1) / w)
            assert lag_one(w, False) == pytest.approx(rhos[-1], rel=1e-12)
        # P(|X| > c, |X'| <= c) <= P(X > c, X' <= c) + P(X < -c, X' >= -c), the two equal
        bound = sensors * sum(2 * norm.sf(c) + (steps - 1) * 2 * _crossing(c, r) for r in rhos)
        assert bound == pytest.approx(0.9 * options.share, rel=1e-6)  # the rest: the windows with a gap
        gapped = options.drift_gapped_threshold(sensors)
        assert 2 * norm.sf(gapped) * steps * sensors * len(rhos) == pytest.approx(0.1 * options.share, rel=1e-6)
        assert c < options.drift_threshold(sensors) - 0.15
    assert chain_threshold(0.01, 300, (0.0,)) == pytest.approx(norm.isf(0.01 / 600), abs=0.05)


def test_white_residuals_cross_the_chain_threshold_at_most_at_the_share():
    """White N(0, 1) residuals of 3 sensors over 300 steps, every drift
    window tested from the step it fits in (computed here by convolution):
    the runs in which any statistic passes the chain bound's threshold are at
    most the share (3 standard errors of slack over 4000 runs), and the
    threshold is not far above what the runs need (the bound is not empty:
    at the union bound's threshold they cross far less often)."""
    runs, steps, sensors = 4000, 300, 3
    options = DetectorOptions(0.1, (1, 8, 32), steps, ("mean", "drift"))  # a share of 5 %: countable
    c = options.drift_threshold(sensors, exact=True)
    rng = np.random.default_rng(11)
    z = rng.standard_normal((runs, sensors, steps))
    top = np.zeros(runs)
    for w in DRIFT_RAMPS:
        weights = np.arange(1, w + 1, dtype=float)
        for j in range(sensors):
            stats = np.stack([np.convolve(row, weights[::-1], mode="valid") for row in z[:, j]]) / np.sqrt(weights @ weights)
            top = np.maximum(top, np.abs(stats).max(axis=1))
    for w in DRIFT_MEANS:
        csum = np.concatenate([np.zeros((runs, sensors, 1)), np.cumsum(z, axis=2)], axis=2)
        top = np.maximum(top, (np.abs(csum[:, :, w:] - csum[:, :, :-w]) / math.sqrt(w)).max(axis=(1, 2)))
    share = options.share
    crossed = int((top > c).sum())
    assert crossed <= share * runs + 3 * math.sqrt(runs * share * (1 - share)), crossed
    assert crossed > int((top > options.drift_threshold(sensors)).sum())


def test_an_exact_observers_drift_window_with_a_reading_missing_is_held_to_the_gapped_threshold():
    """On an exact observer's residuals a drift window read whole is held
    to the chain bound's threshold, at (1 - DRIFT_GAPPED) of the share; one
    with a sample not read (its term 0) to the union bound's over every
    window at DRIFT_GAPPED of it: a ramp with one reading missing alarms
    either on a window without the gap or on one with it at that threshold,
    and a sensor read every other step is still tested, later. A re-armed
    detector keeps its residuals' kind."""
    from bgc.diagnosis.detect import DRIFT_GAPPED, chain_threshold, lag_one

    steps, start, slope = 300, 40, 0.006
    ramp = np.where(np.arange(steps) >= start, slope * (np.arange(steps) - start + 1), 0.0)
    options = DetectorOptions(0.01, (1, 8, 32), steps, ("mean", "drift"))
    shapes = [lag_one(w, True) for w in DRIFT_RAMPS] + [lag_one(w, False) for w in DRIFT_MEANS]
    chain = chain_threshold(0.9 * options.share, steps, tuple(shapes))
    gapped = norm.isf(DRIFT_GAPPED * options.share / (2 * steps * len(shapes)))
    assert DRIFT_GAPPED == 0.1 and chain < options.drift_threshold(1) < gapped

    def first(series, detector=None):
        d = detector or Detector(("y",), options, exact=True)
        return next(a for a in (d.update([0.0], exact=[v]) for v in series) if a is not None)

    whole = first(ramp)
    assert whole.test == "drift" and whole.threshold == pytest.approx(chain, rel=1e-9)
    gap = ramp.copy()
    missing = whole.step - 10
    gap[missing] = np.nan
    alarm = first(gap)
    holds = alarm.step - alarm.window + 1 <= missing
    assert alarm.threshold == pytest.approx(gapped if holds else chain, rel=1e-9)
    assert alarm.step >= whole.step
    halves = ramp.copy()
    halves[::2] = np.nan
    late = first(halves)
    assert late.step > whole.step and late.threshold == pytest.approx(gapped, rel=1e-9)
    rearmed = Detector(("y",), options, exact=True)
    rearmed.update([0.0], exact=[0.0])
    rearmed.rearm()
    assert rearmed.more.exact and first(ramp, rearmed).threshold == pytest.approx(chain, rel=1e-9)
    with pytest.raises(ValueError, match="exact"):  # told exact, given a particle filter's shares instead
        Detector(("y",), options, exact=True).update([0.1], [0.05])


def test_the_banks_state_round_trips_and_the_run_goes_on_as_if_never_stopped():
    rng = np.random.default_rng(8)
    steps = 400
    z = rng.standard_normal((steps, 2))
    z[300:, 0] += 0.01 * np.arange(100)  # a drift late in the run
    y = np.round(1.0 + 0.05 * z, 4)
    spread = 1.0 + 0.5 * rng.random((steps, 2))
    options = DetectorOptions(0.01, (1, 8, 32), steps, ALL)
    corr = np.array([[1.0, 0.3], [0.3, 1.0]])

    def run(detector, rows):
        for k in rows:
            alarm = detector.update(z[k], None, y[k], spread[k], corr)
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
    assert out.returncode == 2 and "'slope': give some of mean, drift, variance, frozen, pooled, matched" in out.stderr
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
        if change == "burst":  # the alarm alone, row by row (the diagnosis after it is another test's)
            alarm = _first_alarm(fast_session("circuit"), tmp_path / "run.csv", ALL)
            assert alarm is not None and 150 <= alarm.step <= 159, (seed, alarm)
            continue
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


# -- the pooled test ------------------------------------------------------------------------------------------

def _pooled_statistics(z: np.ndarray, corr: np.ndarray, k: int, mc: float = 0.0) -> dict:
    """Every pooled statistic at step k, computed directly: over each window
    W, s = the sum of the residual vectors, M = W corr + n diag((W mc)^2),
    s' M^-1 s."""
    n = z.shape[1]
    out = {}
    for w in POOLED_WINDOWS:
        if w <= k + 1:
            s = z[k - w + 1:k + 1].sum(axis=0)
            M = w * corr + n * (w * mc) ** 2 * np.eye(n)
            out[w] = float(s @ np.linalg.solve(M, s))
    return out


@pytest.mark.parametrize("mc", [0.0, 0.05])
def test_a_small_shift_in_every_sensor_is_found_by_the_pooled_test_at_its_closed_form(mc):
    """Two sensors whose residuals are correlated -0.7 (the circuit's f2 and
    f6 are, as its observer predicts them) each shift by 0.45 of their
    std from step 100: too little for the mean test over 300 steps (0.45
    sqrt(32) = 2.5 against 4.5), but against the correlation the shift is
    large, s' (W R)^-1 s = W 0.45^2 2 / (1 - 0.7). The pooled test alarms at
    the first step its closed form passes the chi-square's quantile (2
    degrees of freedom: -2 log p), with that statistic, and dates the shift
    at its first step (the sums from it score the most, by Cauchy-Schwarz);
    with a Monte Carlo share the bound M adds n diag(A^2)."""
    steps, start, shift = 300, 100, 0.45
    corr = np.array([[1.0, -0.7], [-0.7, 1.0]])
    z = np.where(np.arange(steps)[:, None] >= start, shift, 0.0) * np.ones((1, 2))
    options = DetectorOptions(0.01, (1, 8, 32), steps, ("mean", "pooled"))
    level = 0.005 / (steps * len(POOLED_WINDOWS))
    assert options.pooled_level() == pytest.approx(level, rel=1e-12)
    threshold = -2.0 * math.log(level)  # chi-square with 2 degrees of freedom: P(X > x) = exp(-x / 2)
    assert _chi2_even_sf(threshold, 2) == pytest.approx(level, rel=1e-12)
    expected = None
    for k in range(steps):
        stats = _pooled_statistics(z, corr, k, mc)
        if max(stats.values()) > threshold:
            expected = (k, max(stats, key=lambda w: stats[w]), max(stats.values()))
            break
    assert expected is not None and expected[0] > start
    detector = Detector(("f2", "f6"), options)
    for k in range(steps):
        alarm = detector.update(z[k], np.full(2, mc), None, None, corr)
        if alarm is not None:
            break
    assert alarm is not None and alarm.test == "pooled"
    assert (alarm.step, alarm.window) == expected[:2]
    assert alarm.statistic == pytest.approx(expected[2], rel=1e-9)
    assert alarm.threshold == pytest.approx(threshold, rel=1e-9)
    assert alarm.onset_step == start
    # the same shift against residuals said to be independent is a weaker one (2 W 0.45^2 at most): later
    later = Detector(("f2", "f6"), options)
    for k in range(steps):
        other = later.update(z[k], np.full(2, mc), None, None, np.eye(2))
        if other is not None:
            break
    assert other is None or other.step > alarm.step


@pytest.mark.slow
@pytest.mark.long
def test_the_pooled_test_holds_its_share_only_with_the_residuals_own_correlation():
    """White residuals whose correlation swings between +0.9 and -0.6 every
    50 steps (a transient changes how the observer's spread and the
    sensors' noise share the prediction): with each step's correlation the
    pooled test alarms at most at its share (3 standard errors of slack
    over 200 runs); told the residuals are independent, it alarms more than
    three times as often (the test can fail)."""
    rng = np.random.default_rng(11)
    runs, steps, alpha = 200, 300, 0.2
    options = DetectorOptions(alpha, (1, 8, 32), steps, ("mean", "pooled"))
    rho = np.where((np.arange(steps) // 50) % 2 == 0, 0.9, -0.6)
    corrs = np.array([[[1.0, r], [r, 1.0]] for r in rho])
    roots = np.linalg.cholesky(corrs)
    own = blind = 0
    for _ in range(runs):
        z = np.einsum("kij,kj->ki", roots, rng.standard_normal((steps, 2)))
        right = Families(("a", "b"), options)
        wrong = Families(("a", "b"), options)
        hit = miss = False
        for k in range(steps):
            hit = hit or bool(right.update(z[k], None, None, None, corrs[k]))
            miss = miss or bool(wrong.update(z[k], None, None, None, np.eye(2)))
        own += hit
        blind += miss
    share = alpha / 2
    assert own <= share * runs + 3 * math.sqrt(runs * share * (1 - share)), own
    assert blind > 3 * share * runs, blind  # measured: 11 of 200 with it, 102 without


def test_a_step_without_its_correlation_is_in_no_pooled_window_and_a_sensor_not_read_leaves_it():
    """A step whose correlation is not given keeps the windows that hold it
    untested, and only those: residuals of 3 in both sensors from the first
    step, the first step's correlation missing. One step (|s|^2 = 18) stays
    under the chi-square's quantile (-2 log p = 24.2), eight (144) pass it:
    the first pooled alarm is at step 8, the first 8-step window without
    step 0 (with step 0's correlation given: step 7). A sensor not read
    (NaN) takes its row and column out: the window's test has one degree of
    freedom fewer."""
    options = DetectorOptions(0.01, (1, 8, 32), 300, ("mean", "pooled"))
    assert -2.0 * math.log(options.pooled_level()) == pytest.approx(24.2, abs=0.05)
    for missing, first in ((0, 8), (None, 7)):
        tests = Families(("a", "b"), options)
        alarms = [k for k in range(40)
                  if tests.update(np.array([3.0, 3.0]), None, None, None, None if k == missing else np.eye(2))]
        assert alarms and alarms[0] == first and alarms == list(range(first, 40)), (missing, alarms)
    tests = Families(("a", "b"), options)
    for k in range(5):
        tests.update(np.array([0.0, 0.0]), None, None, None, np.eye(2))
    s, M, keep = tests._scores((1,))[0][2:]
    assert keep.tolist() == [0, 1]
    tests.update(np.array([1.0, np.nan]), None, None, None, np.array([[1.0, 0.5], [0.5, 1.0]]))
    s, M, keep = tests._scores((1,))[0][2:]
    assert keep.tolist() == [0] and s.tolist() == [1.0] and M.tolist() == [[1.0]]
    s, M, keep = tests._scores((2,))[0][2:]
    assert keep.tolist() == [0, 1] and M.tolist() == [[2.0, 0.0], [0.0, 1.0]]


@pytest.mark.parametrize("model", ["circuit", "two_tank"])
def test_the_predicted_correlation_is_the_kalman_filters_own_prediction(model):
    """The cubature rule the pooled test takes its correlation from
    (:meth:`bgc.filters.cubature._Filter.predicted_measurement`) predicts,
    from the nominal Kalman observer's state, the measurement mean and std
    that observer's own step predicts (its arithmetic, written apart: the
    step updates as it goes), at a step in the middle of a simulated run."""
    from bgc.filters.cubature import NominalKalman
    from conftest import session

    s = session(model)
    nominal = s.package.MODELS["nominal"]
    sim = bgc.simulate(s, "none", seed=2)
    ys = np.column_stack([sim.measurements[y] for y in nominal.OUTPUTS])
    us = np.column_stack([sim.inputs[u] for u in nominal.INPUTS])
    kf = NominalKalman(nominal, len(nominal.OUTPUTS))
    for k in range(60):
        kf.step(ys[k], us[k])
    mean, cov = kf.kf.predicted_measurement(kf.m[0], kf.P[0], us[60])
    kf.step(ys[60], us[60])
    assert mean == pytest.approx(kf.y_mean[-1], rel=1e-9)
    assert np.sqrt(np.diagonal(cov)) == pytest.approx(kf.y_std[-1], rel=1e-9)
    assert np.allclose(cov, cov.T) and (np.linalg.eigvalsh(cov) > 0).all()


def _source_low(path, seed: int, drop: float, at: int = 150) -> None:
    """A run of the circuit by another simulator (tests/test_mismatch.py's
    exact solution, the model's own numbers) whose source gives ``drop``
    less than the logger's V column says from step ``at`` on: every flow
    falls by as much at steady state, each sensor a little."""
    from test_mismatch import DT, NOMINAL, START, STEPS, V, circuit, readings

    rng = np.random.default_rng(seed)
    e, process, sensor = circuit(NOMINAL, 1.0)
    x, lines = np.array(START), ["time,u:V,y:f2,y:f6,y:e11"]
    for k in range(1, STEPS + 1):
        v = V * (1.0 - drop) if k >= at else V
        x = e[:3, :3] @ x + e[:3, 3] * v + process * rng.standard_normal(3)
        y = readings(NOMINAL, x, v) + sensor * rng.standard_normal(3)
        lines.append(",".join(f"{q:.6g}" for q in (k * DT, V, *y)))
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")


def _first_alarm(s, path, tests):
    """The first alarm of a diagnoser with the detector's ``tests`` fed the run file ``path`` row by row."""
    import csv

    d = s.diagnoser(bgc.DiagnosisOptions(detectors=tests))
    with open(path, encoding="utf-8") as f:
        for row in csv.DictReader(f):
            alarm = d.step(float(row["time"]), {"V": float(row["u:V"])},
                           {y: float(row[f"y:{y}"]) for y in ("f2", "f6", "e11")}).alarm
            if alarm is not None:
                return alarm
    return None


def first_alarms(s, path, write, seeds, banks) -> dict:
    """Per bank of tests in ``banks``, the first alarm (:func:`_first_alarm`)
    of each seed's run, ``write(path, seed)`` writing it, in the seeds' order."""
    out = {tests: [] for tests in banks}
    for seed in seeds:
        write(path, seed)
        for tests in banks:
            out[tests].append(_first_alarm(s, path, tests))
    return out


@pytest.mark.slow
def test_a_source_a_little_low_is_seen_sooner_by_the_pooled_test(tmp_path):
    """The circuit's source 5 % below what its column says from step 150
    (another simulator): every flow falls by 5 % of 2.5 A at steady state,
    each sensor a little. Over 8 seeds the mean test alone alarms after a
    median of 14.5 steps (0 to 31), with the pooled test after 5 (0 to 6),
    the pooled test named every time (measured); asked here: at most half
    the delay, the pooled test named in most runs, and no alarm on the
    same simulator's fault-free runs."""
    from conftest import fast_session

    s = fast_session("circuit")
    alarms = first_alarms(s, tmp_path / "run.csv", lambda path, seed: _source_low(path, seed, 0.05), range(8),
                          (("mean",), ("mean", "pooled")))
    for tests, found in alarms.items():
        assert all(a is not None and a.step >= 149 for a in found), (tests, found)
    delays = {tests: [a.step - 149 for a in found] for tests, found in alarms.items()}
    named = [a.test for a in alarms[("mean", "pooled")]]
    assert np.median(delays[("mean", "pooled")]) <= 0.5 * np.median(delays[("mean",)]), delays
    assert named.count("pooled") >= 5, named
    for seed in range(2):
        _source_low(tmp_path / "run.csv", 100 + seed, 0.0)
        assert _first_alarm(s, tmp_path / "run.csv", ("mean", "pooled")) is None, seed


@pytest.mark.slow
@pytest.mark.parametrize("model, controlled", [("ro_hybrid_valve", True), ("ro_hybrid", False)])
@pytest.mark.long
def test_a_model_with_modes_gets_the_correlation_of_the_mode_its_cloud_agrees_on(model, controlled, monkeypatch):
    """RO with its three valve settings, the mode in the data (controlled)
    and hidden (the guards): the particle cloud agrees on the mode at every
    step of a fault-free run that switches, its dwell in the mode held
    exactly and its guards' thresholds spread as the cloud spreads them, so
    the pooled test gets a correlation at every step, and the residuals
    whitened by it have unit variances and no correlation left (within 0.1
    over 2 runs: 560 samples, a standard error of 0.06 on a variance)."""
    from bgc.diagnosis import detect
    from conftest import session

    seen = []
    original = detect.Detector.update

    def spy(self, z, mc=None, y=None, spread=None, corr=None, exact=None, whitened=None):
        seen.append((np.array(z, dtype=float), corr))
        return original(self, z, mc, y, spread, corr, exact, whitened)

    monkeypatch.setattr(detect.Detector, "update", spy)
    from conftest import MODELS

    s = session(MODELS / f"{model}.yaml")
    white = []
    for seed in range(2):
        sim = bgc.simulate(s, "none", seed=100 + seed,
                           modes="secondary@100,purge@160,primary@200" if controlled else None)
        assert len(sim.switches) >= 2
        seen.clear()
        d = s.diagnoser(bgc.DiagnosisOptions(detectors=("mean", "pooled"), seed=seed, particles=500))
        for k, t in enumerate(sim.time):
            u = {n: v[k] for n, v in sim.inputs.items()}
            if controlled:
                u["mode"] = float(sim.modes[k])
            assert d.step(float(t), u, {n: v[k] for n, v in sim.measurements.items()}).alarm is None
        assert all(c is not None for _, c in seen)
        white += [np.linalg.solve(np.linalg.cholesky(c), z) for z, c in seen[20:]]
    cov = np.cov(np.array(white).T)
    assert np.abs(np.diagonal(cov) - 1.0).max() < 0.1, cov
    assert np.abs(cov[~np.eye(len(cov), dtype=bool)]).max() < 0.1, cov
    # the drift family's Kalman observer does not follow a mode: a model with modes has none
    assert s.diagnoser(bgc.DiagnosisOptions(detectors=("mean", "drift"), particles=100)).loop.companion is None
