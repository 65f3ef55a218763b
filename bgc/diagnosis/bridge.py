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
  no stable eigenvalue is not run on (its mean is the last estimate);
  a model with modes takes the slowest time constant of any of its modes,
  and its hidden mode (the data have no mode column) follows its guards in
  the run on; where the data set the mode (a controlled transition) it is
  not run on: what the modes were in the gap is not known, and a mode held
  alone need not settle where the plant's cycle keeps it (RO's secondary
  valve setting fills its tank until a purge);
- **spread**: each physical state's std grows to ``sqrt(s^2 + s0^2 + d^2)``,
  ``s`` the observer's std before the gap, ``s0`` the model file's initial
  spread (``X0_STD``; not a started package's, whose start is an estimate's) and ``d`` how far the run on moved it: what happened
  in the gap is not known (the inputs may have moved, and back), and the
  observer's first rows after it settle where the data say.

A model whose state holds its mode may be anywhere on the course it settles
into (a level switch cycling a pump: at an unknown point of the cycle, in
either mode): its start is the mean of the run on's second half (none: of
the observer's estimates before the gap, those in the row's mode where the
data give it and the record has two or more), each physical state's spread
widened by that half's variance too, and the mode's reader (the data have
no mode column) starts from one branch per mode visited there, at that
mode's points' mean and covariance (the physical states and the time in
the mode together), weighed by their share
(:meth:`~bgc.diagnosis.hidden.ModeDecoder.start_among`); the mode before is
not known, so the first mode decided is no change of mode.

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
    x0_std = np.asarray(nominal_model(base_package(d.config.package)).X0_STD, dtype=float)  # the model file's
    uk = d.sampler.row_inputs(t, u)
    moded = getattr(nominal, "MODE_ROW", None) is not None
    # the mode hidden (no mode column; a diagnoser that took no row yet, an episode's, reads it from the first)
    hidden = moded and (d.decoder is not None or nominal.INPUTS[nominal.MODE_INPUT] not in u)
    if hidden:  # the model switches by its own guards in the run on
        uk[nominal.MODE_INPUT] = np.nan
    # a mode the data set (a controlled transition): what the modes were in the gap is not known, and one mode
    # held alone need not settle (RO's secondary setting fills its tank until a purge), so no run on
    steps = 0 if moded and not hidden else min(missing + 1, settle_steps(nominal), MOST_STEPS)
    course = _run_on(nominal, last[0], uk, steps)
    if course is None:
        steps = 0
    old = d.config.package
    if not moded:
        mean = last[0] if course is None else course[-1]
        moved = mean - last[0]
        std = np.where(physical, np.sqrt(last[1] ** 2 + x0_std ** 2 + moved ** 2), last[1])
        branches = None
    else:
        mean, std, branches = _settled(nominal, course, d, last, x0_std, float(uk[nominal.MODE_INPUT]))
    package = started_package(old, mean, std)
    if package is not old:
        forget_started(old)
    modes = ()
    new = d.again(package)
    if hidden:  # (a model with modes: its branches)
        new.start_among(*branches)
        modes = tuple(nominal.MODES[int(m[nominal.MODE_ROW]) - 1] for m in branches[0])
    return new, ev.Bridged(float(since), float(t), int(missing), int(steps), moded, modes)


def _run_on(nominal, x: np.ndarray, u: np.ndarray, steps: int) -> np.ndarray | None:
    """The model's noise-free course from state ``x`` at inputs ``u`` over
    ``steps`` steps (steps x states, the state after each); None when there
    are none or it ran off (not finite)."""
    if not steps:
        return None
    x = np.asarray(x, dtype=float)[:, None].copy()
    theta = np.asarray(nominal.THETA, dtype=float)
    course = np.empty((steps, len(x)))
    with np.errstate(all="ignore"):
        for k in range(steps):
            nominal.predict(x, u, theta, nominal.DT, out=x)
            course[k] = x[:, 0]
    return course if np.all(np.isfinite(course)) else None


def _settled(nominal, course: np.ndarray | None, d, last: tuple, x0_std: np.ndarray, mode: float = math.nan):
    """A model whose state holds its mode, after a gap: where it may be is
    anywhere on its settled course (a plant that cycles through its modes
    is at an unknown point of its cycle), the second half of the run on
    (``course``); with none (the data set the mode), anywhere the observer's
    estimates over the record before the gap were in the row's ``mode``
    (all of them where none was). Returns the start's mean and std (those
    points', each physical state's widened as in the module docstring, the
    mode and time in it the last point's) and the mode reader's branches:
    one per mode visited there, at that mode's points' mean and covariance
    (the physical states' widened as the start's, the time in the mode
    with them; other rows, a threshold's draw, the last point's), weighed
    by their share."""
    kinds = getattr(nominal, "STATE_KINDS", ("physical",) * len(nominal.STATES))
    physical = np.array([k == "physical" for k in kinds])
    if course is not None:
        points = course[len(course) // 2:]
    else:
        points = np.asarray(d.loop.x_mean, dtype=float) if d.loop.samples else last[0][None]
        mine = points[np.rint(points[:, nominal.MODE_ROW]) == mode] if math.isfinite(mode) else points[:0]
        points = mine if len(mine) >= 2 else points
    s, s0 = last[1], x0_std
    mean = points.mean(axis=0)
    mean[~physical] = points[-1][~physical]
    moved = mean - last[0]
    std = np.where(physical, np.sqrt(s ** 2 + s0 ** 2 + points.var(axis=0) + moved ** 2), s)
    row = nominal.MODE_ROW
    modes = np.rint(points[:, row]).astype(int)
    # the physical states and the time in the mode move along the course together (a timed mode's level and
    # its time in it): their covariance over the mode's points, the rest (a threshold's draw) the last point's
    moving = np.array([k in ("physical", "dwell") for k in kinds])
    means, covariances, weights = [], [], []
    for mode in np.unique(modes):
        mine = points[modes == mode]
        m = np.where(moving, mine.mean(axis=0), mine[-1])
        m[row] = mode
        centred = (mine - m)[:, moving]
        cov = np.zeros((len(kinds), len(kinds)))
        cov[np.ix_(moving, moving)] = centred.T @ centred / len(mine)
        cov[physical, physical] += (s ** 2 + s0 ** 2)[physical]
        means.append(m)
        covariances.append(cov)
        weights.append(len(mine))
    return mean, std, (np.array(means), np.array(covariances), np.array(weights, dtype=float))


def settle_steps(nominal) -> int:
    """The steps of :data:`SETTLE` times the slowest stable time constant of
    ``nominal``'s linearisation (a model with modes: of any of its modes'
    modules; 0: no stable eigenvalue given)."""
    modules = (nominal,) + tuple(getattr(nominal, "_MODULES", ()))
    rates = [-float(re) for m in modules for re, _ in getattr(m, "EIGENVALUES", ()) if float(re) < 0.0]
    if not rates:
        return 0
    return int(math.ceil(SETTLE / min(rates) / float(nominal.DT)))
