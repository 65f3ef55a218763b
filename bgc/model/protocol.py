"""What the runtime reads of a generated model, and the conventions of its fault."""

from __future__ import annotations

from types import ModuleType

import numpy as np


def onset_transition(model: ModuleType, x: np.ndarray, u: np.ndarray, theta) -> np.ndarray:
    """The noise-free transition into a fault's onset sample, in place on a
    fault model's particles ``x``: the dynamics that lead to the sample are
    nominal, the sample sees the fault. A fault with onset k changes the
    parameter at the instant of sample k: as in the thesis's DBN (the
    parameter of time slice k enters y_k and the transition out of slice k)
    and in the simulator, y_k sees the new value and the states move from
    step k on. So the magnitude state (the last: a bias, or a drift's slope)
    is held at zero for this one transition, then restored; a drifting
    parameter's own state stays at its nominal value. The filter's step then
    adds the process noise and weighs the particles with the fault in
    (``step(y, u, predicted=True)``)."""
    row = len(model.STATES) - 1
    magnitude = x[row].copy()
    x[row] = 0.0
    model.predict(x, u, theta, model.DT, out=x)
    x[row] = magnitude
    return x
