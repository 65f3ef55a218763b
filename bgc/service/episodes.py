"""A monitor's fault episodes (``bgc monitor --episodes``): the monitor goes
on after a verdict, and keeps a fault log.

An episode opens with an alarm and closes at the first checkpoint
(``--checkpoint T``: a diagnosis of the data so far every T while hypotheses
are tracked) whose verdict is ``isolated``, or, whatever the verdict, once
``--rearm T`` has passed since the alarm (an episode not decided: the
checkpoint's verdict is logged, ``unexplained`` or ``ambiguous``). What the
monitor does then, an :class:`~bgc.events.EpisodeClosed` event saying it:

- **accommodated**: an isolated fault whose estimate is a value of one of
  the model's parameters (a part of the plant's, a sensor's or an actuator's
  offset; a drift at the value it reached) becomes part of the model the
  next diagnoser watches with (that parameter at the estimate's value,
  :func:`~bgc.model.package.started_package`): a second fault is detected
  against the plant as it now is, and its fault models are sized from
  there (sequential multiple faults);
- **sensor out**: an isolated fault of a sensor that no parameter holds (a
  stuck or noisy sensor), or any sensor fault with
  ``--exclude-faulty-sensor``: the sensor is taken out of the nominal
  observer (when another is left);
- **not accommodated**: an isolated fault neither of these holds (a switch
  stuck, a noisy sensor that is the last one): watching again on the
  model as it was;
- **re-armed**: an episode not decided (``--rearm``): the same.

A repair while an episode is under way closes it (action ``repaired``).

The next diagnoser's observer starts where the plant is: from the isolated
hypothesis's state estimate at the checkpoint (else the nominal observer's),
and it watches the rows after the checkpoint's.

A repair (the operator's word: a ``# repaired`` line of the stream, or
:meth:`Episodes.repaired`) takes the accommodated faults out of the model
(``# repaired: R2`` only that parameter's; a :class:`~bgc.events.Repaired`
event) and the monitor watches on the model as it was, from the nominal
observer's estimate. The fault log is these events: the monitor's lines as
they happen, and the report's events (report.md, report.html,
report.json), led by them.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from .. import events as ev
from ..model.package import STARTED_AT, STARTED_THETA, forget_started, started_package

#: What a comment line of the stream says to declare a repair (``# repaired``, ``# repaired: R2``).
REPAIRED = "repaired"

#: An estimate of a parameter held at a faulty value within this fraction of the way back to its
#: value in the model file names the fault gone (:func:`_returned`).
BACK = 0.2


class Episodes:
    """The fault log and the faults accommodated of one monitor (module
    docstring). ``base``: the model's own package (the healthy plant);
    ``rearm``: the time after an alarm at which an episode not decided is
    closed and the monitor re-armed (None: only an isolation closes one);
    ``exclude_faulty``: a sensor fault takes the sensor out instead of being
    accommodated."""

    def __init__(self, base, rearm: float | None = None, exclude_faulty: bool = False, per_time: str = "per unit time"):
        self.base, self.rearm, self.exclude_faulty, self.per_time = base, rearm, exclude_faulty, per_time
        self.theta: dict[str, float] = {}  # the parameters of the faults accommodated, at their values
        self.by: dict[str, int] = {}  # per parameter accommodated, its episode
        self.log: list = []  # EpisodeClosed and Repaired, in order
        self.alarm: tuple[float, str] | None = None  # the open episode's alarm (time, sensor)
        #: per parameter accommodated at least once, its appearances: [onset, end (None: present), value]
        self.spells: dict[str, list[list]] = {}
        self.remarks = 0  # the stream's comment lines read so far (a repair is one)
        #: of them, those read before the last row was taken: the ones after it, taken already, are
        #: ``remarks - at_row`` (a restart takes none of them twice, :meth:`bgc.service.monitor.Monitor.row`)
        self.at_row = 0

    def watch(self, belief, d) -> None:
        """Note the alarm of a belief (the open episode's)."""
        if self.alarm is None and belief.alarm is not None:  # (the change test's: when the record's test raised it)
            self.alarm = (d.time_of(belief.alarm.raised), belief.alarm.sensor)

    def due(self, c, now: float) -> bool:
        """Whether checkpoint diagnosis ``c`` at time ``now`` closes the open episode."""
        if self.alarm is None:
            return False
        return c.verdict in ("isolated", "no fault") or frozen_unsized(c) is not None \
            or (self.rearm is not None and now - self.alarm[0] >= self.rearm)

    def close(self, c, d, now: float, sensors: list[str], forced: str | None = None):
        """Close the open episode on checkpoint diagnosis ``c`` of diagnoser
        ``d`` at time ``now``: (the next diagnoser, its sensors, the
        :class:`~bgc.events.EpisodeClosed` event). ``forced``: why the
        episode is closed before its checkpoint decides it, ``"memory"`` (its
        record reached the most the diagnosis holds in memory) or ``"gap"``
        (a gap longer than that came); not isolated, it is re-armed for that
        reason (``--rearm`` or not)."""
        from ..kinds import fault_kind
        from ..output.events import fault_sentence

        e = c.estimate if c.verdict == "isolated" else None
        held = e is not None and _held(e, d.nominal)  # a parameter's value the model can take
        action, parameter, value, out = "re-armed" if e is None else "not accommodated", None, None, list(sensors)
        number, appearance = len(self.episodes()) + 1, 0
        came = c.best.intermittent if e is not None and c.best is not None else None  # one fault node that comes and goes
        if came is not None and held and e.parameter not in self.theta:
            spans = [[c.time_of(sp.on), None if sp.off is None else c.time_of(sp.off), float(e.parameter_value)]
                     for sp in came.spans]
            self.spells.setdefault(e.parameter, []).extend(spans)
            appearance = len(self.spells[e.parameter])
            if spans[-1][1] is not None:  # gone again by the checkpoint: the model watched stays the file's
                action, parameter, value = "ended", e.parameter, self._file_value(e.parameter)
            else:
                action, parameter, value = "accommodated", e.parameter, float(e.parameter_value)
                self.theta[parameter], self.by[parameter] = value, number
        elif came is not None and held:  # a fault accommodated: the node's spans are its absences (its step back)
            parameter, spell = e.parameter, self.spells[e.parameter]
            for sp in came.spans:
                spell[-1][1] = c.time_of(sp.on)
                if sp.off is not None:  # back again: a new appearance at the value it had
                    spell.append([c.time_of(sp.off), None, self.theta[parameter]])
            appearance = len(spell)
            if came.spans[-1].off is None:  # absent at the checkpoint: gone
                action, value = "ended", self._file_value(parameter)
                del self.theta[parameter], self.by[parameter]
            else:  # it went away and came back: still accommodated as it was
                action, value = "accommodated", self.theta[parameter]
        elif held and e.parameter in self.theta and not fault_kind(e.kind).drifts \
                and _returned(e, self._file_value(e.parameter)):  # a step back (a drift's slope is no value)
            action, parameter, value = "ended", e.parameter, self._file_value(e.parameter)
            del self.theta[parameter], self.by[parameter]
            spell = self.spells[parameter][-1]
            spell[1] = c.onset if c.onset is not None else now
            appearance = len(self.spells[parameter])
        elif e is not None and e.target == "sensor" and (self.exclude_faulty or not held) \
                and e.subject in sensors and len(sensors) > 1:
            action, parameter = "sensor out", e.subject
            out = [y for y in sensors if y != e.subject]
        elif frozen_unsized(c) in sensors and len(sensors) > 1:
            action, parameter = "sensor out", frozen_unsized(c)
            out = [y for y in sensors if y != parameter]
        elif held:
            action, parameter, value = "accommodated", e.parameter, float(e.parameter_value)
            if parameter not in self.theta:  # an appearance (a fault of it that went away before: again)
                self.spells.setdefault(parameter, []).append([c.onset, None, value])
            else:  # a further change of a fault still present: its value while present is now this
                self.spells[parameter][-1][2] = value
            appearance = len(self.spells[parameter])
            self.theta[parameter] = value
            self.by[parameter] = number
        finding = frozen_finding(parameter) if e is None and action == "sensor out" else \
            "" if e is None else fault_sentence(e, c.onset, self.per_time, clock=c.clock)
        alarm, sensor = self.alarm
        glitch = any(isinstance(x, ev.Glitch) for x in c.events)  # one reading off, quiet after it
        reason = ("" if action != "re-armed" else "glitch" if glitch and c.verdict == "no fault" else "false alarm"
                  if c.verdict == "no fault" else forced if forced else "rearm" if c.verdict != "isolated"
                  else "no estimate")
        closed = ev.EpisodeClosed(number, alarm, sensor, now, c.verdict, tuple(c.candidates), c.onset, finding,
                                  action, parameter, value, None, appearance, self.present(parameter), reason)
        self.log.append(closed)
        self.alarm = None
        return self._next(d, *_state_now(c, d), out), out, closed

    def repaired(self, d, now: float, which: tuple[str, ...] = ()):
        """The operator says the plant was repaired at time ``now`` (``which``:
        the parameters repaired; empty: every one accommodated): (the next
        diagnoser, the :class:`~bgc.events.Repaired` event)."""
        if self.alarm is not None:  # an episode under way ends with the repair
            alarm, sensor = self.alarm
            self.log.append(ev.EpisodeClosed(len(self.episodes()) + 1, alarm, sensor, now, "undecided", (), None, "",
                                             "repaired"))
        names = tuple(p for p in self.theta if not which or p in which)
        done = ev.Repaired(now, tuple(sorted({self.by[p] for p in names})), names)
        for p in names:
            del self.theta[p]
            del self.by[p]
            self.spells.pop(p, None)  # repaired: a fault of it later is a new one, not this one again
        self.log.append(done)
        self.alarm = None
        if d.loop.x_mean:  # the nominal observer's estimate now
            x, s = np.asarray(d.loop.x_mean[-1], dtype=float), np.asarray(d.loop.x_std[-1], dtype=float)
        else:  # no row since the last diagnoser was opened: where it started
            x, s = getattr(d.config.package, STARTED_AT, None) or (None, None)
        return self._next(d, x, s, None), done

    def present(self, parameter: str | None) -> tuple:
        """The spans over which ``parameter``'s fault was present, as far as
        the episodes tell: ((onset, end), ...), the end None while it still
        is (empty: no fault of it accommodated)."""
        return tuple((on, off) for on, off, _ in self.spells.get(parameter, ())) if parameter else ()

    def _file_value(self, parameter: str) -> float:
        """``parameter``'s value in the model file (the healthy plant's)."""
        from ..model.protocol import nominal_model

        nominal = nominal_model(self.base)
        return float(nominal.THETA[nominal.PARAMETERS.index(parameter)])

    def plain(self) -> dict:
        """The log, the faults accommodated and the open episode's alarm as
        JSON data (a monitor's state, :mod:`bgc.service.resume`)."""
        return {"theta": dict(self.theta), "by": dict(self.by), "remarks": self.remarks, "at_row": self.at_row,
                "spells": self.spells,
                "alarm": None if self.alarm is None else list(self.alarm),
                "log": [[type(e).__name__, {f.name: getattr(e, f.name) for f in dataclasses.fields(e)}]
                        for e in self.log]}

    def restore(self, data: dict) -> None:
        """Take up :meth:`plain`'s data (of a monitor's state, checked whole by its checksum)."""
        self.theta = {str(k): float(v) for k, v in data["theta"].items()}
        self.by = {str(k): int(v) for k, v in data["by"].items()}
        self.remarks = int(data["remarks"])
        self.at_row = int(data.get("at_row", self.remarks))
        self.spells = {str(p): [list(spell) for spell in spells] for p, spells in data.get("spells", {}).items()}
        self.alarm = None if data["alarm"] is None else (float(data["alarm"][0]), str(data["alarm"][1]))
        kinds = {"EpisodeClosed": ev.EpisodeClosed, "Repaired": ev.Repaired}
        self.log = [kinds[name](**{k: _tuples(v) for k, v in fields.items()})
                    for name, fields in data["log"]]

    def sensors_out(self) -> set[str]:
        """The sensors the episodes took out."""
        return {e.parameter for e in self.episodes() if e.action == "sensor out"}

    def episodes(self) -> list[ev.EpisodeClosed]:
        return [e for e in self.log if isinstance(e, ev.EpisodeClosed)]

    def _next(self, d, mean, std, sensors):
        """A diagnoser for the rows after now: on the model with the faults
        accommodated, its observer from ``mean``, ``std`` (None: the model's
        X0), with ``sensors`` (None: ``d``'s)."""
        old = d.config.package
        package = started_package(self.base, mean, std, theta=dict(self.theta))  # the base itself when neither
        if package is not old and getattr(old, STARTED_THETA, None) is not None:
            forget_started(old)
        return d.again(package, sensors)


def _held(e, nominal) -> bool:
    """Whether fault estimate ``e`` is a value one of ``nominal``'s
    parameters can take (a part of the plant's, a sensor's or an actuator's
    offset), not a change of a sensor's noise or reading."""
    from ..kinds import fault_kind

    kind = fault_kind(e.kind)
    return (not kind.noise and not kind.replaces and not kind.discrete and e.parameter in nominal.PARAMETERS
            and math.isfinite(e.parameter_value))


def _tuples(value):
    """JSON's lists as the tuples an event holds (nested: a fault's spans)."""
    return tuple(_tuples(v) for v in value) if isinstance(value, list) else value


def _returned(e, file_value: float) -> bool:
    """Whether estimate ``e`` of a parameter held at a faulty value says it
    went back to ``file_value`` (its value in the model file): that value
    inside the estimate's interval, or the estimate within ``BACK`` of the
    way back from the faulty value (the particle filter's interval may be
    narrower than its error)."""
    back = file_value - e.nominal  # the step back, from the faulty value the model held
    return bool(e.low <= back <= e.high or abs(e.value - back) <= BACK * abs(back))


def _state_now(c, d) -> tuple[np.ndarray | None, np.ndarray | None]:
    """Where the plant is at the end of checkpoint diagnosis ``c``: the
    isolated hypothesis's state estimate (one that comes and goes: its
    filter switched at its spans), else the nominal observer's (None:
    neither is finite)."""
    n = len(d.nominal.STATES)
    if c.verdict == "isolated":
        h = next((h for h in c.hypotheses if h.name == c.candidates[0]), None)
        i = None if h is None else h.intermittent
        if i is not None and i.x_end is not None:  # a fault that comes and goes: its filter switched at its spans
            mean, std = np.asarray(i.x_end, dtype=float)[:n], np.asarray(i.x_end_std, dtype=float)[:n]
            if np.all(np.isfinite(mean)) and np.all(np.isfinite(std)):
                return mean, std
        elif h is not None and len(h.x_mean):
            mean, std = np.asarray(h.x_mean[-1], dtype=float)[:n], np.asarray(h.x_std[-1], dtype=float)[:n]
            if np.all(np.isfinite(mean)) and np.all(np.isfinite(std)):
                return mean, std
    mean, std = np.asarray(c.nominal_x_mean[-1], dtype=float), np.asarray(c.nominal_x_std[-1], dtype=float)
    if np.all(np.isfinite(mean)) and np.all(np.isfinite(std)):
        return mean, std
    return None, None


def repair_of(line: str) -> tuple[str, ...] | None:
    """The parameters a comment line of the stream says were repaired (empty:
    all), or None when it says no repair: ``repaired`` or ``repaired: R2, C1``."""
    text = line.strip()
    if not text.lower().startswith(REPAIRED):
        return None
    rest = text[len(REPAIRED):].strip()
    if rest.startswith(":"):
        return tuple(p.strip() for p in rest[1:].split(",") if p.strip())
    return () if not rest else None


def frozen_finding(sensor: str) -> str:
    """What the fault log says of a sensor taken out as :func:`frozen_unsized`."""
    return f"sensor {sensor}'s reading is frozen, and no stuck fault of the model explains it"


def frozen_unsized(c) -> str | None:
    """The sensor diagnosis ``c`` found frozen and could not size (the model
    declares no stuck fault of it, or the one it declares does not explain
    the data: the verdict is unexplained, and the reading is off all the
    same, :class:`~bgc.events.ReadingFrozen`); else None."""
    if c.verdict != "unexplained":
        return None
    return next((e.sensor for e in c.events if isinstance(e, ev.ReadingFrozen)), None)
