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
>>> fault_kind("incipient").prior_bounds("decrease", 10.0, horizon=100.0, widen=2.0)  # stays above -95 %
(-0.095, 0.0)
>>> fault_kind("bias").prior_bounds("both", 2.0, horizon=100.0, declared=(-0.1, 0.3))
(-0.2, 0.6)
>>> fault_kind("drift").parameter_of("P_memb"), fault_kind("gain").parameter_of("V")
('P_memb_offset', 'V_gain')
>>> fault_kind("incipient").truth([0.0, 1.0, 2.0], [10.0, 10.5, 11.0], 10.0)  # the last step's slope
0.5
>>> fault_kind("abrupt").truth([0.0, 1.0, 2.0], [10.0, 10.5, 11.0], 10.0) is None  # still moving: no step
True
>>> fault_kind("incipient").change(0.5, 4.0), fault_kind("incipient").magnitude_for(2.0, 4.0)
(2.0, 0.5)
>>> noise = fault_kind("noise")
>>> noise.parameter_of("F12"), noise.noise_factor(4.0), noise.noise_factor(-1.0)  # five times; floored
('F12_noise', 5.0, 0.001)
>>> noise.prior_bounds("increase", 1.0, horizon=100.0), noise.prior_bounds("decrease", 1.0, 100.0, widen=2.0)
((0.0, 9.0), (-0.95, 0.0))
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
    ElementKind("C", "storage", "capacitor", 1, frozenset({"parameter", "initial", "noise", "quantity"}), "C",
                imposes="effort"),
    ElementKind("I", "storage", "inertia", 1, frozenset({"parameter", "initial", "noise", "quantity"}), "I",
                imposes="flow"),
    ElementKind("TF", "two_port", "transformer", 2, frozenset({"parameter"}), "TF", two_port="transformer"),
    ElementKind("GY", "two_port", "gyrator", 2, frozenset({"parameter"}), "GY", two_port="gyrator"),
    ElementKind("0", "junction", "0-junction", None, frozenset({"switch"}), "0", common="effort"),
    ElementKind("1", "junction", "1-junction", None, frozenset({"switch"}), "1", common="flow"),
)


def element_kind(name: str) -> ElementKind:
    """The registry entry of an element kind; KeyError lists the valid kinds."""
    try:
        return ELEMENT_KINDS[name]
    except KeyError:
        raise KeyError(f"unknown element kind '{name}' (valid: {', '.join(ELEMENT_KINDS)})") from None


# ------------------------------------------------------------------- domains
@dataclass(frozen=True, slots=True)
class Domain:
    """A physical domain a model may declare (``domain:``): what its efforts
    and flows are, so that a state reads as the quantity it is (a C's
    effort: a pressure in a hydraulic model, a voltage in an electrical
    one; an I's flow: a volume flow, a current)."""

    name: str
    effort: str
    flow: str


#: The domains a model may declare; without one, an effort is an "effort" and a flow a "flow".
DOMAINS: Mapping[str, Domain] = {d.name: d for d in (
    Domain("electrical", "voltage", "current"),
    Domain("hydraulic", "pressure", "volume flow"),
    Domain("rotational", "torque", "angular velocity"),
    Domain("thermal", "temperature", "entropy flow"),
    Domain("translational", "force", "velocity"),
)}
#: The effort and flow of a model that declares no domain.
GENERIC = Domain("generic", "effort", "flow")


# -------------------------------------------------------------------- faults
#: Directions a fault candidate may take, and the signs of change they allow.
DIRECTIONS: Mapping[str, tuple[int, ...]] = {"increase": (1,), "decrease": (-1,), "both": (1, -1)}


#: The lowest a parameter's prior may take it, as a fraction of its nominal below it: a widened
#: prior (``--prior-scale``, the YAML's ``size``) keeps a decreasing parameter positive.
LOWEST = -0.95

#: The smallest factor a noise fault multiplies its sensor's noise std by (a magnitude
#: of -1 or below would leave the sensor without noise, or with a negative std).
NOISE_FLOOR = 1e-3


