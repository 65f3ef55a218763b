"""Intermediate representations (IRs) of the compiler, in pipeline order.

Every IR is a frozen dataclass holding tuples, sympy expressions and frozen
networkx graphs. Stages take one IR and return the next; nothing here does I/O.
Importing this module does not import sympy (the runtime reads the IRs' plain
types, :class:`Settings`, :class:`FaultCandidate`, :class:`NoiseLevels`, ...,
and a compiled model's plain-data view, :mod:`bgc.view`, without it).

Pipeline order: :class:`RawModel` -> :class:`BondGraph` -> :class:`CausalBondGraph`
-> :class:`TemporalCausalGraph` -> :class:`StateSpaceModel` -> :class:`DbnModel`
-> :class:`Numerics` -> :class:`GeneratedPackage`.
"""

from __future__ import annotations

import math

from dataclasses import dataclass, field
from pathlib import PurePath
from typing import TYPE_CHECKING, Any, Mapping

import numpy as np

from .errors import SourceLoc
from .kinds import SWITCH_KINDS, element_kind, releases, stuck_state, stuck_title

if TYPE_CHECKING:
    import sympy


def sym(name: str) -> sympy.Symbol:
    """The one sympy symbol bgc uses for a name (no assumptions: they are slow)."""
    import sympy

    return sympy.Symbol(name)


def var_key(name: str) -> tuple:
    """Sort key of variable names: bond variables by bond number, effort before
    flow, then every other name alphabetically (``e2 < f2 < e10 < y``)."""
    if name[:1] in "ef" and name[1:].isdigit():
        return (0, int(name[1:]), name[0])
    return (1, 0, name)


def effort(bond: int) -> str:
    """Name of the effort variable of a bond, e.g. ``effort(4) == 'e4'``."""
    return f"e{bond}"


def flow(bond: int) -> str:
    """Name of the flow variable of a bond, e.g. ``flow(10) == 'f10'``."""
    return f"f{bond}"


# --------------------------------------------------------------------------- load
@dataclass(frozen=True, slots=True)
class RawModel:
    """A YAML document as plain data, with the location of every node.

    ``locations`` maps a path (tuple of keys and indices from the root) to the
    place where that node starts; ``key_locations`` maps a mapping entry's path to
    where its key starts.
    """

    path: str
    data: Any
    locations: Mapping[tuple, SourceLoc]
    key_locations: Mapping[tuple, SourceLoc]
    sha256: str = ""

    def loc(self, *path: Any) -> SourceLoc:
        """Location of the deepest existing node on ``path``."""
        p = tuple(path)
        while p:
            if p in self.locations:
                return self.locations[p]
            p = p[:-1]
        return self.locations.get((), SourceLoc(self.path, 1, 1))

    def key_loc(self, *path: Any) -> SourceLoc:
        p = tuple(path)
        return self.key_locations.get(p) or self.loc(*p)


# ----------------------------------------------------------------------- modes
#: The comparisons a guard may make, and what each means of lhs - rhs.
GUARD_OPS = (">=", "<=", ">", "<")


@dataclass(frozen=True, slots=True)
class Guard:
    """A transition's condition ``lhs OP rhs`` (OP one of :data:`GUARD_OPS`),
    over bond variables, measurements (their noise-free value), inputs and
    parameters, as written (``text``)."""

    lhs: sympy.Expr
    op: str
    rhs: sympy.Expr
    text: str
    loc: SourceLoc

    def holds(self, lhs: float, rhs: float) -> bool:
        """Whether the guard holds for these values of its two sides."""
        return {">": lhs > rhs, ">=": lhs >= rhs, "<": lhs < rhs, "<=": lhs <= rhs}[self.op]


@dataclass(frozen=True, slots=True)
class Transition:
    """A change of mode from ``source`` to ``target``: *autonomous* when
    ``guard`` is given (the plant switches when it holds), *timed* when
    ``after`` is (the plant switches after that long in ``source``: a
    schedule), else *controlled* (the mode is set from outside and the data
    say it). ``resets``: states given new values at the transition (state,
    expression of the values just before it). ``tolerance``: an autonomous
    transition's threshold is uncertain: on each visit of ``source`` the
    plant switches where ``lhs - rhs`` crosses a value drawn from
    N(0, tolerance^2) instead of 0 (0: exactly at the guard)."""

    source: str
    target: str
    guard: Guard | None
    after: float | None
    resets: tuple[tuple[str, Any], ...]
    description: str | None
    loc: SourceLoc
    tolerance: float = 0.0

    @property
    def kind(self) -> str:
        """``autonomous``, ``timed`` or ``controlled``."""
        return "autonomous" if self.guard is not None else "timed" if self.after is not None else "controlled"


