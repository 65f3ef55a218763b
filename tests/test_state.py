"""The diagnoser's state is plain data: a stream stepped half way, its state
taken through bytes and taken up again (``Diagnoser.to_state``,
``DiagnoserState.to_bytes`` / ``from_bytes``, ``Diagnoser.from_state``),
then stepped to its end, gives exactly what the uninterrupted diagnoser
gives: every belief after the cut and the whole diagnosis (every number,
bit for bit; the seconds aside), on every shipped model and every filter
on both backends, cut while watching and while tracking hypotheses, and
across a switch of filter. The bytes are read back by an unpickler that makes only a state's
types."""

from __future__ import annotations

import dataclasses
import functools
import io
import pickle

import numpy as np
import pytest

import bgc
from bgc.analysis import simulate
from bgc.data import runs
from bgc import events as ev
from bgc.diagnosis.diagnoser import Diagnoser
from bgc.diagnosis.options import DiagnosisOptions
from bgc.diagnosis.state import MAGIC, DiagnoserState
from bgc.errors import ArgumentValueError

from conftest import MODELS, TEST_MODELS, fast_session
from conftest import session as session_of

#: Per shipped model, a fault scenario whose alarm comes after about half of the run.
SCENARIOS = {"circuit": "R2:abrupt:0.6@5", "two_tank": "R12:abrupt:0.8@75", "ro": "R_pipe:incipient:0.5@165"}
#: The runs' lengths (None: the model's declared run), each long enough for a cut at 0.8 of it to fall
#: while the hypotheses are tracked and for the fault to be isolated at the end: the circuit's 170 steps
#: of 0.05 put its fault at t = 5 (sample 100, the alarm at 99: the cut at 136), the two tanks' 240 of
#: 0.5 theirs at t = 75 (sample 150, the alarm at 155: the cut at 192). Their declared 300 would only
#: leave the end more samples to track and weigh, bit for bit as well, twice (uninterrupted and resumed).
STEPS = {"circuit": 170, "two_tank": 240, "ro": None}


@pytest.fixture(scope="module")
def sessions():
    return {}


def _session(sessions, path):
    if path not in sessions:
        sessions[path] = bgc.open(path)
    return sessions[path]


def _rows(session, scenario: str, seed: int = 1, steps: int | None = None):
    """The rows of a simulated run (time, inputs by name, measurements by name) and the run."""
    c = session.compiled
    injected = None if scenario == "none" else simulate.parse_fault(scenario, c.numerics)
    result = simulate.simulate(c.numerics, simulate.SimulationOptions(steps=steps, seed=seed, fault=injected))
    run = runs.parse_run(simulate.to_csv(result), scenario)
    rows = [(float(t), {u: float(v[i]) for u, v in run.inputs.items()},
             {y: float(v[i]) for y, v in run.measurements.items()}) for i, t in enumerate(run.time)]
    return rows, run


def _equal(a, b, path: str = "") -> None:
    """``a`` and ``b`` equal to the bit (NaN equals NaN), dataclasses field by
    field (their ``seconds`` aside: a duration)."""
    if dataclasses.is_dataclass(a) and not isinstance(a, type):
        assert type(a) is type(b), path
        for f in dataclasses.fields(a):
            if f.name != "seconds":
                _equal(getattr(a, f.name), getattr(b, f.name), f"{path}.{f.name}")
    elif isinstance(a, np.ndarray):
        assert a.shape == b.shape and np.array_equal(a, b, equal_nan=True), path
    elif isinstance(a, (tuple, list)):
        assert len(a) == len(b), path
        for i, (x, y) in enumerate(zip(a, b)):
            _equal(x, y, f"{path}[{i}]")
    elif isinstance(a, dict):
        assert a.keys() == b.keys(), path
        for k in a:
            _equal(a[k], b[k], f"{path}[{k}]")
    elif isinstance(a, float):
        assert a == b or (a != a and b != b), (path, a, b)
    else:
        assert a == b, (path, a, b)


def _round_trip(session, rows, run, cut: float | int, **options):
    """(the uninterrupted diagnoser's beliefs after the cut and diagnosis,
    the resumed one's, a diagnoser taken up at the cut and not stepped);
    ``cut``: a share of the rows, or (an int) a number of rows; ``options``:
    of DiagnosisOptions (the end's filters in this process). The state is
    taken from the diagnoser that then goes on uninterrupted: taking it
    leaves that diagnoser as it was (a second state equals the first's bytes read back),
    so it goes on as if nothing had been taken."""
    options = DiagnosisOptions(**{"workers": 1, **options})
    whole = session.diagnoser(options)
    k = cut if isinstance(cut, int) else int(cut * len(rows))
    for t, u, y in rows[:k]:
        whole.step(t, u, y)
    data = whole.to_state().to_bytes()
    state = DiagnoserState.from_bytes(data)
    _equal(whole.to_state(), state, "state")  # taking the state changed nothing; the bytes hold all of it
    assert state.epoch == k
    resumed = Diagnoser.from_state(whole.config, state)
    beliefs = [whole.step(t, u, y) for t, u, y in rows[k:]]
    later = [resumed.step(t, u, y) for t, u, y in rows[k:]]
    at_cut = Diagnoser.from_state(whole.config, DiagnoserState.from_bytes(data))
    return (beliefs, whole.finish(run)), (later, resumed.finish(run)), at_cut


