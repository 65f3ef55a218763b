"""Inputs people drive plants with: sine, square, PRBS and chirp signals in
the model file (bgc/ir.py's Signal, the generated ``inputs(t)``), checked
against values derived by hand, the PRBS against the recurrence of its
polynomial, and a sine-driven simulation against scipy's solve_ivp on the
plant's equations written here."""

import math

import numpy as np
import pytest
from scipy.integrate import solve_ivp

import bgc
from bgc.analysis import simulate
from bgc.compiler.codegen import input_code
from bgc.errors import BgcError
from bgc.ir import PRBS_BITS, Signal, prbs_bits

MSD = """\
# a mass-spring-damper driven by a force: m dv/dt = F - Fs - b v, dFs/dt = k v
name: msd_driven
parameters:
  m: {value: 2.0, unit: kg}
  k: {value: 8.0, unit: N/m}
  b: {value: 0.5, unit: N*s/m}
inputs:
  F: SIGNAL
elements:
  force: {kind: Se, value: F}
  v: {kind: "1"}
  mass: {kind: I, parameter: m}
  spring: {kind: C, parameter: 1/k}
  damper: {kind: R, parameter: b}
bonds:
  1: [force, v]
  2: [v, mass]
  3: [v, spring]
  4: [v, damper]
measurements:
  vel: {expr: f2, noise: 0.02}
  Fs: {expr: e3, noise: 0.02}
faults:
  b: [abrupt]
simulation:
  dt: 0.05
  steps: 200
  time_unit: s
"""


def test_a_sine_square_and_chirp_take_the_values_derived_by_hand():
    sine = Signal("sine", 1.0, start=2.0, amplitude=0.5, period=4.0)
    assert sine.at(1.9) == 1.0 and sine.at(2.0) == 1.0
    assert sine.at(3.0) == pytest.approx(1.5, abs=1e-15)  # a quarter period after the start: the crest
    assert sine.at(6.0) == pytest.approx(1.0, abs=1e-15) and sine.at(5.0) == pytest.approx(0.5, abs=1e-15)
    square = Signal("square", -1.0, start=0.0, amplitude=3.0, period=2.0, duty=0.25)
    assert [square.at(t) for t in (0.0, 0.4, 0.5, 0.6, 1.9, 2.0, 2.49, 2.51)] == [2.0, 2.0, -1.0, -1.0, -1.0,
                                                                                  2.0, 2.0, -1.0]
    assert Signal("square", 0.0, start=0.0, amplitude=1.0, period=0.1, duty=0.5).at(0.3) == 1.0  # 0.3/0.1 = 2.999..
    chirp = Signal("chirp", 0.0, start=0.0, amplitude=2.0, f0=0.5, f1=1.5, duration=4.0)
    # phase 2 pi (f0 tau + (f1 - f0) tau^2 / (2 D)): tau = 1 -> 2 pi (0.5 + 0.125) = 1.25 pi; tau = 2 -> 3 pi
    assert chirp.at(1.0) == pytest.approx(-math.sqrt(2.0), abs=1e-12)
    assert chirp.at(2.0) == pytest.approx(0.0, abs=1e-12)
    assert chirp.at(5.0) == pytest.approx(chirp.at(1.0), abs=1e-12)  # the sweep starts again after D


def test_the_prbs_is_the_maximal_length_sequence_of_its_polynomial():
    """x^9 + x^5 + 1: each bit is the XOR of the bits 9 and 5 places before
    it (b[k+9] = b[k] xor b[k+4]), the sequence repeats after 511 bits and
    not before, holds 256 ones, and every nonzero window of 9 bits once."""
    for seed in (1, 77, 511):
        bits = [int(b) for b in prbs_bits(seed)]
        assert len(bits) == PRBS_BITS and sum(bits) == 256
        twice = bits + bits
        assert all(twice[k + 9] == twice[k] ^ twice[k + 4] for k in range(PRBS_BITS))
        windows = {tuple(twice[k:k + 9]) for k in range(PRBS_BITS)}
        assert len(windows) == PRBS_BITS and (0,) * 9 not in windows
    prbs = Signal("prbs", 10.0, start=1.0, amplitude=-4.0, period=0.5, seed=77)
    bits = prbs_bits(77)
    assert prbs.at(0.9) == 10.0
    assert [prbs.at(1.0 + 0.5 * k) for k in range(20)] == [10.0 - 4.0 * int(bits[k]) for k in range(20)]
    assert prbs.at(1.0 + 0.5 * (PRBS_BITS + 3) + 0.25) == 10.0 - 4.0 * int(bits[3])


