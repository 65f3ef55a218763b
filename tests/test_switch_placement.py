"""Where within a sample period a change of mode the data give is placed
(the generated model's ``_fraction``), checked against closed forms.

The plant crossed its guard somewhere in the step that ended at the sample
whose row says the new mode. A particle's own margin places the crossing
when the guard's threshold is exact and the particle crosses within the
step (a particle whose margin reaches the threshold at neither end is behind
the plant: the step's middle). With an uncertain threshold T ~ N(0, s^2) the
data's switch says T lies on the particle's margin path, and the crossing
fraction has T's distribution on the path: with margins m0 and m1 at the
step's ends (linear in between),

    P(f <= phi) = (Q(m0/s) - Q((m0 + phi (m1 - m0))/s)) / (Q(m0/s) - Q(m1/s)),

Q the standard normal's upper tail; a margin that already holds at the
start by the nominal threshold does not put the switch at the start.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy.special import ndtr

from bgc.model.package import load_package

from conftest import bgc_cli

ROOT = Path(__file__).resolve().parent.parent
RELAY = ROOT / "tests" / "data" / "hybrid" / "relay_rl.yaml"
#: The std of the closing guard's threshold in the variant with a tolerance.
S = 0.5


def _module(folder: Path, name: str):
    nominal = load_package(folder, name).MODELS["nominal"]
    return __import__(nominal.__name__, fromlist=["_fraction"])


@pytest.fixture(scope="module")
def relays(tmp_path_factory):
    """The relay as shipped (its guards exact) and a copy whose closing guard's threshold has std S."""
    out = tmp_path_factory.mktemp("placement")
    text = RELAY.read_text()
    exact_guard = '{from: open, to: closed, when: "v_C > 6"}'
    assert exact_guard in text
    tolerant = out / "relay_tol.yaml"
    tolerant.write_text(text.replace("name: relay_rl", "name: relay_tol").replace(
        exact_guard, f'{{from: open, to: closed, when: "v_C > 6", tolerance: {S}}}'))
    for model in (RELAY, tolerant):
        done = bgc_cli("compile", model, "-o", out, "--no-pictures")
        assert done.returncode == 0, done.stderr
    return _module(out, "relay_rl"), _module(out, "relay_tol")


def _ends(module, v_start: np.ndarray, v_end: np.ndarray, draws: np.ndarray | None = None):
    """States of particles in the open relay at a step's start and end with capacitor voltages
    ``v_start`` and ``v_end`` (the guard's margins: v - 6), their uniform draws ``draws``."""
    n = len(v_start)
    a = np.zeros((len(module.STATES), n))
    a[module.STATES.index("e6")] = v_start
    a[module.MODE_ROW] = 1.0
    b = a.copy()
    b[module.STATES.index("e6")] = v_end
    if draws is not None:
        a[module._THRESHOLD_ROWS[0]] = draws
    return a, b


def _closing(module) -> int:
    return next(k for k, t in enumerate(module._TRANSITIONS) if t[0] == 1 and t[1] == 2)


def test_an_exact_guard_places_a_crossing_by_the_margin(relays):
    exact, _ = relays
    k, n = _closing(exact), 4000
    theta, v = exact.THETA, np.array([8.0])
    # crossing within the step: where the margin's linear path reaches 0
    a, b = _ends(exact, np.full(n, 5.8), np.full(n, 6.3))
    assert exact._fraction(a, b, k, v, theta, 0.01) == pytest.approx(np.full(n, 0.2 / 0.5))
    # the guard held at the start (the last sample's noise carried the particle across): at the start
    a, b = _ends(exact, np.full(n, 6.1), np.full(n, 6.4))
    assert (exact._fraction(a, b, k, v, theta, 0.01) == 0.0).all()
    # behind the plant (the margin under 0 at both ends): the step's middle
    a, b = _ends(exact, np.full(n, 5.0), np.full(n, 5.5))
    assert (exact._fraction(a, b, k, v, theta, 0.01) == 0.5).all()


def test_a_particles_placement_is_its_own_whatever_its_column(relays):
    """A Kalman filter's points are columns too, and the points of many
    cells step as one array: a point's placement must not depend on where
    in the array it stands. With the draw the model's initial value gives
    (0.5, as a Kalman filter's points keep it) the placement is the median
    of the threshold's distribution on the path."""
    _, tol = relays
    k = _closing(tol)
    v0 = np.array([5.9, 6.1, 5.95, 5.9, 6.1, 5.95])
    v1 = v0 + 0.3
    a, b = _ends(tol, v0, v1, np.full(6, 0.5))
    f = tol._fraction(a, b, k, np.array([8.0]), tol.THETA, 0.01)
    assert f[:3] == pytest.approx(f[3:], abs=0.0)
    a1, b1 = _ends(tol, v0[:1], v1[:1], np.full(1, 0.5))
    assert tol._fraction(a1, b1, k, np.array([8.0]), tol.THETA, 0.01)[0] == f[0]
    for m0, m1, phi in zip(v0[:3] - 6.0, v1[:3] - 6.0, f[:3]):
        assert _cdf(np.array([phi]), m0, m1)[0] == pytest.approx(0.5, abs=0.01)


def _cdf(phi: np.ndarray, m0: float, m1: float) -> np.ndarray:
    """The closed form of the module docstring."""
    q = lambda m: 1.0 - ndtr(m / S)  # noqa: E731
    return (q(m0) - q(m0 + phi * (m1 - m0))) / (q(m0) - q(m1))


@pytest.mark.parametrize("v0, v1", [(5.9, 6.05), (6.1, 6.4), (5.2, 6.8), (6.6, 7.1)])
def test_an_uncertain_threshold_places_the_crossing_by_its_density_on_the_margin_path(relays, v0, v1):
    """Margins rising through, beyond, across and far beyond the nominal threshold (0.2 to 1.3
    threshold stds): the fractions' distribution is the closed form's, to the piecewise-linear
    inverse's resolution and the sample's."""
    _, tol = relays
    k, n = _closing(tol), 20000
    draws = np.random.default_rng(46).random(n)
    a, b = _ends(tol, np.full(n, v0), np.full(n, v1), draws)
    f = np.sort(tol._fraction(a, b, k, np.array([8.0]), tol.THETA, 0.01))
    assert f.min() >= 0.0 and f.max() <= 1.0
    empirical = np.arange(1, n + 1) / n
    gap = np.max(np.abs(empirical - _cdf(f, v0 - 6.0, v1 - 6.0)))
    assert gap < 0.02, gap
    # the margin held at the start by the nominal threshold: the switch is still spread over the step
    if v0 > 6.0:
        assert np.mean(f == 0.0) < 0.01 and np.median(f) > 0.3


def test_a_falling_margin_with_an_uncertain_threshold_places_the_crossing_anywhere(relays):
    _, tol = relays
    k, n = _closing(tol), 8000
    draws = np.random.default_rng(7).random(n)
    a, b = _ends(tol, np.full(n, 6.2), np.full(n, 6.0), draws)
    f = tol._fraction(a, b, k, np.array([8.0]), tol.THETA, 0.01)
    assert f.mean() == pytest.approx(0.5, abs=0.02) and f.var() == pytest.approx(1 / 12, rel=0.05)
