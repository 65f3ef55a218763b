"""A model that does not fit the plant is said so (issue 48, point 1): the
verdict "mismatch", never a fault named "since the first sample".

The plant is the circuit of models/circuit.yaml, simulated here by another
simulator: the exact solution of its linear equations over each sample
period (the matrix exponential of the system augmented by its constant
input, Van Loan's block), derived by hand from Fig. II.3 of the thesis
(e4 on C1, e8 on C2, f10 in L; V the source):

    C1 de4/dt  = (V - e4) / R1 - (e4 - e8) / R2
    C2 de8/dt  = (e4 - e8) / R2 - f10
    L  df10/dt = e8 - R3 f10

read by f2 = (V - e4) / R1, f6 = (e4 - e8) / R2 and e11 = R3 f10. Its
parameters are each off the model file's by a uniform draw within 3 %, and
its process and sensor noise are 1.5 times the model's: the data a new
user's plant gives a model written from a datasheet. The slow tests'
diagnoses run on the FAST backend (conftest.fast_session: numba when
installed; the diagnosis does not depend on it, tests/test_backend.py).
"""

import math

import numpy as np
import pytest
from scipy.linalg import expm
from scipy.stats import chi2, norm

import bgc
from bgc.diagnosis import fit as fit_module
from bgc.filters import residuals

from conftest import bgc_cli, fast_backend, fast_session, session

NOMINAL = dict(R1=1.0, C1=0.5, R2=2.0, C2=1.0, L=0.5, R3=1.0)
V, DT, STEPS, START = 10.0, 0.05, 300, (7.5, 2.5, 2.5)


def test_the_model_file_is_the_circuit_derived_here():
    import yaml

    from conftest import MODELS

    data = yaml.safe_load((MODELS / "circuit.yaml").read_text(encoding="utf-8"))
    assert {k: v["value"] for k, v in data["parameters"].items()} == NOMINAL
    assert data["inputs"]["V"]["value"] == V and data["simulation"]["dt"] == DT
    assert tuple(data["elements"][e]["initial"] for e in ("C1", "C2", "L")) == START


def plant_csv(path, seed: int, off: float, noise: float, noise_seed: int | None = None, steps: int = STEPS) -> dict:
    """A run of the circuit, its parameters each off by up to ``off``
    (relative), its noise ``noise`` times the model's (per step: the
    compiled model's declared standard deviations), written as a logger's
    CSV; returns the plant's parameters. ``noise_seed``: another recording
    of the same plant (the parameters are the seed's, the noise this seed's)."""
    rng = np.random.default_rng(seed)
    p = {k: v * (1 + rng.uniform(-off, off)) for k, v in NOMINAL.items()}
    if noise_seed is not None:
        rng = np.random.default_rng([seed, noise_seed])
    e, process, sensor = circuit(p, noise)
    x, lines = np.array(START), ["time,u:V,y:f2,y:f6,y:e11"]
    for k in range(1, steps + 1):
        x = e[:3, :3] @ x + e[:3, 3] * V + process * rng.standard_normal(3)
        y = readings(p, x, V) + sensor * rng.standard_normal(3)
        lines.append(",".join(f"{v:.6g}" for v in (k * DT, V, *y)))
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return p


def circuit(p: dict, noise: float) -> tuple[np.ndarray, np.ndarray, float]:
    """The circuit of parameters ``p`` over one sample period: the matrix
    exponential of its equations augmented by a constant source (Van Loan's
    block: ``e[:3, :3]`` moves the state, ``e[:3, 3]`` times V adds the
    source's share), and its process stds (e4, e8, f10) and sensor std,
    ``noise`` times the model's."""
    nominal = session("circuit").package.MODELS["nominal"]
    a = np.array([[-(1 / p["R2"] + 1 / p["R1"]) / p["C1"], 1 / (p["R2"] * p["C1"]), 0.0],
                  [1 / (p["R2"] * p["C2"]), -1 / (p["R2"] * p["C2"]), -1 / p["C2"]],
                  [0.0, 1 / p["L"], -p["R3"] / p["L"]]])
    block = np.zeros((4, 4))
    block[:3, :3], block[0, 3] = a, 1 / (p["R1"] * p["C1"])
    std = dict(zip(nominal.STATES, np.asarray(nominal.PROCESS_STD, dtype=float)))
    process = noise * np.array([std["e4"], std["e8"], std["f10"]])
    sensor = noise * dict(zip(nominal.OUTPUTS, np.asarray(nominal.MEASUREMENT_STD, dtype=float)))["f2"]
    return expm(block * DT), process, sensor


