"""The onsets a hypothesis is tried from, and how they are weighed: a
drift's grid back from the alarm (:func:`drift_onsets`), its extension
further back (:func:`earlier_onsets`), the onset posterior
(:func:`onset_weights`), a fault's prior (:func:`log_prior`) and the seed
of each onset's filter."""

from __future__ import annotations

import math
import zlib

import numpy as np

from .static_posterior import onset_widths


def earlier_onsets(reach: list[int], tried, search: int) -> tuple[tuple[int, ...], ...]:
    """The onsets of ``reach`` not ``tried`` and before the latest one
    tried, in batches of ``search`` samples back from the earliest tried
    (the gap between the tried ones first: the detector's change point may
    lie far before the others), the nearest batch first.

    >>> earlier_onsets([100, 150, 190, 200, 210, 220], [180, 200, 210, 220], 16)
    ((190,), (150,), (100,))
    >>> earlier_onsets([100, 150, 190, 200, 210, 220], [150, 210, 220], 16)
    ((190, 200), (100,))
    """
    tried = sorted(tried)
    gap = tuple(k for k in reach if tried[0] < k < tried[-1] and k not in tried)
    batches, edge = [gap] if gap else [], tried[0]
    while any(k < edge for k in reach):
        batch = tuple(k for k in reach if edge - search <= k < edge)
        if batch:
            batches.append(batch)
        edge -= search
    return tuple(batches)


#: A drift's onsets are tried every ``spacing`` samples back from the alarm,
#: and further back every 1/16 of the distance to the alarm (when larger): the
#: error of a drift's onset matters relative to how long it ran before the
#: alarm (a slope fitted over d samples from an onset d/32 off is off by about
#: 3 %), so a far onset needs a coarser grid only. (With 1/8, the circuit's and
#: the two tanks' drifts of the sweep were diagnosed a quarter faster, but 2
#: and 3 fewer right: bench/drift_isolation.py.)
ONSET_GROWTH = 1.0 / 16.0


def drift_onsets(step: int, change_point: int, spacing: int, history: int) -> list[int]:
    """The onsets a drift is tried from: the detector's change point and the
    sample before it (the change point is the first sample that deviates; a
    fault that acts through the dynamics began a sample earlier: the
    transition out of its onset sample moves the next one), and from the
    alarm (``step``) back to ``history`` samples before it (not before the
    first sample), ``spacing`` apart, or 1/16 of the distance back
    (:data:`ONSET_GROWTH`) where that is larger."""
    out, d = {change_point, max(change_point - 1, 0)}, 0
    while step - d >= 0 and d <= history:
        out.add(step - d)
        d += max(spacing, int(d * ONSET_GROWTH))
    return sorted(out)


def log_prior(priors, parameter: str, horizon: int = 1) -> float:
    """The log prior of a fault of ``parameter`` (``priors``: by parameter,
    the probability that it happens within the horizon, 0.01 when not
    given), spread over ``horizon`` steps: the log weight of its onset at a
    given step."""
    return math.log(max(priors.get(parameter, 0.01), 1e-300)) - math.log(max(int(horizon), 1))


def onset_weights(starts: list[int], evidence) -> tuple[np.ndarray, float]:
    """A hypothesis's onset posterior (each onset's evidence times its width,
    normalised; zeros when no onset has evidence) and its log evidence (the
    log of that sum; -inf when none has), from its onsets' evidences over a
    common span."""
    e = np.asarray(evidence, dtype=float)
    if not np.isfinite(e).any():
        return np.zeros(len(starts)), -math.inf
    w = onset_widths(starts) * np.exp(e - e.max())
    return w / w.sum(), float(e.max() + math.log(w.sum()))


def hypothesis_seed(seed: int, name: str, onset: int) -> list[int]:
    """The seed of hypothesis ``name``'s filter from ``onset``: fixed by the
    name (a CRC-32 of it, the same in every process), so that a hypothesis gets
    the same random numbers whichever other hypotheses the symbols keep."""
    return [seed, 1, zlib.crc32(name.encode()), onset]


def top_onsets(onsets, posterior, start: int, count: int) -> tuple[int, ...]:
    """The ``count`` most probable of a hypothesis's onsets (those with a posterior)."""
    order = np.argsort(posterior)[::-1][:count]
    return tuple(sorted(onsets[i] for i in order if posterior[i] > 0)) or (start,)
