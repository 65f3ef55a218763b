"""Qualitative fault isolation: observed symbols against TRANSCEND signatures.

After a detection, the nominal observer is stopped (thesis section II.3.3):
its particle cloud at the estimated onset is propagated open loop, without
the faulty measurements, and each measurement is compared with that nominal
prediction (mean and std, process and measurement noise included). Without a
fault each normalised deviation r_t = (y_t - mean_t) / std_t is N(0, 1), but
successive ones are strongly correlated (the truth's process noise persists
in its state), so they are tested one at a time, not summed: the first t at
which |r_t| > c gives that sensor's observed symbol, the sign of r_t (the
direction of its first deviation) and the step it was seen. ``c`` is a Z
threshold with a false-symbol probability ``alpha`` over the sensors and the
steps looked at (the union bound, valid whatever the correlation).

A fault signature is consistent with the observations when every sensor
that deviated has, as the first non-zero symbol of its signature, the
observed sign (or ``?``), and no sensor deviated whose signature is all 0
(that fault cannot move it). Sensors that have not deviated (yet) rule out
nothing: a fault may reach them at a higher derivative order than the data
shows so far. Signatures are derived for a plant at steady state (the
signature stage's docstring), so this is a filter on hypotheses, not the
diagnosis: the fault-model filters decide.
"""

from __future__ import annotations

from dataclasses import dataclass
import numpy as np

from ..ir import FaultSignatures, Signature
from .detect import union_threshold


@dataclass(frozen=True, slots=True)
class Symbol:
    """A sensor's observed first deviation: ``sign`` + or -, seen at ``step``."""

    sensor: str
    sign: str
    step: int
    statistic: float


def threshold(alpha: float, sensors: int, steps: int) -> float:
    """The Z threshold for a false-symbol probability ``alpha`` over ``sensors`` x ``steps`` tests."""
    return union_threshold(alpha, sensors * steps)


def observed_symbols(r: np.ndarray, sensors: tuple[str, ...], onset: int, alpha: float = 0.01) -> tuple[Symbol, ...]:
    """First significant deviation of each sensor in the open-loop residuals
    ``r`` (steps x sensors, row 0 at step ``onset``); NaN entries are skipped."""
    r = np.where(np.isfinite(r), r, 0.0)
    c = threshold(alpha, len(sensors), len(r))
    out = []
    for j, name in enumerate(sensors):
        for t in range(len(r)):
            s = r[t, j]
            if abs(s) > c:
                out.append(Symbol(name, "+" if s > 0 else "-", onset + t, float(s)))
                break
    return tuple(out)


def first_symbol(symbols: tuple[str, ...]) -> str:
    """The first symbol of a signature that is not 0 (``0`` if none)."""
    return next((s for s in symbols if s != "0"), "0")


def consistent(signature: Signature, measurements: tuple[str, ...], seen: tuple[Symbol, ...]) -> str | None:
    """None when the signature explains the observed symbols, else why not."""
    predicted = dict(zip(measurements, signature.symbols))
    for s in seen:
        first = first_symbol(predicted[s.sensor])
        if first == "0":
            return f"{s.sensor} deviated ({s.sign}) but {signature.name} does not move it"
        if first not in ("?", s.sign):
            return f"{s.sensor} deviated {s.sign}, {signature.name} predicts {first}"
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
