"""The generated models of a model with modes (bgc/compiler/hybrid_codegen.py):
each mode's step against the relay circuit's equations derived by hand, the
resets and idle states of a change of mode, and the filters through the
switches of a run made by an independent simulator (solve_ivp, with events:
tests/hybrid_reference.py)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from bgc import pipeline
from bgc.compiler import printing
from bgc.filters import cubature
from bgc.model.package import load_package

from conftest import bgc_cli
from hybrid_reference import C, DT, R_load, V, derivative, sampled

ROOT = Path(__file__).resolve().parent.parent
RELAY = ROOT / "tests" / "data" / "hybrid" / "relay_rl.yaml"


@pytest.fixture(scope="module")
def folder(tmp_path_factory):
    out = tmp_path_factory.mktemp("generated")
    done = bgc_cli("compile", RELAY, "-o", out, "--no-pictures")
    assert done.returncode == 0, done.stderr
    return out


@pytest.fixture(scope="module")
def package(folder):
    return load_package(folder, "relay_rl")


def exact_step(mode: str, x0, dt: float = DT) -> np.ndarray:
    """(i, v) after ``dt`` in ``mode`` from ``x0``, by solve_ivp on the hand-derived equations."""
    sol = solve_ivp(lambda t, x: derivative(mode, x), (0.0, dt), list(x0), rtol=1e-12, atol=1e-14)
    return sol.y[:, -1]


def test_the_folder_has_each_modes_stages_and_one_package_across_the_modes(folder):
    root = folder / "relay_rl"
    for mode in ("open", "closed", "unpowered"):
        assert (root / "modes" / mode / "equations.txt").exists()
        assert (root / "modes" / mode / "dbn" / "nominal.json").exists()
    assert (root / "numpy_model" / "_m3_R_load_abrupt.py").exists()
    assert (root / "numba_model" / "_jit__m2_nominal.py").exists()
    again = bgc_cli("compile", "--check", RELAY, "-o", folder)
    assert again.returncode == 0 and "up to date" in again.stdout, again.stderr


def test_the_model_has_the_union_of_the_modes_states_then_the_mode(package):
    nominal = package.MODELS["nominal"]
    # the time in the mode too: the relay's supply closes again 5 s after it was tripped (a timed transition)
    assert nominal.STATES == ("f3", "e6", "mode", "dwell")
    assert nominal.STATE_KINDS == ("physical", "physical", "mode", "dwell")
    assert nominal.INPUTS == ("V", "mode") and nominal.MODES == ("open", "closed", "unpowered")
    fault = package.MODELS["R_load_abrupt"]
    assert fault.STATES == ("f3", "e6", "mode", "dwell", "delta_R_load")
    assert fault.X0[2] == 1.0 and fault.PROCESS_STD[2] == 0.0 and fault.X0_STD[2] == 0.0
    assert np.isnan(nominal.inputs(0.0)[-1])  # the data say the mode


@pytest.mark.parametrize("mode, number", [("open", 1), ("closed", 2), ("unpowered", 3)])
def test_each_mode_steps_as_its_hand_derived_equations(package, mode, number):
    nominal = package.MODELS["nominal"]
    starts = [(0.0, 0.0), (3.0, 5.0), (7.5, 6.2)]
    x = np.array([[i for i, _ in starts], [v for _, v in starts], [number] * 3, [0.0] * 3], dtype=float)
    if mode == "unpowered":
        x[0] = 0.0  # the coil carries no current with the supply off
    got = nominal.predict(x, np.array([V, number]), nominal.THETA, DT)
    for k in range(3):
        want = exact_step(mode, x[:2, k])
        # RK4 over one sample (|lambda| DT < 0.05): its local error is about 1e-9 of the state
        assert got[:2, k] == pytest.approx(want, rel=1e-7, abs=1e-9)
    assert np.all(got[2] == number)
    y = nominal.observe(got, np.array([V, number]), nominal.THETA)
    assert np.array_equal(y, got[:2])  # i_L = f3, v_C = e6 (no offset)


def test_a_change_of_mode_settles_the_idle_states_and_applies_the_transitions_resets(package):
    """A step integrates each particle in its mode, then moves it into the mode the data say at the
    sample (a run's row holds the state after the changes due at its time)."""
    nominal = package.MODELS["nominal"]
    theta = nominal.THETA
    # closed -> unpowered (no reset declared): a step of the closed relay, then the coil's current is no state
    # with the supply off: 0
    x = np.array([[4.0], [5.0], [2.0], [1.5]])
    after = nominal.predict(x, np.array([V, 3.0]), theta, DT)
    assert after[0, 0] == 0.0 and after[2, 0] == 3.0 and after[3, 0] == 0.0  # a new mode: no time in it yet
    assert after[1, 0] == pytest.approx(exact_step("closed", (4.0, 5.0))[1], rel=1e-7)
    # unpowered: the capacitor discharges through R_load alone, v(t) = v0 exp(-t / (R_load C))
    x = np.array([[0.0], [5.0], [3.0], [1.0]])
    after = nominal.predict(x, np.array([V, 3.0]), theta, DT)
    assert after[1, 0] == pytest.approx(5.0 * np.exp(-DT / (R_load * C)), rel=1e-9)
    assert after[3, 0] == pytest.approx(1.0 + DT)
    # unpowered -> open resets f3 to 0 (reset: {f3: 0}), from the values before it
    module = __import__(nominal.__name__, fromlist=["_TRANSITIONS"])
    resets = [(t[0], t[1]) for t in module._TRANSITIONS if t[4] is not None]
    assert resets == [(3, 1)]
    block = np.array([[0.7, 1.5], [5.0, 4.0], [3.0, 3.0], [2.0, 2.0]])
    module._TRANSITIONS[4][4](block, np.array([V]), theta)
    assert list(block[0]) == [0.0, 0.0] and list(block[1]) == [5.0, 4.0]
    # the mode NaN: each particle follows its own mode's equations, in one array, then its guards
    x = np.array([[3.0, 3.0, 0.0], [5.0, 5.0, 5.0], [1.0, 2.0, 3.0], [0.0, 0.0, 0.0]])
    after = nominal.predict(x, np.array([V, np.nan]), theta, DT)
    for k, mode in enumerate(("open", "closed", "unpowered")):
        assert after[:2, k] == pytest.approx(exact_step(mode, x[:2, k]), rel=1e-7, abs=1e-9)
    assert list(after[2]) == [1.0, 2.0, 3.0]
    with pytest.raises(ValueError, match="no mode of relay_rl"):
        nominal.predict(x, np.array([V, 4.0]), theta, DT)


def test_process_noise_leaves_a_state_idle_in_its_mode_alone(package):
    nominal = package.MODELS["nominal"]
    x = np.array([[0.0, 2.0], [5.0, 5.0], [3.0, 1.0], [0.5, 0.5]])
    nominal.perturb(x, np.random.default_rng(1))
    assert x[0, 0] == 0.0 and x[0, 1] != 2.0 and list(x[2]) == [3.0, 1.0] and list(x[3]) == [0.5, 0.5]


@pytest.fixture(scope="module")
def exact_run():
    """The relay from the exact solution, its measurement noise the model's (seeded), the supply tripped at 12 s."""
    times, states, modes, switches = sampled(20.0)
    rng = np.random.default_rng(7)
    return times, states, modes, switches, rng


def test_the_kalman_filter_follows_an_exact_run_through_its_switches(package, exact_run):
    times, states, modes, switches, rng = exact_run
    nominal = package.MODELS["nominal"]
    ys = states + nominal.MEASUREMENT_STD * rng.standard_normal(states.shape)
    us = np.column_stack([np.full(len(times), V), modes])
    kf = cubature.NominalKalman(nominal, 2)
    for k in range(len(times)):
        kf.step(ys[k], us[k])
    z = kf.track().z
    assert len(switches) >= 15 and set(modes) == {1, 2, 3}
    # the data have no process noise, the filter allows for some: its residuals are at most white
    assert np.all(np.mean(z * z, axis=0) < 1.2)
    assert np.max(np.abs(z)) < 4.5
    near = np.unique(np.concatenate([np.flatnonzero(np.abs(times - t) < 3.5 * DT) for t in switches]))
    assert len(near) > 40 and np.max(np.abs(z[near])) < 4.0  # no jump at a switch
    # the mode as the filter carries it is the data's at every step
    assert np.array_equal(kf.track().x_mean[:, 2], modes.astype(float))


def test_without_the_mode_the_filter_follows_the_guards_but_not_a_controlled_trip(package, exact_run):
    """The mode input NaN (the data do not say it): each point of the cubature filter goes through the
    relay's guards by itself (v_C > 6 closes it, v_C < 4 opens it), and the filter follows the cycles;
    the operator's trip of the supply (a controlled transition) only the data can tell, and its
    residuals leave the noise there: what the mode column is for."""
    times, states, modes, switches, rng = exact_run
    nominal = package.MODELS["nominal"]
    ys = states + nominal.MEASUREMENT_STD * np.random.default_rng(7).standard_normal(states.shape)
    kf = cubature.NominalKalman(nominal, 2)
    for k in range(len(times)):
        kf.step(ys[k], np.array([V, np.nan]))
    track = kf.track()
    trip = int(np.flatnonzero(modes == 3)[0])
    assert np.max(np.abs(track.z[:trip])) < 5.0
    assert np.mean(np.rint(track.x_mean[:trip, 2]) == modes[:trip]) > 0.95
    assert np.max(np.abs(track.z[trip:trip + 3])) > 10.0  # the coil's current falls to 0: many stds off


def test_a_particle_filter_follows_an_exact_run_through_its_switches(package, exact_run):
    times, states, modes, switches, rng = exact_run
    nominal = package.MODELS["nominal"]
    ys = states + nominal.MEASUREMENT_STD * np.random.default_rng(8).standard_normal(states.shape)
    pf = package.filters.GenericParticleFilter(nominal, 1000, np.random.default_rng(0))
    worst = 0.0
    for k in range(len(times)):
        s = pf.step(ys[k], np.array([V, modes[k]]))
        spread = np.sqrt(s.y_std ** 2 + nominal.MEASUREMENT_STD ** 2)
        worst = max(worst, float(np.max(np.abs(ys[k] - s.y_mean) / spread)))
        assert s.mean[2] == pytest.approx(modes[k], abs=1e-9)
    assert worst < 5.0


@pytest.mark.numba
def test_the_compiled_package_gives_the_numpy_packages_filter(folder, package, exact_run):
    """The folder's compiled package, loaded from the copy of it that bgc.open
    runs (the same files, checked here, in their folder of bgc's cache that
    lasts, where numba's disk cache stays valid from run to run: a folder
    new in every run would compile the kernels every time), filters as the
    NumPy package does."""
    from bgc.api import cache

    times, states, modes, _, _ = exact_run
    lasting = Path(cache.numba_folder(cache.open_model(RELAY)))
    ours, lasting_files = ([(p.name, p.read_text(encoding="utf-8"))
                            for p in sorted((f / "relay_rl" / "numba_model").glob("*.py"))] for f in (folder, lasting))
    assert ours == lasting_files  # the folder's compiled package, file for file
    compiled = load_package(lasting, "relay_rl", backend="numba")
    ys = states + package.MODELS["nominal"].MEASUREMENT_STD * np.random.default_rng(9).standard_normal(states.shape)
    us = np.column_stack([np.full(len(times), V), modes])
    tracks = []
    for p in (package, compiled):
        kf = cubature.NominalKalman(p.MODELS["nominal"], 2)
        for k in range(600):
            kf.step(ys[k], us[k])
        tracks.append(kf.track())
    assert np.allclose(tracks[0].z, tracks[1].z, rtol=1e-9, atol=1e-9)
    assert np.allclose(tracks[0].loglik, tracks[1].loglik, rtol=1e-9)


@pytest.mark.slow
def test_generation_is_a_pure_function_of_the_model():
    first = pipeline.generated_files(pipeline.compile_model(RELAY))
    printing._cse_text.cache_clear()  # the second compilation prints its blocks again, not from the first's
    assert pipeline.generated_files(pipeline.compile_model(RELAY)) == first


@pytest.mark.slow
def test_bgc_filter_follows_a_simulated_run_through_its_switches(folder, tmp_path):
    run = tmp_path / "relay.csv"
    made = bgc_cli("simulate", RELAY, "--steps", "1500", "--modes", "unpowered@9", "--seed", "4", "-o", run)
    assert made.returncode == 0, made.stderr
    done = bgc_cli("filter", RELAY, run, "--generated", folder, "--backend", "numpy", "--filter", "gpf",
                   "--plot", tmp_path / "f.png")
    assert done.returncode == 0, done.stderr
    rmse = dict(part.split() for part in done.stdout.split("RMSE vs truth: ")[1].splitlines()[0].split(", "))
    std = dict(zip(("f3", "e6"), load_package(folder, "relay_rl").MODELS["nominal"].MEASUREMENT_STD))  # i_L, v_C
    # the filter knows each sample's mode (the run's column): it estimates both states better than their sensors
    assert float(rmse["f3"]) < std["f3"] and float(rmse["e6"]) < std["e6"]
    assert (tmp_path / "f.png").stat().st_size > 10_000