#: A covering set of (model, filter): each filter's state is taken up on each backend, each shipped model
#: appears. NumPy: the two tanks' GPF (the fast tier) and the circuit's APF, OPF and CKF; FAST: the RO
#: plant's GPF and the two tanks' APF, OPF and CKF. (The other four pairs ran a filter on a backend a pair
#: here already runs it on.) All eight are kept: on the compiled backend each filter reaches its
#: generator's handle, or the compiled cubature step, at a place of its own (the GPF's fused step and
#: its bank's packed step, the APF's packed bank, the OPF's own step filter by filter; the CKF's
#: compiled step and its caches), so each (filter, backend) is a path of its own through a restored state.
CASES = [("two_tank", "gpf"), ("circuit", "apf"), ("circuit", "opf"), ("circuit", "ckf"),
         ("ro", "gpf"), ("two_tank", "apf"), ("two_tank", "opf"), ("two_tank", "ckf")]
#: The cases of 4 s or more (measured, docs/results.md section 72): long runs, in make long's tier.
LONG = {("two_tank", "opf")}


def _fast(name: str, method: str) -> bool:
    """Whether case (name, method) runs on the FAST backend."""
    return name == "ro" or (name == "two_tank" and method != "gpf")


#: The case whose end weighs the fault models the symbols ruled out (``recheck``, the default) after the
#: round trip: that weighing reads the restored record like the rest of the end, and one case (the fast
#: tier's) covers it; the other seven leave it off (a third of their time, the same for a filter of either
#: backend, since it runs its own filters from the record after the loop). All eight with it, at 200
#: particles, as before: bench/full_cases.py state-cases.
RECHECKED = ("two_tank", "gpf")


#: The particles of a case: 100, but 200 on the RO plant (with 100 its alarm comes later and the cut at 0.8
#: falls while the hypotheses are still being isolated, not tracked).
PARTICLES = {"ro": 200}


@functools.lru_cache(maxsize=None)
def _case(name: str, method: str):
    """The round trip of case (name, method) of CASES (:func:`_round_trip`,
    cut at 0.8 of the run, PARTICLES, seed 3; ``recheck`` on for
    RECHECKED only), once per test process: the RO plant's GPF on FAST is
    also the compiled backend's own test below (FAST is numba when numba is
    installed), which asserts on it again. 100 particles (was 200): every filter's
    whole state (its clouds, its generator, its trackers) is taken up all the
    same, and the faults are still isolated (asserted), so a number of the
    state lost or wrong still shows in the beliefs after the cut."""
    session = fast_session(name) if _fast(name, method) else session_of(MODELS / f"{name}.yaml")
    rows, run = _rows(session, SCENARIOS[name], steps=STEPS[name])
    return session, _round_trip(session, rows, run, 0.8, filter=method, particles=PARTICLES.get(name, 100), seed=3,
                                recheck=(name, method) == RECHECKED)


@pytest.mark.parametrize("name, method", [
    pytest.param(name, method, marks=() if (name, method) == ("two_tank", "gpf") else
                 (pytest.mark.slow, pytest.mark.long) if (name, method) in LONG else pytest.mark.slow)
    for name, method in CASES])
def test_a_diagnoser_taken_up_from_its_state_goes_on_as_if_it_never_stopped(name, method):
    """The circuit on NumPy (APF, OPF, CKF) and the two tanks' GPF, in the
    fast tier, on NumPy; the two tanks' other filters and the RO plant's GPF,
    whose diagnoses take longest, on the FAST backend (conftest.fast_session;
    the slow tier only): each filter's state is taken up on both backends,
    on each shipped model."""
    _, ((beliefs, whole), (later, resumed), at_cut) = _case(name, method)
    assert at_cut.loop.phase == "tracking"  # cut with hypotheses tracked: their filters are in the state
    assert (method == "ckf") == (not at_cut.loop.trackers)
    _equal(beliefs, later, "beliefs")
    _equal(whole, resumed, "diagnosis")
    assert whole.verdict == "isolated"


@pytest.mark.slow
def test_a_state_taken_while_watching_keeps_the_detectors_windows_and_the_clouds_ring(sessions):
    session = _session(sessions, MODELS / "two_tank.yaml")
    # 300 rows watched at the cut: more than the ring's history + 1 = 257 clouds
    rows, run = _rows(session, "R12:abrupt:0.8@200", steps=500)
    (beliefs, whole), (later, resumed), at_cut = _round_trip(session, rows, run, 0.6, particles=100, seed=4,
                                                             recheck=False)  # the end's weighing: RECHECKED
    assert at_cut.loop.phase == "watching" and len(at_cut.loop.samples) == 300
    # the nominal clouds are a ring of the last `history` steps (the onsets are looked for no further back)
    options = at_cut.options
    kept = sorted(at_cut.loop.clouds)
    assert len(kept) == options.history + 1 and kept[-1] == len(at_cut.loop.samples) - 1
    _equal(beliefs, later, "beliefs")
    _equal(whole, resumed, "diagnosis")


