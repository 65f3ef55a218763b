"""The diagnosis made of a plant's submodels (issue 49, point 4;
:mod:`bgc.diagnosis.decomposed`, :mod:`bgc.model.joined`).

The joined model's likelihood is checked against the product of its parts'
(independent given the readings), the sign of a read sensor's bias against
the input it shifts (derived by hand), and the verdicts and estimates on data
of a chain of tanks simulated by solve_ivp on its equations derived by hand
(tests/chain_reference.py), a fault the model does not list among them."""

from __future__ import annotations

import numpy as np
import pytest

import bgc
from bgc.diagnosis import decomposed
from bgc.diagnosis.options import DiagnosisOptions
from bgc.filters.cubature import nominal_track
from bgc.model.joined import Joined
from bgc.model.protocol import FaultModel, nominal_model
from bgc.pipeline import decompose_model

import chain_reference as chain
from conftest import bgc_cli

CKF = DiagnosisOptions(filter="ckf")


@pytest.fixture(scope="module")
def plan3(tmp_path_factory):
    """The chain of three tanks split into its three submodels, each opened as its own model file."""
    folder = tmp_path_factory.mktemp("chain3")
    path = folder / "chain3.yaml"
    path.write_text(chain.model_yaml(3))
    d = decompose_model(path)
    packages = []
    for s in d.decomposition.submodels:
        (folder / f"{s.name}.yaml").write_text(s.text)
        packages.append(bgc.open(str(folder / f"{s.name}.yaml")).package)
    return decomposed.plan(d, packages)


def test_plan_maps_each_fault_to_the_submodels_that_model_it(plan3):
    """A pipe's resistance is held by the tanks on both sides; a sensor's
    bias is its own submodel's, and the neighbours' input's with the
    opposite sign; a tank's capacity is its own tank's alone."""
    names = [part.name for part in plan3.parts]
    assert names == ["chain3_p1", "chain3_p2", "chain3_p3"]
    assert plan3.faults["R1_abrupt"].models == ((0, "R1_abrupt", 1), (1, "R1_abrupt", 1))
    assert plan3.faults["C2_abrupt"].models == ((1, "C2_abrupt", 1),)
    assert plan3.faults["p2_offset_bias"].models == ((0, "p2_offset_bias", -1), (1, "p2_offset_bias", 1),
                                                     (2, "p2_offset_bias", -1))
    assert plan3.faults["p2_offset_bias"].prior[0] == -plan3.faults["p2_offset_bias"].prior[1]


def test_joined_likelihood_is_the_product_of_its_parts(plan3):
    """Independent given the readings: the joined nominal filter's
    log-likelihood is the sum of the parts' filters', its predictions their
    predictions side by side."""
    t, y = chain.run(3, "R2:0.4", seed=3)
    data = decomposed._data(chain.as_run(t, y), plan3, CKF)
    T = len(data.time)
    tracks = [nominal_track(part.nominal, ys, us, T) for part, ys, us in zip(plan3.parts, data.ys, data.us)]
    joined = Joined("all", [part.nominal for part in plan3.parts])
    assert isinstance(joined, FaultModel)
    track = nominal_track(joined, np.concatenate(data.ys, axis=1), np.concatenate(data.us, axis=1), T)
    assert track.loglik[T] == pytest.approx(sum(tr.loglik[T] for tr in tracks), rel=1e-9)
    np.testing.assert_allclose(track.y_mean, np.concatenate([tr.y_mean for tr in tracks], axis=1), rtol=1e-9)
    stacked = decomposed.stacked(tracks)
    np.testing.assert_allclose(stacked.loglik, track.loglik, rtol=1e-9)


