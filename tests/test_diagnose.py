"""Diagnosis end to end: truth from the simulator (sympy, 8x finer RK4),
diagnosis with the committed generated packages; detection window, isolated
fault, onset and estimate checked against the injected fault, and fault-free
runs that must not alarm. Also ``bgc diagnose`` and its errors."""

import json

import numpy as np
import pytest

import bgc
from bgc.output.events import NOTABLE
from bgc import events
from bgc.diagnosis.options import DiagnosisOptions

from conftest import FAST, ROOT, bgc_cli, fast_session, numba_package, session
from bgc.analysis import track

GENERATED = ROOT / "generated"


def run(model: str, scenario: str, seed: int, workers: int = 1, **noise):
    """The diagnosis of a shipped model's scenario with the committed package
    on the FAST backend (1000 particles, gpf); for the slow tests only (make
    check compiles no kernel)."""
    return bgc.diagnose(fast_session(model, **noise), scenario=scenario,
                        seed=seed, options=DiagnosisOptions(seed=seed, workers=workers)).diagnosis


@pytest.mark.slow
def test_ro_abrupt_pipe_blockage_is_detected_at_once_isolated_and_sized():
    """R_pipe 69 -> 100 at t = 165 (the thesis's Table IV.2 scenario): the loop
    flow jumps, so the alarm comes within a few samples, the onset is the
    fault's sample, and the bias is within 10 % of 31, its interval covering it."""
    d = run("ro", "R_pipe:abrupt:31@165", seed=3)
    assert d.verdict == "isolated" and d.candidates == ("R_pipe_abrupt",)
    assert 165 <= d.time_of(d.detection.step) <= 170 and abs(d.onset - 165) <= 2
    e = d.estimate
    assert abs(e.value - 31.0) < 0.1 * 31.0 and e.low <= 31.0 <= e.high
    assert e.parameter_value == pytest.approx(69.0 + e.value, rel=0.05)
    dropped = {h.name: h for h in d.hypotheses if h.dropped_step is not None}
    assert dropped and all(h.reason for h in dropped.values())


@pytest.mark.slow
def test_ro_incipient_pipe_blockage_its_slope_and_onset():
    """R_pipe drifting at 0.5 per unit time from t = 165 (Table IV.4), one
    seeded run: found long after it began, but the onsets tried reach back to
    it (within 16 samples: four steps of the 4-sample onset grid near the
    alarm; one run's onset can be 9 samples off, the onset and the slope
    trading off), and the slope is sized within 4 of its reported stds (an
    honest std fails this once in 16000 runs). Over seeds (the mean onset
    error within two grid steps, 8 samples, the mean slope error under 15 %,
    the interval holding the slope in at least 4 of 5 runs): ``bench/seeded_statistics.py ro-incipient``, and
    bench/diagnosis_accuracy.py over 20 seeds."""
    d = run("ro", "R_pipe:incipient:0.5@165", seed=1)
    assert d.candidates[0] == "R_pipe_incipient" and d.verdict in ("isolated", "ambiguous")
    assert d.time_of(d.detection.step) > 170
    assert abs(d.onset - 165) <= 16, d.onset
    e = d.estimate
    assert abs(e.value - 0.5) < 4 * e.std and e.low < e.value < e.high, e


@pytest.mark.slow
def test_circuit_resistor_fault_at_noise_levels_other_than_the_models():
    """The filters assume the data's noise levels (here a third and a half of
    the model's): R2 2 -> 2.6 at t = 5 is isolated and sized."""
    d = run("circuit", "R2:abrupt:0.6@5", seed=2, process_noise=0.01, measurement_noise=0.01)
    assert d.candidates[0] == "R2_abrupt" and d.verdict == "isolated"
    e = d.estimate
    # one run: the truth within 4 of its stds (an honest std fails this once in 16000 runs; the 95 %
    # interval's coverage over seeds: the RO drift test above, and bench/diagnosis_accuracy.py)
    assert abs(e.value - 0.6) < 0.1 * 0.6 and abs(e.value - 0.6) < 4 * e.std, e


@pytest.mark.slow
def test_two_tank_pipe_fault():
    d = run("two_tank", "R12:abrupt:1.0@60", seed=4)
    assert d.candidates[0] == "R12_abrupt"
    assert abs(d.estimate.value - 1.0) < 0.1


@pytest.mark.slow
@pytest.mark.parametrize("model, seed, noise", [
    ("ro", 11, {}), ("ro", 12, {"process_noise": 0.01, "measurement_noise": 0.005}),
    ("circuit", 13, {}), ("circuit", 15, {"process_noise": 0.06, "measurement_noise": 0.04}),
    ("two_tank", 14, {}), ("two_tank", 16, {"process_noise": 0.01, "measurement_noise": 0.005})])
