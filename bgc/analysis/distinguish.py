"""Which faults the data of a scenario can tell apart, predicted from the model.

TRANSCEND's signatures (``bgc show signatures``) say which faults the
qualitative symbols of the residuals cannot separate. Whether the *data* can
separate two faults depends on more: the noise, the size of the fault, how long
it acts, and its kind. A slow drift of one resistor may move the sensors along
almost the same direction as a slow drift of another for a hundred samples,
with the difference under the noise, although their signatures differ in a
second-order symbol that such a drift hardly shows.

This module predicts that difference before any data are seen. It is the
distinguishability of Eriksson, Frisk and Krysander (2013, "A method for
quantitative fault diagnosability analysis of stochastic linear descriptor
models", Automatica 49(6)): the Kullback-Leibler divergence between the
distributions of the measurements under two faults, the second's magnitude
and onset chosen to make it smallest. For Gaussian measurement sequences with
a common covariance, what a Bayes classifier weighs, the log Bayes factor
``B`` of the true fault ``i`` against a rival ``j``, is itself Gaussian over
the data sets the noise can produce, with

* mean ``E = D(i, j) - D(i, i)``: the divergence of the truth from the rival's
  best fit, less that from the truth's own best fit within the same
  (linearised) family of responses, so that the family's approximation error
  cancels;
* variance ``V = 2 D(a, b)``: twice the divergence between the two best fits.

The diagnoser, which also weighs the faults' prior probabilities, names the
truth over ``j`` when ``B > log(prior_j / prior_i)``, which happens with
probability ``Phi((E - log(prior_j / prior_i)) / sqrt(V))``. The rivals for
which that probability is under ``level`` (default 0.95) are the scenario's
**predicted ambiguity group**: faults the data are not expected to separate
from the truth.

How the divergences are computed
--------------------------------
* The noise-free nominal run of the generated model from ``X0`` under the run's
  inputs; its linearisation along the run: ``F_k`` (the step into sample k,
  with respect to the state before it) and ``H_k`` (the measurements at sample
  k), by central differences of the generated ``predict`` and ``observe``.
* The whitening operator ``W`` of the nominal model: the innovations of its
  time-varying Kalman filter (process and measurement stds of the package,
  the initial spread ``X0_STD``), each divided by the Cholesky factor of its
  covariance. For measurement sequences with mean ``mu`` and the nominal
  model's covariance ``Sigma``, ``||W (y - mu)||^2 = (y - mu)' Sigma^-1 (y - mu)``,
  so a divergence is half a squared norm of whitened deviations.
* Each fault model's response to a unit magnitude from every onset ``tau``:
  its state augmented with the fault states, linearised at the nominal run
  (the fault states at their nominal values), started at sample ``tau`` with
  the magnitude at 1 (the onset convention of ``track.onset_transition``: the
  sample sees the fault, the states move after it). Whitened, these columns
  span the family of the fault's mean deviations; the best fit of a target is
  a least-squares projection per onset, with the magnitude kept inside the
  bounds of its prior.
* The truth's deviation from the nominal run, by the fault model itself
  (nonlinear), at its magnitude and onset.

Approximations, stated: the covariance of the measurements is the nominal
model's under every hypothesis (a fault that changes a time constant also
changes the noise's colour; the divergence leaves that out); the rivals'
families are linearised (their fit is judged against the truth's own
linearised family, so a shared error cancels; a bound of a prior is applied to
the linearised response, which maps it only roughly); the Bayes factor's Occam
terms (the prior widths of the magnitudes and onsets) are left out.

Noise faults
------------
A noise fault (``bgc.kinds``: a burst of measurement noise, the sensor's
noise std times ``k = 1 + b``) moves no mean, so the common-covariance
account above does not see it; it is predicted from the change of the
covariance instead (:func:`noise_divergence`). The nominal Kalman filter's
innovations keep their mean and their covariance ``S_k`` grows by
``(k^2 - 1) R_j`` on the sensor's entry; on the sensor's whitened
direction that is a variance ratio ``1 + delta_k``, ``delta_k = (k^2 - 1)
R_j (S_k^-1)_jj``, and the divergence from no fault is the sum over the
samples from the onset of ``(delta_k - log(1 + delta_k)) / 2`` (the
``(k^2 - 1 - log k^2) / 2`` per sample of a sensor whose innovation is its
noise alone, ``R_j = S_k``). Stated approximations: the innovations are
taken as independent from sample to sample (the burst also leaks into the
filter's state estimates, which correlates them) and the rivals of a noise
fault fit its unchanged mean best with no change of their own: each is as
far from the truth as no fault is (expected log Bayes factor the
divergence, variance twice it). A noise fault as the rival of a fault that
moves the mean explains the share of the deviation on its own sensor by a
wider noise (its best factor and onset on a grid), and nothing of the
other sensors' (:func:`_noise_fit`).

Stuck switches
--------------
A switched junction stuck ON or OFF (a model with modes; ``bgc.kinds``'
``stuck_on``, ``stuck_off``) has no size: its fault model's magnitude is a
flag. Its family is its own noise-free runs from every onset of the grid, by
the fault model itself (nonlinear, not linearised): as the truth, its
deviation from the nominal run is its run from the scenario's onset, and its
own family's best fit is itself (no misfit); as a rival, its best fit is the
onset whose run comes nearest the truth's whitened deviation, or no fault
when none comes nearer than no fault does (:func:`_stuck_fit`). The rest is
as for any fault: a rival the truth's name is less than ``SURE`` likely
against is judged again with both runs' own covariances (:func:`divergence`:
a stuck switch changes the plant's dynamics, and so its noise's colour). On
a plant whose transitions its own guards make, the truth's run follows the
faulty plant's own modes (the scenario's ``us``: a relay welded shut keeps
the voltage under the guard that would have opened it); a stuck rival's runs
follow their own too, by the generated model's guards and timers and the
nominal run's commands (:func:`_own_modes`); a sized rival's family is
linearised along the nominal run, through the nominal plant's modes.
"""

