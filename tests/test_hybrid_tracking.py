"""Following a hidden mode (bgc/templates/hybrid_model.py.j2, bgc/analysis/hybrid.py):
where within a step a particle switches, a guard's tolerance in the truth
simulator and in the particles, and ``bgc filter --hidden-mode``. Expected
values come from the relay circuit's hand-derived equations by solve_ivp
(tests/hybrid_reference.py) and from the normal law by scipy, not from bgc."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy.integrate import solve_ivp
from scipy.stats import norm

import bgc
from bgc.model.package import load_package

from conftest import bgc_cli
from hybrid_reference import DT, V, derivative, sampled

ROOT = Path(__file__).resolve().parent.parent
RELAY = ROOT / "tests" / "data" / "hybrid" / "relay_rl.yaml"
#: The relay's closing guard with an uncertain threshold (std 0.2 V), for the tolerance's tests.
SPREAD = 0.2


def relay_with(tmp: Path, text: str) -> Path:
    """The relay model with its closing transition written as ``text``."""
    model = RELAY.read_text()
    line = '  - {from: open, to: closed, when: "v_C > 6"}'
    assert line in model
    path = tmp / "relay_rl.yaml"
    path.write_text(model.replace(line, text))
    return path


@pytest.fixture(scope="module")
def folder(tmp_path_factory):
    out = tmp_path_factory.mktemp("relay")
    done = bgc_cli("compile", RELAY, "-o", out, "--no-pictures")
    assert done.returncode == 0, done.stderr
    return out


@pytest.fixture(scope="module")
def relay(folder):
    return load_package(folder, "relay_rl").MODELS["nominal"]


@pytest.fixture(scope="module")
def uncertain(tmp_path_factory):
    """The relay with a tolerance on its closing guard: (its model file, its nominal generated model)."""
    folder = tmp_path_factory.mktemp("uncertain")
    path = relay_with(folder, f'  - {{from: open, to: closed, when: "v_C > 6", tolerance: {SPREAD}}}')
    done = bgc_cli("compile", path, "-o", folder / "out", "--no-pictures")
    assert done.returncode == 0, done.stderr
    return path, load_package(folder / "out", "relay_rl").MODELS["nominal"]


def open_until(level: float) -> tuple[float, np.ndarray]:
    """When the relay, from rest with the supply on and the relay open, first has v = level, and its (i, v)
    then (solve_ivp on the hand-derived equations, with an event)."""
    def event(t, x):
        return x[1] - level
    event.terminal, event.direction = True, 1
    sol = solve_ivp(lambda t, x: derivative("open", x), (0.0, 50.0), [0.0, 0.0], events=event, rtol=1e-12,
                    atol=1e-14)
    return float(sol.t_events[0][0]), sol.y_events[0][0]


def carried(mode: str, x0, span: float) -> np.ndarray:
    sol = solve_ivp(lambda t, x: derivative(mode, x), (0.0, span), list(x0), rtol=1e-12, atol=1e-14)
    return sol.y[:, -1]


def test_a_particle_switches_where_within_the_step_its_guard_is_crossed(relay):
    """From 3/8 of a step before v reaches 6 (the closing guard), one step with the mode unknown: the
    particle is closed, 5/8 of the step into the mode, and its state is the exact one (open for 3/8 of
    the step, closed for the rest), not the state of a switch at the step's end."""
    t_star, at_guard = open_until(6.0)
    start = carried("open", open_until(5.0)[1], t_star - 0.375 * DT - open_until(5.0)[0])
    assert start[1] < 6.0
    x = np.zeros((len(relay.STATES), 1))
    x[:2, 0] = start
    x[relay.MODE_ROW] = 1.0
    out = relay.predict(x, np.array([V, np.nan]), relay.THETA, relay.DT)
    exact = carried("closed", at_guard, 0.625 * DT)
    late = carried("open", start, DT)  # a switch found at the step's end: the open mode's state
    assert out[relay.MODE_ROW, 0] == 2.0
    assert out[relay.DWELL_ROW, 0] == pytest.approx(0.625 * DT, rel=0.01)
    assert np.max(np.abs(out[:2, 0] - exact)) < 1e-4
    assert np.max(np.abs(late - exact)) > 0.02