def test_no_fault_no_alarm(model, seed, noise):
    """Fault-free runs at the models' noise levels and at others: no alarm (the
    threshold is set for a false-alarm probability per run, on residuals the
    observer normalises by its own predicted std)."""
    d = run(model, "none", seed=seed, **noise)
    assert d.verdict == "no fault" and d.detection is None and d.hypotheses == ()


@pytest.mark.process  # forks a pool of workers: what it tests
def test_the_filters_of_a_diagnosis_run_in_worker_processes_with_the_same_results():
    """Hypothesis filters are independent: on two processes or in this one,
    the same seeds give the same numbers. (It forks a pool of two workers:
    that is what it tests.) A short run (160 samples, 8 s, the fault at
    t = 5, every hypothesis tracked and weighed) of 300 particles: what is
    compared is each hypothesis's numbers, whatever the run's size."""
    model = session(ROOT / "models" / "circuit.yaml", generated=GENERATED)
    a = bgc.diagnose(model, scenario="R2:abrupt:0.6@5", steps=160,
                     options=DiagnosisOptions(seed=5, workers=2, particles=300)).diagnosis
    b = bgc.diagnose(model, scenario="R2:abrupt:0.6@5", steps=160,
                     options=DiagnosisOptions(seed=5, workers=1, particles=300)).diagnosis
    assert a.hypotheses and [h.name for h in a.hypotheses] == [h.name for h in b.hypotheses]
    for x, y in zip(a.hypotheses, b.hypotheses):
        # a rejected filter stops: the rest of its arrays is NaN in both
        assert x.log_evidence == y.log_evidence and np.array_equal(x.magnitude, y.magnitude, equal_nan=True)


# ------------------------------------------------------------------- the CLI (in this process: conftest.bgc_cli)
@pytest.mark.slow
@pytest.mark.long
def test_bgc_diagnose_writes_a_report_and_plots(tmp_path):
    """On the FAST backend, --backend (conftest.fast_session's kernels; the
    result does not depend on it: tests/test_backend.py; the slow tier
    only)."""
    if FAST == "numba":
        numba_package("circuit")  # the kernels the command loads, compiled once per test run
    out = tmp_path / "diag"
    r = bgc_cli("diagnose", "models/circuit.yaml", "--scenario", "R2:abrupt:0.6@5", "--seed", "2", "--backend", FAST,
                "-o", str(out))
    assert r.returncode == 0, r.stderr
    assert r.stdout.startswith("circuit: isolated: R2_abrupt")
    assert f"wrote {out}/: report.md, report.json, report.html" in r.stdout
    report = json.loads((out / "report.json").read_text())
    assert report["verdict"] == "isolated" and report["diagnosis"] == ["R2_abrupt"]
    best = next(h for h in report["hypotheses"] if h["model"] == "R2_abrupt")
    e = best["estimate"]
    assert best["dropped"] is None and e["method"] == "kalman"
    assert e["covers_truth"] is (e["interval"][0] <= 0.6 <= e["interval"][1])
    assert abs(e["value"] - 0.6) < 4 * e["std"] and e["interval"][0] < e["value"] < e["interval"][1]
    assert best["filter_estimate"]["std"] > e["std"]  # the particle filters' magnitude with its random walk
    assert all(h["dropped"]["why"] for h in report["hypotheses"] if h["model"] != "R2_abrupt")
    md = (out / "report.md").read_text()
    assert "**Fault isolated: R2_abrupt.**" in md and "## Fault-model filters" in md
    for name in ("measurements.png", "residuals.png", "hypotheses.png", "estimate.png"):
        assert (out / name).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert "Fault isolated: R2_abrupt." in (out / "report.html").read_text()  # tests/test_html_report.py: the rest
    # the recorded run is beside it, and can be diagnosed again from the file
    again = bgc_cli("diagnose", "models/circuit.yaml", "--data", str(out / "run.csv"), "--seed", "2", "--backend", FAST,
                    "-o", str(tmp_path / "again"))
    assert again.returncode == 0 and again.stdout.startswith("circuit: isolated: R2_abrupt"), again.stderr


def one_line(r) -> str:
    assert r.returncode == 1 and "Traceback" not in r.stderr, r.stderr
    lines = r.stderr.splitlines()
    assert len(lines) == 1, r.stderr
    return lines[0]


def test_bgc_diagnose_bad_input_is_one_located_line(tmp_path):
    assert one_line(bgc_cli("diagnose", "models/circuit.yaml", "--scenario", "Q9:abrupt:1@5")).startswith(
        "--scenario: 'Q9' is no parameter, measurement or input of circuit")
    assert one_line(bgc_cli("diagnose", "models/circuit.yaml")).startswith(
        "give --data RUN.csv or --scenario NAME:KIND:MAGNITUDE@TIME")
    other = tmp_path / "ro.csv"
    assert bgc_cli("simulate", "models/ro.yaml", "--steps", "5", "-o", str(other)).returncode == 0
    assert one_line(bgc_cli("diagnose", "models/circuit.yaml", "--data", str(other))).startswith(
        f"{other} is a run of model 'ro', not of 'circuit'")
    cut = tmp_path / "cut.csv"
    cut.write_text("time,y:q9\n1.0,2.5\n2.0,2.5\n")
    assert one_line(bgc_cli("diagnose", "models/circuit.yaml", "--data", str(cut))) == (
        f"{cut}: the data have none of the model's sensors (y:e11, y:f2, y:f6) (record at least one of them as a "
        "y:NAME column)")
    assert one_line(bgc_cli("diagnose", "models/circuit.yaml", "--scenario", "none", "--particles", "0")).startswith(
        "--particles 0: at least 1 particle is needed")


