"""The mode of a model with modes, read from the data when they do not say it (a hidden mode).

A plant whose valves or relays switch by themselves (autonomous transitions:
a guard on its state, or a time in the mode) often logs no mode column. The
diagnosis then reads the mode from the measurements before anything else
sees the samples: :class:`ModeDecoder` is a bank of cubature Kalman filters
of the nominal model, one per *branch*, a history of modes the data may
have followed (a multiple-hypothesis filter over the modes, pruned):

* each step, a branch in mode i may stay or leave by one of i's transitions:
  a timed one when its time in the mode runs out (exactly where a branch
  knows when it entered; a mode entered by a guard within a step has its
  time in the mode uncertain by the step's uniform placement, variance
  dt^2/12, and the exit comes with its hazard over each step, so that an
  exit just before or after a sample is tried both ways); an autonomous one with the probability that its guard
  is crossed over the step, from the branch's estimate: the guard's margin
  g at the branch's cubature points, its mean and variance, and the
  threshold's std tau the model declares, give Phi(mean / sqrt(variance +
  tau^2)) that the guard holds, at the step's start (the estimate after the
  last sample: its process noise may have carried the plant across) and at
  its end (the prediction in mode i); with a tau, a branch that has not
  switched knows its threshold lies beyond where it was at the end of the
  step before, and the hazard is the probability's increase since then over
  what was left, (max(Phi_start, Phi_end) - Phi_before) / (1 - Phi_before),
  the particle filter's rule (the generated model's ``_first``); without a
  tau, max(Phi_start, Phi_end). A controlled transition needs the data: a
  model that has one is not read this way (:func:`readable`);
* each branch that moves is a filter of its own from there (the generated
  model's step with the mode given: the transition placed within the step
  where the guard or the time in the mode puts it, the resets, the rest of
  the step in the mode entered), weighted by the probability of its move
  times its likelihood of the sample;
* branches under ``FLOOR`` of the weight are dropped, and the ``BRANCHES``
  likeliest kept.

A step's mode is **decided** when the branches that disagree on it hold less
than ``AGREE`` of the weight (they are dropped), or, the oldest sample
waiting ``LAG`` steps, as the likeliest mode (the branches that disagree
dropped): a plant that stays in its mode has each sample's mode decided as
it comes; around a switch the samples wait until the data settle it. The
decided samples go on with the mode as their ``mode`` input, as if the data
had said it, each switch with a :class:`~bgc.events.ModeRead` event.

That is the nominal model's reading. A fault moves the switches (a guard
crossed early), so after a diagnosis the likeliest hypotheses read the modes
again each with its own fault model (:func:`read_again`, from the nominal
reading before its onset, :func:`read_head`) at the onset and size that make
the data likeliest with the modes hidden (:func:`read_fault`: one bank per
onset and size of a grid, weighed together, ``logliks``), and the diagnosis is made again on
that reading (:meth:`bgc.diagnosis.diagnoser.Diagnoser.finish`).

The decoder's state is plain data (:class:`DecoderState`).
"""

from __future__ import annotations

import dataclasses
import math
import sys
from dataclasses import dataclass

import numpy as np

from ..data.sampler import Sample
from .. import events as ev
from ..filters.cubature import _Filter
from .identify import log_sum_exp

__all__ = ["AGREE", "BRANCHES", "DecoderState", "FINER", "FLOOR", "GRID", "LAG", "ModeDecoder", "ONSETS", "POOL",
           "REREAD", "read_again", "read_fault", "read_head", "read_job", "readable"]

#: The most steps a sample waits for its mode to be decided.
LAG = 10
#: The most branches (histories of modes) the bank keeps.
BRANCHES = 8
#: A step's mode is decided when the branches that disagree hold less than this share of the weight.
AGREE = 1e-6
#: A branch under this share of the weight is dropped.
FLOOR = 1e-12
#: The most hypotheses whose own equations read the modes again after a diagnosis
#: (:meth:`bgc.diagnosis.diagnoser.Diagnoser.finish`).
REREAD = 3
#: The most hypotheses, the diagnosis's likeliest, that read the modes to be ranked by that reading (of
#: which :data:`REREAD` take theirs): a bound on what a plant of many fault models pays.
POOL = 2 * REREAD
#: A fault's onset read with the hidden mode: from this many samples before its diagnosis's onset to 2 after.
ONSETS = 4
#: The points of the first grid over a fault's prior on which its size is read with the hidden mode.
GRID = 7
#: The steps each side of the best size in the one grid after the first, between the best point's
#: neighbours: 27 times finer than the first grid's spacing, the spacing three zooms of 7 points reach.
FINER = 27
#: A mode with a timed exit entered by a guard: the least probability given to its entry at the step's
#: start (the last sample's noise carried the plant across) and to its entry within the step.
PLACED = 0.01


