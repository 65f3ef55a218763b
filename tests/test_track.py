"""End to end: truth from the simulator (sympy, 8x finer RK4), filters from the
committed generated package, fault injected, estimates and residuals checked."""

import numpy as np
import pytest

from bgc.data import runs
from bgc.analysis import simulate as sim
from bgc.model import package as runtime
from bgc.analysis import track
from bgc.filters import registry
from bgc.model import protocol

from conftest import ROOT, bgc_cli, compiled


def run_of(model: str, fault: str | None, seed: int) -> runs.Run:
    num = compiled(model).numerics
    options = sim.SimulationOptions(seed=seed, fault=sim.parse_fault(fault, num) if fault else None)
    return runs.parse_run(sim.to_csv(sim.simulate(num, options)))


def normalised_residuals(r: track.TrackResult, run: runs.Run) -> np.ndarray:
    y = np.column_stack([run.measurements[name] for name in r.output_names])
    return (y - r.y_mean) / r.y_std


@pytest.fixture(scope="module")
def ro():
    return runtime.load_package(ROOT / "generated", "ro")


@pytest.mark.parametrize("method", ["gpf", "apf"])
def test_ro_membrane_abrupt_fault_is_identified(ro, method):
    """R_memb 26 -> 50 at t = 165 (thesis Table IV.3: GPF 45.73, APF 47.92): after
    the hand-over at t = 167 the faulty-model filter ends within 5 % of 50."""
    run = run_of("ro", "R_memb:abrupt:24@165", seed=5)
    r = track.track(run, ro, "R_memb_abrupt", method, 200, seed=0, start=167)
    k = r.state_names.index("delta_R_memb")
    estimate = 26.0 + r.mean[-20:, k].mean()
    assert abs(estimate - 50.0) < 0.05 * 50.0, estimate
    assert np.isnan(r.mean[: 166, k]).all() and np.isfinite(r.mean[166:, k]).all()


def test_ro_nominal_filter_is_consistent_without_fault_and_not_after_one(ro):
    """No fault: the nominal filter's normalised residuals (y - predicted y) /
    predicted std have mean square about 1, so a detector on them stays quiet.
    After an R_pipe abrupt fault (69 -> 100 at t = 165) the loop-flow residual
    leaves that band: its mean square over t > 170 is many times larger."""
    quiet = normalised_residuals(track.track(run_of("ro", None, seed=3), ro, "nominal", "gpf", 200, 0),
                                 run_of("ro", None, seed=3))
    assert np.all(np.mean(quiet[20:] ** 2, axis=0) < 2.0), np.mean(quiet[20:] ** 2, axis=0)
    faulty = run_of("ro", "R_pipe:abrupt:31@165", seed=3)
    r = track.track(faulty, ro, "nominal", "gpf", 200, 0)
    z = normalised_residuals(r, faulty)
    loop = r.output_names.index("F_loop")
    assert np.mean(z[166:175, loop] ** 2) > 10 * np.mean(quiet[20:, loop] ** 2)


def test_every_registered_filter_tracks_the_nominal_model_through_the_one_protocol(ro):
    """The registry names each filter once; track() builds and runs any of
    them alike: the ckf, as the particle filters, has white normalised
    residuals without a fault. A hand-over needs a particle cloud: ckf with
    start is refused."""
    from bgc.errors import TrackingError
    from bgc.filters import Filter
    from bgc.filters.cubature import CubatureKalmanFilter

    assert registry.filter_class(ro, "ckf") is CubatureKalmanFilter
    run = run_of("ro", None, seed=3)
    for method in registry.FILTER_CLASSES:
        assert isinstance(registry.filter_class(ro, method)(ro.nominal, 20, np.random.default_rng(0)), Filter)
    r = track.track(run, ro, "nominal", "ckf", 200, 0)
    z = normalised_residuals(r, run)
    assert np.all(np.abs(np.mean(z[20:] ** 2, axis=0) - 1.0) < 0.5), np.mean(z[20:] ** 2, axis=0)
    assert np.isinf(r.ess).all() and r.recoveries == 0
    with pytest.raises(TrackingError, match="ckf has none"):
        track.track(run, ro, "R_pipe_abrupt", "ckf", 200, 0, start=167)
    with pytest.raises(TrackingError, match="unknown filter 'kf'.*gpf, apf, opf, ckf"):
        registry.filter_class(ro, "kf")


def test_the_true_fault_model_explains_the_data_better_than_a_wrong_one(ro):
    """Thesis Fig. IV.6: after the hand-over, the filter on the true fault model
    (R_pipe incipient) predicts the measurements better than the one on a wrong
    hypothesis (R_fp incipient)."""
    run = run_of("ro", "R_pipe:incipient:0.5@165", seed=1)
    right = track.track(run, ro, "R_pipe_incipient", "gpf", 200, 0, start=167)
    wrong = track.track(run, ro, "R_fp_incipient", "gpf", 200, 0, start=167)
    late = slice(200, None)
    right_ms = np.mean(normalised_residuals(right, run)[late] ** 2)
    wrong_ms = np.mean(normalised_residuals(wrong, run)[late] ** 2)
    assert right_ms < 1.3 and right_ms < 0.7 * wrong_ms, (right_ms, wrong_ms)