def test_read_sensor_bias_shifts_the_neighbours_input_by_minus_the_bias(plan3):
    """Sensor p2 reading b too high: tank 1's submodel reads p2 as the
    pressure beyond pipe 1, so under the joined model it must step as its
    nominal model does with the reading lowered by b; tank 2's own
    submodel predicts its reading b higher."""
    f = plan3.faults["p2_offset_bias"]
    parts = [plan3.parts[i] for i, _, _ in f.models]
    joined = Joined(f.name, [part.package.MODELS[m] for part, (_, m, _) in zip(parts, f.models)],
                    [s for _, _, s in f.models], decomposed._fault(plan3, f), f.prior)
    b = 0.3
    x = np.array([[3.1], [2.0], [1.05], [b]])  # p1, p2, p3, the bias
    u = np.array([1.0, 2.2, 2.1, 1.1, 2.3])  # tank 1: f_in, p2 read; tank 2: p1, p3 read; tank 3: p2 read
    moved = joined.predict(x.copy(), u, joined.THETA, joined.DT)
    tank1 = parts[0].nominal
    lowered = np.array([1.0, 2.2 - b])
    expected = tank1.predict(x[:1].copy(), lowered, tank1.THETA, tank1.DT)
    assert moved[0, 0] == pytest.approx(expected[0, 0], rel=1e-12)
    tank3 = parts[2].nominal
    expected3 = tank3.predict(x[2:3].copy(), np.array([2.3 - b]), tank3.THETA, tank3.DT)
    assert moved[2, 0] == pytest.approx(expected3[0, 0], rel=1e-12)
    assert moved[3, 0] == b  # the bias holds
    seen = joined.observe(x, u, joined.THETA)
    assert seen[1, 0] == pytest.approx(2.0 + b)  # tank 2's sensor reads its pressure plus the bias
    assert seen[0, 0] == pytest.approx(3.1) and seen[2, 0] == pytest.approx(1.05)


def test_held_reading_is_the_mean_of_a_samples_two_readings():
    """A reading read as an input is held over the sample that ends at a row
    at the mean of that row's and the one before; a missing reading is the
    last one read."""
    np.testing.assert_allclose(decomposed.held(np.array([1.0, 3.0, np.nan, 5.0])), [1.0, 2.0, 3.0, 4.0])


@pytest.mark.parametrize("fault, name, truth", [
    ("R2:0.5", "R2_abrupt", 0.5),
    ("p2:0.3", "p2_offset_bias", 0.3),
    ("R3:-0.4", "R3_abrupt", -0.4),
])
def test_isolates_and_sizes_a_listed_fault(plan3, fault, name, truth):
    """Data of solve_ivp with the sensors 0.7 times as noisy as the model
    says: the fault is isolated with its magnitude's 95 % interval around
    the truth."""
    t, y = chain.run(3, fault, seed=1)
    d = decomposed.diagnose(chain.as_run(t, y), plan3, CKF)
    assert (d.verdict, d.candidates) == ("isolated", (name,))
    h = next(h for h in d.hypotheses if h.name == name)
    assert h.estimate.low <= truth <= h.estimate.high
    assert abs(d.time[d.onset_step] - 50.0) <= 2.0


def test_a_fault_the_model_does_not_list_is_unexplained(plan3):
    """A leak from tank 2 (an outflow the model has no element for): no
    listed fault explains every sensor; the verdict is not "isolated"."""
    t, y = chain.run(3, "leak2:0.3", seed=0)
    d = decomposed.diagnose(chain.as_run(t, y), plan3, CKF)
    assert d.verdict == "unexplained"


def test_fault_free_and_the_run_length(plan3):
    """A fault-free run: no alarm, and the model fits the data."""
    t, y = chain.run(3, "none", seed=2)
    d = decomposed.diagnose(chain.as_run(t, y), plan3, CKF)
    assert d.verdict == "no fault" and d.detection is None and d.fit.fits
    assert len(d.time) == chain.STEPS and d.outputs == ("p1", "p2", "p3")
    assert d.hypotheses == ()


def test_refuses_data_without_a_read_sensor(plan3):
    """A submodel that reads a sensor the data lack cannot run: one line naming the column and the submodel."""
    t, y = chain.run(3, "none", seed=0)
    run = chain.as_run(t, y)
    del run.measurements["p2"]
    with pytest.raises(bgc.DataError, match=r"no column y:p2, which submodel chain3_p1 reads"):
        decomposed.diagnose(run, plan3, CKF)