def _due(over: np.ndarray, spread: np.ndarray, span: float, slack: float) -> np.ndarray:
    """The probability that a timed exit happens within the step of ``span``,
    the branch having stayed until its start: its time in the mode at the
    step's end is ``over`` the exit's time, with a normal error of std
    ``spread`` (0: exactly, with ``slack`` for rounding); the hazard
    (Phi(over/spread) - Phi((over - span)/spread)) / (1 - Phi((over -
    span)/spread)), the exit's distribution over the step given it had not
    come by the step's start."""
    from scipy.special import ndtr

    with np.errstate(divide="ignore", invalid="ignore"):
        scale = np.where(spread > 0, spread, 1.0)
        end, start = ndtr(over / scale), ndtr((over - span) / scale)
        left = 1.0 - start
        h = np.where(left > 1e-300, (end - start) / np.where(left > 1e-300, left, 1.0), 1.0)
    return np.where(spread > 0, np.clip(h, 0.0, 1.0), (over >= -slack).astype(float))


def readable(model) -> str | None:
    """Why the mode of ``model`` (a generated model with modes) cannot be read
    from the data (None: it can): a controlled transition, which only the data
    can say."""
    controlled = [t for t in model.TRANSITIONS if t[2] is None and t[3] is None]
    if controlled:
        names = ", ".join(f"{model.MODES[t[0] - 1]} -> {model.MODES[t[1] - 1]}" for t in controlled)
        which = f"transition {names} is" if len(controlled) == 1 else f"transitions {names} are"
        return f"its {which} controlled (set from outside), which only the data can say"
    return None


@dataclass(frozen=True, slots=True)
class DecoderState:
    """A :class:`ModeDecoder`'s: per branch its mean ``m`` (B, n), covariance
    ``P`` (B, n, n), log weight, each transition's probability that its guard
    held at the branch's last estimate and at the end of its last prediction
    (B, transitions each) and its modes over the samples waiting (B,
    waiting); the samples waiting; the mode of the last sample decided; each
    branch's fault states (f, B), the steps taken, per bank the
    log-likelihood of the samples taken, and each branch's bank."""

    m: np.ndarray
    P: np.ndarray
    logw: np.ndarray
    held: np.ndarray
    before: np.ndarray
    history: np.ndarray
    waiting: tuple
    mode: int
    fixed: np.ndarray
    k: int
    logliks: np.ndarray
    cell: np.ndarray