@pytest.mark.slow
@pytest.mark.numba  # the compiled backend when numba is installed (conftest.FAST)
def test_the_95_percent_interval_is_an_honest_interval_of_one_seeded_run():
    """Honest uncertainty, one run (the circuit's R2 up by 0.6 at t = 5 at a
    third and a half of the model's noise, seed 200, without the weighing of
    the fault models the symbols ruled out, ``recheck``, which leaves the
    interval of a hypothesis they kept as it is): the truth lies within 4 of
    the reported stds, and the 95 % interval of this near-normal posterior
    is the estimate +-1.96 of its std (within a quarter). That the interval
    covers the truth at least 16 times in 20 seeded runs (with a true
    coverage of 90 %, the issue's target, that passes with probability
    0.96, with 70 % only 0.24) is ``bench/seeded_statistics.py coverage``;
    bench/diagnosis_accuracy.py over more scenarios and seeds."""
    d = bgc.diagnose(fast_session("circuit", process_noise=0.01, measurement_noise=0.01), scenario="R2:abrupt:0.6@5",
                     seed=200, options=DiagnosisOptions(seed=200, workers=1, recheck=False)).diagnosis
    h = next(h for h in d.hypotheses if h.name == "R2_abrupt")
    e = h.estimate
    assert abs(e.value - 0.6) < 4 * e.std, e
    assert e.low < e.value < e.high and 0.8 < (e.high - e.low) / (2 * 1.96 * e.std) < 1.25, e


@pytest.mark.slow
def test_bgc_diagnose_rewrites_its_own_folder_but_no_one_elses(tmp_path):
    out = tmp_path / "diag"
    for _ in range(2):
        r = bgc_cli("diagnose", "models/two_tank.yaml", "--scenario", "none", "--particles", "100", "-o", str(out))
        assert r.returncode == 0, r.stderr
    assert json.loads((out / "manifest.json").read_text())["files"]["report.md"]
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "notes.txt").write_text("x")
    line = one_line(bgc_cli("diagnose", "models/two_tank.yaml", "--scenario", "none", "-o", str(mine)))
    assert line.startswith(f"{mine} is not empty and holds no bgc manifest.json")


@pytest.mark.slow
def test_symbols_from_a_subsample_of_the_paths_when_particles_are_many(monkeypatch):
    """Above ``PATHS`` particles the open loop keeps a random subsample of
    the paths for the symbols' null distribution (memory); the circuit's R2
    step is still read as f6 falling and isolated. (On the FAST backend:
    conftest.fast_session, the slow tier only; the open loop's paths are
    bgc.diagnosis.openloop's on either backend.)"""
    from bgc.diagnosis import openloop

    monkeypatch.setattr(openloop, "PATHS", 64)
    d = bgc.diagnose(fast_session("circuit"), scenario="R2:abrupt:0.6@5", seed=1,
                     options=DiagnosisOptions(seed=1, particles=300, workers=1)).diagnosis
    assert [(s.sensor, s.sign) for s in d.symbols][:1] == [("f6", "-")]
    assert d.candidates[0] == "R2_abrupt"


def test_the_estimate_over_onsets_is_the_weighted_mixture_of_their_clouds():
    """Hand values: onset A (weight 1) has particles 1, 1, 1, 1 of equal weight,
    onset B (weight 3) particles 3 and 3 with log-weights that differ only by a
    constant. The mixture is 1 with probability 1/4 and 3 with 3/4: mean 2.5,
    variance 1/4 * 1.5^2 + 3/4 * 0.5^2 = 0.75; its 95 % interval runs from the
    1's to the 3's."""
    from bgc.diagnosis.estimate import onset_mixture

    mean, std, low, high = onset_mixture([(1.0, [1.0] * 4, [0.0] * 4), (3.0, [3.0, 3.0], [-7.0, -7.0])], 0.95)
    assert mean == pytest.approx(2.5) and std == pytest.approx(0.75 ** 0.5)
    assert low == pytest.approx(1.0) and high == pytest.approx(3.0)


