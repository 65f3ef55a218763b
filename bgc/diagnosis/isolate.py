"""Qualitative fault isolation: observed symbols against TRANSCEND signatures.

After a detection, the nominal observer is stopped (thesis section II.3.3):
its particle cloud at the estimated onset is propagated open loop, without
the faulty measurements (:class:`OpenLoop`). Each particle is then a path of
the nominal model from the onset on, so the cloud is a sample of what the
sensors would read without a fault, with the correlation over time that the
plant's process noise gives (a deviation of the truth persists in its state).

**Symbols from tests over windows.** A symbol is a linear statistic of a
sensor's deviation ``d_t = y_t - mean_t`` from the mean nominal prediction,
``S = sum_t a_t d_t``, tested against its distribution without a fault: its
variance is the variance of ``sum_t a_t (h(x_t^i) - mean_t)`` over the
particle paths (the plant's own correlation) plus ``sum_t a_t^2 sigma^2``
(the white measurement noise), so ``Z = S / sd`` is N(0, 1) without a fault,
however correlated the samples are.

* **Magnitude** (``+``/``-``): the sign of the first window mean that
  deviates, windows of ``W`` samples in ``windows`` (1, 8, 32: a jump is seen
  in one sample, a slow drift only over many), the first step ``t`` at which
  any ``|Z| > c_m``.
* **Slope** (``+``/``-``, or ``""`` when the data do not say): the sign of the
  least-squares slope of the deviation over the ``max(8, W)`` samples from
  the step the magnitude was seen on (after the fault, whatever the onset
  estimate), when its ``|Z| > c_s``.

The thresholds are Z thresholds for a false-symbol probability ``alpha``
each, over every test made (the union bound, valid whatever the correlation):
``c_m`` over sensors x steps x windows, ``c_s`` over sensors.

**Matching** (TRANSCEND). A signature's symbols at a sensor are the signs of
the deviation's derivatives at orders 0, 1, 2, ... at the fault (a jump, a
slope, a bend); its first non-zero order ``k`` dominates from the start, so:

* the magnitude seen must be the symbol at order ``k`` (or ``?``), and a
  sensor whose signature is all 0 must not deviate;
* the slope seen must be the symbol at order ``k`` too when ``k >= 1`` (the
  deviation grows from zero), and after a jump (``k = 0``) the first non-zero
  symbol after it (the transient that follows the jump); a slope the data do
  not show, or a ``?``, rules out nothing.

Sensors that have not deviated (yet) rule out nothing: a fault may reach
them at a higher derivative order than the data shows so far. Signatures are
derived for a plant at steady state (the signature stage's docstring), so
this is a filter on hypotheses, not the diagnosis: the fault-model filters
decide.
"""

from __future__ import annotations

from dataclasses import dataclass
from itertools import combinations

import numpy as np

from ..ir import FaultSignatures, Signature, expected_slope, first_symbol
from .detect import union_threshold
from .values import ModeSplit, Symbol


@dataclass(frozen=True, slots=True)
class OpenLoop:
    """The nominal model run open loop from step ``onset``: ``deviation`` (steps
    x sensors) of the data from the mean prediction (NaN: not read),
    ``paths`` (steps x sensors x particles) of each particle's noise-free
    measurement from that mean, ``noise`` the measurement noise std per sensor."""

    onset: int
    deviation: np.ndarray
    paths: np.ndarray
    noise: np.ndarray


def threshold(alpha: float, sensors: int, steps: int, windows: int = 1) -> float:
    """The Z threshold for a false-symbol probability ``alpha`` over ``sensors`` x ``steps`` x ``windows`` tests."""
    return union_threshold(alpha, sensors * steps * windows)


def window_z(run: OpenLoop, windows: tuple[int, ...]) -> dict[int, np.ndarray]:
    """Per window length ``w``: Z of the sum of the deviation over the ``w``
    samples ending at each step (steps x sensors; NaN before ``w`` samples)."""
    d = np.where(np.isfinite(run.deviation), run.deviation, 0.0)
    c = np.concatenate([np.zeros((1,) + d.shape[1:]), np.cumsum(d, axis=0)])
    cp = np.concatenate([np.zeros((1,) + run.paths.shape[1:]), np.cumsum(run.paths, axis=0)])
    out = {}
    for w in windows:
        out[w] = np.full(d.shape, np.nan)
        if len(d) >= w:
            var = (cp[w:] - cp[:-w]).var(axis=-1) + w * run.noise ** 2
            out[w][w - 1:] = (c[w:] - c[:-w]) / np.sqrt(var)
    return out