@pytest.mark.parametrize("cut", [3, 0.9])
def test_a_state_taken_before_or_after_a_switch_of_filter_gives_the_same_diagnosis(sessions, cut):
    """The drivetrain's particle observer degenerates (a stiff shaft
    measured sharply) and the diagnoser's policy hands the record to
    cubature Kalman filters: a state taken before the switch switches alike,
    one taken after it resumes the cubature Kalman loop with the switch's
    events."""
    session = _session(sessions, TEST_MODELS / "drivetrain.yaml")
    rows, run = _rows(session, "none", seed=2)
    (beliefs, whole), (later, resumed), at_cut = _round_trip(session, rows, run, cut, particles=500, seed=2)
    assert any(isinstance(e, ev.Switched) for e in whole.events) and whole.options.filter == "ckf"
    assert bool(at_cut.switched) == (cut == 0.9)  # the alarm, and the switch, at step 6
    _equal(beliefs, later, "beliefs")
    _equal(whole, resumed, "diagnosis")


def test_state_bytes_that_would_make_anything_else_are_refused_in_one_line():
    class Boom:
        def __reduce__(self):
            return (print, ("never",))

    for data in (MAGIC + pickle.dumps(Boom()), MAGIC + pickle.dumps(io.StringIO("x")), b"not a state",
                 MAGIC + b"\x80\x05garbage"):
        with pytest.raises(ArgumentValueError) as info:
            DiagnoserState.from_bytes(data)
        assert "DiagnoserState.from_bytes" in str(info.value) and "\n" not in str(info.value)


def test_a_state_is_taken_up_only_by_a_diagnoser_of_its_model(sessions):
    tanks = _session(sessions, MODELS / "two_tank.yaml")
    circuit = _session(sessions, MODELS / "circuit.yaml")
    d = tanks.diagnoser(particles=50)
    d.step(0.5, y={"F10": 0.1, "F12": 0.2, "F20": 0.1})
    other = circuit.diagnoser(particles=50)
    with pytest.raises(ArgumentValueError, match="a state of model 'two_tank'"):
        Diagnoser.from_state(other.config, d.to_state())


def test_a_diagnoser_taken_up_runs_on_its_own_count_of_processes(sessions):
    """The processes a diagnosis's hypotheses run on change no number, so a
    state holds to none (a monitor started again with another --workers):
    the diagnoser taken up runs on its configuration's, not the saver's."""
    tanks = _session(sessions, MODELS / "two_tank.yaml")
    d = tanks.diagnoser(DiagnosisOptions(particles=50, workers=1))
    d.step(0.5, y={"F10": 0.1, "F12": 0.2, "F20": 0.1})
    again = tanks.diagnoser(DiagnosisOptions(particles=50, workers=2))
    assert Diagnoser.from_state(again.config, d.to_state()).loop.options.workers == 2


@pytest.mark.numba
def test_a_diagnoser_on_the_compiled_backend_is_taken_up_alike():
    """The compiled kernels draw through a handle of each filter's generator:
    a filter taken up keeps its generator object, whose state is set, so the
    handle stays valid (numba, a test of the compiled backend): the RO
    plant's GPF, cut while tracking, on numba (the round trip of that case of
    CASES, which runs on FAST: numba, numba being installed; made once for
    both tests)."""
    pytest.importorskip("numba")
    session, ((beliefs, whole), (later, resumed), at_cut) = _case("ro", "gpf")
    assert session.backend == "numba" and at_cut.options.filter == "gpf"
    assert at_cut.loop.phase == "tracking" and at_cut.loop.trackers
    _equal(beliefs, later, "beliefs")
    _equal(whole, resumed, "diagnosis")


@pytest.mark.slow
def test_a_checkpoint_is_the_batch_diagnosis_of_the_data_so_far(sessions):
    """A checkpoint of the online diagnoser (the finish of a copy made from
    its state: the hypotheses it tracks online are not tracked again) equals
    the batch diagnosis of the rows so far, number for number."""
    session = _session(sessions, MODELS / "two_tank.yaml")
    rows, run = _rows(session, SCENARIOS["two_tank"], steps=STEPS["two_tank"])
    d = session.diagnoser(DiagnosisOptions(particles=200, seed=3, workers=1))
    k = 192  # 37 samples after the alarm (155), 48 rows before the end
    for t, u, y in rows[:k]:
        d.step(t, u, y)
    assert d.loop.phase == "tracking" and d.loop.trackers
    checkpoint = d.checkpoint()
    lines = runs.run_csv(run).splitlines(keepends=True)
    head = next(i for i, line in enumerate(lines) if line.startswith("time,"))
    prefix = dataclasses.replace(runs.parse_run("".join(lines[:head + 1 + k]), "prefix"), parameters={})
    batch = bgc.diagnose(session, data=prefix, options=d.options).diagnosis
    _equal(checkpoint, batch, "checkpoint")
    assert checkpoint.verdict == "isolated" and not d.finished  # the stream goes on
    d.step(*rows[k])