@dataclass(frozen=True, slots=True)
class Mode:
    """One mode of a hybrid bond graph: the switched junctions ON in it (every
    other one is OFF)."""

    name: str
    on: tuple[str, ...]
    description: str | None
    loc: SourceLoc


#: The fault kinds of a switched junction: it stays ON, or OFF, whatever the mode says (stuck), or
#: turns so without a command until a mode asks for it so (uncommanded).
SWITCH_FAULTS = tuple(SWITCH_KINDS)


@dataclass(frozen=True, slots=True)
class StuckSwitch:
    """A switched junction that may stick (a valve that does not move): from
    the fault's onset it is ON (``stuck_on``) or OFF (``stuck_off``) in every
    mode, the rest of each mode's junctions as the mode says; or that may
    move by itself (``uncommanded_on``, ``uncommanded_off``): ON, or OFF, from
    the onset as if stuck, until a mode asks for it in that state
    (:attr:`releases`); ``prior``: the fault's probability before any data."""

    junction: str
    kind: str
    prior: float
    loc: SourceLoc

    @property
    def name(self) -> str:
        """``K:stuck_off``: what ``--fault`` and ``bgc show dbn --fault`` call it."""
        return f"{self.junction}:{self.kind}"

    @property
    def title(self) -> str:
        return stuck_title(self.junction, self.kind)

    def on(self, on: tuple[str, ...]) -> tuple[str, ...]:
        """The junctions ON in a mode whose own are ``on``, with this fault."""
        kept = set(on) | {self.junction} if self.state == "ON" else set(on) - {self.junction}
        return tuple(sorted(kept))

    @property
    def state(self) -> str:
        """Where the fault puts the switch: ``ON`` or ``OFF``."""
        return stuck_state(self.kind)

    @property
    def releases(self) -> bool:
        """The fault ends where a mode asks for the switch in :attr:`state`
        (an uncommanded change, which the controller's next command of the
        switch takes back); a stuck switch's lasts."""
        return releases(self.kind)

    def released(self, on: tuple[str, ...]) -> bool:
        """Whether a mode whose ON junctions are ``on`` ends this fault: it
        releases and the mode asks for the switch where the fault put it."""
        return self.releases and (self.junction in on) == (self.state == "ON")

    def releasing(self, modes) -> tuple[str, ...]:
        """The names of the modes of ``modes`` (:class:`Mode`) that end this fault (none for a stuck switch)."""
        return tuple(m.name for m in modes if self.released(m.on))


@dataclass(frozen=True, slots=True)
class Modes:
    """A hybrid bond graph's switched junctions, its modes (the first is the
    plant's mode at time 0), its transitions, in the model file's order, and
    the switches the model says may stick (``stuck``, its ``faults:`` on them)."""

    switches: tuple[str, ...]
    modes: tuple[Mode, ...]
    transitions: tuple[Transition, ...]
    stuck: tuple[StuckSwitch, ...] = ()

    def stuck_fault(self, name: str) -> StuckSwitch | None:
        """The stuck switch called ``name`` (``K:stuck_off``), or None."""
        return next((f for f in self.stuck if f.name == name), None)

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(m.name for m in self.modes)

    @property
    def initial(self) -> str:
        return self.modes[0].name

    def mode(self, name: str) -> Mode:
        for m in self.modes:
            if m.name == name:
                return m
        raise KeyError(name)


# ------------------------------------------------------------------ bond graph
@dataclass(frozen=True, slots=True)
class Parameter:
    name: str
    value: float
    unit: str | None
    description: str | None
    loc: SourceLoc


@dataclass(frozen=True, slots=True)
class Law:
    """A constitutive law ``output = expr`` in the element's own bond variables.

    ``output`` is the bond variable the law gives (``'e5'`` or ``'f5'``); ``text`` is
    the law as written in the model file, with the element-local names ``e``/``f``.
    """

    output: str
    expr: sympy.Expr
    text: str
    loc: SourceLoc