def slope_z(run: OpenLoop, j: int, start: int, length: int) -> float | None:
    """Z of the least-squares slope of sensor ``j``'s deviation over ``length``
    steps from ``start`` (None when the run is shorter)."""
    if start + length > len(run.deviation) or length < 3:
        return None
    t = np.arange(length, dtype=float)
    a = (t - t.mean()) / ((t - t.mean()) ** 2).sum()
    d = run.deviation[start:start + length, j]
    seen = np.isfinite(d)
    a = np.where(seen, a, 0.0)
    value = float(a @ np.where(seen, d, 0.0))
    var = float((a @ run.paths[start:start + length, j, :]).var() + (a * a).sum() * run.noise[j] ** 2)
    return value / np.sqrt(var) if var > 0 else None


def observed_symbols(run: OpenLoop, sensors: tuple[str, ...], windows: tuple[int, ...] = (1, 8, 32),
                     alpha: float = 0.01) -> tuple[Symbol, ...]:
    """Each deviating sensor's magnitude and slope symbols (see the module docstring)."""
    steps = len(run.deviation)
    c_m = threshold(alpha, len(sensors), steps, len(windows))
    c_s = threshold(alpha, len(sensors), 1)
    zs = window_z(run, windows)
    out = []
    for j, name in enumerate(sensors):
        for t in range(steps):
            hits = [(abs(zs[w][t, j]), w) for w in windows if np.isfinite(zs[w][t, j]) and abs(zs[w][t, j]) > c_m]
            if not hits:
                continue
            _, w = max(hits)
            z = float(zs[w][t, j])
            s = slope_z(run, j, t, max(8, w))
            slope = "" if s is None or abs(s) <= c_s else ("+" if s > 0 else "-")
            out.append(Symbol(name, "+" if z > 0 else "-", run.onset + t, z, w, slope, 0.0 if s is None else float(s)))
            break
    return tuple(out)


def consistent(signature: Signature, measurements: tuple[str, ...], seen: tuple[Symbol, ...]) -> str | None:
    """None when the signature explains the observed symbols, else why not."""
    predicted = dict(zip(measurements, signature.symbols))
    for s in seen:
        first = first_symbol(predicted[s.sensor])
        if first == "0":
            return f"{s.sensor} deviated ({s.sign}) but {signature.name} does not move it"
        if first not in ("?", s.sign):
            return f"{s.sensor} deviated {s.sign}, {signature.name} predicts {first}"
        slope = expected_slope(predicted[s.sensor])
        if s.slope and slope in ("+", "-") and slope != s.slope:
            return f"{s.sensor}'s slope is {s.slope}, {signature.name} predicts {slope}"
    return None


def hypotheses(signatures: FaultSignatures, seen: tuple[Symbol, ...]) -> tuple[list[Signature], list[tuple[Signature, str]]]:
    """(consistent signatures, [(refuted signature, why)])."""
    keep, dropped = [], []
    for sig in signatures.signatures:
        why = consistent(sig, signatures.measurements, seen)
        if why is None:
            keep.append(sig)
        else:
            dropped.append((sig, why))
    return keep, dropped


