"""The two tanks of models/two_tank.yaml simulated by hand, independently of
bgc's simulator: scipy's solve_ivp on the equations derived from the bond
graph (tank 1's 0-junction: C1 dp1/dt = f_in - p1/R10 - (p1 - p2)/R12; tank
2's: C2 dp2/dt = (p1 - p2)/R12 - p2/R20; the sensors F10 = p1/R10, F12 =
(p1 - p2)/R12, F20 = p2/R20), from the steady state of f_in = 1 (p1 = 20/9,
p2 = 4/3). The noise is the model file's as docs/format.md defines it: each
sensor's std 2 % of its initial reading; each pressure's process noise
kicked once per sample with std 3 % of its initial value times sqrt(2 dt /
tau), tau its own time constant (C over the sum of the conductances at its
node), so that its stationary spread is about 3 %."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from scipy.integrate import solve_ivp

C1, C2, R10, R12, R20 = 2.0, 1.5, 4.0, 2.0, 3.0
P0 = np.array([20.0 / 9.0, 4.0 / 3.0])


def readings(p: np.ndarray, r10: float, r12: float, r20: float) -> np.ndarray:
    return np.array([p[0] / r10, (p[0] - p[1]) / r12, p[1] / r20])


def run(seed: int, fault: tuple[str, float, float] | None = None, steps: int = 600, dt: float = 0.5,
        measurement: float = 0.02, process: float = 0.03, inflow: float = 1.0, start=None,
        t0: float = 0.0) -> list[tuple[float, float, float, float]]:
    """``steps`` samples (time, F10, F12, F20) of the plant, ``fault`` (the
    parameter, what it gains, from which time) stepping one of R10, R12, R20;
    ``inflow``: f_in; ``start``: the pressures at time ``t0`` (None: the
    steady state of f_in = 1; the noise's levels stay those of that state,
    as the model file's are)."""
    rng = np.random.default_rng(seed)
    y0 = readings(P0, R10, R12, R20)
    tau = np.array([C1 / (1 / R10 + 1 / R12), C2 / (1 / R12 + 1 / R20)])
    kick = process * P0 * np.sqrt(2 * dt / tau)

    def rhs(t, p, r10, r12, r20):
        q12 = (p[0] - p[1]) / r12
        return [(inflow - p[0] / r10 - q12) / C1, (q12 - p[1] / r20) / C2]

    p, t, rows = (P0 if start is None else np.asarray(start, dtype=float)).copy(), t0, []
    for k in range(1, steps + 1):
        values = {"R10": R10, "R12": R12, "R20": R20}
        if fault is not None and t >= fault[2] - 1e-9:  # over the step after the fault's time
            values[fault[0]] += fault[1]
        p = solve_ivp(rhs, (t, t + dt), p, args=(values["R10"], values["R12"], values["R20"]), rtol=1e-10,
                      atol=1e-12).y[:, -1] + kick * rng.standard_normal(2)
        t = t0 + k * dt
        y = readings(p, values["R10"], values["R12"], values["R20"]) + measurement * y0 * rng.standard_normal(3)
        rows.append((t, *y))
    return rows


def write(path: Path, rows, inflow=1.0) -> Path:
    """The rows as a run file of the model's columns (``inflow``: f_in, one
    value, or one per row)."""
    inflows = np.broadcast_to(np.asarray(inflow, dtype=float), (len(rows),))
    with open(path, "w", encoding="utf-8") as f:
        f.write("time,u:f_in,y:F10,y:F12,y:F20\n")
        for (t, a, b, c), u in zip(rows, inflows):
            f.write(f"{t:.12g},{u:g},{a:.9g},{b:.9g},{c:.9g}\n")
    return path