@dataclass(frozen=True, slots=True)
class Element:
    """One bond-graph element.

    ``parameter`` is the coefficient of a linear law (R: e = R f; C: de/dt = f/C;
    I: df/dt = e/I; TF: e_in = m e_out, f_out = m f_in; GY: e_in = r f_out,
    e_out = r f_in); for modulated elements it may depend on bond variables.
    ``source`` is the value a source imposes. ``law`` replaces ``parameter`` for a
    nonlinear resistor.
    """

    name: str
    kind: str
    parameter: sympy.Expr | None
    law: Law | None
    source: sympy.Expr | None
    initial: float | None
    description: str | None
    loc: SourceLoc
    #: Process-noise level of a storage element's state (fraction of the signal);
    #: None: the model's default.
    noise: float | None = None
    #: What a storage element's state is (``conductivity``), where the model's
    #: domain does not say it; None: the domain's effort or flow.
    quantity: str | None = None
    #: A switched junction (hybrid bond graphs): ON an ordinary junction, OFF
    #: zero flow (a 1-junction) or zero effort (a 0-junction) on its bonds.
    switch: bool = False


@dataclass(frozen=True, slots=True)
class Bond:
    """A bond; power flows from ``tail`` to ``head`` (the half arrow's direction)."""

    number: int
    tail: str
    head: str
    loc: SourceLoc

    def other(self, element: str) -> str:
        return self.head if element == self.tail else self.tail


#: The bits of the pseudo-random binary sequence (PRBS) of an input: a
#: maximal-length sequence of a 9-bit linear-feedback shift register
#: (x^9 + x^5 + 1), 511 bits, then it repeats.
PRBS_BITS = 511
#: A time on a boundary of a period (a bit, a square wave's half) is in the
#: period it starts, within this fraction of a period (0.3 / 0.1 is 2.9999...).
PERIOD_SLACK = 1e-9


def prbs_bits(seed: int) -> str:
    """The :data:`PRBS_BITS` bits of the PRBS whose register starts at
    ``seed`` (1 to 511), as text of 0 and 1: the register's last bit, then
    it shifts with the new bit the XOR of bits 9 and 5.

    >>> prbs_bits(1)[:12]
    '100000000100'
    """
    state = seed
    out = []
    for _ in range(PRBS_BITS):
        out.append(state & 1)
        bit = ((state >> 0) ^ (state >> 4)) & 1  # taps 9 and 5 of x^9 + x^5 + 1, read from the output end
        state = (state >> 1) | (bit << 8)
    return "".join(map(str, out))


@dataclass(frozen=True, slots=True)
class Signal:
    """An input signal, ``value`` before ``start`` (default 0) and then:

    - ``constant``: value;
    - ``step``: final;
    - ``ramp``: value + slope (t - start);
    - ``sine``: value + amplitude sin(2 pi (t - start) / period);
    - ``square``: value + amplitude over the first ``duty`` of each period
      (from start), value over the rest;
    - ``prbs``: value + amplitude b_k, b_k the k-th bit (k = floor((t -
      start) / period)) of the PRBS of :func:`prbs_bits` (``seed``);
    - ``chirp``: value + amplitude sin(2 pi (f0 tau + (f1 - f0) tau^2 / (2
      duration))), tau = (t - start) mod duration: a sine whose frequency
      sweeps linearly from f0 to f1 over ``duration``, again and again.
    """

    kind: str
    value: float
    final: float | None = None
    start: float | None = None
    slope: float | None = None
    amplitude: float | None = None
    period: float | None = None
    duty: float | None = None
    seed: int | None = None
    f0: float | None = None
    f1: float | None = None
    duration: float | None = None

    @property
    def text(self) -> str:
        """The signal in words: ``'constant 1'``, ``'step 1 to 2 at t = 5'``."""
        s = self
        if s.kind == "constant":
            return f"constant {s.value:g}"
        if s.kind == "step":
            return f"step {s.value:g} to {s.final:g} at t = {s.start:g}"
        if s.kind == "ramp":
            return f"ramp from {s.value:g} at t = {s.start:g}, slope {s.slope:g}"
        since = f" from t = {s.start:g}" if s.start else ""
        if s.kind == "sine":
            return f"sine {s.value:g} +- {s.amplitude:g}, period {s.period:g}{since}"
        if s.kind == "square":
            return f"square wave {s.value:g} to {s.value + s.amplitude:g}, period {s.period:g}, duty {s.duty:g}{since}"
        if s.kind == "prbs":
            return f"PRBS {s.value:g} or {s.value + s.amplitude:g}, a bit each {s.period:g} (seed {s.seed}){since}"
        return f"chirp {s.value:g} +- {s.amplitude:g}, frequency {s.f0:g} to {s.f1:g} over {s.duration:g}{since}"

    def at(self, t: float) -> float:
        """The signal's value at time t."""
        if self.kind == "constant" or t < (self.start or 0.0):
            return self.value
        tau = t - (self.start or 0.0)
        if self.kind == "step":
            return self.final
        if self.kind == "ramp":
            return self.value + self.slope * tau
        if self.kind == "sine":
            return self.value + self.amplitude * math.sin(2 * math.pi / self.period * tau)
        if self.kind == "square":
            phase = tau / self.period + PERIOD_SLACK
            return self.value + (self.amplitude if phase - math.floor(phase) < self.duty else 0.0)
        if self.kind == "prbs":
            k = int(math.floor(tau / self.period + PERIOD_SLACK))
            return self.value + self.amplitude * int(prbs_bits(self.seed or 1)[k % PRBS_BITS])
        tau = tau - self.duration * math.floor(tau / self.duration)  # chirp
        return self.value + self.amplitude * math.sin(
            2 * math.pi * (self.f0 * tau + (self.f1 - self.f0) * tau * tau / (2 * self.duration)))