@dataclass(frozen=True, slots=True)
class ModeSignatures:
    """The signatures of a model with modes, one set per mode (``modes[i]``:
    mode number i + 1, in the model's order), for the matching above: a
    switch changes what a fault shows (an open relay's load carries no
    current; its fault changes nothing), so the symbols are matched against
    the signatures of the modes the plant was in while they were read.
    ``signatures`` and ``measurements`` are the first mode's (every mode has
    the model's faults and sensors)."""

    modes: tuple[FaultSignatures, ...]
    names: tuple[str, ...]

    @property
    def signatures(self) -> tuple[Signature, ...]:
        return self.modes[0].signatures

    @property
    def measurements(self) -> tuple[str, ...]:
        return self.modes[0].measurements

    def hypotheses(self, seen: tuple[Symbol, ...], numbers) -> tuple[list[Signature], list[tuple[Signature, str]]]:
        """(consistent signatures, [(refuted signature, why)]) over the modes
        ``numbers`` (the modes' numbers, from 1; NaN: a sample whose mode the
        data do not say, which may be any): a signature is kept when it is
        consistent in one of them, refuted when it is in none (the reason
        of each mode given)."""
        numbers = np.asarray(numbers, dtype=float)
        if np.isnan(numbers).any() or not len(numbers):
            chosen = list(range(len(self.modes)))
        else:
            chosen = sorted({int(n) - 1 for n in numbers})
        results = [dict(hypotheses_why(self.modes[i], seen)) for i in chosen]
        keep, dropped = [], []
        for sig in self.signatures:
            whys = [r[sig.name] for r in results]
            if any(why is None for why in whys):
                keep.append(sig)
            elif len(chosen) == 1:
                dropped.append((sig, whys[0]))
            else:
                dropped.append((sig, "; ".join(f"in mode {self.names[i]}: {why}" for i, why in zip(chosen, whys))))
        return keep, dropped

    def split(self, candidates: tuple[str, ...], numbers) -> ModeSplit | None:
        """The pairs of fault models ``candidates`` (``PARAMETER_KIND``) whose
        signatures are alike in every mode of ``numbers`` (the modes the
        plant was in, by number from 1) and differ in another mode, with
        those modes (None: no such pair, or a sample whose mode the data do
        not say, so that the modes seen are not known)."""
        numbers = np.asarray(numbers, dtype=float)
        if not len(numbers) or np.isnan(numbers).any():
            return None
        seen = sorted({int(n) - 1 for n in numbers})

        def shown(i: int, name: str) -> tuple:  # what the fault model's signatures predict in mode i
            return tuple(sorted(s.symbols for s in self.modes[i].signatures if f"{s.parameter}_{s.kind}" == name))

        pairs = []
        for one, other in combinations(candidates, 2):
            if any(shown(i, one) != shown(i, other) for i in seen):
                continue  # the modes seen can separate them: no switch needed
            differ = tuple(self.names[i] for i in range(len(self.modes))
                           if i not in seen and shown(i, one) != shown(i, other))
            if differ:
                pairs.append((one, other, differ))
        return ModeSplit(tuple(self.names[i] for i in seen), tuple(pairs)) if pairs else None


def hypotheses_why(signatures: FaultSignatures, seen: tuple[Symbol, ...]) -> list[tuple[str, str | None]]:
    """Each signature's name and why the symbols ``seen`` refute it (None: they do not)."""
    return [(sig.name, consistent(sig, signatures.measurements, seen)) for sig in signatures.signatures]



#: A symbol of a signature in the opposite direction: a deviation's sign turns, no change stays none.
_OPPOSITE = {"+": "-", "-": "+", "0": "0", "?": "?"}


def with_returns(signatures, returning: tuple[str, ...]):
    """``signatures`` (:class:`~bgc.ir.FaultSignatures`, or a model with
    modes' :class:`ModeSignatures`) with, for each parameter of
    ``returning`` (a fault accommodated: the model watched holds it at its
    faulty value), the signatures of its step faults in the direction back
    to its value in the model file where the model lists only the other:
    a fault that goes away, as an intermittent one does, moves every sensor
    the other way (the symbols of the opposite direction, ``+`` and ``-``
    swapped), and is named then as the same fault model sized back to where
    the model file has it."""
    from ..kinds import fault_kind

    if not returning:
        return signatures
    if isinstance(signatures, ModeSignatures):
        return ModeSignatures(tuple(with_returns(s, returning) for s in signatures.modes), signatures.names)
    have = {s.name for s in signatures.signatures}
    back = tuple(Signature(s.parameter, -s.direction, s.kind,
                           tuple(tuple(_OPPOSITE[c] for c in row) for row in s.symbols), s.first)
                 for s in signatures.signatures
                 if s.parameter in returning and not fault_kind(s.kind).drifts
                 and Signature(s.parameter, -s.direction, s.kind, (), ()).name not in have)
    if not back:
        return signatures
    from dataclasses import replace

    return replace(signatures, signatures=signatures.signatures + back)
