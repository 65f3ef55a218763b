"""The truth simulator (bgc.analysis.simulate), run files (bgc.data.runs) and ``bgc simulate``.

Expected trajectories are derived here, independently of the simulator: the circuit
is linear, so its exact solution is x* + exp(t A)(x0 - x*) with A the sympy Jacobian
and x* the DC steady state (i = V / (R1 + R2 + R3)); RK4's one-step map on a linear
system is the polynomial R(hA) = I + hA + (hA)^2/2 + (hA)^3/6 + (hA)^4/24.
"""

import importlib.util
import math
import subprocess
import sys
from functools import lru_cache

import numpy as np
import pytest
import sympy

from bgc.cli import main
from bgc.errors import DataError
from bgc.data import runs
from bgc.analysis import simulate as sim
from bgc.ir import sym
from bgc.pipeline import compile_model

from conftest import ROOT, bgc_cli, compiled

CIRCUIT = ROOT / "models" / "circuit.yaml"
PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


def circuit_compiled():
    return compiled("circuit")


def circuit():
    return circuit_compiled().equations


@lru_cache(maxsize=None)
def generated():
    d = ROOT / "generated" / "circuit" / "numpy_model"
    name = "_bgc_simulate_circuit"
    spec = importlib.util.spec_from_file_location(name, d / "__init__.py", submodule_search_locations=[str(d)])
    pkg = importlib.util.module_from_spec(spec)
    sys.modules[name] = pkg
    spec.loader.exec_module(pkg)
    return pkg.nominal


def linear(ssm, theta, u):
    """A and c of dx/dt = A x + c (sympy Jacobian; c = rhs at x = 0)."""
    xs = [sym(s) for s in ssm.states]
    sub = {sym(p): float(v) for p, v in zip(ssm.parameters, theta)}
    sub.update({sym(i): float(v) for i, v in zip(ssm.inputs, u)})
    jac = sympy.Matrix(list(ssm.rhs)).jacobian(xs).xreplace(sub)
    a = np.array(jac.tolist(), dtype=float)
    c = np.array([float(e.xreplace(sub).xreplace({x: 0 for x in xs})) for e in ssm.rhs])
    return a, c


def expm(m):
    norm = np.linalg.norm(m, 1)
    s = max(0, math.ceil(math.log2(norm / 0.5))) if norm > 0 else 0
    a, result, term = m / 2.0 ** s, np.eye(len(m)), np.eye(len(m))
    for k in range(1, 30):
        term = term @ a / k
        result = result + term
    for _ in range(s):
        result = result @ result
    return result


def rk4_map(a, h):
    z = h * a
    return np.eye(len(a)) + z + z @ z / 2 + z @ z @ z / 6 + z @ z @ z @ z / 24


def steady_state(theta, v=10.0):
    """The circuit at DC: C's open, L shorted, i = V / (R1 + R2 + R3)."""
    p = dict(zip(circuit().parameters, theta))
    i = v / (p["R1"] + p["R2"] + p["R3"])
    return np.array([v - p["R1"] * i, v - (p["R1"] + p["R2"]) * i, i])


def quiet(steps=60, fault=None, seed=0, process=0.0, measurement=0.0, num=None):
    options = sim.SimulationOptions(steps=steps, process_noise=process, measurement_noise=measurement,
                                    seed=seed, fault=fault)
    return sim.simulate(num or circuit_compiled().numerics, options)


def cli(tmp_path, *args, name="run.csv"):
    out = tmp_path / name
    status = main(["simulate", str(CIRCUIT), "-o", str(out), *args])
    return status, out


