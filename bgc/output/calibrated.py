"""The calibrated model file: the user's YAML with the estimated values in place.

The text is edited, not dumped again: the user's comments, order, quoting
and layout survive, and only the value tokens of the estimated quantities
change. Where each goes in the model file (docs/calibrate.md, "Where the
estimates go"):

* a sensor's measurement noise: its relative level, the measurement's
  ``noise`` (the estimated std over the sensor's reading at the initial
  state, the size the compiler multiplies it by); written into the
  measurement when it had none (it then took ``simulation.measurement_noise``);
* the process noise: ``simulation.process_noise``; a storage element with
  its own ``noise`` gets it scaled by the same ratio (the model's shape of
  the process noise is kept, as :meth:`bgc.ir.Numerics.noise_at` scales it);
* a parameter: its value under ``parameters`` (``R1: 2.0`` or ``R1: {value:
  2.0, ...}``);
* what the estimates' uncertainty leaves on a sensor's residual variance:
  the measurement's ``residual_variance_sd`` (a measurement written without
  fields, ``e1:``, becomes one mapping of it and its noise).

Each changed value gets a comment line above its line: the estimate, its
95 % interval, the data it came from (and the date the data's header gives,
when it gives one) and the value it replaces; an estimate the data cannot
identify keeps the model's value and its comment says why. The positions
come from PyYAML's composer (node marks: nothing is constructed or
executed); the text written is read back by bgc's own reader, and a value
that does not read back as written is a bug (:class:`InternalError`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import yaml

from ..errors import CalibrationError, InternalError, printable
from .artifacts import MARK
from ..analysis.calibrate import Calibration, Estimate


def number(value: float) -> str:
    """A value as the calibrated file writes it: 6 significant digits, read
    back as a float (``2.0``, ``0.0201``, ``1.5e-05``)."""
    text = f"{value:.6g}"
    if not any(c in text for c in ".en"):
        text += ".0"
    return text


@dataclass(frozen=True, slots=True)
class TextChange:
    """A value written: the keys leading to it (``('parameters', 'R1')``),
    the text written, and the comment line(s) to put above it."""

    path: tuple[str, ...]
    text: str | None
    comment: str


def calibrated_text(text: str, source: str, cal: Calibration, element_levels: dict[str, float],
                    dates: Sequence[str] = ()) -> str:
    """The model file ``text`` (from ``source``) with the estimates of
    ``cal`` written in, a mark line first (the output is bgc's:
    :func:`bgc.output.artifacts.write_file` seals it). ``element_levels``:
    the storage elements that declare their own process ``noise``, with it;
    ``dates``: the dates the data's headers give."""
    data = ", ".join(printable(s) for s in cal.sources)
    when = f" (recorded {', '.join(printable(d) for d in dates)})" if dates else ""
    changes: list[TextChange] = []
    for e in cal.estimates:
        if e.kind == "measurement_noise":
            changes.append(TextChange(("measurements", e.subject, "noise"), _written(e, e.level),
                                   _comment(e, f"noise of sensor {e.subject}", data + when, "std")))
        elif e.kind == "process_noise":
            changes.append(TextChange(("simulation", "process_noise"), _written(e, e.level),
                                   _comment(e, "process noise level", data + when, None)))
            if e.identifiable and e.start > 0:
                for name, own in sorted(element_levels.items()):
                    changes.append(TextChange(("elements", name, "noise"), number(own * e.level / e.start),
                                           f"# bgc calibrate: {name}'s own process noise scaled as the process "
                                           f"level ({e.level / e.start:.4g} times; was {own:g})"))
        elif e.kind == "parameter":
            changes.append(TextChange(("parameters", e.subject), _written(e, e.value),
                                   _comment(e, e.subject, data + when, None)))
    changes += [TextChange(("measurements", sensor, "residual_variance_sd"), number(v),
                           f"# bgc calibrate: on other data of this plant, {sensor}'s normalised residuals' variance "
                           f"may lie {v:.3g} (one std) off 1 by the estimates' own uncertainty; the test of the "
                           "model's fit allows for it")
                for sensor, v in cal.spread]  # bgc.analysis.calibrate._spread
    out = edit_text(text, changes)
    head = f"# {MARK} calibrate from {printable(source)} on {data}\n"
    return head + out


def _written(e: Estimate, value: float) -> str | None:
    """The text of an identifiable estimate, None for one kept at the model's value."""
    return number(value) if e.identifiable else None


def _comment(e: Estimate, what: str, data: str, std: str | None) -> str:
    """The comment of an estimate: value, interval, data, what it replaces."""
    if not e.identifiable:
        return f"# bgc calibrate: {what} kept at the model's {e.start_level:.6g}: the data ({data}) cannot " \
               f"identify it: {e.why}"
    extra = f", std {e.value:.4g} in [{e.low:.4g}, {e.high:.4g}]" if std else ""
    bound = ""
    if e.at_bound:
        bound = "; the data show none (the likelihood is highest at 0)" if e.value == 0 else \
            "; at the end of the range searched"
    return (f"# bgc calibrate: {what} {e.level:.6g} in [{e.level_low:.6g}, {e.level_high:.6g}] (95 %){extra} "
            f"from {data} (was {e.start_level:.6g}){bound}")


def _last_token(text: str, end: int) -> str:
    """The last character of YAML before index ``end`` that is neither
    blank nor in a comment (a flow mapping may span lines, a comment after
    its trailing comma)."""
    for line in reversed(text[:end].split("\n")):
        cut = next((i for i, c in enumerate(line) if c == "#" and (i == 0 or line[i - 1] in " \t")), len(line))
        kept = line[:cut].rstrip()
        if kept:
            return kept[-1]
    return ""


