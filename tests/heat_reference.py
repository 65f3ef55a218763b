"""The two-body thermal plant of tests/data/heat_two_body.yaml, simulated by
scipy's solve_ivp from its equations written out by hand (not by bgc
simulate), for tests/test_stretch_misfit.py and bench/stretch_misfit.py:

    C1 dT1/dt = Q - (T1 - T2)/R12 - (T1 - Ta)/R1a - G (T1 - Ta) [a loss outside the model, from its onset],
    C2 dT2/dt = (T1 - T2)/R12 - (T2 - Ta)/R2a,
    T1, T2 and q_out = (T2 - Ta)/R2a read,

the disturbance heat flows held over each sample, sized so that the states
move by the model's process std per sample; the sensors' noise the model's.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from scipy.integrate import solve_ivp

from bgc.data import runs
from bgc.model.protocol import nominal_model

from conftest import session

MODEL = Path(__file__).parent / "data" / "heat_two_body.yaml"
PLANT = {"C1": 500.0, "C2": 1000.0, "R12": 0.05, "R1a": 0.5, "R2a": 0.1}
Q, TA, DT = 500.0, 20.0, 1.0
OUTPUTS = ("T1", "T2", "q_out")


def heated(leak: float, bias: float, onset: float, steps: int, seed: int, stuck: float | None = None) -> runs.Run:
    """The readings of the plant above: from ``onset`` a heat loss of the
    block of ``leak`` W/K, T1 reading ``bias`` off, and T2 reading ``stuck``
    exactly (None: T2 reads); the model's process and measurement noise,
    drawn from ``default_rng(seed)``."""
    nominal = nominal_model(session(MODEL).package)
    process, measurement = np.asarray(nominal.PROCESS_STD)[:2], np.asarray(nominal.MEASUREMENT_STD)
    rng = np.random.default_rng(seed)
    p = PLANT
    heat_std = process * np.array([p["C1"], p["C2"]]) / DT  # a flow held over a sample moves a state by it

    def flow(t, x, w):
        q12 = (x[0] - x[1]) / p["R12"]
        loss = leak * (x[0] - TA) if t >= onset else 0.0
        return [(Q - q12 - (x[0] - TA) / p["R1a"] - loss + w[0]) / p["C1"],
                (q12 - (x[1] - TA) / p["R2a"] + w[1]) / p["C2"]]

    # the steady state: T1 (1/R12 + 1/R1a) - T2/R12 = Q + Ta/R1a, -T1/R12 + T2 (1/R12 + 1/R2a) = Ta/R2a
    g12, g1, g2 = 1 / p["R12"], 1 / p["R1a"], 1 / p["R2a"]
    x = np.linalg.solve([[g12 + g1, -g12], [-g12, g12 + g2]], [Q + g1 * TA, g2 * TA])
    time = DT * np.arange(1, steps + 1)
    y = []
    for t in time:
        w = heat_std * rng.standard_normal(2)
        x = solve_ivp(flow, (t - DT, t), x, args=(w,), rtol=1e-10, atol=1e-10).y[:, -1]
        y.append([x[0] + (bias if t >= onset else 0.0), x[1], (x[1] - TA) / p["R2a"]])
    y = np.array(y) + measurement * rng.standard_normal((steps, 3))
    if stuck is not None:
        y[time >= onset, 1] = stuck
    ones = np.ones(steps)
    return runs.Run(time, {"Q": Q * ones, "Ta": TA * ones}, dict(zip(OUTPUTS, y.T)), {}, {},
                    ("made by tests/test_stretch_misfit.py",), "heated.csv")