@dataclass(frozen=True, slots=True)
class Input:
    name: str
    signal: Signal
    unit: str | None
    description: str | None
    loc: SourceLoc


@dataclass(frozen=True, slots=True)
class Measurement:
    name: str
    expr: sympy.Expr
    text: str
    noise: float
    unit: str | None
    description: str | None
    loc: SourceLoc
    #: The standard deviation a calibration's estimates leave on the normalised residuals' variance
    #: on other data (``residual_variance_sd``, written by ``bgc calibrate``).
    residual_variance_sd: float = 0.0


@dataclass(frozen=True, slots=True)
class FaultCandidate:
    """Something that may fail, the fault kinds considered and their priors.

    ``subject``: what the model file names (a parameter, a measurement or an
    input); ``target``: which of the three (``parameter``, ``sensor``,
    ``actuator``); ``parameter``: the symbol of the equations the fault
    changes (the parameter itself, or the one the compiler adds for a sensor
    or actuator: :meth:`bgc.kinds.FaultKind.parameter_of`). ``prior``: the
    probability of the fault before any data. ``size`` and ``rate``: the
    model's own bounds of a step's size and a drift's rate, in units of the
    fault's scale (None: the kind's default)."""

    parameter: str
    kinds: tuple[str, ...]
    direction: str
    prior: float
    loc: SourceLoc
    target: str = "parameter"
    subject: str = ""
    size: tuple[float, float] | None = None
    rate: tuple[float, float] | None = None

    @property
    def name(self) -> str:
        """What the fault strikes, as the model file names it."""
        return self.subject or self.parameter


@dataclass(frozen=True, slots=True)
class Settings:
    """Defaults for simulation and filtering; noise as a fraction of the signal;
    ``time_unit``: the unit of time the model declares (None: none).

    ``locations``: where each setting the model gives is written (key ->
    place), and under ``""`` the place errors about the settings point at when
    the key is not written (the ``simulation`` section, else the model's name).
    """

    dt: float = 1.0
    steps: int = 300
    process_noise: float = 0.03
    measurement_noise: float = 0.02
    locations: tuple[tuple[str, SourceLoc], ...] = ()
    #: The unit of time and ``dt`` (``s``); None: not declared.
    time_unit: str | None = None

    def loc(self, key: str) -> SourceLoc | None:
        """Where setting ``key`` is written, or where the settings are."""
        places = dict(self.locations)
        return places.get(key, places.get(""))


