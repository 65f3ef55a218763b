"""What bgc's own detector sees of a scenario: the probability that the test
the diagnosis runs (the nominal observer's residuals, the windowed Z-test at
its false-alarm rate) alarms on the fault, estimated from simulated runs
with an interval.

``bgc distinguish`` prints an ideal detector's probability of telling a
fault from no fault (a likelihood test of the whole run that knows the
fault's shape, :mod:`bgc.analysis.distinguish`). bgc's detector knows
neither the shape nor the onset: it tests the residuals' mean over windows
of 1, 8 and 32 samples at a false-alarm rate per horizon. Where the two
differ, the user sees the second: a scenario the ideal detector tells apart
at 0.98 may pass bgc's detector unseen (a slow drift, a small step near the
noise). This module measures it the only way that holds for every plant:
``runs`` scenario runs simulated at the session's noise levels (seeds
``seed``, ``seed + 1``, ...), each fed sample by sample to a diagnoser with
the diagnosis's default options until its first alarm; a run is *detected*
when that alarm comes at or after the onset's sample, a *false alarm* when
before. The probability is the detected fraction with its 95 % Wilson
score interval.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from ..analysis import simulate
from ..diagnosis.options import DiagnosisOptions
from ..model import linear
from ..model.protocol import onset_sample
from .session import Session

#: Simulated runs of a scenario, by default.
RUNS = 50
#: z of the two-sided 95 % interval.
_Z95 = 1.959963984540054


@dataclass(frozen=True, slots=True)
class DetectorRate:
    """How often bgc's detector alarmed on a scenario: ``detected`` of
    ``runs`` simulated runs at or after the onset, ``false_alarms`` before
    it, the detected fraction's 95 % Wilson interval (``low``, ``high``),
    the median delay from the onset to the alarm (time units; None: no
    detection), and the detector's settings: the filter and its particles,
    the false-alarm probability per ``horizon`` (time units), its tests."""

    runs: int
    detected: int
    false_alarms: int
    low: float
    high: float
    median_delay: float | None
    method: str
    particles: int
    false_alarm: float
    horizon: float
    first_seed: int
    time_unit: str | None = None
    detectors: tuple[str, ...] = ("mean",)
    #: The delays of the runs it detected (time units, in the order of the runs)
    delays: tuple[float, ...] = ()

    @property
    def median_over_runs(self) -> float:
        """The median delay over every run, a run not detected at or after
        the onset counted as never (inf when half of them were): what a
        bound on the median delay of any detector
        (:meth:`bgc.analysis.distinguish.Distinction.ideal_delay`) bounds."""
        every = sorted(self.delays) + [math.inf] * (self.runs - len(self.delays))
        return float(np.median(every)) if every else math.nan

    @property
    def probability(self) -> float:
        return self.detected / self.runs if self.runs else math.nan


def wilson(successes: int, n: int, z: float = _Z95) -> tuple[float, float]:
    """The Wilson score interval of a binomial proportion (``z``: 95 % by default).

    >>> [round(v, 4) for v in wilson(47, 50)]
    [0.8378, 0.9794]
    """
    if n == 0:
        return 0.0, 1.0
    p = successes / n
    centre = (p + z * z / (2 * n)) / (1 + z * z / n)
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / (1 + z * z / n)
    low = 0.0 if successes == 0 else max(0.0, centre - half)  # exactly the bound, not its rounding
    return low, 1.0 if successes == n else min(1.0, centre + half)


def detector_rate(session: Session, injection: simulate.FaultInjection, steps: int, runs: int = RUNS,
                  seed: int = 0, options: DiagnosisOptions | None = None, progress=None,
                  signals: tuple = (), schedule: tuple = ()) -> DetectorRate:
    """The rate at which the diagnosis's detector alarms on ``injection``
    (see the module docstring) over ``runs`` runs of ``steps`` samples,
    simulated at the session's noise levels (``signals``: (name,
    :class:`~bgc.ir.Signal`) pairs driving inputs instead of the model's);
    ``options``: the diagnosis's (default: :class:`DiagnosisOptions`'
    defaults, one process). A model with modes runs through its automaton
    and the controlled changes ``schedule`` ((time, mode) pairs), and its
    diagnoser reads each sample's mode from the run's mode column, as from
    a logger that records it."""
    opts = session.options(options or DiagnosisOptions(workers=1))
    dt = session.view.model.settings.dt
    detected = false = 0
    delays = []
    for i in range(runs):
        if progress is not None:
            progress(f"bgc's detector: simulated run {i + 1} of {runs}")
        time, rows = _simulated(session, injection, steps, seed + i, signals, schedule)
        onset = onset_sample(time, injection.time)
        d = session.diagnoser(dataclasses.replace(opts, seed=seed + i))
        for k, t in enumerate(time):
            alarm = d.step(float(t), *rows(k)).alarm
            if alarm is not None:  # (the change test's: when the record's test raised it)
                if alarm.raised >= onset:
                    detected += 1
                    delays.append((alarm.raised - onset) * dt)
                else:
                    false += 1
                break
    low, high = wilson(detected, runs)
    return DetectorRate(runs, detected, false, low, high, float(np.median(delays)) if delays else None,
                        opts.filter, opts.particles, opts.false_alarm, opts.horizon, seed,
                        session.view.model.settings.time_unit, tuple(opts.detectors), tuple(delays))


def _simulated(session: Session, injection, steps: int, seed: int, signals: tuple, schedule: tuple):
    """One truth-simulator run of ``injection`` at the session's noise
    levels: its times, and per step k the (inputs, measurements) a diagnoser
    takes (a model with modes: through its automaton and ``schedule``, the
    mode among the inputs, as the run's mode column gives it)."""
    process, measurement = session.noise
    if not session.view.modes:
        r = simulate.simulate(session.view.numerics, simulate.SimulationOptions(
            steps=steps, process_noise=process, measurement_noise=measurement, seed=seed, fault=injection,
            signals=signals))
        return r.time, lambda k: (r.inputs[k], r.measurements[k])
    from .simulate import simulated_run

    run = simulated_run(session.view, injection, injection.text, steps, seed, (process, measurement), signals,
                        schedule)

    def rows(k: int):
        u = {name: float(values[k]) for name, values in run.inputs.items()}
        u["mode"] = float(run.modes[k])
        return u, {name: float(values[k]) for name, values in run.measurements.items()}

    return run.time, rows


@dataclass(frozen=True, slots=True)
class Unseen:
    """A fault model bgc's detector would most often miss at the model's
    declared noise and inputs (:func:`unseen`): at the ``size`` its prior
    expects, the largest mean of the windowed statistic, ``reach``, stays
    under the detector's ``threshold``; ``still``: it changes nothing the
    sensors see while the inputs are constant (a capacitance or inductance
    at steady state); ``burst``: a burst of a sensor's noise, which moves no
    reading's mean whatever the inputs (the variance test sees it), so
    neither ``still`` nor a size the mean test would reach."""

    name: str
    size: float
    reach: float
    threshold: float
    still: bool
    burst: bool = False


def unseen(c, options: DiagnosisOptions | None = None) -> list[Unseen]:
    """The fault models of the compiled model ``c`` (a
    :class:`bgc.pipeline.Compiled`) whose detection the declared noise and
    inputs leave to chance: the closed form of
    :func:`bgc.analysis.distinguish.detector_reach` (the fault from mid-run
    of the model's declared run, at its prior's typical size) against the
    detector's threshold with the diagnosis's default settings
    (``options``). A fault whose mean statistic stays under the threshold
    is missed by one look at that window in more than half of the runs,
    to linear order (the statistic is that mean plus a standard normal); the
    detector's many looks over time catch some of them (measured: DC motor,
    R_a:abrupt:0.4167@2.5, mean 3.82 against 4.65: detected in 13 of 30
    simulated runs, ``bgc distinguish --detector-runs 30``)."""
    from ..analysis import distinguish as distinction
    from ..diagnosis.detect import DetectorOptions
    from ..diagnosis.diagnose import horizon_steps
    from ..kinds import fault_kind
    from ..model import package as packages
    from .folders import package_folder

    package = packages.load_package(package_folder(c), c.model.name, str(c.model.source), None)
    settings = c.model.settings
    opts = options or DiagnosisOptions()
    steps = settings.steps
    horizon = horizon_steps(opts.horizon, settings.dt, steps)
    threshold = DetectorOptions(opts.false_alarm, tuple(opts.windows), horizon,
                                tuple(opts.detectors)).threshold(len(c.model.measurements))
    reach = distinction.detector_reach(package, linear.scenario_inputs(package, steps), steps // 2,
                                       tuple(opts.windows))
    bursts = {name for name in reach if fault_kind(package.MODELS[name].FAULT["kind"]).noise}
    return [Unseen(name, size, r, threshold, r < 1e-6 * threshold and name not in bursts, name in bursts)
            for name, (size, r) in reach.items() if r < threshold]