@pytest.fixture(scope="module")
def chain4(tmp_path_factory):
    path = tmp_path_factory.mktemp("chain4") / "chain4.yaml"
    path.write_text(chain.model_yaml(4))
    return path


@pytest.mark.parametrize("fault, name", [("p1:0.3", "p1_offset_bias"), ("p2:0.15", "p2_offset_bias")])
def test_whole_plant_ckf_finds_a_bias_between_its_first_grids_points(chain4, fault, name):
    """The whole plant's ``--filter ckf`` lays its first grid over the
    bias's whole prior (points 1.2 apart on tank 2's sensor): a bias of
    0.15 lies between two points, the best point (0) fails the fit test
    far, and the search gave up after that pass, naming another fault or
    none ("unexplained"; "isolated R1_abrupt" for p1's). The far-off test
    now waits for a grid fine enough to tell (static_posterior.COARSE)."""
    t, y = chain.run(4, fault, seed=0)
    d = bgc.diagnose(str(chain4), chain.as_run(t, y), filter="ckf").diagnosis
    assert (d.verdict, d.candidates) == ("isolated", (name,))


@pytest.mark.slow
@pytest.mark.long
def test_the_submodels_alarm_where_the_whole_plant_does(chain4, seed=3):
    """The detector watches the whole plant's nominal filter (the model
    without its faults), so the decomposed diagnosis alarms at the sample
    and on the sensor the whole plant's ``--filter ckf`` diagnoser does
    (stepped row by row to its alarm), on a leak of 0.05 from tank 2
    (outside the model): the submodels' own residuals, wider (each reads
    its neighbours' noisy readings), alarmed 50 samples later on this run
    (17 to 50 on seeds 0 to 3). The report's residuals are the whole
    plant's filter's, which the detector read."""
    import dataclasses

    from bgc import events
    from bgc.api.decomposed import open_plan

    t, y = chain.run(4, "leak2:0.05", seed=seed)
    run = chain.as_run(t, y)
    plan = open_plan(str(chain4))
    whole_nominal = nominal_model(plan.whole)  # the four tanks' pressures, no fault state
    assert (len(whole_nominal.STATES), whole_nominal.OUTPUTS) == (4, ("p1", "p2", "p3", "p4"))
    split = decomposed.diagnose(run, plan, DiagnosisOptions(no_fault=False)).detection
    d = bgc.open(str(chain4)).diagnoser(DiagnosisOptions(filter="ckf", workers=1))
    alarm = None
    for k, time in enumerate(run.time):
        belief = d.step(time, {"f_in": run.inputs["f_in"][k]}, {s: run.measurements[s][k] for s in run.measurements})
        alarm = next((e for e in belief.events if isinstance(e, events.Alarmed)), None)
        if alarm is not None:
            break
    assert alarm is not None and (split.sensor, split.step) == (alarm.sensor, alarm.step), (split, alarm)
    parts_alone = decomposed.diagnose(run, dataclasses.replace(plan, whole=None),
                                      DiagnosisOptions(no_fault=False)).detection
    assert parts_alone is None or parts_alone.step > split.step, (parts_alone, split)


@pytest.mark.long
@pytest.mark.slow
def test_api_and_cli_diagnose_on_the_submodels(chain4, tmp_path):
    """``bgc.diagnose(..., decompose=True)`` and ``bgc diagnose --decompose``:
    the plan's verdict, a report that says what was weighed in place of
    the signatures, and the submodels in report.json."""
    t, y = chain.run(4, "R2:0.5", seed=2)
    run = chain.as_run(t, y)
    r = bgc.diagnose(str(chain4), run, decompose=True)
    assert (r.diagnosis.verdict, r.diagnosis.candidates) == ("isolated", ("R2_abrupt",))
    assert r.diagnosis.submodels == ("chain4_p1", "chain4_p2", "chain4_p3", "chain4_p4")
    data = tmp_path / "run.csv"
    from bgc.data.runs import run_csv
    data.write_text(run_csv(run))
    out = tmp_path / "report"
    done = bgc_cli("diagnose", chain4, "--data", data, "--decompose", "-o", out)
    assert done.returncode == 0, done.stderr
    assert "isolated: R2_abrupt" in done.stdout
    text = (out / "report.md").read_text()
    assert "## Isolation on the submodels" in text and "TRANSCEND" not in text
    import json
    assert json.loads((out / "report.json").read_text())["settings"]["submodels"][0] == "chain4_p1"