def readings(p: dict, x: np.ndarray, v: float) -> np.ndarray:
    """f2, f6 and e11 of state ``x`` (e4, e8, f10) with the source at ``v``."""
    return np.array([(v - x[0]) / p["R1"], (x[0] - x[1]) / p["R2"], p["R3"] * x[2]])


def test_the_models_sensors_share_one_noise_level():  # plant_csv draws every sensor at f2's level
    nominal = session("circuit").package.MODELS["nominal"]
    assert len(set(np.asarray(nominal.MEASUREMENT_STD, dtype=float).tolist())) == 1


@pytest.mark.slow
@pytest.mark.long
def test_a_plant_off_its_model_gets_mismatch_and_never_a_fault(tmp_path):
    # an alarm at t = 2, and at the data's start (bench/mismatch.py runs twelve: a sensor offset "since
    # t = 0.5" among them)
    for seed in (0, 4):
        plant_csv(tmp_path / "run.csv", seed, 0.03, 1.5)
        d = bgc.diagnose(fast_session("circuit"), tmp_path / "run.csv").diagnosis
        assert d.verdict == "mismatch", (seed, d.verdict, d.candidates)
        said = [e for e in d.events if type(e).__name__ == "Mismatched"]
        assert len(said) == 1 and "noise" in said[0].estimate
        assert d.fit.short or d.fit.findings


@pytest.mark.slow
def test_a_change_at_a_records_start_is_no_change_of_a_plant_off_its_model(tmp_path):
    """The circuit 3 % off its model at its own noise (bench/watched_change_null.py
    off's run of seed 2), 2100 samples kept 1024 steps: no test of the
    detector alarms; the record, tested when it holds 2048 samples, fails
    the test of the fit (e11's residuals average -0.14 stds), and its
    residuals' change point falls 18 samples in, where the observer has
    just settled. Those 18 samples cannot vouch for the model: under it
    and like the data after it they are about as likely (an offset of 0.14
    stds over 18 samples is worth a fraction of a nat, not the log of the
    Bayes factor). It was taken for a change, an alarm raised there, and
    the diagnosis said "ambiguous: e11_offset_bias, R3_abrupt"; now the
    record is a misfit, said at t = 102.4, and no fault is named."""
    from bgc.diagnosis.options import DiagnosisOptions

    plant_csv(tmp_path / "run.csv", 502, 0.03, 1.0, steps=2100)
    d = bgc.diagnose(fast_session("circuit"), tmp_path / "run.csv",
                     options=DiagnosisOptions(keep=1024 * DT, filter="ckf", workers=1)).diagnosis
    assert d.detection is None and d.verdict in ("mismatch", "no fault") and d.candidates == (), (d.verdict,
                                                                                                  d.candidates)
    said = [e for e in d.events if type(e).__name__ == "Mismatched" and e.said is not None]
    assert [(e.said, e.span) for e in said] == [(102.4, (0.05, 102.4, 2048))], d.events
    assert not any(type(e).__name__ == "ChangeMissed" for e in d.events)


