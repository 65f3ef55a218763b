"""bgc simulate of a model with modes (bgc/analysis/hybrid.py) against an
independent simulator: scipy's solve_ivp, with events, on the relay
circuit's equations derived by hand (tests/data/hybrid/relay_rl.yaml)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import bgc
from bgc import pipeline
from bgc.analysis import hybrid
from bgc.analysis.simulate import SimulationOptions
from bgc.data import runs
from bgc.errors import BgcError

from conftest import bgc_cli
from hybrid_reference import BACK, DT, STEPS, TRIP, reference

#: Simulations of thousands of samples and an exact reference: the full suite's (make test), not make check's.
pytestmark = pytest.mark.slow

ROOT = Path(__file__).resolve().parent.parent
RELAY = ROOT / "tests" / "data" / "hybrid" / "relay_rl.yaml"
@pytest.fixture(scope="module")
def run():
    h = pipeline.check_model(RELAY)
    nums = h.numerics()
    options = SimulationOptions(steps=STEPS, process_noise=0.0, seed=3)
    return hybrid.simulate(h, nums, options, hybrid.parse_schedule(f"unpowered@{TRIP}", h.model.modes.names))


def test_the_automaton_switches_where_the_exact_solution_does(run):
    switches, _ = reference(STEPS * DT)
    got = [(w.time, w.target) for w in run.switches]
    assert [m for _, m in got] == [m for _, m in switches]
    # a guard's crossing is found by bisection of the RK4 substep (DT / 8), and the switch made there: the
    # times agree to RK4's error (about 1e-9 here), not to a substep; no delay builds up over the cycles
    for (t_got, _), (t_ref, _) in zip(got, switches):
        assert abs(t_got - t_ref) < 1e-7
    kinds = {w.kind for w in run.switches}
    assert kinds == {"autonomous", "controlled", "timed"}
    back = [w for w in run.switches if w.kind == "timed"]
    assert len(back) == 1 and back[0].time == pytest.approx(TRIP + BACK, abs=1e-9)


def test_the_states_follow_the_exact_solution_through_the_switches(run):
    _, exact = reference(STEPS * DT)
    r = run.result
    assert r.state_names == ("f3", "e6")
    ref = np.array([exact(t) for t in r.time])
    # RK4 (substeps of DT / 8) against solve_ivp at rtol 1e-10, each switch where the guard crosses: about
    # 2e-9 apart over 30 switches (a switch a substep late would move them by 1e-2)
    assert np.max(np.abs(r.states - ref)) < 1e-6
    off = run.modes == 3
    assert off.any() and np.all(r.states[off, 0] == 0.0) and np.all(r.clean_measurements[off, 0] == 0.0)


def test_the_run_file_has_a_mode_column_with_the_modes_numbers(run, tmp_path):
    path = tmp_path / "relay.csv"
    path.write_text(hybrid.to_csv(run), encoding="utf-8")
    text = path.read_text(encoding="utf-8")
    assert "# modes: 1 open, 2 closed, 3 unpowered; " in text
    read = runs.read_run(path)
    assert np.array_equal(read.modes, run.modes.astype(float))
    assert set(np.unique(run.modes)) == {1, 2, 3} and run.modes[0] == 1


def test_bgc_simulate_runs_the_automaton_and_refuses_a_change_the_model_does_not_declare(tmp_path):
    done = bgc_cli("simulate", "tests/data/hybrid/relay_rl.yaml", "--steps", "500", "--seed", "1",
                   "-o", tmp_path / "r.csv")
    assert done.returncode == 0, done.stderr
    assert "switches of mode" in done.stdout and (tmp_path / "r.csv").exists()
    wrong = bgc_cli("simulate", "tests/data/hybrid/relay_rl.yaml", "--steps", "500", "--modes", "open@0.1",
                    "-o", tmp_path / "w.csv")
    assert wrong.returncode == 1 and "no controlled transition from open to it" in wrong.stderr
    with pytest.raises(BgcError, match="is not MODE@TIME"):
        hybrid.parse_schedule("closed", ("open", "closed"))
    single = bgc_cli("simulate", "models/two_tank.yaml", "--modes", "open@1", "-o", tmp_path / "t.csv")
    assert single.returncode == 1 and single.stderr.strip() == \
        "--modes: models/two_tank.yaml has no modes (drop --modes)"
    assert not (tmp_path / "t.csv").exists()


def test_the_plot_shows_the_mode_timeline_under_the_measurements(run, tmp_path):
    from bgc.output import plots

    fig = plots.simulation_plot(run.result, modes=(run.modes, run.mode_names))
    axes = fig.axes
    assert axes[-1].get_ylabel() == "mode"
    assert [t.get_text() for t in axes[-1].get_yticklabels()] == ["open", "closed", "unpowered"]
    steps = axes[-1].lines[0].get_ydata()
    assert np.array_equal(steps, run.modes)
    shaded = [p for p in axes[0].patches]  # one span per stretch of one mode
    assert len(shaded) == len(run.switches) + 1
    done = bgc_cli("simulate", "tests/data/hybrid/relay_rl.yaml", "--steps", "300", "-o", tmp_path / "r.csv",
                   "--plot", tmp_path / "r.png")
    assert done.returncode == 0, done.stderr
    assert (tmp_path / "r.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_a_session_of_a_model_with_modes_simulates_its_automaton():
    """bgc.simulate of a session (bgc.open) of a model with modes runs the
    automaton as the model file does: the same run, the same switches (it
    once took the session for a model of one mode and refused modes=)."""
    session = bgc.open(RELAY, backend="numpy")
    by_session = bgc.simulate(session, "R_aux:abrupt:0.4@3", seed=2, steps=600, modes="unpowered@4")
    by_file = bgc.simulate(RELAY, "R_aux:abrupt:0.4@3", seed=2, steps=600, modes="unpowered@4")
    assert by_session.switches == by_file.switches and by_session.switches
    assert any(s.kind == "controlled" and s.target == "unpowered" for s in by_session.switches)
    for name, values in by_file.measurements.items():
        assert np.array_equal(by_session.measurements[name], values), name


def test_a_sensor_fault_the_model_does_not_list_is_simulated_and_said_unexpected(tmp_path):
    """i_L's bias of 0.3 from 0.5 s, which the relay's model does not list
    (no symbol of it in the equations): the reading is the true current
    plus 0.3 from the onset (it once failed with a traceback), and the
    scenario is said to be outside the model's candidates."""
    with pytest.warns(bgc.ScenarioWarning, match="lists no fault i_L:bias among its candidates"):
        sim = bgc.simulate(RELAY, "i_L:bias:0.3@0.5", seed=3, steps=100, process_noise=0.0,
                           measurement_noise=1e-9)
    offset = sim.measurements["i_L"] - sim.run.states["f3"]
    after = sim.time >= 0.5 - 1e-9
    assert np.allclose(offset[after], 0.3, atol=1e-6) and np.allclose(offset[~after], 0.0, atol=1e-6)
    done = bgc_cli("simulate", str(RELAY), "--steps", "100", "--fault", "i_L:drift:0.1@0.5", "-o",
                   str(tmp_path / "run.csv"))
    assert done.returncode == 0 and "lists no fault i_L:drift among its candidates" in done.stderr


