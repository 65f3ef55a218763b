"""A fault that comes and goes, as one fault node with two states (a loose
connector, a sticking valve: the thesis's future direction V.2 (iii)).

A step fault (a parameter's ``abrupt`` change, a sensor's or actuator's
``bias`` or ``gain``, a sensor's ``noise``) may be *intermittent*: present
(its magnitude ``c``) or absent (0), switching between the two by itself.
Its node in the DBN is a Markov chain of three states, per sample:

* ``before``: it has not appeared yet (the nominal model). It appears at a
  given sample with the per-sample weight of a persistent fault's onset
  (:func:`bgc.diagnosis.weigh.posterior`: a fault model's prior p is the
  probability that it begins within the horizon, p / horizon per sample),
  so the two hypotheses are weighed on one scale;
* ``present``: it goes away at each sample with probability ``1 / on``;
* ``absent`` (after an appearance): it comes back with probability ``1 / off``.

The mean durations ``on`` and ``off`` (in samples) are not known: each
lies on a geometric grid (:data:`DURATIONS` points from :data:`SHORTEST`
samples to the record's span), every pair equally likely a priori. A
change of state takes effect at a sample's instant, both ways, as the
simulator injects it (the onset rule of :mod:`bgc.model.protocol`): the
sample sees the new state, the transition into it the old one.

Given ``c`` and the durations, the chain and the plant are a switching
linear-Gaussian model (on a plant linear in its states) whose likelihood a
bank of cubature Kalman filters follows: per state one Gaussian, and per
sample each of the six transitions between the states filtered and merged
into its state by moments (the generalised pseudo-Bayesian filter of order
1, GPB1: exact for each path of switches, the merging its approximation). The magnitude's
uniform prior is integrated as the static posterior's is, on a grid
refined around its peak (:func:`bgc.filters.quadrature.row_quadrature`),
and the durations summed over their grid: the evidence ``log p(y |
intermittent f)`` compares with the static posterior's ``log p(y |
persistent f)``. The prior of the intermittent hypothesis is
:data:`SHARE` times its fault model's.

Each sample's probability that the fault is present comes from a
backward pass over the forward pass's pairwise likelihoods (the
forward-backward recursion of the hidden Markov model the switches make,
with the filters' predictive densities as its emissions), averaged over
the grid's cells by their posterior. The fault's spans are where that
probability is above one half; each appearance's and disappearance's
sample is read from the switches' smoothed probabilities around it (the
most probable sample and a central interval).

A diagnosis tries the intermittent hypothesis of its likeliest step faults
when no persistent fault explains the data (:func:`revised`, from
:func:`bgc.diagnosis.finish.finish`): a fault that went away fails the
persistent model's fit tests; and of a fault it names whose residuals' mean
wanders after the onset (:func:`_wanders`). The intermittent model with its spans must
then pass the same test (the windowed Z-test of section 5 on its
residuals, the fault switched at the spans' samples).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from ..filters.cubature import NominalTrack, _Filter
from ..filters.quadrature import row_quadrature
from ..kinds import comes_and_goes, fault_kind
from ..model.protocol import FaultModel, state_rows
from .. import events as ev
from .estimate import pressed
from .onsets import log_prior
from .static import mean_alarm
from .values import Detection, Drop, Hypothesis

__all__ = ["DURATIONS", "GRID", "Intermittence", "REFINE", "SHARE", "SHORTEST", "Span", "TRIED", "intermittence",
           "revised"]

#: The prior of a fault model's fault coming and going, as a share of its fault model's prior.
SHARE = 0.1
#: The points of each duration's geometric grid (the mean time present, and absent between appearances).
DURATIONS = 3
#: The shortest mean duration on that grid, in samples.
SHORTEST = 4.0
#: The points of each grid of magnitudes (the first over the prior, each next between the best one's neighbours).
GRID = 9
#: The most refinements of the magnitude's grid.
REFINE = 6
#: The refinements stop when the log likelihood changes by less than this between neighbouring points.
SMOOTH = 3.0
#: The most step faults a diagnosis tries as intermittent (the likeliest, by their persistent evidence).
TRIED = 3
#: The segments (samples) over which a named fault's residual means are tested for wandering (:func:`_wanders`).
SEGMENT = 20
#: The level of that test: a named fault is tried as one that comes and goes when it fails it.
WANDERS = 1e-3
#: The pairs of states (from, to) over one sample: before, present, absent.
_PAIRS = ((0, 0), (0, 1), (1, 1), (1, 2), (2, 2), (2, 1))


@dataclass(frozen=True, slots=True)
class Span:
    """One appearance of an intermittent fault: it appeared at sample
    ``on`` (the most probable; ``on_low`` .. ``on_high`` a central interval
    of probability ``level``) and went away at ``off`` (None: still present
    at the record's end), steps of the time grid."""

    on: int
    on_low: int
    on_high: int
    off: int | None
    off_low: int | None
    off_high: int | None


@dataclass(frozen=True, slots=True)
class Intermittence:
    """The intermittent hypothesis of fault model ``name``: ``log_evidence``,
    log p(y | it comes and goes) on the static posterior's scale; the
    magnitude while present (``value``, ``std`` and the central interval
    ``low`` .. ``high`` of probability ``level``); the posterior means of
    the mean durations present and absent (``on``, ``off``, samples);
    ``present``: per step, the probability that it is present (0 before the
    bank's first step); its ``spans``; ``z``: the normalised residuals of
    its model switched at the spans' samples with the magnitude's posterior
    mean (from the bank's first step ``start``: the nominal filter's before the
    first appearance; NaN before it), and ``alarm``: their fit test's first
    alarm over that stretch (None: it passes)."""

    name: str
    log_evidence: float
    value: float
    std: float
    low: float
    high: float
    level: float
    on: float
    off: float
    present: np.ndarray
    spans: tuple[Span, ...]
    z: np.ndarray
    alarm: Detection | None
    start: int
    cells: int
    #: log p(y | the fault persists) by the same bank on the same grid of magnitudes, its durations endless:
    #: the persistent fault's onset summed over every sample from ``start`` (the scale ``log_evidence`` is on)
    persistent_evidence: float = -math.inf
    #: the plant's state at the end (mean, std) by the filter switched at the spans (None: no span)
    x_end: np.ndarray | None = None
    x_end_std: np.ndarray | None = None
    #: the magnitudes of the last grid the bank ran on (the persistent reference's too)
    grid: np.ndarray | None = None

    def __repr__(self) -> str:
        return (f"<Intermittence {self.name}: {self.value:.4g} [{self.low:.4g}, {self.high:.4g}] while present, "
                f"{len(self.spans)} span(s)>")


def durations(span: int) -> np.ndarray:
    """The grid of mean durations (samples): :data:`DURATIONS` points,
    geometric from :data:`SHORTEST` to ``span`` (at least 4 times it)."""
    return np.geomspace(SHORTEST, max(float(span), 4.0 * SHORTEST), DURATIONS)


@dataclass(frozen=True, slots=True)
class _Pass:
    """One bank over a grid: per cell (magnitude x durations), log p(y,
    appeared) (``loglik``); with ``keep``, per step the log weights of the
    three states after it (``alpha``, steps x 3 x cells) and each pair's
    log predictive density (``pair``, steps x 6 x cells)."""

    loglik: np.ndarray
    alpha: np.ndarray | None
    pair: np.ndarray | None
    on: np.ndarray
    off: np.ndarray
    first: np.ndarray


def _bank(model: FaultModel, ys, us, track: NominalTrack, start: int, magnitudes, on, off, fixed,
          keep: bool = False) -> _Pass:
    """The GPB1 bank of every cell (magnitude, mean duration present, mean
    duration absent) from step ``start`` (the nominal filter's state
    there) to the end of ``ys``. The state ``before`` is the nominal filter
    itself (``track``), the same in every cell, and an appearance from it
    depends on the magnitude alone: the filters run per step are one per
    magnitude for the appearances and four per cell for the other pairs."""
    kf = _Filter(model)
    G, D = len(magnitudes), len(on)
    K = G * D
    g = np.asarray(magnitudes, dtype=float)
    c = np.repeat(g, D)
    logpi = _log_transitions(np.tile(np.asarray(on, dtype=float), G), np.tile(np.asarray(off, dtype=float), G))
    n = kf.n
    m = np.repeat(np.asarray(track.mean[start], dtype=float)[None, None], 3, axis=0).repeat(K, axis=1)
    P = np.repeat(np.asarray(track.cov[start], dtype=float)[None, None], 3, axis=0).repeat(K, axis=1)
    logw = np.full((3, K), -math.inf)
    logw[0] = float(track.loglik[start])
    first = logw.copy()
    src = np.array([a for a, _ in _PAIRS])
    rest = _PAIRS[2:]  # present -> present, present -> absent, absent -> absent, absent -> present
    seen_c = np.concatenate([g] + [c if b == 1 else np.zeros(K) for _, b in rest])  # the magnitude each update sees
    moved_c = np.concatenate([np.zeros(G)] + [c if a == 1 else np.zeros(K) for a, _ in rest])  # and each transition
    states = np.repeat(np.asarray(fixed, dtype=float).reshape(-1, 1), G + 4 * K, axis=1)
    states[kf.magnitude] = seen_c
    T = len(ys)
    alpha = np.full((T, 3, K), -math.inf) if keep else None
    pair = np.full((T, 6, K), -math.inf) if keep else None
    ll, mu, Pu = np.empty((6, K)), np.empty((6, K, n)), np.empty((6, K, n, n))
    with np.errstate(all="ignore"):
        for k in range(start, T):
            M = np.concatenate([np.repeat(np.asarray(track.mean[k], dtype=float)[None], G, axis=0),
                                m[src[2:]].reshape(4 * K, n)])
            V = np.concatenate([np.repeat(np.asarray(track.cov[k], dtype=float)[None], G, axis=0),
                                P[src[2:]].reshape(4 * K, n, n)])
            lk, mk, Pk, _, _, _ = kf.step(ys[k], us[k], M, V, states.copy(), moved=moved_c)
            ll[0] = float(track.loglik[k + 1] - track.loglik[k])  # before -> before: the nominal filter
            mu[0], Pu[0] = track.mean[k + 1], track.cov[k + 1]
            ll[1], mu[1], Pu[1] = np.repeat(lk[:G], D), np.repeat(mk[:G], D, axis=0), np.repeat(Pk[:G], D, axis=0)
            ll[2:], mu[2:], Pu[2:] = lk[G:].reshape(4, K), mk[G:].reshape(4, K, n), Pk[G:].reshape(4, K, n, n)
            ll[~np.isfinite(ll)] = -math.inf
            _merge(logw[src] + logpi + ll, mu, Pu, logw, m, P)
            if keep:
                alpha[k], pair[k] = logw, ll
    appeared = np.logaddexp(logw[1], logw[2])
    return _Pass(np.where(np.isfinite(appeared), appeared, -math.inf), alpha, pair,
                 np.tile(np.asarray(on, dtype=float), G), np.tile(np.asarray(off, dtype=float), G), first)


def _log_transitions(on: np.ndarray, off: np.ndarray) -> np.ndarray:
    """The log weights (6 x cells) of the pairs of :data:`_PAIRS` for each
    cell's mean durations present ``on`` and absent ``off``: an appearance
    weighs 1 per sample (the onset's weight, applied outside), going away
    1 / on, coming back 1 / off."""
    leave, back = 1.0 / np.asarray(on, dtype=float), 1.0 / np.asarray(off, dtype=float)
    with np.errstate(divide="ignore"):
        return np.stack([np.zeros(len(leave)), np.zeros(len(leave)), np.log1p(-leave), np.log(leave),
                         np.log1p(-back), np.log(back)])


#: The pairs of :data:`_PAIRS` into the states present and absent (the state before has one, its own).
_INTO = tuple((s, np.array([i for i, (_, b) in enumerate(_PAIRS) if b == s])) for s in (1, 2))


def _merge(lw: np.ndarray, mu: np.ndarray, Pu: np.ndarray, logw: np.ndarray, m: np.ndarray, P: np.ndarray) -> None:
    """Each state's log weight (``logw``, 3 x cells) and Gaussian (``m``,
    ``P``), in place, from the pairs of :data:`_PAIRS` into it: their log
    weights ``lw`` (6 x cells: the source's weight, the transition's, the
    sample's predictive density) and updated means and covariances (``mu``,
    ``Pu``), merged by moments (a state no pair reaches keeps its Gaussian;
    the state before, one pair into it, takes that pair's)."""
    before = np.isfinite(lw[0])
    logw[0] = np.where(before, lw[0], -math.inf)
    m[0][before], P[0][before] = mu[0][before], Pu[0][before]
    for s, into in _INTO:
        w = lw[into]
        top = w.max(axis=0)
        alive = np.isfinite(top)
        safe = np.where(alive, top, 0.0)
        e = np.exp(w - safe)  # (pairs, K)
        total = e.sum(axis=0)
        logw[s] = np.where(alive, safe + np.log(np.where(total > 0, total, 1.0)), -math.inf)
        if not alive.any():
            continue
        share = e / np.where(total > 0, total, 1.0)
        mean = np.einsum("pk,pkn->kn", share, mu[into])
        d = mu[into] - mean[None]
        cov = np.einsum("pk,pkij->kij", share, Pu[into] + d[..., :, None] * d[..., None, :])
        m[s][alive], P[s][alive] = mean[alive], cov[alive]


def _smoothed(p: _Pass, weights: np.ndarray, start: int, T: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per step, the posterior probability that the fault is present, that
    it appeared at that sample and that it went away at it, averaged over
    the cells with ``weights`` (the backward pass over each cell's
    pairwise predictive densities, the paths that end before any
    appearance left out)."""
    K = p.loglik.shape[0]
    logpi = _log_transitions(p.on, p.off)
    present, appear, vanish = np.zeros(T), np.zeros(T), np.zeros(T)
    beta = np.zeros((3, K))
    beta[0] = -math.inf  # never appeared: not the hypothesis
    total = p.loglik  # log p(y, appeared | cell)
    src = np.array([a for a, _ in _PAIRS])
    dst = np.array([b for _, b in _PAIRS])
    w = np.asarray(weights, dtype=float)
    with np.errstate(all="ignore"):
        for k in range(T - 1, start - 1, -1):
            post = np.exp(p.alpha[k] + beta - total)  # (3, K): P(state at k | y)
            post = np.where(np.isfinite(post), post, 0.0)
            present[k] = float(post[1] @ w)
            before = p.alpha[k - 1] if k > start else p.first
            xi = np.exp(before[src] + logpi + p.pair[k] + beta[dst] - total)  # (6, K)
            xi = np.where(np.isfinite(xi), xi, 0.0)
            appear[k] = float((xi[1] + xi[5]) @ w)
            vanish[k] = float(xi[3] @ w)
            nxt = np.full((3, K), -math.inf)
            for s in range(3):
                out = np.flatnonzero(src == s)
                nxt[s] = log_sum_exp_rows(logpi[out] + p.pair[k][out] + beta[dst[out]])
            beta = nxt
    return present, appear, vanish


def log_sum_exp_rows(a: np.ndarray) -> np.ndarray:
    """log sum exp over the first axis, -inf where every term is."""
    top = a.max(axis=0)
    safe = np.where(np.isfinite(top), top, 0.0)
    with np.errstate(divide="ignore"):
        return np.where(np.isfinite(top), safe + np.log(np.exp(a - safe).sum(axis=0)), -math.inf)


def _interval(mass: np.ndarray, lo: int, hi: int, level: float) -> tuple[int, int, int]:
    """The most probable step of ``mass`` over [lo, hi) and a central
    interval of probability ``level`` of it there."""
    part = np.clip(np.asarray(mass[lo:hi], dtype=float), 0.0, None)
    if part.sum() <= 0:
        return lo, lo, lo
    cdf = np.cumsum(part) / part.sum()
    tail = (1.0 - level) / 2.0
    return (int(lo + np.argmax(part)), int(lo + np.searchsorted(cdf, tail)),
            int(lo + min(int(np.searchsorted(cdf, 1.0 - tail)), hi - lo - 1)))


def spans_of(present: np.ndarray, appear: np.ndarray, vanish: np.ndarray, start: int, level: float) \
        -> tuple[Span, ...]:
    """The fault's spans: the runs of steps where it is present with
    probability above one half; each appearance's and disappearance's step
    read from the switches' probabilities between the midpoints to the
    neighbouring runs."""
    on = present > 0.5
    on[:start] = False
    edges = np.flatnonzero(np.diff(np.concatenate([[0], on.astype(int), [0]])))
    runs = [(int(a), int(b)) for a, b in zip(edges[::2], edges[1::2])]
    T = len(present)
    out = []
    for i, (a, b) in enumerate(runs):
        lo = start if i == 0 else (runs[i - 1][1] + a) // 2
        mid = (a + b) // 2 + 1
        on_k, on_lo, on_hi = _interval(appear, lo, max(mid, lo + 1), level)
        if b >= T:
            out.append(Span(on_k, on_lo, on_hi, None, None, None))
            continue
        hi = T if i == len(runs) - 1 else (b + runs[i + 1][0]) // 2 + 1
        off_k, off_lo, off_hi = _interval(vanish, (a + b) // 2 + 1, hi, level)
        out.append(Span(on_k, on_lo, on_hi, off_k, off_lo, off_hi))
    return tuple(out)


def _narrower(values: np.ndarray, logd: np.ndarray, lo: float, hi: float) -> np.ndarray | None:
    """The next grid of magnitudes, or None when ``values`` resolve the
    peak of the log density ``logd`` (its fall between neighbouring points
    near the peak under :data:`SMOOTH`). A peak at an end of the grid short
    of the prior's bound (``lo``, ``hi``) moves the grid, as wide, to be
    centred there; an interior one narrows it: :data:`GRID` points over
    four stds either side of the parabola's vertex through the best point
    and its neighbours (its std from the parabola's curvature), within those
    neighbours."""
    best = int(np.argmax(logd))
    if not np.isfinite(logd[best]) or len(values) < 3:
        return None
    width = values[-1] - values[0]
    if (best == 0 and values[0] > lo) or (best == len(values) - 1 and values[-1] < hi):
        centre = values[best]
        low, high = max(lo, centre - width / 2.0), min(hi, centre + width / 2.0)
        return np.linspace(low, high, GRID) if high > low else None
    near = logd[max(best - 1, 0):best + 2]
    if np.all(np.isfinite(near)) and np.max(np.abs(np.diff(near))) < SMOOTH:
        return None
    a, b = values[max(best - 1, 0)], values[min(best + 1, len(values) - 1)]
    h = values[1] - values[0]
    centre, half = values[best], (b - a) / 2.0
    if 0 < best < len(values) - 1 and np.all(np.isfinite(near)):
        curve = (near[0] - 2.0 * near[1] + near[2]) / (h * h)
        if curve < 0:
            centre = min(max(values[best] - (near[2] - near[0]) / (2.0 * h * curve), a), b)
            half = min(half, 4.0 * math.sqrt(-1.0 / curve))
    low, high = max(a, centre - half), min(b, centre + half)
    return np.linspace(low, high, GRID) if high > low else None


def switched_residuals(model: FaultModel, ys, us, track: NominalTrack, spans: tuple[Span, ...], value: float,
                       fixed) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None]:
    """The normalised residuals (steps x outputs; NaN before the first
    appearance) of one cubature Kalman filter of ``model`` with magnitude
    ``value`` present over ``spans`` (their most probable samples) and 0
    between them, the changes at the samples' instants both ways; and its
    state's mean and std after the last step (None: no span)."""
    kf = _Filter(model)
    T, n_y = ys.shape
    z = np.full((T, n_y), np.nan)
    if not spans:
        return z, None, None
    present = np.zeros(T, dtype=bool)
    for s in spans:
        present[s.on:T if s.off is None else s.off] = True
    first = spans[0].on
    m, P = track.mean[first][None].copy(), track.cov[first][None].copy()
    states = np.asarray(fixed, dtype=float).reshape(-1, 1).copy()
    with np.errstate(all="ignore"):
        for k in range(first, T):
            states[kf.magnitude] = value if present[k] else 0.0
            moved = np.array([value if k > 0 and present[k - 1] else 0.0])
            _, m, P, zk, _, _ = kf.step(ys[k], us[k], m, P, states.copy(), moved=moved)
            z[k] = zk[0]
    return z, m[0], np.sqrt(np.maximum(np.diagonal(P[0]), 0.0))


def _searched(row, lo: float, hi: float, worth=None):
    """The magnitude's grid: :data:`GRID` points over the prior [``lo``,
    ``hi``], narrowed around the peak (:func:`_narrower`) on banks of the
    middle durations alone, then the last grid's bank over every pair of
    durations: (that bank's pass, the grid, its log densities, the cells
    run). ``worth(values, logd)``: asked of the last narrow grid; False
    stops there (the pass returned is None)."""
    values = np.linspace(lo, hi, GRID)
    cells = 0
    for _ in range(REFINE):
        p, logd = row(values, False)
        cells += p.loglik.size
        narrower = _narrower(values, logd, lo, hi)
        if narrower is None:
            break
        values = narrower
    if worth is not None and not worth(values, logd):
        return None, values, logd, cells
    p, logd = row(values, True)
    return p, values, logd, cells + p.loglik.size


def _evidence(values: np.ndarray, logd: np.ndarray, lo: float, hi: float) -> float:
    """The log of the density ``logd`` (known at the grid ``values``)
    integrated over the magnitude's uniform prior on [``lo``, ``hi``]."""
    return _integrated(row_quadrature(values, logd)[1], lo, hi)


def _integrated(logm: np.ndarray, lo: float, hi: float) -> float:
    """The log of the quadrature's log masses ``logm`` summed, over the
    prior's width ``hi`` - ``lo`` (-inf: no mass)."""
    top = float(np.max(logm)) if len(logm) else -math.inf
    if not math.isfinite(top):
        return -math.inf
    return top + math.log(np.exp(logm - top).sum()) - math.log(hi - lo)


def _moments(x: np.ndarray, logm: np.ndarray, top: float, level: float) -> tuple[float, float, float, float]:
    """The mean, std and central interval of probability ``level`` of the
    magnitude, from quadrature nodes ``x`` and their log masses ``logm``
    (largest ``top``)."""
    q = np.exp(logm - top)
    q /= q.sum()
    mean = float(q @ x)
    std = float(math.sqrt(max(q @ (x - mean) ** 2, 0.0)))
    order = np.argsort(x)
    cdf = np.cumsum(q[order])
    tail = (1.0 - level) / 2.0
    low = float(x[order][min(int(np.searchsorted(cdf, tail)), len(x) - 1)])
    high = float(x[order][min(int(np.searchsorted(cdf, 1.0 - tail)), len(x) - 1)])
    return mean, std, low, high


def intermittence(model: FaultModel, ys, us, track: NominalTrack, start: int, fixed, outputs, rejection: float,
                  windows, level: float = 0.95) -> Intermittence:
    """The intermittent hypothesis of fault model ``model`` over the data
    from step ``start`` (:mod:`this module <bgc.diagnosis.intermittent>`):
    its evidence, magnitude while present, spans and fit test (the windowed
    Z-test with probability ``rejection`` and ``windows``)."""
    from .static import first_alarm

    T = len(ys)
    lo, hi = (float(v) for v in model.FAULT_PRIOR)
    grid = durations(T - start)
    on, off = np.repeat(grid, DURATIONS), np.tile(grid, DURATIONS)

    def row(values, full: bool):  # full: every pair of durations (else the middle one's: to find the peak)
        a, b = (on, off) if full else (grid[DURATIONS // 2:DURATIONS // 2 + 1],) * 2
        p = _bank(model, ys, us, track, start, values, a, b, fixed, keep=full)
        per = p.loglik.reshape(len(values), len(a))
        return p, log_sum_exp_rows(per.T) - math.log(len(a))  # per magnitude, the durations summed (uniform prior)

    reference = {}

    def worth(values, logd):
        # the fault that never goes away, on the same bank and grid (its magnitude, where the data make the
        # two ways alike, the one present; where they do not, the static posterior's evidence is the
        # persistent one that counts: _pool takes the larger); coming and going must be likelier than
        # persisting by more than its smaller prior, or it cannot be named: the last pass is not run
        kept = _bank(model, ys, us, track, start, values, [math.inf], [math.inf], fixed)
        reference.update(evidence=_evidence(values, kept.loglik, lo, hi), cells=kept.loglik.size)
        return _evidence(values, logd, lo, hi) > reference["evidence"] - math.log(SHARE)

    p, values, logd, cells = _searched(row, lo, hi, worth)
    persistent = reference.get("evidence", -math.inf)
    cells += reference.get("cells", 0)
    x, logm = row_quadrature(values, logd)
    top = float(np.max(logm)) if len(logm) else -math.inf
    if p is None:  # no likelier than persisting: not tried further
        return Intermittence(model.NAME, _evidence(values, logd, lo, hi), math.nan, math.nan, math.nan, math.nan,
                             level, math.nan, math.nan, np.zeros(T), (), np.full(ys.shape, np.nan), None, start,
                             cells, persistent, grid=values)
    if not math.isfinite(top):
        return Intermittence(model.NAME, -math.inf, math.nan, math.nan, math.nan, math.nan, level, math.nan,
                             math.nan, np.zeros(T), (), np.full(ys.shape, np.nan), None, start, cells, persistent,
                             grid=values)
    evidence = _integrated(logm, lo, hi)
    mean, std, low, high = _moments(x, logm, top, level)
    # the cells' posterior: each point of the magnitude's grid and pair of durations by its likelihood
    w = np.exp(p.loglik - top_cell(p.loglik))
    w = np.where(np.isfinite(w), w, 0.0)
    w /= w.sum()
    present, appear, vanish = _smoothed(p, w, start, T)
    spans = spans_of(present, appear, vanish, start, level)
    z, x_end, x_end_std = switched_residuals(model, ys, us, track, spans, mean, fixed)
    if spans and track.z is not None:  # before the first appearance: the nominal filter's own residuals
        z[start:spans[0].on] = track.z[start:spans[0].on]
    alarm = first_alarm(z[start:], tuple(outputs), rejection, windows) if spans else None
    if alarm is not None:
        alarm = replace(alarm, step=alarm.step + start)
    return Intermittence(model.NAME, evidence, mean, std, low, high, level, float(w @ p.on), float(w @ p.off),
                         present, spans, z, alarm, start, cells, persistent, x_end, x_end_std, values)


def revised(hyps: tuple[Hypothesis, ...], verdict: str, candidates: tuple[str, ...], r, s, observer) \
        -> tuple[tuple[Hypothesis, ...], str, tuple[str, ...], list]:
    """The verdict with the likeliest step faults tried as intermittent
    (:data:`TRIED` of them, by their persistent evidence and prior), when no
    persistent fault explains the data (the verdict is ``unexplained``:
    a fault that went away fails its persistent model's tests), or the
    verdict's own step faults whose residual means wander after their onset
    (:func:`_wanders`: a fault that went away briefly, or whose absence the
    observer's states partly took in, passes those tests). Each intermittent
    hypothesis that passes its own fit test, its magnitude not pressed
    against a bound of its prior, is weighed beside the persistent
    hypotheses still in the running (prior :data:`SHARE` times its fault
    model's); the credible set of ``level`` over them all names the faults,
    those that come and go carrying their :class:`Intermittence`
    (``Hypothesis.intermittent``). Returns (the hypotheses, the verdict,
    its candidates, the events)."""
    T = len(r.time)
    if observer is None or verdict not in ("unexplained", "isolated", "ambiguous"):
        return hyps, verdict, candidates, []
    by = hyps_by(hyps)
    if verdict == "unexplained":
        tried = _tried(hyps, s, T)
    else:  # a named fault whose residuals' mean wanders after its onset: it may have gone and come back
        tried = [by[n] for n in candidates if n in by and comes_and_goes(by[n].kind) and _wanders(by[n])][:TRIED]
    if not tried:
        return hyps, verdict, candidates, []
    s.say(f"trying {', '.join(h.name for h in tried)} as faults that come and go")
    found, fixed_of = {}, {}
    for h in tried:
        model = s.package.MODELS[h.name]
        _, extra = state_rows(model)
        fixed_of[h.name] = model.augment(observer.mean[0][:, None], np.random.default_rng(0))[extra, 0]
        start = max(0, min(h.static.onsets if _finite(h) else h.onset_steps) - 2)
        found[h.name] = intermittence(model, r.ys, r.us, observer, start, fixed_of[h.name], r.outputs,
                                      s.options.rejection, s.options.windows, 0.95)
    events = [ev.IntermittentTried(T - 1, name, i.log_evidence - i.persistent_evidence, len(i.spans),
                                   bool(i.spans) and i.alarm is None) for name, i in found.items()]
    from .later import redated  # a fault that persists, but from after every onset tried

    hyps, later = redated(hyps, found, r, s, observer, fixed_of)
    events += later
    pool = _pool(hyps, found, s, tuple(r.outputs))
    names, comes, weight = _credible(pool, s.options.isolation_level)
    if (not comes and not later) or not names:
        return hyps, verdict, candidates, events
    out = tuple(_decided(h, names, comes, weight, found, T) for h in hyps)
    events += [ev.Intermittent(T - 1, name, found[name].value, found[name].low, found[name].high,
                               tuple((sp.on, sp.off) for sp in found[name].spans), weight[name])
               for name in names if name in comes]
    return out, ("isolated" if len(names) == 1 else "ambiguous"), names, events


def _wanders(h: Hypothesis) -> bool:
    """Whether the residuals of ``h``'s static posterior's most likely cell,
    from its onset on, change their mean or their spread along the stretch:
    cut into consecutive segments of :data:`SEGMENT` samples, per sensor,
    the segments' means differ (the between-segment sum of squares over the
    stretch's variance, chi-square of k - 1 degrees of freedom when the mean
    holds) or their variances do (Bartlett's statistic, chi-square of k - 1),
    the sensors' statistics summed, beyond the quantile of 1 - :data:`WANDERS`
    / 2 of either. A fault that went away and came back leaves segments of
    one sign and then the other (a burst of noise, segments too wide and too
    narrow), which a persistent model's windowed test, built to alarm within
    a horizon, can pass; a plant noisier than its model, or offset from it,
    throughout, does not wander."""
    p = h.static
    if p is None or p.residuals is None or p.best is None:
        return False
    from scipy.special import chdtrc  # chi2.sf inside its support (scipy.stats costs a second to import)

    z = np.asarray(p.residuals, dtype=float)[int(p.best[0]):]
    means, spreads, dof = 0.0, 0.0, 0
    for j in range(z.shape[1] if z.ndim == 2 else 0):
        segments = [seg[np.isfinite(seg)] for seg in (z[lo:lo + SEGMENT, j]
                                                      for lo in range(0, len(z) - SEGMENT + 1, SEGMENT))]
        segments = [seg for seg in segments if len(seg) >= SEGMENT // 2]
        k = len(segments)
        if k < 3:
            continue
        n = np.array([len(seg) for seg in segments], dtype=float)
        m = np.array([seg.mean() for seg in segments])
        v = np.array([seg.var(ddof=1) for seg in segments])
        N = n.sum()
        grand = float((n * m).sum() / N)
        pooled = float(((n - 1) * v).sum() / (N - k))
        if not pooled > 0 or not np.all(v > 0):
            continue
        means += float((n * (m - grand) ** 2).sum()) / pooled
        correction = 1.0 + (float((1.0 / (n - 1)).sum()) - 1.0 / (N - k)) / (3.0 * (k - 1))
        spreads += ((N - k) * math.log(pooled) - float(((n - 1) * np.log(v)).sum())) / correction
        dof += k - 1
    return dof > 0 and min(float(chdtrc(dof, means)), float(chdtrc(dof, spreads))) < WANDERS / 2.0


def _prior(h: Hypothesis, s) -> float:
    """The log prior of hypothesis ``h``'s fault model (setting ``s``'s)."""
    return log_prior(s.priors, h.parameter)


def _finite(h: Hypothesis) -> bool:
    """Whether ``h`` has a static posterior with a finite evidence."""
    return h.static is not None and math.isfinite(h.static.log_evidence)


def _tried(hyps, s, T: int) -> list:
    """The step faults to try as intermittent: not refuted by their
    signatures' symbols, in the running or dropped by a test of their fit
    (their filters' online, or the static posterior's: a fault that went
    away fails them); first those weighed with their magnitude held static,
    likeliest first (their prior times their evidence: the closest to the
    data as persistent faults), then the others, those that lasted longest
    first; :data:`TRIED` of them."""
    steps = [h for h in hyps if comes_and_goes(h.kind) and not h.ruled_out
             and (h.drop is None or h.drop.code in ("static-test", "bayes-factor", "inconsistent"))]
    return sorted(steps, key=lambda h: (0, -(_prior(h, s) + h.static.log_evidence), 0.0) if _finite(h) else
                  (1, -(h.dropped_step if h.drop else T), -(_prior(h, s) + h.log_evidence)))[:TRIED]


def _pool(hyps, found: dict, s, outputs: tuple[str, ...]) -> list[tuple[str, bool, float]]:
    """(name, intermittent, log weight) of the persistent hypotheses still in
    the running (a fault tried, by the larger of its static posterior's
    evidence and the bank's persistent one: the static posterior sums its
    onset over a grid, which can miss a few nats the bank's sum over every
    sample has) and of the intermittent ones that fit, went away at least
    once and whose magnitude is within their prior."""
    by = hyps_by(hyps)

    def persistent(h):  # a fault tried: the larger of its static evidence and the bank's own, on one scale
        i = found.get(h.name)
        return h.static.log_evidence if i is None else max(h.static.log_evidence, i.persistent_evidence)

    pool = [(h.name, False, _prior(h, s) + persistent(h)) for h in hyps
            if _finite(h) and (h.drop is None or h.drop.code == "bayes-factor")]
    pool += [(name, True, _prior(by[name], s) + math.log(SHARE) + i.log_evidence)
             for name, i in found.items() if i.alarm is None and math.isfinite(i.log_evidence)
             and any(sp.off is not None for sp in i.spans)  # it went away at least once
             and not (fault_kind(by[name].kind).noise  # a burst moves no mean, on or off
                      and mean_alarm(np.asarray(i.z, dtype=float)[i.spans[0].on:], outputs) is not None)
             and pressed(replace(by[name].estimate, value=i.value, low=i.low, high=i.high),
                         tuple(float(v) for v in s.package.MODELS[name].FAULT_PRIOR)) is None]
    return pool


def _credible(pool, level: float) -> tuple[tuple[str, ...], set, dict]:
    """The credible set of ``level`` over ``pool``: (the fault models named,
    best first; those named as coming and going; each model's share of the
    posterior, its two ways together)."""
    if not pool:
        return (), set(), {}
    logs = np.array([v for _, _, v in pool])
    share = np.exp(logs - logs.max())
    share /= share.sum()
    chosen, mass = [], 0.0
    for i in np.argsort(-share):
        chosen.append(int(i))
        mass += share[i]
        if mass >= level:
            break
    weight: dict[str, float] = {}
    for (name, _, _), w in zip(pool, share):
        weight[name] = weight.get(name, 0.0) + float(w)
    return tuple(dict.fromkeys(pool[i][0] for i in chosen)), {pool[i][0] for i in chosen if pool[i][1]}, weight


def _decided(h: Hypothesis, names, comes: set, weight: dict, found: dict, T: int) -> Hypothesis:
    """Hypothesis ``h`` after the intermittent ones are weighed: named
    (``names``; coming and going, ``comes``: its estimate the magnitude
    while present), or dropped by the Bayes factor when it was in the running."""
    w = weight.get(h.name, 0.0)
    if h.name in names:
        i = found.get(h.name) if h.name in comes else None
        h = replace(h, drop=None, posterior=w, intermittent=i)
        if i is not None:
            h = replace(h, estimate=replace(h.estimate, value=i.value, std=i.std, low=i.low, high=i.high,
                                            level=i.level, parameter_value=h.estimate.nominal + i.value,
                                            method="kalman", bound=None))
        return h
    if h.drop is None:
        best = names[0]
        return replace(h, posterior=w, drop=Drop("bayes-factor", T - 1, (
            f"the data favour {best}" + (" coming and going" if best in comes else "") + f" (posterior {w:.2g})")))
    return replace(h, posterior=w)


def top_cell(loglik: np.ndarray) -> float:
    """The largest finite log likelihood of the cells (0 when none is)."""
    finite = loglik[np.isfinite(loglik)]
    return float(finite.max()) if len(finite) else 0.0


def hyps_by(hyps) -> dict:
    """The hypotheses by name."""
    return {h.name: h for h in hyps}