from __future__ import annotations

from .. import arguments

import dataclasses
import math
from dataclasses import dataclass, field

import numpy as np

from ..errors import TrackingError
from ..ir import Numerics
from ..kinds import SWITCH_KINDS, fault_kind, fault_parameter, stuck_title
from .simulate import MAX_STEPS
from ..model.protocol import FaultModel, Package, magnitude_row, nominal_model, sized_models, stuck_models
from ..model.linear import (Whitening, jacobian as _jacobian, linearised as _linearised, noise as _noise,
                            scales as _scales, typical_size, unit_responses as _unit_responses,
                            whitening as _whitening)

#: A rival is in the predicted ambiguity group when the data, with the priors,
#: are expected to name the truth over it with a probability under this.
LEVEL = 0.95
#: Most onsets per family: a longer run takes every k-th sample as an onset.
MAX_ONSETS = 400
#: The false-alarm probability per run (bgc's detector's default per horizon, a run's length:
#: :class:`~bgc.diagnosis.options.DiagnosisOptions`) at which the ideal detector is held where a
#: campaign or a prediction without measured runs compares with it.
FALSE_ALARM = 0.01
#: Memory the arrays of one prediction may take (:func:`memory`); a longer run
#: is refused before any work (:func:`check_steps`).
MAX_BYTES = 2_000_000_000


@dataclass(frozen=True, slots=True)
class Families:
    """What a package and a run's inputs give once, for every scenario on
    them: the nominal run (``x_before[k]``: the state before the step into
    sample k; ``x_after[k]``: after it; ``y``: its measurements), the
    whitening operator, and per fault model (``names``) its whitened unit
    responses (T n_y, onsets) from each of ``onsets`` and the bounds of its
    magnitude's prior (``bounds``); ``stuck``: the stuck switches' fault
    models, whose families are their own runs from each onset (no size:
    nothing linearised is kept for them)."""

    package: Package
    us: np.ndarray
    x_before: np.ndarray
    x_after: np.ndarray
    y: np.ndarray
    whitening: Whitening
    onsets: np.ndarray
    names: tuple[str, ...]
    responses: tuple[np.ndarray, ...]
    bounds: tuple[tuple[float, float], ...]
    stuck: tuple[str, ...] = ()
    #: Per stuck switch, its whitened noise-free runs (T n_y, onsets) from each of ``onsets``: its family
    stuck_runs: tuple[np.ndarray, ...] = ()

    def response(self, name: str) -> np.ndarray:
        return self.responses[self.names.index(name)]


@dataclass(frozen=True, slots=True)
class Rival:
    """A rival fault model against the truth: ``expected`` and ``std`` of the
    log Bayes factor of the truth against it over the data sets the noise can
    produce; ``probability`` that the data, with the priors, name the truth
    over it; its best fit to the truth's deviation: ``onset`` (a sample) and
    ``magnitude`` (linearised; ``stuck``, a stuck switch: 1, stuck from the
    onset, or 0, no fault fits better)."""

    name: str
    expected: float
    std: float
    probability: float
    onset: int
    magnitude: float
    stuck: bool = False


@dataclass(frozen=True, slots=True)
class Distinction:
    """What the data of one scenario are predicted to tell: the true fault
    model ``truth`` with its ``magnitude`` from sample ``onset``;
    ``divergence``: its Kullback-Leibler divergence from the nominal model
    (its detectability: 0 when no sensor sees it); ``misfit``: that from its
    own linearised family's best fit (the linearisation's error); the
    ``rivals``, least separable first; ``level``: the probability under which
    a rival is in the predicted ambiguity group; ``reach``: the squared norm
    of the truth's whitened deviation from no fault summed from the onset to
    each sample (``reach[i]`` to sample ``onset + i``; twice the divergence
    of the data up to it; empty for a noise fault), what
    :meth:`ideal_delay` reads."""

    truth: str
    magnitude: float
    onset: int
    divergence: float
    misfit: float
    rivals: tuple[Rival, ...]
    level: float = LEVEL
    reach: tuple[float, ...] = field(default=(), repr=False)

    @property
    def group(self) -> tuple[str, ...]:
        """The rivals the data are not expected to separate from the truth."""
        return tuple(r.name for r in self.rivals if r.probability < self.level)

    @property
    def separable(self) -> bool:
        return not self.group

    @property
    def detectability(self) -> float:
        """The probability that the data favour the fault over no fault (the
        rule of the rivals, with equal priors: the log Bayes factor has mean
        ``divergence`` and variance twice that)."""
        return _normal_above(self.divergence, math.sqrt(2.0 * self.divergence))

    def power(self, false_alarm: float) -> float:
        """The probability that the ideal detector, the likelihood-ratio test
        of this fault (its onset and magnitude known) against no fault, held
        at the false-alarm probability ``false_alarm``, detects it
        (:func:`ideal_power`)."""
        return ideal_power(self.detectability, false_alarm)

    def ideal_delay(self, false_alarm: float) -> int | None:
        """The fewest samples after the onset by which any detector holding
        the false-alarm probability ``false_alarm`` over the run can alarm in
        half of the runs with this fault (its median delay's lower bound);
        None when even the whole run does not let it (or for a noise fault,
        whose ``reach`` is not kept).

        An alarm by sample k is a test of no fault against this fault on the
        data up to k, whose size is at most ``false_alarm`` (it is at most
        the run's false-alarm probability). By Neyman and Pearson no such
        test detects more often than the likelihood-ratio test of this fault,
        its onset and magnitude known; on the whitened innovations its log
        ratio is N(V/2, V) under the fault and N(-V/2, V) under no fault,
        V = ``reach`` up to k, so its power is Phi(sqrt(V) - z), z =
        Phi^-1(1 - ``false_alarm``): at least a half once V >= z^2. Exact for
        a fault that shifts the residuals' mean on a plant linear in its
        states (the approximations of the module's docstring otherwise); a
        detector that does not know the fault's shape, onset or size, and
        holds its rate over windows, needs longer.

        >>> d = Distinction("R_drift", 1.0, 10, 8.0, 0.0, (), reach=(1.0, 3.0, 5.5, 8.0))
        >>> d.ideal_delay(0.01), d.ideal_delay(0.05), d.ideal_delay(0.001)
        (2, 1, None)
        """
        from statistics import NormalDist

        z = NormalDist().inv_cdf(1.0 - false_alarm)
        need = z * z if z > 0 else 0.0
        return next((i for i, v in enumerate(self.reach) if v >= need), None)

    @property
    def label(self) -> str:
        """``PARAM+:kind`` or ``PARAM-:kind``, as the signatures name a fault;
        a stuck switch as ``K stuck ON``."""
        parameter = fault_parameter(self.truth)
        kind = self.truth[len(parameter) + 1:]
        if kind in SWITCH_KINDS:
            return stuck_title(parameter, kind)
        return f"{parameter}{'+' if self.magnitude >= 0 else '-'}:{kind}"


