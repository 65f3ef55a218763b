""":func:`simulate`: a run of a model's plant from Python, with its truth (:class:`Simulation`)."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
import threading
from pathlib import Path
from typing import Any

import numpy as np

from .. import arguments
from ..analysis import simulate as simulation
from ..data import runs
from ..errors import ArgumentValueError, ModelError, SimulationError, printable
from . import cache
from .session import Session, _session_of, input_signals, scenario_of
from .tables import frame


@dataclass(frozen=True, slots=True)
class Simulation:
    """A simulated run of a model's plant: ``run`` (a
    :class:`~bgc.data.runs.Run`, what :func:`bgc.diagnose` takes as ``data``),
    the ``fault`` injected (None: fault-free), the ``scenario`` text and
    ``seed``. The arrays by name: ``time``, ``inputs``, ``measurements``
    (with sensor noise), ``states`` and ``parameters`` (the faulty
    parameter's true value at each sample) in the model's units; ``truth``
    the fault as injected; :meth:`to_frame` and :meth:`write` the run as a
    DataFrame and as a run file. A run of another length (``steps``) is
    another run: the same seed does not give the first samples of a longer one."""

    model: str
    scenario: str
    seed: int
    fault: simulation.FaultInjection | None
    run: runs.Run
    #: A model with modes: the changes of mode, in time order (each a :class:`bgc.analysis.hybrid.Switch`:
    #: ``time``, ``source``, ``target``, ``kind``); empty otherwise.
    switches: tuple = ()
    #: A model with modes: the modes' names, in the model's order (a mode's number is its place, from 1).
    mode_names: tuple[str, ...] = ()

    @property
    def modes(self) -> np.ndarray | None:
        """A model with modes: each sample's mode, as its number (1 for the first of ``mode_names``); else None."""
        return self.run.modes

    @property
    def time(self) -> np.ndarray:
        return self.run.time

    @property
    def inputs(self) -> dict[str, np.ndarray]:
        return self.run.inputs

    @property
    def measurements(self) -> dict[str, np.ndarray]:
        return self.run.measurements

    @property
    def states(self) -> dict[str, np.ndarray]:
        return self.run.states

    @property
    def parameters(self) -> dict[str, np.ndarray]:
        return self.run.parameters

    @property
    def truth(self) -> dict[str, Any]:
        """The fault as injected: ``fault`` (``NAME:KIND`` as the scenario
        names it, None when fault-free), ``hypothesis`` (the name bgc's
        diagnosis gives its fault model: ``R12_abrupt``, a sensor's
        ``F12_offset_bias``; what ``Diagnosis.candidates`` holds when it is
        named), ``target`` (parameter, sensor or actuator), ``magnitude`` (a
        step's size, a drift's rate per time unit) and ``onset`` (a time)."""
        f = self.fault
        if f is None:
            return {"fault": None, "hypothesis": None, "target": None, "magnitude": None, "onset": None}
        return {"fault": f"{f.subject or f.parameter}:{f.kind}", "hypothesis": f"{f.parameter}_{f.kind}",
                "target": f.target, "magnitude": f.magnitude, "onset": f.time}

    def to_frame(self):
        """The run as a pandas DataFrame: ``time``, then ``u:``, ``y:``, ``x:``
        and ``theta:`` columns as in a run file (``pip install 'bgc[data]'``)."""
        r = self.run
        columns = {"time": r.time}
        for prefix, group in (("u", r.inputs), ("y", r.measurements), ("x", r.states), ("theta", r.parameters)):
            columns.update({f"{prefix}:{name}": values for name, values in group.items()})
        names = list(columns)
        return frame([dict(zip(names, row)) for row in zip(*(columns[n].tolist() for n in names))], names)

    def write(self, path: str | Path) -> Path:
        """Write the run file ``bgc simulate -o`` writes (a new file, or one bgc
        wrote before and nobody changed since). Returns the path."""
        arguments.path("bgc.Simulation.write", "path", path)
        from ..output import artifacts

        return artifacts.write_file(Path(path), runs.run_csv(self.run))

    def __repr__(self) -> str:
        return (f"<bgc.Simulation of {self.model}: {printable(self.scenario)}, {len(self.run.time)} samples, "
                f"seed {self.seed}>")


def simulate(model: str | Path | Session, scenario: str | simulation.FaultInjection = "none", *, seed: int = 0,
             steps: int | None = None, inputs: Mapping[str, Any] | None = None,
             process_noise: float | None = None, measurement_noise: float | None = None,
             modes: str | None = None) -> Simulation:
    """Simulate ``model``'s plant (the model file, or a :class:`Session`) with
    ``scenario`` (``NAME:KIND:MAGNITUDE@TIME``, e.g. ``R12:abrupt:0.5@75``,
    or ``none``), as ``bgc simulate`` does: the truth simulator (RK4 on a
    finer grid than the filters'), process noise at the model's level (or
    ``process_noise``, relative), sensor noise likewise, ``steps`` samples
    (default: the model's), ``inputs`` driven otherwise than the model says
    (as in :func:`bgc.diagnose`), seeded by ``seed`` (bit for bit the same
    run for the same seed).

    >>> import bgc
    >>> sim = bgc.simulate("models/two_tank.yaml", "R12:abrupt:0.5@75", seed=1, steps=200)
    >>> sim.truth
    {'fault': 'R12:abrupt', 'hypothesis': 'R12_abrupt', 'target': 'parameter', 'magnitude': 0.5, 'onset': 75.0}
    >>> sorted(sim.measurements), float(sim.time[-1])
    (['F10', 'F12', 'F20'], 100.0)

    Raises
    ------
    ArgumentTypeError, ArgumentValueError
        An argument of the wrong type or out of range, a malformed scenario or
        one whose onset is outside the run.
    SimulationError
        The simulated plant diverges.
    """
    func = "bgc.simulate"
    if not isinstance(model, Session):
        arguments.path(func, "model", model)
    if not isinstance(scenario, simulation.FaultInjection):
        arguments.text(func, "scenario", scenario)
    arguments.integer(func, "seed", seed, 0, "is negative", "seed=0")
    if steps is not None:
        arguments.integer(func, "steps", steps, 1, "simulate at least 1 step", "steps=300")
    arguments.noise_levels(func, process_noise, measurement_noise)
    if modes is not None:
        arguments.text(func, "modes", modes)
    if not isinstance(model, Session):
        from .. import pipeline
        from ..compiler.load import declares_modes

        if declares_modes(model):
            h = pipeline.check_model(model)
            return _hybrid(func, h, h.numerics(), scenario, seed, steps, inputs, (process_noise, measurement_noise),
                           modes)
    elif model.view.modes:  # a session of a model with modes: its noise levels, its file as it was compiled
        _session_of(func, model, process_noise, measurement_noise, None, lambda text: None)
        return _hybrid(func, *_checked(model.view), scenario, seed, steps, inputs, model.noise, modes)
    if modes is not None:
        raise ArgumentValueError(f"{func}: modes={modes!r}, and the model has no modes", None, "drop modes=")
    if isinstance(model, Session):  # its noise levels apply, as in bgc.diagnose
        _session_of(func, model, process_noise, measurement_noise, None, lambda text: None)
        c, noise = model.view, model.noise
    else:
        c, noise = cache.open_model(model).view, (process_noise, measurement_noise)
    injected, _ = checked_scenario(func, c, scenario, steps)
    text = "none" if injected is None else injected.text
    run = simulated_run(c, injected, text, steps, seed, noise, input_signals(func, inputs, c.model))
    return Simulation(c.model.name, text, seed, injected, run)


def _hybrid(func: str, h, nums, scenario, seed: int, steps: int | None, inputs, noise,
            modes: str | None) -> Simulation:
    """:func:`simulate` of a model with modes (``h`` its check, ``nums`` each
    mode's numerics): its automaton (:mod:`bgc.analysis.hybrid`)."""
    from types import SimpleNamespace

    # the first mode's numbers read and check the scenario, as a compiled model's do
    injected, _ = checked_scenario(func, SimpleNamespace(model=h.model, numerics=nums[0]), scenario, steps)
    signals = input_signals(func, inputs, h.model)
    schedule = _schedule(func, modes, h.model.modes.names)
    text = "none" if injected is None else injected.text
    run, result = _automaton_run(h, nums, injected, text, steps, seed, noise, signals, schedule)
    return Simulation(h.model.name, text, seed, injected, run, result.switches, result.mode_names)


def _schedule(func: str, modes: str | None, names: tuple[str, ...]) -> tuple:
    """The controlled changes ``modes`` (``MODE@TIME,...``) of a model whose modes are ``names``."""
    from ..analysis import hybrid

    try:
        return hybrid.parse_schedule(modes, names)
    except SimulationError as exc:  # a malformed argument, told as one
        raise ArgumentValueError(f"{func}: {exc.what}", None, exc.fix) from None


def _automaton_run(h, nums, injected, text: str, steps: int | None, seed: int, noise, signals: tuple,
                   schedule: tuple):
    """The truth simulator's run of the model with modes ``h`` (its check,
    ``nums`` each mode's numerics) through the controlled changes
    ``schedule``: (the :class:`~bgc.data.runs.Run`, the simulator's result)."""
    from ..analysis import hybrid

    options = simulation.SimulationOptions(steps=steps, process_noise=noise[0], measurement_noise=noise[1],
                                           seed=seed, fault=injected, signals=signals)
    result = hybrid.simulate(h, nums, options, schedule)
    return runs.parse_run(hybrid.to_csv(result), f"scenario {text}"), result


#: Checked models with modes and their modes' numerics, by model file and text (a campaign's worker
#: simulates many runs of a few models; the view a session holds has no truth simulator of the modes),
#: and the lock its threads (a Dask worker's) share.
_CHECKED: dict[tuple[str, str], tuple] = {}
_CHECKED_LOCK = threading.Lock()


def _checked(c) -> tuple:
    """(the check of the compiled model with modes ``c``'s file, each mode's
    numerics), made once per file and text; the file as it was compiled
    (its text changed since: a one-line error, never another model's run)."""
    import hashlib

    from .. import pipeline

    path = c.model.source
    try:
        text = Path(path).read_bytes()
    except OSError as exc:
        raise ModelError(f"{printable(str(path))}: cannot read the model file to simulate it ({exc.strerror})",
                         None, "open the model again from where its file is") from None
    digest = hashlib.sha256(text).hexdigest()
    if c.model.source_sha256 and digest != c.model.source_sha256:
        raise ModelError(f"{printable(str(path))} changed since it was compiled: its run would not be of the model "
                         "diagnosed", None, "open the model again (bgc.open) and simulate from that session")
    key = (str(path), digest)
    with _CHECKED_LOCK:
        found = _CHECKED.get(key)
        if found is None:
            h = pipeline.check_model(path)
            found = (h, h.numerics())
            while len(_CHECKED) >= 8:
                _CHECKED.pop(next(iter(_CHECKED)))
            _CHECKED[key] = found
    return found


def checked_scenario(func: str, c, scenario, steps: int | None) -> tuple[simulation.FaultInjection | None, str]:
    """``scenario`` of the compiled model ``c`` (:mod:`bgc.view`) read once
    (:func:`~bgc.api.session.scenario_of`) and checked before any work, with
    the run's length (``steps``, default the model's): its arrays within
    bgc's limits, its onset inside the run. Returns the injection (None:
    fault-free) and how the request's length is named in messages."""
    T = steps or c.model.settings.steps
    where = arguments.spelled(f"{func}: steps={steps}", "--steps") if steps is not None else \
        f"{printable(c.model.source)}: simulation.steps"
    simulation.check_steps(T, c.numerics, where)
    injected = scenario_of(func, scenario, c.numerics, getattr(c, "modules", None))
    last = T * c.model.settings.dt
    if injected is not None and not 0 < injected.time < last:
        raise (SimulationError if arguments.DOOR.get() == "cli" else ArgumentValueError)(
            f"{arguments.spelled(f'{func}: scenario', 'scenario')} {printable(injected.text)}: onset "
            f"{injected.time:g} is outside the run (0 to {last:g})", None,
            f"choose an onset inside the run, or more {arguments.spelled('steps', '--steps')}")
    return injected, where


def simulated_run(c, injected: simulation.FaultInjection | None, text: str, steps: int | None, seed: int,
                  noise: tuple[float | None, float | None], signals: tuple = (),
                  schedule: tuple = ()) -> runs.Run:
    """The truth simulator's run of ``c`` with the fault ``injected`` (checked
    by :func:`checked_scenario`), at the relative ``noise`` levels, as a
    :class:`~bgc.data.runs.Run` whose source is ``scenario TEXT``; a model
    with modes through its automaton and the controlled changes ``schedule``
    ((time, mode) pairs, sorted)."""
    if c.modes:
        h, nums = _checked(c)
        return _automaton_run(h, nums, injected, text, steps, seed, noise, signals, schedule)[0]
    result = simulation.simulate(c.numerics, simulation.SimulationOptions(
        steps=steps, process_noise=noise[0], measurement_noise=noise[1], seed=seed, fault=injected,
        signals=signals))
    return runs.parse_run(simulation.to_csv(result), f"scenario {text}")
