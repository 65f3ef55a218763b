"""The variance test of the model's fit with and without its farthest
reading (``bgc.filters.residuals.failures``; issue 48: one glitch of a
reading on a healthy plant made the verdict "mismatch"), on draws made here.

Per stretch length n (samples of one sensor), 100,000 stretches of each:

- **null**: N(0, 1) draws, the model's own noise;
- **glitch**: the same with one reading 5 stds off (sign drawn);
- **x1.3, x1.5**: a noise 1.3 and 1.5 times the model's.

Each is tested as the diagnosis tests one sensor at the level it gives one
test (0.001 over 3 sensors and 2 tests: 0.001 / 6): ``plain``, the variance
alone against the chi-square's exact tail (n times it, n - 1 degrees of
freedom: ``variance_z``'s test; the mean test left out here), and ``now``,
the diagnosis's: that and the variance without the farthest reading against
its own expectation (``largest_square``). The rows: the share of stretches
each calls too wide. The claims: on the null, ``now`` at most the plain
test's share (both tests must fail: by construction) at every n; on the
glitch, ``now`` at most 1 % at every n; on a noise 1.5 times the model's,
``now`` at least 90 % of the plain test's power at n >= 60. (The plain
test's share on the null is the level, its tail being exact; before
2026-12-07 it was the normal approximation sqrt(2 / n), whose share on the
null was above the level at every n, the chi-square's skew left out.) Run::

    .venv/bin/python bench/variance_test.py
"""

from __future__ import annotations

import math
import sys

import _claims  # noqa: F401  (the suite's set-up, before NumPy loads)
import numpy as np

LENGTHS = (12, 30, 60, 120, 300)
DRAWS = 100_000
LEVEL = 0.001 / 6


def rejections(z: np.ndarray) -> tuple[float, float]:
    """(plain, now): the shares of the rows of ``z`` (stretches x n) each
    test calls wider than N(0, 1) at :data:`LEVEL` (one-sided, as the
    diagnosis's: only a variance above 1)."""
    from statistics import NormalDist

    from scipy.stats import chi2

    from bgc.filters.residuals import Innovations, _wider

    n = z.shape[1]
    cut = NormalDist().inv_cdf(1 - LEVEL / 2)  # the diagnosis's two-sided quantile, its variance side
    v = z.var(axis=1)
    far = np.abs(z - z.mean(axis=1, keepdims=True)).argmax(axis=1)
    keep = np.ones_like(z, dtype=bool)
    keep[np.arange(len(z)), far] = False
    rest = z[keep].reshape(len(z), n - 1).var(axis=1)
    plain = v > chi2.isf(LEVEL / 2, n - 1) / n  # the variance alone, by its exact tail
    # the diagnosis's own test on each stretch's two variances (the other fields play no part in it)
    now = [_wider(Innovations("y", n, 0.0, float(a), math.nan, 1, 1.0, float(b)), cut) for a, b in zip(v, rest)]
    return float(plain.mean()), float(np.mean(now))


def claim():
    rng = np.random.default_rng(2026)
    rows = [f"  {'n':>4} | {'null plain':>10} {'now':>8} | {'glitch plain':>12} {'now':>8} | "
            f"{'x1.3 plain':>10} {'now':>6} | {'x1.5 plain':>10} {'now':>6}"]
    checks = []
    for n in LENGTHS:
        null = rng.standard_normal((DRAWS, n))
        glitch = rng.standard_normal((DRAWS, n))
        glitch[:, n // 2] += 5.0 * rng.choice([-1.0, 1.0], DRAWS)
        shares = [rejections(null), rejections(glitch), rejections(1.3 * rng.standard_normal((DRAWS, n))),
                  rejections(1.5 * rng.standard_normal((DRAWS, n)))]
        rows.append(f"  {n:4d} | {shares[0][0]:10.5f} {shares[0][1]:8.5f} | {shares[1][0]:12.4f} {shares[1][1]:8.4f} | "
                    f"{shares[2][0]:10.3f} {shares[2][1]:6.3f} | {shares[3][0]:10.3f} {shares[3][1]:6.3f}")
        checks.append((f"n = {n}: null {shares[0][1]:.5f} <= plain {shares[0][0]:.5f}", shares[0][1] <= shares[0][0]))
        checks.append((f"n = {n}: one reading 5 stds off called too wide {shares[1][1]:.4f} <= 0.01",
                       shares[1][1] <= 0.01))
        if n >= 60:
            plain, now = shares[3]
            checks.append((f"n = {n}: noise x1.5 {now:.3f} >= 0.9 x plain {plain:.3f}", now >= 0.9 * plain))
    rows.append(f"  (the shares of {DRAWS} stretches per cell called too wide at the level {LEVEL:.2e})")
    return rows, checks


CLAIMS = {"variance": claim}

if __name__ == "__main__":
    sys.exit(_claims.run(CLAIMS, __doc__))