# ------------------------------------------------------------------- CSV
def test_cli_writes_a_csv_whose_header_says_what_is_in_it(tmp_path, capsys):
    status, out = cli(tmp_path, "--steps", "40", "--fault", "R2:abrupt:0.5@1", "--seed", "3",
                      "--noise", "process=0.01,measurement=0.03")
    assert status == 0
    assert f"wrote {out}: 40 steps of circuit" in capsys.readouterr().out
    text = out.read_text()
    comments = [line[2:] for line in text.splitlines() if line.startswith("# ")]
    header = "\n".join(comments)
    substeps = generated().SUBSTEPS * 8
    for fact in ("bgc simulate", "models/circuit.yaml", "model circuit", "40 steps of dt = 0.05",
                 f"RK4 with {substeps} substeps", "8x finer", "R2 abrupt, bias 0.5 from t = 1",
                 "process 0.01", "measurement 0.03", "seed 3", "columns:"):
        assert fact in header, fact
    columns = next(line for line in text.splitlines() if not line.startswith("#")).split(",")
    ssm = circuit()
    assert columns == (["time"] + [f"u:{n}" for n in ssm.inputs] + [f"y:{n}" for n in ssm.outputs]
                       + [f"x:{n}" for n in ssm.states] + ["theta:R2"])
    rows = [line for line in text.splitlines() if not line.startswith("#")][1:]
    assert len(rows) == 40 and all(len(r.split(",")) == len(columns) for r in rows)


def test_csv_round_trip_is_exact():
    fault = sim.FaultInjection("C1", "incipient", -0.02, 0.8)
    r = quiet(steps=50, fault=fault, seed=4, process=0.03, measurement=0.02)
    run = runs.parse_run(sim.to_csv(r))
    assert run.header == r.header
    assert np.array_equal(run.time, r.time)
    for j, name in enumerate(r.input_names):
        assert np.array_equal(run.inputs[name], r.inputs[:, j])
    for j, name in enumerate(r.output_names):
        assert np.array_equal(run.measurements[name], r.measurements[:, j])
    for j, name in enumerate(r.state_names):
        assert np.array_equal(run.states[name], r.states[:, j])
    assert list(run.parameters) == ["C1"] and np.array_equal(run.parameters["C1"], r.parameter)


@pytest.mark.parametrize("text,what", [
    ("# only a comment\n", "bad.csv: no data"),
    ("time,y:a\n0.1,abc\n", "bad.csv:2: 'abc' in column y:a is not a number"),
    ("t,y:a\n0.1,2\n", "bad.csv:1: the first column must be 'time', not 't'"),
    ("time,a\n0.1,2\n", "bad.csv:1: column 'a' is not time, u:NAME"),
    ("time,y:a\n", "bad.csv: the run has no data rows"),
    ("time,y:a\n0.1,2,3\n", "bad.csv:2: 3 fields, expected 2"),
    ("time,y:a\n0.2,2\n0.1,3\n", "bad.csv:3: time 0.1 does not increase"),
    ("time,y:a,y:a\n0.1,2,3\n", "bad.csv:1: column 'y:a' appears twice"),
    ("time,y:a\n0.1," + "9" * 2000 + "\n", "bad.csv:2: a field of 2000 characters"),
])
def test_read_csv_rejects_what_bgc_did_not_write(text, what):
    with pytest.raises(DataError) as err:
        runs.parse_run(text, "bad.csv")
    assert err.value.line().startswith(what), err.value.line()


# --------------------------------------------------------- the integrator
def test_noise_free_circuit_at_its_steady_state_stays_there():
    ssm = circuit()
    x_ss = steady_state(ssm.parameter_values)
    np.testing.assert_allclose(ssm.initial, x_ss, rtol=1e-12)  # the model starts at DC steady state
    r = quiet(steps=200)
    assert np.max(np.abs(r.states - x_ss)) <= 1e-12 * np.max(np.abs(x_ss))
    assert r.parameter is None