@dataclass(frozen=True, slots=True)
class BondGraph:
    """A validated bond-graph model. Tuples are sorted by name or bond number."""

    name: str
    description: str
    source: str
    parameters: tuple[Parameter, ...]
    elements: tuple[Element, ...]
    bonds: tuple[Bond, ...]
    inputs: tuple[Input, ...]
    measurements: tuple[Measurement, ...]
    faults: tuple[FaultCandidate, ...]
    settings: Settings
    source_sha256: str = ""
    #: The physical domain of its efforts and flows (:data:`bgc.kinds.DOMAINS`); None: not declared.
    domain: str | None = None
    #: Its modes and transitions when it has switched junctions (a hybrid bond graph); None: one mode.
    modes: Modes | None = None

    def element(self, name: str) -> Element:
        for el in self.elements:
            if el.name == name:
                return el
        raise KeyError(name)

    def bond(self, number: int) -> Bond:
        for b in self.bonds:
            if b.number == number:
                return b
        raise KeyError(number)

    def bonds_of(self, name: str) -> tuple[Bond, ...]:
        return tuple(b for b in self.bonds if name in (b.tail, b.head))

    def parameter_values(self) -> dict[str, float]:
        return {p.name: p.value for p in self.parameters}

    def unit(self, name: str) -> str | None:
        """The declared unit of a parameter, measurement or input (None: none)."""
        for x in (*self.parameters, *self.measurements, *self.inputs):
            if x.name == name:
                return x.unit
        return None

    @property
    def display_source(self) -> str:
        """The model path as written into generated files: ``models/<file>`` for
        the shipped layout, else ``<folder>/<file>``, so output does not depend on
        the working directory. Model text: escape it where it enters code."""
        p = PurePath(self.source)
        return f"{p.parent.name}/{p.name}" if p.parent.name else p.name


# ------------------------------------------------------------------- causality
@dataclass(frozen=True, slots=True)
class Diagnostic:
    """A finding short of an error, shown by the CLI."""

    severity: str  # "warning" or "note"
    message: str
    element: str | None = None


@dataclass(frozen=True, slots=True)
class BondCausality:
    """Causality of one bond: ``effort_by`` imposes the effort, ``flow_by`` the flow.

    The causal stroke sits at the ``flow_by`` end, i.e. next to the element that
    receives the effort and imposes the flow.
    """

    bond: int
    effort_by: str
    flow_by: str


@dataclass(frozen=True, slots=True)
class StorageCausality:
    element: str
    kind: str
    bond: int
    integral: bool

    @property
    def state(self) -> str:
        """The co-energy state variable: ``e`` of a C, ``f`` of an I."""
        return effort(self.bond) if element_kind(self.kind).state_variable == "e" else flow(self.bond)


@dataclass(frozen=True, slots=True)
class CausalBondGraph:
    model: BondGraph
    bonds: tuple[BondCausality, ...]
    storage: tuple[StorageCausality, ...]
    arbitrary: tuple[str, ...]
    diagnostics: tuple[Diagnostic, ...] = field(default=())

    def causality(self, bond: int) -> BondCausality:
        for c in self.bonds:
            if c.bond == bond:
                return c
        raise KeyError(bond)

    @property
    def states(self) -> tuple[StorageCausality, ...]:
        return tuple(s for s in self.storage if s.integral)


# ------------------------------------------------------------------------- TCG
@dataclass(frozen=True, slots=True)
class TcgEdge:
    """One TCG edge ``source -> target``.

    ``parameters`` are the component parameters of the relation and ``effects``
    the sign of the target's change when each increases (None: undetermined);
    ``sign`` is the sign of the target's change when the source increases.
    """

    source: str
    target: str
    label: str
    relation: str
    element: str | None
    parameters: tuple[str, ...]
    effects: tuple[int | None, ...]
    sign: int | None
    temporal: bool


@dataclass(frozen=True, slots=True)
class TemporalCausalGraph:
    """The TCG (``graph``, frozen networkx DiGraph) and its simplified form over
    state, input and measured variables (``simplified``)."""

    causal: CausalBondGraph
    graph: Any
    simplified: Any
    edges: tuple[TcgEdge, ...]

    @property
    def model(self) -> BondGraph:
        return self.causal.model