def memory(steps: int, states: int, outputs: int, inputs: int, fault_models: int, stuck: int = 0) -> int:
    """The bytes the largest arrays of a prediction over ``steps`` samples
    take at once, for a model of ``states`` states, ``outputs`` sensors,
    ``inputs`` inputs and ``fault_models`` fault models (each with up to 2
    fault states), counted per sample in 8-byte numbers: the nominal run
    (inputs, states before and after each step, measurements); the
    Jacobians ``F`` (n x n) and ``H`` (n_y x n), the gains ``K`` and the
    whitening ``Linv``; the central differences' scratch (the displaced
    states and their images, 4 n_z^2); every fault model's whitened unit
    responses (n_y x onsets, kept for every scenario; the onsets counted
    as ``min(steps, MAX_ONSETS)``, an upper bound of what :func:`prepare`
    takes, so that the estimate grows with the steps), with either one
    fault model's unwhitened responses being whitened or the exact fit's
    grid (its runs' states before and after each step, measurements and
    whitened deviations, 99 columns); and two linearised fault runs (their
    own F, H, K, Linv). On the shipped models this is 2 to 10 % above the
    peak tracemalloc measures when the onsets are close to ``MAX_ONSETS``
    (the circuit: 132 kB a sample, measured 127 kB at 800 and 1600 samples
    and 120 kB at 3000; the RO plant: 178 kB, measured 172 and 162 kB at
    800 and 3000), up to about twice it just past a multiple of
    ``MAX_ONSETS`` (the two tanks at 450 samples, 225 onsets: 1.7 times).
    ``stuck`` stuck switches (a model with modes): each one's whitened runs
    from every onset kept (n_y x onsets), and one's runs being made (their
    states before and after each step, measurements and deviations)."""
    n, n_y, n_u, n_f = states, outputs, inputs, fault_models
    n_z = n + 2
    onsets = min(steps, MAX_ONSETS)  # prepare takes every k-th sample: between half this and this many
    grid = len(_ONSET_OFFSETS) * len(_FACTORS)
    per_step = (n_u + 3 * n + n_y                              # the nominal run
                + n * n + 2 * n * n_y + n_y * n_y              # F, H, K, Linv
                + 4 * n_z * n_z                                # central differences
                + n_f * n_y * onsets                           # the whitened unit responses
                + max(n_y * onsets, grid * (2 * n_z + 3 * n_y),  # one family being whitened, or the exact fit,
                      onsets * (2 * n_z + 3 * n_y) if stuck else 0)  # or one stuck switch's runs being made
                + stuck * n_y * onsets                         # the stuck switches' whitened runs
                + 2 * (n_z * n + 2 * n * n_y + n_y * n_y + n_y))  # two linearised fault runs
    return 8 * steps * per_step


def most_steps(num: Numerics, stuck: int = 0) -> int:
    """The longest run whose prediction stays within ``MAX_BYTES`` (``stuck``: the model's stuck switches)."""
    size = (*_sizes(num), stuck)
    lo, hi = 0, MAX_STEPS  # no run is longer than bgc simulates
    while lo < hi:  # memory grows with the steps
        mid = (lo + hi + 1) // 2
        if memory(mid, *size) <= MAX_BYTES:
            lo = mid
        else:
            hi = mid - 1
    return lo


def check_steps(steps: int, num: Numerics, where: str, stuck: int = 0) -> None:
    """Refuse, before any work, a prediction over ``steps`` samples whose
    arrays would take more than ``MAX_BYTES`` (:func:`memory`; ``stuck``:
    the model's stuck switches); ``where`` names the request (``--steps``,
    or the model's ``simulation.steps``)."""
    need = memory(steps, *_sizes(num), stuck)
    if need > MAX_BYTES:
        most = most_steps(num, stuck)
        what = "bgc distinguish" if arguments.DOOR.get() == "cli" else "the prediction"
        raise TrackingError(f"{where}: {steps} steps: {what} would take about {need / 1e9:.3g} GB for "
                            f"{num.equations.model.name} (at most {most} steps for this model)", None,
                            "give fewer steps, e.g. " + arguments.spelled(f"steps={min(most, 300)}",
                                                                          f"--steps {min(most, 300)}"))


def _sizes(num: Numerics) -> tuple[int, int, int, int]:
    ssm = num.equations
    return len(ssm.states), len(ssm.outputs), len(ssm.inputs), len(num.faults)


