"""Shared test set-up: hypothesis profiles (``ci`` is derandomized)."""

import os
from functools import lru_cache
from pathlib import Path

from hypothesis import HealthCheck, settings

settings.register_profile("ci", derandomize=True, max_examples=200, deadline=None,
                          suppress_health_check=[HealthCheck.too_slow])
settings.register_profile("dev", max_examples=100, deadline=None)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "dev"))

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