@dataclass(frozen=True, slots=True)
class FaultKind:
    """How a fault kind enters the model, its prior and its injection.

    Declared here once, and read by the validator, the equations, the
    simulator, the filters, the estimates, the plots and the campaigns: what
    it may strike (``targets``), the magnitude and its prior, how the faulty
    quantity changes from the onset (:meth:`value`, :meth:`change`; the
    onset sample sees the fault, the transition into it is nominal), and how
    the truth is read from a run (:meth:`truth`, :meth:`truth_series`).

    A fault is always a change of one symbol of the equations, the fault's
    *parameter*: a model parameter itself (``abrupt``, ``incipient``), or one
    the compiler adds for a sensor or an actuator fault (``suffix``): a
    sensor's offset ``<sensor>_offset`` (nominal 0) added to its reading; an
    input's offset ``<input>_offset`` (nominal 0) added to what the actuator
    delivers, or its gain ``<input>_gain`` (nominal 1) multiplying it. The
    recorded input stays the command; the plant sees ``gain * u + offset``.
    A sensor's noise factor ``<sensor>_noise`` (nominal 1) multiplies the
    std of its measurement noise and enters no equation (``noise``).

    ``magnitude`` names the fault state ``delta_P`` estimates: a ``bias`` b
    (a step, thesis eq. II.1: ``P(t) = P + b`` from the onset) or a ``slope``
    c per unit time (a drift, eq. II.2: ``P(t) = P + c (t - t_f)``). With
    ``drifts`` the parameter itself becomes a state that drifts at the slope
    (``P(t+dt) = P(t) + c dt``); otherwise ``P`` is replaced by ``P + b``.

    ``prior``: per direction, the default bounds of the uniform prior of the
    magnitude, in units of the fault's *scale* (a parameter's |nominal|, a
    sensor's nominal reading, an input's nominal value, 1 for a gain), and
    for a drift per monitoring horizon (so that the change over the horizon
    stays in those bounds). A model may declare its own bounds (``size`` for
    a step, ``rate`` per unit time for a drift: :meth:`prior_bounds`).
    ``jitter``: the per-step random-walk std of the magnitude state that
    keeps the particle cloud from collapsing, as a fraction of
    ``jitter_scale`` (``parameter``: the scale; ``prior``: the prior's width).
    """

    name: str
    magnitude: str
    drifts: bool
    prior: Mapping[str, tuple[float, float]]
    jitter: float
    jitter_scale: str
    description: str
    targets: tuple[str, ...] = ("parameter",)
    suffix: str | None = None
    nominal: float = 0.0
    #: The fault's parameter replaces the sensor's reading instead of adding to it (a stuck
    #: sensor reads its value, whatever the plant does); its prior is centred on the nominal reading.
    replaces: bool = False
    #: The fault's parameter multiplies the sensor's measurement-noise std (the thesis's
    #: measurement node M_i, whose variance grows when its fault node E_i is true, section
    #: III.3): it enters no equation and moves no mean. Its fault model's ``measurement_std``
    #: is ``noise_factor`` times the sensor's; its DBN's fault node is the parent of the
    #: measurement alone; its signature is '?' at every order on its sensor.
    noise: bool = False

    @property
    def discrete(self) -> bool:
        """A fault with no size (a switch that sticks): its magnitude state is
        a flag, 0 before the onset and 1 from it, its prior the one point 1;
        a hypothesis of it is weighed over its onsets alone."""
        return self.magnitude == "switch"

    @property
    def searched_back(self) -> bool:
        """Its onset is looked for far back from the alarm, on a drift's
        grid of onsets, not only around the detector's change point, which
        does not mark it: a drift grows from nothing, and a burst of noise
        moves no mean (the detector, a test of the residuals' mean, sees it
        late)."""
        return self.drifts or self.noise

    @property
    def factor(self) -> bool:
        """The fault's parameter is a factor (nominal 1: a gain, a noise
        std's multiplier): its magnitude has no unit and is written in units
        of 1, whatever the size of what it multiplies."""
        return self.nominal == 1.0

    def noise_factor(self, magnitude):
        """What a noise fault of this magnitude multiplies its sensor's
        noise std by: |1 + b|, never under NOISE_FLOOR (a sensor without
        noise would make any residual infinitely unlikely); arrays
        broadcast."""
        import numpy as np

        factor = np.maximum(np.abs(self.nominal + np.asarray(magnitude, dtype=float)), NOISE_FLOOR)
        return float(factor) if factor.ndim == 0 else factor

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

    def parameter_of(self, subject: str) -> str:
        """The symbol this kind changes when it strikes ``subject``: the
        parameter itself, or the sensor's or input's added one."""
        return subject if self.suffix is None else f"{subject}_{self.suffix}"

    def prior_bounds(self, direction: str, scale: float, horizon: float,
                     declared: tuple[float, float] | None = None, widen: float = 1.0) -> tuple[float, float]:
        """(low, high) of the uniform prior of the magnitude: the model's
        ``declared`` bounds (a step's size in units of ``scale``, a drift's
        rate in units of ``scale`` per unit time), else the kind's default
        for the direction; both times ``widen`` (``--prior-scale``). A
        parameter's prior never takes it below ``LOWEST`` of its nominal
        (over the horizon, for a drift)."""
        scale = abs(scale) or 1.0
        if declared is not None:
            lo, hi = declared
            per = 1.0
        else:
            lo, hi = self.prior[direction]
            per = horizon if self.drifts else 1.0
        lo, hi = lo * widen, hi * widen
        if "parameter" in self.targets or self.noise:  # a noise std's factor stays positive too
            lo = max(lo, LOWEST / (horizon if self.drifts else 1.0) * per)
        return lo * scale / per, hi * scale / per

    def jitter_std(self, scale: float, bounds: tuple[float, float]) -> float:
        """Per-step random-walk std of the magnitude state."""
        base = (abs(scale) or 1.0) if self.jitter_scale == "parameter" else bounds[1] - bounds[0]
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
    "bias": FaultKind(
        "bias", "bias", False,
        {"increase": (0.0, 0.5), "decrease": (-0.5, 0.0), "both": (-0.5, 0.5)},
        0.004, "parameter", "an offset b added from the onset: a sensor reads y + b, an actuator delivers u + b",
        ("sensor", "actuator"), "offset", 0.0),
    "drift": FaultKind(
        "drift", "slope", True,
        # offsets that reach up to half the scale over the horizon
        {"increase": (0.0, 0.5), "decrease": (-0.5, 0.0), "both": (-0.5, 0.5)},
        0.01, "prior", "an offset growing at c per unit time from the onset: a sensor reads y + c (t - t_f)",
        ("sensor", "actuator"), "offset", 0.0),
    "stuck": FaultKind(
        "stuck", "value", False,
        # a reading from half its scale below 0 to two and a half times its nominal
        # reading: a dead sensor (0) and a frozen one (near its reading) both inside
        {"increase": (0.0, 1.5), "decrease": (-1.5, 0.0), "both": (-1.5, 1.5)},
        0.002, "parameter", "the reading stays at a value v from the onset, whatever the plant does (a frozen "
        "or dead sensor)", ("sensor",), "stuck", 0.0, True),
    "noise": FaultKind(
        "noise", "bias", False,
        # the sensor's noise std times 1 + b: up to ten times it; a quieter sensor (a
        # decrease) down to a tenth of it; a decrease's bound, widened, stays above -95 %
        {"increase": (0.0, 9.0), "decrease": (-0.9, 0.0), "both": (-0.9, 9.0)},
        0.004, "parameter", "a burst of measurement noise from the onset: the sensor's noise std becomes "
        "(1 + b) times its own (the thesis's measurement node M_i, section III.3)",
        ("sensor",), "noise", 1.0, noise=True),
    "gain": FaultKind(
        "gain", "bias", False,
        {"increase": (0.0, 1.0), "decrease": (-0.5, 0.0), "both": (-0.5, 1.0)},
        0.004, "parameter", "a gain change from the onset: the actuator delivers (1 + g) u",
        ("actuator",), "gain", 1.0),
}