def prepare(package: Package, us: np.ndarray, progress=None) -> Families:
    """The nominal run, its whitening and every fault model's whitened unit
    responses, for the inputs ``us`` (T, n_u) of a run; ``progress(text)``,
    when given, is told what is being done."""
    say = progress or (lambda text: None)
    say("preparing the families: the nominal run and its Kalman filter")
    us = np.asarray(us, dtype=float).reshape(len(us), -1)
    T = len(us)
    x_before, x_after, y, F, H, whitening = _linearised(package, us)
    stride = max(1, math.ceil(T / MAX_ONSETS))
    onsets = np.arange(0, T, stride)
    names, responses, bounds = [], [], []
    faulty = sized_models(package)  # a stuck switch's family is its own runs (stuck_models): nothing to keep
    for i, name in enumerate(faulty, start=1):
        say(f"preparing the families: fault model {i} of {len(faulty)} ({name})")
        model = package.MODELS[name]
        G = _unit_responses(model, F, H, x_before, x_after, us, onsets)
        responses.append(whitening.apply(G).reshape(T * H.shape[1], len(onsets)))
        names.append(name)
        lo, hi = (float(b) for b in model.FAULT_PRIOR)
        bounds.append((lo, hi))
    stuck = tuple(stuck_models(package))
    families = Families(package, us, x_before, x_after, y, whitening, onsets, tuple(names), tuple(responses),
                        tuple(bounds), stuck)
    runs = []
    for i, name in enumerate(stuck, start=1):
        say(f"preparing the families: stuck switch {i} of {len(stuck)} ({name})")
        dev = deviations(families, name, np.ones(len(onsets)), onsets)
        runs.append(whitening.apply(dev).reshape(-1, len(onsets)))
    return dataclasses.replace(families, stuck_runs=tuple(runs)) if runs else families


def detector_reach(package: Package, us: np.ndarray, onset: int, windows: tuple[int, ...]) -> dict[str, tuple]:
    """How far each fault model, at the size its prior expects
    (:func:`typical_size`) from sample ``onset``, moves bgc's detector:
    (size, the largest mean of the windowed statistic) by name. The
    statistic's mean is that of the linearised nominal Kalman filter's
    whitened innovations (the fault's noise-free deviation through
    :class:`Whitening`), summed over each window of ``windows`` samples and
    divided by its square root, per whitened sensor: a closed form of the
    detector's test (the nominal observer's residuals normalised per sensor
    and windowed) to linear order, where the whitening stands for the
    per-sensor normalisation (exact when the innovations of the sensors are
    uncorrelated). With noise, the statistic at that window is that mean plus
    a standard normal: a mean under the detector's threshold passes unseen in
    most runs."""
    us = np.asarray(us, dtype=float).reshape(len(us), -1)
    x_before, x_after, _, F, H, whitening = _linearised(package, us)
    out = {}
    for name in sized_models(package):
        model = package.MODELS[name]
        size = typical_size(*(float(b) for b in model.FAULT_PRIOR))
        e = whitening.apply(_unit_responses(model, F, H, x_before, x_after, us, np.array([onset])))[:, :, 0] * size
        sums = np.vstack([np.zeros((1, e.shape[1])), np.cumsum(e, axis=0)])
        reach = max((float(np.max(np.abs(sums[w:] - sums[:-w]))) / math.sqrt(w) for w in windows if w <= len(e)),
                    default=0.0)
        out[name] = (size, reach if math.isfinite(reach) else 0.0)
    return out


def deviations(families: Families, name: str, magnitudes, onsets, us: np.ndarray | None = None) -> np.ndarray:
    """The noise-free deviations (T, n_y, M) of fault model ``name``'s
    measurements from the nominal run's, column m with ``magnitudes[m]``
    from sample ``onsets[m]`` (zero before it), by the fault model itself;
    ``us``: its inputs (None: the families')."""
    return _fault_runs(families, name, magnitudes, onsets, us)[2] - families.y[:, :, None]