def test_truth_is_rk4_eight_times_finer_than_the_filters(tmp_path):
    """From rest (all initial values 0): the truth equals RK4 with 8 x SUBSTEPS substeps per sample, and
    its error against the exact solution is about 8^4 times smaller than the filter's own step."""
    text = CIRCUIT.read_text().replace("initial: 7.5}", "initial: 0.0}").replace("initial: 2.5}", "initial: 0.0}")
    assert text.count("initial: 0.0}") == 3
    (tmp_path / "models").mkdir()
    path = tmp_path / "models" / "circuit.yaml"
    path.write_text(text)
    rest = compile_model(path)
    ssm = rest.equations
    r = quiet(steps=80, num=rest.numerics)
    mod = generated()
    a, c = linear(ssm, ssm.parameter_values, mod.inputs(0.0))
    x_ss = np.linalg.solve(a, -c)
    np.testing.assert_allclose(x_ss, steady_state(ssm.parameter_values), rtol=1e-12)
    dt, substeps = mod.DT, mod.SUBSTEPS
    d0 = np.zeros(3) - x_ss
    exact = np.array([x_ss + expm(t * a) @ d0 for t in r.time])
    fine = np.linalg.matrix_power(rk4_map(a, dt / (8 * substeps)), 8 * substeps)
    d, rk4_fine = d0, []
    for _ in r.time:
        d = fine @ d
        rk4_fine.append(x_ss + d)
    np.testing.assert_allclose(r.states, np.array(rk4_fine), rtol=1e-10, atol=1e-12)
    x = np.zeros((3, 1))
    filter_steps = []
    for _ in r.time:
        x = mod.predict(x, mod.inputs(0.0), mod.THETA, dt)
        filter_steps.append(x[:, 0])
    truth_error = np.abs(r.states - exact).max()
    filter_error = np.abs(np.array(filter_steps) - exact).max()
    assert filter_error > 0 and truth_error < filter_error / 1000, (truth_error, filter_error)
    assert np.abs(r.states[-1] - r.states[0]).max() > 1.0  # it moved: the comparison means something


# ---------------------------------------------------------------- faults
@pytest.mark.parametrize("t_f", [1.0, 1.02])
def test_abrupt_fault_changes_the_parameter_exactly_from_t_f(tmp_path, t_f):
    status, out = cli(tmp_path, "--steps", "60", "--fault", f"R2:abrupt:0.5@{t_f}", "--seed", "1")
    assert status == 0
    run = runs.parse_run(out.read_text())
    r2 = dict(zip(circuit().parameters, circuit().parameter_values))["R2"]
    after = run.time >= t_f
    assert after.any() and (~after).any()
    assert np.all(run.parameters["R2"][after] == r2 + 0.5)
    assert np.all(run.parameters["R2"][~after] == r2)
    if t_f == 1.0:
        assert run.time[np.argmax(after)] == 1.0  # the sample at t_f itself is faulty (t >= t_f)
    # The plant before t_f is the no-fault plant, step for step (same seed, same noise).
    _, clean = cli(tmp_path, "--steps", "60", "--seed", "1", name="clean.csv")
    base = runs.parse_run(clean.read_text())
    for name in base.states:
        before = run.time < t_f - 0.05 + 1e-9  # samples whose whole step lies before t_f
        assert np.array_equal(run.states[name][before], base.states[name][before])
    assert not np.array_equal(run.states["e8"][after], base.states["e8"][after])


def test_noise_free_abrupt_fault_follows_the_exact_piecewise_solution():
    """Fault at t_f = 1 (a sample time, so a substep boundary): exact solution, steady state up to t_f,
    then the faulty circuit's flow from there. RK4's error here is ~1e-10; evaluating the fault at the
    stage times instead of per substep would be off by h/6 * (change of dx/dt), about 1e-3."""
    ssm, mod = circuit(), generated()
    theta = np.array(ssm.parameter_values)
    r = quiet(steps=60, fault=sim.FaultInjection("R2", "abrupt", 0.5, 1.0))
    faulty = theta.copy()
    faulty[ssm.parameters.index("R2")] += 0.5
    a, c = linear(ssm, faulty, mod.inputs(0.0))
    x_f = np.linalg.solve(a, -c)
    x_before = steady_state(theta)
    want = np.array([x_before if t <= 1.0 else x_f + expm((t - 1.0) * a) @ (x_before - x_f) for t in r.time])
    assert np.abs(r.states - want).max() < 1e-6, np.abs(r.states - want).max()