@pytest.mark.parametrize("signal", [
    Signal("constant", 2.5), Signal("step", 1.0, final=3.0, start=2.0), Signal("ramp", 1.0, start=1.0, slope=-0.5),
    Signal("sine", 1.0, start=2.0, amplitude=0.5, period=4.0),
    Signal("square", -1.0, start=0.5, amplitude=3.0, period=0.3, duty=0.25),
    Signal("prbs", 10.0, start=1.0, amplitude=-4.0, period=0.1, seed=300),
    Signal("chirp", 0.2, start=0.0, amplitude=2.0, f0=0.05, f1=3.0, duration=7.0)])
def test_the_generated_input_code_is_the_signal_to_the_bit(signal):
    code = compile(input_code(signal, "m.yaml"), "<input>", "eval")
    for t in np.r_[np.linspace(0.0, 60.0, 1201), [0.3, 0.6, 0.9, 2.0, 7.0, 14.0]]:
        assert eval(code, {"math": math, "t": float(t)}) == signal.at(float(t)), t


@pytest.mark.parametrize("spec, message", [
    ("{signal: sine, value: 0, period: 2}", "input F: a sine signal needs amplitude"),
    ("{signal: chirp, value: 0, amplitude: 1, f0: 0.1, duration: 5}", "input F: a chirp signal needs f1"),
    ("{signal: sine, value: 0, amplitude: 1, period: 2, duty: 0.3}", "input F: a sine signal takes no duty"),
    ("{signal: square, value: 0, amplitude: 1, period: 0}", "a square signal's period must be above 0"),
    ("{signal: square, value: 0, amplitude: 1, period: 2, duty: 1.5}", "duty is the fraction of a period"),
    ("{signal: prbs, value: 0, amplitude: 1, period: 2, seed: 0}", "seed starts its shift register"),
    ("{signal: chirp, value: 0, amplitude: 1, f0: -1, f1: 2, duration: 5}", "a chirp's f0 is a frequency"),
    ("{signal: triangle, value: 0}", "'triangle' is not valid for inputs.F.signal"),
])
def test_a_wrong_signal_is_one_located_line(tmp_path, spec, message):
    path = tmp_path / "m.yaml"
    path.write_text(MSD.replace("SIGNAL", spec), encoding="utf-8")
    with pytest.raises(BgcError) as e:
        bgc.open(path, backend="numpy")
    assert message in str(e.value) and "m.yaml:8" in str(e.value)


def test_a_sine_driven_plant_follows_its_equations(tmp_path):
    """The plant driven by a sine of period 2 s, without noise: bgc's
    simulation (RK4, the input held over each step at its value at the
    step's start, as a logger's zero-order hold) equals scipy's solve_ivp
    of m dv/dt = F - Fs - b v, dFs/dt = k v with the same held input, step
    by step; and the package's inputs(t) is the signal's."""
    path = tmp_path / "msd.yaml"
    path.write_text(MSD.replace("SIGNAL", "{signal: sine, value: 0.5, amplitude: 2.0, period: 2.0, start: 1.0}"),
                    encoding="utf-8")
    s = bgc.open(path, backend="numpy")
    num = s.compiled.numerics
    r = simulate.noise_free(num, simulate.SimulationOptions(steps=200))
    m, k, b, dt = 2.0, 8.0, 0.5, 0.05
    force = lambda t: 0.5 if t < 1.0 else 0.5 + 2.0 * math.sin(math.pi * (t - 1.0))  # noqa: E731
    x = np.zeros(2)  # v, Fs
    truth = []
    for j in range(200):
        u = force(j * dt)
        sol = solve_ivp(lambda t, z: [(u - z[1] - b * z[0]) / m, k * z[0]], (0.0, dt), x, rtol=1e-11, atol=1e-13)
        x = sol.y[:, -1]
        truth.append(x.copy())
    truth = np.array(truth)
    states = dict(zip(r.state_names, r.states.T))
    assert np.max(np.abs(states["f2"] - truth[:, 0])) < 1e-7 and np.max(np.abs(states["e3"] - truth[:, 1])) < 1e-7
    assert np.ptp(truth[:, 0]) > 0.5  # the plant moves
    assert r.inputs[:, 0].tolist() == [force(j * dt) for j in range(200)]
    model = s.package.MODELS["nominal"]
    assert [float(model.inputs(t)[0]) for t in r.time] == [force(t) for t in r.time]