def _entry(node: yaml.Node | None, key: str) -> tuple[yaml.Node, yaml.Node] | None:
    """The (key, value) nodes of ``key`` in a mapping node."""
    if not isinstance(node, yaml.MappingNode):
        return None
    for k, v in node.value:
        if isinstance(k, yaml.ScalarNode) and k.value == key:
            return k, v
    return None


def _shared(root: yaml.Node) -> set[int]:
    """The nodes a YAML alias reaches as well (the same node object at more than one place)."""
    seen: dict[int, int] = {}
    stack = [root]
    while stack:
        node = stack.pop()
        seen[id(node)] = seen.get(id(node), 0) + 1
        if seen[id(node)] > 1:
            continue
        if isinstance(node, yaml.MappingNode):
            for k, v in node.value:
                stack += [k, v]
        elif isinstance(node, yaml.SequenceNode):
            stack += list(node.value)
    return {i for i, n in seen.items() if n > 1}


def edit_text(text: str, changes: Sequence[TextChange]) -> str:
    """``text`` with every change made: a value replaced in place, or a key
    added to its mapping (a flow mapping gets ``, key: value`` before its
    ``}``, a block mapping a new line at its keys' indentation, an empty
    entry ``{key: value}``); each change's comment on a line above it."""
    root = yaml.compose(text, Loader=yaml.SafeLoader)
    shared = _shared(root)
    spans: list[tuple[int, int, int, str]] = []  # (start, end, order, replacement) within one line
    inserted: set[int] = set()  # the closing braces a key was added before
    opened: dict[int, int] = {}  # an empty entry (``e1:``) made a mapping -> its span's index
    above: dict[int, list[str]] = {}  # original line -> comments to put above it
    after: dict[int, list[tuple[str, str]]] = {}  # original line -> new lines (indented text, comment) after it
    for ch in changes:
        node, key_node = root, None
        for depth, key in enumerate(ch.path):
            found = _entry(node, key)
            if found is None:
                break
            key_node, node = found
        else:
            depth = len(ch.path)
        if depth == len(ch.path):  # the value is there
            if not isinstance(node, yaml.ScalarNode):
                value = _entry(node, "value") if ch.path[0] == "parameters" else None
                if value is None:
                    raise InternalError(f"the calibrated value of {'.'.join(ch.path)} is not a scalar")
                node = value[1]
            line = node.start_mark.line
            above.setdefault(line, []).append(ch.comment)
            if ch.text is not None and id(node) in shared:
                raise CalibrationError(f"{'.'.join(ch.path)} is written through a YAML alias (*name): replacing it "
                                       "would change every value the anchor gives", None,
                                       "write the value in place of the alias, then calibrate")
            if ch.text is not None:
                spans.append((node.start_mark.index, node.end_mark.index, len(spans), ch.text))
            continue
        if ch.text is None:  # kept, and not written in the file: the comment at the mapping
            line = (key_node.start_mark.line if key_node is not None else 0)
            above.setdefault(line, []).append(ch.comment)
            continue
        if id(node) in shared:  # a key added to a mapping an alias gives elsewhere would change it there too
            raise CalibrationError(f"{'.'.join(ch.path[:depth])} is written through a YAML alias (*name): adding "
                                   f"{ch.path[depth]} to it would change every place the anchor gives", None,
                                   "write the mapping in place of the alias, then calibrate")
        missing = ch.path[depth:]  # the keys to add: the first in this mapping, the others nested in flow style
        entry = f"{missing[0]}: " + "".join(f"{{{k}: " for k in missing[1:]) + ch.text + "}" * (len(missing) - 1)
        if isinstance(node, yaml.MappingNode) and node.flow_style:
            end = node.end_mark.index - 1  # the closing brace
            if text[end] != "}":
                raise InternalError(f"a flow mapping of {'.'.join(ch.path[:depth])} without its closing brace")
            bare = _last_token(text, end) in ("{", ",") and end not in inserted  # {} or {a: 1, }
            inserted.add(end)
            spans.append((end, end, len(spans), ("" if bare else ", ") + entry))
            above.setdefault(text.count("\n", 0, end), []).append(ch.comment)
        elif isinstance(node, yaml.MappingNode):  # block: a new line after its last entry
            indent = node.value[0][0].start_mark.column if node.value else 0
            last = node.value[-1][1].end_mark
            line = last.line - 1 if last.column == 0 else last.line
            after.setdefault(line, []).append((" " * indent + entry, ch.comment))
        elif isinstance(node, yaml.ScalarNode) and node.tag.endswith(":null") and key_node is not None:
            if id(node) in opened:  # another key into the same empty entry: one mapping of them all
                start, stop, order, new = spans[opened[id(node)]]
                spans[opened[id(node)]] = (start, stop, order, new[:-1] + ", " + entry + "}")
            else:
                opened[id(node)] = len(spans)
                start = key_node.end_mark.index
                spans.append((start, max(node.end_mark.index, start + 1), len(spans), ": {" + entry + "}"))
            above.setdefault(key_node.start_mark.line, []).append(ch.comment)
        else:
            raise InternalError(f"cannot write {'.'.join(ch.path)} into the model file")
    for start, end, _, new in sorted(spans, reverse=True):  # at one place, the later change first: in order
        if "\n" in text[start:end]:
            raise InternalError("a calibrated value spans lines")
        text = text[:start] + new + text[end:]
    lines = text.split("\n")
    out: list[str] = []
    for i, line in enumerate(lines):
        indent = line[:len(line) - len(line.lstrip())]
        out.extend(indent + c for c in above.get(i, []) if c)
        out.append(line)
        for new, comment in after.get(i, []):
            pad = new[:len(new) - len(new.lstrip())]
            if comment:
                out.append(pad + comment)
            out.append(new)
    return "\n".join(out)