def test_incipient_fault_is_a_ramp_from_t_f(tmp_path):
    status, out = cli(tmp_path, "--steps", "80", "--fault", "C1:incipient:-0.05@1.5", "--seed", "2")
    assert status == 0
    run = runs.parse_run(out.read_text())
    c1 = dict(zip(circuit().parameters, circuit().parameter_values))["C1"]
    t = run.time
    after = t > 1.5
    assert after.any() and (~after).any()
    assert np.all(run.parameters["C1"][~after] == c1)
    np.testing.assert_allclose(run.parameters["C1"][after], c1 - 0.05 * (t[after] - 1.5), rtol=1e-14, atol=0)
    assert run.parameters["C1"][-1] == pytest.approx(c1 - 0.05 * (4.0 - 1.5), rel=1e-12)


# ----------------------------------------------------------- measurements
def test_noise_free_measurements_are_the_model_observation_of_the_true_states():
    fault = sim.FaultInjection("R2", "abrupt", 0.7, 1.0)
    r = quiet(steps=80, fault=fault, process=0.03, measurement=0.0)  # the states wander; y is exact
    mod = generated()
    theta = [np.full(len(r.time), v) for v in mod.THETA]
    theta[mod.PARAMETERS.index("R2")] = r.parameter  # the true value at each sample
    want = mod.observe(r.states.T, r.inputs[0], tuple(theta)).T
    np.testing.assert_allclose(r.measurements, want, rtol=1e-12)
    np.testing.assert_allclose(r.clean_measurements, want, rtol=1e-12)
    assert np.ptp(r.states[:, 0]) > 0.1  # process noise did move the plant


def test_measurement_noise_has_the_model_level():
    r = quiet(steps=300, process=0.03, measurement=None)
    mod = generated()
    theta_now = mod.THETA
    clean = mod.observe(r.states.T, r.inputs[0], theta_now).T
    np.testing.assert_allclose(r.clean_measurements, clean, rtol=1e-12)
    z = (r.measurements - clean) / mod.MEASUREMENT_STD
    n = z.shape[0]
    assert np.all(np.abs(z.mean(axis=0)) < 4 / math.sqrt(n))
    assert np.all(np.abs(z.std(axis=0) - 1) < 4 / math.sqrt(2 * n))


# ------------------------------------------------------------- the CLI
def test_same_seed_same_csv_bytes(tmp_path):
    args = ("--steps", "30", "--fault", "L:incipient:0.1@0.5")
    _, a = cli(tmp_path, *args, "--seed", "7", name="a.csv")
    _, b = cli(tmp_path, *args, "--seed", "7", name="b.csv")
    _, c = cli(tmp_path, *args, "--seed", "8", name="c.csv")
    assert a.read_bytes() == b.read_bytes()
    assert a.read_bytes() != c.read_bytes()


ERRORS = [
    (["--fault", "R2-abrupt-1"], "is not NAME:KIND:MAGNITUDE@TIME"),
    (["--fault", "Q9:abrupt:1@1"], "'Q9' is no parameter, measurement or input of circuit"),
    (["--fault", "R2:sudden:1@1"], "unknown kind 'sudden'"),
    (["--fault", "R2:abrupt:1..2@1"], "must be numbers"),
    (["--noise", "foo=1"], "unknown key 'foo'"),
    (["--noise", "process=abc"], "'abc' is not a number"),
    (["--noise", "process=-0.1"], "process level must be a finite number >= 0"),
    (["--noise", "measurement=inf"], "measurement level must be a finite number >= 0"),
    (["--noise", "process=nan"], "process level must be a finite number >= 0"),
    (["--steps", "0"], "at least 1"),
]


