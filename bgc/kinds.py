"""Element kinds and fault kinds, declared once (a registry read everywhere).

Every module that needs to know what an element kind is (how many ports it has,
which keys a model file may give it, what it imposes on its bond) or how a fault
kind enters the model (which states it adds, its prior, how the simulator
injects it) reads it from :data:`ELEMENT_KINDS` and :data:`FAULT_KINDS`. A new
kind is one entry here (as BondGraphTools keeps its components in
``components/base.json``).

Examples
--------
>>> element_kind("MSe").imposes, element_kind("C").state_variable
('effort', 'e')
>>> fault_kind("incipient").value(10.0, 0.5, onset=100.0, t=110.0)
15.0
>>> fault_kind("abrupt").prior_bounds("increase", 69.0, horizon=300.0)
(0.0, 69.0)
>>> fault_kind("incipient").truth([0.0, 1.0, 2.0], [10.0, 10.5, 11.0], 10.0)  # the last step's slope
0.5
>>> fault_kind("abrupt").truth([0.0, 1.0, 2.0], [10.0, 10.5, 11.0], 10.0) is None  # still moving: no step
True
>>> fault_kind("incipient").change(0.5, 4.0), fault_kind("incipient").magnitude_for(2.0, 4.0)
(2.0, 0.5)
>>> element_kind("Q")
Traceback (most recent call last):
...
KeyError: "unknown element kind 'Q' (valid: 0, 1, C, GY, I, MGY, MR, MSe, MSf, MTF, R, Se, Sf, TF)"
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Mapping

# ------------------------------------------------------------------ elements
ROLES = ("source", "resistor", "storage", "two_port", "junction")


@dataclass(frozen=True, slots=True)
class ElementKind:
    """What an element kind is.

    ``ports``: bonds it takes (None: a junction, two or more). ``keys``: what a
    model file may give it beyond ``kind`` and ``description``. ``imposes``: for
    a source, what it always imposes on its bond; for a storage element, what it
    imposes in integral causality (its state is then that variable: C the
    effort, I the flow). ``common``: the variable a junction's bonds share
    (0: effort, 1: flow). ``two_port``: ``transformer`` (passes causality
    through) or ``gyrator`` (swaps it). ``modulated``: its parameter or value
    may depend on bond variables (signal links); ``base`` is the kind without
    the modulation.
    """

    name: str
    role: str
    title: str
    ports: int | None
    keys: frozenset[str]
    base: str
    modulated: bool = False
    imposes: str | None = None
    common: str | None = None
    two_port: str | None = None

    @property
    def state_variable(self) -> str | None:
        """``e`` or ``f``: the co-energy variable a storage element integrates."""
        if self.role != "storage":
            return None
        return "e" if self.imposes == "effort" else "f"


def _kinds(*kinds: ElementKind) -> Mapping[str, ElementKind]:
    out: dict[str, ElementKind] = {}
    for k in kinds:
        out[k.name] = k
        if k.role in ("source", "resistor", "two_port"):  # the modulated form: same kind, signal links
            out["M" + k.name] = ElementKind("M" + k.name, k.role, "modulated " + k.title, k.ports, k.keys,
                                            k.name, True, k.imposes, k.common, k.two_port)
    return dict(sorted(out.items()))


ELEMENT_KINDS: Mapping[str, ElementKind] = _kinds(
    ElementKind("Se", "source", "effort source", 1, frozenset({"value"}), "Se", imposes="effort"),
    ElementKind("Sf", "source", "flow source", 1, frozenset({"value"}), "Sf", imposes="flow"),
    ElementKind("R", "resistor", "resistor", 1, frozenset({"parameter", "law"}), "R"),
    ElementKind("C", "storage", "capacitor", 1, frozenset({"parameter", "initial", "noise"}), "C",
                imposes="effort"),
    ElementKind("I", "storage", "inertia", 1, frozenset({"parameter", "initial", "noise"}), "I", imposes="flow"),
    ElementKind("TF", "two_port", "transformer", 2, frozenset({"parameter"}), "TF", two_port="transformer"),
    ElementKind("GY", "two_port", "gyrator", 2, frozenset({"parameter"}), "GY", two_port="gyrator"),
    ElementKind("0", "junction", "0-junction", None, frozenset(), "0", common="effort"),
    ElementKind("1", "junction", "1-junction", None, frozenset(), "1", common="flow"),
)


def element_kind(name: str) -> ElementKind:
    """The registry entry of an element kind; KeyError lists the valid kinds."""
    try:
        return ELEMENT_KINDS[name]
    except KeyError:
        raise KeyError(f"unknown element kind '{name}' (valid: {', '.join(ELEMENT_KINDS)})") from None


# -------------------------------------------------------------------- faults
#: Directions a fault candidate may take, and the signs of change they allow.
DIRECTIONS: Mapping[str, tuple[int, ...]] = {"increase": (1,), "decrease": (-1,), "both": (1, -1)}


@dataclass(frozen=True, slots=True)
class FaultKind:
    """How a fault kind enters the model, its prior and its injection.

    Declared here once, and read by the simulator, the filters, the
    estimates, the plots and the campaigns: the magnitude and its prior, how
    the parameter changes from the onset (:meth:`value`, :meth:`change`; the
    onset sample sees the fault, the transition into it is nominal), and how
    the truth is read from a run (:meth:`truth`, :meth:`truth_series`).

    ``magnitude`` names the fault state ``delta_P`` estimates: a ``bias`` b
    (abrupt, thesis eq. II.1: ``P(t) = P + b`` from the onset) or a ``slope`` c
    per unit time (incipient, eq. II.2: ``P(t) = P + c (t - t_f)``). With
    ``drifts`` the parameter itself becomes a state that drifts at the slope
    (``P(t+dt) = P(t) + c dt``); otherwise ``P`` is replaced by ``P + b``.

    ``prior``: per direction, the bounds of the uniform prior of the magnitude
    in units of |P| (a bias) or of |P| / horizon (a slope, so that the change
    over the horizon stays in those bounds). ``jitter``: the per-step
    random-walk std of the magnitude state that keeps the particle cloud from
    collapsing, as a fraction of ``jitter_scale`` (``parameter``: |P|;
    ``prior``: the prior's width).
    """

    name: str
    magnitude: str
    drifts: bool
    prior: Mapping[str, tuple[float, float]]
    jitter: float
    jitter_scale: str
    description: str

    def value(self, nominal: float, magnitude: float, onset: float, t: float) -> float:
        """The faulty parameter at time t (a step at the onset, or a ramp from it)."""
        if self.drifts:
            return nominal + magnitude * (t - onset) if t > onset else nominal
        return nominal + magnitude if t >= onset else nominal

    def change(self, magnitude, span):
        """The parameter's change a magnitude makes over ``span`` time units
        after the onset: a bias its own, a slope times the span (arrays
        broadcast)."""
        return magnitude * span if self.drifts else magnitude

    def magnitude_for(self, change: float, span: float) -> float:
        """The magnitude that changes the parameter by ``change`` over ``span``
        time units after the onset (the inverse of :meth:`change`)."""
        return change / span if self.drifts else change

    def truth(self, time, recorded, nominal: float) -> float | None:
        """The true magnitude from a run's recorded parameter (``recorded``
        at ``time``): a bias, the last value less the nominal; a slope, the
        last step's change per unit time. None when the recorded parameter is
        not of this kind (one still moving at the end drifts, one that stopped
        stepped) or too short to tell."""
        if recorded is None or len(recorded) < 2 or bool(recorded[-1] != recorded[-2]) != self.drifts:
            return None
        if self.drifts:
            return float((recorded[-1] - recorded[-2]) / (time[-1] - time[-2]))
        return float(recorded[-1] - nominal)

    def truth_series(self, time, recorded, nominal: float):
        """The true magnitude at each sample, as the estimate's plot draws it:
        a bias, the parameter less its nominal; a slope, its rate of change."""
        import numpy as np

        return np.gradient(recorded, time) if self.drifts else recorded - nominal

    def prior_bounds(self, direction: str, nominal: float, horizon: float) -> tuple[float, float]:
        """(low, high) of the uniform prior of the magnitude."""
        lo, hi = self.prior[direction]
        scale = abs(nominal) or 1.0
        if self.drifts:
            scale /= horizon
        return lo * scale, hi * scale

    def jitter_std(self, nominal: float, bounds: tuple[float, float]) -> float:
        """Per-step random-walk std of the magnitude state."""
        base = (abs(nominal) or 1.0) if self.jitter_scale == "parameter" else bounds[1] - bounds[0]
        return self.jitter * base


FAULT_KINDS: Mapping[str, FaultKind] = {
    "abrupt": FaultKind(
        "abrupt", "bias", False,
        {"increase": (0.0, 1.0), "decrease": (-0.5, 0.0), "both": (-0.5, 1.0)},
        0.004, "parameter", "a step change P + b from the onset (thesis eq. II.1)"),
    "incipient": FaultKind(
        "incipient", "slope", True,
        # slopes that change the parameter by up to +400 % or -80 % over the horizon
        # (a decreasing parameter stays positive)
        {"increase": (0.0, 4.0), "decrease": (-0.8, 0.0), "both": (-0.8, 4.0)},
        0.01, "prior", "a drift P + c (t - t_f) from the onset (thesis eq. II.2)"),
}


def fault_kind(name: str) -> FaultKind:
    """The registry entry of a fault kind; KeyError lists the valid kinds."""
    try:
        return FAULT_KINDS[name]
    except KeyError:
        raise KeyError(f"unknown fault kind '{name}' (valid: {', '.join(FAULT_KINDS)})") from None