@pytest.mark.parametrize("method", ["gpf", "apf"])
@pytest.mark.parametrize("model_name, fault", [("ro", "R_pipe_incipient"), ("two_tank", "R12_abrupt")])
def test_filters_stepped_in_a_bank_end_each_step_as_if_each_were_stepped_alone(model_name, fault, method):
    """A FilterBank steps several filters in shared arrays. Each filter must
    end every step exactly (bit for bit) as its own predict() and
    step(predicted=True) leave a twin with the same seed: same particles,
    weights, predicted measurement, moments, ESS and resampling, whichever
    filters run beside it. The run mixes what a diagnosis meets: filters
    joining and leaving the bank, particle counts that are not multiples of
    4, a measurement with one output missing, one with all missing, one far
    off the data (weights that underflow: the filters recover), then the
    Liu and West move on the bank's arrays against a lone row's."""
    from bgc.model import package as packages
    from bgc.diagnosis.hypothesis import _shrink_together
    from bgc.diagnosis.hypothesis import kernel_shrinkage as _kernel_shrinkage

    package = packages.load_package(ROOT / "generated", model_name)
    model = package.MODELS[fault]
    cls = {"gpf": package.filters.GenericParticleFilter, "apf": package.filters.AuxiliaryParticleFilter}[method]
    rng = np.random.default_rng(5)
    u = model.inputs(0.0)
    y0 = model.observe(model.initial_particles(rng, 1), u, model.THETA)[:, 0]
    n_y = len(y0)
    n = 301
    seeds = range(6)
    banked = {s: cls(model, n, np.random.default_rng(s)) for s in seeds}
    alone = {s: cls(model, n, np.random.default_rng(s)) for s in seeds}
    bank = package.filters.FilterBank(model)
    k_mag = len(model.STATES) - 1
    recovered = 0
    with np.errstate(all="ignore"):  # the far measurement overflows
        for k in range(40):
            y = y0 * (1.0 + 0.01 * rng.standard_normal(n_y))
            if k == 7:
                y[0] = np.nan
            if k == 11:
                y[:] = np.nan
            if k == 15:
                y = y0 * 1e200  # every weight underflows
            members = [s for s in seeds if (s + k) % 7 != 0 and not (s == 5 and k > 30)]
            if k in (20, 21):
                members = [2]  # a lone filter: its own step
            results = bank.step([banked[s] for s in members], y, u)
            resampled = [r.resampled for r in results]
            _shrink_together(bank, [banked[s] for s in members], k_mag, 0.98, resampled)
            for s, r in zip(members, results):
                pf = alone[s]
                model.predict(pf.x, u, pf.theta, model.DT, out=pf.x)
                want = pf.step(y, u, predicted=True)
                _kernel_shrinkage(pf.x[k_mag][None], pf.logw[None], 0.98, [pf.rng], np.array([want.resampled]))
                for field in ("mean", "std", "y_mean", "y_std", "ess", "resampled", "recovered"):
                    np.testing.assert_array_equal(getattr(r, field), getattr(want, field), err_msg=f"step {k}: {field}")
                recovered += want.recovered
            for s in members:
                np.testing.assert_array_equal(banked[s].x, alone[s].x, err_msg=f"step {k}: particles")
                np.testing.assert_array_equal(banked[s].logw, alone[s].logw, err_msg=f"step {k}: log-weights")
    assert recovered > 0  # the far measurement made the filters recover
    assert sum(pf.recoveries for pf in alone.values()) == sum(pf.recoveries for pf in banked.values())


def test_a_bank_of_filters_of_different_sizes_steps_them_one_by_one():
    """Filters of different particle counts cannot share arrays: the bank
    predicts each theta's particles in one call and steps each filter alone,
    with the same numbers as each filter's own step."""
    from bgc.model import package as packages

    package = packages.load_package(ROOT / "generated", "ro")
    model = package.MODELS["R_pipe_incipient"]
    u = model.inputs(0.0)
    pfs = [package.filters.GenericParticleFilter(model, n, np.random.default_rng(n)) for n in (300, 500, 200)]
    twins = [package.filters.GenericParticleFilter(model, n, np.random.default_rng(n)) for n in (300, 500, 200)]
    y = model.observe(pfs[0].x, u, model.THETA)[:, 0]
    bank = package.filters.FilterBank(model)
    results = bank.step(pfs, y, u)
    assert not bank.packed
    for pf, twin, r in zip(pfs, twins, results):
        model.predict(twin.x, u, twin.theta, model.DT, out=twin.x)
        want = twin.step(y, u, predicted=True)
        np.testing.assert_allclose(pf.x, twin.x, rtol=1e-13, atol=0)
        np.testing.assert_allclose(r.y_mean, want.y_mean, rtol=1e-13, atol=0)


def test_a_hypothesis_is_seeded_by_its_name_not_by_its_rank():
    """The hypothesis filters' seeds depend on the run's seed, the hypothesis's
    name and the onset only: the same whichever other hypotheses survive the
    symbols, and different for different names, onsets and seeds."""
    import zlib

    from bgc.diagnosis.onsets import hypothesis_seed

    assert hypothesis_seed(3, "R_pipe_incipient", 160) == [3, 1, zlib.crc32(b"R_pipe_incipient"), 160]
    seeds = {tuple(hypothesis_seed(s, n, o)) for s in (0, 1) for n in ("R1_abrupt", "R2_abrupt") for o in (5, 6)}
    assert len(seeds) == 8