# ------------------------------------------------------------------- equations
@dataclass(frozen=True, slots=True)
class StateSpaceModel:
    """``dx/dt = rhs(x, u, theta)``, ``y = output_exprs(x, u, theta)``.

    ``variables`` gives every bond variable in terms of states, inputs and
    parameters; ``loops`` lists the algebraic loops that were solved.
    """

    tcg: TemporalCausalGraph
    states: tuple[str, ...]
    state_elements: tuple[str, ...]
    inputs: tuple[str, ...]
    parameters: tuple[str, ...]
    parameter_values: tuple[float, ...]
    outputs: tuple[str, ...]
    rhs: tuple[Any, ...]
    output_exprs: tuple[Any, ...]
    variables: tuple[tuple[str, Any], ...]
    initial: tuple[float, ...]
    loops: tuple[tuple[str, ...], ...]

    @property
    def model(self) -> BondGraph:
        return self.tcg.causal.model


# ------------------------------------------------------------------------- DBN
@dataclass(frozen=True, slots=True)
class Dbn:
    """One two-slice DBN: nodes ``var@t`` / ``var@t+1`` with ``role`` and ``slice``
    attributes, arcs with ``arc`` in persistence/temporal/intra/fault/drift/indicator."""

    name: str
    parameter: str | None
    kind: str | None
    graph: Any


@dataclass(frozen=True, slots=True)
class DbnModel:
    equations: StateSpaceModel
    nominal: Dbn
    faulty: tuple[Dbn, ...]

    def get(self, name: str) -> Dbn:
        """The DBN called ``nominal`` or ``PARAM:KIND`` (a sensor's or
        actuator's fault also by its name in the model: ``F12:bias`` for
        ``F12_offset:bias``)."""
        for f in self.equations.model.faults:
            if name in {f"{f.name}:{k}" for k in f.kinds} and f.name != f.parameter:
                name = f"{f.parameter}:{name.rsplit(':', 1)[1]}"
        for d in (self.nominal, *self.faulty):
            if d.name == name:
                return d
        valid = ", ".join(d.name for d in (self.nominal, *self.faulty))
        raise KeyError(f"no DBN '{name}' (valid: {valid})")


# ------------------------------------------------------------------ signatures
@dataclass(frozen=True, slots=True)
class Signature:
    """TRANSCEND signature of one fault: ``symbols[j][k]`` is the deviation of
    measurement j at derivative order k (``+ - 0 ?``); ``first`` the
    measurements expected to deviate first. ``direction``: +1 increase, -1
    decrease."""

    parameter: str
    direction: int
    kind: str
    symbols: tuple[tuple[str, ...], ...]
    first: tuple[str, ...]

    @property
    def name(self) -> str:
        """``R2+:abrupt``: parameter, direction, kind."""
        return f"{self.parameter}{'+' if self.direction > 0 else '-'}:{self.kind}"


def first_symbol(symbols: tuple[str, ...]) -> str:
    """The first symbol of a signature that is not 0 (``0`` if none)."""
    return next((s for s in symbols if s != "0"), "0")


def expected_slope(symbols: tuple[str, ...]) -> str:
    """The slope a sensor shows once it deviates: its first non-zero symbol
    when that is at order 1 or higher, after a jump (order 0) the first
    non-zero symbol after it (``0``: none)."""
    k = next((i for i, s in enumerate(symbols) if s != "0"), None)
    if k is None:
        return "0"
    return first_symbol(symbols[k + 1:]) if k == 0 else symbols[k]


@dataclass(frozen=True, slots=True)
class FaultSignatures:
    """Every fault's signature (``measurements`` in model order), the order up
    to which they separate the faults (``orders``), the groups of faults with
    identical signatures (``ambiguity``), groups of fault parameters that enter
    the model as one combination (``structural``) and faults no sensor sees."""

    equations: StateSpaceModel
    measurements: tuple[str, ...]
    orders: int
    signatures: tuple[Signature, ...]
    ambiguity: tuple[tuple[str, ...], ...]
    structural: tuple[tuple[str, ...], ...]
    undetectable: tuple[str, ...]

    def get(self, name: str) -> Signature:
        for s in self.signatures:
            if s.name == name:
                return s
        raise KeyError(name)


# -------------------------------------------------------------------- numerics
@dataclass(frozen=True, slots=True)
class NoiseLevels:
    """Absolute noise stds: per state and step (``process``), per measurement
    (``measurement``), and of the one-step predictive of each measurement
    (``predictive``: measurement noise plus the process noise seen through the
    outputs)."""

    process: tuple[float, ...]
    measurement: tuple[float, ...]
    predictive: tuple[float, ...]