def test_circuit_abrupt_fault_on_r2_is_identified():
    pkg = runtime.load_package(ROOT / "generated", "circuit")
    run = run_of("circuit", "R2:abrupt:1.0@5", seed=1)
    r = track.track(run, pkg, "R2_abrupt", "apf", 300, seed=0, start=5.1)
    k = r.state_names.index("delta_R2")
    assert abs(2.0 + r.mean[-1, k] - 3.0) < 0.15


def test_cli_filter_prints_the_estimate_and_refuses_bad_options(tmp_path):
    csv = tmp_path / "run.csv"
    assert bgc_cli("simulate", "models/circuit.yaml", "--fault", "R2:abrupt:1.0@5", "--seed", "1", "-o",
                   csv).returncode == 0
    out = bgc_cli("filter", "models/circuit.yaml", csv, "--fault", "R2:abrupt", "--start", "5.1", "--filter", "gpf",
                  "--plot", tmp_path / "p.png")
    assert out.returncode == 0, out.stderr
    assert "estimate of R2 = 2 + delta" in out.stdout and "(true 3," in out.stdout
    assert (tmp_path / "p.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    for bad in (["--particles", "0"], ["--start", "3"]):
        r = bgc_cli("filter", "models/circuit.yaml", csv, *bad)
        assert r.returncode == 1 and "Traceback" not in r.stderr and r.stderr.count("\n") == 1, r.stderr


@pytest.mark.parametrize("name, magnitude", [("cd_abrupt", 0.3), ("cd_incipient", 0.002)])
def test_the_transition_into_an_onset_sample_is_nominal_and_keeps_the_magnitude(name, magnitude):
    """A fault with onset k changes the parameter at the instant of sample k
    (the thesis's DBN: the parameter of slice k enters y_k and the transition
    out of k): the fault filter's particles make the nominal transition into
    sample k, and keep their magnitude (a bias, a slope) for the next ones;
    a drifting parameter's own state stays nominal."""
    from conftest import session

    package = runtime.load_package(session("orifice_tanks").folder, "orifice_tanks")
    nominal, fault = package.MODELS["nominal"], package.MODELS[name]
    rng = np.random.default_rng(8)
    physical = nominal.X0[:, None] * (1.0 + 0.1 * rng.standard_normal((len(nominal.STATES), 5)))
    x = fault.augment(physical.copy(), rng)
    x[-1] = magnitude
    before = x.copy()
    u = nominal.inputs(0.0)
    protocol.onset_transition(fault, x, u, fault.THETA)
    want = nominal.predict(physical.copy(), u, nominal.THETA, nominal.DT)
    np.testing.assert_allclose(x[:len(nominal.STATES)], want, rtol=1e-13)
    np.testing.assert_array_equal(x[len(nominal.STATES):], before[len(nominal.STATES):])
    moved = fault.predict(before.copy(), u, fault.THETA, fault.DT)  # with the fault in: not the same
    assert np.abs(moved[:len(nominal.STATES)] - want).max() > 1e-4


def test_a_models_own_package_folder_given_as_the_root_is_named_with_its_parent(tmp_path, capsys):
    """--generated generated/ro (one model's folder) instead of generated/:
    the fix names the folder to give, not a compile that would nest it."""
    from bgc import cli

    code = cli.main(["diagnose", str(ROOT / "models" / "ro.yaml"), "--scenario", "none", "--generated",
                     str(ROOT / "generated" / "ro"), "-o", str(tmp_path / "d")])
    err = capsys.readouterr().err
    assert code == 1 and "is the folder of one model's package" in err
    assert f"point --generated at the folder bgc compile -o wrote: {ROOT / 'generated'}" in err


def test_data_messages_name_the_run_by_its_source(ro):
    """A run's messages name where it comes from: its file, a scenario, or a
    Run built in Python."""
    from bgc.errors import DataError

    run = runs.parse_run("# model ro: 2 steps\ntime,y:F_loop\n1,2\n2,3\n", "lab/ro run.csv")
    with pytest.raises(DataError, match=r"^lab/ro run.csv: the run has no column y:"):
        track.run_arrays(run, ro, "nominal")
    with pytest.raises(DataError, match=r"^lab/ro run.csv is a run of model 'ro', not of 'circuit'"):
        track.check_run_of(run, "circuit")
    python = runs.Run(run.time, {}, {}, {}, {}, ("model ro: x",))
    with pytest.raises(DataError, match=r"^<Run from Python> is a run of model 'ro'"):
        track.check_run_of(python, "circuit")
    with pytest.raises(DataError, match=r"^given.csv is a run of model 'ro'"):
        track.check_run_of(python, "circuit", "given.csv")