def test_a_drifts_onsets_are_every_4_samples_near_the_alarm_and_coarser_further_back():
    """drift_onsets(100, 90, 4, 100): back from the alarm at 100 every 4
    samples while 1/16 of the distance is at most 4 (distances 0, 4, ..., 80),
    then 1/16 of the distance, rounded down (80 +5 -> 85 +5 -> 90 +5 -> 95 +5
    -> 100), down to sample 0; the change point 90 as well, and the sample
    before it, 89 (the first deviating sample of a fault that acts through
    the dynamics is the one after its onset). With a history of 64 the grid
    stops at 64."""
    from bgc.diagnosis.onsets import drift_onsets

    assert drift_onsets(100, 90, 4, 100) == sorted({100 - d for d in (*range(0, 81, 4), 85, 90, 95, 100)}
                                                   | {89, 90})
    assert drift_onsets(100, 90, 4, 64) == sorted({100 - d for d in range(0, 65, 4)} | {89, 90})
    assert min(drift_onsets(30, 28, 4, 256)) == 2  # never before the first sample: 30 - 28
    assert drift_onsets(5, 0, 4, 256) == [0, 1, 5]  # a change point at the first sample: nothing before it


def test_each_onset_weighs_the_span_of_samples_it_stands_for():
    """The onset prior is uniform in time: consecutive samples weigh 1 each,
    a grid 4 apart 4 each, and an uneven grid the span between the midpoints
    to its neighbours (0, 4, 6: edges -2, 2, 5, 7)."""
    from bgc.diagnosis.static_posterior import onset_widths

    assert onset_widths([5, 6, 7]).tolist() == [1.0, 1.0, 1.0]
    assert onset_widths([10, 14, 18]).tolist() == [4.0, 4.0, 4.0]
    assert onset_widths([0, 4, 6]).tolist() == [4.0, 3.0, 2.0]
    assert onset_widths([7]).tolist() == [1.0]


@pytest.mark.slow
@pytest.mark.long
def test_a_drift_found_long_after_it_began_gets_its_onset_grid_extended_back():
    """R3 drifting from t = 5.3 (sample 106) in the circuit, detected more
    than 64 samples later (a drift of the sweep, bgc's seed 473362393): the
    first onset grid (64 samples back from the alarm) misses the onset, the
    onset posterior piles up at its earliest onset, and the grid is extended
    back (by the particle filters with ``identify="filter"``, by the Kalman
    filters of the static posterior by default); the drift is isolated with
    its onset within 12 samples. Both diagnoses on two workers; the particle
    filters' rounds of earlier onsets give the same numbers on one process
    (a Kalman diagnosis on one process gives the same numbers:
    test_the_filters_of_a_diagnosis_run_in_worker_processes_with_the_same_results,
    and the Kalman filters' searches side by side each model's alone:
    tests/test_kalman.py's
    test_static_posteriors_side_by_side_are_each_models_alone_bit_for_bit)."""
    d = run("circuit", "R3:incipient:0.0308906@5.3", seed=473362393, workers=2)
    assert d.detection.step - 106 > 64
    assert d.candidates[0] == "R3_incipient"
    h = d.best
    assert min(h.static.onsets) < d.detection.step - 64
    assert abs(h.onset_step - 106) <= 12 and d.onset_step == h.onset_step, h.onset_step
    circuit = fast_session("circuit")  # as run() above
    f = bgc.diagnose(circuit, scenario="R3:incipient:0.0308906@5.3", seed=473362393,
                     options=DiagnosisOptions(seed=473362393, workers=2, identify="filter", spacing=4)).diagnosis
    h = f.best
    assert f.candidates[0] == "R3_incipient" and min(h.onset_steps) < f.detection.step - 64
    assert abs(h.start_step - 106) <= 12, h.start_step
    # each hypothesis's batches of onsets depend on its own results only: on one process (the
    # batches one after another) the same onsets are tried and give the same numbers
    one = bgc.diagnose(circuit, scenario="R3:incipient:0.0308906@5.3", seed=473362393,
                       options=DiagnosisOptions(seed=473362393, workers=1, identify="filter", spacing=4)).diagnosis
    assert [(x.name, x.onset_steps) for x in one.hypotheses] == [(x.name, x.onset_steps) for x in f.hypotheses]
    for x, y in zip(one.hypotheses, f.hypotheses):
        assert x.log_evidence == y.log_evidence and x.onset_posterior == y.onset_posterior
        assert np.array_equal(x.magnitude, y.magnitude, equal_nan=True)


TEST_MODELS = ROOT / "tests" / "data" / "models"