def test_a_timed_change_happens_where_its_time_runs_out_within_the_step(relay):
    """Unpowered for 5 s less 1/4 of a step: one step takes the relay back to open (its timed
    transition, the coil's current reset to 0) 1/4 into the step, then 3/4 of a step open."""
    x = np.zeros((len(relay.STATES), 1))
    x[1, 0] = 3.0
    x[relay.MODE_ROW] = 3.0
    x[relay.DWELL_ROW] = 5.0 - 0.25 * DT
    out = relay.predict(x, np.array([V, np.nan]), relay.THETA, relay.DT)
    idle = carried("unpowered", [0.0, 3.0], 0.25 * DT)
    exact = carried("open", [0.0, idle[1]], 0.75 * DT)
    assert out[relay.MODE_ROW, 0] == 1.0
    assert out[relay.DWELL_ROW, 0] == pytest.approx(0.75 * DT, rel=1e-9)
    assert np.max(np.abs(out[:2, 0] - exact)) < 1e-6


def crossing_share(model, v0: float, before: float, n: int = 40000, seed: int = 1):
    """Of n particles at (i, v0) = (10, v0) in mode open whose closing margin was ``before`` at the
    last step's end, after one step: (which closed, which closed at the step's start, their log
    importance weights, v at the step's end in open by solve_ivp)."""
    rng = np.random.default_rng(seed)
    x = model.initial_particles(rng, n)
    x[0], x[1], x[model.MODE_ROW] = 10.0, v0, 1.0  # any current: the guard reads v only
    draw, margin = (model.STATES.index(name) for name in ("threshold1", "margin1"))
    x[margin] = before
    x[draw] = rng.random(n)
    out = model.predict(x, np.array([V, np.nan]), model.THETA, model.DT)
    closed = out[model.MODE_ROW] == 2.0
    at_start = closed & np.isclose(out[model.DWELL_ROW], model.DT, rtol=1e-12)
    return closed, at_start, out[model.PROPOSAL_ROW], carried("open", [10.0, v0], model.DT)[1]


def within(share: float, p: float, n: int) -> bool:
    return abs(share - p) < 4 * np.sqrt(max(p * (1 - p), 1e-4) / n)


@pytest.mark.parametrize("before", [5.9 - 6.0, 5.7 - 6.0])
def test_a_tolerance_makes_a_particle_cross_with_the_normal_laws_probability(uncertain, before):
    """A particle still open has its threshold (6 + 0.2 Z) above the margin it had at the last step's
    end; it closes within the step with P(threshold between that and the end's margin | above the
    former), at the step's start for the part the process noise jumped (5.7 -> 5.9)."""
    _, model = uncertain
    n = 40000
    closed, at_start, log_weight, v_end = crossing_share(model, 5.9, before, n)
    above = norm.sf(before / SPREAD)
    p = (above - norm.sf((v_end - 6.0) / SPREAD)) / above
    p_start = (above - norm.sf((5.9 - 6.0) / SPREAD)) / above
    assert p > 0.1 and within(closed.mean(), p, n) and within(at_start.mean(), p_start, n)
    assert np.all(log_weight == 0.0)  # likely enough: proposed as the model says, no correction


def test_a_switch_in_the_thresholds_tail_is_proposed_and_weighted_back(uncertain):
    """5 stds below the threshold, a step closes the relay with probability about 1e-6: 2 % of the
    particles propose it, each weighted by that probability over 2 %, the others by its complement
    over 98 %: the weighted share closed is the model's probability, the weights average 1."""
    _, model = uncertain
    n = 40000
    closed, _, log_weight, v_end = crossing_share(model, 5.0, 5.0 - 6.0, n)
    above = norm.sf(-1.0 / SPREAD)
    p = (above - norm.sf((v_end - 6.0) / SPREAD)) / above
    assert 0 < p < 1e-4 and within(closed.mean(), 0.02, n)
    weight = np.exp(log_weight)
    assert np.allclose(weight[closed], p / 0.02, rtol=1e-6)
    assert np.allclose(weight[~closed], (1 - p) / 0.98, rtol=1e-9)
    assert abs(weight.mean() - 1.0) < 4 * np.sqrt(0.02 * 0.98 / n) / 0.98


