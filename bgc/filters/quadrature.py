"""The integral of a likelihood over a row of magnitudes (the static
posterior's quadrature, :mod:`bgc.diagnosis.static_posterior`): the log
density interpolated by parabolas between the row's points, integrated by
Gauss-Legendre panels. The compiled kernel has the same rule
(``numba_kernel.row_quadrature``)."""

from __future__ import annotations

import math

import numpy as np

#: Gauss-Legendre nodes and weights on [0, 1], for each interval of a row
_GL_NODES, _GL_WEIGHTS = np.polynomial.legendre.leggauss(8)
_GL_NODES, _GL_WEIGHTS = (_GL_NODES + 1.0) / 2.0, _GL_WEIGHTS / 2.0


#: exp of a log mass above this is taken relative to the largest (exp overflows past 709)
_SAFE_EXP = 300.0


def overflow_shift(peak: float) -> float:
    """What to subtract from log masses whose largest is ``peak`` before exp:
    0, unless ``peak`` exceeds ``_SAFE_EXP``."""
    return peak if peak > _SAFE_EXP else 0.0


#: the most the log density may change over one Gauss-Legendre panel (8 nodes
#: integrate exp(-8 t) on [0, 1] to about 1e-10); a steeper interval is split
_PANEL_RANGE = 8.0


#: the most Gauss-Legendre panels an interval is split into
_MOST_PANELS = 256


#: How many times an interval's own change of log density (plus 1) a neighbour may lie below it and
#: still shape the interval's parabola (:func:`row_quadrature`)
_WILD = 1e6


def row_quadrature(values: np.ndarray, logd: np.ndarray, kernel=None) -> tuple[np.ndarray, np.ndarray]:
    """Quadrature nodes and the log of their masses for a density known by
    its log ``logd`` at the evenly spaced points ``values`` (-inf: outside
    the prior).

    Between two points the log density is the mean of the parabolas through
    the three points on either side (one of them at an end of the row; the
    line between the two when neither exists), integrated by Gauss-Legendre
    panels, an interval split into as many as keep the log density's range
    on each under ``_PANEL_RANGE``. The rule is exact for a Gaussian at any
    spacing, cut off by a bound of the prior or not, and for an exponential
    tail (the trapezoid rule, exact for a smooth density that vanishes at
    both ends, is off by a factor of about half the log density's fall over
    one interval where a bound cuts a steep density off); a peak that lies
    between two points is found. An interval with an end outside the prior
    holds no mass. A row of one point (or of zero width) is a point mass.
    ``kernel``: a generated package's kernel; a compiled one's
    ``row_quadrature`` does the same arithmetic in one call.

    >>> x, logm = row_quadrature(np.linspace(-4.0, 4.0, 9), -np.linspace(-4.0, 4.0, 9) ** 2 / 2)
    >>> round(float(np.exp(logm).sum()), 6) == round(math.sqrt(2 * math.pi) * math.erf(4 / math.sqrt(2)), 6)
    True
    """
    v = np.asarray(values, dtype=float)
    lg = np.asarray(logd, dtype=float)
    if len(v) < 2 or not v[-1] > v[0]:
        return v[:1].copy(), lg[:1].copy()
    if hasattr(kernel, "row_quadrature"):
        return kernel.row_quadrature(v, lg, _GL_NODES, _GL_WEIGHTS, _PANEL_RANGE, _MOST_PANELS, _WILD)
    h = (v[-1] - v[0]) / (len(v) - 1)
    l0, l1 = lg[:-1, None], lg[1:, None]
    lm = np.concatenate([[-math.inf], lg[:-2]])[:, None]  # the point before each interval
    lp = np.concatenate([lg[2:], [-math.inf]])[:, None]  # the point after it

    def interpolant(t: np.ndarray) -> np.ndarray:
        with np.errstate(invalid="ignore"):
            left = l0 + (l1 - lm) / 2.0 * t + (l1 - 2.0 * l0 + lm) / 2.0 * t * t
            right = l0 + (l1 - l0) * t + (lp - 2.0 * l1 + l0) / 2.0 * (t * t - t)
            line = l0 + (l1 - l0) * t
            # a neighbour that lies below the interval by over _WILD times the interval's own change (a
            # grid cell whose model diverged: -2e18 beside -4e3) shapes no parabola: through it the
            # parabola would bend far above the interval's points
            own = _WILD * (np.abs(l1 - l0) + 1.0)
            has_left, has_right = np.isfinite(lm) & ~(l0 - lm > own), np.isfinite(lp) & ~(l1 - lp > own)
            out = np.where(has_left & has_right, (left + right) / 2.0,
                           np.where(has_left, left, np.where(has_right, right, line)))
        return np.where(np.isfinite(l0) & np.isfinite(l1), out, -math.inf)

    probe = interpolant(np.linspace(0.0, 1.0, 9)[None, :])
    ok = np.isfinite(probe).all(axis=1)
    spread = float(np.max(np.ptp(probe[ok], axis=1))) if ok.any() else 0.0
    panels = int(min(max(math.ceil(spread / _PANEL_RANGE), 1), _MOST_PANELS))
    t = ((np.arange(panels)[:, None] + _GL_NODES[None, :]) / panels).ravel()[None, :]
    w = np.tile(_GL_WEIGHTS / panels, panels)[None, :]
    with np.errstate(divide="ignore"):
        logm = interpolant(t) + np.log(w * h)
    return (v[:-1, None] + h * t).ravel(), logm.ravel()