@dataclass(frozen=True, slots=True)
class FaultNumerics:
    """The numbers of one fault model (``name``: its DBN, ``PARAM:KIND``): the
    nominal value of the parameter, the uniform prior of the fault magnitude and
    the per-step random-walk std (``jitter``) of the magnitude state;
    ``scale``: the size its prior is written in units of
    (:func:`bgc.compiler.numerics.fault_scale`)."""

    name: str
    parameter: str
    kind: str
    nominal: float
    prior: tuple[float, float]
    jitter: float
    scale: float = 1.0


@dataclass(frozen=True, slots=True)
class Numerics:
    """What bgc fixes at compile time for the generated filters, at the
    nominal operating point (states X0, inputs at t = 0, nominal parameters).

    ``eigenvalues`` of the Jacobian there set the RK4 ``substeps`` per sample;
    ``x_scale`` and ``y_scale`` are the sizes that relative noise levels
    multiply; ``process_factor`` (per state) is ``sqrt(min(1, 2 dt / tau))``,
    ``tau`` the state's own time constant; ``process_levels`` the
    storage elements' own relative levels (None: the model's default);
    ``output_jacobian`` is H = dy/dx there. ``noise`` gives the absolute stds
    at the model's own levels; :meth:`noise_at` gives them at other levels.
    """

    dbn: DbnModel
    eigenvalues: tuple[complex, ...]
    substeps: int
    u0: tuple[float, ...]
    y0: tuple[float, ...]
    jacobian_diag: tuple[float, ...]
    output_jacobian: tuple[tuple[float, ...], ...]
    x_scale: tuple[float, ...]
    y_scale: tuple[float, ...]
    process_factor: tuple[float, ...]
    process_levels: tuple[float | None, ...]
    faults: tuple[FaultNumerics, ...]

    @property
    def equations(self) -> StateSpaceModel:
        return self.dbn.equations

    @property
    def noise(self) -> NoiseLevels:
        """The absolute stds at the model's own relative levels."""
        return self.noise_at()

    def fault(self, name: str) -> FaultNumerics:
        for f in self.faults:
            if f.name == name:
                return f
        raise KeyError(name)

    def noise_at(self, process_noise: float | None = None,
                 measurement_noise: float | None = None) -> NoiseLevels:
        """Absolute stds for relative levels: ``process_noise`` replaces the
        model's default level and scales the storage elements' own levels by
        the same ratio; ``measurement_noise`` replaces every sensor's level."""
        settings = self.equations.model.settings
        default = settings.process_noise
        process = []
        for own, s, factor in zip(self.process_levels, self.x_scale, self.process_factor):
            q = own
            if q is None:
                q = default if process_noise is None else process_noise
            elif process_noise is not None:
                q = q * (process_noise / default if default else 1.0)
            process.append(q * s * factor)
        measurement = tuple((m.noise if measurement_noise is None else measurement_noise) * s
                            for m, s in zip(self.equations.model.measurements, self.y_scale))
        h = np.array(self.output_jacobian, dtype=float).reshape(len(measurement), len(process))
        spread = (h ** 2) @ (np.array(process) ** 2) if process else np.zeros(len(measurement))
        predictive = tuple(float(np.sqrt(r * r + v)) for r, v in zip(measurement, spread))
        return NoiseLevels(tuple(process), measurement, predictive)


# ------------------------------------------------------------------- codegen
#: Folder of ``generated/<model>/`` that holds the generated NumPy package.
PACKAGE = "numpy_model"
#: Folder of ``generated/<model>/`` that holds the compiled (numba) package.
NUMBA_PACKAGE = "numba_model"
#: Backend name -> its package's folder.
PACKAGES = {"numpy": PACKAGE, "numba": NUMBA_PACKAGE}


@dataclass(frozen=True, slots=True)
class GeneratedPackage:
    """The generated packages of a model: ``files`` are the NumPy package's
    (path relative to the package, Python source), sorted by path;
    ``modules`` the model modules (``nominal`` first, then one per fault
    model); ``numba_files`` the compiled package's files, the same modules
    with numba kernels."""

    numerics: Numerics
    files: tuple[tuple[str, str], ...]
    modules: tuple[str, ...]
    numba_files: tuple[tuple[str, str], ...] = ()