def test_a_recorded_run_replayed_with_its_inputs_and_mode_column_is_the_same_run(tmp_path):
    """bgc simulate --inputs FILE of a model with modes: the file's u:
    columns drive the inputs and its mode column the controlled changes
    (the valve RO: every change controlled); the run replayed with the same
    seed is the run, number for number."""
    valve = str(ROOT / "models" / "ro_hybrid_valve.yaml")
    first = bgc_cli("simulate", valve, "--steps", "150", "--modes", "secondary@60,purge@100,primary@120",
                    "--seed", "4", "-o", tmp_path / "a.csv")
    again = bgc_cli("simulate", valve, "--steps", "150", "--inputs", tmp_path / "a.csv", "--seed", "4",
                    "-o", tmp_path / "b.csv")
    assert first.returncode == 0 and again.returncode == 0, again.stderr
    a, b = runs.read_run(tmp_path / "a.csv"), runs.read_run(tmp_path / "b.csv")
    assert np.array_equal(a.modes, b.modes) and all(np.array_equal(a.states[x], b.states[x]) for x in a.states)
    assert any(h.startswith("inputs: u:tau_fp, u:tau_rp recorded in") for h in b.header)
    both = bgc_cli("simulate", valve, "--inputs", tmp_path / "a.csv", "--modes", "purge@10", "-o", tmp_path / "c.csv")
    assert both.returncode == 1 and "--modes and the mode column of --inputs" in both.stderr


def test_a_mode_column_sets_the_controlled_changes_and_leaves_the_guards_to_the_plant(tmp_path):
    """The relay: open <-> closed by guards on v_C, open or closed ->
    unpowered controlled, unpowered -> open after 5 s. A mode column that
    goes unpowered at row 200 (t = 2) schedules that change only; one that
    goes from unpowered to closed, which no transition allows, is refused
    naming the file and the time."""
    h = pipeline.check_model(RELAY)
    names = h.model.modes.names
    times = DT * np.arange(1, 401)
    modes = np.where(np.arange(400) < 199, names.index("open") + 1, names.index("unpowered") + 1).astype(float)
    modes[50:60] = names.index("closed") + 1  # the guards' own: not scheduled
    run = runs.Run(times, {}, {}, {}, {}, (), "relay.csv", modes)
    assert hybrid.schedule_of(run, h.model) == ((pytest.approx(2.0), "unpowered"),)
    modes[300] = names.index("closed") + 1
    with pytest.raises(BgcError, match=r"relay.csv: its mode goes from unpowered to closed at t = 3.01, a change no "
                                       r"transition of relay_rl allows"):
        hybrid.schedule_of(runs.Run(times, {}, {}, {}, {}, (), "relay.csv", modes), h.model)