def _msd(tmp_path, signal: str):
    path = tmp_path / "msd.yaml"
    path.write_text(MSD.replace("SIGNAL", signal), encoding="utf-8")
    return bgc.open(path, backend="numpy")


def test_a_recorded_profile_drives_the_plant_step_by_step(tmp_path):
    """A profile's rows (time, u:F) at 0.05, 0.10, 0.20 (empty), 0.25, 0.25001
    and 0.40, dt 0.05: the first row drives the first step; the step of 0.15,
    which no row falls on, and the empty cell hold 1; the second row on the
    step of 0.25 is not used; after the last row -1 is held. A run's own u
    column fed back as a profile gives that run again, bit for bit."""
    s = _msd(tmp_path, "{signal: sine, value: 0.0, amplitude: 1.0, period: 0.7}")
    num = s.compiled.numerics
    nan = float("nan")
    profile = simulate.InputProfile(np.array([0.05, 0.10, 0.20, 0.25, 0.25001, 0.40]),
                                    {"F": np.array([0.0, 1.0, nan, 2.0, 5.0, -1.0])}, "bench.csv")
    r = simulate.simulate(num, simulate.SimulationOptions(steps=12, seed=3, inputs=profile))
    assert r.inputs[:, 0].tolist() == [0.0, 1.0, 1.0, 1.0, 2.0, 2.0, 2.0, -1.0, -1.0, -1.0, -1.0, -1.0]
    assert r.header[-1].startswith("inputs: u:F recorded in bench.csv")
    sine = simulate.simulate(num, simulate.SimulationOptions(steps=80, seed=5))
    again = simulate.simulate(num, simulate.SimulationOptions(
        steps=80, seed=5, inputs=simulate.InputProfile(sine.time, {"F": sine.inputs[:, 0]})))
    assert np.array_equal(again.states, sine.states) and np.array_equal(again.measurements, sine.measurements)
    late = simulate.InputProfile(np.array([7.0, 7.1]), {"F": np.array([nan, 3.0])})  # a logger's clock: shifted
    r = simulate.simulate(num, simulate.SimulationOptions(steps=4, inputs=late))
    assert r.inputs[:, 0].tolist() == [sine.inputs[0, 0], sine.inputs[1, 0], 3.0, 3.0]


def test_bgc_simulate_inputs_reads_a_profile_and_says_what_is_wrong_with_one(tmp_path):
    from conftest import bgc_cli

    (tmp_path / "msd.yaml").write_text(MSD.replace("SIGNAL", "{signal: constant, value: 0.0}"), encoding="utf-8")
    (tmp_path / "p.csv").write_text("time,u:F\n0.05,1\n0.1,2\n", encoding="utf-8")
    out = bgc_cli("simulate", "msd.yaml", "--inputs", "p.csv", "--steps", "3", "-o", "run.csv", cwd=tmp_path)
    assert out.returncode == 0, out.stderr
    rows = [line.split(",")[1] for line in (tmp_path / "run.csv").read_text().splitlines() if line[:1].isdigit()]
    assert rows == ["1.0", "2.0", "2.0"]
    (tmp_path / "q.csv").write_text("time,u:G,y:vel\n0.05,1,0\n", encoding="utf-8")
    (tmp_path / "r.csv").write_text("time,y:vel\n0.05,0\n", encoding="utf-8")
    for profile, message in (("q.csv", "q.csv: u:G is no input of the model (its inputs are u:F)"),
                             ("r.csv", "r.csv: no u:NAME column: an input profile records inputs"),
                             ("run.csv", "--inputs run.csv is the file -o would write")):
        out = bgc_cli("simulate", "msd.yaml", "--inputs", profile, "-o", "run.csv", cwd=tmp_path)
        assert out.returncode != 0 and out.stderr.strip().startswith(message), out.stderr
    out = bgc_cli("simulate", "msd.yaml", "--columns", "m.yaml", cwd=tmp_path)
    assert out.returncode != 0 and "--columns applies to --inputs" in out.stderr