@pytest.mark.slow
def test_a_fault_named_after_a_misfit_said_on_data_before_it_is_a_possibility_beside_the_mismatch(tmp_path):
    """The same circuit's plant of seed 6: its record, tested when it holds
    2048 samples (t = 0.05 to 102.4), fails the test of the fit (e11's
    residuals average +0.12 stds) and is said off the model, then halved;
    at the next sample the detector's mean test alarms (a window of 32
    samples). The record kept (from t = 51.25) fits before the fault's
    onset (t = 90.45) at the end's level, and L's faults were named
    "ambiguous". But most of the data the misfit was said on (t = 0.05 to
    90.45 of 102.4) precede that onset: the model did not fit the plant
    before the fault. The verdict is mismatch, L's faults possibilities,
    the misfit said carrying them."""
    from bgc.diagnosis.options import DiagnosisOptions

    plant_csv(tmp_path / "run.csv", 506, 0.03, 1.0, steps=2100)
    d = bgc.diagnose(fast_session("circuit"), tmp_path / "run.csv",
                     options=DiagnosisOptions(keep=1024 * DT, filter="ckf", workers=1)).diagnosis
    assert d.detection is not None and d.detection.test == "mean"
    assert d.verdict == "mismatch" and d.candidates, (d.verdict, d.candidates)  # faults named: possibilities
    said = [e for e in d.events if type(e).__name__ == "Mismatched" and e.said is not None]
    assert [(e.said, e.span, e.possible) for e in said] == [(102.4, (0.05, 102.4, 2048), d.candidates)], said
    assert float(d.time[d.onset_step]) - 0.05 >= 0.5 * (102.4 - 0.05)  # most of its data before the onset


@pytest.mark.slow
def test_the_same_simulator_with_the_models_numbers_gives_no_fault(tmp_path):
    """The test is no alarm on everything another simulator makes: with the
    model's parameters and noise, its runs fit (two seeds; the rate over
    many: ``bench/mismatch.py --runs 12``'s column of the model's own
    numbers, and ``--null`` on bgc's own runs)."""
    for seed in range(2):
        plant_csv(tmp_path / "run.csv", seed, 0.0, 1.0)
        d = bgc.diagnose(fast_session("circuit"), tmp_path / "run.csv").diagnosis
        assert d.verdict == "no fault", (seed, d.verdict, d.fit.findings)
        assert d.fit.fits and d.fit.end == STEPS


@pytest.mark.slow
def test_a_fault_since_the_first_samples_is_a_possibility_beside_the_mismatch(tmp_path):
    """R3 a fifth higher in the plant from its start: data that a fault at
    the start and a model that does not fit make alike; the diagnosis says
    mismatch, R3's fault among its possibilities."""
    nominal = dict(NOMINAL)
    try:
        NOMINAL["R3"] = 1.2
        plant_csv(tmp_path / "run.csv", 3, 0.0, 1.0)
    finally:
        NOMINAL.clear()
        NOMINAL.update(nominal)
    d = bgc.diagnose(fast_session("circuit"), tmp_path / "run.csv").diagnosis
    assert d.verdict == "mismatch"
    assert d.detection is not None and d.fit.short
    assert any(name.startswith("R3") for name in d.candidates), d.candidates
    said = next(e for e in d.events if type(e).__name__ == "Mismatched")
    assert said.possible == d.candidates and "R3" in said.estimate