def closing_levels(model, seeds) -> np.ndarray:
    """The voltage at each closing of the relay in noise-free runs of ``model``: the quadratic through
    the three samples before the switch (the open mode's smooth rise), at the switch's time."""
    levels = []
    for seed in seeds:
        sim = bgc.simulate(model, seed=seed, steps=1150, process_noise=0.0)
        v, t = sim.run.states["e6"], sim.time
        for s in sim.switches:
            if s.source == "open" and s.target == "closed":
                k = int(np.searchsorted(t, s.time - 1e-12))  # the samples before: k - 3 .. k - 1
                levels.append(float(np.polyval(np.polyfit(t[k - 3:k], v[k - 3:k], 2), s.time)))
    return np.array(levels)


@pytest.mark.slow
def test_the_truth_simulator_draws_a_threshold_per_visit(uncertain):
    """Noise-free runs: the voltage at which the relay closes is 6 without a tolerance, and with it
    a new draw per visit and per seed (two seeds), each within 5 of its stds (0.2) of 6 (a normal
    draw leaves that once in 1.7 million) and not all on one side of 6. That the draws are spread
    around 6 with std 0.2 (their mean within 4 standard errors of 6, their std within 40 % of 0.2,
    over four seeds' 24 and more draws) is ``bench/seeded_statistics.py relay-thresholds``."""
    path, _ = uncertain
    exact, drawn = closing_levels(RELAY, [0]), closing_levels(path, range(2))
    assert len(exact) >= 6 and np.max(np.abs(exact - 6.0)) < 1e-3
    assert len(drawn) >= 12 and len(np.unique(np.round(drawn, 6))) == len(drawn)
    assert np.max(np.abs(drawn - 6.0)) < 5 * SPREAD and np.min(drawn) < 6.0 < np.max(drawn)


def test_bgc_filter_hidden_mode_says_how_often_it_follows_the_run(relay, folder, tmp_path):
    """The exact relay (solve_ivp) before the trip, written as a run with its mode column: bgc filter
    --hidden-mode follows the guards without the column and counts the samples where its most
    probable mode is the column's."""
    times, states, modes, switches = sampled(11.5)
    rng = np.random.default_rng(5)
    ys = states + relay.MEASUREMENT_STD * rng.standard_normal(states.shape)
    lines = ["time,mode,u:V,y:v_C,y:i_L"] + [f"{t:.10g},{m},{V},{y[1]:.10g},{y[0]:.10g}"
                                              for t, m, y in zip(times, modes, ys)]
    run = tmp_path / "relay.csv"
    run.write_text("\n".join(lines) + "\n")
    done = bgc_cli("filter", RELAY, run, "--generated", folder, "--filter", "gpf", "--hidden-mode",
                   "--backend", "numpy")
    assert done.returncode == 0, done.stderr
    line = next(x for x in done.stdout.splitlines() if x.strip().startswith("mode:"))
    right, total = (int(v) for v in line.split("run's at ")[1].split(" samples")[0].split(" of "))
    assert total == len(times) and len(switches) >= 12
    assert right / total > 0.98


def test_a_tolerance_needs_a_guard_and_room_between_thresholds(tmp_path):
    timed = relay_with(tmp_path, '  - {from: open, to: closed, when: "v_C > 6"}').read_text().replace(
        "  - {from: unpowered, to: open, after: 5, reset: {f3: 0}}",
        "  - {from: unpowered, to: open, after: 5, tolerance: 0.1, reset: {f3: 0}}")
    (tmp_path / "timed.yaml").write_text(timed)
    done = bgc_cli("check", tmp_path / "timed.yaml")
    assert done.returncode != 0 and "Traceback" not in done.stderr
    assert "has a tolerance but no guard" in done.stderr and "timed.yaml:" in done.stderr
    wide = relay_with(tmp_path, '  - {from: open, to: closed, when: "v_C > 6", tolerance: 0.6}')
    done = bgc_cli("check", wide)
    assert done.returncode != 0 and "under 4 times their tolerances" in done.stderr