@pytest.mark.slow
def test_a_parameter_seen_directly_by_a_sensor_changed_at_a_sample_is_isolated():
    """The DC motor's e4 = k w: k changed at t = 150 moves the sample of that
    instant (the states have not moved yet), so the alarm comes on it and the
    filters' onset (the first step whose dynamics are faulty) is the sample
    after it. That onset must be tried, and the filter from the alarm's sample
    (whose magnitude settles on half the change to fit it, then fails its
    test) must not prune it before it starts. Both failed before: the verdict
    was 'unexplained' in every such run of a campaign."""
    d = bgc.diagnose(session(TEST_MODELS / "dc_motor.yaml"), scenario="k:abrupt:0.03@150", seed=3,
                     options=DiagnosisOptions(seed=3, workers=1)).diagnosis
    assert d.time_of(d.detection.step) == 150
    assert d.verdict == "isolated" and d.candidates == ("k_abrupt",)
    h = d.best
    assert max(h.onset_steps) == d.detection.step + 1  # the sample after the alarm was tried
    e = d.estimate
    assert e.low <= 0.03 <= e.high and abs(e.value - 0.03) < 0.1 * 0.03


@pytest.mark.slow
def test_a_hypothesis_whose_earliest_filters_all_stop_before_the_next_onset_starts():
    """A campaign run that raised (``cannot reshape array of size 0``): every
    filter started had stopped while the hypothesis's later onsets had not
    started, so a step had no filter to run."""
    d = bgc.diagnose(session(TEST_MODELS / "dc_motor.yaml", process_noise=0.005, measurement_noise=0.01),
                     scenario="R_a:incipient:0.00113856@170", seed=505876183,
                     options=DiagnosisOptions(filter="gpf", particles=500, seed=505876183, workers=1)).diagnosis
    assert d.detection is not None and "R_a_incipient" in d.candidates


@pytest.mark.slow
def test_the_auxiliary_filters_residuals_of_a_product_of_states_keep_unit_variance():
    """The DC motor starts at rest, where P_mech = k i w has no slope: the APF
    took its predictive std from there and left out the process noise P_mech
    passes on once the motor runs. Its normalised P_mech residuals had std
    1.35 (the GPF's: 0.98) and 8 of 40 fault-free runs at 2 %/3 % noise
    alarmed, against a target of 1 %. Over 3 runs (900 residuals, the std's
    standard error 0.024) the std must now be that of N(0, 1), and no run
    may alarm."""
    z = []
    for seed in (1, 2, 3):
        d = bgc.diagnose(session(TEST_MODELS / "dc_motor.yaml", process_noise=0.02, measurement_noise=0.03),
                         scenario="none", seed=seed,
                         options=DiagnosisOptions(filter="apf", particles=500, seed=seed, workers=1)).diagnosis
        assert d.detection is None
        z.append(np.asarray(d.nominal_z)[10:, d.outputs.index("P_mech")])
    assert 0.9 < np.std(np.concatenate(z)) < 1.1


@pytest.mark.slow
def test_a_parameter_a_sensor_sees_is_sized_right_when_it_changes_at_a_sample():
    """The orifice tanks' F_orifice = cd sqrt(P1 - P2) sees cd directly: a
    change at t = 149 moves the sample of that instant, the levels move from
    then on. The fault filters took the transition into their onset sample
    with the fault in, a sample of dynamics too early: at 0.5 %/1 % noise
    cd + 0.3595 was sized +0.546 (52 % off) with an interval that missed it.
    The estimate must now hold the truth and lie within 5 % of it."""
    truth = 0.359508
    d = bgc.diagnose(session("orifice_tanks", process_noise=0.005, measurement_noise=0.01),
                     scenario=f"cd:abrupt:{truth}@149", seed=2765532394,
                     options=DiagnosisOptions(particles=500, seed=2765532394, workers=1)).diagnosis
    assert d.verdict == "isolated" and d.candidates == ("cd_abrupt",)
    e = d.estimate
    assert e.low <= truth <= e.high and abs(e.value - truth) < 0.05 * truth
    assert d.time_of(d.best.start_step) == 149


@pytest.mark.slow
@pytest.mark.long
def test_a_drift_whose_particle_filters_start_off_its_onset_is_tested_as_its_fault_model_states_it():
    """The RO membrane's drift (slope 0.2 from t = 165) at the thesis's noise,
    APF, 200 particles, seed 0: the drift's particle filters start every 8
    samples (the nearest 3 samples before the truth), the one from that onset
    fails its test late in the run (a 32-sample window just over the
    threshold), and so does every other hypothesis's: the verdict was
    'unexplained'. When no hypothesis passes, those whose best filter ran to
    the end are tested with the magnitude held static, on the Kalman filters'
    finer onsets; R_memb's drift passes, and is the diagnosis. (On the FAST
    backend: conftest.fast_session, the slow tier only.)"""
    d = bgc.diagnose(fast_session("ro"), scenario="R_memb:incipient:0.2@165", seed=0,
                     options=DiagnosisOptions(filter="apf", particles=200, seed=0, workers=1)).diagnosis
    assert d.verdict == "isolated" and d.candidates == ("R_memb_incipient",)
    assert any(isinstance(e, events.Rescued) and e.hypothesis == "R_memb_incipient" for e in d.events)
    e = d.estimate
    assert e.low <= 0.2 <= e.high and abs(e.value - 0.2) < 0.05 * 0.2