def test_the_fit_findings_against_their_closed_forms():
    """The mean's and variance's tests of :func:`bgc.filters.residuals.findings`
    at their Bonferroni level, on series whose statistics are known exactly."""
    n, level = 400, 0.001
    cut = norm.isf(level / (2 * 2) / 2)  # two sensors, two tests each, two-sided
    base = np.tile([1.0, -1.0], n // 2)  # mean 0, variance 1 exactly
    just_over = cut / math.sqrt(n) * 1.01
    shifted = np.column_stack([base + just_over, base])
    said = residuals.findings(residuals.summary([shifted], ("a", "b")), level, correlation=False)
    assert len(said) == 1 and said[0].startswith("sensor a's residuals average")
    under = np.column_stack([base + cut / math.sqrt(n) * 0.99, base])
    assert residuals.findings(residuals.summary([under], ("a", "b")), level, correlation=False) == ()
    # the variance, about the mean (n - 1 degrees of freedom), just beyond the chi-square's quantile each side
    tail = level / (2 * 2) / 2
    scale = math.sqrt(chi2.isf(tail, n - 1) / n * 1.01)
    wide = np.column_stack([base, base * scale])
    said = residuals.findings(residuals.summary([wide], ("a", "b")), level, correlation=False)
    assert len(said) == 1 and "sensor b's residuals have variance" in said[0]
    within = np.column_stack([base, base * math.sqrt(chi2.isf(tail, n - 1) / n * 0.99)])
    assert residuals.findings(residuals.summary([within], ("a", "b")), level, correlation=False) == ()
    within = np.column_stack([base, base * math.sqrt(chi2.ppf(tail, n - 1) / n * 1.01)])
    assert residuals.findings(residuals.summary([within], ("a", "b")), level, correlation=False) == ()
    narrow = np.column_stack([base, base * math.sqrt(chi2.ppf(tail, n - 1) / n * 0.99)])
    assert len(residuals.findings(residuals.summary([narrow], ("a", "b")), level, correlation=False)) == 1
    # the diagnosis's test: a variance under 1 (a filter more cautious than the plant) is no misfit
    assert residuals.findings(residuals.summary([narrow], ("a", "b")), level, correlation=False,
                              narrower=False) == ()


def test_the_fit_takes_the_data_before_the_onset_only():
    """fit() tests steps 0 .. end - 1: a jump after ``end`` is not seen."""
    nominal = session("circuit").package.MODELS["nominal"]
    run = bgc.simulate(session("circuit"), "none", seed=2).run
    ys = np.column_stack([run.measurements[y] for y in nominal.OUTPUTS])
    us = np.column_stack([run.inputs[u] for u in nominal.INPUTS])
    ys[150:] += 1.0  # twenty sensor stds from step 150 on
    assert fit_module.fit(nominal, ys, us, tuple(nominal.OUTPUTS), 150).findings == ()
    assert fit_module.fit(nominal, ys, us, tuple(nominal.OUTPUTS), 300).findings != ()


@pytest.mark.slow
def test_a_late_alarm_on_a_noisier_plant_is_a_mismatch_not_a_fault(tmp_path):
    """A plant 1.5 times noisier than its model whose alarm comes late (seed
    35's second recording: the alarm at t = 10.6, the drifts it names from
    t = 2.25): the 45 samples before the onset are too few to show the noise,
    but the named fault's own residuals after it have the variance of a noise
    1.5 times the model's (about 2.25, not 1), which no fault model explains:
    the verdict is mismatch, the faults kept as possibilities."""
    plant_csv(tmp_path / "run.csv", 35, 0.03, 1.5, noise_seed=1)
    d = bgc.diagnose(fast_session("circuit"), tmp_path / "run.csv").diagnosis
    assert d.verdict == "mismatch" and d.candidates, (d.verdict, d.candidates)
    wide = [f for f in d.fit.findings if f.startswith(f"with {d.candidates[0]}, ") and "variance" in f]
    assert wide, d.fit.findings
    said = [float(f.split("variance ")[1].split(" ")[0].rstrip(",")) for f in wide]
    assert all(1.5 < v < 3.4 for v in said), said  # 2.25 within its spread over some 250 samples


@pytest.mark.slow
@pytest.mark.long
def test_an_unexplained_alarm_on_a_noisier_plant_tests_the_model_up_to_the_change_point(tmp_path):
    """Seed 6's second recording (3 % off, noise 1.5 times the model's): the
    alarm at t = 3 on e11, no fault model explains the data, the closest a
    drift of C2 from t = 0.65. The stretch the verdict calls fault-free ends
    at the detector's change point (57 samples), not at that closest model's
    onset (12 samples, too few to show the noise: the verdict was
    "unexplained"): over it e11 and f6 fail the test, the verdict is
    mismatch, and no fault is kept as a possibility."""
    plant_csv(tmp_path / "run.csv", 6, 0.03, 1.5, noise_seed=1)
    d = bgc.diagnose(fast_session("circuit"), tmp_path / "run.csv").diagnosis
    assert (d.verdict, d.candidates) == ("mismatch", ()), (d.verdict, d.candidates)
    assert d.detection is not None and d.fit.end == d.detection.onset_step > 40
    assert any(f.startswith("sensor e11's residuals") for f in d.fit.findings), d.fit.findings


@pytest.mark.slow
@pytest.mark.long
def test_the_monitor_says_why_the_model_does_not_fit_at_its_first_mismatch_checkpoint(tmp_path):
    """The circuit 3 % off its model with 1.5 times its noise (plant_csv, the
    exact solution: not bgc's simulator), streamed by bgc monitor with a
    checkpoint every 3 s: the first checkpoint whose verdict is mismatch
    says at once why and what to do (the model does not fit, per sensor, and
    the calibration to run), once, long before the stream ends (t = 15);
    the later checkpoints say their verdict only, and the end says it again."""
    data = tmp_path / "plant.csv"
    plant_csv(data, 3, 0.03, 1.5)
    r = bgc_cli("monitor", "models/circuit.yaml", "--data", str(data), "--checkpoint", "3", *fast_backend("circuit"),
                "-o", str(tmp_path / "m"))
    assert r.returncode == 0, r.stderr
    lines = r.stdout.splitlines()
    first = next(i for i, line in enumerate(lines) if line.endswith("checkpoint: mismatch")
                 or ": checkpoint: mismatch" in line)
    said = [line for line in lines if "the model does not fit this plant" in line]
    assert lines[first + 1] == said[0] and "calibrate the model on healthy data (bgc calibrate" in said[0]
    when = float(said[0].split(":")[0].removeprefix("t = "))
    assert when < 10.0 and len(said) == 2 and said[1].startswith("t = 15: ")


@pytest.mark.slow
def test_the_monitor_says_a_misfit_while_watching_without_an_alarm(tmp_path):
    """The circuit with the model's parameters and 1.3 times its noise (the
    exact solution, seed 0): the detector never alarms (the residuals' mean
    stays in its bounds), but their variance is 1.6 to 2. A monitor with a
    checkpoint every 5 s tests the model's fit once, when its record
    reaches 5 s (100 samples), and says there that the model does not fit, with the
    calibration to run, before any alarm; it says it once more at the end,
    and nothing else is decided. With the model's own noise the same
    monitor says nothing of a misfit (one test per diagnoser: its level)."""
    data = tmp_path / "plant.csv"
    plant_csv(data, 0, 0.0, 1.3)
    r = bgc_cli("monitor", "models/circuit.yaml", "--data", str(data), "--checkpoint", "5", *fast_backend("circuit"),
                "-o", str(tmp_path / "m"))
    assert r.returncode == 0, r.stderr
    lines = r.stdout.splitlines()
    said = [line for line in lines if "the model does not fit this plant" in line]
    assert len(said) == 2 and said[0].startswith("t = 5: ") and said[1].startswith("t = 15: "), lines
    assert "variance" in said[0] and "bgc calibrate" in said[0]
    assert lines[lines.index(said[0]) - 1] == "t = 5: checkpoint: mismatch"
    assert not any("fault detected" in line or "alarm" in line for line in lines), lines
    plant_csv(data, 0, 0.0, 1.0)
    r = bgc_cli("monitor", "models/circuit.yaml", "--data", str(data), "--checkpoint", "5", *fast_backend("circuit"),
                "-o", str(tmp_path / "n"))
    assert r.returncode == 0 and "does not fit" not in r.stdout and "circuit: no fault" in r.stdout, r.stdout