#: The fault kinds of a switched junction. A valve that does not move (``stuck_on``, ``stuck_off``):
#: from the onset it is ON, or OFF, whatever the mode says. A valve that moves by itself
#: (``uncommanded_on``, ``uncommanded_off``): at the onset it turns ON, or OFF, though its mode
#: asks for the other, and stays so until a mode asks for it in that state (the controller's next
#: command of the switch), from when it follows the modes again. Not a change of a symbol: its
#: fault model runs the plant in the configuration the faulty switch makes in each mode
#: (bgc.compiler.modes.compile_stuck), its magnitude state ``<junction>_<suffix>`` a flag
#: (:attr:`FaultKind.discrete`), which a mode asking for the switch's state clears
#: (:func:`releases`).
SWITCH_KINDS: Mapping[str, FaultKind] = {
    f"{suffix}_{state.lower()}": FaultKind(
        f"{suffix}_{state.lower()}", "switch", False, {d: (1.0, 1.0) for d in ("increase", "decrease", "both")}, 0.0,
        "prior", f"a switched junction {what.format(state=state)}", ("switch",), suffix)
    for suffix, what in (("stuck", "stuck {state} from the onset, whatever the mode says"),
                         ("uncommanded", "turned {state} at the onset without a command, until a mode asks for it "
                                         "{state} (the controller's next command of the switch)"))
    for state in ("ON", "OFF")}


