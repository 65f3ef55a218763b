"""Classical RK4 on one state vector, NumPy only: the nominal run that sets a
model's substeps (:mod:`bgc.compiler.numerics`) and the truth simulator
(:mod:`bgc.analysis.simulate`), which must not import sympy to use it."""

from __future__ import annotations

import numpy as np


def rk4_sample(rhs, x: np.ndarray, t0: float, h: float, substeps: int) -> np.ndarray:
    """x after ``substeps`` classical RK4 steps of length h from t0, one state
    vector; ``rhs(x, t, t_sub)`` is dx/dt at time t within the substep that
    starts at t_sub."""
    for s in range(substeps):
        t = t0 + s * h
        k1 = rhs(x, t, t)
        k2 = rhs(x + 0.5 * h * k1, t + 0.5 * h, t)
        k3 = rhs(x + 0.5 * h * k2, t + 0.5 * h, t)
        k4 = rhs(x + h * k3, t + h, t)
        x = x + (h / 6.0) * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
    return x