@pytest.mark.slow
@pytest.mark.parametrize("method", ["gpf", "apf"])
@pytest.mark.long
def test_a_drifts_onset_is_marginalised_sample_by_sample_where_its_posterior_is(method):
    """The DC motor's armature resistance drifting from t = 93 at 0.5 %/1 %
    noise: given its onset, the slope is known to 0.3 %, far sharper than the
    Kalman filters' onsets 4 samples apart. Their posterior kept one onset,
    a sample late (GPF) or 3 early (APF), and its interval missed the truth
    (-0.0015137 and -0.0014746 against -0.0015021, each +-0.3 %). Every
    sample between the most probable onset's neighbours is tried now: the
    truth's onset (sample 92, t = 93) is the most probable, and the
    interval holds the truth."""
    truth = -0.00150208
    d = bgc.diagnose(session("dc_motor", process_noise=0.005, measurement_noise=0.01),
                     scenario=f"R_a:incipient:{truth}@93", seed=2937888235,
                     options=DiagnosisOptions(filter=method, particles=500, seed=2937888235, workers=1)).diagnosis
    assert d.candidates == ("R_a_incipient",)
    assert d.onset == 93 and d.time_of(d.onset_step) == 93
    e = d.estimate
    assert e.low <= truth <= e.high


@pytest.mark.slow
def test_a_fault_its_symbols_rule_out_is_tried_when_those_they_keep_explain_nothing():
    """A sweep run of the two tanks: R20 up by 1.02 at t = 48. The fault is
    seen on F20 at once and the plant settles fast, so the slope read after
    the jump rules R20's signature out and keeps R12's only, whose filters then
    fail: the verdict was 'unexplained'. The fault models the symbols ruled
    out are now tried too, with a note. (On the FAST backend:
    conftest.fast_session, the slow tier only.)"""
    d = bgc.diagnose(fast_session("two_tank"), scenario="R20:abrupt:1.02018@48", seed=2743265757,
                     options=DiagnosisOptions(particles=500, seed=2743265757, workers=1)).diagnosis
    assert any(name.startswith("R20") for name, _ in d.refuted)  # the symbols still rule it out
    assert d.verdict == "isolated" and d.candidates == ("R20_abrupt",)
    assert any(isinstance(e, events.AllTried) and e.why == "unexplained" for e in d.events)
    assert d.estimate.low <= 1.02018 <= d.estimate.high


@pytest.mark.slow
def test_a_sensor_sharp_against_the_process_noise_degenerates_the_particle_filters_and_kalman_filters_take_over():
    """The drivetrain test plant: a stiff shaft between two inertias whose
    torque is measured to 0.17 N m, while the speeds' process noise of one
    step moves the next step's torque by several N m. The generic filter's
    cloud collapses (mean ESS a few of 500) and it alarms without a fault;
    the diagnosis says why and, by default, diagnoses with cubature Kalman
    filters instead (unless told not to: then it says what to use). The
    plant is linear in its states, so its cubature Kalman filter is the
    Kalman filter, whose innovations are white with unit variance whatever
    the particle count (Kalman filter theory): checked on two seeds. (The
    locally optimal proposal is no remedy: it draws step k's particles
    towards y_k, but the torque at step k is fixed by the speeds' noise drawn
    at step k-1, so its weights degenerate as well, and on 5 of 8 seeds at
    N = 1000 it lost the state altogether.) The diagnosis that must not
    switch is of 100 samples: what it is read for is its first alarm."""
    from bgc.filters import cubature as kalman
    from bgc.data import runs
    from bgc.analysis import simulate

    model = session(TEST_MODELS / "drivetrain.yaml")
    d = bgc.diagnose(model, scenario="none", seed=1, steps=100,
                     options=DiagnosisOptions(particles=500, seed=1, workers=1, switch=False)).diagnosis
    degenerate = [e for e in d.events if isinstance(e, events.Degenerate)]
    assert [(e.method, e.particles, e.switched) for e in degenerate] == [("gpf", 500, False)]
    assert degenerate[0].ess < 0.05 * 500 and degenerate[0].step == d.detection.step
    # by default the diagnosis switches to cubature Kalman filters by itself, and says so
    d = bgc.diagnose(model, scenario="none", seed=2, options=DiagnosisOptions(seed=2, workers=1)).diagnosis
    assert d.options.filter == "ckf" and d.verdict == "no fault"
    assert any(isinstance(e, events.Degenerate) and e.switched for e in d.events)
    assert any(isinstance(e, events.Switched) and e.to == "ckf" for e in d.events)
    c, package = model.compiled, model.package  # the NumPy package of the model, in a private folder
    for seed in (1, 2):
        result = simulate.simulate(c.numerics, simulate.SimulationOptions(seed=seed))
        ys, us = track.run_arrays(runs.parse_run(simulate.to_csv(result), "none"), package, "nominal")
        gpf = package.filters.GenericParticleFilter(package.nominal, 1000, np.random.default_rng(seed)).run(ys, us)
        assert gpf.ess.mean() < 0.02 * 1000
        z = kalman.nominal_track(package.nominal, ys, us, len(ys)).z[10:]
        assert np.all(np.abs(z.var(axis=0) - 1.0) < 0.2) and np.abs(z).max() < 5.0
        lag1 = [np.corrcoef(z[:-1, j], z[1:, j])[0, 1] for j in range(z.shape[1])]
        assert np.all(np.abs(lag1) < 0.2)