def test_an_input_given_on_the_command_line_drives_the_simulation_instead_of_the_models(tmp_path):
    """``bgc simulate --input F=SPEC``: SPEC is written as in the model's
    inputs section and checked by the same rules; the run's u:F column is the
    signal's value at the start of each step (derived here from the sine's
    formula), and the file's header says which signal drove it."""
    from conftest import bgc_cli

    (tmp_path / "msd.yaml").write_text(MSD.replace("SIGNAL", "{signal: constant, value: 0.0}"), encoding="utf-8")
    out = bgc_cli("simulate", "msd.yaml", "--steps", "5", "--input",
                  "F={signal: sine, value: 1, amplitude: 2, period: 0.4}", "-o", "run.csv", cwd=tmp_path)
    assert out.returncode == 0, out.stderr
    text = (tmp_path / "run.csv").read_text()
    assert "# input u:F: sine 1 +- 2, period 0.4 (instead of the model's)" in text
    u = [float(line.split(",")[1]) for line in text.splitlines() if line[:1].isdigit()]
    assert u == pytest.approx([1 + 2 * math.sin(2 * math.pi * k * 0.05 / 0.4) for k in range(5)], abs=1e-12)
    for option, message in (("G=1", "--input: 'G' is not an input of the model (its inputs: F)"),
                            ("F", "--input 'F' is not NAME=SIGNAL"),
                            ("F={signal: sine, value: 1}", "--input F: a sine signal needs amplitude, period"),
                            ("F={signal: sine, value: 1, amplitude: 1, period: 0}",
                             "--input F: a sine signal's period must be above 0"),
                            ("F={signal: sine, value: .inf, amplitude: 1, period: 1}", "--input F: value:"),
                            ("F=[1", "--input F: the signal is not YAML")):
        out = bgc_cli("simulate", "msd.yaml", "--input", option, "-o", "x.csv", cwd=tmp_path)
        assert out.returncode != 0 and out.stderr.strip().startswith(message), (option, out.stderr)
        assert "Traceback" not in out.stderr and not (tmp_path / "x.csv").exists()
    (tmp_path / "p.csv").write_text("time,u:F\n0.05,1\n", encoding="utf-8")
    out = bgc_cli("simulate", "msd.yaml", "--inputs", "p.csv", "--input", "F=2", "-o", "x.csv", cwd=tmp_path)
    assert out.returncode != 0 and "both drive u:F" in out.stderr


def test_an_input_test_reaches_the_diagnosis_the_prediction_and_a_campaign(tmp_path):
    """The same signals in the API (``inputs=``) and in a campaign's groups:
    the simulated scenario's u:F column is the square wave's value at the
    start of each step (derived here), the distinguishability report says
    which input drove it, and a campaign refuses a signal the model's rules
    refuse, at its line."""
    from bgc.experiment.campaign_file import load_campaign

    model = tmp_path / "msd.yaml"
    model.write_text(MSD.replace("SIGNAL", "{signal: constant, value: 0.0}"), encoding="utf-8")
    square = {"signal": "square", "value": 0.5, "amplitude": 1.0, "period": 1.0}
    r = bgc.diagnose(model, scenario="none", inputs={"F": square}, steps=40, particles=50, filter="ckf")
    expected = [0.5 + (1.0 if (k * 0.05) % 1.0 < 0.5 - 1e-9 else 0.0) for k in range(40)]
    assert r.run.inputs["F"].tolist() == pytest.approx(expected)
    with pytest.raises(bgc.errors.ArgumentValueError, match="inputs: 'G' is not an input of the model"):
        bgc.diagnose(model, scenario="none", inputs={"G": 1})
    with pytest.raises(bgc.errors.ArgumentValueError, match="inputs= with data"):
        bgc.diagnose(model, data=tmp_path / "run.csv", inputs={"F": 1})
    d = bgc.distinguishability(model, "b:abrupt:0.3@5", steps=200, inputs={"F": square})
    assert d.signals == (("F", Signal("square", 0.5, start=0.0, amplitude=1.0, period=1.0, duty=0.5)),)
    assert "# input u:F: square wave 0.5 to 1.5, period 1, duty 0.5 (instead of the model's)" in \
        bgc.output.render.distinguishability_text(d)
    plain = bgc.distinguishability(model, "b:abrupt:0.3@5", steps=200)
    assert d.distinctions[0].divergence != pytest.approx(plain.distinctions[0].divergence, rel=1e-3)
    campaign = tmp_path / "c.yaml"
    campaign.write_text("campaign: c\ngroups:\n  - name: g\n    model: msd.yaml\n    scenarios: [none]\n"
                        "    inputs: {F: {signal: square, value: 0.5, amplitude: 1.0, period: 1.0}}\n", encoding="utf-8")
    assert load_campaign(campaign).specs[0].inputs == d.signals
    campaign.write_text(campaign.read_text().replace("period: 1.0", "period: -1"), encoding="utf-8")
    with pytest.raises(bgc.errors.BgcError, match=r"c.yaml:6:\d+: inputs F: a square signal's period must be above 0"):
        load_campaign(campaign)