class ModeDecoder:
    """The mode of a model with modes read from its data, one sample at a
    time (module docstring): :meth:`push` a sample (its ``mode`` input NaN),
    get the samples whose mode is decided, with it; :meth:`flush` at the end
    decides the rest."""

    def __init__(self, model, fault: tuple[int, np.ndarray] | None = None, decide: bool = True):
        """``model``: the generated model (the nominal model, or a fault
        model with ``fault`` = (its onset step, its fault states from the
        onset: a drifting parameter's value, then the magnitude; (f,), or (f,
        cells) for several banks at once, one per column, each with its own
        branches and likelihood), whose branches run with the fault from that
        step); ``decide``: decide the samples' modes (one bank), else only
        weigh the data (:attr:`logliks`, per bank)."""
        why = readable(model)
        if why is not None:
            raise ValueError(f"the mode of {model.MODEL} cannot be read from the data: {why}")
        self.model = model
        self.kf = kf = _Filter(model)
        self.transitions = tuple(model.TRANSITIONS)
        self.row, self.input = model.MODE_ROW, model.MODE_INPUT
        #: the index of the time in the mode among the filter's rows (None: no transition is timed)
        self.clock = None if model.DWELL_ROW is None else kf.physical.index(model.DWELL_ROW)
        #: per mode number, whether a timed transition leaves it
        self.timed = {i + 1: any(t[0] == i + 1 and t[3] is not None for t in self.transitions)
                      for i in range(len(model.MODES))}
        values = None if fault is None else np.asarray(fault[1], dtype=float)
        cells = 1 if values is None or values.ndim == 1 else values.shape[1]
        self.decide = decide
        if decide and cells > 1:
            raise ValueError("a decoder that decides the samples' modes has one bank")
        #: the bank of each branch
        self.cell = np.arange(cells)
        self.m = np.repeat(np.asarray(model.X0, dtype=float)[None, kf.physical], cells, axis=0)
        self.P = np.repeat(np.diag(np.asarray(model.X0_STD, dtype=float)[kf.physical] ** 2)[None], cells, axis=0)
        self.logw = np.zeros(cells)
        self.history = np.zeros((cells, 0), dtype=np.intp)
        self.waiting: list[Sample] = []
        self.mode = self._modes(self.m)[0]
        #: the fault's onset step and each bank's fault states from it (f, cells)
        self.fault = None if fault is None else (np.broadcast_to(np.asarray(fault[0], dtype=np.intp), (cells,)).copy(),
                                                 values.reshape(len(kf.extra), cells))
        self.k = 0  # the steps taken
        #: each branch's fault states (f, B): before the onset the nominal model's (the magnitude 0)
        self.fixed = np.zeros((len(kf.extra), cells))
        if fault is not None:
            self.fixed[:] = self.fault[1]
            self.fixed[kf.magnitude] = 0.0
        self.held = self._held(self.m, self.P, np.asarray(model.inputs(0.0), dtype=float))
        self.before = self.held.copy()
        #: per bank, log p(y_0 .. y_k) of the samples taken over its branches (those pruned as they stood)
        self.logliks = np.zeros(cells)

    def start_among(self, means: np.ndarray, covariances: np.ndarray, weights: np.ndarray) -> None:
        """Start a decoder that took no sample from several branches instead
        of the model's one start: branch b at the carried states ``means[b]``
        (each a full state of the model: its mode among them) with covariance
        ``covariances[b]`` (states x states), weighed by ``weights[b]`` (a
        plant whose mode is not known when the data begin again,
        :mod:`bgc.diagnosis.bridge`). The mode before is not known: the
        first sample decided says no change of mode."""
        if self.k or self.waiting or self.fault is not None or not self.decide:
            raise ValueError("a decoder starts among branches before its first sample, nominal and deciding")
        rows = self.kf.physical
        means = np.atleast_2d(np.asarray(means, dtype=float))
        covariances = np.asarray(covariances, dtype=float).reshape(len(means), means.shape[1], means.shape[1])
        weights = np.asarray(weights, dtype=float)
        self.m = means[:, rows].copy()
        self.P = covariances[:, rows][:, :, rows].copy()
        self.mode = 0  # (not known)
        with np.errstate(divide="ignore"):
            self.logw = np.log(weights / weights.sum())
        self.cell = np.zeros(len(means), dtype=np.intp)
        self.history = np.zeros((len(means), 0), dtype=np.intp)
        self.fixed = np.zeros((len(self.kf.extra), len(means)))
        self.held = self._held(self.m, self.P, np.asarray(self.model.inputs(0.0), dtype=float))
        self.before = self.held.copy()

    # -- the bank -------------------------------------------------------------------------------------------

    def _modes(self, m: np.ndarray) -> np.ndarray:
        return np.rint(m[:, self.kf.physical.index(self.row)]).astype(np.intp)

    def _points(self, m: np.ndarray, P: np.ndarray, fixed: np.ndarray | None = None) -> np.ndarray:
        """The cubature points of the branches (n_x, C 2n), their fault
        states ``fixed`` (f, C; None: the model's X0)."""
        kf, C = self.kf, m.shape[0]
        X = np.empty((kf.n_x, C, 2 * kf.n))
        X[:] = np.asarray(self.model.X0, dtype=float)[:, None, None]
        if fixed is not None:
            for j, row in enumerate(kf.extra):
                X[row] = fixed[j][:, None]
        kf._points(m, P, X)
        return X.reshape(kf.n_x, -1)

    def _margins(self, flat: np.ndarray, C: int, k: int, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The mean and variance over each branch's points of transition k's guard margin."""
        guard = self.transitions[k][2]
        g = np.asarray(guard(flat, u[:self.input], self.model.THETA), dtype=float).reshape(C, -1)
        return g.mean(axis=1), g.var(axis=1)

    def _holds(self, mean: np.ndarray, var: np.ndarray, k: int) -> np.ndarray:
        """The probability that transition k's guard holds, its margin's mean and variance given."""
        _, _, _, _, _, strict, tolerance, _ = self.transitions[k]
        scale = np.sqrt(var + (tolerance or 0.0) ** 2)
        sharp = (mean > 0) if strict else (mean >= 0)
        from scipy.special import ndtr  # here: scipy.special costs half a second to import, and only modes hidden in the data ask
        with np.errstate(divide="ignore", invalid="ignore"):
            p = ndtr(mean / np.where(scale > 0, scale, 1.0))
        return np.where(scale > 0, p, sharp.astype(float))

    def _held(self, m: np.ndarray, P: np.ndarray, u: np.ndarray) -> np.ndarray:
        """Per branch, each transition's probability that its guard holds at
        the branch's estimate (0 for those out of other modes, or with no guard)."""
        out = np.zeros((m.shape[0], len(self.transitions)))
        modes = self._modes(m)
        flat = None
        for k, t in enumerate(self.transitions):
            rows = np.flatnonzero(modes == t[0])
            if t[2] is None or not len(rows):
                continue
            if flat is None:
                flat = self._points(m, P, self.fixed)
            C = m.shape[0]
            mean, var = self._margins(flat, C, k, u)
            out[rows, k] = self._holds(mean, var, k)[rows]
        return out

    def _moves(self, u: np.ndarray) -> tuple[list[tuple], np.ndarray]:
        """Each branch's moves over the next step: (branches, mode after the
        step, log probability of the move, the share of it that happens at the
        step's start (None: none), the time in the mode after the step (NaN:
        as the model's step puts it)) per group; and each branch's
        probabilities that its guards hold at the end of the step in its mode."""
        dt = self.model.DT
        modes = self._modes(self.m)
        ends = np.zeros_like(self.held)
        moves = []
        for i in np.unique(modes):
            sel = np.flatnonzero(modes == i)
            hazards, starts = self._hazards(int(i), sel, u, ends)
            stay = np.ones(len(sel))
            for h in hazards.values():
                stay = stay * (1.0 - h)
            share = {k: h * stay / np.where(h < 1.0, 1.0 - h, 1.0) for k, h in hazards.items()}
            for k, h in hazards.items():  # a certain crossing: the others' share is 0 unless certain too
                share[k] = np.where(h >= 1.0, np.prod([np.where(hazards[j] >= 1.0, 1.0, 1.0 - hazards[j])
                                                        for j in hazards if j != k], axis=0), share[k])
            clock = self.m[sel, self.clock] + dt if self.clock is not None else np.full(len(sel), np.nan)
            # the std of the time in the mode: 0 where the branch knows when it entered, else what the data
            # said of an entry within a step (the step's placement and the samples after it)
            spread = np.sqrt(np.maximum(self.P[sel, self.clock, self.clock], 0.0)) if self.clock is not None \
                else np.zeros(len(sel))
            clocks = {}
            for k, t in enumerate(self.transitions):  # a timed exit: when the time in the mode runs out
                if t[0] != i or t[2] is not None or t[3] is None:
                    continue
                due = _due(clock - t[3], spread, dt, 1e-9 * max(1.0, t[3]))
                share[k] = due * stay
                stay = (1.0 - due) * stay
                clocks[k] = np.maximum(clock - t[3], 0.0)  # the time in the mode entered, exactly
            # staying, a branch unsure of its time in the mode lets the step's update move it
            clock = np.where(spread > 0, np.nan, clock)
            total = stay + sum(share.values()) if share else stay
            total = np.where(total > 0, total, 1.0)
            with np.errstate(divide="ignore"):
                moves.append((sel, int(i), np.log(stay / total), None, clock))
                for k, p in share.items():
                    moves.append((sel, self.transitions[k][1], np.log(p / total), starts.get(k),
                                  clocks.get(k, np.full(len(sel), np.nan))))
        return moves, ends

    def _hazards(self, i: int, sel: np.ndarray, u: np.ndarray, ends: np.ndarray) -> tuple[dict, dict]:
        """For branches ``sel``, all in mode i: per autonomous transition out
        of i, the probability that it fires over the next step and the share
        of that at the step's start; ``ends`` gets the probabilities that the
        guards hold at the step's end."""
        model = self.model
        hazards, starts = {}, {}
        autonomous = [(k, t) for k, t in enumerate(self.transitions) if t[0] == i and t[2] is not None]
        if not autonomous:
            return hazards, starts
        ui = u.copy()
        ui[self.input] = i
        flat = self._points(self.m[sel], self.P[sel], self.fixed[:, sel])
        model.predict(flat, ui, model.THETA, model.DT, out=flat)
        for k, t in autonomous:
            ends[sel, k] = end = self._holds(*self._margins(flat, len(sel), k, ui), k)
            start = self.held[sel, k]
            now = np.maximum(start, end)
            before = self.before[sel, k] if t[6] else np.zeros(len(sel))
            if t[6]:  # a threshold with a std: not crossed before, so beyond where the branch was
                h = np.clip((now - before) / np.maximum(1.0 - before, 1e-300), 0.0, 1.0)
                hazards[k] = np.where(before < 1.0, h, 1.0)
            else:
                hazards[k] = now
            # of the crossing, the share at the start (the last sample's noise carried it across); at least
            # PLACED each way: the estimate's margins place a crossing within a step roughly, and a timed
            # exit later tells which it was
            gain = now - before
            starts[k] = np.clip(np.where(gain > 0, (start - before) / np.where(gain > 0, gain, 1.0), 0.0),
                                PLACED, 1.0 - PLACED)
        return hazards, starts

    def _advance(self, y: np.ndarray, u: np.ndarray) -> None:
        """One step of every branch and its moves; the pruned bank after it."""
        parents, targets, logp, dwell = [], [], [], []
        moves, ends = self._moves(u)
        dt = self.model.DT
        for sel, target, lp, start, clock in moves:
            if start is not None and self.timed[target]:  # the time in the mode entered: from the start, or less
                for share, at in ((start, dt), (1.0 - start, -1.0)):
                    with np.errstate(divide="ignore"):
                        self._keep(parents, targets, logp, dwell, sel, target, lp + np.log(share), at)
            else:
                self._keep(parents, targets, logp, dwell, sel, target, lp, clock)
        parents, targets, logp = np.concatenate(parents), np.concatenate(targets), np.concatenate(logp)
        m, P, loglik, fixed = self._children(y, u, parents, targets)
        self.k += 1
        if self.clock is not None:  # each branch's time in its mode: exactly where it says when it entered
            row, dwell = self.clock, np.concatenate(dwell)
            m[:, row] = np.where(dwell >= 0, dwell, np.where(dwell == -1.0, np.minimum(m[:, row], dt * (1 - 1 / 8)),
                                                               m[:, row]))
            m[:, row] = np.where(np.isfinite(m[:, row]), m[:, row], 0.0)
            exact = dwell >= 0  # (a stay not knowing when it entered: the variance it had)
            within = dwell == -1.0  # an entry somewhere within the step: uniform over it
            P[exact | within, row, :] = 0.0
            P[exact | within, :, row] = 0.0
            P[within, row, row] = dt * dt / 12.0
        logw = self.logw[parents] + logp + np.where(np.isfinite(loglik), loglik, -np.inf)
        history = np.concatenate([self.history[parents], targets[:, None]], axis=1) if self.decide else \
            self.history[parents]
        moved = targets != self._modes(self.m)[parents]
        cell = self.cell[parents]
        order, weights = self._pruned(cell, logw, self.logw[parents] + logp)
        self.m, self.P, self.history, self.fixed = m[order], P[order], history[order], fixed[:, order]
        self.cell, self.logw = cell[order], weights
        self.held = self._held(self.m, self.P, u)
        # the end of the step in its mode, where a branch that stayed did not switch; a mode entered: its start
        self.before = np.where(moved[order][:, None], self.held, ends[parents[order]])

    def _pruned(self, cell: np.ndarray, logw: np.ndarray, prior: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Each bank (the children of one cell) weighed, pruned and normalised
        on its own, all banks in a few array operations: the children kept
        (bank by bank, the heaviest first, those within ``FLOOR`` of their
        bank's heaviest, at most ``BRANCHES``) and their normalised log
        weights; each bank's log-likelihood of the sample added to
        ``logliks``. A bank none of whose children explains the sample keeps
        them as they were weighed before it (``prior``)."""
        banks, index = np.unique(cell, return_inverse=True)
        finite = np.isfinite(logw)
        explained = np.bincount(index, weights=finite, minlength=len(banks)) > 0
        lw = np.where(explained[index], logw, prior)
        sort = np.lexsort((-lw, index))  # bank by bank, the heaviest first (ties: in the children's order)
        lw, index = lw[sort], index[sort]
        first = np.flatnonzero(np.r_[True, index[1:] != index[:-1]])
        top = lw[first]  # each bank's heaviest
        rank = np.arange(len(lw)) - np.repeat(first, np.diff(np.r_[first, len(lw)]))
        total = _group_log_sum_exp(lw, index, top, len(banks))
        ok = np.isfinite(total)
        self.logliks[banks[ok]] += total[ok]
        keep = (lw - top[index] > math.log(FLOOR)) & (rank < BRANCHES)
        lw, index = lw[keep], index[keep]
        return sort[keep], lw - _group_log_sum_exp(lw, index, top, len(banks))[index]

    def _children(self, y, u, parents: np.ndarray, targets: np.ndarray):
        """Each child's filter step from its parent branch into its mode
        ``targets`` (the generated model's step with the mode given): its mean,
        covariance, log-likelihood of the sample and fault states."""
        n = self.kf.n
        m, P, loglik = np.empty((len(parents), n)), np.empty((len(parents), n, n)), np.empty(len(parents))
        fixed = self.fixed[:, parents]
        cell = self.cell[parents]
        at_onset = np.zeros(len(parents), dtype=bool) if self.fault is None else self.fault[0][cell] == self.k
        # from its onset's sample on a bank has its fault (its transition into it nominal: the onset rule)
        fixed[:, at_onset] = self.fault[1][:, cell[at_onset]] if at_onset.any() else fixed[:, at_onset]
        for j in np.unique(targets):
            for onset in (False, True):
                rows = np.flatnonzero((targets == j) & (at_onset == onset))
                if not len(rows):
                    continue
                uj = u.copy()
                uj[self.input] = j
                held = np.ascontiguousarray(fixed[:, rows])
                with np.errstate(all="ignore"):
                    ll, mj, Pj, *_ = self.kf.step(y, uj, self.m[parents[rows]], self.P[parents[rows]], held,
                                                  slice(0, len(rows) if onset else 0))
                m[rows], P[rows], loglik[rows], fixed[:, rows] = mj, Pj, ll, held
        return m, P, loglik, fixed

    @staticmethod
    def _keep(parents, targets, logp, dwell, sel, target, lp, clock) -> None:
        """Add the moves of branches ``sel`` into mode ``target`` of log
        probability ``lp`` (those over ``FLOOR``); ``clock``: the time in
        its mode after the step (NaN: as the model's step puts it; -1: less
        than a step, as the step puts it)."""
        keep = lp > math.log(FLOOR)
        parents.append(sel[keep])
        targets.append(np.full(int(keep.sum()), target, dtype=np.intp))
        logp.append(lp[keep])
        dwell.append(np.broadcast_to(np.asarray(clock, dtype=float), sel.shape)[keep])

    # -- the samples ----------------------------------------------------------------------------------------

    def push(self, s: Sample) -> list[Sample]:
        """Take sample ``s``; the samples whose mode is decided (oldest first)."""
        self._advance(s.y, s.u)
        if not self.decide:
            return []
        self.waiting.append(s)
        return self._decide(final=False)

    def flush(self) -> list[Sample]:
        """The samples still waiting, each with its likeliest mode (the data end)."""
        return self._decide(final=True)

    def _decide(self, final: bool) -> list[Sample]:
        out = []
        while self.waiting:
            first = self.history[:, 0]
            w = np.exp(self.logw)
            modes = np.unique(first)
            weights = np.array([w[first == mode].sum() for mode in modes])
            best = int(np.argmax(weights))
            share = weights[best] / weights.sum()
            if not (share >= 1.0 - AGREE or final or len(self.waiting) > LAG):
                break
            mode = int(modes[best])
            keep = first == mode
            self.m, self.P, self.held, self.before = self.m[keep], self.P[keep], self.held[keep], self.before[keep]
            self.fixed, self.cell = self.fixed[:, keep], self.cell[keep]
            self.logw = self.logw[keep] - log_sum_exp(self.logw[keep])
            self.history = self.history[keep, 1:]
            s = self.waiting.pop(0)
            u = s.u.copy()
            u[self.input] = mode
            name = self.model.INPUTS[self.input]
            events = tuple(ev.ModeHidden(LAG) if isinstance(e, ev.InputFromModel) and e.input == name else e
                           for e in s.events)
            if mode != self.mode and self.mode:  # (0: the mode before not known, after an outage)
                events += (ev.ModeRead(s.k, self.model.MODES[self.mode - 1], self.model.MODES[mode - 1],
                                       float(share)),)
                self.mode = mode
            out.append(dataclasses.replace(s, u=u, events=events))
        return out

    # -- the state ------------------------------------------------------------------------------------------

    def state(self) -> DecoderState:
        return DecoderState(self.m.copy(), self.P.copy(), self.logw.copy(), self.held.copy(), self.before.copy(),
                            self.history.copy(), tuple(self.waiting), self.mode, self.fixed.copy(), self.k,
                            self.logliks.copy(), self.cell.copy())

    def restore(self, s: DecoderState) -> None:
        self.m, self.P, self.logw = s.m.copy(), s.P.copy(), s.logw.copy()
        self.held, self.before, self.history = s.held.copy(), s.before.copy(), s.history.copy()
        self.waiting, self.mode = list(s.waiting), int(s.mode)
        self.fixed, self.k, self.logliks, self.cell = s.fixed.copy(), int(s.k), s.logliks.copy(), s.cell.copy()



def read_head(model, samples, onset: int, branches: tuple | None = None) \
        -> tuple[DecoderState, list[Sample]] | None:
    """The nominal ``model``'s reading of ``samples`` up to the last sample
    before step ``onset`` at which no sample waits: its state there and the
    samples it decided (None: none such), where every reading of a fault
    from that onset starts (:func:`read_again`); ``branches``: where the
    reading starts (:meth:`ModeDecoder.start_among`'s arguments; None: the
    model's start)."""
    decoder = ModeDecoder(model)
    if branches is not None:
        decoder.start_among(*branches)
    decided: list[Sample] = []
    head = None
    for s in samples[:max(onset, 0)]:
        decided += decoder.push(s)
        if not decoder.waiting:
            head = (decoder.state(), list(decided))
    return head


def read_again(model, samples, fault: tuple[int, np.ndarray], head=None) -> list[Sample]:
    """``samples`` (their mode input NaN) with the modes a fault model reads
    from them (:class:`ModeDecoder` of ``model`` with ``fault``: its onset
    step and fault states), the :class:`~bgc.events.ModeRead` events anew.
    ``head``: :func:`read_head`'s reading before the onset, taken up there."""
    decoder = _taken_up(ModeDecoder(model, fault), head)
    out = [] if head is None else list(head[1])
    out += [decided for s in samples[len(out):] for decided in decoder.push(s)]
    return out + decoder.flush()


def _taken_up(decoder: ModeDecoder, head) -> ModeDecoder:
    """``decoder`` (of a fault model, one bank per column of its fault
    states) taken up from ``head``'s nominal reading, each bank a copy of it."""
    if head is None:
        return decoder
    state = head[0]
    cells = decoder.fault[1].shape[1]
    before = decoder.fault[1].copy()
    before[decoder.kf.magnitude] = 0.0
    B = len(state.logw)
    decoder.restore(dataclasses.replace(
        state, m=np.tile(state.m, (cells, 1)), P=np.tile(state.P, (cells, 1, 1)), logw=np.tile(state.logw, cells),
        held=np.tile(state.held, (cells, 1)), before=np.tile(state.before, (cells, 1)),
        history=np.tile(state.history, (cells, 1)), fixed=np.repeat(before, B, axis=1),
        logliks=np.full(cells, float(state.logliks[0])), cell=np.repeat(np.arange(cells), B)))
    return decoder


def read_fault(model, samples, onsets, start: np.ndarray, hint: float, head=None) -> tuple[int, float, float]:
    """The onset (one of ``onsets``) and size of fault model ``model``
    (``start``: its fault states at the onset, the magnitude last) that make
    the samples likeliest with the modes hidden (a bank of
    :class:`ModeDecoder` per onset and size, weighed together, from
    ``head``): every onset with a grid of :data:`GRID` sizes over the
    fault's prior and ``hint`` (NaN: none); then, at the best onset, a grid
    between the best size's neighbours, :data:`FINER` steps each side of it
    (one pass: a decoder's step costs about as much for eight banks as for
    sixty, so three zooms of a few points, one pass each, cost twice as much
    for the same spacing), the best one among them. A fault with no size (a
    stuck switch's flag) is its one point. Returns the onset, the size and the
    log-likelihood of every sample with the modes hidden at them (the
    head's with the rest's: comparable between fault models)."""
    low, high = (float(v) for v in model.FAULT_PRIOR)
    onsets = np.asarray(sorted(set(int(k) for k in onsets)), dtype=np.intp)
    hints = [np.clip(hint, low, high)] if math.isfinite(hint) else []
    sizes = np.array([low]) if high <= low else np.unique(np.append(np.linspace(low, high, GRID), hints))
    cells_onset, cells_size = np.repeat(onsets, len(sizes)), np.tile(sizes, len(onsets))
    for _ in range(2 if high > low else 1):
        faults = np.repeat(np.asarray(start, dtype=float)[:, None], len(cells_size), axis=1)
        faults[-1] = cells_size
        decoder = _taken_up(ModeDecoder(model, (cells_onset, faults), decide=False), head)
        for s in samples[0 if head is None else len(head[1]):]:
            decoder.push(s)
        best = int(np.argmax(np.where(np.isfinite(decoder.logliks), decoder.logliks, -np.inf)))
        onset, size, loglik = int(cells_onset[best]), float(cells_size[best]), float(decoder.logliks[best])
        mine = np.flatnonzero(cells_onset == onset)
        where = int(np.searchsorted(cells_size[mine], size))
        a, b = cells_size[mine][max(where - 1, 0)], cells_size[mine][min(where + 1, len(mine) - 1)]
        # the best point in the finer grid's middle, each side in as many steps (the hint spaced the first grid
        # unevenly): no grid's best is less likely than the one before's
        cells_size = np.unique(np.concatenate([np.linspace(a, size, FINER + 1), np.linspace(size, b, FINER + 1)]))
        cells_onset = np.full(len(cells_size), onset)
    return onset, size, loglik


def read_job(job: tuple) -> tuple[int, float, float]:
    """:func:`read_fault` of one fault model (in a worker process): ``job``
    is (the generated package's module name, the fault model's name, the
    samples, the onsets, the fault states at the onset, the size's hint, the
    nominal reading before the onsets)."""
    package_name, name, samples, onsets, start, hint, head = job
    return read_fault(sys.modules[package_name].MODELS[name], samples, onsets, start, hint, head)


def _group_log_sum_exp(lw: np.ndarray, index: np.ndarray, top: np.ndarray, groups: int) -> np.ndarray:
    """log(sum(exp(lw))) per group (``index``: each entry's group; ``top``:
    each group's largest entry, the shift): :func:`log_sum_exp` of every
    group at once; -inf for a group whose entries are all -inf."""
    shift = np.where(np.isfinite(top), top, 0.0)
    with np.errstate(divide="ignore"):
        sums = np.log(np.bincount(index, weights=np.exp(lw - shift[index]), minlength=groups))
    return np.where(np.isfinite(top), shift + sums, top)