def _fault_runs(families: Families, name: str, magnitudes, onsets,
                us: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Fault model ``name``'s noise-free runs, column m with ``magnitudes[m]``
    from sample ``onsets[m]``: its states before and after each step (T, n_z,
    M) and its measurements (T, n_y, M); before its onset a column is the
    nominal run (its fault states nominal). The transition into an onset
    sample is nominal, the sample sees the fault (``track.onset_transition``).
    Every column runs from the earliest onset; until its own, its magnitude
    is zero, which is the nominal model. ``us``: the inputs from the
    earliest onset on (None: the families'; a model with modes: a mode
    column the fault makes its own)."""
    model = families.package.MODELS[name]
    own = _own_modes(families, model) if us is None else None
    us = families.us if us is None else us
    T, n = families.x_after.shape
    magnitudes = np.asarray(magnitudes, dtype=float).ravel()
    onsets = np.asarray(onsets, dtype=int).ravel()
    M = len(onsets)
    fixed = np.tile(np.asarray(model.X0, dtype=float)[n:], (T, 1))
    row = magnitude_row(model)
    fixed[:, row - n] = 0.0  # the magnitude nominal before the onset (a stuck switch's flag starts at 1 in X0)
    before = np.repeat(np.hstack([families.x_before, fixed])[:, :, None], M, axis=2)
    after = np.repeat(np.hstack([families.x_after, fixed])[:, :, None], M, axis=2)
    y = np.repeat(families.y[:, :, None], M, axis=2)
    first = int(onsets.min()) if M else T
    if first >= T:
        return before, after, y
    theta = np.asarray(model.THETA, dtype=float)
    z = after[first].copy()
    z[row] = 0.0  # the onset rule: the transition into an onset sample is nominal
    with np.errstate(all="ignore"):
        for k in range(first, T):
            if k > first:
                moved = onsets < k  # past their onset: the states before this step are the fault model's
                before[k][:, moved] = z[:, moved]
                if own is None or not moved.any():
                    z = model.predict(z, us[k], theta, model.DT)
                else:  # the columns past their onset through their own modes, the others the nominal run's
                    z[:, moved] = model.predict(z[:, moved], own[k], theta, model.DT)
                    if not moved.all():
                        z[:, ~moved] = model.predict(z[:, ~moved], us[k], theta, model.DT)
            starting = onsets == k
            z[row, starting] = magnitudes[starting]
            seen = onsets <= k
            after[k][:, seen] = z[:, seen]
            y[k][:, seen] = model.observe(z, us[k], theta)[:, seen]
    return before, after, y


def _own_modes(families: Families, model: FaultModel) -> np.ndarray | None:
    """For a stuck switch's fault model on a plant some of whose transitions
    its own guards or timers make: the families' inputs with the mode column
    blank (NaN: the generated model's hidden-mode step takes each column
    through the guards and timers its own states meet) but at the samples
    where the nominal run changes mode by a controlled transition (the
    schedule's commands, which the faulty plant takes too: the mode
    commanded); None for any other model (a size's family is linearised
    along the nominal run, and a plant switched by commands alone takes the
    nominal run's modes)."""
    nominal = nominal_model(families.package)
    column = getattr(nominal, "MODE_INPUT", None)
    transitions = getattr(nominal, "TRANSITIONS", ())
    fault = getattr(model, "FAULT", None)
    autonomous = {(a, b) for a, b, g, t, *_ in transitions if g is not None or t is not None}
    if column is None or not fault or not fault_kind(fault["kind"]).discrete or not autonomous \
            or getattr(nominal, "PROPOSAL_ROW", None) is not None:
        # (guards with a tolerance: the hidden-mode step draws where each column switches, a noise-free
        # run's modes are the nominal run's, as a sized rival's are)
        return None
    # a change the nominal run made by a command (a pair no guard or timer also makes: that one is its own)
    commanded = {(a, b) for a, b, g, t, *_ in transitions if g is None and t is None} - autonomous
    modes = np.asarray(families.us[:, column], dtype=float)
    own = np.array(families.us, dtype=float)
    own[:, column] = np.nan
    for k in range(1, len(modes)):
        if np.isfinite(modes[k - 1:k + 1]).all() and (int(round(modes[k - 1])), int(round(modes[k]))) in commanded:
            own[k, column] = modes[k]
    return own


def distinguish(families: Families, name: str, magnitude: float, onset: int, priors: dict[str, float],
                level: float = LEVEL, us: np.ndarray | None = None) -> Distinction:
    """Predicted distinguishability of fault model ``name`` (its ``magnitude``
    from sample ``onset``; a stuck switch's: 1) from every other fault model
    of the package; ``priors``: each fault parameter's prior probability
    (the model's; a stuck switch's by its junction); ``us``: the truth's
    inputs (None: the families'; a stuck switch on a plant whose guards
    switch it: the mode column of the faulty plant's own run).

    Every rival is fitted to the truth's deviation within its linearised
    family (a stuck switch: its own runs, :func:`_stuck_fit`); a rival whose
    fit leaves the truth's name less than ``SURE`` likely is fitted again by
    its fault model itself, on a grid of onsets and magnitudes around the
    linearised fit and then at the vertex of a parabola in the magnitude
    (:func:`_exact_fit`; a stuck switch's fit is already its own run); the
    divergence of the truth from that fit is then computed with both runs'
    own means and covariances (:func:`divergence`), against the truth's own
    exact fit (the truth itself, divergence 0). Not when the truth's mean is
    not expected to be told from no fault (the detector would not see it),
    nor when the rival's run does not stay finite (the linearised fit
    stands)."""
    package = families.package
    if name not in families.names and name not in families.stuck:
        raise TrackingError(f"no fault model {name!r}", None,
                            "pick one of: " + ", ".join(families.names + families.stuck))
    every = families.names + families.stuck
    prior_of = {m: float(priors.get(package.MODELS[m].FAULT["parameter"], 0.01)) for m in every}
    if noisy_row(package.MODELS[name]) is not None:
        return _distinguish_noise(families, name, magnitude, onset, prior_of, level)
    if name in families.stuck:
        magnitude = 1.0  # a stuck switch's flag
    d = deviations(families, name, [magnitude], [onset], us)
    if not np.all(np.isfinite(d)):
        raise TrackingError(f"the noise-free run of {name} with magnitude {magnitude:g} is not finite", None,
                            "choose a smaller magnitude")
    w = families.whitening.apply(d).ravel()
    ww = float(w @ w)
    fits, fitted_vectors = _rival_fits(families, name, w, ww)
    own_r, own = (0.0, w) if name in families.stuck else (fits[name][0], fitted_vectors[name])  # (a stuck: itself)
    seen = _normal_above(0.5 * ww, math.sqrt(ww))  # the mean's divergence from no fault: can it be detected
    truth = None
    rivals = []
    for other in every:
        if other == name:
            continue
        r, col, c = fits[other]
        noise_rival = noisy_row(package.MODELS[other]) is not None
        if noise_rival:  # its fit is not linearised: its divergence from the truth itself, as an exact fit's
            expected, std = r, math.sqrt(2.0 * r)
        else:
            expected = r - own_r
            std = float(np.linalg.norm(own - fitted_vectors[other]))
        threshold = _threshold(prior_of, other, name)
        probability = _normal_above(expected - threshold, std)
        fit_onset, fit_magnitude = (int(col) if other in families.stuck else int(families.onsets[col])), c
        if SURE > probability and seen >= level and not noise_rival:
            if other not in families.stuck:
                exact, fit_onset, fit_magnitude = (_exact_fit(families, other, w, fit_onset, c) if c != 0.0
                                                   else (0.5 * ww, fit_onset, 0.0))
                if not exact < 0.5 * ww:  # no magnitude fits better than no fault
                    fit_magnitude = 0.0
            truth = truth or path(families, name, magnitude, onset, us)
            fitted = path(families, other, fit_magnitude, fit_onset)
            exact = math.nan if truth is None or fitted is None else divergence(families, truth, fitted)
            if math.isfinite(exact):  # else (the rival's run diverges) the linearised fit stands
                expected, std = exact, math.sqrt(2.0 * exact)
                probability = _normal_above(expected - threshold, std)
        rivals.append(Rival(other, expected, std, probability, fit_onset, fit_magnitude, other in families.stuck))
    rivals.sort(key=lambda r: (r.probability, r.expected, r.name))
    energy = (w.reshape(len(families.y), -1) ** 2).sum(axis=1)[onset:]  # nothing before the onset
    return Distinction(name, float(magnitude), int(onset), 0.5 * ww, own_r, tuple(rivals), level,
                       tuple(float(v) for v in np.cumsum(energy)))


def _rival_fits(families: Families, name: str, w: np.ndarray, ww: float) -> tuple[dict, dict]:
    """Every fault model's best fit to the whitened deviation ``w`` of
    truth ``name`` (``ww``: its squared norm): (half the squared residual,
    the onset's index, the magnitude) by name, within its linearised family
    (:func:`_fit`), a stuck switch's over its own runs (:func:`_stuck_fit`,
    its onset a sample, not an index; not the truth's own: it fits itself) and a noise fault's by a wider
    noise (:func:`_noise_fit`); and the fit's whitened deviation by name (a
    noise fault's: none)."""
    fits, vectors = {}, {}
    for i, other in enumerate(families.names):
        if noisy_row(families.package.MODELS[other]) is not None:  # its sensor's share by a wider noise
            fits[other] = _noise_fit(families, w, ww, other)
            continue
        r, col, c = fits[other] = _fit(w, ww, families.response(other), families.bounds[i])
        vectors[other] = c * families.response(other)[:, col]
    for other in families.stuck:
        if other != name:
            r, col, c, vectors[other] = _stuck_fit(families, other, w, ww)
            fits[other] = (r, col, c)
    return fits, vectors


def _stuck_fit(families: Families, name: str, w: np.ndarray, ww: float) -> tuple[float, int, float, np.ndarray]:
    """The best fit of whitened target ``w`` by stuck switch ``name``'s own
    noise-free runs from each onset of the families' grid (nonlinear: a
    stuck switch has no size to linearise in), then, where the best of them
    comes nearer than no fault, from every sample between its neighbours on
    the grid (a switch's fault moves the readings at once: one sample off
    the truth's onset can cost more than a whole run's difference, and a
    stuck switch and an uncommanded change of it are the same run until a
    mode asks for the switch), or by no fault when none comes nearer: (half
    the squared residual, the onset sample, 1 (from it) or 0 (no fault), the
    fit's whitened deviation)."""
    wz = families.stuck_runs[families.stuck.index(name)]  # its runs from every onset, whitened (prepare)
    with np.errstate(invalid="ignore", over="ignore"):
        r = 0.5 * ((wz - w[:, None]) ** 2).sum(axis=0)
    r[~np.isfinite(r)] = math.inf
    j = int(np.argmin(r))
    if not r[j] < 0.5 * ww * (1.0 - 1e-9):  # no grid onset nearer than no fault (a late one: as near, to rounding)
        return 0.5 * ww, int(families.onsets[-1]), 0.0, np.zeros_like(w)
    best = (float(r[j]), int(families.onsets[j]), wz[:, j])
    grid = [int(o) for o in families.onsets]
    end = grid[j + 1] if j + 1 < len(grid) else families.x_after.shape[0]  # (after the grid's last: to the run's end)
    between = [k for k in range(grid[max(j - 1, 0)] + 1, end) if k not in grid]
    if between:
        dev = deviations(families, name, np.ones(len(between)), between)
        wk = families.whitening.apply(dev).reshape(-1, len(between))
        with np.errstate(invalid="ignore", over="ignore"):
            rk = 0.5 * ((wk - w[:, None]) ** 2).sum(axis=0)
        rk[~np.isfinite(rk)] = math.inf
        i = int(np.argmin(rk))
        if rk[i] < best[0]:
            best = (float(rk[i]), between[i], wk[:, i])
    return max(best[0], 0.0), best[1], 1.0, best[2]


def noisy_row(model: FaultModel) -> int | None:
    """The row of the sensor whose noise std a noise fault's model scales
    (its ``FAULT``'s subject), None for any other model."""
    fault = getattr(model, "FAULT", None)
    if not fault or not fault_kind(fault["kind"]).noise:
        return None
    return list(model.OUTPUTS).index(fault["subject"])


def _noise_variance(families: Families, j: int) -> float:
    """Sensor ``j``'s nominal measurement noise variance R_j."""
    return float(np.asarray(nominal_model(families.package).MEASUREMENT_STD, dtype=float)[j]) ** 2


def _threshold(prior_of: dict[str, float], rival: str, truth: str) -> float:
    """The log Bayes factor of ``truth`` against ``rival`` above which the
    diagnoser, weighing their priors, names the truth: log(prior_rival /
    prior_truth)."""
    return math.log(max(prior_of[rival], 1e-300) / max(prior_of[truth], 1e-300))


def _noise_ratios(families: Families, model: FaultModel, magnitude: float) -> np.ndarray:
    """delta_k (T,): by how much a noise fault of ``magnitude`` widens the
    variance of the nominal filter's whitened innovation along its sensor,
    ``(k^2 - 1) R_j (S_k^-1)_jj`` with ``S_k^-1 = Linv_k' Linv_k``."""
    j = noisy_row(model)
    k = fault_kind(model.FAULT["kind"]).noise_factor(magnitude)
    r = _noise_variance(families, j)
    precision = np.einsum("kij,kij->k", families.whitening.Linv[:, :, j:j + 1], families.whitening.Linv[:, :, j:j + 1])
    return (k * k - 1.0) * r * precision


def noise_divergence(families: Families, name: str, magnitude: float, onset: int) -> float:
    """The Kullback-Leibler divergence of noise fault ``name`` (its
    ``magnitude`` from sample ``onset``) from no fault: the sum over the
    samples from the onset of (delta_k - log(1 + delta_k)) / 2 (module
    docstring, "Noise faults")."""
    delta = _noise_ratios(families, families.package.MODELS[name], magnitude)[onset:]
    return float(0.5 * np.sum(delta - np.log1p(delta)))


def _distinguish_noise(families: Families, name: str, magnitude: float, onset: int, prior_of: dict[str, float],
                       level: float) -> Distinction:
    """:func:`distinguish` for a noise fault as the truth: its divergence
    from no fault (:func:`noise_divergence`), and every rival as far from it
    as no fault is (it fits the truth's unchanged mean best with no change)."""
    D = noise_divergence(families, name, magnitude, onset)
    std = math.sqrt(2.0 * D)
    rivals = []
    for other in families.names + families.stuck:
        if other != name:
            threshold = _threshold(prior_of, other, name)
            rivals.append(Rival(other, D, std, _normal_above(D - threshold, std), int(onset), 0.0,
                                other in families.stuck))
    rivals.sort(key=lambda r: (r.probability, r.expected, r.name))
    return Distinction(name, float(magnitude), int(onset), D, 0.0, tuple(rivals), level)


def _noise_fit(families: Families, w: np.ndarray, ww: float, name: str) -> tuple[float, int, float]:
    """The best fit of a mean deviation (whitened ``w``, ``ww`` = w'w) by
    noise fault ``name``: (divergence, onset column, magnitude). Its
    sensor's innovation (mean ``m_k``, nominal variance ``s_k``) is
    explained by a variance ``s_k + (k^2 - 1) R_j`` from the onset, the rest
    of the deviation not at all: ww / 2 less sum m_k^2 / (2 s_k) plus sum
    (KL of N(m_k, s_k) from N(0, s_k + (k^2 - 1) R_j)), smallest over the
    onsets of the families and 41 magnitudes across the prior."""
    model = families.package.MODELS[name]
    j = noisy_row(model)
    Linv = families.whitening.Linv
    T, n_y, _ = Linv.shape
    L = np.linalg.inv(Linv)  # the innovations' Cholesky factors
    m = np.einsum("ki,ki->k", L[:, j, :], w.reshape(T, n_y))  # the sensor's mean innovation
    s = np.einsum("ki,ki->k", L[:, j, :], L[:, j, :])
    lo, hi = families.bounds[families.names.index(name)]
    magnitudes = np.unique(np.concatenate([np.linspace(lo, hi, 41), [0.0]]))
    r = _noise_variance(families, j)
    k = fault_kind(model.FAULT["kind"]).noise_factor(magnitudes)
    wide = s[:, None] + (k * k - 1.0)[None, :] * r  # (T, magnitudes)
    gain = 0.5 * ((s + m * m)[:, None] / wide - 1.0 + np.log(wide / s[:, None])) - (0.5 * m * m / s)[:, None]
    after = np.cumsum(gain[::-1], axis=0)[::-1]  # from each sample to the end
    total = 0.5 * ww + after[families.onsets]  # (onsets, magnitudes)
    col, i = np.unravel_index(int(np.argmin(total)), total.shape)
    return max(float(total[col, i]), 0.0), int(col), float(magnitudes[i])


@dataclass(frozen=True, slots=True)
class FaultRun:
    """A fault model's noise-free run with its magnitude from an onset: its
    measurements ``y`` and its Kalman filter (``whitening``), linearised
    along the run."""

    y: np.ndarray
    whitening: Whitening


def path(families: Families, name: str, magnitude: float, onset: int, us: np.ndarray | None = None) -> FaultRun | None:
    """Fault model ``name``'s noise-free run with ``magnitude`` from sample
    ``onset`` (the nominal run before it; ``us``: its inputs, None: the
    families') and its linearisation; None when the run does not stay
    finite."""
    model = families.package.MODELS[name]
    n = families.x_after.shape[1]
    theta = np.asarray(model.THETA, dtype=float)
    before, after, y = (a[:, :, 0] for a in _fault_runs(families, name, [magnitude], [onset], us))
    if us is None and _own_modes(families, model) is not None:  # linearised through the modes its run took
        nominal = nominal_model(families.package)
        us = np.array(families.us, dtype=float)
        us[:, nominal.MODE_INPUT] = np.rint(after[:, nominal.MODE_ROW])
    us = families.us if us is None else us
    if not (np.isfinite(y).all() and np.isfinite(after).all()):
        return None
    scale = _scales(model, families.x_before)
    F = _jacobian(lambda X, u: model.predict(X, u, theta, model.DT)[:n], before, range(n), scale, us)
    H = _jacobian(lambda X, u: model.observe(X, u, theta), after, range(n), scale, us)
    return FaultRun(y, _whitening(model, F, H))


def divergence(families: Families, a: FaultRun, b: FaultRun) -> float:
    """The Kullback-Leibler divergence KL(a || b) of the measurements' Gaussian
    distributions under two linearised runs, each with its own mean and its
    own covariance (the difference in the noise's colour counts too): the sum
    over steps of 1/2 [tr(S_b^-1 E_a[e e']) + log det S_b - n_y - log det S_a],
    e the innovations of b's Kalman filter on data from a (a deterministic
    part: b's filter on the means' difference; a random part: the joint
    second moments of a's state and b's estimate, propagated exactly)."""
    Wa, Wb = a.whitening, b.whitening
    T, n_y, n = Wa.H.shape
    P0, Q, R = _noise(nominal_model(families.package), n)
    mean = np.zeros(n)  # b's estimate of the deviation a's mean makes from b's
    Z = np.zeros((2 * n, 2 * n))  # (a's state about its mean, b's estimate of it)
    Z[:n, :n] = P0
    total = 0.0
    for k in range(T):
        A = np.zeros((2 * n, 2 * n))
        A[:n, :n], A[n:, n:] = Wa.F[k], Wb.F[k]
        Z = A @ Z @ A.T
        Z[:n, :n] += Q
        C = np.hstack([Wa.H[k], -Wb.H[k]])
        mean = Wb.F[k] @ mean
        e_mean = (a.y[k] - b.y[k]) - Wb.H[k] @ mean
        E = C @ Z @ C.T + R + np.outer(e_mean, e_mean)
        Lb, La = Wb.Linv[k], Wa.Linv[k]  # S^-1 = Linv' Linv; log det S = -2 log det Linv
        total += 0.5 * (float(np.trace(Lb @ E @ Lb.T)) - n_y - 2.0 * float(np.log(np.diagonal(Lb)).sum())
                        + 2.0 * float(np.log(np.diagonal(La)).sum()))
        G = np.vstack([np.zeros((n, n_y)), Wb.K[k]])
        J = np.eye(2 * n) + G @ C
        Z = J @ Z @ J.T + G @ R @ G.T
        mean = mean + Wb.K[k] @ e_mean
    return max(total, 0.0) if math.isfinite(total) else math.nan


#: A rival whose linearised fit leaves the truth's name at least this likely
#: is not fitted again by its fault model itself.
SURE = 0.9999
#: The exact fit's grid around the linearised fit: onsets (in steps of the
#: families' onset spacing) and magnitudes (factors of the linearised one).
_ONSET_OFFSETS = (-8, -4, -2, -1, 0, 1, 2, 4, 8)
_FACTORS = np.linspace(0.5, 1.5, 11)


def _exact_fit(families: Families, name: str, w: np.ndarray, onset: int, magnitude: float) -> tuple[float, int, float]:
    """The smallest divergence of whitened target ``w`` from fault model
    ``name``'s own noise-free runs, on a grid of onsets and magnitudes around
    (``onset``, ``magnitude``) (within the magnitude's prior and the run):
    (divergence, onset, magnitude). The magnitude is then the vertex of the
    parabola through the best one and its neighbours at the best onset
    (the divergence is the grid's best: the vertex's is at most that)."""
    T = families.x_after.shape[0]
    stride = int(families.onsets[1] - families.onsets[0]) if len(families.onsets) > 1 else 1
    lo, hi = families.bounds[families.names.index(name)]
    taus = sorted({min(max(onset + o * stride, 0), T - 1) for o in _ONSET_OFFSETS})
    mags = np.unique(np.clip(magnitude * _FACTORS, lo, hi))
    grid_t, grid_m = np.meshgrid(taus, mags, indexing="ij")
    dev = deviations(families, name, grid_m.ravel(), grid_t.ravel())
    wz = families.whitening.apply(dev).reshape(-1, dev.shape[2])
    r = (0.5 * ((wz - w[:, None]) ** 2).sum(axis=0)).reshape(grid_t.shape)
    r[~np.isfinite(r)] = math.inf
    t, i = np.unravel_index(int(np.argmin(r)), r.shape)
    best = (float(r[t, i]), int(taus[t]), float(mags[i]))
    if 0 < i < len(mags) - 1 and np.all(np.isfinite(r[t, i - 1:i + 2])):
        (m0, m1, m2), (r0, r1, r2) = mags[i - 1:i + 2], r[t, i - 1:i + 2]
        denominator = (m1 - m0) * (r1 - r2) - (m1 - m2) * (r1 - r0)
        if denominator != 0.0:
            vertex = m1 - 0.5 * ((m1 - m0) ** 2 * (r1 - r2) - (m1 - m2) ** 2 * (r1 - r0)) / denominator
            best = (best[0], best[1], float(np.clip(vertex, m0, m2)))
    return best


def _fit(w: np.ndarray, ww: float, G: np.ndarray, bounds: tuple[float, float]) -> tuple[float, int, float]:
    """The best fit of whitened target ``w`` by ``c G[:, j]`` over the columns
    j and the magnitudes c within ``bounds``: (half the squared residual, j,
    c). Per column the unconstrained least-squares c is clipped to the
    bounds, which is the constrained optimum of a one-dimensional quadratic."""
    gg = np.einsum("ij,ij->j", G, G)
    wg = w @ G
    with np.errstate(divide="ignore", invalid="ignore"):
        c = np.where(gg > 0, wg / gg, 0.0)
    c = np.clip(c, bounds[0], bounds[1])
    r = 0.5 * (ww - 2.0 * c * wg + c * c * gg)
    j = int(np.argmin(r))
    return max(float(r[j]), 0.0), j, float(c[j])


def ideal_power(detectability: float, false_alarm: float) -> float:
    """The power of the likelihood-ratio test of a fault (onset and
    magnitude known) against no fault, at the false-alarm probability
    ``false_alarm``, from the fault's ``detectability`` (the probability
    that the data favour it at equal priors, :attr:`Distinction.detectability`).
    The log likelihood ratio is N(D, 2 D) under the fault and N(-D, 2 D)
    under no fault (D the divergence), so detectability = Phi(sqrt(D / 2))
    and the test that alarms above the no-fault law's 1 - ``false_alarm``
    quantile detects with probability Phi(sqrt(2 D) - z), z =
    Phi^-1(1 - ``false_alarm``), sqrt(2 D) = 2 Phi^-1(detectability): the
    "ideal detector" against which a detector holding the same false-alarm
    rate is measured. Exact for a fault that shifts the whitened residuals'
    mean (a plant linear in its states); for a noise fault the ratio is a
    scaled chi-square, not normal, and this overstates the power of a short
    or weak one (a noise 2 times its std over 10 samples: 0.955 against an
    exact 0.83 at 1 %).

    >>> round(ideal_power(0.5, 0.01), 4), round(ideal_power(0.95, 0.05), 4), round(ideal_power(0.95, 0.01), 4)
    (0.01, 0.95, 0.8323)
    """
    from statistics import NormalDist

    normal = NormalDist()
    d = min(max(float(detectability), 1e-300), 1.0 - 1e-16)
    return normal.cdf(2.0 * normal.inv_cdf(d) - normal.inv_cdf(1.0 - false_alarm))


def _normal_above(mean: float, std: float) -> float:
    """P(X > 0) for X ~ N(mean, std^2); a point mass when ``std`` is 0."""
    if std <= 0.0:
        return 1.0 if mean > 0 else (0.0 if mean < 0 else 0.5)
    return 0.5 * math.erfc(-mean / (std * math.sqrt(2.0)))