@pytest.mark.slow
@pytest.mark.long
def test_cubature_kalman_filters_alone_isolate_and_size_a_fault_the_particle_filters_cannot_follow():
    """The drivetrain's motor torque gain g_m down by 0.2 at t = 8 s (sample
    160): the speeds answer with the drivetrain's 10 s time constant, so the
    alarm comes seconds later, far after the step; the step's onsets reach
    back to it, and g_m's step is the most probable hypothesis, sized within
    10 % with its interval covering -0.2 and its onset within 3 samples."""
    d = bgc.diagnose(session(TEST_MODELS / "drivetrain.yaml"), scenario="g_m:abrupt:-0.2@8", seed=1,
                     options=DiagnosisOptions(filter="ckf", seed=1, workers=1)).diagnosis
    assert d.detection.step > 160 + 20 and d.candidates[0] == "g_m_abrupt"
    e = d.estimate
    assert abs(e.value + 0.2) < 0.02 and e.low <= -0.2 <= e.high and abs(d.onset_step - 160) <= 3
    best = d.best
    assert best.x_mean.shape == (len(d.time) - best.start_step, len(d.states)) and np.isfinite(best.magnitude).all()


@pytest.mark.slow
@pytest.mark.long
def test_cubature_kalman_filters_alone_find_the_static_posterior_the_particle_filters_hint_at():
    """--filter ckf lays its first grid over the magnitude's whole prior; the
    particle filters' path starts from their interval. The adaptive grid
    converges to the same static posterior either way (circuit, R1 up by 0.3
    at t = 5; on the FAST backend: conftest.fast_session, the slow tier
    only)."""
    def diagnosis(method):
        return bgc.diagnose(fast_session("circuit"), scenario="R1:abrupt:0.3@5", seed=1,
                            options=DiagnosisOptions(filter=method, seed=1, workers=1, particles=500)).diagnosis

    k, p = diagnosis("ckf"), diagnosis("gpf")
    assert k.candidates == p.candidates == ("R1_abrupt",)
    assert k.estimate.value == pytest.approx(p.estimate.value, rel=1e-3)
    assert k.estimate.low == pytest.approx(p.estimate.low, rel=1e-3)
    assert k.estimate.high == pytest.approx(p.estimate.high, rel=1e-3)
    assert k.estimate.low <= 0.3 <= k.estimate.high
    dropped = [h for h in k.hypotheses if h.dropped_step is not None]
    assert dropped and all(h.reason and h.posterior == 0.0 for h in dropped if "residual" in h.reason)


@pytest.mark.slow
def test_a_diagnosis_runs_on_the_locally_optimal_proposal_too():
    """--filter opf: the nominal observer and every hypothesis's filters (one
    by one: the bank does not pack them), on the FAST backend
    (conftest.fast_session; the slow tier only)."""
    d = bgc.diagnose(fast_session("circuit"), scenario="R2:abrupt:0.6@5", seed=4,
                     options=DiagnosisOptions(filter="opf", particles=500, seed=4, workers=1)).diagnosis
    assert d.verdict == "isolated" and d.candidates == ("R2_abrupt",)
    assert d.estimate.low <= 0.6 <= d.estimate.high
    assert not [e for e in d.events if isinstance(e, NOTABLE)]


@pytest.mark.slow
def test_a_fault_that_degenerates_the_observer_after_it_does_not_switch_the_filter():
    """The nominal filter degenerates after a large fault (the fault is what
    the data show): only the steps before the alarm say whether the filter
    itself is degenerate. R2 tripled from t = 1 left the circuit's nominal GPF
    14 of 1000 particles on average over the run. (On the FAST backend:
    conftest.fast_session, the slow tier only.)"""
    d = bgc.diagnose(fast_session("circuit"), scenario="R2:abrupt:2@1", seed=1,
                     options=DiagnosisOptions(seed=1, workers=1)).diagnosis
    assert d.options.filter == "gpf" and not any(isinstance(e, events.Degenerate) for e in d.events)
    assert d.candidates[0] == "R2_abrupt"