def test_decompose_refuses_what_it_cannot_do(chain4):
    """Particle filters, other noise levels: one line each, no traceback."""
    done = bgc_cli("diagnose", chain4, "--scenario", "none", "--decompose", "--filter", "apf")
    assert done.returncode != 0 and "Traceback" not in done.stderr
    assert "--decompose with --filter apf" in done.stderr and len(done.stderr.strip().splitlines()) == 1
    with pytest.raises(bgc.ArgumentValueError, match="decompose=True with process_noise="):
        bgc.diagnose(str(chain4), scenario="none", decompose=True, process_noise=0.01)


@pytest.mark.slow
@pytest.mark.long
def test_a_leak_its_tanks_sensor_bias_mimics_is_unexplained(tmp_path):
    """A quarter of the inflow leaking from tank 3 of six: in tank 3's own
    submodel a negative bias of its sensor mimics it, and the windowed test
    passes it (the submodels' residuals are wide: "isolated: p3_offset_bias"
    on this run before stretch_tested); over the stretch from the onset its
    neighbours' residuals stay off 0, and the verdict is "unexplained" as
    the whole plant's is."""
    import math
    model = tmp_path / "chain6.yaml"
    model.write_text(chain.model_yaml(6))
    p3 = chain.steady(6)[2]
    t, y = chain.run(6, f"leak3:{0.25 * chain.F_IN / math.sqrt(p3):.6g}", seed=1)
    d = bgc.diagnose(str(model), chain.as_run(t, y), decompose=True).diagnosis
    assert d.verdict == "unexplained"
    bias = next(h for h in d.hypotheses if h.name == "p3_offset_bias")
    assert bias.drop is not None and bias.drop.code == "static-test" and bias.static_alarm.window > 32


def test_noisier_sensors_than_the_model_says_are_a_mismatch(chain4):
    """Sensors 1.3 times as noisy as the model says: the fault's residuals
    after its onset are too wide, which is noise the model lacks, said as
    "mismatch" with the fault named as a possibility (the whole plant's
    verdict), not "unexplained"."""
    t, y = chain.run(4, "R2:0.5", seed=1, noise=0.013)
    d = bgc.diagnose(str(chain4), chain.as_run(t, y), decompose=True).diagnosis
    assert d.verdict == "mismatch" and "R2_abrupt" in d.candidates


def test_a_reading_is_read_at_its_rows_time_whatever_the_inputs_timing(plan3):
    """With ``input_timing="start"`` a row's input acts over the step that
    starts at it; a reading read as an input is a measurement at its row's
    time all the same, so every step gets the same held reading as with
    ``end`` (the first step's, before any reading, aside)."""
    from dataclasses import replace

    t, y = chain.run(3, "R2:0.5", seed=0)
    run = chain.as_run(t, y)
    end = decomposed._data(run, plan3, CKF)
    start = decomposed._data(run, plan3, replace(CKF, input_timing="start"))
    for a, b, part in zip(end.us, start.us, plan3.parts):
        read = [j for j, u in enumerate(part.nominal.INPUTS) if u != "f_in"]
        np.testing.assert_allclose(a[1:, read], b[1:, read], rtol=1e-12)


def test_refuses_what_it_does_not_weigh(plan3, chain4):
    """A read sensor without a reading, and the particle filters' ranking and refining: one line each."""
    t, y = chain.run(3, "none", seed=0)
    run = chain.as_run(t, y)
    run.measurements["p2"] = np.full(len(t), np.nan)
    with pytest.raises(bgc.DataError, match=r"column y:p2, which submodel chain3_p1 reads as an input, has no"):
        decomposed.diagnose(run, plan3, CKF)
    with pytest.raises(bgc.ArgumentValueError, match="decompose=True with refine"):
        bgc.diagnose(str(chain4), scenario="none", decompose=True, options=DiagnosisOptions(refine=True))
