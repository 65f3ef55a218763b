"""The matched test's kernels: each fault model's own response, as the
detector's Kalman observer would see it (bgc.diagnosis.detect, ``matched``).

A fault that grows slowly moves every sensor a little, in a pattern and a
time course its model fixes: R12's drift in the two tanks raises one flow's
residual and lowers another's, more each sample, and the Kalman observer
that does not know of it takes part of it into its states. The generalised
likelihood ratio of such a fault against no fault, its onset at the start of
a window and its size unknown, is the projection of the observer's whitened
innovations over the window on the fault's whitened response (Willsky and
Jones 1976, "A generalized likelihood ratio approach to the detection and
estimation of jumps in linear systems"; Basseville and Nikiforov 1993,
section 7.2): a matched filter. Over the W samples up to step k,

    S_k = sum_(m<W) g(m)' e_(k-W+1+m) / sqrt(sum_(m<W) |g(m)|^2),

``e`` the innovations whitened by the Cholesky factor of their predicted
covariance, ``g(m)`` the fault's response m samples after its onset (unit
size). Without a fault ``e`` is white N(0, I) and ``S_k`` is N(0, 1)
whatever ``g`` is, so the test holds its false-alarm rate whether or not the
kernel describes the plant well; how soon it sees a fault depends on that.

The responses come from the model, linearised along its noise-free nominal
run under its declared inputs (:mod:`bgc.model.linear`, as
:mod:`bgc.analysis.distinguish`'s unit responses, whitened by the same
Kalman filter), from an onset at
:data:`KERNEL_AT`, once the filter has settled: one time course per fault
model, the plant taken as at that operating point. A plant run at other
inputs keeps the test's level and loses some of its power.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np

from ..errors import BgcError
from ..kinds import fault_kind
from ..model.linear import linearised, scenario_inputs, typical_size, unit_responses
from ..model.protocol import Package, nominal_model, sized_models

#: The matched test's windows (samples): its onsets, a factor of 2 apart, before the newest sample.
MATCHED_WINDOWS = (8, 16, 32, 64, 128, 256)
#: The onset of the responses (a sample of the nominal run where its Kalman filter has settled).
KERNEL_AT = 64
#: A fault model whose response at its prior's typical size has a squared whitened norm over the longest
#: window below this gets no kernel: the sensors would not show it (a capacitance at steady state: a response
#: of rounding errors), and its kernels would spend the test's share.
SEEN = 1e-6


@dataclass(frozen=True, slots=True)
class Kernels:
    """The matched test's kernels: ``K`` (kernels, L, n_y), each a fault
    model's whitened response over a window, normalised, placed at the end
    (the window ends at the newest sample; zeros before it), L the longest
    window; per kernel its fault model (``fault``, an index into ``names``),
    its window (``window``) and its lag-one correlation on white innovations
    (``rho``); ``g`` (faults, L, n_y): each fault model's whitened response
    from its onset, unnormalised (the onset's search); ``raw`` (faults, L,
    n_y): its response in each sensor's own units of noise, not whitened
    (the sensor an alarm names: whitening mixes the sensors)."""

    names: tuple[str, ...]
    K: np.ndarray
    fault: np.ndarray
    window: np.ndarray
    rho: tuple[float, ...]
    g: np.ndarray
    raw: np.ndarray

    def sensor(self, index: int) -> int:
        """The sensor kernel ``index``'s fault model moves most over its
        window, in units of each sensor's noise."""
        w = int(self.window[index])
        part = self.raw[int(self.fault[index]), :w]
        return int(np.argmax((part * part).sum(axis=0)))

    @property
    def longest(self) -> int:
        return int(self.K.shape[1])


def kernels(package: Package, windows: tuple[int, ...] = MATCHED_WINDOWS) -> Kernels | None:
    """The package's kernels (:class:`Kernels`), one per fault model that
    moves a mean (not a noise fault, not a replaced reading; its response
    not negligible, :data:`SEEN`) and window; None when there is none, for
    a model with modes (its Kalman observer would not know the mode), or
    when the nominal run over the kernels' length (:data:`KERNEL_AT` and the
    longest window) is not finite."""
    return _kernels(package, tuple(int(w) for w in windows))


@functools.lru_cache(maxsize=4)
def _kernels(package: Package, windows: tuple[int, ...]) -> Kernels | None:
    try:
        return _made(package, windows)
    except BgcError:  # the nominal run over the kernels' length not finite, its covariance singular: no test
        return None


def _made(package: Package, windows: tuple[int, ...]) -> Kernels | None:
    nominal = nominal_model(package)
    if getattr(nominal, "MODE_INPUT", None) is not None:
        return None
    names = [name for name in sized_models(package)
             if not fault_kind(package.MODELS[name].FAULT["kind"]).noise
             and not fault_kind(package.MODELS[name].FAULT["kind"]).replaces]
    if not names:
        return None
    longest = max(windows)
    T = KERNEL_AT + longest
    us = scenario_inputs(package, T)
    with np.errstate(all="ignore"):
        x_before, x_after, _, F, H, whitening = linearised(package, us)
    n_y = H.shape[1]
    sigma = np.asarray(nominal.MEASUREMENT_STD, dtype=float)
    K, fault, window, rho, g, raw = [], [], [], [], [], []
    kept = []
    for name in names:
        with np.errstate(all="ignore"):
            G = unit_responses(package.MODELS[name], F, H, x_before, x_after, us, np.array([KERNEL_AT]))
            w = whitening.apply(G)[KERNEL_AT:, :, 0]  # (longest, n_y) from the onset
        low, high = (float(b) for b in package.MODELS[name].FAULT_PRIOR)
        if not np.isfinite(w).all() or not float((w * w).sum()) * typical_size(low, high) ** 2 > SEEN:
            continue  # nothing the sensors would show (a capacitance at steady state): a kernel of rounding
        i = len(kept)
        kept.append(name)
        g.append(w)
        raw.append(G[KERNEL_AT:, :, 0] / np.where(sigma > 0, sigma, 1.0))
        for width in windows:
            k = np.zeros((longest, n_y))
            k[longest - width:] = w[:width]
            norm = float((k * k).sum())
            if not norm > 0.0:
                continue
            K.append(k / math.sqrt(norm))
            fault.append(i)
            window.append(width)
            rho.append(float((k[1:] * k[:-1]).sum()) / norm)
    if not K:
        return None
    return Kernels(tuple(kept), np.array(K), np.array(fault), np.array(window), tuple(rho), np.array(g),
                   np.array(raw))