@pytest.mark.parametrize("args,message", ERRORS)
def test_cli_errors_are_one_line_exit_1_and_write_nothing(tmp_path, capsys, args, message):
    status, out = cli(tmp_path, *args)
    captured = capsys.readouterr()
    assert status == 1
    lines = captured.err.splitlines()
    assert len(lines) == 1 and message in lines[0], captured.err
    assert "Traceback" not in captured.err and captured.out == ""
    assert not out.exists()


@pytest.mark.process  # python -m bgc itself: its exit status and stderr
def test_cli_error_in_a_real_process_has_no_traceback(tmp_path):
    r = subprocess.run([sys.executable, "-m", "bgc", "simulate", "models/circuit.yaml", "--fault", "R2:abrupt",
                        "-o", str(tmp_path / "x.csv")], cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert r.returncode == 1
    assert r.stderr.count("\n") == 1 and "Traceback" not in r.stderr and "NAME:KIND:MAGNITUDE@TIME" in r.stderr
    assert not (tmp_path / "x.csv").exists()


def test_plot_writes_a_png(tmp_path, capsys):
    png = tmp_path / "run.png"
    status, out = cli(tmp_path, "--steps", "40", "--fault", "R2:abrupt:0.5@1", "--plot", str(png))
    assert status == 0 and out.exists()
    data = png.read_bytes()
    assert data[:8] == PNG_SIGNATURE
    width, height = int.from_bytes(data[16:20], "big"), int.from_bytes(data[20:24], "big")
    assert width >= 300 and height >= 200
    assert f"wrote {png}" in capsys.readouterr().out


def test_the_truth_on_python_floats_is_the_truth_on_numpy_scalars(monkeypatch):
    """The truth simulator evaluates sympy's lambdified equations on Python
    floats when every power has an integer exponent (float_safe): the same
    IEEE operations as on NumPy scalars, so the same bits. A run whose
    equations divide by zero (R_pipe brought to 0) raises on Python floats;
    the simulator then evaluates on NumPy scalars and stops the run as
    diverged, as it always did."""
    ro = compiled("ro")
    assert sim.float_safe(ro.numerics.equations)
    x = sympy.Symbol("x")
    assert not sim.float_safe(type("Equations", (), {"rhs": (x ** sympy.Rational(3, 2),), "output_exprs": ()})())

    def both(fault):
        runs_ = []
        for floats in (True, False):
            monkeypatch.setattr(sim, "float_safe", lambda ssm, floats=floats: floats)
            try:
                r = sim.simulate(ro.numerics, sim.SimulationOptions(seed=3, steps=80, fault=fault))
                runs_.append((r.states, r.measurements))
            except Exception as e:  # noqa: BLE001 - the error is what is compared
                runs_.append((type(e), str(e)))
        return runs_

    # what float_safe relies on: an integer power (sympy prints x**2, x**(-1.0)) is the same number on both
    xs = np.random.default_rng(0).standard_normal(2000) * np.exp(np.random.default_rng(1).standard_normal(2000) * 3)
    for e in (2, 3, -1.0, -2.0):
        assert all(np.float64(v) ** e == float(v) ** e for v in xs), e
    with np.errstate(all="ignore"):
        floats, scalars = both(sim.parse_fault("R_pipe:incipient:0.5@20", ro.numerics))
        np.testing.assert_array_equal(floats[0], scalars[0])
        np.testing.assert_array_equal(floats[1], scalars[1])
        floats, scalars = both(sim.parse_fault("R_pipe:abrupt:-69@10", ro.numerics))
    assert floats == scalars and "diverged at t = 11" in floats[1]


def test_simulate_refuses_an_onset_outside_the_run(tmp_path):
    r = bgc_cli("simulate", "models/circuit.yaml", "--fault", "R1:abrupt:0.5@100", "--steps", "30", "-o",
                tmp_path / "f.csv")
    assert r.returncode == 1 and "Traceback" not in r.stderr
    assert r.stderr.strip() == ("--fault R1:abrupt:0.5@100: onset 100 is outside the run (0 to 1.5) (choose an onset "
                                "inside the run, or more --steps)")
    assert not (tmp_path / "f.csv").exists()
