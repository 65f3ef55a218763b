"""Shared test set-up: hypothesis profiles (``ci`` is derandomized)."""

import atexit
import os
import shutil
import tempfile
import tracemalloc
from functools import lru_cache
from pathlib import Path

import numpy as np
from hypothesis import HealthCheck, settings

settings.register_profile("ci", derandomize=True, max_examples=200, deadline=None,
                          suppress_health_check=[HealthCheck.too_slow])
settings.register_profile("dev", max_examples=100, deadline=None)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "dev"))
# The suite runs on the NumPy backend (a model the tests write afresh would be compiled by numba
# each time); tests/test_backend.py asks for numba by name, so does the seeded interval-coverage test
# of tests/test_diagnose.py when numba is installed (shipped models only), and a run may choose:
# BGC_BACKEND=numba make test.
os.environ.setdefault("BGC_BACKEND", "numpy")
# bgc's cache (models compiled once, numba's packages) in a folder of this test run, removed at its end,
# unless one is given (BGC_CACHE_DIR=~/.cache/bgc make test keeps it from run to run).
if not os.environ.get("BGC_CACHE_DIR"):
    os.environ["BGC_CACHE_DIR"] = tempfile.mkdtemp(prefix="bgc-test-cache-")
    atexit.register(shutil.rmtree, os.environ["BGC_CACHE_DIR"], True)

ROOT = Path(__file__).resolve().parent.parent
MODELS = ROOT / "models"
TEST_MODELS = ROOT / "tests" / "data" / "models"
#: Every model the stage tests run on: the shipped three and the test plants.
ALL_MODELS = {
    "circuit": MODELS / "circuit.yaml",
    "two_tank": MODELS / "two_tank.yaml",
    "ro": MODELS / "ro.yaml",
    "dc_motor": TEST_MODELS / "dc_motor.yaml",
    "resistor_loop": TEST_MODELS / "resistor_loop.yaml",
    "mass_spring_damper": TEST_MODELS / "mass_spring_damper.yaml",
    "orifice_tanks": TEST_MODELS / "orifice_tanks.yaml",
}


@lru_cache(maxsize=None)
def compiled(name: str):
    """Every IR of one of ALL_MODELS, compiled once per test session."""
    from bgc.pipeline import compile_model

    return compile_model(ALL_MODELS[name])


def tank_map(R12: float, dt: float = 0.5, R10: float = 4.0, R20: float = 3.0):
    """The two tanks' RK4 step (one substep of dt, as generated: SUBSTEPS = 1)
    derived by hand: C1 dP1/dt = f_in - P1/R10 - (P1 - P2)/R12, C2 dP2/dt =
    (P1 - P2)/R12 - P2/R20, i.e. dx/dt = A x + b, whose RK4 step is x' = M x + c
    with M = I + hA + (hA)^2/2 + (hA)^3/6 + (hA)^4/24 and c = h (I + hA/2 +
    (hA)^2/6 + (hA)^3/24) b. Measurements F10 = P1/R10, F12 = (P1 - P2)/R12,
    F20 = P2/R20."""
    C1, C2, f_in = 2.0, 1.5, 1.0
    A = np.array([[-1 / (C1 * R10) - 1 / (C1 * R12), 1 / (C1 * R12)],
                  [1 / (C2 * R12), -1 / (C2 * R12) - 1 / (C2 * R20)]])
    b = np.array([f_in / C1, 0.0])
    hA = dt * A
    I2 = np.eye(2)
    M = I2 + hA + hA @ hA / 2 + hA @ hA @ hA / 6 + hA @ hA @ hA @ hA / 24
    c = dt * (I2 + hA / 2 + hA @ hA / 6 + hA @ hA @ hA / 24) @ b
    H = np.array([[1 / R10, 0.0], [1 / R12, -1 / R12], [0.0, 1 / R20]])
    return M, c, H


def peak_memory(fn):
    """(fn(), the peak of the memory tracemalloc saw allocated while it ran)."""
    tracemalloc.start()
    try:
        return fn(), tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