def fault_parameter(name: str) -> str:
    """What a fault model's name (``R1_abrupt``, ``v_C_offset_bias``,
    ``K_stuck_on``) is a fault of: its parameter (a sensor's or an input's
    offset or gain), or a stuck switch's junction.

    >>> fault_parameter("R1_abrupt"), fault_parameter("v_C_offset_bias"), fault_parameter("K_stuck_on")
    ('R1', 'v_C_offset', 'K')
    """
    for kind in SWITCH_KINDS:
        if name.endswith("_" + kind):
            return name[:-len(kind) - 1]
    return name.rsplit("_", 1)[0]


def kind_of(name: str) -> str:
    """The kind of a fault model by its name (``R1_abrupt``, ``K_uncommanded_on``).

    >>> kind_of("R1_abrupt"), kind_of("K_uncommanded_on"), kind_of("v_C_offset_bias")
    ('abrupt', 'uncommanded_on', 'bias')
    """
    return name[len(fault_parameter(name)) + 1:]


def stuck_state(kind: str) -> str:
    """Where a switch's fault of ``kind`` (stuck_on, stuck_off, uncommanded_on,
    uncommanded_off) puts the switch: ``ON`` or ``OFF``."""
    return "ON" if kind.endswith("_on") else "OFF"


def releases(kind: str) -> bool:
    """Whether a switch's fault of ``kind`` ends when a mode asks for the
    state it put the switch in (an uncommanded change: the controller's next
    command of the switch takes it back), rather than lasting (stuck)."""
    return kind in SWITCH_KINDS and SWITCH_KINDS[kind].suffix == "uncommanded"


def switch_held(kind: str) -> str:
    """How a switch's fault of ``kind`` holds from its onset, in words before
    the onset's time.

    >>> switch_held("stuck_on"), switch_held("uncommanded_off")
    ('stuck from', 'moved without a command at')
    """
    return "moved without a command at" if releases(kind) else "stuck from"


def stuck_title(junction: str, kind: str) -> str:
    """A switch's fault in words: ``K stuck OFF``, ``K turned OFF without a command``."""
    if releases(kind):
        return f"{junction} turned {stuck_state(kind)} without a command"
    return f"{junction} stuck {stuck_state(kind)}"


def kinds_for(target: str) -> str:
    """What a target takes, for messages: ``a sensor takes: bias, drift, stuck, noise``."""
    valid = ", ".join(k for k, fk in FAULT_KINDS.items() if target in fk.targets)
    return f"{'an' if target[0] in 'aeiou' else 'a'} {target} takes: {valid}"


def fault_kind(name: str) -> FaultKind:
    """The registry entry of a fault kind; KeyError lists the valid kinds."""
    try:
        return FAULT_KINDS[name] if name in FAULT_KINDS else SWITCH_KINDS[name]
    except KeyError:
        raise KeyError(f"unknown fault kind '{name}' (valid: {', '.join(FAULT_KINDS)})") from None


def comes_and_goes(name: str) -> bool:
    """Whether a fault of kind ``name`` may be intermittent (come and go by
    itself, :mod:`bgc.diagnosis.intermittent`): a step whose magnitude is a
    bias that holds while present (``abrupt``, ``bias``, ``gain``,
    ``noise``), not a drift, a stuck reading or a stuck switch."""
    k = fault_kind(name)
    return k.magnitude == "bias" and not k.drifts and not k.discrete and not k.replaces
