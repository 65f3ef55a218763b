"""A gap longer than the diagnosis holds, bridged while watching.

A logger that was down for hours leaves a gap of more steps than a
diagnosis holds in memory (or than :data:`~bgc.data.sampler.MAX_GAP_STEPS`):
a diagnosis of one record refuses the row after it (``bgc diagnose``: split
the data at the gap). A monitor that is watching (no alarm in progress:
nothing looks back past the gap) bridges it instead: a new diagnoser of the
same model (the faults accommodated kept) takes the row after the gap as its
first, its observer started where the plant may be after the gap:

- **mean**: the nominal observer's last estimate before the gap, run on by
  the model (noise-free) with the inputs of the row after the gap held
  (its empty cells: the inputs held before), for the gap's steps but at
  most :data:`SETTLE` times the slowest time constant of the model's
  linearisation (its ``EIGENVALUES``) and :data:`MOST_STEPS`: a stable
  plant has forgotten where it was by then, and a longer run would only
  add the cost. A model with
  no stable eigenvalue, or one whose state holds a mode, is not run on (its
  mean is the last estimate);
- **spread**: each physical state's std grows to ``sqrt(s^2 + s0^2 + d^2)``,
  ``s`` the observer's std before the gap, ``s0`` the model file's initial
  spread (``X0_STD``; not a started package's, whose start is an estimate's) and ``d`` how far the run on moved it: what happened
  in the gap is not known (the inputs may have moved, and back), and the
  observer's first rows after it settle where the data say.

The detector's residuals are normalised by the observer's own predicted
spread, so a wide start raises no alarm; the new diagnoser's record, its
detector's windows and its fit test start at the row (as a monitor started
there would). :class:`~bgc.events.Bridged` says it.
"""

from __future__ import annotations

import math

import numpy as np

from .. import events as ev
from ..model.package import base_package, forget_started, started_package
from ..model.protocol import nominal_model

#: Time constants (of the slowest stable eigenvalue) the nominal model is run on across a gap.
SETTLE = 10.0
#: The most steps the model is run on (a plant this slow has hardly moved after them, and each costs a step).
MOST_STEPS = 20000


def bridged(d, t: float, u: dict, since: float, missing: int):
    """The diagnoser that takes the row of time ``t`` (inputs ``u`` by name)
    after ``missing`` steps with no sample since time ``since``, where
    diagnoser ``d`` is watching; and the :class:`~bgc.events.Bridged`
    event that says it. ``d``'s package goes (when it was started: its
    start is the new one's)."""
    nominal = d.nominal
    kinds = getattr(nominal, "STATE_KINDS", ("physical",) * len(nominal.STATES))
    physical = np.array([k == "physical" for k in kinds])
    if d.loop.samples:
        last = np.asarray(d.loop.x_mean[-1], dtype=float), np.asarray(d.loop.x_std[-1], dtype=float)
    else:  # a diagnoser that took no row yet (an episode closed): its start
        last = np.asarray(nominal.X0, dtype=float), np.asarray(nominal.X0_STD, dtype=float)
    mean, std = last[0].copy(), last[1].copy()
    steps = min(missing + 1, settle_steps(nominal), MOST_STEPS) if physical.all() else 0
    if steps:
        x = mean[:, None].copy()
        uk = d.sampler.row_inputs(t, u)
        theta = np.asarray(nominal.THETA, dtype=float)
        with np.errstate(all="ignore"):
            for _ in range(steps):
                nominal.predict(x, uk, theta, nominal.DT, out=x)
        if np.all(np.isfinite(x)):
            mean = x[:, 0]
        else:  # the model ran off: the last estimate
            steps = 0
    moved = mean - last[0]
    x0_std = np.asarray(nominal_model(base_package(d.config.package)).X0_STD, dtype=float)  # the model file's
    std = np.where(physical, np.sqrt(std ** 2 + x0_std ** 2 + moved ** 2), std)
    old = d.config.package
    package = started_package(old, mean, std)
    if package is not old:
        forget_started(old)
    event = ev.Bridged(float(since), float(t), int(missing), int(steps))
    return d.again(package), event


def settle_steps(nominal) -> int:
    """The steps of :data:`SETTLE` times the slowest stable time constant of
    ``nominal``'s linearisation (0: no stable eigenvalue given)."""
    rates = [-float(re) for re, _ in getattr(nominal, "EIGENVALUES", ()) if float(re) < 0.0]
    if not rates:
        return 0
    return int(math.ceil(SETTLE / min(rates) / float(nominal.DT)))
